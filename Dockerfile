# One image for every station: `docker compose up` (compose.yaml) runs four of them.
FROM python:3.11-slim-bookworm

COPY apt-packages.txt /tmp/apt-packages.txt
RUN apt-get update \
 && grep -v '^#' /tmp/apt-packages.txt | xargs apt-get install -y --no-install-recommends \
 && rm -rf /var/lib/apt/lists/*

WORKDIR /abyss
COPY pyproject.toml README.md ./
COPY common common
COPY linkemu linkemu
COPY stations stations
COPY scenarios scenarios
RUN pip install --no-cache-dir .

ENV MUJOCO_GL=egl PYTHONUNBUFFERED=1
EXPOSE 7447
ENTRYPOINT ["abyss"]
CMD ["--help"]

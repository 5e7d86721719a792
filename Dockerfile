# One image for every station: `docker compose up` (compose.yaml) runs four of them.
FROM python:3.11-slim-bookworm

COPY apt-packages.txt /tmp/apt-packages.txt
RUN apt-get update \
 && grep -v '^#' /tmp/apt-packages.txt | xargs apt-get install -y --no-install-recommends \
 && rm -rf /var/lib/apt/lists/*

WORKDIR /abyss
# the package is the repository's top level (pyproject.toml maps it to `abyss`): the shared
# code, the stations, and the testbed around them
COPY pyproject.toml README.md __init__.py py.typed ./
COPY common common
COPY linkemu linkemu
COPY stations stations
COPY launch launch
COPY validation validation
COPY console console
COPY cli cli
COPY scenarios scenarios
RUN pip install --no-cache-dir .

ENV MUJOCO_GL=egl PYTHONUNBUFFERED=1
EXPOSE 7447
ENTRYPOINT ["abyss"]
CMD ["--help"]

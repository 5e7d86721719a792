# One image for every station: `docker compose up` (compose.yaml) runs four of them.
# Needs BuildKit (Docker 23+ by default; DOCKER_BUILDKIT=1 before): the pip layer takes a CA
# bundle as a build secret, for a TLS proxy in the way to PyPI, and never keeps it:
#   docker build --secret id=ca,src=/etc/ssl/certs/ca-certificates.crt -t abyss:latest .
# The base is any Debian 12 with Python 3.11; with no registry at hand, deploy/base-image.sh
# makes one from Debian's packages: --build-arg BASE=abyss-base:bookworm
ARG BASE=python:3.11-slim-bookworm

# the runtime requirements alone, from pyproject.toml: the dependency layer below is rebuilt only
# when they change, not when anything else in pyproject.toml does
FROM ${BASE} AS requirements
COPY pyproject.toml /tmp/pyproject.toml
RUN python3 -c 'import tomllib; p = tomllib.load(open("/tmp/pyproject.toml", "rb")); \
print("\n".join(p["build-system"]["requires"] + p["project"]["dependencies"]))' > /tmp/requirements.txt

FROM ${BASE} AS runtime
COPY apt-packages.txt /tmp/apt-packages.txt
RUN apt-get update \
 && grep -v '^#' /tmp/apt-packages.txt | xargs apt-get install -y --no-install-recommends \
 && rm -rf /var/lib/apt/lists/*

# one virtual environment, whichever Python the base has (the official image's or Debian's)
RUN python3 -m venv /opt/abyss
ENV PATH=/opt/abyss/bin:$PATH MUJOCO_GL=egl PYTHONUNBUFFERED=1

# the heavy layer (MuJoCo, Pinocchio, Open3D, rerun, Zenoh, ...), before the code; the CA bundle
# is mounted for this step only; pip's cache is BuildKit's, never the image's (it keeps what the
# index lets it cache, for the next change of requirements)
COPY --from=requirements /tmp/requirements.txt /tmp/requirements.txt
RUN --mount=type=secret,id=ca --mount=type=cache,target=/root/.cache/pip \
    if [ -s /run/secrets/ca ]; then export PIP_CERT=/run/secrets/ca; fi \
 && pip install --disable-pip-version-check -r /tmp/requirements.txt

WORKDIR /abyss
# the package is the repository's top level (pyproject.toml maps it to `abyss`): the shared
# code, the stations, and the testbed around them; a thin layer, installed offline
COPY pyproject.toml README.md __init__.py py.typed ./
COPY common common
COPY description description
COPY interface interface
COPY timing timing
COPY security security
COPY config config
COPY bus bus
COPY linkemu linkemu
COPY scene scene
COPY mavlink mavlink
COPY stations stations
COPY launch launch
COPY validation validation
COPY console console
COPY cli cli
COPY recording recording
COPY ros2 ros2
COPY scenarios scenarios
RUN pip install --disable-pip-version-check --no-cache-dir --no-deps --no-build-isolation --no-index . \
 && rm -rf build

EXPOSE 7447
ENTRYPOINT ["abyss"]
CMD ["--help"]

# the physics in C, built against the MuJoCo installed above (stations/simulation/native.py) in a
# stage of its own, so that the compiler stays out of the image: the same physics as a host's
# setup.sh builds, and a run replays alike in either
FROM runtime AS native
RUN apt-get update \
 && apt-get install -y --no-install-recommends gcc libc6-dev \
 && python3 -m abyss.stations.simulation.native

FROM runtime
COPY --from=native /opt/abyss/lib/abyss /opt/abyss/lib/abyss

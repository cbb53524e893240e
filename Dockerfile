# The image of every fixstream Python service (recorder, player, estimators, and the router of
# compose.local-router.yaml); compose.yaml names it fixstream:latest. docs/stack.md#the-image.
#
#   docker build -t fixstream:latest .                                   # official Python base image
#   podman build --build-arg BASE_IMAGE=localhost/fixstream-base:bookworm \
#       --secret id=pip_cert,src=/etc/ssl/certs/ca-certificates.crt -t fixstream:latest .
#
# BASE_IMAGE: any Debian-like image with python3 (>= 3.11) and its venv module; `make base-image` builds
# localhost/fixstream-base:bookworm from Debian packages where no registry image can be pulled.
# The secret pip_cert (optional): a CA bundle for pip, where HTTPS goes through a proxy with its own CA.
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}

ENV PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    VIRTUAL_ENV=/opt/fixstream \
    PATH=/opt/fixstream/bin:$PATH \
    MPLCONFIGDIR=/tmp/matplotlib

# 1. Dependencies: exactly the lock file (versions and hashes), nothing resolved. This layer depends on
#    requirements.lock alone, so a code edit does not reinstall numpy.
COPY requirements.lock /opt/requirements.lock
RUN --mount=type=secret,id=pip_cert \
    if [ -s /run/secrets/pip_cert ]; then export PIP_CERT=/run/secrets/pip_cert; fi \
    && python3 -m venv "$VIRTUAL_ENV" \
    && pip install -q --require-hashes --no-deps -r /opt/requirements.lock

# 2. The user the services run as; the recordings directory (a volume in compose.yaml) is its own, so a
#    named volume starts writable by it (a bind-mounted host directory must be: docs/stack.md).
RUN groupadd --system --gid 10001 fixstream \
    && useradd --system --uid 10001 --gid fixstream --home-dir /home/fixstream --create-home \
       --shell /usr/sbin/nologin fixstream \
    && mkdir -p /data/recordings \
    && chown fixstream:fixstream /data/recordings

# 3. The project itself, without dependency resolution (they are all in layer 1), built with the locked
#    setuptools; scenarios last (editing a scenario reinstalls nothing).
WORKDIR /app
COPY pyproject.toml README.md ./
COPY schemas ./schemas
COPY shared ./shared
COPY services ./services
COPY tools ./tools
RUN pip install -q --no-deps --no-build-isolation . \
    && pip check \
    && rm -rf build ./*.egg-info
COPY scenarios ./scenarios

USER fixstream:fixstream

# compose.yaml gives each service its full command ("fixstream run recorder", "fixstream play ...").
ENTRYPOINT []
CMD ["fixstream", "--help"]

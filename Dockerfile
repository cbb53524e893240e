# The image of every fixstream Python service (recorder, player, estimators); compose.yaml builds it.
FROM python:3.11-slim

ENV PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

WORKDIR /app

# Dependencies and code first, scenarios last (editing a scenario does not reinstall the package).
COPY pyproject.toml README.md ./
COPY schemas ./schemas
COPY shared ./shared
COPY services ./services
RUN pip install . && mkdir -p /data/recordings

COPY scenarios ./scenarios

# compose.yaml gives each service its full command ("fixstream run recorder", "fixstream play ...").
ENTRYPOINT []
CMD ["fixstream", "--help"]

# One image for the API, the workers and the one-off migration (docker-compose.yml picks the command).
FROM python:3.11-slim

# libglib: OpenCV's bundled FFmpeg links against it (the headless wheel needs no libGL).
RUN apt-get update && apt-get install -y --no-install-recommends libglib2.0-0 \
    && rm -rf /var/lib/apt/lists/*

WORKDIR /app
COPY pyproject.toml README.md alembic.ini ./
COPY core core
COPY cli cli
COPY service service
COPY worker worker
COPY migrations migrations
# Editable, so service/migrate.py finds migrations/ and alembic.ini beside the packages.
RUN pip install --no-cache-dir -e '.[service,monitor]'

ENV MOCAP_DATA_DIR=/data
EXPOSE 8000
CMD ["mocap", "serve", "--host", "0.0.0.0", "--port", "8000", "--workers", "0"]

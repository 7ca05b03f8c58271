# The tuning service, on this machine only:
#   docker build -t tuner . && docker run -p 127.0.0.1:8000:8000 -e TUNER_ALLOW_NO_KEY=1 -v tuner-data:/data tuner
# In its container it listens on 0.0.0.0 (how a published port reaches it), so it starts only with an API key
# (-e TUNER_API_KEY=...: clients send it as X-API-Key) or the explicit TUNER_ALLOW_NO_KEY=1 (logged), which the
# command above gives because -p 127.0.0.1: publishes the port to this machine alone. Serving others: set a key.
# Results go to the SQLite file /data/tuner.db unless TUNER_DATABASE_URL points elsewhere
# (e.g. postgresql+psycopg://user:password@db:5432/tuner); settings: TUNER_* (see api/settings.py).
FROM python:3.11-slim

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

WORKDIR /src
COPY pyproject.toml README.md ./
COPY tuner ./tuner
COPY api ./api
# gcc: the NLPs' compiled code (tuner.optimize.nlp.codecache), built here for the README's loops and at run time
# for new problem shapes (in the background)
RUN apt-get update && apt-get install -y --no-install-recommends gcc libc6-dev && rm -rf /var/lib/apt/lists/*
RUN pip install --no-cache-dir .
# the compiled core's caches, built at build time: the batch's kernels (numba) and the NLP shapes of the README's
# roll loop (px4_rate's shapes are compiled in the background at run time where their C is at most 4 MB, the two
# smallest of six; the others stay interpreted: codecache.MAX_SOURCE_BYTES); writable by the service's user
ENV TUNER_CACHE_DIR=/opt/tuner-cache
RUN python -m tuner.optimize.kernels \
    && (TUNER_NLP_COMPILE=auto tuner tune --plant "0.2655*14.8528^2/(s^2+14.195*s+14.8528^2)" --dt 0.04 --structure pid_z || true) \
    && python -m tuner.optimize.nlp.codecache --wait && python -m tuner.optimize.nlp.codecache

RUN useradd --create-home --uid 10001 --shell /usr/sbin/nologin tuner \
    && mkdir -p /data && chown tuner:tuner /data && chown -R tuner:tuner /opt/tuner-cache
USER tuner
WORKDIR /data
ENV TUNER_DATABASE_URL=sqlite:////data/tuner.db
# Host names served (api.guard): loopback by default (docker run -p 127.0.0.1:8000:8000 ...); reached under
# another name, set e.g. -e TUNER_ALLOWED_HOSTS=tuner.example.com (else 400)
VOLUME ["/data"]

EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=60s --retries=3 \
    CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/health', timeout=4)"
CMD ["python", "-m", "api", "--host", "0.0.0.0", "--port", "8000"]

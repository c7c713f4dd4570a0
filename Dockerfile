# reglib: the HTTP service by default; the same image runs Dask schedulers and workers and batch jobs.
#
#   docker build -t reglib .
#   docker run -p 8000:8000 reglib                                    # the service (health: /livez)
#   docker run --no-healthcheck -p 8786:8786 -p 8787:8787 reglib dask scheduler
#   docker run --no-healthcheck -v /data:/data reglib dask worker tcp://SCHEDULER:8786 --nworkers 1 --nthreads 1
#   docker run --no-healthcheck -v /data:/data reglib reglib batch /data/pairs.csv --out /data/out --scheduler tcp://SCHEDULER:8786
#   docker run --no-healthcheck -v /data:/data reglib reglib batch /data/pairs.csv --out /data/out --workers 4
#
# Batch jobs on a cluster need the images and the output folder at the same path on every worker
# (a shared volume, here /data). The health check probes the service; give --no-healthcheck (or
# healthcheck: disable in compose) to the containers that run something else.
#
# Stopping the service: `docker stop` sends SIGTERM to PID 1, which is `reglib serve` itself (exec-form
# CMD, no shell in between): it answers 503 to new requests, lets the requests in flight finish within
# REGLIB_SHUTDOWN_GRACE_S, and exits 0. Docker kills the container 10 s after the signal unless told
# otherwise, and after the grace uvicorn still waits up to 5 s for connections busy with a request (a
# slow client's included) before the workers stop: the image sets a 3 s grace so that all of it fits.
# For a longer one raise both together, e.g.
#   docker run --stop-timeout 40 -e REGLIB_SHUTDOWN_GRACE_S=30 -p 8000:8000 reglib
# (compose: stop_grace_period; Kubernetes: terminationGracePeriodSeconds, and /readyz for the probe).
#
# The health check probes /livez, not /readyz: Docker (and Swarm, which replaces unhealthy containers) should
# act on a process that no longer answers, not on one that is draining or replacing a worker; a load balancer's
# probe is the place for /readyz.
FROM python:3.11.7-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    REGLIB_SHUTDOWN_GRACE_S=3 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

RUN useradd --create-home --uid 10001 --shell /usr/sbin/nologin reglib
WORKDIR /opt/reglib

# Dependencies first, from pyproject.toml alone, so editing the code does not reinstall them.
COPY pyproject.toml ./
RUN python -c "import tomllib; p = tomllib.load(open('pyproject.toml', 'rb'))['project']; extra = p['optional-dependencies']; print('\n'.join(p['dependencies'] + extra['service'] + extra['dask']))" > /tmp/requirements.txt \
 && pip install -r /tmp/requirements.txt \
 && rm /tmp/requirements.txt

# Then the code itself (no dependency resolution: they are all there).
COPY README.md LICENSE ./
COPY reglib ./reglib
COPY service ./service
RUN pip install --no-deps . && rm -rf build ./*.egg-info

USER reglib
WORKDIR /home/reglib
EXPOSE 8000 8786 8787

HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
  CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/livez', timeout=4)"

STOPSIGNAL SIGTERM
CMD ["reglib", "serve", "--host", "0.0.0.0"]

# vista: one image for the supervisor (`vista serve`), the schema migration
# (`vista migrate`) and the job workers (`vista worker --queues …`); see docker-compose.yml.
#
# Docker does not run on the development machine, so this file is never built there;
# tests/test_compose.py checks it (and docker-compose.yml) statically instead.

FROM python:3.11-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1

# Runtime libraries only: every dependency ships a manylinux wheel, so no compiler.
# libusb-1.0-0 is for open3d (ray casting in the simulators).
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      libusb-1.0-0 \
 && rm -rf /var/lib/apt/lists/*

WORKDIR /app

# torch is pinned to 2.13.0 in pyproject.toml. A Docker build takes the CPU-only wheel
# from PyTorch's own index (the default PyPI wheel drags in CUDA libraries); the
# `pip install -e .` below then finds the pin already satisfied.
RUN pip install torch==2.13.0 --index-url https://download.pytorch.org/whl/cpu

# Only what the distribution needs: the Alembic migrations are found next to the
# `supervisor` package (supervisor/migrate.py), so they are copied alongside it.
COPY pyproject.toml alembic.ini ./
COPY contract ./contract
COPY supervisor ./supervisor
COPY services ./services
COPY migrations ./migrations
RUN pip install -e ".[cad]"

# Non-root user; its data folder holds the artifact volume mount point, created here so
# a fresh named volume takes this ownership.
RUN groupadd --system vista \
 && useradd --system --gid vista --home-dir /var/lib/vista --shell /usr/sbin/nologin vista \
 && mkdir -p /var/lib/vista/artifacts /var/cache/vista-numba \
 && chown -R vista:vista /var/lib/vista /var/cache/vista-numba
USER vista

# The services' numba kernels compiled into the image, so that no container's first job
# waits about a minute for the compiler. The cache is the vista user's: numba only reads a
# cache it could also write.
ENV NUMBA_CACHE_DIR=/var/cache/vista-numba
RUN vista precompile

ENV VISTA_DATA_DIR=/var/lib/vista \
    VISTA_ARTIFACT_DIR=/var/lib/vista/artifacts \
    VISTA_HOST=0.0.0.0 \
    VISTA_PORT=8000

EXPOSE 8000

ENTRYPOINT ["vista"]
CMD ["serve"]

# One image for the farfield API and its render workers (see docker-compose.yml).
#
#   docker build -t farfield .
#   docker run --rm farfield inspect /data/scene.glb          # the entrypoint is the `farfield` command
#
# Rendering is headless OpenGL on EGL (moderngl/glcontext load libEGL.so.1 and libGL.so.1):
#
# - CPU machines: Mesa's EGL (libegl-mesa0) with the llvmpipe software rasteriser (in
#   libgl1-mesa-dri).  Nothing else is needed; this is what a container gets by default.
# - NVIDIA GPUs: nothing NVIDIA is installed in the image.  The NVIDIA Container Toolkit on the
#   host mounts the driver's user-space libraries into the container when it starts, including
#   libEGL_nvidia.so and its GLVND vendor file (/usr/share/glvnd/egl_vendor.d/10_nvidia.json), as
#   long as the "graphics" driver capability is asked for.  NVIDIA_DRIVER_CAPABILITIES below asks
#   for it (plus compute and utility, for nvidia-smi, which `farfield up` uses to count GPUs), and
#   the GLVND loader (libegl1) then offers the NVIDIA EGL devices next to Mesa's.  Run with
#   `docker run --gpus all ...` or the compose profile `gpu` (docker-compose.yml).
FROM python:3.11-slim-bookworm

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    NVIDIA_DRIVER_CAPABILITIES=graphics,compute,utility \
    FARFIELD_HOME=/var/lib/farfield

# libegl1/libgl1: the GLVND loaders; libegl-mesa0 + libgl1-mesa-dri: Mesa EGL and llvmpipe.
RUN apt-get update \
 && apt-get install -y --no-install-recommends libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri \
 && rm -rf /var/lib/apt/lists/*

WORKDIR /opt/farfield
COPY pyproject.toml README.md ./
COPY core ./core
COPY service ./service
COPY api ./api
COPY workers ./workers
COPY cli ./cli
# Installed as a wheel: one import package, farfield, with its shaders, migrations and dashboard.
RUN pip install . \
 && useradd --system --create-home --home-dir /var/lib/farfield --uid 10001 farfield

USER farfield
WORKDIR /var/lib/farfield
EXPOSE 8000
ENTRYPOINT ["farfield"]
CMD ["--help"]

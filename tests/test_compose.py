"""docker-compose.yml: its structure always, and ``docker compose config`` where the docker client has compose.

``docker compose config`` parses, interpolates and validates the file against the Compose
specification without a Docker daemon.  It runs with the docker client's compose plugin, or else
with Debian's ``docker-compose`` (Compose 1.29, which ``.ci/run`` installs when the docker client is
present without the plugin; the file keeps to what both accept, hence no top-level ``name``), and
is skipped, with the reason, where neither exists.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parent.parent
COMPOSE = ROOT / "docker-compose.yml"
SERVICES = {"redis", "postgres", "minio", "api", "worker"}
S3_VARIABLES = {"FARFIELD_S3_ENDPOINT", "FARFIELD_S3_BUCKET", "FARFIELD_S3_KEY", "FARFIELD_S3_SECRET"}


COMMAND: list[str] = []


def _compose(*args: str) -> subprocess.CompletedProcess:
    # Without the variables the file interpolates, so that its defaults are what is checked.
    env = {k: v for k, v in os.environ.items() if not k.startswith(("FARFIELD_", "MINIO_", "POSTGRES_", "COMPOSE_"))}
    env["FARFIELD_ADMIN_KEY"] = "ff_admin_test-secret"  # required: the file has no default admin key
    return subprocess.run(
        [*COMMAND, "-f", str(COMPOSE), *args],
        cwd=ROOT,
        env=env,
        check=False,
        capture_output=True,
        text=True,
        timeout=120,
    )


def _runs(command: list[str]) -> subprocess.CompletedProcess | None:
    try:
        result = subprocess.run([*command, "version"], check=False, capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.SubprocessError):
        return None
    return result if result.returncode == 0 else None


@pytest.fixture(scope="module")
def docker_compose():
    """``docker compose`` (the plugin) or else ``docker-compose`` (Compose 1.29); skips without either."""
    for command in (["docker", "compose"], ["docker-compose"]):
        if shutil.which(command[0]) and (version := _runs(command)):
            COMMAND[:] = command
            return version.stdout.strip()
    pytest.skip("neither 'docker compose' (the docker client's plugin) nor 'docker-compose' is installed")


def test_compose_config_validates(docker_compose):
    result = _compose("config", "-q")
    assert result.returncode == 0, result.stderr
    result = _compose("--profile", "gpu", "config", "-q")
    assert result.returncode == 0, result.stderr


def test_compose_config_has_the_services(docker_compose):
    result = _compose("--profile", "gpu", "config")  # the resolved file, as YAML (every Compose version)
    assert result.returncode == 0, result.stderr
    config = yaml.safe_load(result.stdout)
    services = config["services"]
    assert SERVICES | {"worker-gpu"} <= set(services)
    for name in ("api", "worker", "worker-gpu"):
        environment = services[name]["environment"]
        assert S3_VARIABLES <= set(environment), name
        assert environment["DATABASE_URL"].startswith("postgresql+psycopg://")
        assert environment["REDIS_URL"].startswith("redis://")
    devices = services["worker-gpu"]["deploy"]["resources"]["reservations"]["devices"]
    assert devices[0]["driver"] == "nvidia"


# -- without docker: the file as YAML -----------------------------------------------------


@pytest.fixture(scope="module")
def compose_file() -> dict:
    return yaml.safe_load(COMPOSE.read_text())


def test_compose_file_has_the_services(compose_file):
    services = compose_file["services"]
    assert SERVICES <= set(services)
    assert services["redis"]["image"].startswith("redis:7")
    assert services["postgres"]["image"].startswith("postgres:15")
    assert "healthcheck" in services["postgres"]
    assert services["minio"]["image"].startswith("minio/minio")
    assert services["minio"]["command"][:2] == ["server", "/data"]


def test_api_and_workers_share_one_image_and_the_settings(compose_file):
    services = compose_file["services"]
    api, worker, gpu = services["api"], services["worker"], services["worker-gpu"]
    assert api["build"] == worker["build"] == gpu["build"] == "."
    assert api["image"] == worker["image"] == gpu["image"]
    assert [api["entrypoint"][0], *api["command"]] == [
        "uvicorn",
        "farfield.api.app:app_from_env",
        "--factory",
        "--host",
        "0.0.0.0",
        "--port",
        "8000",
        "--no-server-header",
        "--http",  # header and body read timeouts (api/read_timeouts.py), as farfield up runs it
        "farfield.api.read_timeouts:TimedH11Protocol",
    ]
    assert "8000:8000" in api["ports"]
    assert worker["command"][0] == "worker" and gpu["command"][0] == "worker"
    for name in ("api", "worker", "worker-gpu"):
        environment = services[name]["environment"]
        assert S3_VARIABLES | {"REDIS_URL", "DATABASE_URL", "FARFIELD_ADMIN_KEY"} <= set(environment), name
        assert environment["DATABASE_URL"].startswith("postgresql+psycopg://")
        assert environment["FARFIELD_S3_ENDPOINT"] == "http://minio:9000"
    assert {k: v for k, v in gpu["environment"].items() if k != "NVIDIA_DRIVER_CAPABILITIES"} == worker["environment"]


def test_gpu_worker_reserves_nvidia_gpus_with_graphics(compose_file):
    gpu = compose_file["services"]["worker-gpu"]
    assert gpu["profiles"] == ["gpu"]
    (device,) = gpu["deploy"]["resources"]["reservations"]["devices"]
    assert device["driver"] == "nvidia"
    assert {"gpu", "graphics"} <= set(device["capabilities"])  # graphics: the toolkit mounts libEGL_nvidia


def test_dockerfile_matches(compose_file):
    dockerfile = (ROOT / "Dockerfile").read_text()
    assert "FROM python:3.11-slim-bookworm" in dockerfile
    for package in ("libegl1", "libgl1", "libegl-mesa0"):
        assert package in dockerfile
    assert 'ENTRYPOINT ["farfield"]' in dockerfile
    assert "NVIDIA_DRIVER_CAPABILITIES=graphics,compute,utility" in dockerfile

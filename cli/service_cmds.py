"""``farfield up``, ``farfield worker`` and ``farfield keys``: run the service and manage API keys."""

from __future__ import annotations

import json
import os
import sys
from dataclasses import replace

import click

from farfield.service.db import Database
from farfield.service.keys import create_key, list_keys, revoke_key
from farfield.service.settings import Settings


@click.command("up")
@click.option(
    "--workers",
    type=click.IntRange(min=1),
    default=None,
    help="Render workers to start (default: one per GPU, at least one; FARFIELD_WORKERS).",
)
@click.option("--host", default=None, help="Address the API listens on (default 127.0.0.1; FARFIELD_HOST).")
@click.option(
    "--port",
    type=click.IntRange(0, 65535),
    default=None,
    help="Port the API listens on, 0 for any free one (default 8000; FARFIELD_PORT).",
)
def up(workers, host, port):
    """Start the service with its embedded defaults: Redis, the API and render workers.

    Prints the dashboard URL and the admin API key; Ctrl-C or SIGTERM stops everything.  The
    flags win over the environment variables.
    """
    from farfield.service.supervisor import Service, render_devices

    settings = Settings.from_env()
    settings = replace(
        settings, host=settings.host if host is None else host, port=settings.port if port is None else port
    )
    service = Service(settings, workers=workers or render_devices())
    service.handle_signals()  # before any child exists, so none is left behind by an early signal
    try:
        service.start()
        click.echo(f"farfield is up: dashboard {service.url}/  API {service.url}/v1  docs {service.url}/docs")
        click.echo(f"admin API key: {service.key}")
        click.echo(f"data: {service.settings.home}   workers: {service.workers}   broker: {service.settings.redis_url}")
        click.echo("press Ctrl-C to stop", err=True)
        sys.stdout.flush()
        service.watch()
    finally:
        service.stop()
    click.echo("farfield stopped", err=True)


@click.command("worker", context_settings={"ignore_unknown_options": True})
@click.option(
    "--concurrency",
    "-c",
    type=click.IntRange(min=1),
    default=None,
    help="Cells rendered at once: one per EGL device (default: one per NVIDIA GPU, each pool process on its own "
    "GPU, FARFIELD_EGL_DEVICES; one without GPUs).",
)
@click.option("--name", default="worker", show_default=True)
def worker(concurrency, name):
    """Join this machine to a running service as a render worker (needs REDIS_URL and DATABASE_URL)."""
    from farfield.service.supervisor import gpu_count, worker_command

    gpus = gpu_count()
    if gpus and not (os.environ.get("FARFIELD_EGL_DEVICES") or os.environ.get("FARFIELD_EGL_DEVICE")):
        os.environ["FARFIELD_EGL_DEVICES"] = ",".join(str(i) for i in range(gpus))  # pool process i on GPU i
    concurrency = concurrency or max(1, gpus)

    settings = Settings.from_env()
    if settings.redis_url is None:
        raise click.UsageError(
            "set REDIS_URL, DATABASE_URL and FARFIELD_S3_* (or a shared FARFIELD_BLOB_DIR) to the service's Redis, database and blob store"
        )
    Database(settings.database_url).migrate()
    command = worker_command(name, concurrency)
    os.execvpe(command[0], command, {**os.environ, **settings.environment()})


@click.group("keys")
def keys():
    """Create, revoke and list API keys (stored hashed; each belongs to a tenant)."""


def _db() -> Database:
    db = Database(Settings.from_env().database_url)
    db.migrate()
    return db


@keys.command("create")
@click.option("--tenant", required=True, help="Tenant name (created if new).")
@click.option("--json", "as_json", is_flag=True)
def keys_create(tenant, as_json):
    """Create a key for TENANT and print it (it is shown only once)."""
    key, prefix = create_key(_db(), tenant)
    click.echo(json.dumps({"key": key, "prefix": prefix, "tenant": tenant}) if as_json else key)


@keys.command("revoke")
@click.argument("prefix")
def keys_revoke(prefix):
    """Revoke the key whose prefix (the part after ``ff_``) is PREFIX."""
    revoke_key(_db(), prefix)
    click.echo(f"revoked {prefix}")


@keys.command("list")
@click.option("--json", "as_json", is_flag=True)
def keys_list(as_json):
    """List keys: prefix, tenant, revoked."""
    rows = list_keys(_db())
    if as_json:
        click.echo(json.dumps(rows))
    else:
        for row in rows:
            click.echo(f"{row['prefix']}\t{row['tenant']}\t{'revoked' if row['revoked'] else 'active'}")

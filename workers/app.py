"""The Celery application: Redis broker, the ``render`` and ``render.heavy`` queues, late acknowledgement, prefetch 1.

``celery -A farfield.workers.app worker`` (what ``farfield worker`` runs) reads the settings from the
environment.  A cell is acknowledged only after it ends, so a worker that dies mid-cell leaves it
to be delivered again: at once when a pool child is killed (``task_reject_on_worker_lost``); when
the whole worker is, its cell's lease runs out and the API's sweep queues and sends it again
(:mod:`farfield.service.jobs.leases`), long before the visibility timeout would bring the message back.  The visibility timeout is longer than the
longest cell (the settings refuse one shorter than the task's hard time limit,
``FARFIELD_CELL_TIME_LIMIT`` + 60 s), so a slow cell is not handed to a second worker while the
first still runs.

A cell whose admission planned more than ``FARFIELD_HEAVY_TEXELS`` goes to ``render.heavy``, every
other task to ``render`` (:mod:`farfield.service.pools`: GPU workers consume the first, CPU workers the
second, each the other's too while no worker of that kind is live).
"""

from __future__ import annotations

from collections.abc import Callable

from celery import Celery
from kombu.exceptions import OperationalError
from redis.exceptions import ConnectionError as RedisConnectionError
from redis.exceptions import TimeoutError as RedisTimeoutError

from farfield.service.pools import LIGHT_QUEUE
from farfield.service.settings import Settings

RENDER_QUEUE = LIGHT_QUEUE  # the light queue (service.pools); heavy cells go to render.heavy
BAKE_CELL = "farfield.bake_cell"
# A placement job's planning and its check-and-repair rounds (service.placement) go to the same
# render queue: every worker farfield up starts takes them with no queue of its own to configure, and
# a plan needs what a bake needs (the stored scene, a process that may use much memory for a while).
# The price: a plan waits behind the cells queued before it, like a cell does.
PLAN_PLACEMENT = "farfield.plan_placement"
CHECK_PLACEMENT = "farfield.check_placement"
PLANNING_TASKS = {"plan": PLAN_PLACEMENT, "check": CHECK_PLACEMENT}
# A job's admission (service.jobs.admitting: every cell's full check before any is baked) goes there too.
ADMIT_JOB = "farfield.admit_job"
# Sending while Redis restarts (the API's and a worker's sends alike).
# What a send raises when the broker stays away past its retries (kombu wraps the transport's errors
# in OperationalError; a connection refused or reset is an OSError): the cases in which a message is
# left to the API's next sweep.  Anything else is a bug and raises.
BROKER_ERRORS = (OperationalError, RedisConnectionError, RedisTimeoutError, OSError)
SEND_RETRY_POLICY = {"max_retries": 30, "interval_start": 0.2, "interval_step": 0.5, "interval_max": 2.0}


def make_celery(settings: Settings) -> Celery:
    """A Celery app on ``settings``' Redis (which must be known by now)."""
    app = Celery("farfield", broker=settings.redis_url, include=["farfield.workers.tasks"])
    app.conf.update(
        task_default_queue=RENDER_QUEUE,
        task_routes={name: {"queue": RENDER_QUEUE} for name in (BAKE_CELL, PLAN_PLACEMENT, CHECK_PLACEMENT, ADMIT_JOB)},
        task_acks_late=True,
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,
        task_ignore_result=True,  # job and cell state live in SQL
        broker_transport_options={"visibility_timeout": settings.visibility_timeout},
        broker_connection_retry_on_startup=True,
        broker_connection_max_retries=None,  # ride out a Redis restart
        worker_hijack_root_logger=False,
        worker_send_task_events=False,
    )
    return app


def send_cells(
    celery: Celery,
    cell_ids: list[str],
    queues: dict[str, str] | None = None,
    unsent: Callable[[list[str]], object] | None = None,
    retry_policy: dict = SEND_RETRY_POLICY,
) -> None:
    """One bake task per cell to its queue in ``queues`` (:func:`farfield.service.pools.cell_queues`;
    a cell not named there, to the render queue), each send retried while Redis is away
    (``retry_policy``).  Where a send fails past its retries, ``unsent`` is called with the ids not
    sent (that one on: :func:`farfield.service.jobs.cells.resend_at_next_sweep` has the API's next
    sweep send them) before the error is raised."""
    for n, cell_id in enumerate(cell_ids):
        queue = (queues or {}).get(cell_id, RENDER_QUEUE)
        try:
            celery.send_task(BAKE_CELL, args=[cell_id], queue=queue, retry=True, retry_policy=retry_policy)
        except BROKER_ERRORS:
            if unsent is not None:
                unsent(list(cell_ids[n:]))
            raise


def send_planning(celery: Celery, job_id: str, phase: str = "plan", retry_policy: dict = SEND_RETRY_POLICY) -> None:
    """A placement job's plan (``phase`` "plan") or check task to the render queue."""
    celery.send_task(PLANNING_TASKS[phase], args=[job_id], queue=RENDER_QUEUE, retry=True, retry_policy=retry_policy)


def send_admission(celery: Celery, job_id: str, retry_policy: dict = SEND_RETRY_POLICY) -> None:
    """A job's admission task (its cells' full checks) to the render queue."""
    celery.send_task(ADMIT_JOB, args=[job_id], queue=RENDER_QUEUE, retry=True, retry_policy=retry_policy)


celery_app = make_celery(Settings.from_env())
app = celery_app  # what `celery -A farfield.workers.app` looks for

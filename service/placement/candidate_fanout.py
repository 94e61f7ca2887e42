"""A placement job's candidate step fanned out to the render workers (issue 57, item 5).

With ``FARFIELD_PLANNING_PARTS`` = N > 1 (default 1: in the planning process, as before), the job's
planning task cuts the candidate step into N ranges of hierarchy nodes of about equal work
(:func:`farfield.core.placement.candidate_parts.node_ranges`), stores their inputs (settings,
hierarchy, problem views) in the blob store, and sends one ``plan_candidate_part`` task per range to
the render queue.  Then it computes parts itself: each part is claimed in Redis
(``SET NX`` with an expiry a claimant's thread keeps renewing) by whichever process asks first, the
planning task or a worker's part task; a worker stores its part in the blob store.  The planning
task takes every part no one has claimed, then waits for the others, computing any whose claim
lapsed or was dropped (a worker that died or failed), so a single worker, whose part tasks can only
run after its planning task, plans everything itself and never waits for them.  The parts, merged in
node order, are the candidates one process makes (:func:`farfield.core.placement.candidate_parts.merge_candidates`;
tested through a real worker); the greedy runs on them in the planning task.

While it waits the planning task reports progress (nodes of finished parts) every poll, which is
where a cancelled job is noticed (:func:`farfield.service.placement.rounds._progress`).  Its inputs
and parts are deleted when it ends either way; a part task that finds the inputs gone does nothing.
"""

from __future__ import annotations

import contextlib
import logging
import os
import pickle
import threading
import time
import uuid
from collections.abc import Callable, Mapping

from farfield.core.errors import NotFoundError, ServiceConfigError
from farfield.core.placement.candidate_parts import candidate_part, merge_candidates, node_ranges
from farfield.core.placement.candidates import Candidates
from farfield.core.placement.part_inputs import PartInputs
from farfield.service.blobs import BlobStore

PARTS_ENV = "FARFIELD_PLANNING_PARTS"
CLAIM_S = 30  # a claim lapses this long after its claimant last renewed it
RENEW_S = 5.0
POLL_S = 0.05

log = logging.getLogger("farfield.planning")
# (prefix, part, start, stop) -> send a part's task to the render queue; set by farfield.workers.tasks
_SEND: list[Callable[[str, int, int, int], None]] = []


def register_sender(send: Callable[[str, int, int, int], None]) -> None:
    """How part tasks are sent (the worker's Celery app); without one, planning stays in one process."""
    _SEND[:] = [send]


def planning_parts(env: Mapping[str, str] | None = None) -> int:
    """``FARFIELD_PLANNING_PARTS``: how many parts a job's candidate step is cut into (1: none).

    >>> planning_parts({}), planning_parts({"FARFIELD_PLANNING_PARTS": "8"})
    (1, 8)
    >>> planning_parts({"FARFIELD_PLANNING_PARTS": "0"})
    Traceback (most recent call last):
    ...
    farfield.core.errors.ServiceConfigError: FARFIELD_PLANNING_PARTS must be a whole number >= 1, got '0'
    """
    given = (os.environ if env is None else env).get(PARTS_ENV, "1")
    try:
        parts = int(given)
    except ValueError:
        parts = 0
    if parts < 1:
        raise ServiceConfigError(f"{PARTS_ENV} must be a whole number >= 1, got {given!r}")
    return parts


def _claims():
    """A Redis client on the broker's Redis (where claims live)."""
    import redis

    from farfield.service.settings import Settings

    url = Settings.from_env().redis_url
    if url is None:
        raise ServiceConfigError("fanning planning out needs the broker's Redis (REDIS_URL)")
    return redis.Redis.from_url(url)


def _claim_key(prefix: str, part: int) -> str:
    return f"farfield:{prefix}:claim-{part}"


def _part_key(prefix: str, part: int) -> str:
    return f"{prefix}/part-{part}.pickle"


def _inputs_key(prefix: str) -> str:
    return f"{prefix}/inputs.pickle"


@contextlib.contextmanager
def _held(claims, key: str):
    """Keep claim ``key`` alive while the block runs (a thread renews it); drop it if the block fails."""
    stop = threading.Event()

    def renew() -> None:
        while not stop.wait(RENEW_S):
            with contextlib.suppress(Exception):
                claims.expire(key, CLAIM_S)

    thread = threading.Thread(target=renew, name="claim-renew", daemon=True)
    thread.start()
    try:
        yield
    except BaseException:
        with contextlib.suppress(Exception):
            claims.delete(key)
        raise
    finally:
        stop.set()
        thread.join()


def for_job(blobs: BlobStore, job_id: str, parts: int | None = None):
    """The ``candidates`` hook of :func:`farfield.core.placement.planner.place` for a job: None where
    planning stays in one process (one part, or no worker's sender registered)."""
    parts = planning_parts() if parts is None else parts
    if parts <= 1 or not _SEND:
        return None
    send = _SEND[0]

    def candidates(inputs: PartInputs, progress: Callable[[int, int], None]) -> Candidates:
        ranges = node_ranges(inputs, parts)
        if len(ranges) == 1:
            return candidate_part(inputs, ranges[0], progress)
        return _fan_out(
            blobs, _claims(), send, f"jobs/{job_id}/candidate-parts/{uuid.uuid4().hex}", inputs, ranges, progress
        )

    return candidates


def _fan_out(blobs, claims, send, prefix: str, inputs: PartInputs, ranges: list[range], progress) -> Candidates:
    """Compute or collect every part of ``ranges`` (module docstring) and merge them."""
    total, done, results = inputs.hierarchy.count, [0], {}
    blobs.put_bytes(_inputs_key(prefix), inputs.dumps())
    me = f"planner-{os.getpid()}".encode()

    def compute(k: int) -> None:
        before = done[0]
        with _held(claims, _claim_key(prefix, k)):
            results[k] = candidate_part(inputs, ranges[k], lambda d, _t: progress(before + d, total))
        done[0] += len(ranges[k])
        progress(done[0], total)

    try:
        for k, r in enumerate(ranges):
            send(prefix, k, r.start, r.stop)
        for k in range(len(ranges)):  # every part no worker has claimed (or stored) yet
            if claims.set(_claim_key(prefix, k), me, nx=True, ex=CLAIM_S) and not blobs.exists(_part_key(prefix, k)):
                compute(k)
        while len(results) < len(ranges):
            for k in range(len(ranges)):
                if k in results:
                    continue
                if blobs.exists(_part_key(prefix, k)):
                    results[k] = pickle.loads(blobs.read_bytes(_part_key(prefix, k)))  # noqa: S301 - our own parts
                    done[0] += len(ranges[k])
                elif claims.set(_claim_key(prefix, k), me, nx=True, ex=CLAIM_S):  # its claim lapsed or was dropped
                    if blobs.exists(_part_key(prefix, k)):  # stored just before its claim went
                        continue
                    log.warning("%s: part %d was left by its worker; planning it here", prefix, k)
                    compute(k)
            progress(done[0], total)  # where a cancel is noticed
            if len(results) < len(ranges):
                time.sleep(POLL_S)
        return merge_candidates([results[k] for k in range(len(ranges))])
    finally:
        with contextlib.suppress(Exception):
            claims.delete(*[_claim_key(prefix, k) for k in range(len(ranges))])
        blobs.delete_prefix(prefix)


def run_part(blobs: BlobStore, prefix: str, part: int, start: int, stop: int, claims=None) -> str:
    """A worker's part task: claim part ``part`` (nodes ``start``..``stop``) of the planning at
    ``prefix``, compute it and store it; "taken" where someone claimed it first, "gone" where the
    planning has ended (its inputs deleted), else "stored"."""
    claims = _claims() if claims is None else claims
    key = _claim_key(prefix, part)
    if not blobs.exists(_inputs_key(prefix)):
        return "gone"
    if not claims.set(key, f"worker-{os.getpid()}".encode(), nx=True, ex=CLAIM_S):
        return "taken"
    with _held(claims, key):
        try:  # read for each part, not kept: the process goes on to bake cells within its memory limit
            inputs = PartInputs.loads(blobs.read_bytes(_inputs_key(prefix)))
        except NotFoundError:
            claims.delete(key)
            return "gone"
        found = candidate_part(inputs, range(start, stop))
        if not blobs.exists(_inputs_key(prefix)):  # ended meanwhile: store nothing
            return "gone"
        blobs.put_bytes(_part_key(prefix, part), pickle.dumps(found, protocol=pickle.HIGHEST_PROTOCOL))
    return "stored"

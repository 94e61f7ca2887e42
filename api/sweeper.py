"""The API's background sweep: running cells whose lease expired (their worker died, whichever host it ran
on: :func:`farfield.service.jobs.cells.release_expired_leases`) are queued again and sent at once;
cells queued too long without starting, or left unsent by a send that failed past its retries
(:func:`farfield.service.jobs.cells.resend_at_next_sweep`), are sent to the queue again, and so are placement jobs whose
planning message or planning worker is lost (:func:`farfield.service.placement.lease.lost_planning_jobs`)
and jobs whose admission is (:func:`farfield.service.jobs.admitting.lost_admissions`).

Every API process sweeps; each change is a conditional update, so two sweeping at once send a cell once."""

from __future__ import annotations

import logging
import threading

from farfield.service.jobs.admitting import lost_admissions, resend_admission_at_next_sweep
from farfield.service.jobs.cells import lost_queued_cells, release_expired_leases
from farfield.service.placement.lease import lost_planning_jobs, resend_planning_at_next_sweep

log = logging.getLogger("farfield.sweeper")


class LostCellSweeper:
    """A daemon thread that every ``every_s`` (``FARFIELD_SWEEP_S``) releases the cells whose lease
    expired and sends again the cells :func:`lost_queued_cells` finds (those included)."""

    def __init__(self, services, every_s: float | None = None) -> None:
        self.services = services
        after = services.settings.requeue_after
        # Often enough that a dead worker's cells (service.jobs.cells.release_lost_cells) go out again within seconds.
        self.every_s = every_s or min(float(services.settings.sweep_s), max(1.0, after / 4))
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="farfield-sweeper", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=10)

    def _run(self) -> None:
        while not self._stop.wait(self.every_s):
            try:
                settings = self.services.settings
                expired = release_expired_leases(
                    self.services.db, self.services.blobs, settings.max_attempts, settings.lease_s
                )
                if expired:
                    log.warning(
                        "%d running cells whose lease expired released: %s", len(expired), sorted(set(expired.values()))
                    )
                lost = lost_queued_cells(self.services.db, self.services.settings.requeue_after)
                if lost:
                    log.warning(
                        "sending %d queued cells again (queued over %d s without starting)",
                        len(lost),
                        self.services.settings.requeue_after,
                    )
                    if not self.services.enqueue(lost):
                        continue  # Redis is away past the sends' retries (the cells marked): the next sweep
                self._send_lost_jobs()
            except Exception:  # noqa: BLE001 - the next sweep tries again (e.g. the database is restarting)
                log.exception("sweep failed")

    def _send_lost_jobs(self) -> None:
        """Placement jobs whose planning or check, and jobs whose admission, was lost, sent again; once
        a send fails past its retries (Redis away: that job is left to the next sweep), the rest found
        are left to it too without a send each (a minute of retries apiece)."""
        services, after = self.services, self.services.settings.requeue_after
        sent = True
        for job_id, phase in lost_planning_jobs(services.db, after):
            if sent:
                log.warning("job %s: its %s was lost (message or worker); sending it again", job_id, phase)
                sent = services.send_planning(job_id, phase)
            else:
                resend_planning_at_next_sweep(services.db, job_id)
        for job_id in lost_admissions(services.db, after):
            if sent:
                log.warning("job %s: its admission was lost (message or worker); sending it again", job_id)
                sent = services.send_admission(job_id)
            else:
                resend_admission_at_next_sweep(services.db, job_id)

"""A placement job from a request: its algorithm's admission (the stored params, or a 422 naming the problem) and its row."""

from __future__ import annotations

import uuid

from farfield.core.placement.hierarchy import PlacementError
from farfield.service.db import Database, JobRow, SceneRow, now
from farfield.service.placement import ALGORITHMS, get_algorithm
from farfield.service.placement.base import PLACEMENT_JOB


def _not_given(spec, algorithm) -> None:
    """Refuse the knobs of the other algorithms (given and not null)."""
    knobs = [name for other in ALGORITHMS.values() if other is not algorithm for name in other.fields]
    given = [k for k in knobs if k in spec.model_fields_set and getattr(spec, k) is not None]
    if given:
        raise PlacementError(
            f"{', '.join(given)}: {'not a knob' if len(given) == 1 else 'not knobs'} of the {algorithm.name} placement (algorithm {spec.algorithm!r})"
        )


def placement_params(
    technique_name: str | None, given_options: dict, resolution, fov_deg, spec, model_triangles: int | None = None
) -> dict:
    """Validate a placement request (``spec``: a :class:`~farfield.service.placement.schema.PlacementSpec`);
    the job's stored params (every option and knob as validated, the cost model as a document), or a
    422 error naming the problem.  ``technique_name`` None: the algorithm's default (layered; ldi for
    the primitive-budget placement)."""
    algorithm = get_algorithm(spec.algorithm)
    _not_given(spec, algorithm)
    return algorithm.params(technique_name, given_options, resolution, fov_deg, spec, model_triangles)


def new_placement_job(tenant_id: str, scene: SceneRow, params: dict, requeue_after: float) -> JobRow:
    """The row of a new placement job (queued; its plan task is sent by the caller)."""
    return JobRow(
        id=uuid.uuid4().hex, tenant_id=tenant_id, scene_id=scene.id, job_type=PLACEMENT_JOB, params=params, evaluate=False, state="queued",
        created_at=now(), planning={"phase": "plan", "step": "queued", "done": 0, "total": 0, "round": 0, "rounds": []},
        lease_until=now() + requeue_after, plan_attempts=0,
    )  # fmt: skip


def create_placement_job(
    db: Database, tenant_id: str, scene: SceneRow, spec, requeue_after: float = 3600.0, reserve=None
) -> JobRow:
    """Validate a placement request (``spec``: a :class:`~farfield.service.jobs.schema.JobSpec` with
    ``placement``; :func:`placement_params`: 422 naming the problem) and store the job, queued for
    planning, without cells (the planner makes them).  Its cells are not known yet, so the texel
    admission of a grid job does not apply; ``reserve(session)``, called in the transaction that
    stores it, refuses it past the tenant's quotas
    (:func:`farfield.service.jobs.admission.reserve_tenant_work`)."""
    technique = spec.technique or spec.__dict__.get("job_type")  # None: the algorithm's default
    params = placement_params(technique, spec.options, spec.resolution, spec.fov_deg, spec.placement, scene.triangles)
    job = new_placement_job(tenant_id, scene, params, requeue_after)
    with db.session() as s:
        if reserve is not None:
            reserve(s)
        s.add(job)
    return job

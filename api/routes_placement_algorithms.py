"""``/v1/placement-algorithms``: the registered placement algorithms (what a placement job may ask for)."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from farfield.api.deps import tenant
from farfield.service.placement import ALGORITHMS, DEFAULT_ALGORITHM

router = APIRouter(prefix="/v1/placement-algorithms", tags=["placement"])


@router.get(
    "",
    summary="Every placement algorithm: name, help, the technique it bakes (null: any part technique), its index kind "
    "and what the dashboard shows of it; default: the one a request that names none gets",
)
def list_placement_algorithms(tenant_id: str = Depends(tenant)) -> dict:
    return {"default": DEFAULT_ALGORITHM, "algorithms": [a.describe() for a in ALGORITHMS.values()]}

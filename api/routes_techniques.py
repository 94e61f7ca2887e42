"""``/v1/techniques``: the registered impostor techniques with their options (what a job may ask for)."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from farfield.api.deps import tenant
from farfield.core.techniques import TECHNIQUES

router = APIRouter(prefix="/v1/techniques", tags=["techniques"])


@router.get(
    "", summary="Every technique: name, scope, help, image defaults and options (types, defaults, bounds, help)"
)
def list_techniques(tenant_id: str = Depends(tenant)) -> dict:
    return {"techniques": [t.describe() for t in TECHNIQUES.values()]}

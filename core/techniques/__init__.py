"""The technique registry: every impostor technique farfield bakes, by name.

Adding a technique means adding its module (a :class:`~farfield.core.techniques.base.Technique` named
``TECHNIQUE``) and one line here; the job API, the CLI (``farfield bake --technique``,
``farfield techniques``), ``GET /v1/techniques`` and the dashboard's job form read this table.
"""

from __future__ import annotations

from farfield.core.errors import LayerPlanError
from farfield.core.techniques import envmap, layered, ldi, points, tdm
from farfield.core.techniques.base import Technique

TECHNIQUES: dict[str, Technique] = {t.name: t for t in (layered.TECHNIQUE, envmap.TECHNIQUE, tdm.TECHNIQUE, points.TECHNIQUE, ldi.TECHNIQUE)}
DEFAULT_TECHNIQUE = "layered"  # what a job or a bake that names none gets


def get_technique(name: str) -> Technique:
    """The registered technique ``name``, or LayerPlanError listing the known ones.

    >>> get_technique("tdm").scope
    'part'
    >>> get_technique("nope")
    Traceback (most recent call last):
    ...
    farfield.core.errors.LayerPlanError: unknown technique 'nope'; one of ['layered', 'envmap', 'tdm', 'points', 'ldi']
    """
    try:
        return TECHNIQUES[name]
    except (KeyError, TypeError):
        raise LayerPlanError(f"unknown technique {name!r}; one of {list(TECHNIQUES)}") from None

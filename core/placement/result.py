"""A placement as plain data: what to bake, and what to draw in every conservative problem view.

``Placement.to_dict()`` is the JSON document ``farfield place --out`` writes (format
``farfield-placement``, version 1); equal inputs give equal documents (timings are kept apart, in
``Placement.seconds``).  Units: times in the cost model's unit (``ms`` or ``triangles``), memory
in bytes, lengths in scene units.

* ``impostors``: one per chosen candidate still drawn somewhere: the hierarchy node, the elements
  it replaces (object names, ``name#k`` for a cluster of a split object, see
  ``elements.split``), its view cell, technique and options, estimated layers, texels per layer,
  quads, memory, and the number of CPVs it is drawn in;
* ``cpvs``: per CPV its 3D region, its view-direction interval, its estimated time before and
  after, the impostors drawn in it (ids into ``impostors``), and ``status``: ``solved``,
  ``unsolved`` (no candidate set reaches ``t_max``) or ``unsolvable`` (what no impostor may
  replace, the elements meeting the region, exceeds ``t_max`` alone);
* ``unsolvable``: per region with unsolvable CPVs, the worst such time and the elements to blame;
* ``visibility`` (only when planned with visibility): the potentially visible set of every smallest
  region of the view space, compressed bitsets (:mod:`farfield.core.visibility.region_sets`), what a
  runtime draws as geometry there.

An impostor's ``id`` is stable across check-and-repair rounds (:mod:`farfield.core.placement.repair`): one
that no CPV draws any more after a round keeps its id with ``"cpvs": 0``, and new ones take the
next ids.  Once baked, an impostor carries its real figures in ``baked`` (``quads``,
``texture_bytes``), and the CPV times use them.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

FORMAT = "farfield-placement"
VERSION = 1


@dataclass(frozen=True)
class Placement:
    """The result of :func:`farfield.core.placement.planner.place` (see the module docstring)."""

    parameters: dict
    elements: dict
    impostors: list[dict]
    cpvs: list[dict]
    unsolvable: list[dict]
    summary: dict
    seconds: dict = field(default_factory=dict, compare=False)
    visibility: dict | None = (
        None  # the PVS per smallest region (farfield.core.visibility.region_sets), with visibility only
    )
    state: Any = field(
        default=None, compare=False, repr=False
    )  # farfield.core.placement.repair.PlannerState, when kept

    def to_dict(self) -> dict:
        return {
            "format": FORMAT,
            "version": VERSION,
            "parameters": self.parameters,
            "summary": self.summary,
            "elements": self.elements,
            "impostors": self.impostors,
            "cpvs": self.cpvs,
            "unsolvable": self.unsolvable,
        } | ({"visibility": self.visibility} if self.visibility is not None else {})

    @property
    def memory_bytes(self) -> float:
        return float(self.summary["memory_bytes"])

    def message(self) -> str | None:
        """One line naming the views no placement can serve, or None when every CPV is solved."""
        s = self.summary
        if not (s["cpvs_unsolvable"] or s["cpvs_unsolved"]):
            return None
        parts = []
        if s["cpvs_unsolvable"]:
            worst = max(self.unsolvable, key=lambda r: r["fixed_time"])
            names = ", ".join(worst["elements"][:5]) + (" ..." if len(worst["elements"]) > 5 else "")
            parts.append(
                f"{s['cpvs_unsolvable']} problem views in {len(self.unsolvable)} regions are unsolvable: the geometry meeting the "
                f"region alone takes up to {worst['fixed_time']:.4g} {s['unit']} > t_max {s['t_max']:.4g} (e.g. region "
                f"{worst['region']} with {names}); a smaller --cpv-size or a larger budget may help"
            )
        if s["cpvs_unsolved"]:
            parts.append(
                f"{s['cpvs_unsolved']} problem views stay over t_max with the candidates generated (worst {s['worst_after']:.4g} {s['unit']})"
            )
        return "; ".join(parts)

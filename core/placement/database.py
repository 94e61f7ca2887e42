"""The impostor database of a placement: what to bake, what a runtime draws in every view, and the lookup.

A placement database is an impostor database (:mod:`farfield.core.impostor.database`: ``index.json`` plus
``cells/NNNNN/`` bundles, what ``GET /v1/jobs/{id}/database.zip`` serves) whose cells are the
placement's impostors (cell index = impostor id) and whose index has ``"kind": "placement"`` and a
``placement`` section::

    placement.parameters   scene, view space, t_max, cost model, technique and options, the planner's knobs
                           (``also``: the other techniques whose candidates competed, with their options)
    placement.summary      CPV counts by status, impostors, memory (estimated and baked), worst times, rounds
    placement.elements     the element split (objects over ``cluster_triangles`` triangles cut into ``name#k``)
    placement.cpvs         per conservative problem view: its 3D region [lo, hi], its view-direction
                           interval {face, level, i, j} (farfield.core.placement.view_space.VDI), the estimated time
                           before and after, the impostors drawn there (cell indices), its status
    placement.unsolvable   regions no placement can serve, with the elements to blame
    placement.rounds       the check-and-repair rounds (farfield.core.placement.repair)
    placement.visibility   only when planned with visibility: the potentially visible set of every smallest
                           region of the view space (farfield.core.visibility.region_sets: compressed bitsets);
                           a runtime draws only those elements there (a database without it: every element)

and each cell entry, beside the usual ``index``, ``viewcell``, ``state`` and ``bundle``, has its own
``technique`` (with mixed candidates, ``layered``, ``octahedral`` or ``lod`` cell by cell, and ``kind``: shaft,
box, outside-sphere or lod), ``objects`` (the elements it replaces), ``params`` (``resolution``, ``fov_deg``,
``options``: what its bake takes) and ``figures`` (estimated, and baked once it is).  A cell of simplified
geometry (technique ``lod``, :mod:`farfield.core.placement.lod`) has no bundle: its ``params.options``
name the level of detail (``level``, ``triangles``) of its objects' merged mesh, which a runtime
simplifies from the scene as the planner did (the same chain from the same triangles).

A view (a position in the view space and a direction) falls in at most a few CPVs (on shared
borders); :class:`PlacementLookup` returns the first.  A view in no CPV is *under budget*: the
whole scene drawn as geometry is within ``t_max`` by the cost model (the planner dropped it as
solved, §5.5), so nothing is replaced.  Format version 1.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

import numpy as np

from farfield.core.errors import ViewCellError
from farfield.core.impostor.database import INDEX_NAME, database_index
from farfield.core.impostor.impostor import Impostor
from farfield.core.options import IMAGE_FIELDS, public_fields, stored_values
from farfield.core.placement.hierarchy import Elements, PlacementError
from farfield.core.placement.lod import LOD_TECHNIQUE
from farfield.core.placement.result import Placement
from farfield.core.placement.view_space import FACE_NAMES, VDI
from farfield.core.scene import Scene
from farfield.core.techniques import get_technique
from farfield.core.viewcells import viewcell_from_dict
from farfield.core.visibility.region_sets import StoredSets

KIND = "placement"
VERSION = 1
UNDER_BUDGET = "under budget"


def impostor_params(parameters: dict, objects: list[str], technique: str | None = None) -> dict:
    """What one impostor's bake takes, in a job's stored form: ``resolution``, ``fov_deg``,
    ``objects`` and the technique's other ``options`` (validated, defaults filled in).  ``technique``
    (None: the placement's own) may be one of its mixed candidates' (``parameters["also"]``), whose
    options are its own with the placement's resolution and field of view."""
    name = technique or parameters["technique"]
    given = dict(parameters.get("options") or {})
    if name != parameters["technique"]:
        also = parameters.get("also") or {}
        if name not in also:
            raise PlacementError(f"the placement has no candidates of technique {name!r}")
        given = {**also[name], "resolution": given.get("resolution"), "fov_deg": given.get("fov_deg")}
    technique = get_technique(name)
    public = {f.name for f in public_fields(technique.Options)} - set(IMAGE_FIELDS)  # the document holds every field
    options = technique.options(
        {k: v for k, v in given.items() if k in public}, given.get("resolution"), given.get("fov_deg")
    )
    return {
        "resolution": options.resolution,
        "fov_deg": options.fov_deg,
        "objects": list(objects),
        "options": stored_values(options),
    }


def cell_params(parameters: dict, imp: dict) -> dict:
    """:func:`impostor_params` of impostor ``imp`` of a placement; for simplified geometry
    (technique ``lod``, :mod:`farfield.core.placement.lod`) the placement's image fields and the
    level of detail (``level``, ``triangles``) of its objects' merged mesh."""
    if imp["technique"] != LOD_TECHNIQUE:
        return impostor_params(parameters, imp["objects"], imp["technique"])
    image = impostor_params(parameters, [])
    return {"resolution": image["resolution"], "fov_deg": image["fov_deg"], "objects": list(imp["objects"]),
            "options": {"level": imp["level"], "triangles": imp["triangles"]}}  # fmt: skip


def placement_cells(placement: Placement | dict) -> list[dict]:
    """Per impostor, in id order, what a cell of the placement is: ``index`` (= id), ``technique``,
    ``objects``, ``params`` and ``viewcell``."""
    doc = placement.to_dict() if isinstance(placement, Placement) else placement
    parameters = doc["parameters"]
    return [
        {"index": imp["id"], "technique": imp["technique"], "objects": imp["objects"], "params": cell_params(parameters, imp), "viewcell": imp["cell"]}
        for imp in doc["impostors"]
    ]  # fmt: skip


def placement_index(
    placement: Placement | dict,
    cells: list[dict],
    job: str | None = None,
    scene: str | None = None,
    rounds: list | None = None,
) -> dict:
    """The index document of a placement database (see the module docstring).

    ``cells`` holds per impostor, in id order: ``index`` (the impostor's id), ``state`` and
    ``bundle`` (its folder, or None), and optionally ``stats`` (the baked bundle's).  An impostor no
    CPV draws (``"cpvs": 0``: replaced by an ancestor, or slower than its geometry once baked) is
    listed with its figures, ``"state": "unused"`` and no bundle: a database ships only what a
    runtime draws."""
    doc = placement.to_dict() if isinstance(placement, Placement) else placement
    impostors = {imp["id"]: imp for imp in doc["impostors"]}
    parameters = doc["parameters"]
    entries = []
    for cell in cells:
        imp = impostors.get(cell["index"])
        if imp is None:
            raise PlacementError(f"cell {cell['index']} is no impostor of the placement (it has {len(impostors)})")
        stats = cell.get("stats") or {}
        figures = {
            "estimated": {k: imp[k] for k in ("layers_estimated", "texels_per_layer", "quads_estimated", "memory_bytes_estimated", "time_max") if k in imp},
            "baked": {k: stats[k] for k in ("layers", "quads", "texture_bytes", "texels_covered") if k in stats} or imp.get("baked"),
        }  # fmt: skip
        unused = not imp["cpvs"]
        entries.append({
            "index": imp["id"], "grid": None, "viewcell": imp["cell"], "state": "unused" if unused else cell["state"],
            "bundle": None if unused else cell.get("bundle"),
            "technique": imp["technique"], "objects": imp["objects"], "params": cell_params(parameters, imp),
            "cpvs": imp["cpvs"], "figures": figures,
        } | ({"kind": imp["kind"]} if "kind" in imp else {}) | ({"atlas": imp["atlas"]} if "atlas" in imp else {}))  # fmt: skip
    opts = impostor_params(parameters, [])
    params = {"resolution": opts["resolution"], "fov_deg": opts["fov_deg"], "objects": None, "options": opts["options"]}
    index = database_index(parameters["technique"], params, entries, job=job, scene=scene)
    index["kind"] = KIND
    index["placement"] = {
        "version": VERSION,
        "parameters": parameters,
        "summary": doc["summary"],
        "elements": doc["elements"],
        "cpvs": doc["cpvs"],
        "unsolvable": doc["unsolvable"],
        "rounds": list(rounds or []),
    }
    if doc.get("visibility"):  # planned with visibility: the PVS a runtime draws in each smallest region
        index["placement"]["visibility"] = doc["visibility"]
    return index


class PlacementLookup:
    """What to draw for a view, from a placement database's index (see the module docstring)."""

    def __init__(self, index: dict) -> None:
        section = index.get("placement") if isinstance(index, dict) else None
        if not section:
            raise PlacementError("not a placement database: its index has no 'placement' section")
        self.section = section
        lo, hi = section["parameters"]["view_space"]
        self.lo, self.hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        cpvs = section["cpvs"]
        self.cpvs = cpvs
        self.region_lo = np.array([c["region"][0] for c in cpvs], dtype=np.float64).reshape(-1, 3)
        self.region_hi = np.array([c["region"][1] for c in cpvs], dtype=np.float64).reshape(-1, 3)
        self.vdis = [
            VDI(FACE_NAMES.index(c["vdi"]["face"]), int(c["vdi"]["level"]), int(c["vdi"]["i"]), int(c["vdi"]["j"]))
            for c in cpvs
        ]
        self.objects = {int(cell["index"]): list(cell.get("objects") or []) for cell in index.get("cells", [])}
        span = float(np.max(self.hi - self.lo)) if self.lo.size else 0.0
        self.tol = 1e-9 * max(span, float(np.max(np.abs(np.concatenate([self.lo, self.hi])))), 1.0)
        stored = section.get("visibility")
        self.sets = StoredSets(stored) if stored else None  # None: no PVS stored, every element drawn

    def visible_set(self, position) -> np.ndarray | None:
        """Sorted element indices of the stored PVS of the smallest region holding ``position``;
        None where none is stored (planned without visibility, or outside every region)."""
        return None if self.sets is None else self.sets.at(position)

    def pvs_answer(self, position) -> dict | None:
        """The lookup's ``pvs``: the region (its grid index and box), the element ids and names of
        its PVS and the element count; None where no PVS is stored for the position."""
        if self.sets is None:
            return None
        region = self.sets.region_of(position)
        if region is None:
            return None
        ids = self.sets.pvs(region)
        r_lo, r_hi = self.sets.region_box(region)
        return {
            "region": region, "box": [r_lo, r_hi], "count": int(ids.size), "of": self.sets.count, "ids": ids.tolist(),
            "elements": [self.sets.names[i] for i in ids.tolist()] if self.sets.names else None,
        }  # fmt: skip

    def cpv_of(self, position, direction) -> int:
        """The id of the first CPV holding the view, or -1 (under budget)."""
        p = np.asarray(position, dtype=np.float64).reshape(3)
        d = np.asarray(direction, dtype=np.float64).reshape(3)
        with np.errstate(invalid="ignore", divide="ignore"):
            d = d / np.max(np.abs(d))  # scaled first: the norm of (1e200, 1e200, 0) would overflow
        norm = float(np.linalg.norm(d))
        if not (np.all(np.isfinite(p)) and np.isfinite(norm) and norm > 0.0):
            raise ViewCellError(
                f"a view needs a finite position and a non-zero finite direction, got {p.tolist()} {np.asarray(direction, dtype=np.float64).reshape(3).tolist()}"
            )
        if np.any(p < self.lo - self.tol) or np.any(p > self.hi + self.tol):
            raise ViewCellError(
                f"position {p.tolist()} is outside the placement's view space {self.lo.tolist()} .. {self.hi.tolist()}"
            )
        inside = np.flatnonzero(np.all((self.region_lo - self.tol <= p) & (p <= self.region_hi + self.tol), axis=1))
        d = (d / norm).reshape(1, 3)
        for k in inside:
            if bool(self.vdis[k].contains(d)[0]):
                return int(k)
        return -1

    def find(self, position, direction) -> dict:
        """``cpv`` (id or None), ``status`` (solved, unsolved, unsolvable or ``under budget``),
        ``impostors`` (cell indices to draw), ``replaced`` (the elements they stand for: everything
        else is drawn as geometry, or with a stored PVS only what ``pvs`` holds) and
        ``time_estimated`` (the CPV's time after placement; None under budget); a database planned
        with visibility adds ``pvs`` (:meth:`pvs_answer`)."""
        k = self.cpv_of(position, direction)
        pvs = {} if self.sets is None else {"pvs": self.pvs_answer(position)}
        if k < 0:
            return {"cpv": None, "status": UNDER_BUDGET, "impostors": [], "replaced": [], "time_estimated": None} | pvs
        cpv = self.cpvs[k]
        replaced = sorted({name for i in cpv["impostors"] for name in self.objects.get(int(i), [])})
        return {
            "cpv": k,
            "status": cpv["status"],
            "impostors": list(cpv["impostors"]),
            "replaced": replaced,
            "time_estimated": cpv["time_after"],
        } | pvs

    def find_many(self, positions, directions) -> np.ndarray:
        """(n,) CPV ids (-1: under budget) of ``n`` views."""
        positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
        directions = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
        return np.array([self.cpv_of(p, d) for p, d in zip(positions, directions)], dtype=np.int64)


def impostor_scene(scene: Scene, cluster_triangles: int, objects: list[str]) -> tuple[Scene, list[str] | None]:
    """(scene, objects) to bake an impostor of the elements ``objects`` from: the scene and the
    object names when they are whole objects, else the scene of just those elements (clusters
    ``name#k`` of split objects cut as the planner cut them, :class:`~farfield.core.placement.hierarchy.Elements`)."""
    names = set(scene.names)
    if all(name in names for name in objects):
        return scene, list(objects)
    elements = Elements.of(scene, cluster_triangles)
    by_name = {name: i for i, name in enumerate(elements.names)}
    missing = [name for name in objects if name not in by_name]
    if missing:
        raise PlacementError(
            f"the scene has no elements {missing[:10]} (with objects split at {cluster_triangles} triangles): is it the placement's scene?"
        )
    return elements.scene_of(scene, [by_name[name] for name in objects]), None


def bake_impostor(scene: Scene, entry: dict, cluster_triangles: int, progress: Callable | None = None) -> Impostor:
    """Bake one impostor of a placement: ``entry`` is a cell of :func:`placement_cells` or of a
    placement database's index (``technique``, ``objects``, ``params``, ``viewcell``)."""
    technique = get_technique(entry["technique"])
    options = technique.options_of(entry["params"])
    part, objects = impostor_scene(scene, cluster_triangles, entry["objects"])
    return technique.bake(part, viewcell_from_dict(entry["viewcell"]), options, objects, progress)


def bake_placement(
    scene: Scene, placement: Placement, progress: Callable[[int, int], None] | None = None
) -> dict[int, Impostor]:
    """Every impostor of ``placement`` baked in this process (tests, benchmarks, local use)."""
    cells = [c for c in placement_cells(placement) if c["technique"] != LOD_TECHNIQUE]  # a runtime simplifies those
    cluster = int(placement.elements["cluster_triangles"])
    out = {}
    for n, cell in enumerate(cells):
        out[cell["index"]] = bake_impostor(scene, cell, cluster)
        if progress is not None:
            progress(n + 1, len(cells))
    return out


def write_placement_database(
    directory: str | Path, placement: Placement, impostors: dict[int, Impostor], rounds: list | None = None
) -> Path:
    """Write a placement database folder (``index.json`` and ``cells/NNNNN/`` bundles) from
    impostors baked in this process; impostors missing from ``impostors`` are listed without a bundle."""
    from farfield.core.impostor.bundle import write_bundle

    root = Path(directory)
    root.mkdir(parents=True, exist_ok=True)
    cells = []
    for imp in placement.impostors:
        i = imp["id"]
        if imp["technique"] == LOD_TECHNIQUE:  # simplified geometry: built from the scene by the runtime
            cells.append({"index": i, "state": "done" if imp["cpvs"] else "unused", "bundle": None})
        elif i in impostors and imp["cpvs"]:
            write_bundle(impostors[i], root / "cells" / f"{i:05d}")
            cells.append({"index": i, "state": "done", "bundle": f"cells/{i:05d}/", "stats": impostors[i].stats})
        else:
            cells.append({"index": i, "state": "missing" if imp["cpvs"] else "unused", "bundle": None})
    index = placement_index(placement, cells, rounds=rounds)
    (root / INDEX_NAME).write_text(json.dumps(index, sort_keys=True, indent=1))
    return root

"""The frame-time placement (seed 000): impostors of a part technique wherever a view is too slow by a cost model.

- **plan**: the planner (:func:`farfield.core.placement.planner.place`, ``keep_state=True``) on the
  stored scene; its state is kept as a blob (``jobs/<id>/planner-<round>.pickle``) and every
  impostor becomes one cell (cell index = impostor id) that carries its own technique, objects,
  options and view cell (``cells.params``: :func:`cell_params`).
- **bake**: :func:`farfield.core.placement.database.bake_impostor` with the cell's own parameters,
  keyed by them (equal impostors of another job are found, not baked again).
- **check**, when the last cell of a round ends done: the planner state is loaded and repaired with
  the baked cells' real figures (``PlannerState.repair``); impostors it adds become cells of the next
  round, else (or after ``MAX_REPAIR_ROUNDS``) the database index is written
  (:func:`farfield.core.placement.database.placement_index`, ``kind`` "placement") and the job ends done.
"""

from __future__ import annotations

import math
from typing import Literal

from pydantic import Field, StrictBool, StrictFloat, StrictInt

from farfield.core.options import stored_values
from farfield.core.placement.cost_model import LLVMPIPE_MODEL, CostModel, primitive_model
from farfield.core.placement.hierarchy import Elements, PlacementError
from farfield.core.placement.lod import LOD_TECHNIQUE
from farfield.core.placement.planner import DEFAULT_MAX_IMPOSTOR_BYTES, check_colour_only, check_placeable
from farfield.core.placement.view_space import DEFAULT_DEPTH_COMPLEXITY, MAX_REGIONS, MIN_VDI_DEG
from farfield.core.techniques import DEFAULT_TECHNIQUE, TECHNIQUES, get_technique
from farfield.service.blobs import BlobStore
from farfield.service.db import CellRow, Database, JobRow, job_cells
from farfield.service.placement.base import Algorithm, Round, finite, put_index, state_key, view_space
from farfield.service.placement.candidate_fanout import for_job
from farfield.service.scenes import get_scene_row, load_stored_scene

NAME = "frame-time"
INDEX_KIND = "placement"  # the "kind" of its database index
COST_MODELS = {"llvmpipe": LLVMPIPE_MODEL}  # cost models known by name
CELL_KINDS = ("shafts", "boxes", "both", "leaf-boxes")
Number = StrictFloat | StrictInt


def cost_model_of(budget) -> tuple[CostModel, float, dict]:
    """The budget's cost model, t_max and the stored budget record."""
    if (budget.frame_ms is None) == (budget.primitives is None):
        which = "neither was given" if budget.frame_ms is None else "not both"
        raise PlacementError(
            f"give a budget: 'frame_ms' (with 'cost_model', default 'llvmpipe') or 'primitives'; {which}"
        )
    if budget.primitives is not None:
        if budget.cost_model is not None:
            raise PlacementError("'primitives' counts triangles; 'cost_model' applies to 'frame_ms' only")
        t_max = finite(budget.primitives, "budget.primitives")
        model, record = primitive_model(), {"primitives": t_max}
    else:
        t_max = finite(budget.frame_ms, "budget.frame_ms")
        given = "llvmpipe" if budget.cost_model is None else budget.cost_model
        if isinstance(given, str):
            if given not in COST_MODELS:
                raise PlacementError(
                    f"unknown cost model {given!r}; give one of {sorted(COST_MODELS)} or a cost model document (farfield calibrate --out)"
                )
            model, name = COST_MODELS[given], given
        else:
            model, name = CostModel.from_dict(given), "given"  # CostModelError: bad input, names the problem
        record = {"frame_ms": t_max, "cost_model": name}
    if not t_max > 0:
        field = "budget.primitives" if budget.primitives is not None else "budget.frame_ms"
        raise PlacementError(f"the budget t_max must be > 0 ({field}), got {t_max!r}")
    return model, t_max, {**record, "t_max": t_max, "unit": model.unit}


def also_options(technique: str, also: dict | None, resolution: int, fov_deg: float) -> dict:
    """A request's ``also`` (technique name -> options) as stored: every technique's options
    validated (defaults filled in; the job's ``resolution`` and ``fov_deg``), or a 422 naming the problem."""
    from farfield.core.placement.planner import PlacementSettings, candidate_techniques

    if not also:
        return {}
    also = {k: v for k, v in also.items() if k != LOD_TECHNIQUE}  # simplified geometry: lod_of
    unknown = sorted(set(also) - set(TECHNIQUES))
    if unknown:
        raise PlacementError(
            f"also: unknown techniques {unknown}; known: {sorted(TECHNIQUES)} and {LOD_TECHNIQUE!r} (simplified geometry)"
        )
    for name, values in also.items():
        image = sorted(set(values or {}) & {"resolution", "fov_deg"})
        if image:
            raise PlacementError(f"also.{name}: {image} are the job's own fields, not technique options")
    settings = PlacementSettings(
        1.0, LLVMPIPE_MODEL, technique, {"resolution": resolution, "fov_deg": fov_deg}, also=also
    )
    return {t.name: stored_values(o) for t, o in candidate_techniques(settings)[1:]}


def lod_of(also: dict | None) -> bool:
    """Whether a request's ``also`` asks for simplified geometry (``"lod": {}``, as ``farfield place
    --also lod``: :mod:`farfield.core.placement.lod`); it takes no options (the technique's
    ``max_error_px`` holds its error), else a 422 naming the problem."""
    if not also or LOD_TECHNIQUE not in also:
        return False
    if also[LOD_TECHNIQUE]:
        raise PlacementError(
            f"also.{LOD_TECHNIQUE}: simplified geometry takes no options (give {{}}; the technique's max_error_px "
            f"holds its error), got {sorted(also[LOD_TECHNIQUE])}"
        )
    return True


def planner_settings(params: dict):
    """The job's :class:`~farfield.core.placement.planner.PlacementSettings` and view-space corners."""
    from farfield.core.placement.planner import PlacementSettings

    knobs = params["placement"]
    settings = PlacementSettings(
        t_max=knobs["budget"]["t_max"], model=CostModel.from_dict(knobs["cost_model"]), technique=params["technique"],
        options={**params["options"], "resolution": params["resolution"], "fov_deg": params["fov_deg"]},
        cpv_size=knobs["cpv_size"], vdi_deg=knobs["vdi_deg"], cells=knobs["cells"], leaf_size=knobs["leaf_size"],
        depth_complexity=math.inf if knobs["depth_complexity"] is None else knobs["depth_complexity"],
        cluster_triangles=knobs["cluster_triangles"], max_impostor_bytes=float(knobs.get("max_impostor_mb", math.inf)) * 2**20,  # a job stored before the cap: none
        visibility=bool(knobs.get("visibility", False)),
        also=knobs.get("also"), lod=bool(knobs.get("lod", False)),
    )  # fmt: skip
    return settings, knobs["view_space"]["lo"], knobs["view_space"]["hi"]


def cell_params(entry: dict, cluster_triangles: int) -> dict:
    """A placement cell's own parameters (``cells.params``, what determines its bundle's bytes) from
    its entry of :func:`farfield.core.placement.database.placement_cells`."""
    return {
        "technique": entry["technique"],
        "objects": list(entry["objects"]),
        "params": entry["params"],
        "cluster_triangles": int(cluster_triangles),
    }


def impostor_entry(cell: CellRow) -> dict:
    """The entry :func:`farfield.core.placement.database.bake_impostor` bakes for a placement cell."""
    p = cell.params
    return {
        "index": cell.index,
        "technique": p["technique"],
        "objects": p["objects"],
        "params": p["params"],
        "viewcell": cell.viewcell,
    }


def placement_cells(placement: dict, ids) -> list[dict]:
    """The cells (index, view cell, own parameters) of a placement's impostors ``ids``."""
    from farfield.core.placement.database import placement_cells as cells_of

    cluster = placement["elements"]["cluster_triangles"]
    return [
        {"index": int(e["index"]), "viewcell": e["viewcell"], "params": cell_params(e, cluster)}
        for e in cells_of(placement)
        if e["index"] in ids and e["technique"] != LOD_TECHNIQUE  # simplified geometry is not baked
    ]


def lod_entries(placement: dict) -> list[dict]:
    """The index entries (:func:`farfield.core.placement.database.placement_index`'s ``cells``) of a
    placement's simplified geometry: no cell, no bundle (a runtime simplifies it from the scene)."""
    return [
        {"index": int(imp["id"]), "state": "done", "bundle": None}
        for imp in placement["impostors"]
        if imp["technique"] == LOD_TECHNIQUE
    ]


def lod_answer(entry: dict) -> dict:
    """A lookup's ``lods`` item: which elements a simplified-geometry entry replaces, its level,
    triangles and bytes, and how a client gets the mesh (docs/formats.md, "Simplified geometry")."""
    options = entry["params"]["options"]
    return {
        "index": int(entry["index"]),
        "objects": list(entry["objects"]),
        "level": int(options["level"]),
        "triangles": int(options["triangles"]),
        "memory_bytes_estimated": (entry.get("figures") or {}).get("estimated", {}).get("memory_bytes_estimated"),
        "mesh": LOD_MESH,
    }


# How a client gets a level of detail's mesh: the service stores none (docs/formats.md).
LOD_MESH = (
    "not served: rebuilt from the job's scene, deterministically, as the planner built it: "
    "farfield.core.placement.lod.level_for(the objects' elements' scene, level, keeps_border(elements, ids))"
)


def _cell_entries(db: Database, job_id: str) -> list[dict]:
    return [
        {
            "index": c.index,
            "state": c.state,
            "bundle": f"cells/{c.index:05d}/" if c.result_key else None,
            "stats": c.stats,
        }
        for c in job_cells(db, job_id)
    ]


def by_technique(
    parameters: dict, cells: list[dict], estimated: list[dict], baked: list[dict], own: list[bool]
) -> dict:
    """Mixed candidates: per technique offered (the job's, ``also``'s, ``lod``), the impostors a CPV
    draws and their memory, estimated and baked (simplified geometry's bytes are its mesh's, exact:
    :attr:`farfield.core.placement.lod.LodLevel.memory_bytes`, counted as baked)."""
    names = [
        parameters["technique"],
        *(parameters.get("also") or {}),
        *([LOD_TECHNIQUE] if parameters.get("lod") else []),
    ]
    out = {name: {"impostors": 0, "memory_bytes_estimated": 0.0, "memory_bytes_baked": 0} for name in names}
    for c, e, b, o in zip(cells, estimated, baked, own):
        if not c.get("cpvs"):
            continue
        row = out.setdefault(c["technique"], {"impostors": 0, "memory_bytes_estimated": 0.0, "memory_bytes_baked": 0})
        row["impostors"] += 1
        if o:
            row["memory_bytes_estimated"] += float(e.get("memory_bytes_estimated", 0.0))
            lod = c["technique"] == LOD_TECHNIQUE
            row["memory_bytes_baked"] += (
                int(e.get("memory_bytes_estimated", 0)) if lod else int(b.get("texture_bytes", 0))
            )
    return out


class FrameTime(Algorithm):
    name = NAME
    help = "seed 000: impostors of a part technique wherever a view is too slow by the cost model"
    index_kind = INDEX_KIND
    noun = "impostors"
    choice = "(seed 000): impostors of the technique where a view is too slow"
    summary = "impostors of {technique} where the frame budget needs them"
    offline = "cost-model"
    # The request's fields of this placement, in the request schema's order (farfield place --help).
    fields = {
        "cpv_size": (Number | None, Field(None, description="smallest 3D region of a problem view (default: the view space's longest side / 8)")),
        "vdi_deg": (Number, Field(11.25, description=f"smallest view-direction interval, degrees, in [{MIN_VDI_DEG:g}, 90]")),
        "depth_complexity": (Number | None, Field(DEFAULT_DEPTH_COMPLEXITY, description="a view's estimated covered pixels are at most this many frames (>= 1; null: no cap)")),
        "cells": (Literal[CELL_KINDS], Field("both", description="view cells of the candidates")),
        "leaf_size": (StrictInt, Field(4, description="elements per leaf of the object hierarchy (>= 1)")),
        "max_impostor_mb": (
            Number, Field(DEFAULT_MAX_IMPOSTOR_BYTES / 2**20, description="largest impostor a placement considers, MiB by the cost model's memory estimate (> 0)")
        ),
        "visibility": (
            StrictBool, Field(False, description="problem views count only the potentially visible set of their region (sampled from points with id cube maps; not conservative: docs/placement/visibility.md)")
        ),
        "cluster_triangles": (
            StrictInt | None, Field(None, description="objects over this many triangles are split into elements of at most as many "
                                    "(default: max(64, the scene's triangles / 256)); a level of detail (also: {\"lod\": {}}) needs an element of 256 or more")
        ),
        "also": (
            dict[str, dict] | None,
            Field(None, description="other techniques whose candidates compete with the job's technique's in the same greedy, by memory "
                  "per millisecond saved: technique name -> its options (the job's resolution and fov_deg apply), e.g. "
                  "{\"octahedral\": {\"grid\": 9, \"frame_resolution\": 16}}: an octahedral impostor per element wherever its "
                  "problem views lie beyond its accuracy distance; {\"lod\": {}}: simplified geometry, QEM levels of detail of "
                  "each element within the technique's max_error_px (docs/placement/frame-time.md, mixed candidates)"),
        ),
    }  # fmt: skip

    def params(self, technique_name, given_options, resolution, fov_deg, spec, model_triangles=None) -> dict:
        """Its stored params: a part technique (default layered) with its options, the cost model as a
        document, the planner's knobs as validated."""
        technique = get_technique(technique_name or DEFAULT_TECHNIQUE)
        check_placeable(technique)
        options = technique.options(given_options, resolution, fov_deg)
        check_colour_only(options)
        also = also_options(technique.name, spec.also, options.resolution, options.fov_deg)
        lo, hi, span = view_space(spec)
        model, t_max, budget = cost_model_of(spec.budget)
        cpv_size = None if spec.cpv_size is None else finite(spec.cpv_size, "cpv_size")
        if cpv_size is not None and not cpv_size > 0:
            raise PlacementError(f"cpv_size must be > 0, got {cpv_size!r}")
        size = cpv_size if cpv_size is not None else (max(span) / 8 if max(span) > 0 else 1.0)
        cuts = [s / size for s in span]
        if not all(math.isfinite(c) for c in cuts):  # a size so small the quotient overflows
            raise PlacementError(
                f"a view space of {span} in regions of {size:.6g} has too many regions (over {MAX_REGIONS:.0e}); use a larger cpv_size"
            )
        regions = math.prod(max(1.0, math.ceil(c)) for c in cuts)
        if regions > MAX_REGIONS:
            raise PlacementError(
                f"a view space of {span} in regions of {size:.6g} has {regions:.3g} regions, over {MAX_REGIONS:.0e}; use a larger cpv_size"
            )
        vdi = finite(spec.vdi_deg, "vdi_deg")
        if not MIN_VDI_DEG <= vdi <= 90:
            raise PlacementError(f"vdi_deg must lie in [{MIN_VDI_DEG:g}, 90] degrees, got {vdi!r}")
        depth = None if spec.depth_complexity is None else float(spec.depth_complexity)
        if depth is not None and not (depth >= 1.0):
            raise PlacementError(f"depth_complexity must be >= 1 (null: no cap), got {depth!r}")
        if depth is not None and math.isinf(depth):
            depth = None  # JSON (and PostgreSQL) hold no infinity: null is no cap
        if spec.cluster_triangles is not None and spec.cluster_triangles < 1:
            raise PlacementError(f"cluster_triangles must be >= 1, got {spec.cluster_triangles!r}")
        if spec.leaf_size < 1:
            raise PlacementError(f"leaf_size must be >= 1, got {spec.leaf_size!r}")
        largest = finite(spec.max_impostor_mb, "max_impostor_mb")
        if not largest > 0:
            raise PlacementError(f"max_impostor_mb must be > 0, got {largest!r}")
        knobs = {
            "view_space": {"lo": lo, "hi": hi}, "budget": budget, "cost_model": model.to_dict(), "cpv_size": cpv_size, "vdi_deg": vdi,
            "depth_complexity": depth, "cells": spec.cells, "leaf_size": spec.leaf_size, "cluster_triangles": spec.cluster_triangles,
            "max_impostor_mb": largest,
        }  # fmt: skip
        if lod_of(spec.also):  # only when asked: simplified geometry competes (farfield.core.placement.lod)
            knobs["lod"] = True
        if spec.visibility:  # stored only when on: the params (and keys) of every other job stay as they were
            knobs["visibility"] = True
        if also:  # only when given: a job without mixed candidates stores what it always did
            knobs["also"] = also
        return {
            "technique": technique.name,
            "resolution": options.resolution,
            "fov_deg": options.fov_deg,
            "objects": None,
            "options": stored_values(options),
            "placement": knobs,
        }

    def plan(self, blobs: BlobStore, job: JobRow, scene, progress) -> tuple[str, dict, list[dict]]:
        """Seed 000's planner: (its state's key, the placement, the cells of its impostors)."""
        from farfield.core.placement.planner import place

        settings, lo, hi = planner_settings(job.params)
        placement = place(
            scene, lo, hi, settings, progress=progress, keep_state=True, candidates=for_job(blobs, job.id)
        )
        key = state_key(job.id, 0)
        blobs.put_bytes(key, placement.state.dumps())
        as_dict = placement.to_dict()
        return key, as_dict, placement_cells(as_dict, {imp["id"] for imp in as_dict["impostors"]})

    def impostors(self, doc: dict) -> int:
        return len(doc["impostors"])

    def check(self, db: Database, blobs: BlobStore, job: JobRow, round_: int, rounds: list) -> Round:
        """Repair the planner state with the baked cells' real figures: the impostors it adds are the
        next round's cells; none (or past ``MAX_REPAIR_ROUNDS``): the database is written."""
        from farfield.core.placement.repair import MAX_REPAIR_ROUNDS, PlannerState

        planning = job.planning
        state = PlannerState.loads(blobs.read_bytes(planning["state_key"]))
        baked = {c.index: c.stats for c in job_cells(db, job.id) if c.state == "done" and c.stats}
        # Past the last round the baked figures still go in (extend=False: nothing added), so the
        # database's CPV times and statuses are those of what is baked, never estimates.
        repaired = state.repair(baked, extend=round_ <= MAX_REPAIR_ROUNDS)
        rounds = [*rounds, {**repaired.to_dict(), "round": round_}]
        added = {int(i) for i in repaired.added}
        current = state.placement().to_dict()
        cells = placement_cells(current, added)  # simplified geometry added needs no bake: none of them
        if cells:
            key = state_key(job.id, round_)
            blobs.put_bytes(key, state.dumps())
            return Round(
                key,
                cells,
                self.impostors(current),
                current.get("summary"),
                round_,
                None,
                rounds,
            )
        index_key = self.write_index(db, blobs, job, current, rounds)
        return Round(
            planning["state_key"], [], self.impostors(current), current.get("summary"), round_, index_key, rounds
        )

    def too_many_cells(self, cells: int, limit: int) -> str:
        return (
            f"PlacementError: the placement needs {cells:,} impostors, over the limit of {limit:,} cells per job: "
            "use a larger budget, a smaller view space or larger --cpv-size / --vdi-deg"
        )

    def bake_cell(self, scene, cell: CellRow, progress):
        from farfield.core.placement.database import bake_impostor

        return bake_impostor(scene, impostor_entry(cell), cell.params.get("cluster_triangles"), progress)

    def write_index(self, db: Database, blobs: BlobStore, job: JobRow, doc: dict, rounds: list) -> str:
        """:func:`farfield.core.placement.database.placement_index` of the placement and its cells."""
        from farfield.core.placement.database import placement_index

        cells = sorted([*_cell_entries(db, job.id), *lod_entries(doc)], key=lambda c: c["index"])
        return put_index(blobs, job.id, placement_index(doc, cells, job=job.id, scene=job.scene_id, rounds=rounds))

    def bundled_cells(self, index: dict) -> set[int]:
        """Those its index gives a bundle (an impostor no CPV draws has none)."""
        return {int(c["index"]) for c in index.get("cells", []) if c.get("bundle")}

    def read_index(self, index: dict):
        from farfield.core.placement.database import PlacementLookup

        return PlacementLookup(index)

    def placement_document(self, job: JobRow, index: dict) -> dict:
        """The CPVs, impostors, unsolvable regions and totals (the dashboard's map)."""
        section = index["placement"]
        cells = [
            {k: c.get(k) for k in ("index", "state", "technique", "objects", "viewcell", "cpvs", "figures", "bundle")}
            | ({"atlas": c["atlas"]} if "atlas" in c else {})
            for c in index.get("cells", [])
        ]  # fmt: skip
        estimated = [(c["figures"] or {}).get("estimated") or {} for c in cells]
        baked = [(c["figures"] or {}).get("baked") or {} for c in cells]
        drawn = [c for c in cells if c.get("cpvs")]
        # An instance drawing from a prototype's atlas another impostor holds adds no memory (issue 56).
        own = [not c.get("atlas") or c["atlas"].get("owner") in (None, c["index"]) for c in cells]
        totals = {
            "impostors": len(drawn),
            "impostors_listed": len(cells),
            "impostors_baked": sum(1 for b in baked if "texture_bytes" in b),
            "memory_bytes_estimated": sum(
                float(e.get("memory_bytes_estimated", 0.0))
                for c, e, o in zip(cells, estimated, own)
                if c.get("cpvs") and o
            ),
            "memory_bytes_baked": sum(  # simplified geometry's bytes are exact (by_technique): counted here too
                int(e.get("memory_bytes_estimated", 0))
                if c.get("technique") == LOD_TECHNIQUE
                else int(b.get("texture_bytes", 0))
                for c, e, b, o in zip(cells, estimated, baked, own)
                if c.get("cpvs") and o
            ),
            "cpvs": len(section["cpvs"]),
            "cpvs_by_status": {
                s: sum(1 for c in section["cpvs"] if c["status"] == s) for s in ("solved", "unsolved", "unsolvable")
            },
            "unsolvable_regions": len(section["unsolvable"]),
            "rounds": len(section.get("rounds") or []),
        }
        if section["parameters"].get("also") or section["parameters"].get("lod"):
            totals["by_technique"] = by_technique(section["parameters"], cells, estimated, baked, own)
        return {"job": job.id, "state": job.state, **section, "cells": cells, "totals": totals}

    def lookup(self, index: dict, found, eye, direction) -> tuple[dict, list[int]]:
        """:meth:`PlacementLookup.find` of the view (``cpv``, ``status``, ``impostors``, ``replaced``,
        ``time_estimated``), and the cells of the impostors to draw."""
        answer = found.find(eye, direction)
        lods = {int(c["index"]): c for c in index.get("cells", []) if c.get("technique") == LOD_TECHNIQUE}
        if not lods:
            return answer, answer["impostors"]
        drawn = [i for i in answer["impostors"] if int(i) in lods]
        answer["lods"] = [lod_answer(lods[int(i)]) for i in drawn]  # simplified geometry: no cell, no bundle
        return answer, [i for i in answer["impostors"] if int(i) not in lods]

    def clusters(self, db: Database, blobs: BlobStore, job: JobRow, index: dict) -> dict:
        """Its clusters of split objects (:meth:`farfield.core.placement.hierarchy.Elements.clusters`)."""
        cluster = int(index["placement"]["elements"]["cluster_triangles"])
        scene = load_stored_scene(blobs, get_scene_row(db, job.tenant_id, job.scene_id))
        return {"cluster_triangles": cluster, "clusters": Elements.of(scene, cluster).clusters(scene)}


ALGORITHM = FrameTime()

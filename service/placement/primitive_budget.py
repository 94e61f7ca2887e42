"""The primitive-budget placement (seed 004): a solution grid of layered depth images (technique ``ldi``) so that no view draws more than P triangles.

It goes as a frame-time job does with one round: the plan is
:func:`farfield.core.placement.solution_grid.place_primitives` and its check of ``check_views``
random views; the grid is kept as ``jobs/<id>/planner-grid.json``; every image becomes one cell
(``cells.params``: its name "<point>-<image>" and what its LDI is made of,
:func:`farfield.core.placement.image_database.image_entries`), baked by
:func:`farfield.core.placement.image_database.bake_image` and keyed without its name, so the same
image of another job (another P that keeps it) is found, not baked.  The check has nothing to
repair (the guarantee counts triangles, which baking does not change): it writes the index
(:func:`farfield.core.placement.image_database.image_index`, ``kind`` "primitive-placement", the
bundles under ``cells/NNNNN/``) and ends the job.
"""

from __future__ import annotations

import json

from pydantic import Field, StrictFloat, StrictInt

from farfield.core.errors import InternalError, NotFoundError
from farfield.core.options import stored_values
from farfield.core.placement.hierarchy import PlacementError
from farfield.core.placement.octree_cells import DEFAULT_DEPTH
from farfield.core.placement.planner import check_colour_only
from farfield.core.techniques import get_technique
from farfield.service.blobs import BlobStore
from farfield.service.db import CellRow, Database, JobRow, SceneRow, job_cells
from farfield.service.placement.base import Algorithm, Round, finite, put_index, view_space

NAME = "primitive-budget"
INDEX_KIND = "primitive-placement"  # the "kind" of its database index
TECHNIQUE = "ldi"  # what its images are
DEFAULT_CHECK_VIEWS = 2000
MAX_CHECK_VIEWS = 1_000_000
Number = StrictFloat | StrictInt


def grid_key(job_id: str) -> str:
    """Where a primitive-budget job keeps its solution grid between planning and its database."""
    return f"jobs/{job_id}/planner-grid.json"


def budget_settings(params: dict):
    """A primitive-budget job's :class:`~farfield.core.placement.solution_grid.BudgetSettings`."""
    from farfield.core.placement.solution_grid import BudgetSettings

    knobs = params["placement"]
    return BudgetSettings(
        primitives=knobs["budget"]["primitives"], p_opt=knobs["p_opt"], fov_deg=params["fov_deg"], octree_depth=knobs["octree_depth"],
        grid_points=knobs["grid_points"], max_level=knobs["max_level"],
    )  # fmt: skip


def image_cell_params(entry: dict) -> dict:
    """A primitive-budget cell's own parameters: its image's name and what its LDI is baked from
    (:func:`farfield.core.placement.image_database.image_entries`)."""
    return {"technique": TECHNIQUE, "image": entry["name"], "params": entry["params"]}


class PrimitiveBudget(Algorithm):
    name = NAME
    help = (
        "seed 004: a solution grid of layered depth images, technique 'ldi', so that no view draws more than "
        "budget.primitives triangles"
    )
    index_kind = INDEX_KIND
    noun = "images"
    technique = TECHNIQUE
    choice = "(seed 004): layered depth images on a grid, technique ldi"
    summary = "layered depth images on a solution grid, so that no view draws more than the primitive budget (seed 004)"
    images = True
    labels = {"cpvs": "grid points", "unsolvable": "unsolved", "rounds": "check"}
    offline = "solution-grid"
    # The request's fields of this placement (seed 004 §5; farfield place --algorithm primitive-budget).
    fields = {
        "p_opt": (Number | None, Field(None, description="primitive-budget: the optimisation budget in (0, P] (default: P less 5 % of the model, at least P / 2)")),
        "octree_depth": (StrictInt | None, Field(None, description=f"primitive-budget: depth of the octree's pseudo-leaf cells (default {DEFAULT_DEPTH})")),
        "grid_points": (StrictInt | None, Field(None, description="primitive-budget: initial lattice points along the view space's longest side (>= 2, default 3)")),
        "max_level": (StrictInt | None, Field(None, description="primitive-budget: deepest subdivision of the solution grid (>= 0, default 4)")),
        "check_views": (
            StrictInt | None,
            Field(None, description=f"primitive-budget: random (eye, yaw) pairs the planner checks the guarantee on (0: none; default {DEFAULT_CHECK_VIEWS})"),
        ),
    }  # fmt: skip

    def params(self, technique_name, given_options, resolution, fov_deg, spec, model_triangles=None) -> dict:
        """Its stored params: technique ``ldi``, a budget of ``primitives``, the solution grid's knobs
        checked as ``farfield place`` checks them."""
        from farfield.core.placement.octree_cells import MAX_DEPTH

        if technique_name not in (None, TECHNIQUE):
            raise PlacementError(
                f"the primitive-budget placement replaces geometry with layered depth images: technique 'ldi' (or none), not {technique_name!r}"
            )
        if spec.budget.frame_ms is not None or spec.budget.cost_model is not None or spec.budget.primitives is None:
            raise PlacementError(
                "the primitive-budget placement bounds the triangles a view draws: give budget.primitives (and no frame_ms or cost_model)"
            )
        technique = get_technique(TECHNIQUE)
        options = technique.options(given_options, resolution, fov_deg)
        check_colour_only(options)
        lo, hi, _ = view_space(spec)
        depth = DEFAULT_DEPTH if spec.octree_depth is None else spec.octree_depth
        if not 0 <= depth <= MAX_DEPTH:
            raise PlacementError(f"octree_depth must be an integer in 0..{MAX_DEPTH}, got {depth!r}")
        views = DEFAULT_CHECK_VIEWS if spec.check_views is None else spec.check_views
        if not 0 <= views <= MAX_CHECK_VIEWS:
            raise PlacementError(f"check_views must be an integer in 0..{MAX_CHECK_VIEWS:,}, got {views!r}")
        knobs = {
            "algorithm": NAME, "view_space": {"lo": lo, "hi": hi}, "p_opt": None if spec.p_opt is None else finite(spec.p_opt, "p_opt"),
            "octree_depth": depth, "grid_points": 3 if spec.grid_points is None else spec.grid_points, "max_level": 4 if spec.max_level is None else spec.max_level,
            "check_views": views,
        }  # fmt: skip
        primitives = finite(spec.budget.primitives, "budget.primitives")
        knobs["budget"] = {"primitives": primitives, "t_max": primitives, "unit": "triangles"}
        params = {
            "technique": technique.name,
            "resolution": options.resolution,
            "fov_deg": options.fov_deg,
            "objects": None,
            "options": stored_values(options),
            "placement": knobs,
        }
        budget_settings(params).checked(
            model_triangles if model_triangles is not None else 0
        )  # P, p_opt, the FOV's star-shape bound, the grid's knobs
        return params

    def plan(self, blobs: BlobStore, job: JobRow, scene, progress) -> tuple[str, dict, list[dict]]:
        """Seed 004's solution grid, checked on ``check_views`` random views: (the grid's key, the grid
        with the check in its summary, one cell per image)."""
        from farfield.core.placement.image_database import image_entries
        from farfield.core.placement.solution_grid import check_views, place_primitives

        knobs, options = job.params["placement"], job.params["options"]
        placement = place_primitives(
            scene, knobs["view_space"]["lo"], knobs["view_space"]["hi"], budget_settings(job.params), progress=progress
        )
        grid = placement.to_dict()
        if knobs["check_views"]:
            grid["summary"]["check"] = check_views(placement, knobs["check_views"], progress=progress)
        entries = image_entries(placement, job.params["resolution"], options["images"], options["max_layers"])
        key = grid_key(job.id)
        blobs.put_bytes(key, json.dumps(grid, allow_nan=False).encode())
        return (
            key,
            grid,
            [{"index": e["index"], "viewcell": e["viewcell"], "params": image_cell_params(e)} for e in entries],
        )

    def impostors(self, doc: dict) -> int:
        return int(doc["summary"]["images"])

    def check(self, db: Database, blobs: BlobStore, job: JobRow, round_: int, rounds: list) -> Round:
        """No repair: the grid's guarantee counts triangles, which baking does not change; the database is written."""
        key = job.planning["state_key"]
        grid = json.loads(blobs.read_bytes(key))
        index_key = self.write_index(db, blobs, job, grid, [])
        return Round(key, [], self.impostors(grid), grid["summary"], round_ - 1, index_key, [])

    def too_many_cells(self, cells: int, limit: int) -> str:
        return (
            f"PlacementError: the placement needs {cells:,} images, over the limit of {limit:,} cells per job: "
            "raise the primitive budget or p_opt, or use a smaller view space"
        )

    def cell_inputs(self, cell: CellRow) -> tuple[str, dict]:
        # Keyed by what makes its bytes, not the image's name in its grid: the same image of another job is found.
        return f"placement/{cell.params['technique']}", {k: v for k, v in cell.params.items() if k != "image"}

    def bake_cell(self, scene, cell: CellRow, progress):
        from farfield.core.placement.image_database import bake_image

        try:
            return bake_image(
                scene,
                {"name": cell.params["image"], "viewcell": cell.viewcell, "params": cell.params["params"]},
                progress=progress,
            )
        except PlacementError as error:  # the planner made this cell of the same stored scene: a bug, not bad input
            raise InternalError(f"image {cell.params['image']} does not fit its scene: {error}") from error

    def write_index(self, db: Database, blobs: BlobStore, job: JobRow, doc: dict, rounds: list) -> str:
        """:func:`farfield.core.placement.image_database.image_index` of the grid, its images' bundles under ``cells/NNNNN/``."""
        from farfield.core.placement.image_database import image_index

        with db.session() as s:
            scene_hash = s.get(SceneRow, job.scene_id).content_hash
        cells = job_cells(db, job.id)
        bundles = {c.params["image"]: f"cells/{c.index:05d}/" for c in cells if c.result_key}
        baked = [
            {
                "index": c.index,
                "image": c.params["image"],
                "state": c.state,
                "bundle": bundles.get(c.params["image"]),
                "stats": c.stats,
            }
            for c in cells
        ]
        options = job.params["options"]
        index = image_index(doc, bundles, job.params["resolution"], options["images"], scene_hash, kind=INDEX_KIND, job=job.id,
                            scene=job.scene_id, cells_baked=baked)  # fmt: skip
        return put_index(blobs, job.id, index)

    def read_index(self, index: dict):
        from farfield.core.placement.image_database import placement_of_index

        return placement_of_index(index)

    def placement_document(self, job: JobRow, index: dict) -> dict:
        """Its parameters, the grid's summary and points with their images (each with its cell and bundle), and totals."""
        bundles = index["bundles"]
        baked = {b["image"]: b for b in index.get("cells_baked", [])}
        points = []
        for pi, p in enumerate(index["points"]):
            images = []
            for ii, im in enumerate(p["images"]):
                name = f"{pi}-{ii}"
                cell = baked.get(name) or {}
                images.append({"name": name, "yaw": im["yaw"], "depth": im["depth"], "drawn": im["drawn"], "octree_cells": len(im["cells"]),
                               "cell": cell.get("index"), "bundle": bundles.get(name), "texture_bytes": (cell.get("stats") or {}).get("texture_bytes")})  # fmt: skip
            points.append(
                {
                    "position": p["position"],
                    "level": p["level"],
                    "radius": p["radius"],
                    "failure": p["failure"],
                    "images": images,
                }
            )
        summary = index["summary"]
        sizes = [im["texture_bytes"] or 0 for p in points for im in p["images"]]
        totals = {
            "images": summary["images"], "images_baked": sum(1 for p in points for im in p["images"] if im["bundle"]), "memory_bytes_baked": int(sum(sizes)),
            "grid_points": summary["grid_points"], "unsolved_points": summary["unsolved_points"],
        }  # fmt: skip
        parameters = {"algorithm": NAME, "technique": TECHNIQUE, "primitives": summary["primitives"], "p_opt": summary["p_opt"],
                      "fov_deg": summary["fov_deg"], "octree_depth": summary["octree_depth"], "resolution": index["resolution"],
                      "construction_images": index["construction_images"], "view_space": index["view_space"]}  # fmt: skip
        return {
            "job": job.id,
            "state": job.state,
            "algorithm": NAME,
            "parameters": parameters,
            "summary": summary,
            "points": points,
            "totals": totals,
        }

    def lookup(self, index: dict, found, eye, direction) -> tuple[dict, list[int]]:
        """:func:`farfield.core.placement.image_database.image_lookup`, and the cell that baked the image."""
        from farfield.core.placement.image_database import image_lookup

        answer = image_lookup(index, found, eye, direction)
        cell = (
            next((b["index"] for b in index.get("cells_baked", []) if b["image"] == answer["image"]), None)
            if answer["image"]
            else None
        )
        return answer, [cell] if cell is not None else []

    def clusters(self, db: Database, blobs: BlobStore, job: JobRow, index: dict) -> dict:
        raise NotFoundError(
            f"job {job.id!r} is a primitive-budget placement: its images replace octree cells, not clusters"
        )


ALGORITHM = PrimitiveBudget()

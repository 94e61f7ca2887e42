"""The database of a primitive-budget placement (seed 004): its solution grid and one LDI bundle per image,
and the walkthrough that counts, times and compares what its run time draws.

Layout of the folder (format ``farfield.primitive_placement``, version 1)::

    placement.json              the grid (PrimitivePlacement.to_dict) and "bundles": {"<point>-<image>": "images/<point>-<image>"}
    images/<point>-<image>/     an LDI bundle (technique "ldi", core.bundle): manifest.json, payload.bin, impostor.glb

An image's bundle holds its LDI's samples (:class:`core.impostor.LdiPayload`); its view cell is the
cube around its grid point's star sphere, its reference viewpoint the grid point.  The octree cells
are recomputed from the scene when the database is opened, and their bounds and counts must match
the stored ones: a database is only valid for the scene it was made of.
"""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from farfield.core import __version__
from farfield.core.bundle import read_bundle, write_bundle
from farfield.core.impostor import Impostor
from farfield.core.ldi_pages import ldi_of, ldi_payload_and_pages
from farfield.core.placement.hierarchy import PlacementError
from farfield.core.placement.image_frames import cell_objects, image_ldi, view_camera
from farfield.core.placement.octree_cells import octree_cells
from farfield.core.placement.solution_grid import FORMAT_VERSION, GridPoint, PrimitivePlacement
from farfield.core.placement.yaw_ranges import drawn_cells
from farfield.core.render.raster import MeshRenderer
from farfield.core.render.splats import SplatRenderer
from farfield.core.scene import Scene
from farfield.core.viewcells import BoxCell

FORMAT = "farfield.primitive_placement"
INDEX = "placement.json"


def image_impostor(scene: Scene, placement: PrimitivePlacement, point: GridPoint, index: int, resolution: int, images: int = 9) -> Impostor:
    """Image ``index`` of ``point`` as an ``ldi`` impostor (module docstring)."""
    image = point.images[index]
    started = time.perf_counter()
    made = image_ldi(scene, placement, point, image, resolution, images)
    ldi = made.ldi
    payload, pages = ldi_payload_and_pages(ldi)
    cell = BoxCell(point.position - point.radius, point.position + point.radius)
    return Impostor(
        technique="ldi", viewcell=cell.to_dict(), reference_viewpoint=point.position, resolution=resolution, fov_deg=math.degrees(2 * placement.half),
        pages=pages, payload=payload, layers=[],
        stats={"samples": ldi.count, "layers": ldi.layers, "offered": made.offered, "dropped_full": made.dropped_full, "construction_images": images,
               "splat_bytes": 20 * ldi.count, "texture_bytes": int(sum(p.nbytes for p in pages)), "seconds": {"total": time.perf_counter() - started}},
        parameters={"resolution": resolution, "fov_deg": math.degrees(2 * placement.half), "images": images, "yaw": image["yaw"], "depth": image["depth"],
                    "quad": np.asarray(image["quad"]).tolist(), "cells": np.asarray(image["cells"]).tolist(), "scene_hash": scene.content_hash},
        code_version=__version__,
    )  # fmt: skip


def write_image_database(root: Path, scene: Scene, placement: PrimitivePlacement, resolution: int, images: int = 9,
                         progress: Callable[[str, int, int], None] | None = None) -> dict:  # fmt: skip
    """Bake every image's LDI and write the database folder ``root``; returns its index."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    bundles = {}
    total = placement.images
    done = 0
    for pi, point in enumerate(placement.points):
        for ii in range(len(point.images)):
            name = f"{pi}-{ii}"
            write_bundle(image_impostor(scene, placement, point, ii, resolution, images), root / "images" / name)
            bundles[name] = f"images/{name}"
            done += 1
            if progress is not None:
                progress("images", done, total)
    index = placement.to_dict()
    index.update({"bundles": bundles, "resolution": resolution, "construction_images": images, "scene_hash": scene.content_hash})
    (root / INDEX).write_text(json.dumps(index) + "\n")
    return index


def is_image_database(root: Path) -> bool:
    index = Path(root) / INDEX
    if not index.is_file():
        return False
    try:
        return json.loads(index.read_text()).get("format") == FORMAT
    except (OSError, ValueError):
        return False


class ImageDatabase:
    """An opened primitive-budget database: the placement (cells recomputed from ``scene`` and checked)
    and its LDIs, read when first used."""

    def __init__(self, root: Path, scene: Scene) -> None:
        self.root = Path(root)
        try:
            index = json.loads((self.root / INDEX).read_text())
        except (OSError, ValueError) as error:
            raise PlacementError(f"{self.root} is not a primitive-budget placement database: {error}") from None
        if index.get("format") != FORMAT or index.get("version") != FORMAT_VERSION:
            raise PlacementError(f"{self.root}: format {index.get('format')!r} version {index.get('version')!r}, expected {FORMAT!r} {FORMAT_VERSION}")
        self.index = index
        stored = index["cells"]
        cells = octree_cells(scene, int(stored["depth"]))
        if (cells.count != len(stored["triangles"]) or not np.array_equal(cells.triangles, stored["triangles"])
                or not np.allclose(cells.lo, stored["lo"]) or not np.allclose(cells.hi, stored["hi"])):  # fmt: skip
            raise PlacementError(f"{self.root} was made for another scene (its octree cells differ from this scene's)")
        points = []
        for p in index["points"]:
            point = GridPoint(np.asarray(p["position"], dtype=np.float64), int(p["level"]), float(p["radius"]), np.asarray(p["breaks"], dtype=np.float64),
                              np.asarray(p["image"], dtype=np.int64), failure=p["failure"])  # fmt: skip
            point.images = [{**im, "quad": np.asarray(im["quad"]), "cells": np.asarray(im["cells"], dtype=np.int64)} for im in p["images"]]
            points.append(point)
        s = index["summary"]
        lo, hi = (np.asarray(v, dtype=np.float64) for v in index["view_space"])
        self.placement = PrimitivePlacement(cells, points, lo, hi, float(s["primitives"]), float(s["p_opt"]), math.radians(s["fov_deg"]) / 2,
                                            float(s["spacing"]), len(s["points_per_level"]) - 1, index.get("seconds", {}))  # fmt: skip
        self.scene = scene
        self._ldis: dict[tuple[int, int], Impostor] = {}

    def impostor(self, point: int, image: int) -> Impostor:
        key = (point, image)
        if key not in self._ldis:
            self._ldis[key] = read_bundle(self.root / self.index["bundles"][f"{point}-{image}"])
        return self._ldis[key]


def _median_ms(renderer, camera, repeats: int) -> float:
    renderer.render(camera)  # the first draw uploads
    return 1000.0 * float(np.median([renderer.frame_seconds(camera) for _ in range(repeats)]))


def image_walkthrough(db: ImageDatabase, eyes: np.ndarray, yaws: np.ndarray, repeats: int = 3, compare: bool = True,
                      progress: Callable[[int, int], None] | None = None) -> dict:  # fmt: skip
    """Per view (pitch 0): the grid point and image the run time picks (Fig. 12), the primitives it draws,
    its frame time (frustum-culled geometry + splatted LDI) against plain frustum-culled geometry, and
    (``compare``) hole pixels against the full scene; and a summary against ``P``."""
    if len(eyes) < 1:
        raise PlacementError("a walkthrough needs at least one view")
    placement, scene = db.placement, db.scene
    resolution = int(db.index["resolution"])
    frames = []
    for n, (eye, yaw) in enumerate(zip(eyes, yaws)):
        view = placement.view(eye, float(yaw))
        size = float(placement.cells.cube_size)
        camera = view_camera(eye, float(yaw), 2 * placement.half, resolution, 1e-4 * size, 4.0 * size + float(np.linalg.norm(eye - placement.cells.cube_lo)))
        seen = drawn_cells(placement.cells.lo, placement.cells.hi, eye, float(yaw), placement.half)
        geometry = cell_objects(scene, placement.cells, view["cells"]) if view["cells"].any() else []
        ldis = [ldi_of(db.impostor(view["point"], view["image"]))] if view["image"] >= 0 else []
        row = {"frame": n, "position": np.asarray(eye).tolist(), "yaw": float(yaw), "point": view["point"], "image": view["image"],
               "primitives": view["primitives"], "plain_primitives": int(placement.cells.triangles[seen].sum()),
               "within_p": view["primitives"] <= placement.primitives, "eye_past_quad": view["past_quad"]}  # fmt: skip
        with SplatRenderer(geometry, ldis) as runtime:
            row["drawn_triangles"] = runtime.triangle_count  # what the GL was given, against the count above
            row["runtime_ms"] = _median_ms(runtime, camera, repeats)
            frame = runtime.render(camera) if compare else None
        with MeshRenderer(cell_objects(scene, placement.cells, seen) if seen.any() else []) as plain:
            row["plain_ms"] = _median_ms(plain, camera, repeats)
            if compare:
                full = plain.render(camera)
                row["hole_pixels"] = int(((full[..., 3] > 0) & (frame[..., 3] == 0)).sum())
                both = (full[..., 3] > 0) & (frame[..., 3] > 0)
                row["colour_error_mean"] = float(np.abs(full[..., :3].astype(int) - frame[..., :3].astype(int)).max(axis=-1)[both].mean()) if both.any() else 0.0
        frames.append(row)
        if progress is not None:
            progress(n + 1, len(eyes))
    prims = np.array([f["primitives"] for f in frames], dtype=np.float64)
    ms = np.array([f["runtime_ms"] for f in frames])
    plain = np.array([f["plain_ms"] for f in frames])
    summary = {
        "views": len(frames), "primitives_budget": placement.primitives, "p_opt": placement.p_opt,
        "share_within_p": float(np.mean(prims <= placement.primitives)), "primitives_p99": float(np.percentile(prims, 99)),
        "primitives_max": float(prims.max()), "plain_primitives_max": float(max(f["plain_primitives"] for f in frames)),
        "runtime_ms_p50": float(np.median(ms)), "runtime_ms_p99": float(np.percentile(ms, 99)),
        "plain_ms_p50": float(np.median(plain)), "plain_ms_p99": float(np.percentile(plain, 99)),
        "views_with_image": int(sum(f["image"] >= 0 for f in frames)), "eye_past_quad": int(sum(f["eye_past_quad"] for f in frames)),
    }  # fmt: skip
    if compare:
        summary["hole_pixels"] = int(sum(f["hole_pixels"] for f in frames))
        summary["views_with_holes"] = int(sum(f["hole_pixels"] > 0 for f in frames))
        summary["colour_error_mean"] = float(np.mean([f["colour_error_mean"] for f in frames]))
    return {"frames": frames, "summary": summary}

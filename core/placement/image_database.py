"""The database of a primitive-budget placement (seed 004): its solution grid and one LDI bundle per image,
and the walkthrough that counts, times and compares what its run time draws.

Layout of the folder (format ``farfield.primitive_placement``, version 1)::

    placement.json              the grid (PrimitivePlacement.to_dict) and "bundles": {"<point>-<image>": "images/<point>-<image>"}
    images/<point>-<image>/     an LDI bundle (technique "ldi", farfield.core.impostor.bundle): manifest.json, payload.bin, impostor.glb

A placement job's database (``GET /v1/jobs/{id}/database.zip``, unpacked) holds the same index as
``index.json``, with each image baked as one of the job's cells: its "bundles" name
``cells/<NNNNN>/`` and its "cells_baked" list each cell's index, image name, state and stats.

An image's bundle holds its LDI's samples (:class:`farfield.core.impostor.impostor.LdiPayload`); its view cell is the
cube around its grid point's star sphere, its reference viewpoint the grid point.  The octree cells
are recomputed from the scene when the database is opened, and their bounds and counts must match
the stored ones: a database is only valid for the scene it was made of.
"""

from __future__ import annotations

import contextlib
import json
import math
import tempfile
import time
import zipfile
from collections import OrderedDict
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from farfield.core import __version__
from farfield.core.impostor.bundle import read_bundle, write_bundle
from farfield.core.impostor.impostor import Impostor
from farfield.core.ldi.construction import DEFAULT_MAX_LAYERS, construct_ldi
from farfield.core.ldi.image import ldi_of
from farfield.core.ldi.pages import ldi_payload_and_pages
from farfield.core.placement.hierarchy import PlacementError
from farfield.core.placement.image_frames import cell_objects, view_camera
from farfield.core.placement.octree_cells import OctreeCells, octree_cells
from farfield.core.placement.solution_grid import FORMAT_VERSION, UNSOLVED, GridPoint, PrimitivePlacement
from farfield.core.placement.yaw_ranges import drawn_cells
from farfield.core.render.raster import MeshRenderer
from farfield.core.render.splats import SplatRenderer
from farfield.core.scene import Scene
from farfield.core.viewcells import BoxCell, viewcell_from_dict

FORMAT = "farfield.primitive_placement"
INDEX = "placement.json"  # a database written by ``farfield place --bake``
INDEX_NAMES = (INDEX, "index.json")  # and by a placement job (GET /v1/jobs/{id}/database.zip)


def image_entries(
    placement: PrimitivePlacement, resolution: int, images: int = 9, max_layers: int = DEFAULT_MAX_LAYERS
) -> list[dict]:
    """Every image of ``placement``, in order, as an entry :func:`bake_image` bakes alone (a job's
    cell each): ``index`` (its number), ``name`` ("<point>-<image>"), ``viewcell`` (the cube around
    its grid point's star sphere) and ``params``, what determines its bundle's bytes."""
    out = []
    fov = math.degrees(2 * placement.half)
    for pi, point in enumerate(placement.points):
        cell = BoxCell(point.position - point.radius, point.position + point.radius).to_dict()
        for ii, im in enumerate(point.images):
            params = {
                "octree_depth": placement.cells.depth, "fov_deg": fov, "resolution": int(resolution), "construction_images": int(images),
                "max_layers": int(max_layers), "position": point.position.tolist(), "yaw": float(im["yaw"]), "depth": float(im["depth"]),
                "quad": np.asarray(im["quad"]).tolist(), "cells": np.asarray(im["cells"]).tolist(),
            }  # fmt: skip
            out.append(
                {"index": len(out), "name": f"{pi}-{ii}", "point": pi, "image": ii, "viewcell": cell, "params": params}
            )
    return out


_CELLS: OrderedDict[tuple[int, int], tuple[Scene, OctreeCells]] = (
    OrderedDict()
)  # a worker bakes a job's images one by one
_CELLS_KEPT = 2


def _scene_cells(scene: Scene, depth: int) -> OctreeCells:
    """The octree cells of ``scene`` (this object: its objects' order is the cells' face order), kept
    for the next image of the same scene."""
    key = (id(scene), depth)
    found = _CELLS.get(key)
    if found is None or found[0] is not scene:
        found = _CELLS[key] = (scene, octree_cells(scene, depth))
        while len(_CELLS) > _CELLS_KEPT:
            _CELLS.popitem(last=False)
    _CELLS.move_to_end(key)
    return found[1]


def bake_image(
    scene: Scene, entry: dict, cells: OctreeCells | None = None, progress: Callable | None = None
) -> Impostor:
    """One entry of :func:`image_entries` as an ``ldi`` impostor: its subset's cells (of ``cells``, or
    of the scene's octree at the entry's depth) built into the LDI of its grid point's view."""
    p = entry["params"]
    started = time.perf_counter()
    if cells is None:
        cells = _scene_cells(scene, int(p["octree_depth"]))
    chosen = np.asarray(p["cells"], dtype=np.int64)
    if chosen.size and (chosen.min() < 0 or chosen.max() >= cells.count):
        raise PlacementError(
            f"image {entry.get('name')}: its cells {chosen.min()}..{chosen.max()} are not cells of this scene's octree ({cells.count} cells)"
        )
    position, quad = np.asarray(p["position"], dtype=np.float64), np.asarray(p["quad"], dtype=np.float64)
    made = construct_ldi(cell_objects(scene, cells, chosen), position, float(p["yaw"]), quad, float(p["depth"]), int(p["resolution"]),
                         images=int(p["construction_images"]), max_layers=int(p.get("max_layers", DEFAULT_MAX_LAYERS)),
                         cell=viewcell_from_dict(entry["viewcell"]))  # fmt: skip
    if progress is not None:
        progress("record", 1, 1)
    ldi = made.ldi
    payload, pages = ldi_payload_and_pages(ldi)
    return Impostor(
        technique="ldi", viewcell=entry["viewcell"], reference_viewpoint=position, resolution=int(p["resolution"]), fov_deg=float(p["fov_deg"]),
        pages=pages, payload=payload, layers=[],
        stats={"samples": ldi.count, "layers": ldi.layers, "offered": made.offered, "dropped_full": made.dropped_full,
               "construction_images": int(p["construction_images"]), "splat_bytes": 20 * ldi.count, "texture_bytes": int(sum(pg.nbytes for pg in pages)),
               "seconds": {"total": time.perf_counter() - started}},
        parameters={"resolution": int(p["resolution"]), "fov_deg": float(p["fov_deg"]), "images": int(p["construction_images"]),
                    "max_layers": int(p.get("max_layers", DEFAULT_MAX_LAYERS)), "yaw": float(p["yaw"]),
                    "depth": float(p["depth"]), "quad": quad.tolist(), "cells": chosen.tolist(), "scene_hash": scene.content_hash},
        code_version=__version__,
    )  # fmt: skip


def image_index(
    placement: dict, bundles: dict[str, str], resolution: int, images: int, scene_hash: str, **extra
) -> dict:
    """A database's index: the grid (:meth:`PrimitivePlacement.to_dict`) and where each image's bundle is."""
    return {
        **placement,
        "bundles": bundles,
        "resolution": int(resolution),
        "construction_images": int(images),
        "scene_hash": scene_hash,
        **extra,
    }


def write_image_database(root: Path, scene: Scene, placement: PrimitivePlacement, resolution: int, images: int = 9,
                         progress: Callable[[str, int, int], None] | None = None) -> dict:  # fmt: skip
    """Bake every image's LDI and write the database folder ``root``; returns its index."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    bundles = {}
    entries = image_entries(placement, resolution, images)
    for n, entry in enumerate(entries):
        write_bundle(bake_image(scene, entry, placement.cells), root / "images" / entry["name"])
        bundles[entry["name"]] = f"images/{entry['name']}"
        if progress is not None:
            progress("images", n + 1, len(entries))
    index = image_index(placement.to_dict(), bundles, resolution, images, scene.content_hash)
    (root / INDEX).write_text(json.dumps(index) + "\n")
    return index


def _index_file(root: Path) -> Path | None:
    """The index of a primitive-budget database folder, or None."""
    for name in INDEX_NAMES:
        path = Path(root) / name
        try:
            if path.is_file() and json.loads(path.read_text()).get("format") == FORMAT:
                return path
        except (OSError, ValueError):
            continue
    return None


def is_image_database(root: Path) -> bool:
    return _index_file(root) is not None


def image_index_of(path: Path) -> dict | None:
    """The index of the primitive-budget database at ``path`` (a folder, or a zip of one: read from
    the archive, nothing unpacked), or None when ``path`` holds no such database."""
    path = Path(path)
    if path.is_dir():
        found = _index_file(path)
        return json.loads(found.read_text()) if found is not None else None
    if not (path.is_file() and zipfile.is_zipfile(path)):
        return None
    with zipfile.ZipFile(path) as archive:
        for name in (n for n in INDEX_NAMES if n in archive.namelist()):
            try:
                index = json.loads(archive.read(name))
            except ValueError:
                continue
            if isinstance(index, dict) and index.get("format") == FORMAT:
                return index
    return None


@contextlib.contextmanager
def image_database_folder(path: Path) -> Iterator[Path | None]:
    """A primitive-budget database's folder: ``path`` itself, or a zip of one (``database.zip``)
    unpacked to a temporary folder for the block; None when ``path`` holds no such database."""
    path = Path(path)
    if path.is_dir() or image_index_of(path) is None:
        yield path if path.is_dir() and is_image_database(path) else None
        return
    with tempfile.TemporaryDirectory(prefix="farfield-images-") as tmp, zipfile.ZipFile(path) as archive:
        archive.extractall(tmp)
        yield Path(tmp)


def image_lookup(index: dict, placement: PrimitivePlacement, eye, direction) -> dict:
    """What a run time draws for one view (seed 004 Fig. 12): the grid point, the image (its name,
    None when the view draws geometry alone), the octree cells it culls and those drawn as geometry,
    and the triangles left against P.  Views are horizontal (pitch 0): ``direction``'s y is not used."""
    eye = np.asarray(eye, dtype=np.float64)
    if eye.shape != (3,) or not np.all(np.isfinite(eye)):
        raise PlacementError(f"the view's position must be 3 finite numbers, got {eye.tolist()}")
    dx, _, dz = (float(v) for v in direction)
    if not (math.isfinite(dx) and math.isfinite(dz) and dx * dx + dz * dz > 0):
        raise PlacementError(
            "a primitive-budget placement's views look horizontally (pitch 0, seed 004): give a direction with dx or dz not 0"
        )
    yaw = math.atan2(dx, -dz) % (2 * math.pi)  # forward(yaw) = (sin yaw, 0, -cos yaw)
    view = placement.view(eye, yaw)
    name = f"{view['point']}-{view['image']}" if view["image"] >= 0 else None
    culled = np.asarray(placement.points[view["point"]].images[view["image"]]["cells"]).tolist() if name else []
    status = "no grid point" if view["point"] < 0 else ("unsolved" if view["image"] == UNSOLVED else "solved")
    return {
        "algorithm": "primitive-budget", "position": eye.tolist(), "yaw": yaw, "point": view["point"], "image": name,
        "bundle": index["bundles"].get(name) if name else None, "status": status, "primitives": view["primitives"],
        "primitives_budget": placement.primitives, "within_budget": view["primitives"] <= placement.primitives,
        "replaced_octree_cells": culled, "drawn_octree_cells": np.flatnonzero(view["cells"]).tolist(), "eye_past_quad": view["past_quad"],
    }  # fmt: skip


def stored_cells(index: dict) -> OctreeCells:
    """The octree cells a database stores (bounds, counts: enough to count and cull, not to draw)."""
    c = index["cells"]
    lo = np.asarray(c["lo"], dtype=np.float64).reshape(-1, 3)
    return OctreeCells(lo, np.asarray(c["hi"], dtype=np.float64).reshape(-1, 3), np.asarray(c["triangles"], dtype=np.int64),
                       np.zeros((len(lo), 3), dtype=np.int64), int(c["depth"]), np.asarray(c["cube_lo"], dtype=np.float64), float(c["cube_size"]), ())  # fmt: skip


def placement_of_index(index: dict, cells: OctreeCells | None = None) -> PrimitivePlacement:
    """The placement a database's index holds, with ``cells`` (default: :func:`stored_cells`)."""
    if index.get("format") != FORMAT or index.get("version") != FORMAT_VERSION:
        raise PlacementError(
            f"format {index.get('format')!r} version {index.get('version')!r}, expected {FORMAT!r} {FORMAT_VERSION}"
        )
    points = []
    for p in index["points"]:
        point = GridPoint(np.asarray(p["position"], dtype=np.float64), int(p["level"]), float(p["radius"]), np.asarray(p["breaks"], dtype=np.float64),
                          np.asarray(p["image"], dtype=np.int64), failure=p["failure"])  # fmt: skip
        point.images = [
            {**im, "quad": np.asarray(im["quad"]), "cells": np.asarray(im["cells"], dtype=np.int64)}
            for im in p["images"]
        ]
        points.append(point)
    s = index["summary"]
    lo, hi = (np.asarray(v, dtype=np.float64) for v in index["view_space"])
    return PrimitivePlacement(stored_cells(index) if cells is None else cells, points, lo, hi, float(s["primitives"]), float(s["p_opt"]),
                              math.radians(s["fov_deg"]) / 2, float(s["spacing"]), len(s["points_per_level"]) - 1, index.get("seconds", {}))  # fmt: skip


class ImageDatabase:
    """An opened primitive-budget database (a folder of ``farfield place --bake`` or an unpacked
    placement job's ``database.zip``): the placement (cells recomputed from ``scene`` and checked)
    and its LDIs, read when first used."""

    def __init__(self, root: Path, scene: Scene) -> None:
        self.root = Path(root)
        found = _index_file(self.root)
        try:
            index = json.loads((found or self.root / INDEX).read_text())
        except (OSError, ValueError) as error:
            raise PlacementError(f"{self.root} is not a primitive-budget placement database: {error}") from None
        if index.get("format") != FORMAT or index.get("version") != FORMAT_VERSION:
            raise PlacementError(
                f"{self.root}: format {index.get('format')!r} version {index.get('version')!r}, expected {FORMAT!r} {FORMAT_VERSION}"
            )
        self.index = index
        stored = index["cells"]
        cells = octree_cells(scene, int(stored["depth"]))
        if (cells.count != len(stored["triangles"]) or not np.array_equal(cells.triangles, stored["triangles"])
                or not np.allclose(cells.lo, stored["lo"]) or not np.allclose(cells.hi, stored["hi"])):  # fmt: skip
            raise PlacementError(f"{self.root} was made for another scene (its octree cells differ from this scene's)")
        self.placement = placement_of_index(index, cells)
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
        camera = view_camera(
            eye,
            float(yaw),
            2 * placement.half,
            resolution,
            1e-4 * size,
            4.0 * size + float(np.linalg.norm(eye - placement.cells.cube_lo)),
        )
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
                row["colour_error_mean"] = (
                    float(np.abs(full[..., :3].astype(int) - frame[..., :3].astype(int)).max(axis=-1)[both].mean())
                    if both.any()
                    else 0.0
                )
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

"""The layered-impostor pipeline: a scene part and a view cell in, an :class:`~core.impostor.Impostor` out.

plan layers (seed 000 §3.3.1) -> record layers on EGL (§3.3.2) -> cull hidden texels (§3.4, §3.4.1)
-> box-grown quads (§3.5) -> atlas pages (§3.6) -> world-space quads.

Every stage is timed; memory grows with the texels that survive culling, not with layers x image.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from core import __version__
from core.atlas import compose, fill_nearest_rgb, pack, tile_uvs
from core.culled_layers import culled_layers
from core.culling import CullingMode
from core.errors import LayerPlanError
from core.frustum import MAX_RESOLUTION, PixelModel
from core.impostor import Impostor, QuadPayload, texel_rect_corners
from core.layers import plan_layers
from core.quads import grow_quads
from core.scene import Scene
from core.stage_clock import Progress, StageClock
from core.options import check_options, option
from core.viewcells import ViewCell

# Bytes of one quad's geometry as drawn: 4 vertices x (3 position + 2 uv) float32 + 6 uint32 indices.
QUAD_GEOMETRY_BYTES = 4 * 5 * 4 + 6 * 4


@dataclass(frozen=True, slots=True)
class BakeOptions:
    """The knobs of a layered bake (all recorded in the impostor's parameters); validated from each
    field's declaration (:mod:`core.techniques.options`)."""

    resolution: int = option(512, "output image pixels per side the impostor serves", ge=1, le=MAX_RESOLUTION)
    fov_deg: float = option(45.0, "output field of view, degrees", gt=0.0, lt=180.0)
    grid_cell: int = option(8, "box-growing grid cell, texels (seed 000 §3.5): smaller, less texture but more quads", ge=1, le=1024)
    fill_threshold: float = option(0.8, "box-growing fill ratio (§3.5): lower, fewer quads but more wasted texels", gt=0.0, le=1.0)
    culling: CullingMode = option("penumbra", "hidden-texel culling: penumbra (§3.4.1), umbra (§3.4 3x3 rule) or off")
    pixel_model: PixelModel = option("min", "error bound from the smallest pixel angle (min) or the thesis's centre pixel (center)")
    conservative: bool = option(True, "gap-free recording; false only to demonstrate the holes", internal=True)
    padding: int = option(2, "atlas padding between tiles, texels", ge=0, le=64)

    def __post_init__(self) -> None:
        check_options(self)


def layer_tiles(image: np.ndarray, kept: np.ndarray, grid_cell: int, fill_threshold: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """Box-grown rectangles (q, 4) of a layer's kept texels (§3.5) and their tiles: each its own
    array (not a view that would keep the layer alive), transparent texels coloured from the
    nearest opaque one so that bilinear filtering and mipmaps never pull black into the edges."""
    rects = grow_quads(kept, grid_cell, fill_threshold)
    texels = image.copy()
    texels[..., 3] = np.where(kept, texels[..., 3], 0)
    return rects, [fill_nearest_rgb(texels[y0:y1, x0:x1]) for x0, y0, x1, y1 in rects]


def layer_records(plan, layer_ids, texels) -> list[dict]:
    """The impostor's ``layers`` entries of the layers ``layer_ids`` of ``plan`` that keep
    ``texels`` texels each: index, distance, depth range (recording and eye frame), texels."""
    eye = plan.borders + plan.reference_offset
    return [
        {
            "index": int(i),
            "distance": float(plan.distances[i]),
            "depth_range": [float(plan.borders[i]), float(plan.borders[i + 1])],
            "eye_depth_range": [float(eye[i]), float(eye[i + 1])],
            "texels": int(n),
        }
        for i, n in zip(layer_ids, texels)
    ]


def pack_tiles(tiles: list[np.ndarray], padding: int) -> tuple[tuple[np.ndarray, ...], np.ndarray, np.ndarray, int]:
    """Atlas pages (§3.6) of ``tiles``: (pages, quad uv (q, 4, 2), quad page (q,), tile bytes)."""
    if not tiles:
        return (), np.zeros((0, 4, 2)), np.zeros(0, np.int64), 0
    sizes = np.array([[t.shape[1], t.shape[0]] for t in tiles], dtype=np.int64)
    layout = pack(sizes, padding=padding)
    pages = compose(layout, tiles, padding, bleed=0)
    return tuple(pages), tile_uvs(layout), layout.page.astype(np.int64), int(sizes.prod(axis=1).sum() * 4)


def bake_layered(
    scene: Scene,
    cell: ViewCell,
    options: BakeOptions = BakeOptions(),
    objects: list[str] | None = None,
    progress: Progress | None = None,
) -> Impostor:
    """Bake the layered impostor of ``scene`` (or of its ``objects``) for ``cell``."""
    part = scene.subset(objects) if objects else scene
    clock = StageClock(("plan", "record", "cull", "quads"), progress)

    with clock("plan"):
        plan = plan_layers(cell, part.bounds, math.radians(options.fov_deg), options.resolution, options.pixel_model)
    clock.report("plan", 1, 1)

    # Stream: each layer is recorded, culled against the layers before it, cut into quads and
    # tiles, and dropped, so memory grows with the kept texels, not with layers x image.
    res_x, res_y = (int(r) for r in plan.texture_resolution)
    tiles, quad_layer, quad_corners, layer_ids = [], [], [], []
    counts = {"covered": 0, "culled": 0, "kept": 0, "drawn": 0}
    kept_per_layer: dict[int, int] = {}
    for layer in culled_layers(part, plan, options.culling, clock, options.conservative):
        i = layer.index
        counts["covered"] += layer.covered
        counts["culled"] += layer.culled
        counts["drawn"] += layer.drawn
        clock.report("record", i + 1, plan.count)
        if not layer.kept.any():  # layers with no visible content are dropped
            continue
        with clock("quads"):
            rects, new_tiles = layer_tiles(layer.image, layer.kept, options.grid_cell, options.fill_threshold)
            tiles += new_tiles
            quad_layer.append(np.full(len(rects), i, dtype=np.int64))
            quad_corners.append(texel_rect_corners(plan, float(plan.distances[i]), rects))
            layer_ids.append(i)
            kept_per_layer[i] = int(layer.kept.sum())
            counts["kept"] += kept_per_layer[i]
    if not layer_ids:
        raise LayerPlanError("the part left no visible texel in any layer (is it empty or fully transparent?)")

    with clock("atlas"):
        pages, quad_uv, quad_page, tile_bytes = pack_tiles(tiles, options.padding)
    clock.report("atlas", 1, 1)

    quad_count = len(tiles)
    texture_bytes = int(sum(p.shape[0] * p.shape[1] * 4 for p in pages))
    stats = {
        "layers_planned": plan.count,
        "layers": len(layer_ids),
        "quads": quad_count,
        "texels_covered": counts["covered"],
        "texels_culled": counts["culled"],
        "texels_kept": counts["kept"],
        "triangles_drawn": counts["drawn"],
        "texture_bytes": texture_bytes,
        "texture_bytes_tile_area": tile_bytes,
        "texture_bytes_one_quad_per_layer": int(len(layer_ids) * res_x * res_y * 4),
        "geometry_bytes": quad_count * QUAD_GEOMETRY_BYTES,
        "atlas_pages": len(pages),
        "texture_resolution": [res_x, res_y],
        "seconds": clock.totals(),
    }
    layers = layer_records(plan, layer_ids, [kept_per_layer[i] for i in layer_ids])
    return Impostor(
        technique="layered",
        viewcell=cell.to_dict(),
        reference_viewpoint=plan.reference_viewpoint,
        resolution=options.resolution,
        fov_deg=options.fov_deg,
        pages=tuple(pages),
        payload=QuadPayload(corners=np.concatenate(quad_corners), uv=quad_uv, page=quad_page, layer=np.concatenate(quad_layer)),
        layers=layers,
        stats=stats,
        parameters={**asdict(options), "objects": list(part.names), "scene_hash": scene.content_hash, "plan": plan.to_dict()},
        code_version=__version__,
    )

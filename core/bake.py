"""The layered-impostor pipeline: a scene part and a view cell in, an :class:`~core.impostor.Impostor` out.

plan layers (seed 000 §3.3.1) -> record layers on EGL (§3.3.2) -> cull hidden texels (§3.4, §3.4.1)
-> box-grown quads (§3.5) -> atlas pages (§3.6) -> world-space quads.

Every stage is timed; memory grows with the texels that survive culling, not with layers x image.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass

import numpy as np

from core import __version__
from core.atlas import compose, fill_nearest_rgb, pack, tile_uvs
from core.culling import CULLING_MODES, CullingMode, hidden_texels
from core.errors import LayerPlanError
from core.frustum import PIXEL_MODELS, PixelModel, check_fov, check_resolution
from core.impostor import Impostor, texel_rect_corners
from core.layers import plan_layers
from core.quads import quads_for_layers
from core.recording import record_layers
from core.scene import Scene
from core.viewcells import ViewCell

Progress = Callable[[str, int, int], None]  # (stage, done, total)

# Bytes of one quad's geometry as drawn: 4 vertices x (3 position + 2 uv) float32 + 6 uint32 indices.
QUAD_GEOMETRY_BYTES = 4 * 5 * 4 + 6 * 4


@dataclass(frozen=True, slots=True)
class BakeOptions:
    """The knobs of a layered bake (all recorded in the impostor's parameters)."""

    resolution: int = 512  # output pixels per side
    fov_deg: float = 45.0  # output field of view
    grid_cell: int = 8  # box-growing grid cell, texels (§3.5)
    fill_threshold: float = 0.8  # box-growing fill ratio (§3.5)
    culling: CullingMode = "penumbra"  # §3.4.1, "umbra" (§3.4) or "off"
    pixel_model: PixelModel = "min"
    conservative: bool = True  # gap-free recording; False only to demonstrate the holes
    padding: int = 2  # atlas padding, texels

    def __post_init__(self) -> None:
        check_resolution(self.resolution)
        check_fov(math.radians(self.fov_deg))
        if isinstance(self.grid_cell, bool) or int(self.grid_cell) != self.grid_cell or self.grid_cell < 1:
            raise LayerPlanError(f"grid cell size must be an integer >= 1 texel, got {self.grid_cell!r}")
        if not 0.0 < self.fill_threshold <= 1.0:
            raise LayerPlanError(f"fill threshold must lie in (0, 1], got {self.fill_threshold!r}")
        if self.culling not in CULLING_MODES:
            raise LayerPlanError(f"culling mode must be one of {CULLING_MODES}, got {self.culling!r}")
        if self.pixel_model not in PIXEL_MODELS:
            raise LayerPlanError(f"pixel model must be one of {PIXEL_MODELS}, got {self.pixel_model!r}")
        if isinstance(self.padding, bool) or int(self.padding) != self.padding or self.padding < 0:
            raise LayerPlanError(f"atlas padding must be an integer >= 0, got {self.padding!r}")


def bake_layered(
    scene: Scene,
    cell: ViewCell,
    options: BakeOptions = BakeOptions(),
    objects: list[str] | None = None,
    progress: Progress | None = None,
) -> Impostor:
    """Bake the layered impostor of ``scene`` (or of its ``objects``) for ``cell``."""
    part = scene.subset(objects) if objects else scene
    times: dict[str, float] = {}
    report = progress or (lambda stage, done, total: None)

    start = time.perf_counter()
    plan = plan_layers(cell, part.bounds, math.radians(options.fov_deg), options.resolution, options.pixel_model)
    times["plan"] = time.perf_counter() - start
    report("plan", 1, 1)

    start = time.perf_counter()
    recorded = record_layers(part, plan, options.conservative, on_layer=lambda i: report("record", i + 1, plan.count))
    images = recorded.rgba[:, ::-1]  # top row first from here on
    times["record"] = time.perf_counter() - start

    start = time.perf_counter()
    covered = images[..., 3] > 0
    hidden = hidden_texels(covered, options.culling)
    kept = covered & ~hidden
    times["cull"] = time.perf_counter() - start
    report("cull", 1, 1)

    start = time.perf_counter()
    layer_ids = np.flatnonzero(kept.any(axis=(1, 2)))  # layers with no content are dropped
    if layer_ids.size == 0:
        raise LayerPlanError("the part left no visible texel in any layer (is it empty or fully transparent?)")
    rects = quads_for_layers(kept[layer_ids], options.grid_cell, options.fill_threshold)
    times["quads"] = time.perf_counter() - start
    report("quads", 1, 1)

    start = time.perf_counter()
    tiles, quad_layer, quad_corners = [], [], []
    for layer, layer_rects in zip(layer_ids, rects):
        image = images[layer].copy()
        image[..., 3] = np.where(kept[layer], image[..., 3], 0)
        for x0, y0, x1, y1 in layer_rects:
            tiles.append(image[y0:y1, x0:x1])
        quad_layer.append(np.full(len(layer_rects), layer, dtype=np.int64))
        quad_corners.append(texel_rect_corners(plan, float(plan.distances[layer]), layer_rects))
    sizes = np.array([[t.shape[1], t.shape[0]] for t in tiles], dtype=np.int64)
    layout = pack(sizes, padding=options.padding)
    # Transparent texels take the nearest opaque colour (on the pages, which are about the size of
    # the kept tiles, not of whole layers), so bilinear filtering and mipmaps never pull black
    # into the edges of content.
    pages = [fill_nearest_rgb(page) for page in compose(layout, tiles, options.padding, bleed=0)]
    quad_uv = tile_uvs(layout)
    times["atlas"] = time.perf_counter() - start
    report("atlas", 1, 1)

    quad_count = len(tiles)
    texture_bytes = int(sum(p.shape[0] * p.shape[1] * 4 for p in pages))
    res_x, res_y = (int(r) for r in plan.texture_resolution)
    stats = {
        "layers_planned": plan.count,
        "layers": int(layer_ids.size),
        "quads": quad_count,
        "texels_covered": int(covered.sum()),
        "texels_culled": int((covered & hidden).sum()),
        "texels_kept": int(kept.sum()),
        "triangles_drawn": int(recorded.drawn_triangles.sum()),
        "texture_bytes": texture_bytes,
        "texture_bytes_tile_area": int(sizes.prod(axis=1).sum() * 4),
        "texture_bytes_one_quad_per_layer": int(layer_ids.size * res_x * res_y * 4),
        "geometry_bytes": quad_count * QUAD_GEOMETRY_BYTES,
        "atlas_pages": len(pages),
        "texture_resolution": [res_x, res_y],
        "seconds": {**times, "total": sum(times.values())},
    }
    eye = plan.borders + plan.reference_offset
    layers = [
        {
            "index": int(i),
            "distance": float(plan.distances[i]),
            "depth_range": [float(plan.borders[i]), float(plan.borders[i + 1])],
            "eye_depth_range": [float(eye[i]), float(eye[i + 1])],
            "texels": int(kept[i].sum()),
        }
        for i in layer_ids
    ]
    return Impostor(
        technique="layered",
        viewcell=cell.to_dict(),
        reference_viewpoint=plan.reference_viewpoint,
        resolution=options.resolution,
        fov_deg=options.fov_deg,
        quad_corners=np.concatenate(quad_corners),
        quad_uv=quad_uv,
        quad_page=layout.page.astype(np.int64),
        quad_layer=np.concatenate(quad_layer),
        pages=tuple(pages),
        layers=layers,
        stats=stats,
        parameters={**asdict(options), "objects": list(part.names), "scene_hash": scene.content_hash, "plan": plan.to_dict()},
        code_version=__version__,
    )

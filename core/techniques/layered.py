"""Layered impostors (seed 000 ch. 3): a scene part and a view cell in, an :class:`~farfield.core.impostor.impostor.Impostor` of textured quads on layers out.

plan layers (seed 000 §3.3.1) -> record layers on EGL (§3.3.2) -> cull hidden texels (§3.4, §3.4.1)
-> box-grown quads (§3.5) -> atlas pages (§3.6) -> world-space quads.

Every stage is timed; memory grows with the texels that survive culling, not with layers x image.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from farfield.core import __version__
from farfield.core.errors import LayerPlanError
from farfield.core.impostor.depth import layer_depth_ranges
from farfield.core.impostor.impostor import (
    CHANNELS_HELP,
    ChannelSet,
    Impostor,
    QuadPayload,
    keeps_material,
    texel_rect_corners,
    wants_depth,
    wants_normals,
)
from farfield.core.layering import recording
from farfield.core.layering.atlas import MAX_PAGE
from farfield.core.layering.culled import culled_layers
from farfield.core.layering.culling import CullingMode
from farfield.core.layering.plan import plan_layers
from farfield.core.layering.tiles import (
    QUAD_GEOMETRY_BYTES,
    check_pages,
    layer_records,
    layer_tiles,
    pack_tiles,
    split_channels,
)
from farfield.core.options import check_options, option
from farfield.core.pixel_angles import MAX_ERROR_PX, MAX_RESOLUTION, ErrorBudgetKind, PixelModel
from farfield.core.scene import Scene
from farfield.core.sidedness import seen_from_cell
from farfield.core.stage_clock import Progress, StageClock, seconds_line
from farfield.core.techniques.base import Promise, TechniqueDefinition
from farfield.core.techniques.part import (
    bound_part_cells,
    check_part_cell,
    estimate_part_cell,
    evaluate_part,
    layer_budget,
    part_evaluation_text,
)
from farfield.core.viewcells import ViewCell


@dataclass(frozen=True, slots=True)
class BakeOptions:
    """The knobs of a layered bake (all recorded in the impostor's parameters); validated from each
    field's declaration (:mod:`farfield.core.options`)."""

    resolution: int = option(512, "output image pixels per side the impostor serves", ge=1, le=MAX_RESOLUTION)
    fov_deg: float = option(45.0, "output field of view, degrees", gt=0.0, lt=180.0)
    grid_cell: int = option(
        8, "box-growing grid cell, texels (seed 000 §3.5): smaller, less texture but more quads", ge=1, le=1024
    )
    fill_threshold: float = option(
        0.8, "box-growing fill ratio (§3.5): lower, fewer quads but more wasted texels", gt=0.0, le=1.0
    )
    culling: CullingMode = option("penumbra", "hidden-texel culling: penumbra (§3.4.1), umbra (§3.4 3x3 rule) or off")
    max_error_px: float = option(
        1.0,
        "error budget, output pixels: no hole, and no pixel bloated or moved beyond this many, from anywhere in the cell; "
        "larger, fewer layers and texels",
        gt=0.0,
        le=MAX_ERROR_PX,
    )
    budget: ErrorBudgetKind = option(
        "strict",
        "strict (the guarantee of max_error_px at every pixel) or thesis (seed 000 §3.3: texels and parallax each within "
        "the centre pixel, reproducing its Table 4.1 with fewer layers and up to twice the error at the edge)",
    )
    pixel_model: PixelModel = option(
        "min",
        "expert: error bound from the smallest pixel angle (min) or the centre pixel (center); strict budget only",
    )
    texel_share: float = option(
        0.7,
        "expert: share of the budget given to the texel size, the rest to parallax, so that a silhouette grown by one "
        "texel (gap-free recording, §3.3.2) and moved by parallax stays within it: larger, fewer texels but more layers; "
        "strict budget only",
        gt=0.0,
        lt=1.0,
    )
    channels: ChannelSet = option(
        "albedo",
        CHANNELS_HELP,
    )
    conservative: bool = option(True, "gap-free recording; false only to demonstrate the holes", internal=True)
    padding: int = option(2, "atlas padding between tiles, texels", ge=0, le=64)
    max_page: int = option(
        MAX_PAGE,
        "largest atlas page side, texels (WebGL2 guarantees 2048, many mobile GPUs stop at 4096), a power of two",
        ge=64,
        le=16384,
    )

    def __post_init__(self) -> None:
        check_options(self)
        check_pages(self.max_page, self.padding)


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
        plan = plan_layers(
            cell, part.bounds, math.radians(options.fov_deg), options.resolution, **layer_budget(options)
        )
    clock.report("plan", 1, 1)

    # Stream: each layer is recorded, culled against the layers before it, cut into quads and
    # tiles, and dropped, so memory grows with the kept texels, not with layers x image.
    res_x, res_y = (int(r) for r in plan.texture_resolution)
    tiles, quad_layer, quad_corners, layer_ids = [], [], [], []
    counts = {"covered": 0, "culled": 0, "kept": 0, "drawn": 0}
    kept_per_layer: dict[int, int] = {}
    # One-sided triangles whose back faces the whole cell are not recorded (the plan keeps the part's bounds).
    seen = seen_from_cell(part.objects, cell)
    normals = wants_normals(options.channels)
    material = keeps_material(options.channels, seen)
    depth = wants_depth(options.channels)
    depth_ranges = []  # per quad, ray scales of its slab (farfield.core.impostor.depth), with depth
    layers_of_plan = culled_layers(
        seen, plan, options.culling, clock, options.conservative, normals=normals, depth=depth, material=material
    )
    for layer in layers_of_plan:
        i = layer.index
        counts["covered"] += layer.covered
        counts["culled"] += layer.culled
        counts["drawn"] += layer.drawn
        clock.report("record", i + 1, plan.count)
        if not layer.kept.any():  # layers with no visible content are dropped
            continue
        with clock("quads"):
            rects, new_tiles = layer_tiles(
                layer.image, layer.kept, options.grid_cell, options.fill_threshold, options.max_page, options.padding
            )
            tiles += new_tiles
            quad_layer.append(np.full(len(rects), i, dtype=np.int64))
            quad_corners.append(texel_rect_corners(plan, float(plan.distances[i]), rects))
            depth_ranges.append(layer_depth_ranges(plan, i, len(rects)))
            layer_ids.append(i)
            kept_per_layer[i] = int(layer.kept.sum())
            counts["kept"] += kept_per_layer[i]
    if not layer_ids:
        raise LayerPlanError("the part left no visible texel in any layer (is it empty or fully transparent?)")

    with clock("atlas"):
        pages, quad_uv, quad_page, tile_bytes = pack_tiles(tiles, options.padding, options.max_page)
        pages, channels = split_channels(pages)
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
    if channels:  # memory per channel; a colour-only bake's stats stay as they were
        stats["channel_bytes"] = {"albedo": texture_bytes} | {
            name: int(sum(p.nbytes for p in channel)) for name, channel in channels.items()
        }
    layers = layer_records(plan, layer_ids, [kept_per_layer[i] for i in layer_ids])
    return Impostor(
        technique="layered",
        viewcell=cell.to_dict(),
        reference_viewpoint=plan.reference_viewpoint,
        resolution=options.resolution,
        fov_deg=options.fov_deg,
        pages=tuple(pages),
        payload=QuadPayload(
            corners=np.concatenate(quad_corners),
            uv=quad_uv,
            page=quad_page,
            layer=np.concatenate(quad_layer),
            depth_range=np.concatenate(depth_ranges) if depth else None,
        ),
        layers=layers,
        stats=stats,
        parameters={
            **asdict(options),
            "objects": list(part.names),
            "scene_hash": scene.content_hash,
            "plan": plan.to_dict(),
        },
        code_version=__version__,
        channels=channels,
    )


def _summary(stats: dict) -> str:
    return (
        f"layers: {stats['layers']} (planned {stats['layers_planned']})  quads: {stats['quads']}  "
        f"atlas pages: {stats['atlas_pages']}  texture: {stats['texture_bytes'] / 1024:.1f} KiB "
        f"(one quad per layer: {stats['texture_bytes_one_quad_per_layer'] / 1024:.1f} KiB)\n"
        f"texels: {stats['texels_covered']} covered, {stats['texels_culled']} culled\n" + seconds_line(stats)
    )


TECHNIQUE = TechniqueDefinition(
    name="layered",
    payload_kind=QuadPayload.kind,
    kernels=(recording.warm_kernels,),
    scope="part",
    help="layered impostors of a scene's objects for any view cell (seed 000 ch. 3)",
    Options=BakeOptions,
    check=check_part_cell,
    bound=bound_part_cells,
    estimate=estimate_part_cell,
    bake=bake_layered,
    summary=_summary,
    evaluate=evaluate_part,
    evaluation_text=part_evaluation_text,
    promise=Promise(
        "no hole pixel and no pixel bloated or moved beyond max_error_px (default 1) from anywhere in the view cell",
        holes=True,
        bloat=True,
    ),
)

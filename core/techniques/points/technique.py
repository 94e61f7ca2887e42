"""Point-based impostors (seed 001, Wimmer, Wonka and Sillion 2001): a scene part and a box view
cell in, an :class:`~farfield.core.impostor.impostor.Impostor` of points with directional colours out.

plan (:func:`farfield.core.techniques.points.sampling.plan_point_sampling`: the sampling plane, the three LDI cameras
on the minimum-perimeter triangle, their resolution, §3 and §5.1) -> points (:func:`farfield.core.techniques.points.samples.gather_point_samples`:
every surface hit of the three LDIs, less the redundant ones, §4.2 and §5.1) -> appearance
(:func:`farfield.core.techniques.points.appearance.integrate_appearance`: a tile of directional colours per point by
Monte Carlo integration over the view cell, §4.3 and §5.2) -> compression (§5.3: a point whose
tile varies less than ``single_colour`` keeps one colour) -> the tiles packed row by row onto
atlas pages (:func:`pack_tiles`).

**Memory** (``geometry_bytes``, ``texture_bytes``), as a runtime holds it: per point a float32
position and an RGBA8 colour (16 bytes), per textured point a tile reference (4 bytes: its page
texel as two uint16; its page is that of the draw it is in), and the pages' texels; ``bytes_per_point`` is their sum over the points.
With ``channels="albedo+normal"`` each point also keeps its world shading normal (12 bytes, float32;
one per point whatever its tile: :mod:`farfield.core.ldi.normals`): ``channel_bytes`` gives the memory
per channel, ``albedo`` (the figures above: ``geometry_bytes`` + ``texture_bytes``) and ``normal``.
The paper's ≈ 20 bytes per point assumes 8:1 compressed textures, which farfield does not apply.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from farfield.core import __version__
from farfield.core.errors import AtlasOverflowError, LayerPlanError
from farfield.core.impostor.depth import refuse_depth
from farfield.core.impostor.impostor import (
    CHANNELS_HELP,
    ChannelSet,
    Impostor,
    PointPayload,
    keeps_material,
    wants_normals,
)
from farfield.core.layering.atlas import MAX_PAGE
from farfield.core.layering.recording import faces_with_area
from farfield.core.ldi import image as ldi_kernels
from farfield.core.ldi.materials import sample_material
from farfield.core.ldi.normals import sample_normals
from farfield.core.options import check_options, option
from farfield.core.pixel_angles import MAX_ERROR_PX, MAX_RESOLUTION
from farfield.core.quality.evaluation import Evaluation
from farfield.core.scene import Scene, emits
from farfield.core.sidedness import seen_from_cell
from farfield.core.stage_clock import Progress, StageClock, seconds_line
from farfield.core.techniques.base import CellCost, Promise, TechniqueDefinition
from farfield.core.techniques.part import evaluate_part, part_evaluation_text
from farfield.core.techniques.points.appearance import (
    integrate_appearance,
    mean_colour,
    single_colour,
)
from farfield.core.techniques.points.cover import covering_points, warm_cover
from farfield.core.techniques.points.samples import _lookup_kernel, _spacing_kernel, gather_point_samples
from farfield.core.techniques.points.sampling import plan_point_sampling
from farfield.core.viewcells import BoxCell, ViewCell

POINT_BYTES = 16  # float32 position + RGBA8 colour
NORMAL_BYTES = 12  # a point's float32 normal (channels albedo+normal), as the GLB's NORMAL holds it
TILE_REFERENCE_BYTES = 4  # a textured point's tile: two uint16 texel coordinates


@dataclass(frozen=True, slots=True)
class PointOptions:
    """The knobs of a point-based bake (all recorded in the impostor's parameters)."""

    resolution: int = option(512, "output image pixels per side", ge=1, le=MAX_RESOLUTION)
    fov_deg: float = option(45.0, "output field of view, degrees", gt=0.0, lt=180.0)
    max_error_px: float = option(
        1.0,
        "error budget, output pixels: no sample spacing looks larger than this from anywhere in the cell",
        gt=0.0,
        le=MAX_ERROR_PX,
    )
    tile_u: int = option(
        8,
        "directional texels per point along the sampling plane's u axis, level unless the plane faces up or down (seed 001 §6: 8 x 2)",
        ge=1,
        le=32,
    )
    tile_v: int = option(2, "directional texels per point along the plane's v axis", ge=1, le=32)
    samples: int = option(4, "geometry samples per output pixel side in the appearance's pixel footprint", ge=1, le=8)
    appearance_error: float = option(
        0.02,
        "stop adding views when 95 % of the texels' standard errors are below this (linear luminance, 0-1)",
        gt=0.0,
        le=1.0,
    )
    min_views: int = option(
        64,
        "fewest Monte Carlo views of the appearance integration (they also judge which points are ever visible)",
        ge=1,
        le=4096,
    )
    max_views: int = option(128, "most Monte Carlo views of the appearance integration", ge=1, le=4096)
    visible_only: bool = option(
        True,
        "keep only the points the cell's views need, before the appearance: a greedy cover of every pixel-sized window of cover_views views by points on the surface each window shows (core/techniques/points/cover.py)",
    )
    cover_views: int = option(
        17,
        "views of the cell (its corners, its centre, then Sobol points) whose windows the kept points cover (visible_only)",
        ge=1,
        le=4096,
    )
    single_colour: float = option(
        3.0,
        "a point whose texels' standard deviation stays below this (sRGB levels) stores one colour (seed 001 §5.3); 0: never",
        ge=0.0,
        le=255.0,
    )
    max_layers: int = option(256, "most depth layers each LDI records", ge=1, le=4096)
    sufficient_only: bool = option(
        False,
        "remove a point only where another camera samples its surface better and sufficiently (seed 001 §5.1 as written); "
        "off: wherever another camera samples the same surface more finely",
    )
    max_page: int = option(
        MAX_PAGE,
        "largest atlas page side, texels (WebGL2 guarantees 2048, many mobile GPUs stop at 4096)",
        ge=64,
        le=16384,
    )
    channels: ChannelSet = option(
        "albedo",
        CHANNELS_HELP,
    )

    def __post_init__(self) -> None:
        check_options(self)
        refuse_depth("points", self.channels)  # its geometry is exact (farfield.core.impostor.depth)
        if self.min_views > self.max_views:
            raise LayerPlanError(f"min_views ({self.min_views}) must not exceed max_views ({self.max_views})")


def _box(cell: ViewCell) -> BoxCell:
    if not isinstance(cell, BoxCell):
        raise LayerPlanError(f"a point-based impostor needs a box view cell, got a {cell.kind} cell")
    return cell


def check_points_cell(
    cell: ViewCell, options: PointOptions, bounds: np.ndarray | None, max_texels: int | None = None
) -> CellCost:
    """The cell's recording work: three LDIs at the planned resolution (:func:`plan_point_sampling`,
    which raises where the cell can have no point impostor); without ``bounds``, only the cell's kind."""
    box = _box(cell)
    if bounds is None:
        return CellCost.of_layers(0, (0, 0))
    sampling = plan_point_sampling(box, bounds, options.fov_deg, options.resolution, options.max_error_px)
    side = max(c.resolution for c in sampling.cameras)
    return CellCost.of_layers(len(sampling.cameras), (side, side))


def pack_tiles(
    count: int, tile: tuple[int, int], max_page: int
) -> tuple[list[tuple[int, int]], np.ndarray, np.ndarray]:
    """Places for ``count`` tiles of ``tile`` (tu, tv) texels, row by row on pages of at most
    ``max_page`` texels a side: (each page's (width, height), page (count,), first texel (count, 2)).

    >>> sizes, page, texel = pack_tiles(5, (8, 2), 16)
    >>> sizes, page.tolist(), texel.tolist()
    ([(16, 6)], [0, 0, 0, 0, 0], [[0, 0], [8, 0], [0, 2], [8, 2], [0, 4]])
    >>> pack_tiles(5, (8, 2), 8)[:2]
    ([(8, 8), (8, 2)], array([0, 0, 0, 0, 1]))
    """
    tu, tv = tile
    if tu > max_page or tv > max_page:
        raise AtlasOverflowError(f"a point's tile of {tu}x{tv} texels does not fit on a page of {max_page}")
    across, down = max_page // tu, max_page // tv
    per_page = across * down
    index = np.arange(count, dtype=np.int64)
    page, slot = index // per_page, index % per_page
    texel = np.stack([slot % across * tu, slot // across * tv], axis=1)
    sizes = []
    for p in range(-(-count // per_page)):
        n = min(per_page, count - p * per_page)
        sizes.append((tu * min(n, across), tv * -(-n // across)))
    return sizes, page, texel


def bake_points(
    scene: Scene,
    cell: ViewCell,
    options: PointOptions = PointOptions(),
    objects: list[str] | None = None,
    progress: Progress | None = None,
) -> Impostor:
    """Bake the point-based impostor of ``scene`` (or of its ``objects``) for ``cell`` (a box).

    Same contract as :func:`farfield.core.techniques.layered.bake_layered`; technique ``"points"``.
    """
    part = scene.subset(objects) if objects else scene
    box = _box(cell)
    clock = StageClock(("plan", "points", "appearance", "pack"), progress)
    with clock("plan"):
        sampling = plan_point_sampling(box, part.bounds, options.fov_deg, options.resolution, options.max_error_px)
    clock.report("plan", 1, 1)
    # One-sided triangles whose back faces the whole cell are neither sampled nor drawn.
    seen = seen_from_cell(part.objects, box)
    if not seen:
        raise LayerPlanError("the part shows the view cell no front face: nothing to make a point impostor of")
    if all(faces is not None and faces.size == 0 for faces in map(faces_with_area, seen)):
        # Collinear corners only: the conservative LDIs would sample their segments, a full bake of nothing.
        raise LayerPlanError(
            "the part has no triangle of any area (every one's corners are collinear): nothing to make a point "
            "impostor of"
        )
    with clock("points"):
        samples = gather_point_samples(
            seen,
            sampling,
            box,
            options.fov_deg,
            options.resolution,
            options.max_layers,
            sufficient_only=options.sufficient_only,
        )
    clock.report("points", 1, 1)
    kept = samples.kept
    sample_stats = {k: v for k, v in samples.stats.items() if k != "per_camera"}
    ldi_layers = list(samples.layers)
    if options.visible_only:  # the points the cell's views need: only they reach the appearance's sums
        with clock("visibility"):
            shown = covering_points(
                seen, samples.positions[kept], box, options.fov_deg, options.resolution, options.cover_views
            )
        # None shown (no point in front of any view's window): all kept, as the appearance decides.  A
        # part too small for any view to resolve is still baked (its points keep their LDI colour), as
        # layered and octahedral bake it; a part with no area was refused above.
        if shown.any():
            kept = np.flatnonzero(kept)[shown]
    positions, preview = samples.positions[kept], samples.colour[kept]
    normals = None
    if wants_normals(options.channels):
        with clock("normals"):  # on the side the cell sees (core/ldi/normals.py)
            normals = sample_normals(seen, samples.obj[kept], samples.triangle[kept], positions, box.corners())
    material = emissive = None
    if keeps_material(options.channels, seen):
        with clock("material"):  # glTF's ORM bytes (and the emission where something emits) of each point
            material, emissive = sample_material(seen, samples.obj[kept], samples.triangle[kept], positions)
            emissive = emissive if any(emits(o) for o in seen) else None
    candidates = int(samples.kept.sum())  # not redundant
    del samples
    if positions.shape[0] == 0:
        raise LayerPlanError("the part has no surface the LDI cameras see: nothing to make a point impostor of")
    tile = (options.tile_u, options.tile_v)
    with clock("appearance"):
        appearance = integrate_appearance(
            seen, positions, preview, sampling, box, options.fov_deg, options.resolution, tile, options.samples,
            options.appearance_error, options.max_views, options.min_views, progress=lambda done, total: clock.report("appearance", done, total),
        )  # fmt: skip
    with clock("pack"):
        one = single_colour(appearance.tiles, options.single_colour)
        colour = np.where(appearance.seen[:, None], mean_colour(appearance.tiles), preview).astype(np.int64)
        textured = np.flatnonzero(~one)
        sizes, tile_page, tile_texel = pack_tiles(textured.size, tile, options.max_page)
        pages = [np.zeros((h, w, 4), np.uint8) for w, h in sizes]
        for p, (_w, _h) in enumerate(sizes):
            mine = np.flatnonzero(tile_page == p)
            x, y = tile_texel[mine, 0], tile_texel[mine, 1]
            rows = (y[:, None, None] + np.arange(options.tile_v)[None, :, None]) * np.ones(options.tile_u, np.int64)
            cols = (x[:, None, None] + np.arange(options.tile_u)[None, None, :]) * np.ones(
                (options.tile_v, 1), np.int64
            )
            pages[p][rows, cols] = appearance.tiles[textured[mine]]
        page = np.full(positions.shape[0], -1, np.int64)
        texel = np.zeros((positions.shape[0], 2), np.int64)
        page[textured], texel[textured] = tile_page, tile_texel
    clock.report("pack", 1, 1)
    payload = PointPayload(
        positions, colour, page, texel, np.array(tile), np.concatenate([sampling.normal, [sampling.offset]]),
        np.stack([sampling.u, sampling.v]), sampling.rectangle, normals,
    )  # fmt: skip
    if material is not None:  # the optional per-point material arrays (bytes, as the colour)
        payload = replace(payload, material=material.astype(np.int64),
                          emissive=emissive.astype(np.int64) if emissive is not None else None)  # fmt: skip
    n = positions.shape[0]
    geometry_bytes = n * POINT_BYTES + int(textured.size) * TILE_REFERENCE_BYTES
    texture_bytes = int(sum(w * h * 4 for w, h in sizes))
    channel_bytes = {}
    if normals is not None:  # memory per channel; the other figures (and a colour-only bake's stats) stay as they were
        channel_bytes = {"channel_bytes": {"albedo": geometry_bytes + texture_bytes, "normal": n * NORMAL_BYTES}}
        if material is not None:  # four bytes a point each
            channel_bytes["channel_bytes"]["material"] = n * 4
            if emissive is not None:
                channel_bytes["channel_bytes"]["emissive"] = n * 4
    stats = {
        **sample_stats,
        "points": n,
        "unseen_dropped": candidates - n,
        "ldi_resolution": [c.resolution for c in sampling.cameras],
        "ldi_layers": ldi_layers,
        "single_colour_share": float(one.mean()),
        "appearance": {k: v for k, v in appearance.stats.items() if k != "seconds"},
        "geometry_bytes": geometry_bytes,
        "texture_bytes": texture_bytes,
        "bytes_per_point": (geometry_bytes + texture_bytes) / n,
        "atlas_pages": len(pages),
        **channel_bytes,
        "seconds": clock.totals(),
    }
    return Impostor(
        technique="points",
        viewcell=box.to_dict(),
        reference_viewpoint=box.center,
        resolution=options.resolution,
        fov_deg=options.fov_deg,
        pages=tuple(pages),
        payload=payload,
        layers=[],
        stats=stats,
        parameters={
            **asdict(options),
            "objects": list(part.names),
            "scene_hash": scene.content_hash,
            "sampling": sampling.to_dict(),
        },
        code_version=__version__,
    )


def warm_kernels() -> float:
    """Compile (or load from numba's cache) the numba kernels of a point bake (the conservative
    LDI's merge, the sampling spacing, the points' cover) on tiny arrays, without GL; the seconds it took.  A render
    worker calls it when it starts, beside the TDM's (:mod:`farfield.workers.tasks`)."""
    start = time.perf_counter()
    depth = np.full((1, 2, 2), 1.0)
    keep = ldi_kernels._touched_kept(depth, depth + 1.0, 0.1)
    index, positions, colour = np.zeros((1, 2, 2), np.int64), np.zeros((1, 2, 2, 3)), np.zeros((1, 2, 2, 4), np.uint8)
    ldi_kernels._merge_kernel(
        depth, index, index, positions, colour, depth + 1.0, index, index, positions, colour, keep
    )
    _spacing_kernel(depth, positions, np.zeros((1, 2, 2), np.bool_), np.zeros(3), 1.0, 0.01, 4.0)
    _lookup_kernel(np.zeros(2, np.int64), np.ones(1), np.ones(1), np.zeros(1, np.int64), np.ones(1), np.ones(1))
    warm_cover()
    return time.perf_counter() - start


def _summary(stats: dict) -> str:
    a = stats["appearance"]
    return (
        f"points: {stats['points']:,} of {stats['candidates']:,} LDI samples (redundant {100 * stats['removed_share']:.1f} %, "
        f"never visible {stats['unseen_dropped']:,})  "
        f"LDIs: {'/'.join(str(r) for r in stats['ldi_resolution'])} px, {'/'.join(str(n) for n in stats['ldi_layers'])} layers\n"
        f"appearance: {a['views']} views (standard error p95 {a['standard_error_p95'] if a['standard_error_p95'] is None else round(a['standard_error_p95'], 4)})  "
        f"one colour: {100 * stats['single_colour_share']:.1f} %  {stats['bytes_per_point']:.1f} B/point  "
        f"texture: {stats['texture_bytes'] / 1024:.1f} KiB  geometry: {stats['geometry_bytes'] / 1024:.1f} KiB\n"
        + seconds_line(stats)
    )


def _evaluation_text(result: Evaluation, impostor: Impostor) -> str:
    text = part_evaluation_text(result, impostor)
    return (
        text + f"\npoints: {impostor.payload.count:,} ({impostor.stats.get('bytes_per_point', math.nan):.1f} B/point)"
    )


TECHNIQUE = TechniqueDefinition(
    name="points",
    payload_kind=PointPayload.kind,
    kernels=(warm_kernels,),
    scope="part",
    help="point-based impostors of a scene's objects for a box view cell: LDI points with directional colours (seed 001)",
    Options=PointOptions,
    check=check_points_cell,
    bake=bake_points,
    summary=_summary,
    evaluate=evaluate_part,
    evaluation_text=_evaluation_text,
    promise=Promise(
        "no hole pixel from anywhere in the box view cell: no sample spacing looks larger than max_error_px (default 1)",
        holes=True,
    ),
)

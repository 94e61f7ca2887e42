"""Textured depth meshes (seed 003; seed 000 ch. 4): a scene part and a view cell in, an
:class:`~farfield.core.impostor.impostor.Impostor` of textured triangles out.

plan layers (seed 000 §3.3.1, as for layered impostors) -> record and cull them into a voxel field
(:mod:`farfield.core.techniques.tdm.voxel_field`, seed 003 §4) -> initial covering mesh (:mod:`farfield.core.techniques.tdm.mesh`, §5) ->
voxel-covering simplification (:mod:`farfield.core.techniques.tdm.simplify`, §6) -> charts of edge-connected triangles
(:mod:`farfield.core.techniques.tdm.texture`), their needed texels packed as masks onto atlas pages
(:mod:`farfield.core.techniques.tdm.mask_atlas`) and resampled from the field (§7) -> vertices reprojected to world space
(§8).

**The simplification schedule.**  The enlargement factor f sizes the voxel boxes the mesh must keep
meeting (seed 003 §6: "increasing the size of a voxel results in more simplified, but slightly less
accurate meshes").  A single greedy pass at a large f is not monotone: measured on a box building,
f = 3 left 69 triangles where f = 2 left 28, because long early contractions leave slivers that
then block each other.  farfield therefore simplifies in a cascade over the factors of
:data:`SCHEDULE` below f, then f itself: each pass starts from the previous result, which still
covers every voxel at the larger boxes, and contractions only ever remove triangles.  So for any
two factors on the schedule, the larger never gives more triangles (the monotone trade the knob
promises), and a factor between two steps is at least as simple as the step below it (on a mesh
small enough to be simplified whole: see :func:`simplify_mesh` for a large one's strips).  Each pass
is repeated until it contracts nothing more: an edge that failed is only tried again when a
contraction next to it pushes it again, so a second pass at the same factor still finds some
(measured on the house at 90 m, 512 px, when this was added: 1,946 instead of 2,175 triangles at
f = 1, 629 instead of 660 at f = 2, for a few hundredths of a second).

**Triangles in an Impostor.**  A TDM's payload is a :class:`~farfield.core.impostor.impostor.MeshPayload`: the
indexed triangles, a vertex per (position, chart UV) pair, and per triangle its atlas page and its
mesh (connected component).
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import asdict, dataclass

import numpy as np

from farfield.core import __version__
from farfield.core.errors import InternalError
from farfield.core.impostor.depth import refuse_depth
from farfield.core.impostor.impostor import (
    CHANNELS_HELP,
    ChannelSet,
    Impostor,
    MeshPayload,
    keeps_material,
    wants_normals,
)
from farfield.core.layering import recording
from farfield.core.layering.atlas import MAX_PAGE
from farfield.core.layering.culling import CullingMode
from farfield.core.layering.plan import plan_layers
from farfield.core.layering.tiles import layer_records, split_channels
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
from farfield.core.techniques.tdm.mask_atlas import pack_masks
from farfield.core.techniques.tdm.mesh import TdmMesh, ear_clip, initial_mesh, mesh_labels
from farfield.core.techniques.tdm.simplify import STRIP_MIN_TRIANGLES, box_half_sizes, covered_by, simplify, strip_pass
from farfield.core.techniques.tdm.texture import build_charts, chart_colours, chart_masks, chart_pages, chart_uvs
from farfield.core.techniques.tdm.voxel_field import VoxelField, record_voxel_field
from farfield.core.viewcells import BoxCell, ViewCell


@dataclass(frozen=True, slots=True)
class TdmOptions:
    """The knobs of a TDM bake (all recorded in the impostor's parameters)."""

    resolution: int = option(512, "output image pixels per side", ge=1, le=MAX_RESOLUTION)
    fov_deg: float = option(45.0, "output field of view, degrees", gt=0.0, lt=180.0)
    enlargement: float = option(
        2.0,
        "voxel enlargement factor of the covering test (seed 003 §6): larger, fewer polygons, less accurate",
        ge=1.0,
        le=8.0,
    )
    oversampling: int = option(1, "nearest voxels averaged per texel (seed 003 §7)", ge=1, le=64)
    culling: CullingMode = option("penumbra", "hidden-texel culling of the recorded layers: penumbra, umbra or off")
    max_error_px: float = option(
        1.0,
        "error budget of the recorded layers, output pixels (their texel size and depth ranges)",
        gt=0.0,
        le=MAX_ERROR_PX,
    )
    budget: ErrorBudgetKind = option(
        "strict", "strict (max_error_px from the smallest pixel angle) or thesis (seed 000 §3.3, the centre pixel)"
    )
    pixel_model: PixelModel = option(
        "min",
        "expert: error bound from the smallest pixel angle (min) or the centre pixel (center); strict budget only",
    )
    padding: int = option(2, "atlas padding between charts, texels", ge=0, le=64)
    max_page: int = option(
        MAX_PAGE,
        "largest atlas page side, texels (WebGL2 guarantees 2048, many mobile GPUs stop at 4096)",
        ge=64,
        le=16384,
    )
    texel_margin: int = option(
        1, "texels around each chart's triangles, for bilinear filtering (seed 003 §7)", ge=0, le=8
    )
    channels: ChannelSet = option(
        "albedo",
        CHANNELS_HELP,
    )

    def __post_init__(self) -> None:
        check_options(self)
        refuse_depth("tdm", self.channels)  # its geometry is exact (farfield.core.impostor.depth)


# The cascade of enlargement factors (see the module docstring).
SCHEDULE = (1.0, 1.25, 1.5, 1.75, 2.0, 2.5, 3.0, 4.0, 6.0, 8.0)

# Bytes of the TDM as drawn, an indexed mesh: one vertex of (3 position + 2 uv) float32 per distinct
# (mesh vertex, texture chart) pair (triangles of one chart share their vertices and uvs, a vertex
# on a chart border is stored once per chart), and 3 uint32 indices per triangle.
VERTEX_BYTES = 5 * 4
INDEX_BYTES = 4


def geometry_bytes(triangles: np.ndarray, chart: np.ndarray) -> int:
    """Bytes of the indexed mesh of ``triangles`` (t, 3) whose texture charts are ``chart`` (t,).

    >>> geometry_bytes(np.array([[0, 1, 2], [0, 2, 3]]), np.array([0, 0])), geometry_bytes(np.array([[0, 1, 2], [0, 2, 3]]), np.array([0, 1]))
    (104, 144)
    """
    triangles = np.asarray(triangles, dtype=np.int64)
    pairs = np.stack([triangles.reshape(-1), np.repeat(np.asarray(chart, dtype=np.int64), 3)], axis=1)
    vertices = np.unique(pairs, axis=0).shape[0] if pairs.size else 0
    return int(vertices * VERTEX_BYTES + triangles.size * INDEX_BYTES)


def schedule(enlargement: float) -> tuple[float, ...]:
    """The factors the cascade runs for ``enlargement``: the schedule's steps below it, then it.

    >>> schedule(2.0), schedule(1.0), schedule(2.2)
    ((1.0, 1.25, 1.5, 1.75, 2.0), (1.0,), (1.0, 1.25, 1.5, 1.75, 2.0, 2.2))
    """
    steps = tuple(f for f in SCHEDULE if f < enlargement - 1e-12)
    return steps + (float(enlargement),)


def _kept_vertices(triangles, vertices, original, memory, below: float = 1.0):
    """The mesh on the vertices its ``triangles`` use, renumbered in their order (the same edges in
    the same order, so the same passes): (triangles, vertices, their numbers in the initial mesh
    ``original``, ``memory`` renumbered).  Left as it is when the vertices used are ``below`` that
    share of all or more.

    >>> from farfield.core.techniques.tdm.simplify import PassMemory
    >>> t, v, o, m = _kept_vertices(np.array([[1, 3, 4]]), np.zeros((5, 3)), np.arange(5), PassMemory.empty(5, 1.0))
    >>> t.tolist(), v.shape, o.tolist(), len(m.touch_time)
    ([[0, 1, 2]], (3, 3), [1, 3, 4], 3)
    """
    kept = np.flatnonzero(np.bincount(triangles.ravel(), minlength=len(vertices)))
    if kept.size >= below * len(vertices):
        return triangles, vertices, original, memory
    number = np.zeros(len(vertices), np.int64)
    number[kept] = np.arange(kept.size)
    return number[triangles], vertices[kept], original[kept], memory.renumbered(kept)


def simplify_mesh(
    mesh: TdmMesh,
    field: VoxelField,
    enlargement: float,
    silhouette: np.ndarray | None = None,
    strip_min: int = STRIP_MIN_TRIANGLES,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict]:
    """The cascade of :func:`farfield.core.techniques.tdm.simplify.simplify` passes for ``enlargement``, each repeated
    until it changes nothing: (triangles, voxel offsets, voxels, outcome counts summed over every
    pass, repeats included).  ``silhouette``: the field's
    :attr:`~farfield.core.techniques.tdm.voxel_field.VoxelField.silhouette`, if the caller has it already.
    A mesh of ``strip_min`` triangles or more first runs the whole cascade inside strips, in
    threads (:func:`~farfield.core.techniques.tdm.simplify.strip_pass`), then only the last factor's
    passes on the whole mesh: the strips' borders, which they leave locked, go straight to that
    factor.  So on such a mesh a larger factor keeps fewer triangles as a rule, not by construction
    (the strips' later steps are a prefix of the larger factor's, the border's passes are not)."""
    triangles, offsets, voxels = mesh.triangles, mesh.voxel_offsets, mesh.voxels
    vertices, original = mesh.vertices, np.arange(len(mesh.vertices), dtype=np.int64)
    centres = field.centres
    silhouette = field.silhouette if silhouette is None else silhouette
    totals: dict[str, int] = {}
    memory = None  # each pass skips the edges that would fail again (farfield.core.techniques.tdm.simplify.simplify)
    steps = schedule(enlargement)
    if triangles.shape[0] >= strip_min:
        # The cascade inside strips of the mesh, two at a time on two cores; the last factor's
        # passes below take the borders and skip the strips' failures (see strip_pass).  On the
        # scan of benchmarks/bench_tdm_scale.py (8.8 M initial triangles), against the first pass
        # alone in strips: the same CPU, the critical path 29.7 -> 22.5 s, and 0.8 % fewer
        # triangles, a 1.4 % smaller atlas page (docs/measurements/tdm.md).
        triangles, offsets, voxels, totals, memory = strip_pass(
            vertices, triangles, offsets, voxels, centres, steps, silhouette
        )
        triangles, vertices, original, memory = _kept_vertices(triangles, vertices, original, memory)
        steps = steps[-1:]
    for factor in steps:
        while True:
            before = triangles.shape[0]
            triangles, offsets, voxels, counts, memory = simplify(
                vertices, triangles, offsets, voxels, centres, factor, silhouette, memory
            )
            for key, value in counts.items():
                totals[key] = totals.get(key, 0) + value
            if triangles.shape[0] == before:
                break
            # The next passes read only the vertices left, renumbered in their order: the same
            # edges in the same order, so the same mesh, from arrays a fraction of the size (the
            # first pass of the 327,680-triangle sphere of benchmarks/bench_tdm_scale.py keeps
            # 7 % of its 1.9 M vertices; its later passes took 24-26 s instead of 26-27 s).
            triangles, vertices, original, memory = _kept_vertices(triangles, vertices, original, memory, 0.75)
    return original[triangles], offsets, voxels, totals


def uncovered_voxels(
    vertices: np.ndarray,
    triangles: np.ndarray,
    offsets: np.ndarray,
    voxels: np.ndarray,
    field: VoxelField,
    enlargement: float,
    silhouette: np.ndarray | None = None,
) -> int:
    """Voxels of ``field`` that no triangle stores, or whose storing triangle misses its box
    enlarged by ``enlargement`` (0 after a correct simplification); ``silhouette`` as for
    :func:`simplify_mesh`."""
    owner = np.repeat(np.arange(triangles.shape[0]), np.diff(offsets))
    silhouette = field.silhouette if silhouette is None else silhouette
    hits = covered_by(
        vertices, triangles, owner, field.centres, box_half_sizes(field.count, enlargement, silhouette), voxels
    )
    stored = np.zeros(field.count, dtype=bool)
    stored[voxels[hits]] = True
    return int(field.count - stored.sum())


def mesh_field(field: VoxelField, options: TdmOptions, clock: StageClock) -> tuple:
    """The textured mesh of a recorded ``field`` (stages ``mesh`` to ``texture`` on ``clock``):
    (world triangle corners (t, 3, 3), their uvs, page and mesh per triangle, the atlas pages, the
    pages of the other channels the field keeps (``{"normal": pages}`` parallel to the colour
    pages, or none), and the stats of those stages)."""
    with clock("mesh"):
        mesh = initial_mesh(field)
    clock.report("mesh", 1, 1)

    with clock("simplify"):
        silhouette = field.silhouette
        triangles, offsets, voxels, outcomes = simplify_mesh(mesh, field, options.enlargement, silhouette)
    clock.report("simplify", 1, 1)
    uncovered = uncovered_voxels(mesh.vertices, triangles, offsets, voxels, field, options.enlargement, silhouette)
    if uncovered:
        raise InternalError(f"{uncovered} voxels left uncovered by the simplified mesh (it must cover every voxel)")

    with clock("charts"):
        used, compact = np.unique(triangles, return_inverse=True)
        triangles = compact.reshape(-1, 3)
        voxel_space = mesh.vertices[used]
        world = field.to_world(voxel_space)
        corners = world[triangles]  # (t, 3, 3)
        charts = build_charts(voxel_space, triangles, options.texel_margin)
        masks = chart_masks(charts)
    clock.report("charts", 1, 1)

    # The texels' colours do not depend on the layout: a thread samples them while the packer
    # runs (its widths, on two threads, leave a core idle for about one width's time; the
    # sampling is about 2 s of CPU on the scan of benchmarks/bench_tdm_scale.py).
    with ThreadPoolExecutor(max_workers=1) as pool:
        colours = pool.submit(chart_colours, field, corners, charts, options.oversampling)
        with clock("atlas"):
            layout = pack_masks(masks, options.padding, options.max_page)
        clock.report("atlas", 1, 1)

        with clock("texture"):
            colours = colours.result()
            pages, channels = split_channels(
                tuple(chart_pages(field, corners, charts, layout, options.oversampling, colours))
            )
            uv = chart_uvs(charts, layout)
            triangle_page = layout.page[charts.chart]
        clock.report("texture", 1, 1)

    meshes = mesh_labels(len(used), triangles)
    count = triangles.shape[0]
    texture_bytes = int(sum(p.shape[0] * p.shape[1] * 4 for p in pages))
    stats = {
        **mesh.stats,
        "triangles": int(count),
        "vertices": len(used),
        "meshes": int(meshes.max(initial=-1) + 1),
        "quads": int(count),
        "contractions": outcomes,
        "voxels_uncovered": uncovered,
        "texture_bytes": texture_bytes,
        "texture_bytes_tile_area": 4 * int(charts.texel_chart.size),  # the charts' needed texels
        "geometry_bytes": geometry_bytes(triangles, charts.chart),
        "atlas_pages": len(pages),
        "texture_charts": charts.count,
    }
    if channels:  # memory per channel; a colour-only bake's stats stay as they were
        stats["channel_bytes"] = {"albedo": texture_bytes} | {
            name: int(sum(p.nbytes for p in channel)) for name, channel in channels.items()
        }
    return corners, uv, triangle_page, meshes, tuple(pages), channels, stats


def warm_kernels() -> float:
    """Compile (or load from numba's cache) every numba kernel a TDM bake runs, by meshing a small
    synthetic voxel field (a tilted slab: steps, boundaries, several charts) the way a bake does;
    no GL.  Returns the seconds it took.  A render worker calls it when it starts
    (:mod:`farfield.workers.tasks`), so its first cell does not pay the compilation (some 35 s on a 2-core
    machine with an empty cache, 0.4 s to load a filled one)."""
    start = time.perf_counter()
    plan = plan_layers(
        BoxCell(np.array([-0.5, -0.5, -4.0]), np.array([0.5, 0.5, -3.0])),
        np.array([[-1.0, -1.0, 0.0], [1.0, 1.0, 1.0]]),
        math.radians(45.0),
        64,
        "min",
    )
    res_x, res_y = (int(r) for r in plan.texture_resolution)
    y, x = np.mgrid[res_y // 4 : 3 * res_y // 4, res_x // 4 : 3 * res_x // 4]
    layer = np.minimum((x - x.min()) * plan.count // (2 * max(int(np.ptp(x)), 1)), plan.count - 1)
    key = np.argsort((layer * res_y + y) * res_x + x, axis=None)
    rgba = np.full((key.size, 4), 255, np.uint8)
    field = VoxelField(
        plan,
        x.ravel()[key].astype(np.int64),
        y.ravel()[key].astype(np.int64),
        layer.ravel()[key].astype(np.int64),
        rgba,
        {},
    )
    mesh_field(field, TdmOptions(resolution=64), StageClock(()))
    # The slit closing's ear clipping, which the slab has no slit to need: a square loop.
    ear_clip(np.arange(4), np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]]), np.array([1], np.int64), 4)
    return time.perf_counter() - start


def bake_tdm(
    scene: Scene,
    cell: ViewCell,
    options: TdmOptions = TdmOptions(),
    objects: list[str] | None = None,
    progress: Progress | None = None,
) -> Impostor:
    """Bake the textured depth mesh of ``scene`` (or of its ``objects``) for ``cell``.

    Same contract as :func:`farfield.core.techniques.layered.bake_layered`; technique ``"tdm"``.
    """
    part = scene.subset(objects) if objects else scene
    clock = StageClock(("plan",), progress)

    with clock("plan"):
        plan = plan_layers(
            cell, part.bounds, math.radians(options.fov_deg), options.resolution, **layer_budget(options)
        )
    clock.report("plan", 1, 1)

    seen = seen_from_cell(part.objects, cell)
    field = record_voxel_field(
        seen, plan, options.culling, clock, wants_normals(options.channels), keeps_material(options.channels, seen)
    )
    corners, uv, triangle_page, meshes, pages, channels, stats = mesh_field(field, options, clock)
    stats = {
        "layers_planned": plan.count,
        "layers": field.stats["layers"],
        "voxels": field.count,
        "texels_covered": field.stats["texels_covered"],
        "texels_culled": field.stats["texels_culled"],
        "triangles_drawn": field.stats["triangles_drawn"],
        **stats,
        "texture_resolution": [int(r) for r in plan.texture_resolution],
        "seconds": clock.totals(),
    }
    layers = layer_records(plan, *np.unique(field.layer, return_counts=True))
    return Impostor(
        technique="tdm",
        viewcell=cell.to_dict(),
        reference_viewpoint=plan.reference_viewpoint,
        resolution=options.resolution,
        fov_deg=options.fov_deg,
        pages=pages,
        payload=MeshPayload.from_triangle_corners(corners, uv, page=triangle_page, mesh=meshes),
        layers=layers,
        stats=stats,
        parameters={
            **asdict(options),
            "schedule": list(schedule(options.enlargement)),
            "objects": list(part.names),
            "scene_hash": scene.content_hash,
            "plan": plan.to_dict(),
        },
        code_version=__version__,
        channels=channels,
    )


def _summary(stats: dict) -> str:
    return (
        f"layers: {stats['layers']} (planned {stats['layers_planned']})  voxels: {stats['voxels']}  "
        f"triangles: {stats['initial_triangles']} -> {stats['triangles']}  meshes: {stats['meshes']}\n"
        f"texture: {stats['texture_bytes'] / 1024:.1f} KiB  geometry: {stats['geometry_bytes'] / 1024:.1f} KiB  "
        f"atlas pages: {stats['atlas_pages']}\n" + seconds_line(stats)
    )


TECHNIQUE = TechniqueDefinition(
    name="tdm",
    payload_kind=MeshPayload.kind,
    kernels=(recording.warm_kernels, warm_kernels),
    scope="part",
    help="textured depth meshes of a scene's objects for any view cell (seed 003; planned like layered)",
    Options=TdmOptions,
    check=check_part_cell,
    bound=bound_part_cells,
    estimate=estimate_part_cell,
    bake=bake_tdm,
    summary=_summary,
    evaluate=evaluate_part,
    evaluation_text=part_evaluation_text,
    promise=Promise(
        "no hole pixel from anywhere in the view cell at max_error_px (default 1); the simplified mesh may stray up to "
        "(enlargement - 1) / 2 voxels beyond the part, so bloat is not bounded",
        holes=True,
    ),
)

"""Layered environment-map impostors: a scene and a cubic view cell in, an ``envmap`` :class:`~farfield.core.impostor.impostor.Impostor` out.

Seed 002 (Jeschke, Wimmer, Schumann, GI 2002), per cubic view cell:

1. layer cubes and the near-field cube from Eqs. 1-2 (:func:`farfield.core.techniques.envmap.arrangement.envmap_plan`),
   given the number of layers or the near-field distance (§4.2, §4.3), recorded from the cell's
   centre (the reference viewpoint, §4.1);
2. every chosen cube face (six, or a subset such as the four horizontal ones of §6) records its
   layers with farfield's gap-free slab recording (seed 000 §3.3.2, :mod:`farfield.core.layering.recording`): a
   90-degree frustum through the face, each layer clipped to the depth slab between its two border
   cubes.  Inside a face's frustum the distance along the face axis *is* the cube distance, so the
   slab clip is the cube-border clip, and the innermost slab starts exactly at the near-field cube
   (:mod:`farfield.core.techniques.envmap.near_field` lists the triangles inside it for the runtime);
3. compression (§5): gap filling (§5.1, :mod:`farfield.core.techniques.envmap.gap_fill`), invisible-texel removal (§5.2 with
   the penumbra improvement of seed 000 §3.4.1, :mod:`farfield.core.layering.culling`), microtextures by greedy
   rectangle growing on an 8x8 grid (§5.3, :func:`farfield.core.layering.quads.grow_quads`), macrotexture packing
   (§5.4, :func:`farfield.core.layering.atlas.pack`) and PNG (§5.4, last paragraph);
4. the cell's output: quads and atlas pages for all faces, the near-field list, and the three byte
   counts of seed 002 Table 2 (raw layers, macrotextures, PNG).

With ``channels=albedo+normal`` every face records the world shading normal of the point each
texel shows beside its colour (:func:`farfield.core.layering.recording.pair_normals`, double-sided back
faces reversed towards the cell centre); gap filling copies a texel's normal with its colour, and
the normals become a second set of atlas pages parallel to the colour pages (``channels`` of the
impostor), which the GLB turns into lit materials with tangent-space normal textures.  The colour
bytes are those of a colour-only bake.

Layers are streamed face by face: memory grows with the kept texels, not with faces x layers x
image.  Macrotexture packing uses farfield's seed 000 §3.6 packer, the thesis's refinement of
§5.4 (same sort by decreasing height, power-of-two pages, lowest-position placement; it spills
onto a further page instead of leaving a page half empty).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field

import numpy as np

from farfield.core import __version__
from farfield.core.cube_faces import FACES
from farfield.core.errors import LayerPlanError, ViewCellError
from farfield.core.impostor.depth import fill_gaps_with_depth, layer_depth_ranges
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
from farfield.core.impostor.png_pages import PagePngs
from farfield.core.layering import recording
from farfield.core.layering.atlas import MAX_PAGE
from farfield.core.layering.culled import culled_layers
from farfield.core.layering.culling import CullingMode
from farfield.core.layering.tiles import QUAD_GEOMETRY_BYTES, check_pages, layer_tiles, pack_tiles, split_channels
from farfield.core.options import check_options, option
from farfield.core.pixel_angles import MAX_ERROR_PX, MAX_RESOLUTION, pixel_angle
from farfield.core.scene import Scene
from farfield.core.sidedness import seen_from_cell
from farfield.core.stage_clock import Progress, StageClock, seconds_line
from farfield.core.techniques.base import CellCost, Promise, TechniqueDefinition
from farfield.core.techniques.envmap.arrangement import EnvmapPlan, envmap_plan, layers_for_near_field
from farfield.core.techniques.envmap.gap_fill import fill_gaps
from farfield.core.techniques.envmap.lit import evaluate_envmap_lit
from farfield.core.techniques.envmap.near_field import near_field
from farfield.core.techniques.envmap.runtime import EnvmapCellRenderer, evaluate_envmap
from farfield.core.viewcells import BoxCell

# Cube faces (farfield.core.cube_faces.FACES): image x and y run along the next two world axes, so a face's
# frustum square is the cube face itself.


# A cube may differ from a cube by this relative amount (grids of equal cells, float64 division).
CUBE_TOLERANCE = 1e-9


DEFAULT_LAYERS = 64


@dataclass(frozen=True, slots=True)
class EnvmapOptions:
    """The knobs of an environment-map bake (all recorded in the impostor's parameters).

    ``layers`` or ``near_field`` (not both) sets the arrangement: the number of layers, or the
    largest acceptable near-field distance from the cell centre (the fewest layers that reach it).
    ``face_resolution`` is seed 002's Res, texels per cube-face side; by default the one whose
    texel at the face centre is as wide as an output pixel at the image centre,
    ``ceil(resolution / tan(fov / 2))`` (= ``resolution`` at the paper's 90 degrees).
    """

    resolution: int = option(512, "output image pixels per side", ge=1, le=MAX_RESOLUTION)
    fov_deg: float = option(90.0, "output field of view, degrees (the paper's 90)", gt=0.0, lt=180.0)
    layers: int | None = option(
        None,
        f"number of layers (seed 002 Eqs. 1-2), default {DEFAULT_LAYERS} unless near_field is given; more bring the near field closer for more memory",
        ge=1,
        le=4096,
    )
    near_field: float | None = option(
        None,
        "largest acceptable near-field distance from the cell centre, scene units: the fewest layers that reach it (instead of layers)",
        gt=0.0,
    )
    directions: tuple[str, ...] = option(
        tuple(FACES),
        "cube faces that get layers, e.g. +x,-x,+z,-z (the others are drawn as geometry)",
        choices=tuple(FACES),
    )
    face_resolution: int | None = option(
        None,
        "texels per cube-face side (seed 002 Res); default ceil(resolution / tan(fov / 2))",
        ge=1,
        le=MAX_RESOLUTION,
    )
    max_error_px: float = option(
        1.0,
        "error budget, output pixels: the parallax the layers may show from anywhere in the cell",
        gt=0.0,
        le=MAX_ERROR_PX,
    )
    gap_fill: bool = option(False, "seed 002 §5.1 gap filling (off: the conservative recording leaves no gap to fill)")
    culling: CullingMode = option(
        "penumbra", "invisible-texel removal: penumbra (§5.2 + seed 000 §3.4.1), umbra (§5.2) or off"
    )
    # The paper's grid is 8 (§5.3); at 4 the city walkthrough's nine cells keep 18 % less texture
    # for 12 % more quads, and the runtime rasterises less empty quad area (README, "The runtime's
    # frame, second round").
    grid_cell: int = option(4, "microtexture grid (§5.3; the paper's 8), texels", ge=1, le=1024)
    fill_threshold: float = option(0.8, "microtexture fill ratio (§5.3)", gt=0.0, le=1.0)
    padding: int = option(2, "atlas padding, texels", ge=0, le=64)
    channels: ChannelSet = option(
        "albedo",
        CHANNELS_HELP,
    )
    max_page: int = option(
        MAX_PAGE,
        "largest atlas page side, texels (WebGL2 guarantees 2048, many mobile GPUs stop at 4096), a power of two",
        ge=64,
        le=16384,
    )
    conservative: bool = option(True, "gap-free recording; false only to demonstrate the holes", internal=True)

    def __post_init__(self) -> None:
        check_options(self)
        check_pages(self.max_page, self.padding)
        if self.layers is None and self.near_field is None:
            object.__setattr__(self, "layers", DEFAULT_LAYERS)
        if self.layers is not None and self.near_field is not None:
            raise LayerPlanError("give exactly one of 'layers' or 'near_field' for an envmap impostor")
        directions = tuple(self.directions)
        if not directions or len(set(directions)) != len(directions):
            raise LayerPlanError(f"directions must be distinct cube faces out of {list(FACES)}, got {list(directions)}")
        object.__setattr__(self, "directions", tuple(d for d in FACES if d in directions))  # canonical order

    @property
    def texels_per_face(self) -> int:
        """Seed 002's Res."""
        if self.face_resolution is not None:
            return int(self.face_resolution)
        return int(math.ceil(self.resolution / (self.max_error_px * math.tan(0.5 * math.radians(self.fov_deg))) - 1e-9))

    @property
    def alpha(self) -> float:
        """The parallax angle: ``max_error_px`` times the smallest angle of an output pixel (seed 002 §4.3)."""
        return self.max_error_px * pixel_angle(math.radians(self.fov_deg), self.resolution, "min")


def cubic_cell_size(cell: BoxCell) -> float:
    """The side of a cubic view cell; raises for a box that is not a cube or a shaft."""
    if not isinstance(cell, BoxCell):
        raise ViewCellError("environment-map impostors need a cubic box view cell")
    size = cell.size
    if float(size.max() - size.min()) > CUBE_TOLERANCE * float(size.max()):
        raise ViewCellError(f"environment-map impostors need a cubic view cell, got sides {size.tolist()}")
    return float(size.mean())


def plan_envmap(cell: BoxCell, options: EnvmapOptions) -> EnvmapPlan:
    """The seed 002 §4.2 arrangement for ``cell`` and ``options``."""
    size = cubic_cell_size(cell)
    res = options.texels_per_face
    layers = options.layers
    if layers is None:
        layers = layers_for_near_field(size, res, float(options.near_field), options.alpha)
    return envmap_plan(size, res, int(layers), options.alpha)


@dataclass(frozen=True, slots=True)
class FacePlan:
    """One cube face's layers in the form :func:`farfield.core.layering.recording.iter_layers` records.

    Distances are eye depths along the face axis from the reference viewpoint (``reference_offset``
    is 0); the last border is the scene's farthest extent along the axis, standing in for infinity.
    """

    name: str
    distances: np.ndarray  # (k,) float64
    borders: np.ndarray  # (k + 1,) float64, finite, ascending
    reference_viewpoint: np.ndarray  # (3,) float64 world
    axis: np.ndarray  # (3,)
    u: np.ndarray  # (3,) image x
    v: np.ndarray  # (3,) image y
    texture_resolution: np.ndarray  # (2,) int64
    reference_offset: float = 0.0
    frustum_half_tangents: np.ndarray = field(default_factory=lambda: np.ones(2))

    @property
    def count(self) -> int:
        return int(self.distances.shape[0])


def face_plan(name: str, plan: EnvmapPlan, centre: np.ndarray, scene_bounds: np.ndarray) -> FacePlan | None:
    """The recording plan of face ``name``; None when no geometry lies beyond the near field there."""
    index, sign = FACES[name]
    eye = np.eye(3)
    axis = sign * eye[index]
    u, v = eye[(index + 1) % 3], sign * eye[(index + 2) % 3]
    reach = float(np.max(sign * (np.asarray(scene_bounds)[:, index] - centre[index])))
    if not reach >= plan.near_field:
        return None
    borders = plan.borders.copy()
    # The outer border (infinity) becomes the farthest geometry, a little beyond: slab borders must
    # be finite for the recording, and nothing lies farther.
    finite = borders[-2]
    borders[-1] = max(reach, finite) * (1.0 + 1e-6) + 1e-9 * max(abs(reach), 1.0)
    res = np.array([plan.resolution, plan.resolution], dtype=np.int64)
    return FacePlan(name, plan.distances.copy(), borders, np.asarray(centre, dtype=np.float64), axis, u, v, res)


def bake_envmap(
    scene: Scene, cell: BoxCell, options: EnvmapOptions = EnvmapOptions(), progress: Progress | None = None
) -> Impostor:
    """Bake the layered environment-map impostor of ``scene`` for the cubic ``cell``."""
    clock = StageClock(("plan", "record", "gap_fill", "cull", "quads", "atlas", "png"), progress)
    with clock("plan"):
        plan = plan_envmap(cell, options)
        if all(faces is not None and faces.size == 0 for faces in map(recording.faces_with_area, scene.objects)):
            # Collinear corners only (points and lines are no triangles at all): no layer, no near field to draw.
            raise LayerPlanError(
                "the scene has no triangle of any area (every one's corners are collinear): nothing to make an "
                "envmap impostor of"
            )
        centre = cell.center
        near = near_field(scene, centre, plan.near_field, [f for f in FACES if f not in options.directions])
        faces = [face_plan(name, plan, centre, scene.bounds) for name in options.directions]
        # One-sided triangles whose back faces the whole cell are not recorded; the near field
        # (drawn per camera by the runtime) keeps its face indices of the scene.
        seen = seen_from_cell(scene.objects, cell)
    clock.report("plan", 1, 1)

    res = plan.resolution
    normals = wants_normals(options.channels)
    depth = wants_depth(options.channels)
    depth_ranges = []  # per quad, ray scales of its slab (farfield.core.impostor.depth), with depth
    material = keeps_material(options.channels, seen)
    total_layers = len(options.directions) * plan.count
    tiles, quad_layer, quad_corners, layers = [], [], [], []
    counts = {"covered": 0, "culled": 0, "kept": 0, "drawn": 0, "gap_filled": 0}
    done = 0
    for face_index, face in enumerate(faces):
        if face is None:
            done += plan.count
            clock.report("record", done, total_layers)
            continue
        fill = (fill_gaps_with_depth if depth else fill_gaps) if options.gap_fill else None
        layers_of_face = culled_layers(
            seen,
            face,
            options.culling,
            clock,
            options.conservative,
            fill,
            normals=normals,
            depth=depth,
            material=material,
        )
        for layer in layers_of_face:
            i = layer.index
            done += 1
            counts["drawn"] += layer.drawn
            counts["gap_filled"] += layer.filled
            counts["covered"] += layer.covered
            counts["culled"] += layer.culled
            clock.report("record", done, total_layers)
            if not layer.kept.any():
                continue
            with clock("quads"):
                rects, face_tiles = layer_tiles(
                    layer.image,
                    layer.kept,
                    options.grid_cell,
                    options.fill_threshold,
                    options.max_page,
                    options.padding,
                )
                tiles += face_tiles
                layer_id = face_index * plan.count + i
                quad_layer.append(np.full(len(rects), layer_id, dtype=np.int64))
                quad_corners.append(texel_rect_corners(face, float(face.distances[i]), rects))
                depth_ranges.append(layer_depth_ranges(face, i, len(rects)))
                kept_count = int(layer.kept.sum())
                counts["kept"] += kept_count
                layers.append(
                    {
                        "index": layer_id,
                        "face": face.name,
                        "layer": int(i),
                        "distance": float(plan.distances[i]),
                        "depth_range": [
                            float(plan.borders[i]),
                            float(plan.borders[i + 1]) if math.isfinite(plan.borders[i + 1]) else None,
                        ],
                        "texels": kept_count,
                        "quads": int(len(rects)),
                    }
                )
    clock.report("record", total_layers, total_layers)

    with clock("atlas"):
        pages, quad_uv, quad_page, tile_bytes = pack_tiles(
            tiles, options.padding, options.max_page
        )  # none: all is near field
        pages, channels = split_channels(pages)
    with clock("png"):
        # the pages side by side; remembered, so that writing the bundle does not encode them again
        png_bytes = int(sum(map(len, PagePngs(remember=True).encode(pages))))
    clock.report("atlas", 1, 1)

    quad_count = len(tiles)
    texture_bytes = int(sum(p.shape[0] * p.shape[1] * 4 for p in pages))
    stats = {
        "layers_planned": plan.count,
        "faces": len(options.directions),
        "layers": len(layers),
        "quads": quad_count,
        "near_field": plan.near_field,
        "near_field_triangles": near.triangle_count,
        "texels_covered": counts["covered"],
        "texels_culled": counts["culled"],
        "texels_kept": counts["kept"],
        "texels_gap_filled": counts["gap_filled"],
        "triangles_drawn": counts["drawn"],
        # Seed 002 Table 2: raw layers -> macrotextures -> PNG.
        "raw_layer_bytes": int(len(options.directions) * plan.count * res * res * 4),
        "texture_bytes_tile_area": tile_bytes,
        "texture_bytes": texture_bytes,
        "png_bytes": png_bytes,
        "geometry_bytes": quad_count * QUAD_GEOMETRY_BYTES,
        "atlas_pages": len(pages),
        "texture_resolution": [res, res],
        "seconds": clock.totals(),
    }
    if channels:  # memory per channel; a colour-only bake's stats stay as they were
        stats["channel_bytes"] = {"albedo": texture_bytes} | {
            name: int(sum(p.nbytes for p in channel)) for name, channel in channels.items()
        }
    parameters = {
        **asdict(options),
        "directions": list(options.directions),
        "face_resolution": res,
        "scene_hash": scene.content_hash,
        "plan": plan.to_dict(),
        "near_field": near.to_dict(),
    }
    return Impostor(
        technique="envmap",
        viewcell=cell.to_dict(),
        reference_viewpoint=centre,
        resolution=options.resolution,
        fov_deg=options.fov_deg,
        pages=tuple(pages),
        payload=QuadPayload(
            corners=np.concatenate(quad_corners) if quad_corners else np.zeros((0, 4, 3)),
            uv=quad_uv,
            page=quad_page,
            layer=np.concatenate(quad_layer) if quad_layer else np.zeros(0, np.int64),
            depth_range=(np.concatenate(depth_ranges) if depth_ranges else np.zeros((0, 2))) if depth else None,
        ),
        layers=layers,
        stats=stats,
        parameters=parameters,
        code_version=__version__,
        channels=channels,
    )


def envmap_cost(cell, options: EnvmapOptions) -> CellCost:
    """The cost of ``cell``'s bake: every chosen face's layers of its face texels (seed 002 Res),
    counted as if every face had geometry beyond the near field (a face without any records none).

    >>> cost = envmap_cost(BoxCell([0.0, 0.0, 0.0], [2.0, 2.0, 2.0]), EnvmapOptions(resolution=256, directions=("+x", "-x", "+z", "-z")))
    >>> cost.describe(), cost.texels == 4 * 64 * 256 * 256
    ('256 layers of 256x256', True)
    """
    if not isinstance(cell, BoxCell):
        raise ViewCellError(f"an envmap impostor needs a cubic box view cell, got a {cell.to_dict()['kind']!r} cell")
    plan = plan_envmap(cell, options)
    return CellCost.of_layers(len(options.directions) * plan.count, (plan.resolution, plan.resolution))


def _check(cell, options, bounds, max_texels: int | None = None) -> CellCost:
    return envmap_cost(cell, options)  # closed form (seed 002 Eqs. 1-2): no budget needed


def _bound(cells, options, bounds) -> np.ndarray:
    """(n,) int64: each cell's texels by :func:`envmap_cost`, the worker's own check (closed form,
    about 0.1 ms a cell), so the request refuses what the worker would, a non-cubic cell included."""
    return np.array([envmap_cost(cell, options).texels for cell in cells], dtype=np.int64)


def _bake(scene, cell, options, objects, progress):
    _check(cell, options, None)
    return bake_envmap(scene, cell, options, progress)


def _summary(stats: dict) -> str:
    return (
        f"faces: {stats['faces']}  layers: {stats['layers']} kept of {stats['faces'] * stats['layers_planned']}  "
        f"near field: {stats['near_field']:.6g} ({stats['near_field_triangles']} triangles)  quads: {stats['quads']}\n"
        f"memory: raw layers {stats['raw_layer_bytes'] / 2**20:.1f} MiB -> macrotextures "
        f"{stats['texture_bytes'] / 2**20:.2f} MiB -> PNG {stats['png_bytes'] / 1024:.1f} KiB\n" + seconds_line(stats)
    )


def _evaluate(scene, impostor, random_count: int, outside_count: int, seed: int) -> dict:
    # Outside the cell an envmap impostor promises nothing (its near field is cut to the cell's cube).
    return evaluate_envmap(scene, impostor, random_count=random_count, seed=seed)


def _evaluate_lit(scene, impostor, random_count: int, seed: int):
    # What the envmap stands in for: the scene beyond the near field, from the unlit evaluation's views.
    return evaluate_envmap_lit(scene, impostor, random_count=random_count, seed=seed)


def _evaluation_text(result: dict, impostor) -> str:
    lines = [f"{'kind':<7} {'forward':<20} {'geometry':>9} {'holes':>6} {'>1px':>6} {'err mean':>9} {'err max':>8}"]
    for row in result["views"]:
        s = row["stats"]
        forward = ",".join(f"{c:+.2f}" for c in row["forward"])
        lines.append(
            f"{row['kind']:<7} {forward:<20} {s['geometry_pixels']:>9} {s['hole_pixels']:>6} "
            f"{s['bloat_beyond_1px']:>6} {s['colour_error_mean']:>9.2f} {s['colour_error_max']:>8}"
        )
    t, stats = result["totals"], impostor.stats
    lines.append(f"inside the view cell: {t['views']} views, {t['hole_pixels']} hole pixels, {t['bloat_beyond_1px']} pixels bloated beyond 1 px, "
                 f"colour error mean {t['colour_error_mean']:.3f}")  # fmt: skip
    lines.append(
        f"impostor: {stats.get('faces')} faces, {stats.get('layers')} layers, {stats.get('quads')} quads, "
        f"near field {stats.get('near_field'):.6g} ({stats.get('near_field_triangles')} triangles), "
        f"{stats.get('texture_bytes', 0) / 1024:.1f} KiB texture, {stats.get('png_bytes', 0) / 1024:.1f} KiB PNG"
    )
    return "\n".join(lines)


TECHNIQUE = TechniqueDefinition(
    name="envmap",
    payload_kind=QuadPayload.kind,
    runtime=EnvmapCellRenderer,
    kernels=(recording.warm_kernels,),
    scope="scene",
    help="layered environment-map impostors of the whole scene around cubic box view cells (seed 002)",
    Options=EnvmapOptions,
    check=_check,
    bound=_bound,
    bake=_bake,
    summary=_summary,
    evaluate=_evaluate,
    evaluate_lit=_evaluate_lit,
    evaluation_text=_evaluation_text,
    promise=Promise(
        "no hole pixel from anywhere in the cubic view cell: the near field, and every face without layers, are geometry; "
        "layer parallax within max_error_px (default 1)",
        holes=True,
    ),
)

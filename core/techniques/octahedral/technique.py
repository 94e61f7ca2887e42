"""Octahedral impostors: a part and a view cell beyond its bounding sphere in, an
:class:`~farfield.core.impostor.impostor.Impostor` of ``n x n`` orthographic frames on one atlas
page out, drawn as one camera-facing card blending the three frames around the view direction.

frame directions on the (hemi-)octahedral grid (:mod:`~farfield.core.techniques.octahedral.mapping`)
-> frames drawn by the evaluation's renderer (:mod:`~farfield.core.techniques.octahedral.frames`)
-> one atlas page (colour dilated, alpha kept; normals and depth on a parallel page)
-> with depth on a grid whose frames all have opposites, the part's longest internal gap
(:func:`~farfield.core.techniques.octahedral.frames.internal_gap`, peeled)
-> the payload (:mod:`~farfield.core.techniques.octahedral.payload`) and the accuracy distance
(:mod:`~farfield.core.techniques.octahedral.accuracy`), in the stats and the manifest.

The technique is the octahedral impostor of the engines (Amplify Impostors, Unreal's impostor
baker, Godot's and three.js's octahedral impostor libraries), with the octahedral map of Cigolle
et al. 2014; docs/techniques/octahedral.md.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from farfield.core import __version__
from farfield.core.errors import LayerPlanError, ViewCellError
from farfield.core.impostor.impostor import ChannelSet, Impostor, keeps_material, wants_depth, wants_normals
from farfield.core.layering.atlas import MAX_PAGE
from farfield.core.options import check_options, option
from farfield.core.pixel_angles import MAX_RESOLUTION
from farfield.core.quality.evaluation import Evaluation
from farfield.core.scene import Scene, emits
from farfield.core.stage_clock import Progress, StageClock, seconds_line
from farfield.core.techniques.base import CellCost, Promise, TechniqueDefinition
from farfield.core.techniques.octahedral.accuracy import accuracy_distance
from farfield.core.techniques.octahedral.estimate import estimate_octahedral, outside_estimate
from farfield.core.techniques.octahedral.frames import (
    Sphere,
    column_gap,
    compose_atlas,
    frame_axes,
    internal_gap,
    pages_layout,
    record_frames,
)
from farfield.core.techniques.octahedral.instancing import instancing
from farfield.core.techniques.octahedral.mapping import frame_directions, opposite_frames
from farfield.core.techniques.octahedral.payload import OctahedralPayload
from farfield.core.techniques.part import evaluate_part, part_evaluation_text
from farfield.core.viewcells import SphereOutsideCell, ViewCell, viewcell_from_dict


@dataclass(frozen=True, slots=True)
class OctahedralOptions:
    """The knobs of an octahedral bake (all recorded in the impostor's parameters)."""

    resolution: int = option(
        512, "output image pixels per side the accuracy distance is computed for", ge=1, le=MAX_RESOLUTION
    )
    fov_deg: float = option(
        45.0, "output field of view the accuracy distance is computed for, degrees", gt=0.0, lt=180.0
    )
    grid: int = option(
        13, "frames per side of the octahedral grid (grid x grid frames); an odd grid gives every frame its opposite, "
        "which bounds the depth channel's columns (docs/techniques/octahedral.md)", ge=2, le=64,
    )  # fmt: skip
    frame_resolution: int = option(
        64, "texels per side of each frame (at the accuracy distance a part is a few pixels wide: more texels serve nearer views)",
        ge=4, le=4096,
    )  # fmt: skip
    hemisphere: bool = option(
        False, "frames of the upper hemisphere only (the hemi-octahedral map), for a part never seen from below"
    )
    padding: int = option(
        4, "texels around each frame in its atlas cell, filled with dilated colour: mip levels up to log2(padding) "
        "never mix two frames", ge=0, le=64,
    )  # fmt: skip
    samples: int = option(
        2,
        "samples per texel side: they antialias the colour, normal and depth (with coverage=exact, coverage is "
        "exact whatever this is; with coverage=sampled, a texel is covered only where a sample is)",
        ge=1,
        le=8,
    )
    coverage: str = option(
        "exact",
        "exact: a texel is covered wherever the part touches it (the layered recording's slab test; features "
        "thinner than a sample are kept, the one-pixel guarantee holds for any part); sampled: only where one of "
        "the samples is (2-13x faster bakes; a feature thinner than texel/samples may be lost in some frames)",
        choices=("exact", "sampled"),
    )
    channels: ChannelSet = option(
        "albedo",
        "what each texel keeps: albedo, albedo+normal (world normals on a second page), albedo+normal+depth "
        "(the normal page's alpha holds each texel's height: the runtime corrects the frames' parallax with it); "
        "+material (glTF occlusion, roughness, metallic and emission on material and emissive pages, where the "
        "part has a material)",
    )
    max_page: int = option(
        MAX_PAGE, "largest atlas page side, texels: the frames take as many pages as they need", ge=64, le=16384
    )

    def __post_init__(self) -> None:
        check_options(self)


def _nearest(cell: ViewCell, centre: np.ndarray) -> float:
    """How near ``cell`` comes to the point ``centre`` (3,)."""
    return float(cell.distance_to_box(np.stack([centre, centre])))


def _check_cell(cell: ViewCell, centre: np.ndarray, radius: float, options: OctahedralOptions) -> None:
    nearest = _nearest(cell, centre)
    if not nearest > radius:
        raise ViewCellError(
            f"an octahedral impostor is seen from outside its part's bounding sphere (radius {radius:.6g} around "
            f"{np.round(centre, 6).tolist()}); the {cell.kind} view cell comes within {nearest:.6g} of its centre"
        )
    if options.hemisphere and isinstance(cell, SphereOutsideCell) and not cell.hemisphere:
        raise ViewCellError("a hemisphere octahedral impostor needs a view cell above the horizon (outside-hemi)")


def check_octahedral_cell(
    cell: ViewCell, options: OctahedralOptions, bounds: np.ndarray | None, max_texels: int | None = None
) -> CellCost:
    """The frames a bake records (``grid²`` of ``frame_resolution²``); raises ViewCellError where
    the cell reaches into the part's bounding sphere (the bounds' half diagonal: the bake's sphere
    is never larger)."""
    if bounds is not None:
        b = np.asarray(bounds, dtype=np.float64).reshape(2, 3)
        _check_cell(cell, 0.5 * (b[0] + b[1]), 0.5 * float(np.linalg.norm(b[1] - b[0])), options)
    return CellCost.of_layers(options.grid**2, (options.frame_resolution, options.frame_resolution))


def bound_octahedral_cells(cells: list[ViewCell], options: OctahedralOptions, bounds: np.ndarray | None) -> np.ndarray:
    """(n,) int64: :func:`check_octahedral_cell`'s texels of each cell, the same for every cell
    (``grid²`` frames of ``frame_resolution²``): the bounding sphere is checked on a worker."""
    return np.full(len(cells), options.grid**2 * options.frame_resolution**2, dtype=np.int64)


def bake_octahedral(
    scene: Scene,
    cell: ViewCell,
    options: OctahedralOptions = OctahedralOptions(),
    objects: list[str] | None = None,
    progress: Progress | None = None,
) -> Impostor:
    """Bake the octahedral impostor of ``scene`` (or of its ``objects``) for ``cell`` (any cell
    beyond the part's bounding sphere; :class:`~farfield.core.viewcells.SphereOutsideCell` is its own)."""
    part = scene.subset(objects) if objects else scene
    clock = StageClock(("frames", "atlas", "gaps"), progress)
    sphere = Sphere.of_objects(part.objects)
    _check_cell(cell, sphere.centre, sphere.radius, options)
    n, res, pad = options.grid, options.frame_resolution, options.padding
    directions = frame_directions(n, options.hemisphere)
    normals, depth = wants_normals(options.channels), wants_depth(options.channels)
    page_of, texel, sides = pages_layout(n, res, pad, options.max_page)  # an overflow before any work
    material = keeps_material(options.channels, part.objects)  # a matte part keeps no material pages
    emissive = material and any(emits(obj) for obj in part.objects)
    with clock("frames"):
        frames = record_frames(
            part.objects, sphere, directions, res, options.samples, normals, material, emissive,
            exact=options.coverage == "exact",
        )  # fmt: skip
    clock.report("frames", 1, 1)
    covered = frames.colour[..., 3] > 0
    if not covered.any():  # as layered's and tdm's "no visible texel": no full-size atlas of nothing
        raise LayerPlanError(
            "the part left no visible texel in any frame (is it empty, degenerate or fully transparent?): "
            "nothing to make an octahedral impostor of"
        )
    with clock("atlas"):
        pages = compose_atlas(frames.colour, page_of, texel, sides, pad)
        channels = {}
        if frames.normal is not None:
            normal = frames.normal.copy()
            if not depth:
                normal[..., 3] = np.where(covered, 255, 0)
            channels["normal"] = compose_atlas(normal, page_of, texel, sides, pad, mask=covered)
        for name, kept in (("material", frames.material), ("emissive", frames.emissive)):
            if kept is not None:  # laid out and dilated as the colour
                channels[name] = compose_atlas(kept, page_of, texel, sides, pad)
    clock.report("atlas", 1, 1)
    gap = None
    opposite = opposite_frames(n, options.hemisphere)
    if depth and (opposite >= 0).all():  # two-sided columns: the part's longest internal gap bounds their walls
        with clock("gaps"):
            lines = [k for k in range(n * n) if k < opposite[k]]  # one frame of each opposite pair
            gap = internal_gap(part.objects, sphere, directions[lines], res * options.samples)
            gap = max(
                gap, column_gap(part.objects, sphere, directions, res, frames, [(k, int(opposite[k])) for k in lines])
            )
        clock.report("gaps", 1, 1)
    accuracy = accuracy_distance(sphere.radius, frames.depth_extent, n, options.hemisphere, res, options.resolution,
                                 options.fov_deg, depth, gap)  # fmt: skip
    payload = OctahedralPayload(
        axes=frame_axes(directions),
        texel=texel,
        page=page_of,
        sphere=np.concatenate([sphere.centre, [sphere.radius]]),
        grid=np.array([n, res, pad, int(options.hemisphere), int(depth)]),
    )
    texture_bytes = int(sum(p.nbytes for p in pages))
    stats = {
        "frames": n * n,
        "grid": n,
        "frame_resolution": res,
        "atlas_size": [int(pages[0].shape[1]), int(pages[0].shape[0])],
        "atlas_pages": len(pages),
        "texels_covered": int(covered.sum()),
        "texture_bytes": texture_bytes,
        "geometry_bytes": 0,
        "radius": sphere.radius,
        "depth_extent": frames.depth_extent,
        "accuracy_distance": accuracy.distance,
        "accuracy": accuracy.to_dict(),
        "seconds": clock.totals(),
    }
    if channels:
        stats["channel_bytes"] = {"albedo": texture_bytes} | {
            name: int(sum(p.nbytes for p in kept)) for name, kept in channels.items()
        }
    return Impostor(
        technique="octahedral",
        viewcell=cell.to_dict(),
        reference_viewpoint=np.asarray(cell.center, dtype=np.float64),
        resolution=options.resolution,
        fov_deg=options.fov_deg,
        pages=pages,
        payload=payload,
        layers=[],
        stats=stats,
        parameters={**asdict(options), "objects": list(part.names), "scene_hash": scene.content_hash},
        code_version=__version__,
        channels=channels,
    )


def _summary(stats: dict) -> str:
    a = stats["accuracy"]
    return (
        f"frames: {stats['grid']} x {stats['grid']} of {stats['frame_resolution']} texels  atlas: "
        f"{stats['atlas_size'][0]}x{stats['atlas_size'][1]}  texture: {stats['texture_bytes'] / 1024:.1f} KiB\n"
        f"accuracy distance: {a['distance']:.4g} ({a['radii']:.1f} bounding radii) for {a['resolution']} px at "
        f"{a['fov_deg']:g}° (grid angle {a['grid_angle_deg']:.2f}°, texel {a['texel']:.3g}, depth extent "
        f"{stats['depth_extent']:.3g}"
        + (f", two-sided depth: internal gap {a['gap']:.3g}" if a.get("gap") is not None else "")
        + ")\n"
        + seconds_line(stats)
    )


def cell_distance(impostor: Impostor) -> float:
    """Distance from the part's centre (the payload's bounding sphere) to the nearest point of the
    impostor's view cell (a lower bound for a shaft or a hemisphere): the view cell lies beyond the
    accuracy distance, where the promise holds, when it is at least ``stats["accuracy_distance"]``."""
    centre = np.asarray(impostor.payload.sphere[:3], dtype=np.float64)
    return float(viewcell_from_dict(impostor.viewcell).distance_to_box(np.stack([centre, centre])))


def outside_accuracy(impostor: Impostor) -> str | None:
    """Why the impostor's view cell lies where octahedral's promise does not hold: nearer to the part's
    centre than the accuracy distance (:func:`cell_distance`); None beyond it."""
    accurate = impostor.stats.get("accuracy_distance")
    if accurate is None or (nearest := cell_distance(impostor)) >= accurate:
        return None
    return (
        f"the view cell comes within {nearest:.4g} of the part's centre, nearer than the accuracy distance "
        f"{accurate:.4g} beyond which octahedral promises one pixel"
    )


def _evaluation_text(result: Evaluation, impostor: Impostor) -> str:
    distance = impostor.stats.get("accuracy_distance", math.nan)
    text = part_evaluation_text(result, impostor).replace("None layers, ", f"{impostor.payload.count} frames, ")
    return text + f"\naccuracy distance: {distance:.4g} from the part's centre"


TECHNIQUE = TechniqueDefinition(
    name="octahedral",
    payload_kind=OctahedralPayload.kind,
    scope="part",
    help="octahedral impostors of a scene's objects: a grid of orthographic frames blended on one card, "
    "for any viewpoint beyond the part's bounding sphere (Cigolle et al. 2014's octahedral map)",
    Options=OctahedralOptions,
    check=check_octahedral_cell,
    bound=bound_octahedral_cells,
    bake=bake_octahedral,
    summary=_summary,
    evaluate=evaluate_part,
    evaluation_text=_evaluation_text,
    estimate=estimate_octahedral,
    outside_estimate=outside_estimate,
    promise=Promise(
        "within one pixel beyond the accuracy distance the bake reports (stats accuracy_distance)",
        outside=outside_accuracy,
    ),
    instancing=instancing(),  # an instance's impostor is its prototype's moved (instancing.py)
)

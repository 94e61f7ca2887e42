"""Layered-depth-image impostors (seed 004 §4, Aliaga and Lastra 1999): a scene part and a box view
cell in, an :class:`~farfield.core.impostor.impostor.Impostor` of LDI samples out, splatted at run time.

The LDI's centre of projection is the cell's centre, looking at the part's centre.  Its image
plane, which is also its near plane, is the quad through the part's nearest point: the square
window around the part's bounds.  Seed 004's image of a grid point is the same construction, with
the grid point's star sphere as the cell.  The part must lie wholly farther ahead than the cell's
half-diagonal, so that every eye in the cell stays in front of the quad (§3.2.1's condition).  The
LDI is built from nine construction images (§4.1, :mod:`farfield.core.ldi.construction`), or from the
central one alone (``images=1``, the single-image LDI of Fig. 10).

**Stored** as two pages per layer, colour and float32 depth (:mod:`farfield.core.ldi.pages`; PNG in the
bundle).  ``texture_bytes`` counts those pages raw; ``splat_bytes`` what the GPU drawer uploads,
20 bytes a sample (a float32 position, an RGBA8 colour, a float32 footprint width).

**Normals** (``channels="albedo+normal"``): each sample keeps its world shading normal
(:mod:`farfield.core.ldi.normals`), stored as the impostor's ``normal`` channel, a page beside each
layer's colour page (:func:`farfield.core.ldi.pages.normal_pages`); ``channel_bytes`` gives the
pages' raw bytes per channel and ``splat_normal_bytes`` what a splat drawer uploads for them (12 bytes
a sample).

**For standard viewers** the GLB holds the first layer as one textured quad on the image plane, a
billboard (:func:`farfield.core.ldi.pages.preview_quad`), not the splatted LDI.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from farfield.core import __version__
from farfield.core.errors import LayerPlanError
from farfield.core.impostor.depth import refuse_depth
from farfield.core.impostor.impostor import (
    CHANNELS_HELP,
    ChannelSet,
    Impostor,
    LdiPayload,
    keeps_material,
    wants_normals,
)
from farfield.core.ldi.construction import (
    DEFAULT_MAX_LAYERS,
    _image_samples,
    _merge_samples,
    construct_ldi,
    view_frame,
)
from farfield.core.ldi.materials import sample_material
from farfield.core.ldi.normals import sample_normals
from farfield.core.ldi.pages import ldi_payload_and_pages, normal_pages, sample_pages
from farfield.core.ldi.warp import _warp_kernel
from farfield.core.options import check_options, option
from farfield.core.pixel_angles import MAX_RESOLUTION
from farfield.core.quality.evaluation import Evaluation
from farfield.core.scene import Scene, emits
from farfield.core.sidedness import seen_from_cell
from farfield.core.stage_clock import Progress, StageClock, seconds_line
from farfield.core.techniques.base import NO_PROMISE, CellCost, TechniqueDefinition
from farfield.core.techniques.part import evaluate_part, part_evaluation_text
from farfield.core.viewcells import BoxCell, ViewCell, length_and_unit

SAMPLE_BYTES = 20  # float32 position, RGBA8 colour, float32 footprint width
NORMAL_BYTES = 12  # a sample's float32 normal, for a splat drawer that lights it (channels albedo+normal)


@dataclass(frozen=True, slots=True)
class LdiOptions:
    """The knobs of an LDI bake (all recorded in the impostor's parameters)."""

    resolution: int = option(
        512, "output image pixels per side; the LDI has as many across its window", ge=1, le=MAX_RESOLUTION
    )
    fov_deg: float = option(60.0, "output field of view, degrees", gt=0.0, lt=180.0)
    images: int = option(
        9, "construction images: 9 (seed 004 §4.1, Fig. 11) or 1 (the centre's alone, Fig. 10 left)", ge=1, le=9
    )
    max_layers: int = option(DEFAULT_MAX_LAYERS, "most samples an LDI pixel keeps", ge=1, le=64)
    channels: ChannelSet = option(
        "albedo",
        CHANNELS_HELP,
    )

    def __post_init__(self) -> None:
        check_options(self)
        refuse_depth("ldi", self.channels)  # its geometry is exact (farfield.core.impostor.depth)
        if self.images not in (1, 9):
            raise LayerPlanError(f"images must be 1 or 9, got {self.images}")


@dataclass(frozen=True)
class LdiView:
    """Where an LDI of a part is taken from: centre of projection, direction, quad and its depth."""

    eye: np.ndarray
    direction: np.ndarray
    quad: np.ndarray
    depth: float


def ldi_view(cell: ViewCell, bounds: np.ndarray) -> LdiView:
    """The LDI's view of a part with ``bounds`` from a box ``cell`` (module docstring); LayerPlanError
    where the part comes within the cell's half-diagonal of its centre."""
    if not isinstance(cell, BoxCell):
        raise LayerPlanError(f"an LDI impostor needs a box view cell, got a {cell.kind} cell")
    eye = np.asarray(cell.center, dtype=np.float64)
    lo, hi = np.asarray(bounds, dtype=np.float64)
    towards = 0.5 * (lo + hi) - eye
    length, unit = length_and_unit(towards)  # no overflow near 1e300
    if not length > 0:
        raise LayerPlanError("the part's centre is the view cell's centre: an LDI needs the part ahead of the cell")
    with np.errstate(over="ignore"):
        ordinary = math.isfinite(float(np.linalg.norm(towards)))
    r, u, f = view_frame(towards if ordinary else unit)  # the frame of old for every ordinary cell
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])]) - eye
    z = corners @ f
    reach = 0.5 * length_and_unit(np.asarray(cell.hi) - np.asarray(cell.lo))[0]
    if z.min() <= reach:
        raise LayerPlanError(
            f"the part comes within {max(z.min(), 0.0):.6g} of the view cell's centre along its view, inside the cell's "
            f"half-diagonal {reach:.6g}: an LDI's image plane must lie ahead of every eye in the cell (seed 004 §3.2.1)"
        )
    x, y = (corners @ r) / z, (corners @ u) / z
    depth = float(z.min())
    quad = np.stack(
        [
            eye + depth * (f + a * r + b * u)
            for a, b in ((x.min(), y.min()), (x.max(), y.min()), (x.max(), y.max()), (x.min(), y.max()))
        ]
    )
    return LdiView(eye, f, quad, depth)


def check_ldi_cell(
    cell: ViewCell, options: LdiOptions, bounds: np.ndarray | None, max_texels: int | None = None
) -> CellCost:
    """The cell's recording work: ``images`` construction images of ``resolution`` pixels; raises where
    the cell can have no LDI of the part; without ``bounds``, only the cell's kind."""
    if bounds is None:
        if not isinstance(cell, BoxCell):
            raise LayerPlanError(f"an LDI impostor needs a box view cell, got a {cell.kind} cell")
        return CellCost.of_layers(0, (0, 0))
    ldi_view(cell, bounds)
    return CellCost.of_layers(options.images, (options.resolution, options.resolution))


def bound_ldi_cells(cells: list[ViewCell], options: LdiOptions, bounds: np.ndarray | None) -> np.ndarray:
    """(n,) int64: :func:`check_ldi_cell`'s texels of each cell, which do not depend on the cell
    (``images`` of ``resolution``; 0 without ``bounds``): the geometry is checked on a worker."""
    each = options.images * options.resolution**2 if bounds is not None else 0
    return np.full(len(cells), each, dtype=np.int64)


def bake_ldi(
    scene: Scene,
    cell: ViewCell,
    options: LdiOptions = LdiOptions(),
    objects: list[str] | None = None,
    progress: Progress | None = None,
) -> Impostor:
    """Bake the LDI impostor of ``scene`` (or of its ``objects``) for ``cell`` (a box); technique ``"ldi"``."""
    part = scene.subset(objects) if objects else scene
    clock = StageClock(("plan",), progress)
    with clock("plan"):
        view = ldi_view(cell, part.bounds)
    clock.report("plan", 1, 1)
    made = construct_ldi(
        list(part.objects),
        view.eye,
        view.direction,
        view.quad,
        view.depth,
        options.resolution,
        options.images,
        options.max_layers,
        cell=cell,  # one-sided triangles whose back faces the whole cell are not recorded
        clock=clock,  # its stages: frame, upload, draw, read, merge, sort
    )
    clock.report("images", 1, 1)
    ldi = made.ldi
    if ldi.count == 0:
        raise LayerPlanError(
            "the part has no surface the LDI's construction images see: nothing to make an LDI impostor of"
        )
    with clock("pages"):
        payload, pages = ldi_payload_and_pages(ldi)
    n = ldi.count
    stats = {
        "samples": n, "layers": ldi.layers, "offered": made.offered, "dropped_full": made.dropped_full,
        "construction_images": options.images, "quad_depth": view.depth, "splat_bytes": n * SAMPLE_BYTES,
        "texture_bytes": int(sum(p.nbytes for p in pages)), "seconds": clock.totals(),
    }  # fmt: skip
    channels = {}
    if wants_normals(options.channels):
        with clock("normals"), threadpool_limits(1, user_api="blas"):  # as construct_ldi
            # The objects construct_ldi drew (its samples' object indices are theirs), the side the cell sees.
            positions, index = ldi.samples()
            at = (index[:, 0], index[:, 1], index[:, 2])
            normals = sample_normals(
                seen_from_cell(part.objects, cell), ldi.obj[at], ldi.triangle[at], positions, cell.corners()
            )
            channels = {"normal": normal_pages(ldi, normals)}
            objects = seen_from_cell(part.objects, cell)
            if keeps_material(options.channels, objects):  # the material (and emission) of the same samples
                orm, emissive = sample_material(objects, ldi.obj[at], ldi.triangle[at], positions)
                channels["material"] = sample_pages(ldi, orm)
                if any(emits(o) for o in objects):
                    channels["emissive"] = sample_pages(ldi, emissive)
        stats["seconds"] = clock.totals()
        # memory per channel (a colour-only bake's stats stay as they were): the normal pages of the layers, and
        # what a splat drawer uploads per sample (a float32 normal)
        stats["channel_bytes"] = {"albedo": stats["texture_bytes"], "normal": ldi.layers * int(ldi.depth[0].size) * 4}
        for name in ("material", "emissive"):
            if name in channels:
                stats["channel_bytes"][name] = ldi.layers * int(ldi.depth[0].size) * 4
        stats["splat_normal_bytes"] = n * NORMAL_BYTES
    return Impostor(
        technique="ldi", viewcell=cell.to_dict(), reference_viewpoint=view.eye, resolution=options.resolution, fov_deg=options.fov_deg,
        pages=pages, payload=payload, layers=[], stats=stats, channels=channels,
        parameters={**asdict(options), "objects": list(part.names), "scene_hash": scene.content_hash, "quad": view.quad.tolist()},
        code_version=__version__,
    )  # fmt: skip


def warm_kernels() -> float:
    """Compile (or load from numba's cache) the LDI merge and the CPU warp on tiny arrays, without GL;
    the seconds it took.  A render worker calls it when it starts, beside the other techniques'."""
    start = time.perf_counter()
    layers = (
        np.full((1, 1, 1), np.nan),
        np.full((1, 1, 1), -1, np.int64),
        np.full((1, 1, 1), -1, np.int64),
        np.zeros((1, 1, 1, 4), np.uint8),
    )
    _merge_samples(np.array([[0.0, 0.0, 1.0]]), np.zeros(1, np.int64), np.zeros(1, np.int64), np.zeros((1, 4), np.uint8), 0.0, 0.0, 1.0, 1, 0.5,
                   0.01, *layers, np.zeros((1, 1), np.int64))  # fmt: skip
    _image_samples(np.zeros((1, 1, 1, 3)), np.zeros((1, 1, 1, 4), np.uint8), *np.eye(3), np.zeros(3), 0.0, 0.0, 1.0, 1)
    frame = np.eye(3)
    _warp_kernel(np.ones((1, 1, 1)), np.zeros((1, 1, 1, 4), np.uint8), np.zeros(3), frame, 0.0, 0.0, 1.0, np.zeros(3), frame, 0.0, 0.0, 1.0,
                 0.1, 0.5, 0.5, True, np.zeros((1, 1, 4), np.uint8), np.full((1, 1), np.nan))  # fmt: skip
    return time.perf_counter() - start


def _summary(stats: dict) -> str:
    return (
        f"LDI: {stats['samples']:,} samples in {stats['layers']} layers from {stats['construction_images']} construction images "
        f"({stats['offered']:,} offered, {stats['dropped_full']:,} dropped by the layer cap)  pages {stats['texture_bytes'] / 1024:.1f} KiB raw, "
        f"splats {stats['splat_bytes'] / 1024:.1f} KiB\n" + seconds_line(stats)
    )


def _evaluation_text(result: Evaluation, impostor: Impostor) -> str:
    return part_evaluation_text(result, impostor) + f"\nLDI samples: {impostor.payload.count:,}"


TECHNIQUE = TechniqueDefinition(
    name="ldi",
    payload_kind=LdiPayload.kind,
    placement="layered depth images are placed by the primitive-budget algorithm (algorithm primitive-budget, a primitives budget)",
    kernels=(warm_kernels,),
    scope="part",
    help="layered-depth-image impostors of a scene's objects for a box view cell: nine construction images, splatted (seed 004)",
    Options=LdiOptions,
    check=check_ldi_cell,
    bound=bound_ldi_cells,
    bake=bake_ldi,
    summary=_summary,
    evaluate=evaluate_part,
    evaluation_text=_evaluation_text,
    promise=NO_PROMISE,
)

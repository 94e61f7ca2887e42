"""Calibration of the cost model on the process's renderer: scenes in, measured samples (rows of counts and milliseconds) and a fitted :class:`CostModel` out.

Seed 000 §5.8.1 "Parameter Estimation", Figs. 5.5-5.6, on the renderer this process draws with
(llvmpipe on a CPU machine, the NVIDIA driver on a GPU worker):

* geometry (Fig. 5.5): pick random object clusters, render each from random viewpoints outside it
  looking at it, and record draw calls, triangles, covered pixels and the frame time; fit
  ``t = a * draw_calls + b * triangles + c * pixels + d``;
* impostors (Fig. 5.6): pick random clusters, give each a random shaft view cell (apex angle from
  11.25°, 22.5°, 45°, 90°, a random direction, minimum distance ``2**j`` times the cluster's size),
  bake its layered impostor, draw it from random points inside the cell, and record covered pixels,
  quads and the time it adds to an empty frame; fit ``t = e * pixels + f * quads + g``;
* memory (the same setup): each baked impostor's bytes (atlas pages + quad geometry) against the
  estimate a placement ranks by (:func:`farfield.core.layering.plan.estimate_layers`: layers and texels per
  layer), ``bytes = h * (layers_est * texels_per_layer) ** p + k``, and its quads,
  ``quads = q * layers_est``, both fitted to the logarithms (:func:`farfield.core.placement.cost_model.fit_power`:
  bytes span six orders of magnitude, and a ranking by Δt/m needs their ratios).

Clusters are contiguous runs of objects in a Morton (Z-curve) order of their centres, so they are
spatially compact, with sizes log-uniform from one object to ``max_cluster``: a stand-in for the
object hierarchy's nodes, which the thesis sampled (the hierarchy, :mod:`farfield.core.placement`, is built
elsewhere).  Which clusters, cells and viewpoints are measured depends on the seed alone
(:func:`sample_cases`, no GL); the times, of course, vary from run to run.

Deviations from the thesis, and why: frame times are the median of ``repeats`` draws after two
warm-up draws (draw, then ``glFinish``; no read-back), so one slow frame of a shared machine does not
enter the fit; an impostor's time is its frame's time less the median empty frame's (the clear and
the state changes that ``d`` already counts once per frame); impostors whose estimated texels
exceed ``max_texels`` are redrawn (such bakes take minutes on llvmpipe and a placement would not
choose them), which the fit's sample counts report.
"""

from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime

import numpy as np

from farfield.core.errors import LayerPlanError, ViewCellError
from farfield.core.layering.plan import estimate_layers
from farfield.core.placement.cost_model import CostModel, CostModelError, fit_linear, fit_power, fit_quantile
from farfield.core.procedural import city
from farfield.core.quality.evaluation import impostor_objects
from farfield.core.render.context import renderer_info
from farfield.core.render.raster import Camera, MeshRenderer, depth_bounds
from farfield.core.scene import Scene
from farfield.core.stage_clock import Progress, StageClock
from farfield.core.techniques.layered import BakeOptions, bake_layered
from farfield.core.techniques.part import layer_budget
from farfield.core.viewcells import ShaftCell, box_corners

# Shaft apex angles of the thesis's candidates (seed 000 §5.8.1), degrees.
APEX_ANGLES_DEG = (11.25, 22.5, 45.0, 90.0)
# Fewest samples a fit may have, so that each fit keeps as many rows as coefficients and still
# holds a quarter out: 8 geometry rows (4 coefficients), 4 impostors (3 memory coefficients).
MIN_GEOMETRY_SAMPLES = 8
MIN_IMPOSTORS = 4
# Untimed draws before the timed ones of a view: llvmpipe's first draws of new buffers are slower.
WARM_UP = 2


@dataclass(frozen=True, slots=True)
class CalibrationOptions:
    """What a calibration measures (all recorded in the model's ``fit``)."""

    samples: int = 800  # geometry measurements (clusters x views)
    impostors: int = 96  # baked impostors (each drawn from ``views`` points of its cell)
    resolution: int = 256  # output image pixels per side (square), drawing and baking
    fov_deg: float = 45.0  # output field of view, degrees
    seed: int = 0
    views: int = 4  # viewpoints per cluster and per impostor
    repeats: int = 7  # timed draws per viewpoint after a warm-up; the median counts
    max_cluster: int = 256  # most objects in a cluster
    max_distance_exponent: int = 8  # shaft minimum distance 2**j x cluster size, j in 0..this
    max_texels: float = 8e6  # largest estimated layers x texels per layer of a sampled impostor
    holdout: float = 0.25  # share of the samples each fit is judged on
    # The geometry samples: None, clusters drawn from outside (the thesis's Fig. 5.5); else a view
    # space (lo x, y, z, hi x, y, z) of the one scene calibrated, whose frames from random views in
    # it are drawn as the placement runtime draws plain geometry (calibrate_views).
    view_space: tuple[float, ...] | None = None
    # None: the geometry coefficients by least squares (the mean frame); q in (0, 1): by quantile
    # regression, a time about a share q of frames with those counts stay under (fit_quantile).
    quantile: float | None = None

    def __post_init__(self) -> None:
        checks = (
            ("samples", self.samples, MIN_GEOMETRY_SAMPLES),
            ("impostors", self.impostors, MIN_IMPOSTORS),
            ("resolution", self.resolution, 16),
            ("views", self.views, 1),
            ("repeats", self.repeats, 1),
            ("max_cluster", self.max_cluster, 1),
            ("max_distance_exponent", self.max_distance_exponent, 0),
        )
        for name, value, least in checks:
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < least:
                raise CostModelError(f"calibration {name} must be an integer >= {least}, got {value!r}")
        if not (math.isfinite(self.fov_deg) and 0.0 < self.fov_deg < 180.0):
            raise CostModelError(f"calibration fov must lie in (0, 180) degrees, got {self.fov_deg!r}")
        if not self.max_texels > 0.0:
            raise CostModelError(f"calibration max_texels must be > 0, got {self.max_texels!r}")
        if not 0.0 <= self.holdout < 1.0:
            raise CostModelError(f"calibration holdout must lie in [0, 1), got {self.holdout!r}")
        if self.quantile is not None and not (isinstance(self.quantile, float) and 0.0 < self.quantile < 1.0):
            raise CostModelError(f"calibration quantile must lie in (0, 1), got {self.quantile!r}")
        if self.view_space is not None:
            box = np.asarray(self.view_space, dtype=np.float64)
            if box.shape != (6,) or not np.all(np.isfinite(box)) or np.any(box[:3] > box[3:]):
                raise CostModelError(
                    f"calibration view space must be six finite numbers lo x, y, z, hi x, y, z with lo <= hi, got {self.view_space!r}"
                )


@dataclass(frozen=True, slots=True)
class GeometryCase:
    """One cluster of one scene to draw from ``eyes`` (v, 3) float64 world points outside it."""

    scene: int  # index into the calibrated scenes
    objects: tuple[int, ...]  # indices into that scene's objects
    eyes: np.ndarray  # (v, 3) float64


@dataclass(frozen=True, slots=True)
class ImpostorCase:
    """One cluster, its shaft view cell and the (v, 3) float64 points of the cell it is drawn from."""

    scene: int
    objects: tuple[int, ...]
    cell: ShaftCell
    eyes: np.ndarray  # (v, 3) float64
    layers_est: float  # estimate_layers for the cell, the cluster's bounds and the options
    texture: tuple[int, int]  # estimate_layers' texture resolution (x, y)


@dataclass(frozen=True, slots=True)
class GeometrySample:
    """A cluster drawn from one viewpoint: counts and the median frame time, milliseconds."""

    scene: int
    objects: int  # objects drawn (view frames: elements, clusters of split objects counted apart)
    draw_calls: float  # view frames: as the planner counts them (a split object's cluster 1 / n of a call)
    triangles: int
    pixels: float  # covered pixels (view frames: the elements' boxes clipped to the frame, at most a frame)
    ms: float


@dataclass(frozen=True, slots=True)
class ImpostorSample:
    """An impostor drawn from one point of its cell: ``ms`` is its frame's median time less the
    empty frame's, ``frame_ms`` the frame's."""

    impostor: int  # index into the calibration's memory samples
    pixels: int
    quads: int
    draw_calls: int  # atlas pages drawn
    ms: float
    frame_ms: float


@dataclass(frozen=True, slots=True)
class MemorySample:
    """A baked impostor: its bytes and quads against the placement's estimate of its layers."""

    scene: int
    objects: int
    apex_angle_deg: float
    min_distance_sizes: float  # the cell's minimum distance / the cluster's size
    layers_est: float
    texels_per_layer: int
    layers_planned: int
    layers: int  # layers kept (with visible texels)
    quads: int
    bytes: int  # texture_bytes + geometry_bytes
    bake_seconds: float


@dataclass(frozen=True, slots=True)
class Calibration:
    """The fitted model and the samples it was fitted on."""

    model: CostModel
    geometry: tuple[GeometrySample, ...]
    impostors: tuple[ImpostorSample, ...]
    memory: tuple[MemorySample, ...]
    empty_frame_ms: float
    skipped_cells: int = 0  # drawn shaft cells refused (meeting the cluster, or over max_texels)
    seconds: dict = field(default_factory=dict)

    def samples_dict(self) -> dict:
        """JSON-ready raw samples (``farfield calibrate --json``)."""
        return {
            "empty_frame_ms": self.empty_frame_ms,
            "geometry": [asdict(s) for s in self.geometry],
            "impostor": [asdict(s) for s in self.impostors],
            "memory": [asdict(s) for s in self.memory],
        }


def default_scene() -> Scene:
    """The scene calibrated when none is given: a procedural city of 900 buildings of 12 to 12,288
    triangles (:func:`farfield.core.procedural.city`, seed 0, detail 32; 163,862 triangles), fixed so that
    calibrations of different machines measure the same objects."""
    return city(900, seed=0, detail=32)


def morton_order(points: np.ndarray) -> np.ndarray:
    """(n,) int64 order of ``points`` (n, 3) float64 along a Z-order curve of their bounding box
    (10 bits per axis), ties by index: neighbours in the order are neighbours in space.

    >>> morton_order(np.array([[1.0, 1, 1], [0, 0, 0], [0.9, 1, 1], [0.1, 0, 0]])).tolist()
    [1, 3, 2, 0]
    """
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    lo, hi = p.min(axis=0), p.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    q = np.minimum((p - lo) / span * 1024.0, 1023.0).astype(np.int64)
    code = np.zeros(len(p), dtype=np.int64)
    for bit in range(10):
        for axis in range(3):
            code |= ((q[:, axis] >> bit) & 1) << (3 * bit + axis)
    return np.lexsort((np.arange(len(p)), code))


def _cluster(rng: np.random.Generator, order: np.ndarray, max_cluster: int) -> tuple[int, ...]:
    """A contiguous run of ``order``, of log-uniform length in 1..min(len(order), max_cluster)."""
    most = min(len(order), max_cluster)
    size = min(most, math.floor(math.exp(rng.uniform(0.0, math.log(most + 1)))))
    size = max(size, 1)
    start = int(rng.integers(0, len(order) - size + 1))
    return tuple(sorted(int(i) for i in order[start : start + size]))


def _bounds(scene: Scene, objects: tuple[int, ...]) -> np.ndarray:
    corners = np.stack([scene.objects[i].bounds for i in objects])
    return np.stack([corners[:, 0].min(axis=0), corners[:, 1].max(axis=0)])


def _unit(rng: np.random.Generator) -> np.ndarray:
    v = rng.normal(size=3)
    return v / np.linalg.norm(v)


def sample_cases(
    scenes: list[Scene] | tuple[Scene, ...], options: CalibrationOptions = CalibrationOptions()
) -> tuple[list[GeometryCase], list[ImpostorCase], int]:
    """The clusters, viewpoints and shaft cells a calibration measures, deterministic for
    ``options.seed`` (no GL): geometry cases, impostor cases and the count of drawn cells refused.

    Geometry viewpoints lie at log-uniform distances of 1.1 to 20 bounding-sphere radii from the
    cluster's centre, in uniformly random directions.
    """
    if not scenes:
        raise CostModelError("calibration needs at least one scene")
    rng = np.random.default_rng(options.seed)
    orders = [morton_order(np.stack([0.5 * (o.bounds[0] + o.bounds[1]) for o in s.objects])) for s in scenes]
    fov = math.radians(options.fov_deg)
    bake = BakeOptions(resolution=options.resolution, fov_deg=options.fov_deg)
    geometry = []
    clusters = -(-options.samples // options.views)
    for n in range(clusters):
        k = int(rng.integers(len(scenes)))
        objects = _cluster(rng, orders[k], options.max_cluster)
        lo, hi = _bounds(scenes[k], objects)
        centre, radius = 0.5 * (lo + hi), max(0.5 * float(np.linalg.norm(hi - lo)), 1e-9)
        views = min(options.views, options.samples - n * options.views)
        distance = radius * np.exp(rng.uniform(math.log(1.1), math.log(20.0), size=views))
        eyes = centre + distance[:, None] * np.stack([_unit(rng) for _ in range(views)])
        geometry.append(GeometryCase(k, objects, eyes))
    impostors, skipped = [], 0
    while len(impostors) < options.impostors:
        if skipped > 50 * options.impostors:
            raise CostModelError(
                f"calibration: {skipped} random shaft cells were refused (meeting their cluster, or over "
                f"{options.max_texels:g} estimated texels); raise max_texels or give other scenes"
            )
        k = int(rng.integers(len(scenes)))
        objects = _cluster(rng, orders[k], options.max_cluster)
        bounds = _bounds(scenes[k], objects)
        size = float(np.linalg.norm(bounds[1] - bounds[0]))
        angle = float(APEX_ANGLES_DEG[int(rng.integers(len(APEX_ANGLES_DEG)))])
        exponent = int(rng.integers(0, options.max_distance_exponent + 1))
        direction = _unit(rng)
        seed = int(rng.integers(2**31))
        try:
            cell = ShaftCell(0.5 * (bounds[0] + bounds[1]), direction, math.radians(angle), (2.0**exponent) * size)
            layers_est, texture = estimate_layers(cell, bounds, fov, options.resolution, **layer_budget(bake))
        except (LayerPlanError, ViewCellError):
            skipped += 1
            continue
        if layers_est * float(texture[0]) * float(texture[1]) > options.max_texels:
            skipped += 1
            continue
        eyes = cell.sample_random(options.views, seed, depth=cell.min_distance)
        impostors.append(ImpostorCase(k, objects, cell, eyes, float(layers_est), (int(texture[0]), int(texture[1]))))
    return geometry, impostors, skipped


def view_samples(scene: Scene, options: CalibrationOptions, progress: Progress | None = None) -> list[GeometrySample]:
    """``options.samples`` frames of ``scene`` from random views in ``options.view_space``
    (positions uniform in the box, directions uniform on the sphere, seeded), each drawn as the
    placement runtime draws plain geometry (:mod:`farfield.core.placement.runtime`): the scene's
    elements (:class:`~farfield.core.placement.hierarchy.Elements`, default clustering) culled to
    the frustum, one draw per object or run of clusters (:class:`~farfield.core.placement.element_draws.ElementDraws`),
    the runtime's depth range.  A sample counts what the runtime's estimate counts
    (:func:`~farfield.core.placement.runtime.plain_estimate`): draw calls as the planner does,
    triangles, and the elements' boxes clipped to the frame, at most one frame; its time is the
    warm median of ``options.repeats`` draws (:func:`~farfield.core.quality.walkthrough.frames_ms`).

    Calibrating on a scene's own views at the output resolution fits the terms to the frames a
    placement of that scene will draw, where the clusters seen from outside (the default) are
    another scene's frames at another scale.
    """
    from farfield.core.placement.element_draws import ElementDraws
    from farfield.core.placement.frame_pixels import box_frame_pixels
    from farfield.core.placement.hierarchy import Elements
    from farfield.core.placement.runtime import boxes_in_frustum, depth_range
    from farfield.core.quality.walkthrough import frames_ms, random_views
    from farfield.core.techniques.envmap.runtime import camera_at

    box = np.asarray(options.view_space, dtype=np.float64)
    elements = Elements.of(scene)
    corners = box_corners(scene.bounds)
    frame = float(options.resolution) ** 2
    positions, forwards = random_views(box[:3], box[3:], options.samples, options.seed)
    samples = []
    with ElementDraws(scene, elements) as uploads:
        for position, forward in zip(positions, forwards):
            near, far = depth_range(position, corners, elements.bounds[:, 0], elements.bounds[:, 1])
            camera = camera_at(position, forward, options.fov_deg, options.resolution, near, far)
            selected = np.arange(elements.count)
            b = elements.bounds
            selected = selected[boxes_in_frustum(camera, b[:, 0], b[:, 1])]
            draws = uploads.draws(selected)
            b = elements.bounds[selected]
            pixels = float(box_frame_pixels(camera, b[:, 0], b[:, 1]).sum()) if selected.size else 0.0
            ms = frames_ms([lambda: uploads.frame_seconds(camera, draws)], options.repeats)[0]
            samples.append(GeometrySample(
                0, int(selected.size), float(elements.draw_calls[selected].sum()), int(elements.triangles[selected].sum()),
                min(pixels, frame), ms,
            ))  # fmt: skip
            if progress is not None:
                progress(len(samples), options.samples)
    return samples


def confounded_terms(columns: np.ndarray, names: tuple[str, ...], limit: float = 0.98) -> list[str]:
    """Warnings for pairs of the samples' ``columns`` (n, k) whose correlation is above ``limit``:
    the fit cannot tell their costs apart, so it may put one's cost on the other (a scene of one
    object split into clusters: every frame's draw calls are its triangles' share), which holds for
    frames like these and misleads for others.  A column that never varies is reported too.

    >>> x = np.column_stack([np.arange(10.0), 2.0 * np.arange(10.0) + 1, np.ones(10)])
    >>> confounded_terms(x, ("calls", "triangles", "pixels"))  # doctest: +NORMALIZE_WHITESPACE
    ["the samples' calls and triangles rise together (correlation 1.000): the fit cannot tell their costs apart; calibrate on a scene whose frames vary them independently (many objects of different sizes) for a model that holds beyond these frames",
     "the samples' pixels never vary: its cost is not measured"]
    """
    x = np.asarray(columns, dtype=np.float64)
    warnings = []
    spread = x.std(axis=0) > 0.0
    for i in range(x.shape[1]):
        for j in range(i + 1, x.shape[1]):
            if spread[i] and spread[j]:
                r = float(np.corrcoef(x[:, i], x[:, j])[0, 1])
                if r > limit:
                    warnings.append(
                        f"the samples' {names[i]} and {names[j]} rise together (correlation {r:.3f}): the fit cannot tell "
                        "their costs apart; calibrate on a scene whose frames vary them independently (many objects of "
                        "different sizes) for a model that holds beyond these frames"
                    )
    warnings += [f"the samples' {names[i]} never vary: its cost is not measured" for i in np.flatnonzero(~spread)]
    return warnings


def _median_ms(renderer: MeshRenderer, camera: Camera, repeats: int) -> float:
    for _ in range(WARM_UP):  # first-use shader, buffer and binning work stays out of the sample
        renderer.frame_seconds(camera)
    return 1e3 * float(np.median([renderer.frame_seconds(camera) for _ in range(repeats)]))


def _covered(renderer: MeshRenderer, camera: Camera) -> int:
    return int(np.count_nonzero(renderer.render(camera)[..., 3]))


def _camera(eye: np.ndarray, target: np.ndarray, extent: np.ndarray, options: CalibrationOptions) -> Camera:
    forward = (target - eye) / np.linalg.norm(target - eye)
    near, far = depth_bounds(eye, forward, extent)
    return Camera.look_at(eye, target, math.radians(options.fov_deg), options.resolution, near, far)


def calibrate(
    scenes: list[Scene] | tuple[Scene, ...],
    options: CalibrationOptions = CalibrationOptions(),
    progress: Progress | None = None,
) -> Calibration:
    """Measure ``scenes`` on this process's renderer and fit the cost model (see the module docstring).

    Progress stages: ``"geometry"`` (views drawn), ``"impostors"`` (impostors baked and drawn).

    Raises
    ------
    CostModelError
        Too few samples, or a fit that leaves geometry costing nothing.
    RenderBackendError
        No GL context, or a GL error while drawing.
    """
    clock = StageClock(("sample", "geometry", "impostors", "fit"), progress)
    started = datetime.now(UTC)
    with clock("sample"):
        geometry_cases, impostor_cases, skipped = sample_cases(scenes, options)
    target_res = options.resolution

    with clock("geometry"):
        with MeshRenderer([]) as empty:
            probe = Camera.look_at(
                np.zeros(3), np.array([0.0, 1.0, 0.0]), math.radians(options.fov_deg), target_res, 0.1, 10.0
            )
            empty_ms = _median_ms(empty, probe, max(3 * options.repeats, 9))
        geometry: list[GeometrySample] = []
        total_views = sum(len(c.eyes) for c in geometry_cases)
        if options.view_space is not None:
            if len(scenes) != 1:
                raise CostModelError(f"calibration on a view space takes one scene, got {len(scenes)}")
            geometry = view_samples(scenes[0], options, lambda done, total: clock.report("geometry", done, total))
            geometry_cases = []
        for case in geometry_cases:
            scene = scenes[case.scene]
            objects = [scene.objects[i] for i in case.objects]
            bounds = _bounds(scene, case.objects)
            centre, extent = 0.5 * (bounds[0] + bounds[1]), box_corners(bounds)
            triangles = int(sum(o.faces.shape[0] for o in objects))
            with MeshRenderer(objects) as renderer:
                for eye in case.eyes:
                    camera = _camera(eye, centre, extent, options)
                    ms = _median_ms(renderer, camera, options.repeats)
                    # One draw call per object: MeshRenderer renders each object's vertex array once.
                    geometry.append(
                        GeometrySample(
                            case.scene, len(objects), len(objects), triangles, _covered(renderer, camera), ms
                        )
                    )
                    clock.report("geometry", len(geometry), total_views)

    with clock("impostors"):
        impostors: list[ImpostorSample] = []
        memory: list[MemorySample] = []
        bake_options = BakeOptions(resolution=target_res, fov_deg=options.fov_deg)
        for n, case in enumerate(impostor_cases):
            scene = scenes[case.scene]
            part = scene.subset([scene.objects[i].name for i in case.objects])
            start = time.perf_counter()
            try:
                impostor = bake_layered(part, case.cell, bake_options)
            except LayerPlanError:  # e.g. a one-sided part seen only from behind: no texel to keep
                skipped += 1
                clock.report("impostors", n + 1, len(impostor_cases))
                continue
            bake_seconds = time.perf_counter() - start
            stats = impostor.stats
            size = float(np.linalg.norm(part.bounds[1] - part.bounds[0]))
            memory.append(MemorySample(
                case.scene, part.object_count, math.degrees(case.cell.apex_angle), case.cell.min_distance / size,
                case.layers_est, case.texture[0] * case.texture[1], int(stats["layers_planned"]), int(stats["layers"]),
                int(stats["quads"]), int(stats["texture_bytes"]) + int(stats["geometry_bytes"]), bake_seconds,
            ))  # fmt: skip
            drawn = impostor_objects(impostor)
            centre = 0.5 * (part.bounds[0] + part.bounds[1])
            extent = np.concatenate([box_corners(part.bounds), impostor.payload.world_points()])
            with MeshRenderer(drawn) as renderer:
                for eye in case.eyes:
                    camera = _camera(eye, centre, extent, options)
                    frame = _median_ms(renderer, camera, options.repeats)
                    impostors.append(
                        ImpostorSample(
                            len(memory) - 1,
                            _covered(renderer, camera),
                            impostor.quad_count,
                            len(drawn),
                            frame - empty_ms,
                            frame,
                        )
                    )
            clock.report("impostors", n + 1, len(impostor_cases))

    with clock("fit"):
        g = np.array([[s.draw_calls, s.triangles, s.pixels, 1.0] for s in geometry], dtype=np.float64)
        names = ("draw_call", "triangle", "pixel", "frame")
        if options.quantile is None:
            geometry_fit = fit_linear(g, [s.ms for s in geometry], names, options.holdout, options.seed)
        else:
            geometry_fit = fit_quantile(
                g, [s.ms for s in geometry], names, options.quantile, options.holdout, options.seed
            )
        i = np.array([[s.pixels, s.quads, 1.0] for s in impostors], dtype=np.float64)
        impostor_fit = fit_linear(
            i, [s.ms for s in impostors], ("pixel", "quad", "impostor"), options.holdout, options.seed
        )
        layer_texels = [s.layers_est * s.texels_per_layer for s in memory]
        memory_fit = fit_power(
            layer_texels,
            [s.bytes for s in memory],
            ("layer_texel", "exponent", "impostor"),
            options.holdout,
            options.seed,
        )
        quads_fit, q, beta = _quads_law(memory, options)
    seconds = clock.totals()
    fit = {
        "geometry": geometry_fit.to_dict(),
        "impostor": impostor_fit.to_dict(),
        "memory": {**memory_fit.to_dict(), "r2_of": "log(bytes)"},
        "quads": {**quads_fit.to_dict(), "r2_of": "log(quads / layers_est)"},
        "empty_frame_ms": empty_ms,
        "samples": {
            "geometry": len(geometry),
            "impostor": len(impostors),
            "impostors_baked": len(memory),
            "cells_refused": skipped,
        },
        "layers_est_over_planned": _ratio_summary([s.layers_est / s.layers_planned for s in memory]),
        "options": asdict(options),
        "scenes": [{"source": s.source, "objects": s.object_count, "triangles": s.triangle_count} for s in scenes],
        "seconds": {k: round(v, 3) for k, v in seconds.items()},
        "date": started.isoformat(timespec="seconds"),
        "warnings": confounded_terms(g[:, :3], ("draw calls", "triangles", "pixels")),
    }
    h, p, k = memory_fit.coefficients
    if p <= 0.0:
        raise CostModelError(
            f"calibration: memory does not grow with the estimated texels (fit {memory_fit.to_dict()}); give more impostors"
        )
    try:
        model = CostModel("frame_ms", geometry_fit.coefficients, impostor_fit.coefficients, (h, k, q),
                          renderer=renderer_info().renderer, fit=fit, source="calibration", memory_exponent=p,
                          quads_exponent=beta)  # fmt: skip
    except CostModelError as error:
        raise CostModelError(f"calibration: the fit gives no usable model ({error}); give more samples") from None
    return Calibration(model, tuple(geometry), tuple(impostors), tuple(memory), empty_ms, skipped, seconds)


def _quads_law(memory: list[MemorySample], options: CalibrationOptions):
    """(fit, q, beta) of quads per estimated layer as ``q * texels_per_layer ** beta``
    (:meth:`farfield.core.placement.cost_model.CostModel.quads`), beta in [0, 1]: fixed at 1 when the free fit
    is steeper, at 0 when every sample has the same texels per layer (beta is then undetermined)."""
    texels = [s.texels_per_layer for s in memory]
    per_layer = [max(s.quads, 1) / s.layers_est for s in memory]
    names = ("quads_per_layer", "quads_exponent")
    if len(set(texels)) == 1:
        fit = fit_power(texels, per_layer, names[:1], options.holdout, options.seed, exponent=0.0, offset=False)
        return fit, fit.coefficients[0], 0.0
    fit = fit_power(texels, per_layer, names, options.holdout, options.seed, offset=False)
    if fit.coefficients[1] > 1.0:
        fit = fit_power(texels, per_layer, names[:1], options.holdout, options.seed, exponent=1.0, offset=False)
        return fit, fit.coefficients[0], 1.0
    return fit, fit.coefficients[0], fit.coefficients[1]


def _ratio_summary(values: list[float]) -> dict:
    v = np.asarray(values, dtype=np.float64)
    return {"median": float(np.median(v)), "min": float(v.min()), "max": float(v.max())}

"""What the part-scope techniques (layered, tdm) share: the layer-plan check of a job's cells, the
evaluation of a part's impostor against the part's real geometry from inside its view cell, and the
short evaluation a job records for each of its cells."""

from __future__ import annotations

import json
import math

import numpy as np

from farfield.core.constants import TOL
from farfield.core.errors import LayerPlanError, PlanBudgetError, ViewCellError
from farfield.core.impostor.impostor import Impostor
from farfield.core.layering.plan import estimate_layers, first_layer_texels, first_layer_texels_of_boxes, plan_layers
from farfield.core.quality.evaluation import Evaluation, evaluate, evaluate_at, spread_corners
from farfield.core.scene import Scene
from farfield.core.techniques.base import CellCost
from farfield.core.viewcells import BoxCell, BoxCells, ViewCell, viewcell_from_dict


def layer_budget(options) -> dict:
    """The error budget of a part technique's ``options`` as :func:`~farfield.core.layering.plan.plan_layers`
    takes it: ``pixel_model``, ``texel_share`` and ``max_error_px``.

    ``budget="thesis"`` is seed 000's own (§3.3): texels and parallax each within the centre
    pixel's angle, which reproduces Table 4.1; ``"strict"`` (the default) bounds the error from
    the smallest pixel angle and, where the technique shares the budget (``texel_share``), keeps
    the grown silhouette and its parallax together within ``max_error_px``.

    >>> from farfield.core.techniques.layered import BakeOptions
    >>> layer_budget(BakeOptions()), layer_budget(BakeOptions(budget="thesis", max_error_px=2.0))
    ({'pixel_model': 'min', 'texel_share': 0.7, 'max_error_px': 1.0}, {'pixel_model': 'center', 'texel_share': None, 'max_error_px': 2.0})
    """
    max_error_px = float(getattr(options, "max_error_px", 1.0))
    if getattr(options, "budget", "strict") == "thesis":
        return {"pixel_model": "center", "texel_share": None, "max_error_px": max_error_px}
    return {
        "pixel_model": options.pixel_model,
        "texel_share": getattr(options, "texel_share", None),
        "max_error_px": max_error_px,
    }


def check_part_cell(cell: ViewCell, options, bounds: np.ndarray | None, max_texels: int | None = None) -> CellCost:
    """Plan the layers of the part (``bounds``) seen from ``cell`` as the bake will (raises when
    there is no answer); the cell's cost is the plan's layers of its texture resolution.  Past
    ``max_texels`` the planning stops (:func:`farfield.core.layering.plan.plan_layers`) and the cost says at least.

    >>> from farfield.core.techniques.layered import BakeOptions
    >>> from farfield.core.viewcells import BoxCell
    >>> cell, part = BoxCell([-1.0, 0.0, -1.0], [1.0, 2.0, 1.0]), np.array([[-5.0, 0.0, 20.0], [5.0, 10.0, 30.0]])
    >>> small, large = (check_part_cell(cell, BakeOptions(resolution=r), part) for r in (256, 1024))
    >>> small.describe(), large.describe()
    ('21 layers of 315x297', '82 layers of 1260x1188')
    >>> large.texels == 82 * 1260 * 1188, large.bytes == 4 * large.texels
    (True, True)
    >>> check_part_cell(cell, BakeOptions(resolution=1024), part, max_texels=10**7).describe()
    'at least 7 layers of 1254x1188'
    """
    fov = math.radians(options.fov_deg)
    try:
        plan = plan_layers(cell, bounds, fov, options.resolution, max_texels=max_texels, **layer_budget(options))
    except PlanBudgetError as over:
        return CellCost.of_layers(over.layers, over.texture, complete=False)
    return CellCost.of_layers(plan.count, plan.texture_resolution)


def bound_part_cells(cells: list[ViewCell] | BoxCells, options, bounds: np.ndarray | None) -> np.ndarray:
    """(n,) int64: per cell a lower bound of :func:`check_part_cell`'s texels, one layer of the
    plan's texture (:func:`farfield.core.layering.plan.first_layer_texels`), the box cells (or a
    grid's :class:`~farfield.core.viewcells.BoxCells`) at once in numpy (some 4 µs a cell against the plan's tens of milliseconds); raises LayerPlanError
    naming the first cell whose part geometry has no plan (0 for every cell without ``bounds``).

    >>> from farfield.core.techniques.layered import BakeOptions
    >>> cells, part = [BoxCell([-1.0, 0.0, -1.0], [1.0, 2.0, 1.0])], np.array([[-5.0, 0.0, 20.0], [5.0, 10.0, 30.0]])
    >>> bound = bound_part_cells(cells, BakeOptions(resolution=256), part)
    >>> bound.tolist(), check_part_cell(cells[0], BakeOptions(resolution=256), part).texels >= int(bound[0])
    ([93258], True)
    """
    out = np.zeros(len(cells), dtype=np.int64)
    if bounds is None or not cells:
        return out
    fov, budget = math.radians(options.fov_deg), layer_budget(options)
    if isinstance(cells, BoxCells):  # a grid's, as arrays
        boxes, others, lo, hi = np.arange(len(cells)), [], cells.lo, cells.hi
    else:
        boxes = [n for n, cell in enumerate(cells) if isinstance(cell, BoxCell)]
        others = [n for n, cell in enumerate(cells) if not isinstance(cell, BoxCell)]
        lo = np.array([cells[n].lo for n in boxes]).reshape(-1, 3)
        hi = np.array([cells[n].hi for n in boxes]).reshape(-1, 3)
    if len(boxes):
        texels, trouble = first_layer_texels_of_boxes(lo, hi, bounds, fov, options.resolution, **budget)
        out[boxes] = texels
        others += [boxes[k] for k in np.flatnonzero(trouble)]
    for n in sorted(others):  # one at a time: it answers, or raises the plan's own error
        try:
            out[n] = first_layer_texels(cells[n], bounds, fov, options.resolution, **budget)
        except (LayerPlanError, ViewCellError) as error:
            raise type(error)(f"view cell {n} {json.dumps(cells[n].to_dict())}: {error}") from None
    return out


def estimate_part_cell(cell: ViewCell, options, bounds: np.ndarray) -> tuple[float, float]:
    """The placement's estimate for the part in ``bounds`` seen from ``cell``: layers (estimated,
    :func:`farfield.core.layering.plan.estimate_layers`) and texels per layer (exact), without planning every layer;
    LayerPlanError where a layer's texture passes what every renderer draws
    (``TOL.drawable_texture_resolution``: a placement may not choose what a worker cannot bake)."""
    layers, res = estimate_layers(
        cell, bounds, math.radians(options.fov_deg), options.resolution, **layer_budget(options)
    )
    if max(res) > TOL.drawable_texture_resolution:
        raise LayerPlanError(
            f"a layer texture of {int(res[0])} x {int(res[1])} texels is more than every renderer draws "
            f"({TOL.drawable_texture_resolution} per side): the cell is too close to the part"
        )
    return layers, float(res[0]) * float(res[1])


def evaluate_part(scene: Scene, impostor: Impostor, random_count: int, outside_count: int, seed: int) -> Evaluation:
    """The impostor against its part (the bundle's objects of ``scene``) from its cell's corners, the
    reference viewpoint, ``random_count`` seeded points inside and ``outside_count`` outside."""
    names = impostor.parameters.get("objects")
    part = scene.subset(names) if names else scene
    return evaluate(part, impostor, viewcell_from_dict(impostor.viewcell), random_count, outside_count, seed)


# The job report's evaluation of a cell (:func:`report_part`): the reference viewpoint and this many
# cell corners far apart, at this many samples per pixel side.  Few and modest, so it adds little to
# a cell's bake; ``farfield evaluate`` samples the cell more densely.
REPORT_CORNERS = 3
REPORT_SAMPLES = 2
# The figures of the evaluation's totals a job's cell record keeps.
REPORT_FIGURES = (
    "viewpoints", "hole_pixels", "bloat_beyond_1px", "colour_error_mean", "colour_error_p99", "colour_error_max",
    "colour_error_1px_mean", "ssim", "ssim_min",
)  # fmt: skip


# The lit evaluation's totals a lit impostor's cell record keeps (under ``lit``), beside the worst
# light's mean lit colour error.
LIT_REPORT_FIGURES = ("lit_to_unlit_worst", "flat_to_lit_least", "normal_error_median", "normal_error_smooth_p95")


def report_part(scene: Scene, impostor: Impostor, corners: int = REPORT_CORNERS, samples: int = REPORT_SAMPLES) -> dict:
    """The evaluation a job records for one baked cell: the impostor against its part from its
    reference viewpoint and ``corners`` corners of its cell far apart (:func:`farfield.core.quality.evaluation.spread_corners`),
    with ``samples`` per pixel side.

    Returns the totals named in :data:`REPORT_FIGURES` (see :mod:`farfield.core.quality.evaluation`), plus
    ``samples`` and ``seconds`` (the time the evaluation took, apart from the bake's); for an
    impostor with normals also ``lit``: :data:`LIT_REPORT_FIGURES` and ``lit_error_mean_worst`` of
    the same views lit (:mod:`farfield.core.quality.lit`).
    """
    names = impostor.parameters.get("objects")
    part = scene.subset(names) if names else scene
    reference = np.asarray(impostor.reference_viewpoint, dtype=np.float64)
    chosen = spread_corners(viewcell_from_dict(impostor.viewcell), reference, corners)
    points = np.concatenate([reference[None, :], chosen])
    kinds = ["reference"] + ["corner"] * len(chosen)
    result = evaluate_at(part, impostor, points, kinds, samples)
    report = {**{k: result.totals[k] for k in REPORT_FIGURES}, "samples": samples, "seconds": result.seconds}
    if "normal" in impostor.channels:  # a lit impostor: the same views, lit (farfield.core.quality.lit)
        from farfield.core.quality.lit import evaluate_lit_at

        lit = evaluate_lit_at(part, impostor, points, kinds, samples)
        report["lit"] = {k: lit.totals[k] for k in LIT_REPORT_FIGURES} | {
            "lit_error_mean_worst": max(row["lit_error_mean"] for row in lit.totals["lights"])
        }
        report["seconds"] += lit.seconds
    return report


def part_evaluation_text(result: Evaluation, impostor: Impostor) -> str:
    """Per viewpoint: geometry pixels, holes, bloat, colour error (per pixel: mean and 99th
    percentile, 0-255; within one pixel: mean), SSIM; then the totals and the impostor's size."""
    lines = [
        f"{'kind':<10} {'geometry':>9} {'holes':>6} {'bloat':>6} {'>1px':>6} {'err mean':>9} {'err p99':>8} {'1px mean':>9} {'ssim':>6}"
    ]
    for row in result.viewpoints:
        s = row["stats"]
        lines.append(
            f"{row['kind']:<10} {s['geometry_pixels']:>9} {s['hole_pixels']:>6} {s['bloat_pixels']:>6} {s['bloat_beyond_1px']:>6} "
            f"{s['colour_error_mean']:>9.2f} {s['colour_error_p99']:>8.1f} {s['colour_error_1px_mean']:>9.2f} {s['ssim']:>6.3f}"
        )
    t = result.totals
    lines.append(
        f"inside the view cell: {t['viewpoints']} viewpoints, {t['hole_pixels']} hole pixels, {t['bloat_beyond_1px']} pixels bloated beyond 1 px, "
        f"colour error mean {t['colour_error_mean']:.2f} (99th percentile {t['colour_error_p99']:.1f}; within one pixel {t['colour_error_1px_mean']:.2f}), "
        f"SSIM {t['ssim']:.3f} (worst view {t['ssim_min']:.3f})"
    )
    if "outside" in t:
        lines.append(
            f"outside the view cell: {t['outside']['viewpoints']} viewpoints, {t['outside']['hole_pixels']} hole pixels"
        )
    channel = sum(p.nbytes for pages in impostor.channels.values() for p in pages)  # the channels' pages, where kept
    memory = impostor.texture_bytes + channel + impostor.stats.get("geometry_bytes", 0)
    lines.append(
        f"impostor ({impostor.technique}): "
        + (
            f"{impostor.stats.get('layers')} layers, {impostor.triangle_count:,} triangles, "
            if impostor.triangle_count
            else "".join(f"{v:,} {k}, " for k, v in impostor.payload.counts().items())
        )
        + f"{memory / 1024:.1f} KiB (atlas pages {impostor.texture_bytes / 1024:.1f} KiB"
        + (f" + {' + '.join(impostor.channels)} pages {channel / 1024:.1f} KiB" if channel else "")
        + " + geometry)"
    )
    return "\n".join(lines)

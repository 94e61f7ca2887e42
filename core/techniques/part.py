"""What the part-scope techniques (layered, tdm) share: the layer-plan check of a job's cells, the
evaluation of a part's impostor against the part's real geometry from inside its view cell, and the
short evaluation a job records for each of its cells."""

from __future__ import annotations

import math

import numpy as np

from farfield.core.evaluation import Evaluation, evaluate, evaluate_at, spread_corners
from farfield.core.impostor import Impostor
from farfield.core.layers import plan_layers
from farfield.core.scene import Scene
from farfield.core.viewcells import ViewCell, viewcell_from_dict


def check_part_cell(cell: ViewCell, options, bounds: np.ndarray | None) -> None:
    """Plan the layers of the part (``bounds``) seen from ``cell`` (raises when there is no answer)."""
    plan_layers(cell, bounds, math.radians(options.fov_deg), options.resolution, options.pixel_model, texel_share=getattr(options, "texel_share", None))


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


def report_part(scene: Scene, impostor: Impostor, corners: int = REPORT_CORNERS, samples: int = REPORT_SAMPLES) -> dict:
    """The evaluation a job records for one baked cell: the impostor against its part from its
    reference viewpoint and ``corners`` corners of its cell far apart (:func:`core.evaluation.spread_corners`),
    with ``samples`` per pixel side.

    Returns the totals named in :data:`REPORT_FIGURES` (see :mod:`core.evaluation`), plus
    ``samples`` and ``seconds`` (the time the evaluation took, apart from the bake's).
    """
    names = impostor.parameters.get("objects")
    part = scene.subset(names) if names else scene
    reference = np.asarray(impostor.reference_viewpoint, dtype=np.float64)
    chosen = spread_corners(viewcell_from_dict(impostor.viewcell), reference, corners)
    points = np.concatenate([reference[None, :], chosen])
    result = evaluate_at(part, impostor, points, ["reference"] + ["corner"] * len(chosen), samples)
    return {**{k: result.totals[k] for k in REPORT_FIGURES}, "samples": samples, "seconds": result.seconds}


def part_evaluation_text(result: Evaluation, impostor: Impostor) -> str:
    """Per viewpoint: geometry pixels, holes, bloat, colour error (per pixel: mean and 99th
    percentile, 0-255; within one pixel: mean), SSIM; then the totals and the impostor's size."""
    lines = [f"{'kind':<10} {'geometry':>9} {'holes':>6} {'bloat':>6} {'>1px':>6} {'err mean':>9} {'err p99':>8} {'1px mean':>9} {'ssim':>6}"]
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
        lines.append(f"outside the view cell: {t['outside']['viewpoints']} viewpoints, {t['outside']['hole_pixels']} hole pixels")
    memory = impostor.texture_bytes + impostor.stats.get("geometry_bytes", 0)
    lines.append(
        f"impostor ({impostor.technique}): {impostor.stats.get('layers')} layers, {impostor.triangle_count:,} triangles, "
        f"{memory / 1024:.1f} KiB (atlas pages {impostor.texture_bytes / 1024:.1f} KiB + geometry)"
    )
    return "\n".join(lines)

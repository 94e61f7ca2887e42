"""What the part-scope techniques (layered, tdm) share: the layer-plan check of a job's cells, and the
evaluation of a part's impostor against the part's real geometry from inside its view cell."""

from __future__ import annotations

import math

import numpy as np

from farfield.core.evaluation import Evaluation, evaluate
from farfield.core.impostor import Impostor
from farfield.core.layers import plan_layers
from farfield.core.scene import Scene
from farfield.core.viewcells import ViewCell, viewcell_from_dict


def check_part_cell(cell: ViewCell, options, bounds: np.ndarray | None) -> None:
    """Plan the layers of the part (``bounds``) seen from ``cell`` (raises when there is no answer)."""
    plan_layers(cell, bounds, math.radians(options.fov_deg), options.resolution, options.pixel_model)


def evaluate_part(scene: Scene, impostor: Impostor, random_count: int, outside_count: int, seed: int) -> Evaluation:
    """The impostor against its part (the bundle's objects of ``scene``) from its cell's corners, the
    reference viewpoint, ``random_count`` seeded points inside and ``outside_count`` outside."""
    names = impostor.parameters.get("objects")
    part = scene.subset(names) if names else scene
    return evaluate(part, impostor, viewcell_from_dict(impostor.viewcell), random_count, outside_count, seed)


def part_evaluation_text(result: Evaluation, impostor: Impostor) -> str:
    """Per viewpoint: geometry pixels, holes, bloat, colour error; then the totals and the impostor's size."""
    lines = [f"{'kind':<10} {'geometry':>9} {'holes':>6} {'bloat':>6} {'>1px':>6} {'err mean':>9} {'err max':>8}"]
    for row in result.viewpoints:
        s = row["stats"]
        lines.append(
            f"{row['kind']:<10} {s['geometry_pixels']:>9} {s['hole_pixels']:>6} {s['bloat_pixels']:>6} "
            f"{s['bloat_beyond_1px']:>6} {s['colour_error_mean']:>9.2f} {s['colour_error_max']:>8}"
        )
    t = result.totals
    lines.append(f"inside the view cell: {t['viewpoints']} viewpoints, {t['hole_pixels']} hole pixels, colour error mean {t['colour_error_mean']:.2f}")
    if "outside" in t:
        lines.append(f"outside the view cell: {t['outside']['viewpoints']} viewpoints, {t['outside']['hole_pixels']} hole pixels")
    memory = impostor.texture_bytes + impostor.stats.get("geometry_bytes", 0)
    lines.append(
        f"impostor ({impostor.technique}): {impostor.stats.get('layers')} layers, {impostor.triangle_count:,} triangles, "
        f"{memory / 1024:.1f} KiB (atlas pages {impostor.texture_bytes / 1024:.1f} KiB + geometry)"
    )
    return "\n".join(lines)

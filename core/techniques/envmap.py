"""Layered environment-map impostors (seed 002): the whole scene beyond a near-field cube around a
cubic view cell, as layers on the six (or fewer) cube faces."""

from __future__ import annotations

from core.envmap import EnvmapOptions, bake_envmap, plan_envmap
from core.errors import ViewCellError
from core.runtime import evaluate_envmap
from core.techniques.base import Technique
from core.techniques.part import seconds_line
from core.viewcells import BoxCell


def _check(cell, options, bounds) -> None:
    if not isinstance(cell, BoxCell):
        raise ViewCellError(f"an envmap impostor needs a cubic box view cell, got a {cell.to_dict()['kind']!r} cell")
    plan_envmap(cell, options)


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
    lines.append(f"inside the view cell: {t['views']} views, {t['hole_pixels']} hole pixels, colour error mean {t['colour_error_mean']:.3f}")
    lines.append(
        f"impostor: {stats.get('faces')} faces, {stats.get('layers')} layers, {stats.get('quads')} quads, "
        f"near field {stats.get('near_field'):.6g} ({stats.get('near_field_triangles')} triangles), "
        f"{stats.get('texture_bytes', 0) / 1024:.1f} KiB texture, {stats.get('png_bytes', 0) / 1024:.1f} KiB PNG"
    )
    return "\n".join(lines)


TECHNIQUE = Technique(
    name="envmap",
    scope="scene",
    help="layered environment-map impostors of the whole scene around cubic box view cells (seed 002)",
    Options=EnvmapOptions,
    check=_check,
    bake=_bake,
    summary=_summary,
    evaluate=_evaluate,
    evaluation_text=_evaluation_text,
)

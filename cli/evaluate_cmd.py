"""``farfield evaluate``: compare a baked bundle with the real geometry from inside (and outside) its view cell."""

from __future__ import annotations

import json
from pathlib import Path

import click

from core.bundle import read_bundle
from core.evaluation import evaluate as run_evaluation
from core.runtime import evaluate_envmap
from core.exchange import load_scene
from core.viewcells import viewcell_from_dict


@click.command("evaluate")
@click.argument("bundle", type=click.Path(file_okay=False))
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("--random", "random_count", default=16, show_default=True, type=int, help="Random viewpoints inside the cell.")
@click.option("--outside", "outside_count", default=4, show_default=True, type=int, help="Viewpoints just outside the cell.")
@click.option("--seed", default=0, show_default=True, type=int)
@click.option("--json", "as_json", is_flag=True, help="Per-viewpoint results as JSON.")
def evaluate(bundle, scene, random_count, outside_count, seed, as_json):
    """Render SCENE's part and the impostor in BUNDLE from sampled viewpoints and report the errors."""
    impostor = read_bundle(Path(bundle))
    part = load_scene(scene)
    if impostor.technique == "envmap":
        _evaluate_envmap(part, impostor, random_count, seed, as_json)
        return
    names = impostor.parameters.get("objects")
    if names:
        part = part.subset(names)
    cell = viewcell_from_dict(impostor.viewcell)
    result = run_evaluation(part, impostor, cell, random_count, outside_count, seed)
    if as_json:
        click.echo(json.dumps(result.to_dict(), indent=2))
        return
    click.echo(f"{'kind':<10} {'geometry':>9} {'holes':>6} {'bloat':>6} {'>1px':>6} {'err mean':>9} {'err max':>8}")
    for row in result.viewpoints:
        s = row["stats"]
        click.echo(
            f"{row['kind']:<10} {s['geometry_pixels']:>9} {s['hole_pixels']:>6} {s['bloat_pixels']:>6} "
            f"{s['bloat_beyond_1px']:>6} {s['colour_error_mean']:>9.2f} {s['colour_error_max']:>8}"
        )
    t = result.totals
    click.echo(f"inside the view cell: {t['viewpoints']} viewpoints, {t['hole_pixels']} hole pixels, colour error mean {t['colour_error_mean']:.2f}")
    if "outside" in t:
        click.echo(f"outside the view cell: {t['outside']['viewpoints']} viewpoints, {t['outside']['hole_pixels']} hole pixels")
    stats = impostor.stats
    click.echo(f"impostor: {stats.get('layers')} layers, {stats.get('quads')} quads, {stats.get('texture_bytes', 0) / 1024:.1f} KiB texture")


def _evaluate_envmap(scene, impostor, random_count: int, seed: int, as_json: bool) -> None:
    """An envmap bundle: the whole scene vs near field + impostors, from inside the cell in every recorded direction."""
    result = evaluate_envmap(scene, impostor, random_count=random_count, seed=seed)
    if as_json:
        click.echo(json.dumps(result, indent=2))
        return
    click.echo(f"{'kind':<7} {'forward':<20} {'geometry':>9} {'holes':>6} {'>1px':>6} {'err mean':>9} {'err max':>8}")
    for row in result["views"]:
        s = row["stats"]
        forward = ",".join(f"{c:+.2f}" for c in row["forward"])
        click.echo(
            f"{row['kind']:<7} {forward:<20} {s['geometry_pixels']:>9} {s['hole_pixels']:>6} "
            f"{s['bloat_beyond_1px']:>6} {s['colour_error_mean']:>9.2f} {s['colour_error_max']:>8}"
        )
    t = result["totals"]
    stats = impostor.stats
    click.echo(f"inside the view cell: {t['views']} views, {t['hole_pixels']} hole pixels, colour error mean {t['colour_error_mean']:.3f}")
    click.echo(
        f"impostor: {stats.get('faces')} faces, {stats.get('layers')} layers, {stats.get('quads')} quads, "
        f"near field {stats.get('near_field'):.6g} ({stats.get('near_field_triangles')} triangles), "
        f"{stats.get('texture_bytes', 0) / 1024:.1f} KiB texture, {stats.get('png_bytes', 0) / 1024:.1f} KiB PNG"
    )

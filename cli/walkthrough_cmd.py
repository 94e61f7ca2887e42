"""``farfield walkthrough``: a camera path through an impostor database, runtime vs full scene, frame by frame.

An envmap job's database is walked by the envmap runtime (near field + impostors); a placement
database (its index has a ``placement`` section) by the placement runtime (the CPV's impostors and
the elements they do not replace), against plain geometry, with the frame budget t_max; a
primitive-budget database (``farfield place --algorithm primitive-budget --bake``) by seed 004's run
time (the grid point's LDI warped, the rest frustum-culled geometry), with the primitives of every
view against the budget P.
"""

from __future__ import annotations

import json
from pathlib import Path

import click
import numpy as np
from tqdm import tqdm

from farfield.cli import sides_option
from farfield.core.errors import FarfieldError
from farfield.core.exchange import load_scene
from farfield.core.impostor.database import ImpostorDatabase
from farfield.core.placement.image_database import ImageDatabase, image_database_folder, image_walkthrough
from farfield.core.quality.lighting import default_lights, sun
from farfield.core.quality.lit import LitEvaluation, lit_text
from farfield.core.quality.walkthrough import (
    generate_path,
    load_path,
    random_views,
    walkthrough,
    write_image_plot,
    write_placement_plot,
    write_plot,
)


@click.command("walkthrough")
@click.argument("database", type=click.Path(exists=True))
@click.argument("scene", type=click.Path(dir_okay=False, exists=True))
@click.option(
    "--path",
    "path_file",
    default=None,
    type=click.Path(dir_okay=False, exists=True),
    help="Recorded camera path: JSON list of {position, forward}. Default: a generated loop.",
)
@click.option(
    "--frames", default=120, show_default=True, type=click.IntRange(min=1), help="Frames of the generated loop."
)
@click.option(
    "--random",
    "random_count",
    default=None,
    type=click.IntRange(min=1),
    help="Placement databases: this many random views instead of a path (positions uniform in the view space, directions uniform on the sphere).",
)
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0), help="Seed of --random.")
@click.option(
    "--repeats",
    default=3,
    show_default=True,
    type=click.IntRange(min=1),
    help="Draws per frame and renderer; the median counts.",
)
@click.option(
    "--plot", default=None, type=click.Path(dir_okay=False), help="Write a PNG of frame time and error along the path."
)
@click.option("--no-compare", is_flag=True, help="Frame times only (no image comparison).")
@click.option(
    "--lit",
    is_flag=True,
    help="Envmap databases: also draw every served frame lit (G-buffers shaded under the lit evaluation's "
    "lights) and report the lit error beside the unlit one, the flat cards' and the far field's, with the "
    "G-buffer draw and shading times.",
)
@click.option(
    "--light-azimuth",
    default=None,
    type=float,
    help="With --lit: one sun at this azimuth (degrees; 0 along +x, 90 along -z, y up, as the 3D view's) instead "
    "of the five test lights.  [default with --light-elevation alone: 60]",
)
@click.option(
    "--light-elevation",
    default=None,
    type=click.FloatRange(-90.0, 90.0),
    help="With --lit: the sun's elevation (degrees above the horizon).  [default with --light-azimuth alone: 35]",
)
@click.option(
    "--no-pvs",
    is_flag=True,
    help="Placement databases planned with visibility: draw every element in the frustum, not only the "
    "stored potentially visible set of the eye's region (to compare).",
)
@click.option("--json", "as_json", is_flag=True, help="Every frame and the summary as JSON.")
@sides_option
def walkthrough_cmd(database, scene, path_file, frames, random_count, seed, repeats, plot, no_compare, lit,
                    light_azimuth, light_elevation, no_pvs, as_json, sides):  # fmt: skip
    """Walk a camera path through DATABASE (a job's database.zip or its unpacked folder) and compare
    the reference runtime with SCENE drawn in full: an envmap database's near field + impostors, or
    a placement database's impostors + remaining geometry against its frame budget."""
    if plot and not Path(plot).resolve().parent.is_dir():  # before the walk, not after it
        raise FarfieldError(f"--plot {plot}: the folder {Path(plot).resolve().parent} does not exist")
    lights = _lights(lit, light_azimuth, light_elevation)
    loaded = load_scene(scene, sides=sides)
    with image_database_folder(Path(database)) as images:
        if images is not None and lights is not None:
            raise click.UsageError(_NOT_LIT)
        if images is not None:  # a primitive-budget database (farfield place --bake, or a job's)
            _walk_images(
                images,
                loaded,
                path_file,
                frames,
                random_count,
                seed,
                repeats,
                no_compare,
                as_json,
                plot,
                name=Path(database).name,
            )
            return
    with ImpostorDatabase(Path(database)) as db:
        placement = db.placement
        if random_count is not None and not placement:
            raise click.UsageError("--random needs a placement database (an envmap database is walked along a path)")
        if random_count is not None and path_file:
            raise click.UsageError("give --random or --path, not both")
        if placement and lights is not None:
            raise click.UsageError(_NOT_LIT)
        if random_count is not None:
            lo, hi = np.asarray(placement["parameters"]["view_space"], dtype=np.float64).reshape(2, 3)
            positions, forwards = random_views(lo, hi, random_count, seed)
        else:
            positions, forwards = load_path(path_file) if path_file else generate_path(db, frames)
        bar = tqdm(total=len(positions), desc="frames", unit="frame", leave=False, disable=True if as_json else None)
        try:
            result = walkthrough(loaded, db, positions, forwards, repeats=repeats, compare=not no_compare,
                                 progress=lambda done, total: bar.update(done - bar.n), lights=lights,
                                 visibility=not no_pvs)  # fmt: skip
        finally:
            bar.close()
    if placement:
        if plot:
            write_placement_plot(result, plot, title=f"{Path(scene).name}: placement runtime vs plain geometry")
        if as_json:
            click.echo(json.dumps(result, indent=1))
            return
        _print_placement(result, plot)
        return
    if plot:
        write_plot(result, plot, title=f"{Path(scene).name}: full scene vs near field + impostors")
    if as_json:
        click.echo(json.dumps(result, indent=1))
        return
    click.echo(
        f"{'frame':>5} {'cell':>5} {'full ms':>8} {'imp ms':>8} {'speedup':>7} {'holes':>6} {'err mean':>8} {'err max':>7}"
        + (_LIT_HEAD if lights is not None else "")
    )
    for f in result["frames"]:
        fast = f.get("impostor_ms")
        speedup = f"{f['full_ms'] / fast:.1f}x" if fast else "-"
        click.echo(
            f"{f['frame']:>5} {'-' if f['cell'] is None else f['cell']:>5} {f['full_ms']:>8.2f} "
            f"{'-' if fast is None else f'{fast:.2f}':>8} {speedup:>7} "
            f"{f.get('hole_pixels', '-'):>6} {f.get('colour_error_mean', float('nan')):>8.3f} {f.get('colour_error_max', '-'):>7}"
            + (_lit_columns(f.get("lit")) if lights is not None else "")
            + ("  <- cell switch" if f["switched"] else "")
        )
    s = result["summary"]
    line = f"{s['frames']} frames, {s['frames_served']} served by impostors, {s['cell_switches']} cell switches"
    if s["frames_served"]:
        line += f"; mean frame {s['full_ms_mean']:.2f} ms full vs {s['impostor_ms_mean']:.2f} ms impostors ({s['speedup_mean']:.1f}x)"
    if "hole_pixels" in s:
        line += f"; {s['hole_pixels']} hole pixels, colour error mean {s['colour_error_mean']:.3f}, max {s['colour_error_max']}"
    click.echo(line)
    if "lit" in s:
        _print_lit(s["lit"])
    if plot:
        click.echo(f"plot: {plot}")


_NOT_LIT = (
    "--lit needs an envmap database: placement and primitive-budget databases hold colour-only impostors "
    "(placement jobs bake channels=albedo)"
)
# The lit columns of a frame (worst light): the lit error of the whole frame and of the far field
# alone, the flat cards' (far field), and the G-buffer draw and GL shading pass times.
_LIT_HEAD = f" {'lit err':>7} {'far lit':>7} {'far flat':>8} {'gbuf ms':>7} {'shade ms':>8}"


def _lights(lit: bool, azimuth: float | None, elevation: float | None):
    """The lights of ``--lit``: the five test lights, or one sun where an angle is given; None unlit."""
    if not lit:
        if azimuth is not None or elevation is not None:
            raise click.UsageError("--light-azimuth and --light-elevation need --lit")
        return None
    if azimuth is None and elevation is None:
        return default_lights()
    return (sun(60.0 if azimuth is None else azimuth, 35.0 if elevation is None else elevation),)


def _lit_columns(row: dict | None) -> str:
    if row is None:
        return ""

    def num(name, width, fmt=".2f"):
        return f" {format(row[name], fmt) if name in row else '-':>{width}}"

    return (
        num("lit_error_mean", 7)
        + num("far_lit_error_mean", 7)
        + num("far_flat_error_mean", 8)
        + num("impostor_gbuffer_ms", 7)
        + num("shade_gl_ms", 8)
    )


def _print_lit(lit: dict) -> None:
    """The lit totals: per light the whole frame's and the far field's (the lit evaluation's table,
    :func:`farfield.core.quality.lit.lit_text`), the times, and the flat-cards note."""
    if "lights" in lit:
        for title, totals in (("whole frames", lit), ("far field (what the near field leaves)", lit["far"])):
            text = lit_text(LitEvaluation([], totals, lit["sources"]))
            click.echo(f"lit, {title}, {totals['viewpoints']} frames; " + text.splitlines()[0].split("; ", 1)[1])
            click.echo("\n".join(text.splitlines()[1:]))
    click.echo(
        f"lit frame (GL): G-buffer draw {lit['impostor_gbuffer_ms_mean']:.2f} ms near field + impostors vs "
        f"{lit['full_gbuffer_ms_mean']:.2f} ms full scene, then a shading pass of {lit['shade_gl_ms_mean']:.2f} ms "
        f"a light (per pixel, the same for both); numpy's shading of the figures {lit['shade_ms_mean']:.2f} ms a "
        "light (a measurement artefact, not a runtime cost)"
    )
    if "note" in lit:
        click.echo(f"note: {lit['note']}")


def _print_placement(result: dict, plot: str | None) -> None:
    s = result["summary"]
    unit = s["unit"]
    click.echo(
        f"{'frame':>5} {'cpv':>6} {'status':<12} {'plain ms':>8} {'run ms':>8} {'speedup':>7} {'estimate':>9} {'imp':>4} {'holes':>6} {'err mean':>8}"
    )
    for f in result["frames"]:
        speedup = f"{f['plain_ms'] / f['runtime_ms']:.1f}x" if f["runtime_ms"] > 0 else "-"
        over = "  <- over t_max" if not f["within_t_max"] else ""
        click.echo(
            f"{f['frame']:>5} {'-' if f['cpv'] is None else f['cpv']:>6} {f['status']:<12} {f['plain_ms']:>8.2f} {f['runtime_ms']:>8.2f} "
            f"{speedup:>7} {f['estimate']:>9.4g} {f['impostors']:>4} {f.get('hole_pixels', '-'):>6} "
            f"{f.get('colour_error_mean', float('nan')):>8.3f}{over}"
        )

    def pct(x):
        return "-" if x is None else f"{100.0 * x:.1f} %"

    def num(x, fmt=".2f"):
        return "-" if x is None else format(x, fmt)

    click.echo(
        f"{s['frames']} frames; t_max {s['t_max']:.4g} {unit}: {pct(s['share_within_t_max'])} measured within, "
        f"{pct(s['share_estimate_within_t_max'])} by the estimate ({pct(s['share_estimate_within_t_max_solvable'])} of solvable views); "
        f"statuses {s['statuses']}"
    )
    click.echo(
        f"runtime frame ms p50 {num(s['runtime_ms_p50'])}, p99 {num(s['runtime_ms_p99'])}, max {num(s['runtime_ms_max'])}; "
        f"plain geometry p50 {num(s['plain_ms_p50'])}, p99 {num(s['plain_ms_p99'])}, max {num(s['plain_ms_max'])}; "
        f"speed-up {num(s['speedup_median'], '.1f')}x (median); estimate's error {pct(s['estimate_rel_error_median'])} (median relative)"
    )
    ratios = [(label, s.get(key)) for label, key in (("all frames", "estimate_over_measured"), ("in no CPV", "estimate_over_measured_no_cpv"),
                                                      ("in a CPV", "estimate_over_measured_in_cpv"))]  # fmt: skip
    shown = [
        f"{label} ({r['frames']}) p50 {r['p50']:.2f}, p95 {r['p95']:.2f}, {pct(r['share_under_30'])} under by > 30 %"
        for label, r in ratios
        if r
    ]
    if shown:
        click.echo("estimate ÷ measured: " + "; ".join(shown))
    if "hole_pixels" in s:
        click.echo(
            f"{s['hole_pixels']} hole pixels, colour error mean {s['colour_error_mean']:.3f}, max {s['colour_error_max']}"
        )
    if "frames_with_pvs" in s:
        dropped = (
            f"; {s['pvs_dropped_pixels']} pixels of visible elements it dropped (counted as holes)"
            if "pvs_dropped_pixels" in s
            else ""
        )
        click.echo(
            f"visibility: {s['frames_with_pvs']} frames drew only their region's PVS, {s['pvs_culled_mean']:.1f} elements "
            f"in the frustum left out per frame (mean){dropped}"
        )
    if s["over_t_max"]:
        click.echo(f"{len(s['over_t_max'])} frames over t_max:")
        for f in s["over_t_max"][:20]:
            click.echo(
                f"  frame {f['frame']}: {f['measured']:.4g} {unit}, estimate {f['estimate']:.4g} ({f['status']}, cpv {f['cpv']})"
            )
    if plot:
        click.echo(f"plot: {plot}")


def _walk_images(
    root: Path, scene, path_file, frames, random_count, seed, repeats, no_compare, as_json, plot=None, name=None
) -> None:
    """A primitive-budget database: ``--random`` views (positions uniform in the view space, yaw
    uniform, pitch 0), a recorded path (its forwards' yaw) or a generated loop (an ellipse through
    the view space, looking along it); primitives and frame time per view."""
    db = ImageDatabase(root, scene)
    p = db.placement
    if random_count is not None and path_file:
        raise click.UsageError("give --random or --path, not both")
    if path_file:
        positions, forwards = load_path(path_file)
        yaws = np.arctan2(forwards[:, 0], -forwards[:, 2])
    elif random_count is not None:
        rng = np.random.default_rng(seed)
        positions = p.view_lo + rng.random((random_count, 3)) * (p.view_hi - p.view_lo)
        yaws = rng.random(random_count) * 2.0 * np.pi
    else:  # a generated loop: an ellipse through the view space at mid height, looking where it goes
        if frames < 1:
            raise click.UsageError(f"--frames must be >= 1, got {frames}")
        t = np.linspace(0.0, 2.0 * np.pi, frames, endpoint=False)
        centre, half = 0.5 * (p.view_lo + p.view_hi), 0.45 * (p.view_hi - p.view_lo)
        positions = np.stack(
            [centre[0] + half[0] * np.cos(t), np.full(frames, centre[1]), centre[2] + half[2] * np.sin(t)], axis=1
        )
        yaws = np.arctan2(
            -half[0] * np.sin(t), -half[2] * np.cos(t)
        )  # the tangent (dx, dz) = (-a sin t, c cos t): yaw = atan2(dx, -dz)
    bar = tqdm(total=len(positions), desc="frames", unit="frame", leave=False, disable=True if as_json else None)
    try:
        result = image_walkthrough(
            db,
            positions,
            yaws,
            repeats=repeats,
            compare=not no_compare,
            progress=lambda done, total: bar.update(done - bar.n),
        )
    finally:
        bar.close()
    if plot:
        write_image_plot(result, plot, title=f"{name or root.name}: primitives per view against P (seed 004)")
    if as_json:
        click.echo(json.dumps(result, indent=1))
        return
    click.echo(
        f"{'frame':>5} {'point':>6} {'image':>5} {'primitives':>10} {'plain':>8} {'run ms':>7} {'plain ms':>8} {'holes':>6}"
    )
    for f in result["frames"]:
        over = "  <- over P" if not f["within_p"] else ""
        click.echo(f"{f['frame']:>5} {f['point']:>6} {f['image']:>5} {f['primitives']:>10} {f['plain_primitives']:>8} {f['runtime_ms']:>7.2f} "
                   f"{f['plain_ms']:>8.2f} {f.get('hole_pixels', '-'):>6}{over}")  # fmt: skip
    s = result["summary"]
    click.echo(f"{s['views']} views; P {s['primitives_budget']:.6g} (p_opt {s['p_opt']:.6g}): {100 * s['share_within_p']:.2f} % within, primitives p99 "
               f"{s['primitives_p99']:.0f}, max {s['primitives_max']:.0f} (plain geometry's max {s['plain_primitives_max']:.0f}); {s['views_with_image']} views warp an LDI")  # fmt: skip
    click.echo(
        f"frame ms p50 {s['runtime_ms_p50']:.2f}, p99 {s['runtime_ms_p99']:.2f}; plain frustum-culled geometry p50 {s['plain_ms_p50']:.2f}, p99 {s['plain_ms_p99']:.2f}"
    )
    if "hole_pixels" in s:
        click.echo(
            f"{s['hole_pixels']} hole pixels in {s['views_with_holes']} views, colour error mean {s['colour_error_mean']:.3f}"
        )
    if plot:
        click.echo(f"plot: {plot}")

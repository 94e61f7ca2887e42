"""``farfield walkthrough``: a camera path through an envmap impostor database, runtime vs full scene, frame by frame."""

from __future__ import annotations

import json
from pathlib import Path

import click
from tqdm import tqdm

from farfield.core.exchange import load_scene
from farfield.core.impostor_database import ImpostorDatabase
from farfield.core.walkthrough import generate_path, load_path, walkthrough, write_plot


@click.command("walkthrough")
@click.argument("database", type=click.Path(exists=True))
@click.argument("scene", type=click.Path(dir_okay=False, exists=True))
@click.option("--path", "path_file", default=None, type=click.Path(dir_okay=False, exists=True),
              help="Recorded camera path: JSON list of {position, forward}. Default: a generated loop.")
@click.option("--frames", default=120, show_default=True, type=int, help="Frames of the generated loop.")
@click.option("--repeats", default=3, show_default=True, type=int, help="Draws per frame and renderer; the median counts.")
@click.option("--plot", default=None, type=click.Path(dir_okay=False), help="Write a PNG of frame time and error along the path.")
@click.option("--no-compare", is_flag=True, help="Frame times only (no image comparison).")
@click.option("--json", "as_json", is_flag=True, help="Every frame and the summary as JSON.")
def walkthrough_cmd(database, scene, path_file, frames, repeats, plot, no_compare, as_json):
    """Walk a camera path through DATABASE (an envmap job's database.zip or its unpacked folder)
    and compare the reference runtime (near field + impostors) with SCENE drawn in full."""
    loaded = load_scene(scene)
    with ImpostorDatabase(Path(database)) as db:
        positions, forwards = load_path(path_file) if path_file else generate_path(db, frames)
        bar = tqdm(total=len(positions), desc="frames", unit="frame", leave=False, disable=True if as_json else None)
        try:
            result = walkthrough(loaded, db, positions, forwards, repeats=repeats, compare=not no_compare,
                                 progress=lambda done, total: bar.update(done - bar.n))  # fmt: skip
        finally:
            bar.close()
    if plot:
        write_plot(result, plot, title=f"{Path(scene).name}: full scene vs near field + impostors")
    if as_json:
        click.echo(json.dumps(result, indent=1))
        return
    click.echo(f"{'frame':>5} {'cell':>5} {'full ms':>8} {'imp ms':>8} {'speedup':>7} {'holes':>6} {'err mean':>8} {'err max':>7}")
    for f in result["frames"]:
        fast = f.get("impostor_ms")
        speedup = f"{f['full_ms'] / fast:.1f}x" if fast else "-"
        click.echo(
            f"{f['frame']:>5} {'-' if f['cell'] is None else f['cell']:>5} {f['full_ms']:>8.2f} "
            f"{'-' if fast is None else f'{fast:.2f}':>8} {speedup:>7} "
            f"{f.get('hole_pixels', '-'):>6} {f.get('colour_error_mean', float('nan')):>8.3f} {f.get('colour_error_max', '-'):>7}"
            + ("  <- cell switch" if f["switched"] else "")
        )
    s = result["summary"]
    line = f"{s['frames']} frames, {s['frames_served']} served by impostors, {s['cell_switches']} cell switches"
    if s["frames_served"]:
        line += f"; mean frame {s['full_ms_mean']:.2f} ms full vs {s['impostor_ms_mean']:.2f} ms impostors ({s['speedup_mean']:.1f}x)"
    if "hole_pixels" in s:
        line += f"; {s['hole_pixels']} hole pixels, colour error mean {s['colour_error_mean']:.3f}, max {s['colour_error_max']}"
    click.echo(line)
    if plot:
        click.echo(f"plot: {plot}")

"""``farfield calibrate``: fit the rendering-time and memory models of impostor placement on this renderer (seed 000 §5.8.1)."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from farfield.cli import sides_option
from farfield.cli.bake_cmd import _Bar
from farfield.cli.place_cmd import _numbers
from farfield.core.exchange import load_scene
from farfield.core.placement.calibration import Calibration, CalibrationOptions, calibrate, default_scene
from farfield.core.placement.cost_model import CostModelError
from farfield.core.stage_clock import seconds_line

_DEFAULTS = CalibrationOptions()


def _pct(x) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{100.0 * x:.1f}%"


def _quality(fit: dict, what: str = "R²") -> str:
    r2 = fit.get("r2")
    return (
        f"  {what} {'-' if r2 is None else f'{r2:.3f}'} ({fit['samples']} fitted), held-out relative error "
        f"median {_pct(fit.get('holdout_rel_error_median'))}, p90 {_pct(fit.get('holdout_rel_error_p90'))} ({fit['holdout']} held out)"
        + (f"; held out above the model: {_pct(fit.get('holdout_share_above'))}" if "quantile" in fit else "")
    )


def report_lines(result: Calibration, written: str | None) -> list[str]:
    """The text ``farfield calibrate`` prints (coefficients, fit quality, where the model went)."""
    model, fit = result.model, result.model.fit
    a, b, c, d = model.geometry
    e, f, g = model.impostor
    h, k, q = model.memory
    n = fit["samples"]
    o = fit["options"]
    ratio = fit["layers_est_over_planned"]
    lines = [f"renderer: {model.renderer}"]
    lines += [
        f"scene: {s['source']} ({s['objects']} object{'s' if s['objects'] != 1 else ''}, {s['triangles']:,} triangles)"
        for s in fit["scenes"]
    ]
    lines += [
        (
            f"samples: {n['geometry']} geometry views, {n['impostors_baked']} impostors baked ({n['cells_refused']} random cells refused) "
            f"drawn from {n['impostor']} views; {o['resolution']} px, {o['fov_deg']:g}° field of view, seed {o['seed']}"
        ),
        (
            f"geometry  t = a*draw_calls + b*triangles + c*pixels + d  (ms; {'frames from random views in the view space ' + str(o['view_space']) if o.get('view_space') else 'clusters seen from outside'}; "
            f"{'quantile ' + format(o['quantile'], 'g') + ' of the frames' if o.get('quantile') is not None else 'least squares'})"
        ),
        f"  a {a:.4g} ms/draw call   b {b:.4g} ms/triangle   c {c:.4g} ms/pixel   d {d:.4g} ms/frame",
        _quality(fit["geometry"]),
        f"impostor  t = e*pixels + f*quads + g  (ms; its frame less the empty frame's {result.empty_frame_ms:.3g} ms)",
        f"  e {e:.4g} ms/pixel   f {f:.4g} ms/quad   g {g:.4g} ms/impostor",
        _quality(fit["impostor"]),
        "memory    bytes = h*(layers_est*texels_per_layer)^p + k",
        f"  h {h:.4g}   p {model.memory_exponent:.4g}   k {k:.4g} bytes",
        _quality(fit["memory"], "R² of log(bytes)"),
        "quads     quads = q*layers_est*texels_per_layer^beta",
        f"  q {q:.4g}   beta {model.quads_exponent:.4g}",
        _quality(fit["quads"], "R² of log(quads/layers_est)"),
        f"layers_est / planned layers: median {ratio['median']:.3g} ({ratio['min']:.3g} .. {ratio['max']:.3g})",
        *(f"warning: {w}" for w in fit.get("warnings", [])),
        seconds_line(fit),
        f"model written to {written}" if written else "model not written (--out FILE writes it)",
    ]
    return lines


@click.command("calibrate")
@click.argument("scenes", nargs=-1, type=click.Path(dir_okay=False))
@click.option(
    "--samples",
    default=_DEFAULTS.samples,
    show_default=True,
    type=int,
    help="Geometry measurements (random clusters x viewpoints).",
)
@click.option(
    "--impostors",
    default=_DEFAULTS.impostors,
    show_default=True,
    type=int,
    help="Layered impostors baked for random shaft cells and drawn from inside them.",
)
@click.option(
    "--resolution",
    default=_DEFAULTS.resolution,
    show_default=True,
    type=int,
    help="Output image pixels per side (drawing and baking).",
)
@click.option("--fov", default=_DEFAULTS.fov_deg, show_default=True, type=float, help="Output field of view, degrees.")
@click.option(
    "--seed",
    default=_DEFAULTS.seed,
    show_default=True,
    type=click.IntRange(min=0),
    help="Seed of the clusters, viewpoints and cells.",
)
@click.option(
    "--view-space",
    default=None,
    help="x0,y0,z0,x1,y1,z1: measure geometry on frames of the one SCENE from random views in this box, drawn as the "
    "placement runtime draws them (the elements in the frustum), instead of clusters seen from outside; "
    "use the placement's resolution and field of view.",
)
@click.option(
    "--quantile",
    default=None,
    type=float,  # CalibrationOptions checks it: one line, as the other options
    help="Fit the geometry terms by quantile regression: a time this share of frames with those counts stay under "
    "(e.g. 0.9 for a budget), instead of least squares (their mean).",
)
@click.option(
    "--out", default=None, type=click.Path(dir_okay=False), help="Write the model (JSON, for --cost-model) here."
)
@click.option("--json", "as_json", is_flag=True, help="The model, where it was written and every sample, as JSON.")
@sides_option
def calibrate_cmd(scenes, samples, impostors, resolution, fov, seed, view_space, quantile, out, as_json, sides):
    """Fit the rendering-time and memory models of impostor placement on the renderer this runs on
    (seed 000 §5.8.1): draw random object clusters of SCENEs (default: a procedural city) from random
    viewpoints, bake and draw layered impostors for random shaft cells, and fit the coefficients by
    least squares (or, with --view-space, draw SCENE's own frames from random views in the box; with
    --quantile, fit the geometry terms to that quantile of the frames)."""
    if view_space is not None:
        box = tuple(_numbers(view_space, 6, "--view-space"))
        if len(scenes) != 1:
            raise CostModelError(f"--view-space calibrates on one SCENE's own views, got {len(scenes)} scenes")
    else:
        box = None
    options = CalibrationOptions(samples=samples, impostors=impostors, resolution=resolution, fov_deg=fov, seed=seed,
                                 view_space=box, quantile=quantile)  # fmt: skip
    if out and not Path(out).resolve().parent.is_dir():  # before minutes of measuring, not after
        raise CostModelError(f"cannot write the cost model to {out!r}: no folder {str(Path(out).resolve().parent)!r}")
    loaded = [load_scene(path, sides=sides) for path in scenes] if scenes else [default_scene()]
    bar = _Bar(enabled=True)
    try:
        result = calibrate(loaded, options, progress=bar)
    finally:
        bar.close()
    written = None
    if out:
        try:
            Path(out).write_text(json.dumps(result.model.to_dict(), indent=1) + "\n")
        except OSError as error:
            raise CostModelError(f"cannot write the cost model to {out!r}: {error.strerror or error}") from None
        written = str(out)
    if as_json:
        click.echo(
            json.dumps(
                {"model": result.model.to_dict(), "written": written, "samples": result.samples_dict()}, indent=1
            )
        )
    else:
        click.echo("\n".join(report_lines(result, written)))

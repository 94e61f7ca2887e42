"""``farfield evaluate``: compare baked bundles with the real geometry from inside (and outside) their view cell.

One bundle: per-viewpoint errors.  Several bundles of the same part and view cell (say a layered
impostor and a textured depth mesh): each is evaluated from the same viewpoints, and a side-by-side
table ends with the one to use (:func:`farfield.core.quality.comparison.choose`).
"""

from __future__ import annotations

import json
from pathlib import Path

import click

from farfield.cli import ArgumentError, sides_option
from farfield.core.errors import GuaranteeError
from farfield.core.exchange import load_scene
from farfield.core.impostor.bundle import read_bundle
from farfield.core.quality.comparison import PREFERENCES, Candidate, check_comparable, choose
from farfield.core.quality.lit import evaluate_lit, lit_text
from farfield.core.techniques import get_technique


@click.command("evaluate")
@click.argument("bundles", nargs=-1, required=True, type=click.Path(file_okay=False))
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option(
    "--random",
    "random_count",
    default=16,
    show_default=True,
    type=click.IntRange(min=0),
    help="Random viewpoints inside the cell.",
)
@click.option(
    "--outside",
    "outside_count",
    default=4,
    show_default=True,
    type=click.IntRange(min=0),
    help="Viewpoints just outside the cell.",
)
@click.option("--seed", default=0, show_default=True, type=click.IntRange(min=0))
@click.option(
    "--prefer",
    type=click.Choice(PREFERENCES),
    default="memory",
    show_default=True,
    help="With several bundles: what decides among those with the fewest hole pixels.",
)
@click.option("--json", "as_json", is_flag=True, help="Per-viewpoint results as JSON.")
@click.option(
    "--check",
    is_flag=True,
    help="Exit non-zero (4) when a view inside the cell breaks what the bundle's technique promises (farfield "
    "techniques) at the error budget it was baked for (max_error_px): hole pixels, pixels bloated beyond the budget.",
)
@click.option(
    "--lit",
    is_flag=True,
    help="Also light the geometry and the impostor alike (glTF's BRDF as three.js draws it, five test lights, grazing "
    "ones included) and report the lit colour error per light, the normal error, and the impostor lit as flat cards.",
)
@click.option(
    "--max-lit-error",
    type=click.FloatRange(min=0.0),
    default=None,
    help="With --lit and --check: also fail (4) when the lit colour error's mean under any light exceeds this (0-255).",
)
@sides_option
def evaluate(bundles, scene, random_count, outside_count, seed, prefer, as_json, check, lit, max_lit_error, sides):
    """Render SCENE's part and the impostor in each BUNDLE from sampled viewpoints and report the
    errors; with several bundles of one part and view cell, side by side and which to use."""
    if max_lit_error is not None and not (lit and check):
        raise click.UsageError("--max-lit-error goes with --lit and --check")
    if lit and len(bundles) > 1:
        raise click.UsageError("--lit evaluates one bundle at a time")
    impostors = [read_bundle(Path(b)) for b in bundles]
    part = _evaluated_scene(load_scene(scene, sides=sides), impostors)
    if len(impostors) > 1:
        results = _compare(list(bundles), impostors, part, random_count, outside_count, seed, prefer, as_json)
    else:
        impostor = impostors[0]
        technique = get_technique(impostor.technique)
        result = technique.evaluate(part, impostor, random_count, outside_count, seed)
        lit_result = None
        if lit:
            names = impostor.parameters.get("objects")
            own = getattr(technique, "evaluate_lit", None)  # what the impostor stands in for, its technique says
            try:
                if own is not None:
                    lit_result = own(part, impostor, random_count, seed)
                else:
                    lit_result = evaluate_lit(part.subset(names) if names else part, impostor, random_count, seed)
            except ValueError as error:  # a payload drawn otherwise than as triangles
                raise click.UsageError(f"--lit: {error}") from error
        if as_json:
            payload = result.to_dict() if hasattr(result, "to_dict") else result
            click.echo(json.dumps(payload | ({"lit": lit_result.to_dict()} if lit_result else {}), indent=2))
        else:
            click.echo(technique.evaluation_text(result, impostor))
            if lit_result is not None:
                click.echo(lit_text(lit_result))
        results = [result]
        if check and max_lit_error is not None:
            worst = max(row["lit_error_mean"] for row in lit_result.totals["lights"])
            if worst > max_lit_error:
                raise GuaranteeError(
                    f"{bundles[0]}: lit colour error mean {worst:.2f} under the worst test light exceeds {max_lit_error:g}"
                )
    if check:
        _check(list(bundles), impostors, results)


def _evaluated_scene(scene, impostors: list):
    """What the bundles stand in for: ``scene``, or, for bundles of ``farfield bake --instances``
    (``parameters["instances"]``), their prototype in its own space, where their cell is."""
    keys = {impostor.parameters["prototype"] for impostor in impostors if "instances" in impostor.parameters}
    if not keys:
        return scene
    if len(keys) > 1 or any("instances" not in impostor.parameters for impostor in impostors):
        raise ArgumentError(
            "bundles of different prototypes, or of a prototype and a part, are evaluated one at a time"
        )
    from farfield.core.techniques.instances import prototype_scene

    return prototype_scene(scene, keys.pop())


def _totals(result) -> dict:
    return result.totals if hasattr(result, "totals") else result["totals"]


def _check(names: list[str], impostors: list, results: list) -> None:
    """GuaranteeError naming every bundle that breaks its technique's promise inside its cell, at the
    error budget it was baked for, and every bundle whose cell lies where its technique's promise does
    not hold (``Promise.outside``: an octahedral cell nearer than the accuracy distance); a technique that promises nothing
    in pixels is said so, on stderr."""
    broken = []
    for name, impostor, result in zip(names, impostors, results):
        promise = get_technique(impostor.technique).promise
        if promise.outside is not None and (why := promise.outside(impostor)):
            broken.append(f"{name}: {why}")
            continue
        if not promise.checked:
            click.echo(f"{name}: {impostor.technique} promises {promise.text}; nothing to check", err=True)
            continue
        t = _totals(result)
        budget = t.get("error_budget_px", 1.0)
        holes = t.get("hole_pixels_beyond_budget", t["hole_pixels"]) if promise.holes else 0
        bloat = t.get("bloat_beyond_budget", t["bloat_beyond_1px"]) if promise.bloat else 0
        if holes or bloat:
            said = [f"{holes} hole pixels"] if promise.holes else []
            said += [f"{bloat} pixels bloated beyond {budget:g}"] if promise.bloat else []
            broken.append(f"{name}: " + ", ".join(said))
    if broken:
        raise GuaranteeError("from inside the view cell, " + "; ".join(broken))


def _compare(
    names: list[str], impostors, part, random_count: int, outside_count: int, seed: int, prefer: str, as_json: bool
) -> list:
    """Several bundles of one part and view cell: each evaluated alike, side by side, and the one to use."""
    check_comparable(names, impostors)
    results = [get_technique(i.technique).evaluate(part, i, random_count, outside_count, seed) for i in impostors]
    candidates = [Candidate.of(name, impostor, result) for name, impostor, result in zip(names, impostors, results)]
    choice = choose(candidates, prefer)
    if as_json:
        rows = [{**c.to_dict(), "evaluation": r.to_dict()} for c, r in zip(candidates, results)]
        click.echo(
            json.dumps(
                {"bundles": rows, "prefer": prefer, "choice": candidates[choice.index].name, "reason": choice.reason},
                indent=2,
            )
        )
        return results
    width = max(len("bundle"), *(len(n) for n in names))
    # A bundle stores no bake time (bundle.RUN_DEPENDENT_STATS): the column only where one is known.
    timed = any(c.bake_seconds is not None for c in candidates)
    click.echo(
        f"{'bundle':<{width}} {'technique':<9} {'primitives':>10} {'memory KiB':>10} {'holes':>6} {'>1px':>6} {'err mean':>9} {'err p99':>8} {'ssim':>6}"
        + (f" {'bake s':>7}" if timed else "")
    )
    for c in candidates:
        seconds = f" {c.bake_seconds:>7.2f}" if c.bake_seconds is not None else (f" {'-':>7}" if timed else "")
        click.echo(
            f"{c.name:<{width}} {c.technique:<9} {c.primitives:>10,} {c.memory_bytes / 1024:>10.1f} {c.hole_pixels:>6} "
            f"{c.bloat_beyond_1px:>6} {c.colour_error_mean:>9.2f} {c.colour_error_p99:>8.1f} {c.ssim:>6.3f}{seconds}"
        )
    click.echo(
        f"{results[0].totals['viewpoints']} viewpoints inside the view cell for each (hole pixels, pixels bloated beyond 1 px, "
        "colour error per pixel where both cover: mean and 99th percentile, 0-255; SSIM over both coverages, 1 = equal)"
    )
    click.echo(f"use {choice.reason}")
    return results

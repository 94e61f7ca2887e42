"""``farfield place``: where impostors are needed so that every view of a view space meets a frame-time
or primitive budget, at least memory (seed 000 ch. 5); prints the summary, writes the placement JSON."""

from __future__ import annotations

import json
import math
from pathlib import Path

import click

from farfield.cli import sides_option
from farfield.cli.bake_cmd import _Bar
from farfield.core.exchange import load_scene
from farfield.core.options import parse_option_text
from farfield.core.placement.cost_model import LLVMPIPE_MODEL, CostModel, primitive_model
from farfield.core.placement.hierarchy import PlacementError
from farfield.core.placement.image_database import write_image_database
from farfield.core.placement.lod import LOD_TECHNIQUE
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.placement.solution_grid import BudgetSettings, place_primitives
from farfield.core.placement.solution_grid import check_views as count_views
from farfield.core.placement.view_space import DEFAULT_DEPTH_COMPLEXITY
from farfield.core.sidedness import DEFAULT_SIDES
from farfield.core.techniques import DEFAULT_TECHNIQUE, TECHNIQUES, get_technique
from farfield.service.placement import ALGORITHMS, DEFAULT_ALGORITHM


def _numbers(text: str, count: int, what: str) -> list[float]:
    try:
        values = [float(x) for x in text.split(",")]
    except ValueError:
        values = []
    if len(values) != count or not all(math.isfinite(v) for v in values):
        raise PlacementError(f"{what} wants {count} finite comma-separated numbers, got {text!r}")
    return values


def _model(frame_ms, cost_model, primitives) -> tuple[CostModel, float, str | None]:
    """The cost model and t_max of the options, and a note when the builtin model is used."""
    if (frame_ms is None) == (primitives is None):
        which = "neither was given" if frame_ms is None else "not both"
        raise PlacementError(
            f"give a budget: --frame-ms T (with --cost-model FILE, or the builtin llvmpipe model) or --primitives N; {which}"
        )
    if primitives is not None:
        if cost_model:
            raise PlacementError("--primitives counts triangles; --cost-model applies to --frame-ms only")
        return primitive_model(), float(primitives), None
    if cost_model:
        return CostModel.load(cost_model), float(frame_ms), None
    note = (
        f"using the builtin cost model measured on {LLVMPIPE_MODEL.renderer} (farfield calibrate); "
        "the budget is your engine's: calibrate there or give --cost-model FILE"
    )
    return LLVMPIPE_MODEL, float(frame_ms), note


def _check_out(out) -> None:
    if out and not Path(out).resolve().parent.is_dir():
        raise PlacementError(f"cannot write the placement to {out!r}: no folder {str(Path(out).resolve().parent)!r}")


def _write_out(out, document: dict) -> None:
    try:
        Path(out).write_text(json.dumps(document) + "\n")
    except OSError as error:
        raise PlacementError(f"cannot write the placement to {out!r}: {error.strerror or error}") from None


def _with_bar(quiet: bool, run):
    """``run(progress)`` with a progress bar on stderr (none with ``quiet``)."""
    bar = _Bar(enabled=not quiet)
    try:
        return run(bar)
    finally:
        bar.close()


def summary_lines(result) -> list[str]:
    s, unit = result.summary, result.summary["unit"]
    lines = [
        f"view space {result.parameters['view_space']}, t_max {s['t_max']:.6g} {unit}, technique {result.parameters['technique']}, "
        f"{s['elements']} elements in {s['hierarchy_nodes']} hierarchy nodes",
        f"problem views (CPVs): {s['cpvs']} in {s['leaf_regions_with_cpvs']} regions of {result.parameters['cpv_size']:.6g} "
        f"x {result.parameters['vdi_deg']:g} deg ({s['cpvs_solved']} solved, {s['cpvs_unsolved']} unsolved, {s['cpvs_unsolvable']} unsolvable)",
        f"candidates: {s['candidates']} (of {s['candidates_considered']} considered; {s['candidates_refused_by_technique']} refused by the technique, "
        f"{s.get('candidates_refused_by_memory', 0)} over --max-impostor-mb)",
        f"impostors: {s['impostors']} ({s['impostors_deleted']} chosen, then replaced by an ancestor), estimated memory {s['memory_bytes'] / 2**20:.2f} MiB",
        f"worst CPV: {s['worst_before']:.4g} {unit} before, {s['worst_after']:.4g} {unit} after (solvable ones: {s['worst_after_solvable']:.4g})",
        "seconds: " + ", ".join(f"{k} {v:.2f}" for k, v in result.seconds.items()),
    ]
    if "by_technique" in s:  # mixed candidates: what was chosen of each technique
        rows = [f"{name} {row['impostors']} ({row['memory_bytes'] / 2**20:.2f} MiB, drawn in {row['cpvs']} CPVs)"
                for name, row in s["by_technique"].items()]  # fmt: skip
        offered = set(result.parameters.get("also", {})) | ({LOD_TECHNIQUE} if result.parameters.get("lod") else set())
        unused = sorted(offered - set(s["by_technique"]))
        lines.insert(4, "impostors by technique: " + "; ".join(rows + [f"{name} 0" for name in unused]))
    message = result.message()
    if message:
        lines.append("not every view meets the budget: " + message)
    return lines


@click.command("place")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option(
    "--view-space",
    required=True,
    metavar="X0,Y0,Z0,X1,Y1,Z1",
    help="The box the viewer moves in (may be flat or a point).",
)
@click.option(
    "--frame-ms", type=float, default=None, help="Budget: every view within this many milliseconds by the cost model."
)
@click.option(
    "--cost-model",
    type=click.Path(dir_okay=False),
    default=None,
    help="Cost model JSON (farfield calibrate --out) [default: the builtin llvmpipe one].",
)
@click.option(
    "--primitives",
    type=float,
    default=None,
    help="Budget: every view draws at most this many triangles (seed 000 §5.8.3, seed 004).",
)
@click.option(
    "--technique",
    type=click.Choice(list(TECHNIQUES)),
    default=DEFAULT_TECHNIQUE,
    show_default=True,
    help="Impostor technique (a part technique).",
)
@click.option(
    "--option",
    "options",
    multiple=True,
    metavar="NAME=VALUE",
    help="A technique option (repeatable; see farfield techniques).",
)
@click.option(
    "--also",
    "also",
    multiple=True,
    metavar="TECHNIQUE[:NAME=VALUE,...]",
    help="frame-time: candidates of another technique compete with --technique's in the same greedy, by memory per "
    "millisecond saved (repeatable), e.g. --also octahedral:grid=9,frame_resolution=16: an octahedral impostor per "
    "element wherever its problem views lie beyond its accuracy distance; --also lod: simplified geometry, QEM levels of "
    "detail of the hierarchy's nodes whose error is within max_error_px where they are drawn.",
)
@click.option("--resolution", default=512, show_default=True, type=int, help="Output image pixels per side.")
@click.option(
    "--fov",
    default=None,
    type=float,
    help="Output field of view, degrees [default: 45; 60 for --algorithm primitive-budget, square, the same at run time].",
)
@click.option(
    "--algorithm",
    type=click.Choice(list(ALGORITHMS)),
    default=DEFAULT_ALGORITHM,
    show_default=True,
    help="frame-time: impostors of --technique at least memory (seed 000 ch. 5); primitive-budget: a grid of solution points "
    "with one image per view so that no view draws more than --primitives (seed 004).",
)
@click.option(
    "--p-opt",
    type=float,
    default=None,
    help="primitive-budget: the optimisation budget < P [default: P - 5 %% of the model, at least P / 2].",
)
@click.option(
    "--octree-depth",
    type=int,
    default=5,
    show_default=True,
    help="primitive-budget: depth of the octree's pseudo-leaf cells.",
)
@click.option(
    "--grid-points",
    type=int,
    default=3,
    show_default=True,
    help="primitive-budget: initial grid points along the view space's longest side.",
)
@click.option(
    "--max-level",
    type=int,
    default=4,
    show_default=True,
    help="primitive-budget: subdivision levels at most; points still unsolved there are reported.",
)
@click.option(
    "--check-views",
    type=int,
    default=2000,
    show_default=True,
    help="primitive-budget: random (eye, yaw) views to count primitives over after placing (0: none).",
)
@click.option(
    "--bake",
    "bake_dir",
    type=click.Path(file_okay=False),
    default=None,
    help="primitive-budget: bake every image's LDI and write the placement database to this folder (farfield walkthrough reads it).",
)
@click.option(
    "--ldi-resolution", type=int, default=256, show_default=True, help="primitive-budget --bake: LDI pixels per side."
)
@click.option(
    "--cpv-size",
    type=float,
    default=None,
    help="Smallest 3D region of a problem view [default: the view space's longest side / 8].",
)
@click.option(
    "--vdi-deg", type=float, default=11.25, show_default=True, help="Smallest view-direction interval, degrees."
)
@click.option(
    "--cells",
    type=click.Choice(["shafts", "boxes", "both", "leaf-boxes"]),
    default="both",
    show_default=True,
    help="View cells of the candidates: shafts (§5.6), boxes of the view-space hierarchy, both, or leaf-boxes (one per smallest region, Table 5.1 test 14).",
)
@click.option(
    "--depth-complexity",
    type=float,
    default=DEFAULT_DEPTH_COMPLEXITY,
    show_default=True,
    help="A view's estimated covered pixels are at most this many frames (inf: no cap).",
)
@click.option("--leaf-size", type=int, default=4, show_default=True, help="Elements per leaf of the object hierarchy.")
@click.option(
    "--max-impostor-mb",
    type=float,
    default=32.0,
    show_default=True,
    help="Largest impostor considered, MiB by the cost model's memory estimate.",
)
@click.option(
    "--visibility",
    is_flag=True,
    help="Problem views count only their region's potentially visible set (sampled with id cube maps on the GL; not conservative).",
)
@click.option("--out", type=click.Path(dir_okay=False), default=None, help="Write the placement JSON here.")
@click.option(
    "--json", "as_json", is_flag=True, help="Print the summary, seconds and where the placement went as JSON."
)
@click.option("--quiet", is_flag=True, help="No progress bar.")
@sides_option
def place_cmd(scene, view_space, frame_ms, cost_model, primitives, technique, options, also, resolution, fov, algorithm, p_opt, octree_depth,
              grid_points, max_level, check_views, bake_dir, ldi_resolution, cpv_size, vdi_deg, cells, depth_complexity, leaf_size, max_impostor_mb, visibility,
              out, as_json, quiet, sides) -> None:  # fmt: skip
    """Decide where impostors go so that every view from VIEW-SPACE meets the budget at least memory
    (seed 000 ch. 5): problem views, candidates, greedy choice.  Views no placement can serve are
    named; the exit status is 0 either way (see "status" per CPV in the JSON).  With --algorithm
    primitive-budget: seed 004's grid of solution points and images instead."""
    corners = _numbers(view_space, 6, "--view-space")
    offline = _OFFLINE[ALGORITHMS[algorithm].offline]
    offline(scene, corners, sides=sides, frame_ms=frame_ms, cost_model=cost_model, primitives=primitives, technique=technique, options=options,
            also=also, resolution=resolution, fov=fov, p_opt=p_opt, octree_depth=octree_depth, grid_points=grid_points, max_level=max_level,
            check_views=check_views, bake_dir=bake_dir, ldi_resolution=ldi_resolution, cpv_size=cpv_size, vdi_deg=vdi_deg, cells=cells,
            depth_complexity=depth_complexity, leaf_size=leaf_size, max_impostor_mb=max_impostor_mb, visibility=visibility, out=out, as_json=as_json,
            quiet=quiet)  # fmt: skip


def _place_solution_grid(scene, corners, *, frame_ms, cost_model, primitives, fov, p_opt, octree_depth, grid_points, max_level,
                         check_views, bake_dir, ldi_resolution, out, as_json, quiet, sides, visibility=False, also=(), **_) -> None:  # fmt: skip
    """``farfield place`` with an algorithm whose offline placement is a solution grid of images (seed 004)."""
    if visibility:
        raise PlacementError(
            "--visibility applies to the frame-time placement (its problem views), not to --algorithm primitive-budget"
        )
    if also:
        raise PlacementError(
            "--also adds candidates to a frame-time placement; --algorithm primitive-budget places LDIs only"
        )
    if primitives is None or frame_ms is not None or cost_model:
        raise PlacementError(
            "--algorithm primitive-budget takes a budget of --primitives N only (no --frame-ms, no --cost-model)"
        )
    settings = BudgetSettings(primitives=primitives, p_opt=p_opt, fov_deg=60.0 if fov is None else fov, octree_depth=octree_depth,
                              grid_points=grid_points, max_level=max_level)  # fmt: skip
    _place_primitive_budget(scene, corners, settings, check_views, out, as_json, quiet, bake_dir, ldi_resolution, sides)


def parse_also(items) -> dict[str, dict]:
    """``--also`` values (``TECHNIQUE[:NAME=VALUE,...]``) as ``PlacementSettings.also``: technique
    name -> its option values, parsed by the technique's option types.

    >>> parse_also(["octahedral:grid=9,frame_resolution=16"])
    {'octahedral': {'grid': 9, 'frame_resolution': 16}}
    >>> parse_also(["octahedral", "octahedral:grid=9"])
    Traceback (most recent call last):
    ...
    farfield.core.placement.hierarchy.PlacementError: --also octahedral given twice

    ``lod`` (simplified geometry, :mod:`farfield.core.placement.lod`) takes no options; the caller
    turns it into ``PlacementSettings.lod``:

    >>> parse_also(["lod"])
    {'lod': {}}
    """
    out: dict[str, dict] = {}
    for item in items:
        name, _, rest = item.partition(":")
        name = name.strip()
        if name == LOD_TECHNIQUE:
            if rest.strip() or name in out:
                raise PlacementError(f"--also {item!r}: lod takes no options, once (it keeps --option max_error_px)")
            out[name] = {}
            continue
        if name not in TECHNIQUES:
            raise PlacementError(f"--also {item!r}: unknown technique {name!r}; one of {', '.join(TECHNIQUES)}")
        if name in out:
            raise PlacementError(f"--also {name} given twice")
        values = {}
        for pair in filter(None, (p.strip() for p in rest.split(","))):
            key, sep, text = pair.partition("=")
            if not sep or not key.strip():
                raise PlacementError(f"--also {item!r}: expected TECHNIQUE:NAME=VALUE,...")
            values[key.strip()] = parse_option_text(get_technique(name).Options, key.strip(), text)
        out[name] = values
    return out


def _place_cost_model(scene, corners, *, frame_ms, cost_model, primitives, technique, options, resolution, fov, bake_dir, cpv_size,
                      vdi_deg, cells, depth_complexity, leaf_size, max_impostor_mb, out, as_json, quiet, sides, visibility=False, also=(), **_) -> None:  # fmt: skip
    """``farfield place`` with an algorithm whose offline placement is by a cost model (seed 000 ch. 5)."""
    if bake_dir:
        raise PlacementError(
            "--bake writes a primitive-budget placement's database (--algorithm primitive-budget); a frame-time placement is baked as a job"
        )
    fov = 45.0 if fov is None else fov
    model, t_max, note = _model(frame_ms, cost_model, primitives)
    values = {}
    for item in options:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise PlacementError(f"--option {item!r}: expected NAME=VALUE")
        values[name.strip()] = parse_option_text(get_technique(technique).Options, name.strip(), text)
    values.update({"resolution": resolution, "fov_deg": fov})
    _check_out(out)
    if not max_impostor_mb > 0:  # said in the unit given, not in the bytes it becomes
        raise PlacementError(f"--max-impostor-mb must be > 0, got {max_impostor_mb!r}")
    chosen = parse_also(also)  # --also lod: simplified geometry (PlacementSettings.lod)
    settings = PlacementSettings(
        t_max=t_max, model=model, technique=technique, options=values, cpv_size=cpv_size, vdi_deg=vdi_deg, cells=cells,
        depth_complexity=depth_complexity, leaf_size=leaf_size, max_impostor_bytes=max_impostor_mb * 2**20, visibility=visibility,
        also={k: v for k, v in chosen.items() if k != LOD_TECHNIQUE}, lod=LOD_TECHNIQUE in chosen,
    )  # fmt: skip
    loaded = load_scene(scene, sides=sides)
    result = _with_bar(quiet, lambda bar: place(loaded, corners[:3], corners[3:], settings, progress=bar))
    if out:
        _write_out(out, result.to_dict())
    if note and not as_json:
        click.echo(f"note: {note}", err=True)
    if as_json:
        click.echo(json.dumps({"summary": result.summary, "seconds": result.seconds, "written": out, "note": note,
                               "unsolvable": result.unsolvable}, indent=1))  # fmt: skip
    else:
        click.echo("\n".join(summary_lines(result)))
        click.echo(f"placement written to {out}" if out else "placement not written (--out FILE writes it)")


# How `farfield place` places offline, by what the algorithm says of it (Algorithm.offline).
_OFFLINE = {"cost-model": _place_cost_model, "solution-grid": _place_solution_grid}


def primitive_summary_lines(summary: dict, check: dict | None) -> list[str]:
    s = summary
    lines = [
        f"budget P {s['primitives']:g} triangles (p_opt {s['p_opt']:g}) of {s['model_triangles']}, fov {s['fov_deg']:.4g} deg; "
        f"{s['cells']} octree cells at depth {s['octree_depth']}",
        f"grid points: {s['grid_points']} (per level {s['points_per_level']}; spacing {s['spacing']:.6g} at level 0), "
        f"{s['unsolved_points']} unsolved at the last level",
        f"images: {s['images']}; grid points by images: "
        + ", ".join(f"{k}: {v}" for k, v in s["points_with_images"].items()),
    ]
    if s["image_drawn_over_p_opt"]:
        r = s["image_drawn_over_p_opt"]
        lines.append(
            f"primitives left by each image / p_opt: min {r['min']:.3f}, median {r['median']:.3f}, max {r['max']:.3f}"
        )
    if check:
        lines.append(
            f"check: {check['views']} random views, {100 * check['within_p']:.2f} % within P (max {check['max']:.0f}, p99 {check['p99']:.0f} "
            f"= {check['p99_over_p_opt']:.3f} p_opt); {check['without_grid_point']} without a grid point, {check['eye_past_quad']} "
            f"past their image, {check['in_unsolved_range']} in unsolved ranges"
        )
    return lines


def _place_primitive_budget(
    scene, corners, settings, views, out, as_json, quiet, bake_dir=None, ldi_resolution=256, sides=DEFAULT_SIDES
) -> None:
    if isinstance(views, bool) or views < 0:
        raise PlacementError(f"--check-views must be >= 0, got {views!r}")
    if bake_dir and not 1 <= ldi_resolution <= 4096:
        raise PlacementError(f"--ldi-resolution must be in 1..4096, got {ldi_resolution}")
    if bake_dir and Path(bake_dir).exists() and any(Path(bake_dir).iterdir()):
        raise PlacementError(f"--bake {bake_dir!r}: the folder is not empty")
    _check_out(out)
    loaded = load_scene(scene, sides=sides)
    result = _with_bar(quiet, lambda bar: place_primitives(loaded, corners[:3], corners[3:], settings, progress=bar))
    check = count_views(result, views) if views else None
    if bake_dir:
        _with_bar(quiet, lambda bar: write_image_database(Path(bake_dir), loaded, result, ldi_resolution, progress=bar))
    data = result.to_dict()
    data["check"] = check
    if out:
        _write_out(out, data)
    if as_json:
        click.echo(
            json.dumps(
                {
                    "summary": data["summary"],
                    "seconds": result.seconds,
                    "check": check,
                    "written": out,
                    "database": bake_dir,
                },
                indent=1,
            )
        )
    else:
        click.echo("\n".join(primitive_summary_lines(data["summary"], check)))
        click.echo(f"placement written to {out}" if out else "placement not written (--out FILE writes it)")
        if bake_dir:
            click.echo(
                f"database with {result.images} LDIs written to {bake_dir} (farfield walkthrough {bake_dir} SCENE)"
            )

"""``farfield layers``: print the layer arrangement for a part seen from a view cell, or around an
environment-map cell, or the sampling geometry of a point-based impostor."""

from __future__ import annotations

import json
import math

import click

from farfield.cli import ArgumentError, object_names
from farfield.core.errors import ViewCellError
from farfield.core.layering.plan import plan_layers
from farfield.core.pixel_angles import PIXEL_MODELS, pixel_angle
from farfield.core.techniques.envmap.arrangement import envmap_plan, layers_for_near_field
from farfield.core.techniques.points.sampling import plan_point_sampling
from farfield.core.viewcells import BoxCell, parse_viewcell


def _parse_bounds(text: str):
    try:
        nums = [float(x) for x in text.split(",")]
    except ValueError:
        nums = []
    if len(nums) != 6:
        raise ArgumentError(f"--bounds wants x0,y0,z0,x1,y1,z1, got {text!r}")
    return [nums[:3], nums[3:]]


def _emit(data: dict, as_json: bool, lines: list[str]) -> None:
    if as_json:
        click.echo(json.dumps(data, indent=2))
    else:
        click.echo("\n".join(lines))


def _fmt(x) -> str:
    return "inf" if x is None or (isinstance(x, float) and not math.isfinite(x)) else f"{x:.6g}"


@click.group("layers")
def layers() -> None:
    """Layer distances, borders (depth ranges) and near field of the two layer arrangements."""


def _part_bounds(scene, objects, bounds):
    """The part's (2, 3) bounds: of SCENE (or its ``objects``), or parsed from ``bounds``."""
    if (scene is None) == (bounds is None):
        raise ArgumentError(
            "give either a SCENE or --bounds" + ("; neither was given" if scene is None else ", not both")
        )
    if scene is None:
        return _parse_bounds(bounds)
    from farfield.core.exchange import load_scene

    names = object_names(objects)  # before the load: bad input is refused at once
    loaded = load_scene(scene)
    if names is not None:
        loaded = loaded.subset(names)
    return loaded.bounds


def _part_options(viewcells: str):
    """The options both part commands take: SCENE or --bounds, --viewcell (``viewcells``: the kinds
    it accepts), --objects, --resolution, --fov."""

    def wrap(command):
        for decorate in reversed(
            [
                click.argument("scene", required=False, type=click.Path(dir_okay=False)),
                click.option("--viewcell", required=True, help=viewcells),
                click.option(
                    "--objects",
                    default=None,
                    help="Comma-separated object names of SCENE forming the part (default: all).",
                ),
                click.option("--bounds", default=None, help="Part bounds x0,y0,z0,x1,y1,z1 instead of a SCENE."),
                click.option(
                    "--resolution", default=512, show_default=True, type=int, help="Output image pixels per side."
                ),
                click.option(
                    "--fov", default=45.0, show_default=True, type=float, help="Output field of view, degrees."
                ),
            ]
        ):
            command = decorate(command)
        return command

    return wrap


@layers.command("part")
@_part_options(
    "box:x0,y0,z0,x1,y1,z1 | box-center:cx,cy,cz,size | shaft:ax,ay,az,dx,dy,dz,apex_deg,min_dist[,max_dist]"
)
@click.option(
    "--pixel-model",
    type=click.Choice(PIXEL_MODELS),
    default="min",
    show_default=True,
    help="min: smallest pixel angle in the image (strict); center: the thesis's centre pixel.",
)
@click.option(
    "--reference-offset",
    type=float,
    default=None,
    help="s: reference viewpoint behind the cell's near border (default: seed 000 §3.3.1 rule).",
)
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def part(scene, viewcell, objects, bounds, resolution, fov, pixel_model, reference_offset, as_json) -> None:
    """Layers of a layered impostor for a scene part seen from a view cell (seed 000 §3.3.1)."""
    cell = parse_viewcell(viewcell)
    part_bounds = _part_bounds(scene, objects, bounds)
    plan = plan_layers(cell, part_bounds, math.radians(fov), resolution, pixel_model, reference_offset)
    data = plan.to_dict()
    data["viewcell"] = cell.to_dict()
    data["part_bounds"] = [list(map(float, row)) for row in part_bounds]
    lines = [
        f"layers: {plan.count}   texture: {plan.texture_resolution[0]}x{plan.texture_resolution[1]}   "
        f"alpha: {plan.alpha:.4g} rad ({pixel_model})",
        f"part: {plan.t0:.6g} .. {plan.t0 + plan.depth:.6g} from the view cell; reference offset s = {plan.reference_offset:.6g}",
        f"one layer suffices beyond {_fmt(data['single_layer_distance'])}; last layer valid to {_fmt(data['back_limit'])}",
        f"{'#':>5} {'distance':>14} {'depth range':>31}",
    ]
    for i, (t, (a, b)) in enumerate(zip(data["distances"], data["depth_ranges"])):
        lines.append(f"{i:>5} {t:>14.6f} {a:>14.6f} .. {b:<14.6f}")
    _emit(data, as_json, lines)


@layers.command("points")
@_part_options("box:x0,y0,z0,x1,y1,z1 | box-center:cx,cy,cz,size")
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def points(scene, viewcell, objects, bounds, resolution, fov, as_json) -> None:
    """Sampling plane, LDI cameras and their resolution of a point-based impostor (seed 001 §5.1)."""
    cell = parse_viewcell(viewcell)
    if not isinstance(cell, BoxCell):
        raise ViewCellError("a point-based impostor's sampling is planned for a box view cell (box: or box-center:)")
    part_bounds = _part_bounds(scene, objects, bounds)
    sampling = plan_point_sampling(cell, part_bounds, fov, resolution)
    data = sampling.to_dict()
    data["viewcell"] = cell.to_dict()
    data["part_bounds"] = [list(map(float, row)) for row in part_bounds]
    f = sampling.factors
    lines = [
        f"sampling plane: normal {[round(x, 6) for x in sampling.normal.tolist()]}, offset {sampling.offset:.6g}; the part lies {sampling.depth:.6g} beyond it",
        f"polygon: {len(sampling.polygon)} vertices; triangle perimeter {data['perimeter']:.6g}; farthest from a camera: {sampling.reach:.6g} (boundary {sampling.boundary_reach:.6g})",
        f"factors: movement {f['movement']:.4g} x perspective {f['perspective']:.4g} x diagonal {f['diagonal']:.4g}",
        f"{'camera':>6} {'position':>40} {'window (tangents)':>22} {'LDI pixels':>10}",
    ]
    for i, c in enumerate(sampling.cameras):
        position = ", ".join(f"{x:.6g}" for x in c.position)
        lines.append(f"{i:>6} {position:>40} {2.0 * c.half_size:>22.6g} {c.resolution:>7}^2")
    _emit(data, as_json, lines)


@layers.command("envmap")
@click.option("--cell-size", required=True, type=float, help="Side of the cubic view cell.")
@click.option("--resolution", default=512, show_default=True, type=int, help="Texels per cube-face side.")
@click.option("--layers", "count", type=int, default=None, help="Number of layers (give this or --near-field).")
@click.option("--near-field", type=float, default=None, help="Wanted near-field distance from the cell centre.")
@click.option(
    "--alpha", type=float, default=None, help="Parallax angle in radians (default: smallest pixel angle of a 90° face)."
)
@click.option("--dims", type=click.Choice(["2", "3"]), default="3", show_default=True)
@click.option("--json", "as_json", is_flag=True, help="Machine-readable output.")
def envmap(cell_size, resolution, count, near_field, alpha, dims, as_json) -> None:
    """Impostor cubes around a cubic view cell (seed 002 §4, Eqs. 1-2)."""
    dims = int(dims)
    if alpha is None:
        alpha = pixel_angle(math.pi / 2, resolution, "min")
    if (count is None) == (near_field is None):
        raise ArgumentError(
            "give either --layers or --near-field" + ("; neither was given" if count is None else ", not both")
        )
    if count is None:
        count = layers_for_near_field(cell_size, resolution, near_field, alpha, dims)
    plan = envmap_plan(cell_size, resolution, count, alpha, dims)
    data = plan.to_dict()
    lines = [
        f"layers: {plan.count}   near field: {plan.near_field:.6g} from the cell centre   alpha: {alpha:.4g} rad",
        f"{'#':>5} {'distance':>14} {'depth range':>31}  criterion",
    ]
    for i, (t, (a, b), c) in enumerate(zip(data["distances"], data["depth_ranges"], data["criterion"])):
        lines.append(f"{i:>5} {t:>14.6f} {a:>14.6f} .. {_fmt(b):<14}  {c}")
    _emit(data, as_json, lines)

"""``farfield bake``: bake one impostor of any registered technique (:mod:`farfield.core.techniques`) and write its bundle (manifest, atlas PNGs, GLB)."""

from __future__ import annotations

import json
from pathlib import Path

import click
from tqdm import tqdm

from farfield.cli import ArgumentError, object_names, sides_option
from farfield.core.exchange import load_scene
from farfield.core.impostor.bundle import check_destination, write_bundle
from farfield.core.layering.culling import CULLING_MODES
from farfield.core.options import parse_option_text
from farfield.core.pixel_angles import PIXEL_MODELS
from farfield.core.techniques import DEFAULT_TECHNIQUE, TECHNIQUES, get_technique
from farfield.core.viewcells import parse_viewcell


class _Bar:
    """A tqdm bar per pipeline stage, on stderr."""

    def __init__(self, enabled: bool):
        self.enabled, self.bar, self.stage = enabled, None, None

    def __call__(self, stage: str, done: int, total: int) -> None:
        if not self.enabled:
            return
        if stage != self.stage:
            self.close()
            # disable=None: no bar unless stderr is a terminal (scripts and logs stay clean).
            self.bar = tqdm(total=total, desc=f"{stage:>6}", unit="step", leave=False, disable=None)
            self.stage = stage
        self.bar.update(done - self.bar.n)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _shortcuts(
    technique,
    layers,
    near_field,
    directions,
    gap_fill,
    enlargement,
    oversampling,
    grid_cell,
    fill_threshold,
    culling,
    pixel_model,
    max_error_px=None,
    budget=None,
) -> dict:
    """The documented per-technique flags that were given, as option values (only the technique's own)."""
    given = {
        "layers": layers, "near_field": near_field, "directions": directions, "gap_fill": gap_fill, "enlargement": enlargement,
        "oversampling": oversampling, "grid_cell": grid_cell, "fill_threshold": fill_threshold, "culling": culling, "pixel_model": pixel_model,
        "max_error_px": max_error_px, "budget": budget,
    }  # fmt: skip
    known = {o["name"] for o in technique.describe()["options"]}
    wrong = sorted(k for k, v in given.items() if v is not None and k not in known)
    if wrong:
        flags = ", ".join("--" + k.replace("_", "-") for k in wrong)
        raise ArgumentError(f"{flags} do not apply to the {technique.name} technique (its options: {sorted(known)})")
    return {k: v for k, v in given.items() if v is not None}


@click.command("bake")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("--viewcell", required=True, help="box:x0,y0,z0,x1,y1,z1 | box-center:cx,cy,cz,size | shaft:...")
@click.option(
    "--out",
    "out",
    required=True,
    type=click.Path(file_okay=False),
    help="Bundle directory to write: a new or empty folder, or an earlier bundle (replaced whole); any other folder is refused.",
)
@click.option("--objects", default=None, help="Comma-separated object names forming the part (default: all).")
@click.option(
    "--technique",
    type=click.Choice(list(TECHNIQUES)),
    default=DEFAULT_TECHNIQUE,
    show_default=True,
    help="; ".join(f"{t.name}: {t.help}" for t in TECHNIQUES.values())
    + " (`farfield techniques` lists their options).",
)
@click.option(
    "--option",
    "options",
    multiple=True,
    metavar="NAME=VALUE",
    help="A technique option (repeat), e.g. --option grid_cell=4 or --option directions=+x,-x; `farfield techniques` lists them.",
)
@click.option(
    "--resolution", default=None, type=int, help="Output image pixels per side [default: the technique's, 512]."
)
@click.option(
    "--fov", default=None, type=float, help="Output field of view, degrees [default: the technique's: 45; envmap 90]."
)
@click.option("--layers", default=None, type=int, help="envmap: number of layers [default: 64 unless --near-field].")
@click.option(
    "--near-field",
    default=None,
    type=float,
    help="envmap: largest near-field distance from the cell centre (instead of --layers).",
)
@click.option("--directions", default=None, help="envmap: cube faces to record, e.g. +x,-x,+z,-z [default: all six].")
@click.option("--gap-fill/--no-gap-fill", default=None, help="envmap: seed 002 §5.1 gap filling [default: off].")
@click.option(
    "--enlargement",
    default=None,
    type=float,
    help="tdm: voxel enlargement factor of the covering test (seed 003 §6): larger, fewer polygons, less accurate [default: 2].",
)
@click.option(
    "--oversampling", default=None, type=int, help="tdm: nearest voxels averaged per texel (seed 003 §7) [default: 1]."
)
@click.option(
    "--grid-cell",
    default=None,
    type=int,
    help="layered, envmap: box-growing grid cell, texels [default: layered 8, envmap 4].",
)
@click.option(
    "--fill-threshold", default=None, type=float, help="layered, envmap: box-growing fill ratio [default: 0.8]."
)
@click.option(
    "--culling", type=click.Choice(CULLING_MODES), default=None, help="Hidden-texel culling [default: penumbra]."
)
@click.option(
    "--pixel-model",
    type=click.Choice(PIXEL_MODELS),
    default=None,
    help="layered, tdm: pixel angle of the error bound [default: min].",
)
@click.option(
    "--max-error-px",
    type=float,
    default=None,
    help="layered, tdm, points, envmap: the error budget in output pixels, what the technique promises "
    "(farfield techniques) holds within it [default: 1].",
)
@click.option(
    "--budget",
    type=click.Choice(["strict", "thesis"]),
    default=None,
    help="layered, tdm: strict (max-error-px at every pixel) or thesis (seed 000 §3.3, Table 4.1) [default: strict].",
)
@click.option(
    "--instances",
    is_flag=True,
    help="Bake each prototype of an instanced scene once (glTF meshes several nodes share, EXT_mesh_gpu_instancing; "
    "--viewcell in the prototype's own space): one bundle per prototype under --out/<prototype>/, recording its "
    "instances, its GLB one card drawn per instance.",
)
@click.option("--json", "as_json", is_flag=True, help="Print the bundle's statistics as JSON.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
@sides_option
def bake(scene, viewcell, out, objects, technique, options, resolution, fov, layers, near_field, directions, gap_fill, enlargement, oversampling,
         grid_cell, fill_threshold, culling, pixel_model, max_error_px, budget, instances, as_json, quiet, sides):  # fmt: skip
    """Bake the impostor of SCENE for a view cell and write its bundle to --out.

    The per-technique flags (--layers, --enlargement, ...) are shortcuts for --option NAME=VALUE."""
    chosen = get_technique(technique)
    values = _shortcuts(
        chosen,
        layers,
        near_field,
        directions,
        gap_fill,
        enlargement,
        oversampling,
        grid_cell,
        fill_threshold,
        culling,
        pixel_model,
        max_error_px,
        budget,
    )
    for item in options:
        name, sep, text = item.partition("=")
        if not sep or not name.strip():
            raise ArgumentError(f"--option {item!r}: expected NAME=VALUE")
        values[name.strip()] = parse_option_text(chosen.Options, name.strip(), text)
    settings = chosen.options(values, resolution, fov)
    check_destination(out)  # before the bake: a folder that is not a bundle is refused, not replaced
    cell = parse_viewcell(viewcell)
    names = object_names(objects)
    if chosen.scope == "scene" and names:
        raise ArgumentError(f"a {chosen.name} impostor represents the whole scene; --objects does not apply")
    loaded = load_scene(scene, sides=sides)
    if instances:
        _bake_instances(chosen, loaded, cell, settings, names, Path(out), as_json, quiet)
        return
    bar = _Bar(not quiet and not as_json)
    try:
        impostor = chosen.bake(loaded, cell, settings, names, bar)
    finally:
        bar.close()
    write_bundle(impostor, Path(out))
    if as_json:
        click.echo(json.dumps({"bundle": str(out), "stats": impostor.stats}, indent=2))
        return
    click.echo(f"bundle: {out}\n" + chosen.summary(impostor.stats))
    _warn_outside_promise(chosen, impostor)


def _warn_outside_promise(chosen, impostor) -> None:
    """A warning on stderr where the cell lies where the technique's promise does not hold
    (``Promise.outside``); ``farfield evaluate --check`` fails such a bundle."""
    outside = getattr(chosen.promise, "outside", None)
    if outside is not None and (why := outside(impostor)):
        click.echo(f"farfield: warning: {why}; expect holes (evaluate --check fails it)", err=True)


def _bake_instances(chosen, loaded, cell, settings, names, out: Path, as_json: bool, quiet: bool) -> None:
    """``farfield bake --instances``: one bundle per prototype (:func:`farfield.core.techniques.instances.bake_prototypes`)."""
    from farfield.core.techniques.instances import bake_prototypes

    if chosen.scope != "part":
        raise ArgumentError(f"--instances bakes parts; the {chosen.name} technique represents the whole scene")
    if names:
        raise ArgumentError("--instances bakes every prototype of the scene; --objects does not apply")
    if not loaded.instances():
        raise ArgumentError(f"{loaded.source}: no instanced mesh (no glTF mesh drawn twice or more)")
    bar = _Bar(not quiet and not as_json)
    try:
        impostors = bake_prototypes(loaded, chosen, cell, settings, bar)
    finally:
        bar.close()
    written = []
    for impostor in impostors:
        folder = out / impostor.parameters["prototype"][:16]
        write_bundle(impostor, folder)
        written.append({"bundle": str(folder), "instances": len(impostor.parameters["instances"]["matrices"]),
                        "stats": impostor.stats})  # fmt: skip
    if as_json:
        click.echo(json.dumps({"prototypes": written}, indent=2))
        return
    for entry, impostor in zip(written, impostors):
        click.echo(f"bundle: {entry['bundle']} ({entry['instances']} instances)\n" + chosen.summary(impostor.stats))

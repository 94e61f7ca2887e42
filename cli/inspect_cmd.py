"""``farfield inspect SCENE [--json]``: load a scene file and print its objects, triangles, bounds and colour sources.

Errors are :class:`farfield.core.errors.FarfieldError` s, reported by the group in :mod:`farfield.cli.main`.  Load
warnings are shown in the output (table or JSON), not as Python warnings on stderr.
"""

from __future__ import annotations

import json
import math
import warnings
from pathlib import Path

import click

from farfield.cli import sides_option
from farfield.core.exchange import load_scene
from farfield.core.scene import Scene, SceneWarning


def _vector(values, size=None) -> str:
    """``(x, y, z)`` with 4 significant digits, or, given the box's ``size``, as many more as it takes
    for each coordinate to resolve a thousandth of the size along its axis (a 1.7 m duck at 1e7 m,
    whose min would otherwise print as its max).

    >>> corner = [9999999.0382, 0.09929, 9999999.4607]
    >>> _vector(corner), _vector(corner, [1.655, 1.54, 1.153])
    ('(1e+07, 0.09929, 1e+07)', '(9999999.0382, 0.09929, 9999999.4607)')
    """
    if size is None:
        return "(" + ", ".join(f"{v:.4g}" for v in values) + ")"
    digits = [
        4 if v == 0 or s <= 0 else min(17, max(4, math.ceil(math.log10(abs(v) / s)) + 4)) for v, s in zip(values, size)
    ]
    return "(" + ", ".join(f"{v:.{d}g}" for v, d in zip(values, digits)) + ")"


def _size(extents) -> str:
    """``x × y × z`` with 4 significant digits."""
    return " x ".join(f"{v:.4g}" for v in extents)


def format_table(scene: Scene) -> str:
    """The human-readable report of ``scene``: a header, one row per object, then warnings."""
    lines = [
        f"scene      {scene.source}",
        f"hash       {scene.content_hash}",
        f"objects    {scene.object_count}",
        f"triangles  {scene.triangle_count:,}",
        f"bounds     min {_vector(scene.bounds[0], scene.extents)}  max {_vector(scene.bounds[1], scene.extents)}",
        f"size       {_size(scene.extents)}",
        "",
    ]
    colours = [
        obj.colour_source + ("" if obj.texture is None else f" {obj.texture.shape[1]}x{obj.texture.shape[0]}")
        for obj in scene.objects
    ]
    width = max(len("object"), *(len(obj.name) for obj in scene.objects))
    cwidth = max(len("colour"), *map(len, colours))
    lines.append(f"{'object':<{width}}  {'triangles':>10}  {'colour':<{cwidth}}  {'alpha':>5}  size")
    for obj, colour in zip(scene.objects, colours):
        cutoff = "-" if obj.alpha_cutoff is None else f"{obj.alpha_cutoff:.3g}"
        lines.append(
            f"{obj.name:<{width}}  {obj.triangle_count:>10,}  {colour:<{cwidth}}  {cutoff:>5}  "
            f"{_size(obj.bounds[1] - obj.bounds[0])}"
        )
    lines.append("")
    if scene.warnings:
        lines.append(f"warnings ({len(scene.warnings)}):")
        lines.extend(f"  - {message}" for message in scene.warnings)
    else:
        lines.append("warnings   none")
    return "\n".join(lines)


@click.command("inspect")
@click.argument("scene_path", metavar="SCENE", type=click.Path(path_type=Path, dir_okay=True))
@click.option("--json", "as_json", is_flag=True, help="Print the scene summary as JSON.")
@sides_option
def inspect(scene_path: Path, as_json: bool, sides: str) -> None:
    """Load SCENE (.glb, .gltf, .obj, .ply, .stl) and describe its objects."""
    with warnings.catch_warnings():
        # Warnings are part of the report below; do not also print them as Python warnings.
        warnings.simplefilter("ignore", SceneWarning)
        scene = load_scene(scene_path, sides=sides)
    if as_json:
        click.echo(json.dumps(scene.summary(), indent=2))
    else:
        click.echo(format_table(scene))

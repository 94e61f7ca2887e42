"""``farfield lookup``: what a runtime draws for one view of a placement database (offline): the CPV
holding the view, its status, the impostors to draw (with their bundle folders) and the elements
they replace; everything else is drawn as geometry, or with visibility only the region's
potentially visible set (``pvs``) (:class:`farfield.core.placement.database.PlacementLookup`).
A primitive-budget database's answer is its grid point, the image to warp and the triangles left
(:func:`farfield.core.placement.image_database.image_lookup`)."""

from __future__ import annotations

import json
from pathlib import Path

import click

from farfield.core.impostor.database import ImpostorDatabase
from farfield.core.placement.database import PlacementLookup
from farfield.core.placement.hierarchy import PlacementError
from farfield.core.placement.image_database import image_index_of, image_lookup, placement_of_index


def lookup_answer(database: ImpostorDatabase, position, direction, folder: Path | None = None) -> dict:
    """:meth:`PlacementLookup.find` for the view, plus per impostor to draw its ``index``, ``state``,
    ``bundle`` folder (under ``folder``, or as the index names it inside the database when None; None
    without a result), ``technique`` and ``objects``; and the budget."""
    if database.placement is None:
        raise PlacementError(
            f"{database.root}: not a placement database (its index has no 'placement' section); look up a grid job's cells by position"
        )
    lookup = PlacementLookup(database.index)
    found = lookup.find(position, direction)
    entries = {int(e["index"]): e for e in database.index["cells"]}
    cells = []
    for i in found["impostors"]:
        entry = entries.get(int(i), {})
        bundle = entry.get("bundle")
        cells.append({
            "index": int(i), "state": entry.get("state", "missing"), "bundle": str(folder / bundle) if bundle and folder is not None else bundle,
            "technique": entry.get("technique"), "objects": list(entry.get("objects") or []),
        })  # fmt: skip
    summary = database.placement["summary"]
    return {
        "position": [float(v) for v in position], "direction": [float(v) for v in direction], **found, "cells": cells,
        "t_max": summary["t_max"], "unit": summary["unit"], "elements": database.placement["elements"]["count"],
    }  # fmt: skip


def pvs_lines(answer: dict) -> list[str]:
    """The potentially visible set of the view's region, where the database stores one."""
    pvs = answer.get("pvs")
    if "pvs" not in answer:
        return []
    if pvs is None:
        return ["potentially visible set: none stored for this position; every element is drawn"]
    names = pvs["elements"] or [str(i) for i in pvs["ids"]]
    shown = ", ".join(names[:20]) + (f" ... (+{len(names) - 20})" if len(names) > 20 else "")
    lo, hi = pvs["box"]
    return [
        f"potentially visible set of region {pvs['region']} {lo} .. {hi}: {pvs['count']} of {pvs['of']} elements "
        f"(only these are drawn as geometry): {shown}"
    ]


def answer_lines(answer: dict) -> list[str]:
    """The answer for a person: the CPV and its status, each impostor's bundle and what it replaces,
    and the region's potentially visible set where one is stored."""
    unit = answer["unit"]
    lines = [f"view at {answer['position']} looking {answer['direction']} (t_max {answer['t_max']:.6g} {unit})"]
    if answer["cpv"] is None:
        lines.append(
            f"CPV: none ({answer['status']}): the whole scene as geometry is within t_max by the cost model; draw no impostor"
        )
        return lines + pvs_lines(answer)
    lines.append(
        f"CPV {answer['cpv']}: {answer['status']}, estimated {answer['time_estimated']:.6g} {unit} with its impostors"
    )
    lines.append(f"impostors to draw: {len(answer['cells'])}")
    for cell in answer["cells"]:
        where = cell["bundle"] or f"no bundle (cell {cell['state']})"
        lines.append(f"  {cell['index']:5d}  {cell['technique']}  {where}  replaces {', '.join(cell['objects'])}")
    lines.append(f"geometry: every element but the {len(answer['replaced'])} replaced (of {answer['elements']})")
    return lines + pvs_lines(answer)


def image_answer_lines(answer: dict) -> list[str]:
    """A primitive-budget answer for a person: the grid point, the image to warp, the triangles left."""
    lines = [
        f"view at {answer['position']} yaw {answer['yaw']:.4f} rad (P {answer['primitives_budget']:.6g} triangles)"
    ]
    if answer["point"] < 0:
        lines.append("grid point: none holds this view (outside the view space?)")
    else:
        lines.append(f"grid point {answer['point']}: {answer['status']}")
    lines.append(
        f"image to warp: {answer['image']} ({answer['bundle']})"
        if answer["image"]
        else "image to warp: none, geometry alone"
    )
    lines.append(f"geometry: {len(answer['drawn_octree_cells'])} octree cells, {answer['primitives']} triangles"
                 + ("" if answer["within_budget"] else "  <- over P"))  # fmt: skip
    return lines


def _vector(values: tuple[float, float, float]) -> list[float]:
    return [float(v) for v in values]


@click.command("lookup")
@click.argument("database", type=click.Path(path_type=Path))
@click.option(
    "--at",
    "position",
    type=float,
    nargs=3,
    required=True,
    metavar="X Y Z",
    help="the view's position (inside the view space)",
)
@click.option(
    "--look",
    "direction",
    type=float,
    nargs=3,
    required=True,
    metavar="DX DY DZ",
    help="the view's direction (any length but 0)",
)
@click.option("--json", "as_json", is_flag=True, help="print the answer as JSON")
def lookup_cmd(database: Path, position, direction, as_json: bool) -> None:
    """What to draw for one view of a placement DATABASE (a folder or a zip, as ``farfield submit
    --download`` or ``GET /v1/jobs/{id}/database.zip`` gives it): the CPV, its status, the impostors
    to draw with their bundle folders (inside the zip for a zip), and the elements they replace."""
    index = image_index_of(database)
    if index is not None:  # a primitive-budget database (seed 004): no scene needed, the index holds the cells' bounds
        answer = image_lookup(index, placement_of_index(index), _vector(position), _vector(direction))
        if answer["bundle"] is not None and database.is_dir():
            answer["bundle"] = str(database / answer["bundle"])
        click.echo(json.dumps(answer, indent=1) if as_json else "\n".join(image_answer_lines(answer)))
        return
    with ImpostorDatabase(database) as db:
        answer = lookup_answer(db, _vector(position), _vector(direction), database if database.is_dir() else None)
        if as_json:
            click.echo(json.dumps(answer, indent=1))
        else:
            for line in answer_lines(answer):
                click.echo(line)

"""``farfield techniques``: the registered impostor techniques and their options (as ``GET /v1/techniques``)."""

from __future__ import annotations

import json

import click

from farfield.core.techniques import TECHNIQUES


def _bounds(o: dict) -> str:
    low = (
        f"[{o['minimum']:g}"
        if o["minimum"] is not None
        else f"({o['exclusive_minimum']:g}"
        if o["exclusive_minimum"] is not None
        else ""
    )
    high = (
        f"{o['maximum']:g}]"
        if o["maximum"] is not None
        else f"{o['exclusive_maximum']:g})"
        if o["exclusive_maximum"] is not None
        else ""
    )
    if o["choices"] is not None:
        return "|".join(o["choices"])
    if low or high:
        return f"{low or '(-inf'}, {high or 'inf)'}"
    return ""


@click.command("techniques")
@click.option("--json", "as_json", is_flag=True, help="The same document as GET /v1/techniques.")
def techniques(as_json):
    """List the impostor techniques, their scope, what each promises and their options (types, defaults, bounds, help)."""
    described = [t.describe() for t in TECHNIQUES.values()]
    if as_json:
        click.echo(json.dumps({"techniques": described}, indent=2))
        return
    for n, t in enumerate(described):
        if n:
            click.echo()
        image = ", ".join(f"{f['name']} {f['default']:g}" for f in t["image"])
        click.echo(f"{t['name']} ({t['scope']}): {t['help']}\n  promises: {t['promise']['text']}\n  defaults: {image}")
        for o in t["options"]:
            default = ",".join(o["default"]) if isinstance(o["default"], list) else o["default"]
            click.echo(f"  {o['name']:<16} {o['type']:<8} default {str(default):<20} {_bounds(o):<22} {o['help']}")

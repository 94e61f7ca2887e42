"""Layered impostors (seed 000 ch. 3): one part seen from a view cell, as textured quads on layers."""

from __future__ import annotations

from core.bake import BakeOptions, bake_layered
from core.techniques.base import Technique
from core.techniques.part import check_part_cell, evaluate_part, part_evaluation_text, seconds_line


def _bake(scene, cell, options, objects, progress):
    return bake_layered(scene, cell, options, objects, progress)


def _summary(stats: dict) -> str:
    return (
        f"layers: {stats['layers']} (planned {stats['layers_planned']})  quads: {stats['quads']}  "
        f"atlas pages: {stats['atlas_pages']}  texture: {stats['texture_bytes'] / 1024:.1f} KiB "
        f"(one quad per layer: {stats['texture_bytes_one_quad_per_layer'] / 1024:.1f} KiB)\n"
        f"texels: {stats['texels_covered']} covered, {stats['texels_culled']} culled\n" + seconds_line(stats)
    )


TECHNIQUE = Technique(
    name="layered",
    scope="part",
    help="layered impostors of a scene's objects for any view cell (seed 000 ch. 3)",
    Options=BakeOptions,
    check=check_part_cell,
    bake=_bake,
    summary=_summary,
    evaluate=evaluate_part,
    evaluation_text=part_evaluation_text,
)

"""Textured depth meshes (seed 003): one part seen from a view cell, as a simplified textured mesh."""

from __future__ import annotations

from core.tdm import TdmOptions, bake_tdm
from core.techniques.base import Technique
from core.techniques.part import check_part_cell, evaluate_part, part_evaluation_text, seconds_line


def _bake(scene, cell, options, objects, progress):
    return bake_tdm(scene, cell, options, objects, progress)


def _summary(stats: dict) -> str:
    return (
        f"layers: {stats['layers']} (planned {stats['layers_planned']})  voxels: {stats['voxels']}  "
        f"triangles: {stats['initial_triangles']} -> {stats['triangles']}  meshes: {stats['meshes']}\n"
        f"texture: {stats['texture_bytes'] / 1024:.1f} KiB  geometry: {stats['geometry_bytes'] / 1024:.1f} KiB  "
        f"atlas pages: {stats['atlas_pages']}\n" + seconds_line(stats)
    )


TECHNIQUE = Technique(
    name="tdm",
    scope="part",
    help="textured depth meshes of a scene's objects for any view cell (seed 003; planned like layered)",
    Options=TdmOptions,
    check=check_part_cell,
    bake=_bake,
    summary=_summary,
    evaluate=evaluate_part,
    evaluation_text=part_evaluation_text,
)

"""``farfield bake``: bake one impostor (layered, an environment map, or a textured depth mesh) and write its bundle (manifest, atlas PNGs, GLB)."""

from __future__ import annotations

import json
from pathlib import Path

import click
from tqdm import tqdm

from core.bake import BakeOptions, bake_layered
from core.bundle import write_bundle
from core.culling import CULLING_MODES
from core.envmap import FACES, EnvmapOptions, bake_envmap
from core.errors import LayerPlanError
from core.exchange import load_scene
from core.frustum import PIXEL_MODELS
from core.tdm import TdmOptions, bake_tdm
from core.viewcells import parse_viewcell


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


@click.command("bake")
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("--viewcell", required=True, help="box:x0,y0,z0,x1,y1,z1 | box-center:cx,cy,cz,size | shaft:...")
@click.option("--out", "out", required=True, type=click.Path(file_okay=False), help="Bundle directory to write (replaced whole).")
@click.option("--objects", default=None, help="Comma-separated object names forming the part (default: all).")
@click.option("--resolution", default=512, show_default=True, type=int, help="Output image pixels per side.")
@click.option("--technique", type=click.Choice(["layered", "envmap", "tdm"]), default="layered", show_default=True,
              help="layered: one part seen from a view cell; envmap: the whole scene around a cubic view cell (seed 002); "
                   "tdm: textured depth meshes of one part seen from a view cell (seed 003).")
@click.option("--fov", default=None, type=float, help="Output field of view, degrees [default: 45 layered and tdm, 90 envmap].")
@click.option("--layers", default=None, type=int, help="envmap: number of layers [default: 64 unless --near-field].")
@click.option("--near-field", default=None, type=float, help="envmap: largest near-field distance from the cell centre (instead of --layers).")
@click.option("--directions", default=",".join(FACES), show_default=True, help="envmap: cube faces to record, e.g. +x,-x,+z,-z.")
@click.option("--gap-fill/--no-gap-fill", default=False, show_default=True, help="envmap: seed 002 §5.1 gap filling.")
@click.option("--enlargement", default=2.0, show_default=True, type=float,
              help="tdm: voxel enlargement factor of the covering test (seed 003 §6): larger, fewer polygons, less accurate.")
@click.option("--oversampling", default=1, show_default=True, type=int, help="tdm: nearest voxels averaged per texel (seed 003 §7).")
@click.option("--grid-cell", default=8, show_default=True, type=int, help="Box-growing grid cell, texels.")
@click.option("--fill-threshold", default=0.8, show_default=True, type=float, help="Box-growing fill ratio.")
@click.option("--culling", type=click.Choice(CULLING_MODES), default="penumbra", show_default=True)
@click.option("--pixel-model", type=click.Choice(PIXEL_MODELS), default="min", show_default=True)
@click.option("--json", "as_json", is_flag=True, help="Print the bundle's statistics as JSON.")
@click.option("--quiet", is_flag=True, help="No progress bar.")
def bake(scene, viewcell, out, objects, resolution, technique, fov, layers, near_field, directions, gap_fill, enlargement, oversampling, grid_cell,
         fill_threshold, culling, pixel_model, as_json, quiet):  # fmt: skip
    """Bake the impostor of SCENE for a view cell and write its bundle to --out."""
    cell = parse_viewcell(viewcell)
    if technique == "envmap":
        if objects:
            raise LayerPlanError("an envmap impostor represents the whole scene; --objects does not apply")
        faces = tuple(d.strip() for d in directions.split(",") if d.strip())
        options = EnvmapOptions(
            resolution, 90.0 if fov is None else fov, layers if layers is not None or near_field is not None else 64, near_field,
            faces, gap_fill=gap_fill, culling=culling, grid_cell=grid_cell, fill_threshold=fill_threshold,
        )  # fmt: skip
    elif technique == "tdm":
        options = TdmOptions(resolution, 45.0 if fov is None else fov, enlargement, oversampling, culling, pixel_model)
    else:
        options = BakeOptions(resolution, 45.0 if fov is None else fov, grid_cell, fill_threshold, culling, pixel_model)
    loaded = load_scene(scene)
    names = [n.strip() for n in objects.split(",") if n.strip()] if objects else None
    bar = _Bar(not quiet and not as_json)
    try:
        if technique == "envmap":
            impostor = bake_envmap(loaded, cell, options, progress=bar)
        elif technique == "tdm":
            impostor = bake_tdm(loaded, cell, options, names, progress=bar)
        else:
            impostor = bake_layered(loaded, cell, options, names, progress=bar)
    finally:
        bar.close()
    write_bundle(impostor, Path(out))
    stats = impostor.stats
    if as_json:
        click.echo(json.dumps({"bundle": str(out), "stats": stats}, indent=2))
        return
    seconds = stats["seconds"]
    if technique == "envmap":
        click.echo(
            f"bundle: {out}\n"
            f"faces: {stats['faces']}  layers: {stats['layers']} kept of {stats['faces'] * stats['layers_planned']}  "
            f"near field: {stats['near_field']:.6g} ({stats['near_field_triangles']} triangles)  quads: {stats['quads']}\n"
            f"memory: raw layers {stats['raw_layer_bytes'] / 2**20:.1f} MiB -> macrotextures "
            f"{stats['texture_bytes'] / 2**20:.2f} MiB -> PNG {stats['png_bytes'] / 1024:.1f} KiB\n"
            "seconds: " + "  ".join(f"{k} {v:.3f}" for k, v in seconds.items())
        )
        return
    if technique == "tdm":
        click.echo(
            f"bundle: {out}\n"
            f"layers: {stats['layers']} (planned {stats['layers_planned']})  voxels: {stats['voxels']}  "
            f"triangles: {stats['initial_triangles']} -> {stats['triangles']}  meshes: {stats['meshes']}\n"
            f"texture: {stats['texture_bytes'] / 1024:.1f} KiB  geometry: {stats['geometry_bytes'] / 1024:.1f} KiB  atlas pages: {stats['atlas_pages']}\n"
            "seconds: " + "  ".join(f"{k} {v:.3f}" for k, v in seconds.items())
        )
        return
    click.echo(
        f"bundle: {out}\n"
        f"layers: {stats['layers']} (planned {stats['layers_planned']})  quads: {stats['quads']}  "
        f"atlas pages: {stats['atlas_pages']}  texture: {stats['texture_bytes'] / 1024:.1f} KiB "
        f"(one quad per layer: {stats['texture_bytes_one_quad_per_layer'] / 1024:.1f} KiB)\n"
        f"texels: {stats['texels_covered']} covered, {stats['texels_culled']} culled\n"
        "seconds: " + "  ".join(f"{k} {v:.3f}" for k, v in seconds.items())
    )

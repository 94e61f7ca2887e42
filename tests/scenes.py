"""Canonical test scenes: procedural :class:`farfield.core.scene.Scene` s from a seeded ``np.random.default_rng``, bad inputs, and file writers.

Good scenes (``city``, ``forest``, ``sphere_field``, ``dense_mesh``, ``scan_mesh``, ``textured_quad``) are
returned as validated ``Scene`` s; the bad ones cannot be ``Scene`` s, so they come as raw arrays
(``bad_arrays``) or as file text (``bad_obj``) for the loader tests.  ``write_scene`` writes a
``Scene`` as .glb / .obj / .ply / .stl with trimesh (OBJ with a small writer of our own, so that
objects, materials and textures are under test control).  ``SHARED_SCENES`` is the folder of
third-party scenes beside the checkout; ``REAL_SCENES`` is its README table.
"""

from __future__ import annotations

import functools
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from farfield.core.colour_space import linear_to_srgb
from farfield.core.exchange import load_scene
from farfield.core.exchange.export import texture_image, to_trimesh
from farfield.core.procedural import box_object, forest, house  # noqa: F401 - moved to core (farfield scenes demo); tests import them from here
from farfield.core.scene import Scene, SceneObject

SHARED_SCENES = Path(__file__).resolve().parents[1].parent / "shared" / "scenes"


@dataclass(frozen=True, slots=True)
class RealScene:
    """A row of ``SHARED_SCENES/README.md``: path, triangle count, size, and the size's tolerance."""

    path: str  # relative to SHARED_SCENES
    triangles: int
    size: tuple[float, float, float]  # x, y, z extents as the README prints them, scene units
    atol: float  # half a unit in the last digit the README prints


REAL_SCENES = (
    RealScene("scrub_pine/scrubPine.obj", 527, (716.0, 931.0, 702.0), 0.5),
    RealScene("stanford_bunny/bun_zipper.ply", 69_451, (0.156, 0.154, 0.121), 0.0005),
    RealScene("damaged_helmet/DamagedHelmet.glb", 15_452, (1.9, 1.8, 2.0), 0.05),
    RealScene("duck/duck.obj", 4_212, (1.7, 1.5, 1.2), 0.05),
)


@functools.cache
def real_scene(path: str) -> Scene:
    """The shared scene at ``SHARED_SCENES / path``, loaded once per test session (scenes are immutable)."""
    return load_scene(SHARED_SCENES / path)


# ---------------------------------------------------------------------------------- primitives


def checker(size: int = 8, squares: int = 2) -> np.ndarray:
    """(size, size, 4) uint8 RGBA checkerboard of dark and light squares, opaque."""
    index = np.arange(size) * squares // size
    light = (index[:, None] + index[None, :]) % 2 == 0
    texture = np.empty((size, size, 4), dtype=np.uint8)
    texture[...] = (40, 40, 160, 255)
    texture[light] = (230, 200, 60, 255)
    return texture


# ---------------------------------------------------------------------------------- good scenes


def city(buildings: int = 300, seed: int = 0) -> Scene:
    """A city of ``buildings`` boxes on a square grid of lots plus a ground plane, material colours.

    Lots are 20 units apart; footprints 6..16 units, heights log-normal around 15 units.
    """
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(buildings)))
    lots = np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="ij"), axis=-1).reshape(-1, 2)[:buildings]
    footprint = rng.uniform(6.0, 16.0, size=(buildings, 2))
    height = rng.lognormal(np.log(15.0), 0.6, size=buildings)
    grey = rng.uniform(0.35, 0.9, size=buildings)
    objects = []
    for i in range(buildings):
        centre = lots[i] * 20.0
        low = (centre[0] - footprint[i, 0] / 2, 0.0, centre[1] - footprint[i, 1] / 2)
        high = (centre[0] + footprint[i, 0] / 2, height[i], centre[1] + footprint[i, 1] / 2)
        objects.append(box_object(f"building_{i:03d}", low, high, (grey[i], grey[i], grey[i] * 0.95, 1.0)))
    extent = side * 20.0
    ground = SceneObject(
        "ground",
        np.array([[-10.0, 0.0, -10.0], [-10.0, 0.0, extent], [extent, 0.0, extent], [extent, 0.0, -10.0]]),
        np.array([[0, 1, 2], [0, 2, 3]]),  # counter-clockwise seen from +y
        base_color=(0.3, 0.5, 0.25, 1.0),
    )
    return Scene.from_objects([ground, *objects], source=f"city-{buildings}-{seed}")


def sphere_field(spheres: int = 100, seed: int = 2) -> Scene:
    """A field of ``spheres`` icospheres (320 triangles each); even ones textured, odd ones material-coloured.

    Radii 0.5..3 units in a 200 x 50 x 200 box; texture coordinates are longitude / latitude.
    """
    rng = np.random.default_rng(seed)
    unit = trimesh.creation.icosphere(subdivisions=2)
    vertices = np.asarray(unit.vertices, dtype=np.float64)
    faces = np.asarray(unit.faces, dtype=np.int64)
    uv = np.column_stack(
        [
            np.arctan2(vertices[:, 1], vertices[:, 0]) / (2 * np.pi) + 0.5,
            np.arcsin(np.clip(vertices[:, 2], -1.0, 1.0)) / np.pi + 0.5,
        ]
    )
    texture = checker()
    radius = rng.uniform(0.5, 3.0, size=spheres)
    centre = rng.uniform((0.0, 0.0, 0.0), (200.0, 50.0, 200.0), size=(spheres, 3))
    colour = rng.uniform(0.2, 1.0, size=(spheres, 3))
    objects = []
    for i in range(spheres):
        world = centre[i] + vertices * radius[i]
        if i % 2 == 0:
            objects.append(SceneObject(f"sphere_{i:03d}", world, faces, uv=uv, texture=texture))
        else:
            objects.append(SceneObject(f"sphere_{i:03d}", world, faces, base_color=(*colour[i], 1.0)))
    return Scene.from_objects(objects, source=f"spheres-{spheres}-{seed}")


def dense_mesh(subdivisions: int = 6, seed: int = 3) -> Scene:
    """One bumpy icosphere: ``20 * 4**subdivisions`` triangles (81,920 at 6), radius 1 +- 2 %."""
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.icosphere(subdivisions=subdivisions)
    vertices = np.asarray(sphere.vertices, dtype=np.float64)
    vertices = vertices * rng.uniform(0.98, 1.02, size=(len(vertices), 1))
    return Scene.from_objects([SceneObject("dense", vertices, np.asarray(sphere.faces, dtype=np.int64))], "dense")


def scan_mesh(rows: int = 302, seed: int = 5) -> Scene:
    """A scanned-looking blob of radius about 1: a latitude-longitude sphere (trimesh's ``uv_sphere``
    of ``rows`` by ``rows + 1``) minus its hole faces (364,800 triangles before the holes, 351,682
    after, at 302: the size of the scan of issue 60).

    A scan's character, unlike :func:`dense_mesh`'s smooth bumps: 9 octaves of noise, every second
    one ridged (sharp creases where it folds), from a wavelength of 2.1 (amplitude 0.06) down to
    0.008 (0.0006), per-vertex jitter of +-0.002 (about one voxel of
    ``benchmarks/bench_tdm_scale.py --scene scan``, whose voxels at the front are about 0.002 across
    and whose triangles about 0.01), and 24 holes where the scanner saw nothing (boundary loops,
    many small charts).  Deterministic for a ``seed``."""
    rng = np.random.default_rng(seed)
    sphere = trimesh.creation.uv_sphere(radius=1.0, count=[rows, rows + 1])
    p = np.asarray(sphere.vertices, dtype=np.float64)
    direction = p / np.linalg.norm(p, axis=1, keepdims=True)
    radius = np.ones(len(p))
    for octave in range(9):  # wavelengths 2 pi / (3 * 2**octave): 2.1 down to 0.008
        frequency, amplitude = 3.0 * 2.0**octave, 0.06 * 0.55**octave
        waves = rng.normal(size=(6, 3))
        waves *= frequency / np.linalg.norm(waves, axis=1, keepdims=True)
        phase = rng.uniform(0.0, 2.0 * np.pi, size=6)
        value = np.sin(direction @ waves.T + phase).mean(axis=1)
        radius += amplitude * (np.abs(value) if octave % 2 else value)  # odd octaves ridged: creases
    radius += rng.uniform(-0.002, 0.002, size=len(p))
    vertices = direction * radius[:, None]
    faces = np.asarray(sphere.faces, dtype=np.int64)
    centre = vertices[faces].mean(axis=1)
    holes = rng.normal(size=(24, 3))
    holes /= np.linalg.norm(holes, axis=1, keepdims=True)
    size = rng.uniform(0.03, 0.12, size=24)
    distance = np.linalg.norm(centre[:, None, :] / np.linalg.norm(centre, axis=1)[:, None, None] - holes[None], axis=2)
    faces = faces[~(distance < size).any(axis=1)]
    used, faces = np.unique(faces, return_inverse=True)
    return Scene.from_objects([SceneObject("scan", vertices[used], faces.reshape(-1, 3))], "scan")


# A 2 x 2 texture with four distinct texels (top row first): red, green / blue, yellow; the
# yellow texel is half transparent and the green one fully, for alpha tests.
QUAD_TEXTURE = np.array([[[255, 0, 0, 255], [0, 255, 0, 0]], [[0, 0, 255, 255], [255, 255, 0, 128]]], dtype=np.uint8)


def textured_quad(alpha_cutoff: float | None = None, texture: np.ndarray = QUAD_TEXTURE) -> Scene:
    """A unit quad in the z = 0 plane facing +z, uv = (x, y), with ``texture`` (default ``QUAD_TEXTURE``).

    Under the uv convention the corner (0, 1) shows the top-left texel, (0, 0) the bottom-left.
    """
    vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    quad = SceneObject("quad", vertices, faces, uv=vertices[:, :2], texture=texture, alpha_cutoff=alpha_cutoff)
    return Scene.from_objects([quad], "quad")


# ---------------------------------------------------------------------------------- bad inputs


def bad_arrays(kind: str) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (v, 3) float64, faces (f, 3) int64) that no valid scene may hold.

    ``kind`` is one of ``"nan"``, ``"inf"`` (one bad vertex), ``"point"`` (zero extent: every
    vertex at the same place), ``"huge"`` (a coordinate of 1e13, beyond ``TOL.max_coordinate``),
    ``"no_faces"`` and ``"bad_index"`` (a face refers to vertex 9 of 3).
    """
    vertices = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    faces = np.array([[0, 1, 2]])
    if kind == "nan":
        vertices[1, 0] = np.nan
    elif kind == "inf":
        vertices[2, 1] = np.inf
    elif kind == "point":
        vertices[:] = (5.0, 5.0, 5.0)
    elif kind == "huge":
        vertices[1, 0] = 1e13
    elif kind == "no_faces":
        faces = np.zeros((0, 3), dtype=np.int64)
    elif kind == "bad_index":
        faces = np.array([[0, 1, 9]])
    else:
        raise ValueError(f"unknown bad-array kind {kind!r}")
    return vertices, faces


def obj_text(vertices: np.ndarray, faces: np.ndarray, name: str = "thing") -> str:
    """Minimal OBJ text of one object (``o name``, ``v`` and ``f`` lines; non-finite values as nan/inf)."""
    lines = [f"o {name}"]
    lines += [f"v {x!r} {y!r} {z!r}" for x, y, z in vertices.tolist()]
    lines += [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in faces.tolist()]
    return "\n".join(lines) + "\n"


def bad_obj(kind: str) -> str:
    """OBJ text of :func:`bad_arrays` ``(kind)``, object named ``thing``."""
    return obj_text(*bad_arrays(kind))


# ---------------------------------------------------------------------------------- writers


def write_obj(
    scene: Scene, path: Path, texture_names: dict[str, str] | None = None, skip_textures: bool = False
) -> Path:
    """Write ``scene`` as ``path`` (OBJ) + an MTL beside it + one PNG per textured object.

    One ``o`` per object with its own material ``<name>_mat`` (``Kd`` sRGB-encoded, as MTL files
    are authored, ``d``, ``map_Kd``).
    ``texture_names`` maps object name to the PNG file name to reference; ``skip_textures``
    references the PNGs without writing them (the missing-texture case).
    """
    path = Path(path)
    mtl_name = path.with_suffix(".mtl").name
    obj_lines, mtl_lines = [f"mtllib {mtl_name}"], []
    offset = uv_offset = 1  # OBJ indices are 1-based and count v and vt lines separately
    for obj in scene.objects:
        material = f"{obj.name}_mat"
        obj_lines += [f"o {obj.name}", f"usemtl {material}"]
        obj_lines += ["v {:.17g} {:.17g} {:.17g}".format(*v) for v in obj.vertices.tolist()]
        r, g, b = linear_to_srgb(obj.base_color[:3]).tolist()
        a = float(obj.base_color[3])
        mtl_lines += [f"newmtl {material}", f"Kd {r:.17g} {g:.17g} {b:.17g}", f"d {a:.17g}"]
        if obj.uv is not None:
            obj_lines += ["vt {:.17g} {:.17g}".format(*t) for t in obj.uv.tolist()]
            obj_lines += [
                f"f {a}/{a - offset + uv_offset} {b}/{b - offset + uv_offset} {c}/{c - offset + uv_offset}"
                for a, b, c in (obj.faces + offset).tolist()
            ]
            uv_offset += len(obj.uv)
        else:
            obj_lines += ["f {} {} {}".format(*f) for f in (obj.faces + offset).tolist()]
        if obj.texture is not None:
            png = (texture_names or {}).get(obj.name, f"{obj.name}.png")
            mtl_lines.append(f"map_Kd {png}")
            if not skip_textures:
                texture_image(obj.texture).save(path.parent / png)
        offset += len(obj.vertices)
    path.write_text("\n".join(obj_lines) + "\n")
    (path.parent / mtl_name).write_text("\n".join(mtl_lines) + "\n")
    return path


def write_scene(scene: Scene, directory: Path, extension: str, stem: str = "scene") -> Path:
    """Write ``scene`` to ``directory / f"{stem}.{extension}"`` and return the path.

    ``glb`` keeps objects, names and colours; ``obj`` see :func:`write_obj`; ``ply`` and ``stl``
    hold a single mesh, so the objects are concatenated (``ply`` keeps vertex colours).
    """
    path = Path(directory) / f"{stem}.{extension}"
    if extension == "obj":
        return write_obj(scene, path)
    if extension in ("ply", "stl"):
        parts = []
        for obj in scene.objects:
            mesh = trimesh.Trimesh(np.array(obj.vertices), np.array(obj.faces), process=False)
            if obj.vertex_colors is not None:
                mesh.visual = trimesh.visual.ColorVisuals(mesh, vertex_colors=np.array(obj.vertex_colors))
            parts.append(mesh)
        mesh = parts[0] if len(parts) == 1 else trimesh.util.concatenate(parts)
        path.write_bytes(mesh.export(file_type=extension))
        return path
    data = to_trimesh(scene).export(file_type=extension)
    path.write_bytes(data if isinstance(data, bytes) else data.encode())
    return path


def png_bytes(texture: np.ndarray) -> bytes:
    """PNG file bytes of a (h, w, 4) uint8 RGBA texture."""
    buffer = io.BytesIO()
    texture_image(texture).save(buffer, format="PNG")
    return buffer.getvalue()


def instanced_nodes_glb(nodes: int) -> bytes:
    """A GLB of ``nodes`` nodes (``node000000``...) on a square grid, each an instance of the one
    triangle mesh: a scene of ``nodes`` objects in little more than 100 bytes per node (issue 24's
    10^5-node upload)."""
    import json
    import struct

    positions = np.array([[0, 0, 0], [0.5, 0, 0], [0, 0.5, 0]], dtype="<f4").tobytes()
    side = max(1, int(np.ceil(np.sqrt(nodes))))
    document = {
        "asset": {"version": "2.0"},
        "scene": 0,
        "scenes": [{"nodes": list(range(nodes))}],
        "nodes": [{"name": f"node{i:06d}", "mesh": 0, "translation": [i % side, 0, i // side]} for i in range(nodes)],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "accessors": [
            {"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3", "min": [0, 0, 0], "max": [0.5, 0.5, 0]}
        ],
        "bufferViews": [{"buffer": 0, "byteLength": len(positions)}],
        "buffers": [{"byteLength": len(positions)}],
    }
    text = json.dumps(document, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    binary = positions + b"\0" * (-len(positions) % 4)
    chunks = struct.pack("<I4s", len(text), b"JSON") + text + struct.pack("<I4s", len(binary), b"BIN\0") + binary
    return struct.pack("<4sII", b"glTF", 2, 12 + len(chunks)) + chunks

"""Wavefront OBJ + MTL -> (k,) SceneObject, one per (``o`` object, material) pair.

Objects: trimesh splits the faces by ``o`` statement and by ``usemtl`` material (one material per
object is what the scene model holds).  It names a piece ``<object>_<material>`` when the file has
several materials; the material suffix is dropped again where the object name alone is unique.
A file without ``o`` statements gives one object per material, named after the material (or after
the file when there is a single material).

Colours: ``map_Kd`` is the texture and replaces ``Kd``; ``Kd`` is the colour of untextured
materials; ``d`` (or ``1 - Tr``) is the alpha factor.  ``map_d`` (an opacity image: its alpha
channel, or its luminance if it has none) becomes the texture's alpha.  A texture with any alpha
below 255 is alpha-cut at 0.5.  OBJ ``vt`` coordinates already have their origin at the
bottom-left and are kept as they are.

trimesh only logs (at debug level) a material library or texture it cannot find; :func:`load`
looks them up itself and returns a warning for each, and the objects keep the material colour.
"""

from __future__ import annotations

import io
import re
from collections import Counter

import numpy as np
import PIL.Image
import trimesh
from trimesh.resolvers import Resolver
from trimesh.visual.material import SimpleMaterial

from farfield.core.errors import SceneLoadError
from farfield.core.exchange.limits import DEFAULT_LIMITS, SceneLimits
from farfield.core.exchange.trimesh_scene import IMAGE_ERRORS, fetch, objects_from_trimesh, parse
from farfield.core.scene import SceneObject

EXTENSIONS = ("obj",)

_MTLLIB = re.compile(r"^[ \t]*mtllib[ \t]+(.*\S)", re.MULTILINE)


def decode_text(data: bytes) -> str:
    """The text of an OBJ or MTL file: UTF-8, else Latin-1 (which decodes any byte).

    Raises
    ------
    SceneLoadError
        The data holds NUL bytes, so it is binary, not OBJ text.
    """
    if b"\x00" in data:
        raise SceneLoadError("binary data (NUL bytes), not a text OBJ file")
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError:
        return data.decode("latin-1")


def texture_maps(mtl: str) -> dict[str, dict[str, str]]:
    """``{material: {"map_kd": file, "map_d": file}}`` for the texture maps an MTL file names.

    File names are the rest of the line after the keyword, as trimesh reads them.

    >>> texture_maps("newmtl leaf\\nKd 1 1 1\\nmap_Kd leaf.png\\nmap_d leaf mask.png\\n")
    {'leaf': {'map_kd': 'leaf.png', 'map_d': 'leaf mask.png'}}
    """
    maps: dict[str, dict[str, str]] = {}
    current = None
    for line in mtl.splitlines():
        split = line.strip().split()
        if len(split) <= 1:
            continue
        key = split[0].lower()
        if key == "newmtl":
            current = maps.setdefault(" ".join(split[1:]), {})
        elif key in ("map_kd", "map_d") and current is not None:
            start = line.lower().index(key) + len(key)
            current[key] = line[start:].strip()
    return {name: files for name, files in maps.items() if files}


def _opacity(image: PIL.Image.Image) -> PIL.Image.Image:
    """An ``L`` image of opacity from a ``map_d`` image: its alpha channel, or its luminance."""
    if image.mode in ("RGBA", "LA", "PA") or "transparency" in image.info:
        return image.convert("RGBA").getchannel("A")
    return image.convert("L")


def _apply_opacity(material: SimpleMaterial, data: bytes) -> None:
    """Make ``map_d`` (``data``) the alpha channel of the material's texture (a flat ``Kd`` one if none).

    Raises
    ------
    OSError, ValueError, SyntaxError, ...
        See :data:`farfield.core.exchange.trimesh_scene.IMAGE_ERRORS`.
    """
    alpha = _opacity(PIL.Image.open(io.BytesIO(data)))
    if material.image is not None:
        base = material.image.convert("RGBA")
    else:
        rgb = tuple(int(c) for c in np.asarray(material.diffuse)[:3])
        base = PIL.Image.new("RGBA", alpha.size, rgb + (255,))
    if alpha.size != base.size:
        alpha = alpha.resize(base.size, PIL.Image.Resampling.BILINEAR)
    base.putalpha(alpha)
    material.image = base


def _textures(scene: trimesh.Scene, maps: dict[str, dict[str, str]], resolver: Resolver) -> list[str]:
    """Apply ``map_d`` maps to the parsed materials; warn about maps that could not be loaded.

    Materials naming the same texture file share one image (trimesh opens the file once per
    material), and those naming the same ``map_kd`` and ``map_d`` files one composed image, so a
    shared atlas is decoded once however many materials use it (:func:`objects_from_trimesh`
    decodes each image once)."""
    warnings: list[str] = []
    seen: set[int] = set()
    images: dict[str, PIL.Image.Image] = {}  # map_kd file -> the first material's image
    composed: dict[tuple, PIL.Image.Image] = {}  # (map_kd file or Kd, map_d file) -> image with alpha
    for mesh in scene.geometry.values():
        material = getattr(getattr(mesh, "visual", None), "material", None)
        if not isinstance(material, SimpleMaterial) or id(material) in seen:
            continue
        seen.add(id(material))
        files = maps.get(material.name, {})
        if "map_kd" in files and material.image is None:
            warnings.append(
                f"texture {files['map_kd']!r} of material {material.name!r} could not be loaded; "
                "using the material colour"
            )
        if "map_kd" in files and material.image is not None:
            material.image = images.setdefault(files["map_kd"], material.image)
        if "map_d" not in files:
            continue
        key = (files.get("map_kd") if material.image is not None else tuple(np.asarray(material.diffuse).tolist()), files["map_d"])
        if key in composed:
            material.image = composed[key]
            continue
        data = fetch(resolver, files["map_d"])
        if data is None:
            warnings.append(f"opacity map {files['map_d']!r} of material {material.name!r} not found; ignored")
            continue
        try:
            _apply_opacity(material, data)
            composed[key] = material.image
        except IMAGE_ERRORS as error:
            warnings.append(
                f"opacity map {files['map_d']!r} of material {material.name!r} could not be decoded "
                f"({type(error).__name__}: {error}); ignored"
            )
    return warnings


def _short_names(scene: trimesh.Scene) -> dict[str, str]:
    """Node -> object name with the ``_<material>`` suffix dropped where the rest is unique."""
    stripped = {}
    for node in scene.graph.nodes_geometry:
        material = getattr(getattr(scene.geometry[scene.graph[node][1]], "visual", None), "material", None)
        suffix = "_" + str(getattr(material, "name", None))
        if node.endswith(suffix) and len(node) > len(suffix):
            stripped[node] = node[: -len(suffix)]
    counts = Counter(stripped.values())
    taken = set(scene.graph.nodes_geometry) - set(stripped)
    return {node: short for node, short in stripped.items() if counts[short] == 1 and short not in taken}


def load(
    data: bytes, extension: str, name: str, resolver: Resolver, limits: SceneLimits = DEFAULT_LIMITS
) -> tuple[tuple[SceneObject, ...], tuple[str, ...]]:
    """Objects and warnings of an OBJ file (see the module docstring).

    Parameters
    ----------
    data : bytes
        The OBJ file.
    extension : str
        ``"obj"``.
    name : str
        The file's name; trimesh names an unnamed single-material object after it.
    resolver : trimesh.resolvers.Resolver
        Finds the MTL file and the textures.

    Raises
    ------
    SceneLoadError
        Binary data, or trimesh could not parse it (e.g. a face index beyond the vertices).
    """
    text = decode_text(data)
    warnings: list[str] = []
    maps: dict[str, dict[str, str]] = {}
    libraries = _MTLLIB.findall(text)
    if libraries:
        if len(libraries) > 1:
            warnings.append(f"only the first material library, {libraries[0]!r}, is read")
        mtl = fetch(resolver, libraries[0])
        if mtl is None:
            warnings.append(f"material library {libraries[0]!r} not found; objects use the default colour")
        elif b"\x00" in mtl:
            warnings.append(f"material library {libraries[0]!r} is binary, not MTL text; texture maps not checked")
        else:
            maps = texture_maps(decode_text(mtl))
    scene = parse(text.encode("utf-8"), extension, resolver, split_objects=True, group_material=True)
    warnings.extend(_textures(scene, maps, resolver))
    objects, more = objects_from_trimesh(scene, rename=_short_names(scene))
    return objects, tuple(warnings) + more

"""Wavefront OBJ + MTL -> (k,) SceneObject, one per (``o`` object, material) pair.

Objects: trimesh splits the faces by ``o`` statement and by ``usemtl`` material (one material per
object is what the scene model holds).  It names a piece ``<object>_<material>`` when the file has
several materials; the material suffix is dropped again where the object name alone is unique.
A file without ``o`` statements gives one object per material, named after the material (or after
the file when there is a single material).

Colours, after the MTL specification: the diffuse colour is ``Kd`` × ``map_Kd`` (a material with a
texture and no ``Kd`` shows the texture as is); ``d`` (or ``1 - Tr``) is the alpha factor.
``map_d`` is a scalar opacity map multiplied into the texture's alpha: the channel its ``-imfchan``
names (``r``, ``g``, ``b``, ``m`` the matte/alpha, ``l`` luminance), luminance by default, since a
mask is often saved as an RGBA image whose alpha is constant.  Without ``-imfchan`` the image's
alpha is taken instead where it is evidently the mask: it varies while the colour channels do not,
or the map is the ``map_Kd`` file itself (an RGBA texture named twice).  A texture with any alpha
below 255 is alpha-cut at 0.5.  ``map_Kd``'s ``-o`` and ``-s`` move and scale the uv; other map
options that change what is shown (``-t``, ``-clamp on``, ``-mm``, ``-cc on``, ``-boost``, and any
on ``map_d`` but ``-imfchan``) are not supported and each gives a warning naming it.  OBJ ``vt``
coordinates already have their origin at the bottom-left and are kept as they are.

A polygon of five or more corners that trimesh's fan would not cover (concave) is cut into
triangles that do (:mod:`farfield.core.exchange.obj_polygons`).

Relative indices (``f -3 -2 -1``) count back from the face, as the specification and three.js
read them (:mod:`farfield.core.exchange.obj_indices`; trimesh counted from the end of the file).

Shading normals: ``vn`` as the face corners name them (``f v/vt/vn``, ``f v//vn``), a position
with several normals split into several vertices; a face without normal indices in a file whose
other faces have them gets its face normal, and a ``vn`` index out of range is refused
(:mod:`farfield.core.exchange.obj_normals`).  A file without them is shaded flat.

Materials (the PBR extension of MTL, as Blender writes it): ``Pr`` roughness and ``Pm`` metallic
(0..1; default 1 and 0, the matte dielectric of a file without them), ``Ke`` emission (linear RGB),
and their maps ``map_Pr`` and ``map_Pm`` (scalar: the channel ``-imfchan`` names, luminance by
default; composed into the G and B channels of one metallic-roughness image, glTF's packing, and
multiplied by ``Pr``/``Pm``, which default to 1 beside a map) and ``map_Ke`` (sRGB RGB, multiplied
by ``Ke``, default 1 beside the map); over the object's ``vt``.  A map that cannot be read, or whose
size differs from the other scalar map's, is left out with a warning.

Material libraries: every one the file names (:func:`material_libraries`: several ``mtllib`` lines,
several names on one), given to trimesh as one; a ``usemtl`` none of them defines is warned about.
trimesh only logs (at debug level) a material library or texture it cannot find; :func:`load`
looks them up itself and returns a warning for each, and the objects keep the material colour.

Sidedness: the format states none, so every object is one-sided by default (``sides="one"``: seen
from the front of each triangle only, counter-clockwise, as engines and three.js's OBJLoader draw the
file) or double-sided with ``sides="both"`` (:mod:`farfield.core.sidedness`).
"""

from __future__ import annotations

import io
import re
from collections import Counter

import numpy as np
import PIL.Image
import PIL.ImageChops
import trimesh
from trimesh.resolvers import Resolver
from trimesh.visual.material import SimpleMaterial

from farfield.core.errors import SceneLoadError
from farfield.core.exchange.limits import DEFAULT_LIMITS, SceneLimits
from farfield.core.exchange.obj_indices import absolute_indices, beyond_the_end
from farfield.core.exchange.obj_no_uv import paired_indices
from farfield.core.exchange.obj_normals import complete_normals
from farfield.core.exchange.obj_polygons import split_concave
from farfield.core.exchange.references import MapStatement, map_statement
from farfield.core.exchange.trimesh_scene import (
    IMAGE_ERRORS,
    check_texels,
    eight_bit,
    fetch,
    file_normals,
    objects_from_trimesh,
    parse,
    texture_rgba,
)
from farfield.core.scene import SceneObject
from farfield.core.sidedness import DEFAULT_SIDES, double_sided

# The format states no sidedness: load takes the ``sides`` option (farfield.core.exchange.load_scene).
SIDES_OPTION = True
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


# Whitespace before a statement, and a comment after an element's numbers (``v 1 2 3 # corner``).
_INDENT = re.compile(r"^[ \t]+", re.MULTILINE)
_CONTINUED = re.compile(r"\\\r?\n")
# A comment line, whose backslashes at its end (``# C:\\models\\``) continue nothing: a comment ends
# at its line.  The patterns here have no lazy part before a repeated one, so they scan a line once
# (a lazy one before `` *#`` took 0.2 s for a line of 20,000 spaces, and grew as its square).
_COMMENT = re.compile(r"^[ \t]*#[^\n]*", re.MULTILINE)
_TRAILING_COMMENT = re.compile(r"^((?:v|vt|vn|vp|f|l) )([^#\r\n]*)#[^\r\n]*", re.MULTILINE)


def _uncontinued(match: re.Match) -> str:
    line = match.group(0)
    end = "\r" if line.endswith("\r") else ""
    return line.rstrip("\r").rstrip("\\") + end


def plain_statements(text: str) -> str:
    """OBJ text with its statements as trimesh's parser finds them: tabs as spaces, no whitespace
    before a keyword, no comment after an element's numbers.

    The specification separates a statement's keyword and arguments by white space, and three.js's
    OBJLoader reads a line so (trimmed, split on any white space); trimesh finds a statement only
    as ``\\n<keyword> `` and dropped the others in silence (an indented ``v`` line lost its vertex,
    so later faces named the wrong ones or failed; a ``f\\t`` line lost its face), and refused a
    file whose ``v`` or ``f`` line ended in a ``# comment``.  A file without them is unchanged.

    >>> plain_statements("  v\\t1 2 3 # a corner\\nf 1 2 3\\n# kept\\n")
    'v 1 2 3\\nf 1 2 3\\n# kept\\n'
    >>> plain_statements("f 1 2\\\\\\n  3\\n")  # continued: one statement
    'f 1 2   3\\n'
    """
    if "\r" in text and "\n" not in text:  # lines ended by CR alone (classic Mac OS)
        text = text.replace("\r", "\n")
    if "\\\n" in text or "\\\r\n" in text:  # a statement continued on the next line, as one line
        text = _CONTINUED.sub(" ", _COMMENT.sub(_uncontinued, text))
    if "\t" in text:
        text = text.replace("\t", " ")
    if text.startswith(" ") or "\n " in text:  # the checks scan at memchr speed; the regexes do not
        text = _INDENT.sub("", text)
    if _mid_line(text, "#"):
        text = _TRAILING_COMMENT.sub(lambda match: match.group(1) + match.group(2).rstrip(" "), text)
    return text


def _mid_line(text: str, char: str) -> bool:
    """Whether ``char`` occurs in ``text`` other than first on a line (a header comment's ``#``
    does not count)."""
    at = text.find(char)
    while at >= 0:
        if at > 0 and text[at - 1] != "\n":
            return True
        at = text.find(char, at + 1)
    return False


# The PBR extension's maps farfield reads (roughness, metallic: scalar; emission: sRGB colour).
PBR_MAPS = ("map_pr", "map_pm", "map_ke")


def pbr_values(mtl: str) -> dict[str, dict[str, object]]:
    """``{material: {"pr": float, "pm": float, "ke": (r, g, b)}}`` of the PBR extension's values
    an MTL file gives (malformed ones left out).

    >>> pbr_values("newmtl steel\\nPr 0.25\\nPm 1\\nKe 0 0.5 1\\nnewmtl plain\\nKd 1 1 1\\n")
    {'steel': {'pr': 0.25, 'pm': 1.0, 'ke': (0.0, 0.5, 1.0)}}
    """
    out: dict[str, dict[str, object]] = {}
    for material, key, _line, split in mtl_statements(mtl):
        if key not in ("pr", "pm", "ke"):
            continue
        current = out.setdefault(material, {})
        try:
            numbers = [float(x) for x in split[1:4]]
        except ValueError:
            continue
        if key == "ke":
            current[key] = tuple(numbers + numbers[-1:] * (3 - len(numbers)))  # "Ke 1" is grey
        else:
            current[key] = numbers[0]
    return {name: values for name, values in out.items() if values}


def texture_maps(mtl: str) -> dict[str, dict[str, str]]:
    """``{material: {"map_kd": file, "map_d": file, "norm": file, ...}}`` for the texture maps an MTL
    file names (``norm``: a tangent-space normal map, the PBR extension of MTL; ``map_bump`` and
    ``bump``: height maps, which farfield does not apply and warns about).

    File names are the rest of the line after the keyword, as trimesh reads them.

    >>> texture_maps("newmtl leaf\\nKd 1 1 1\\nmap_Kd leaf.png\\nmap_d leaf mask.png\\n")
    {'leaf': {'map_kd': 'leaf.png', 'map_d': 'leaf mask.png'}}
    """
    maps: dict[str, dict[str, str]] = {}
    for material, key, line, _split in mtl_statements(mtl):
        if key in ("map_kd", "map_d", "norm", "map_bump", "bump", *PBR_MAPS):
            start = line.lower().index(key) + len(key)
            maps.setdefault(material, {})[key] = line[start:].strip()
    return maps


def mtl_statements(mtl: str):
    """(material, keyword in lower case, line, its words) of each statement with an argument inside
    a ``newmtl`` block of an MTL file, in order.

    >>> list(mtl_statements("Kd 1 1 1\\nnewmtl a b\\nPr 0.5\\n"))
    [('a b', 'pr', 'Pr 0.5', ['Pr', '0.5'])]
    """
    current = None
    for line in mtl.splitlines():
        split = line.strip().split()
        if len(split) <= 1:
            continue
        key = split[0].lower()
        if key == "newmtl":
            current = " ".join(split[1:])
        elif current is not None:
            yield current, key, line, split


# map options that change what a texture shows and that farfield does not apply (warned about)
_UNSUPPORTED = {"t": None, "clamp": ("off",), "mm": ("0", "1"), "cc": ("off",), "boost": None}


def _unsupported(options: dict, allowed: tuple[str, ...]) -> list[str]:
    """The options of a map statement that farfield does not apply (defaults excepted)."""
    out = []
    for key, args in options.items():
        if key in allowed or (key not in _UNSUPPORTED and key not in ("o", "s", "imfchan")):
            continue
        default = _UNSUPPORTED.get(key)
        if default is not None and tuple(a.lower() for a in args) == default[: len(args)]:
            continue
        out.append("-" + " ".join((key, *args)))
    return out


def _opacity(image: PIL.Image.Image, channel: str | None, colour_file: bool) -> PIL.Image.Image:
    """An ``L`` image of opacity from a ``map_d`` image (see the module docstring): the channel
    ``channel`` (``-imfchan``), else luminance, else the alpha where it is evidently the mask
    (``colour_file``: the map is the ``map_Kd`` file)."""
    image = eight_bit(image)
    has_alpha = image.mode in ("RGBA", "LA", "PA") or "transparency" in image.info
    rgba = image.convert("RGBA")
    if channel in ("r", "g", "b"):
        return rgba.getchannel(channel.upper())
    if channel == "m":
        return rgba.getchannel("A")
    luminance = image.convert("L")
    if channel is None and has_alpha:
        alpha = rgba.getchannel("A")
        alpha_varies = alpha.getextrema()[0] != alpha.getextrema()[1]
        colour_constant = all(lo == hi for lo, hi in rgba.convert("RGB").getextrema())
        if alpha_varies and (colour_constant or colour_file):
            return alpha
    return luminance


def _apply_opacity(
    material: SimpleMaterial, data: bytes, channel: str | None, colour_file: bool, max_pixels: int | None = None
) -> PIL.Image.Image:
    """Multiply ``map_d`` (``data``) into the alpha of the material's texture (a flat ``Kd`` one if
    none); returns the opacity image.

    Raises
    ------
    OSError, ValueError, SyntaxError, ...
        See :data:`farfield.core.exchange.trimesh_scene.IMAGE_ERRORS`.
    """
    opacity = PIL.Image.open(io.BytesIO(data))
    check_texels(opacity.size, max_pixels, f"material {material.name!r}'s opacity map")
    if material.image is not None:
        check_texels(material.image.size, max_pixels, f"material {material.name!r}'s texture")
    alpha = _opacity(opacity, channel, colour_file)
    if material.image is not None:
        base = eight_bit(material.image).convert("RGBA")
    else:
        rgb = tuple(int(c) for c in np.asarray(material.diffuse)[:3])
        base = PIL.Image.new("RGBA", alpha.size, rgb + (255,))
    if alpha.size != base.size:
        alpha = alpha.resize(base.size, PIL.Image.Resampling.BILINEAR)
    # the colour texture's own alpha, named again as its opacity map, applies once (not squared)
    own = colour_file and material.image is not None and alpha.tobytes() == base.getchannel("A").tobytes()
    base.putalpha(alpha if own else PIL.ImageChops.multiply(base.getchannel("A"), alpha))
    material.image = base
    return alpha


def _uv_transforms(scene: trimesh.Scene, statements: dict[str, MapStatement], warnings: list[str]) -> None:
    """Apply ``map_Kd``'s ``-o`` (offset) and ``-s`` (scale) to the uv of the meshes of each material:
    uv' = uv × s + o, on u and v (a texture has no w)."""
    for mesh in scene.geometry.values():
        visual = getattr(mesh, "visual", None)
        material = getattr(visual, "material", None)
        statement = statements.get(getattr(material, "name", None))
        if statement is None or getattr(visual, "uv", None) is None:
            continue
        transform = []
        for key, default in (("s", 1.0), ("o", 0.0)):
            args = list(statement.options.get(key, ()))[:2]
            try:
                values = [float(a) for a in args]
            except ValueError:
                warnings.append(
                    f"material {material.name!r}: map_Kd option -{key} {' '.join(args)} is not numeric; ignored"
                )
                values = []
            values += [default if key == "o" or not values else values[0]] * (2 - len(values))
            transform.append(np.array(values[:2]))
        scale, offset = transform
        if np.any(scale != 1.0) or np.any(offset != 0.0):
            visual.uv = np.asarray(visual.uv, dtype=np.float64) * scale + offset


def _textures(
    scene: trimesh.Scene, maps: dict[str, dict[str, str]], resolver: Resolver, max_pixels: int | None = None
) -> list[str]:
    """Apply ``map_d`` maps and ``map_Kd``'s uv options to the parsed materials; warn about maps that
    could not be loaded and options that are not applied.

    Materials naming the same texture file share one image (trimesh opens the file once per
    material), and those naming the same ``map_kd`` and ``map_d`` files (and channel) one composed
    image, so a shared atlas is decoded once however many materials use it
    (:func:`objects_from_trimesh` decodes each image once)."""
    warnings: list[str] = []
    seen: set[int] = set()
    images: dict[str, PIL.Image.Image] = {}  # map_kd file -> the first material's image
    composed: dict[tuple, PIL.Image.Image] = {}  # (map_kd file or Kd, map_d file, channel) -> image with alpha
    colour_maps = {name: map_statement(files["map_kd"]) for name, files in maps.items() if "map_kd" in files}
    for name, statement in colour_maps.items():
        for option in _unsupported(statement.options, ("o", "s")):
            warnings.append(f"material {name!r}: map_Kd option {option} is not supported; ignored")
    _uv_transforms(scene, colour_maps, warnings)
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
        opacity = map_statement(files["map_d"])
        for option in _unsupported({k: v for k, v in opacity.options.items() if k != "imfchan"}, ()) + [
            f"-{k} {' '.join(v)}" for k, v in opacity.options.items() if k in ("o", "s")
        ]:
            warnings.append(f"material {material.name!r}: map_d option {option} is not supported; ignored")
        channel = (opacity.options.get("imfchan") or (None,))[0]
        channel = channel.lower() if channel else None
        if channel not in (None, "r", "g", "b", "m", "l"):
            warnings.append(
                f"material {material.name!r}: map_d channel -imfchan {channel} is not supported; using luminance"
            )
            channel = "l"
        colour_file = "map_kd" in files and opacity.file == colour_maps[material.name].file
        key = (
            files.get("map_kd") if material.image is not None else tuple(np.asarray(material.diffuse).tolist()),
            files["map_d"],
            channel,
        )
        if key in composed:
            material.image = composed[key]
            continue
        data = fetch(resolver, files["map_d"])
        if data is None:
            warnings.append(f"opacity map {files['map_d']!r} of material {material.name!r} not found; ignored")
            continue
        try:
            alpha = _apply_opacity(material, data, channel, colour_file, max_pixels)
            composed[key] = material.image
        except IMAGE_ERRORS as error:
            warnings.append(
                f"opacity map {files['map_d']!r} of material {material.name!r} could not be decoded "
                f"({type(error).__name__}: {error}); ignored"
            )
            continue
        lo, hi = alpha.getextrema()
        if lo == hi == 255:
            warnings.append(
                f"opacity map {files['map_d']!r} of material {material.name!r} is opaque everywhere; nothing is cut"
            )
        elif hi == 0:
            warnings.append(f"opacity map {files['map_d']!r} of material {material.name!r} is transparent everywhere")
    return warnings


def _normal_maps(
    scene: trimesh.Scene,
    maps: dict[str, dict[str, str]],
    normals: dict,
    resolver: Resolver,
    max_pixels: int | None,
    warnings: list[str],
) -> dict[str, tuple[np.ndarray, float]]:
    """Per geometry, its material's ``norm`` map (RGBA, linear, top row first) and scale (``-bm``,
    default 1), decoded once per file, for the geometries with ``vt`` and ``vn``; a warning for a
    map that cannot be used and, once per material, for ``bump`` height maps (not applied)."""
    out: dict[str, tuple[np.ndarray, float]] = {}
    decoded: dict[str, np.ndarray | None] = {}
    told: set[str] = set()
    for key, mesh in scene.geometry.items():
        material = getattr(getattr(mesh, "visual", None), "material", None)
        name = getattr(material, "name", None)
        files = maps.get(name, {}) if isinstance(name, str) else {}
        for bump in ("map_bump", "bump"):
            if bump in files and name not in told:
                told.add(name)
                warnings.append(f"material {name!r}: {bump} is a height map, which farfield does not apply; ignored")
        if "norm" not in files:
            continue
        statement = map_statement(files["norm"])
        uv = getattr(mesh.visual, "uv", None)
        if uv is None or key not in normals:
            warnings.append(
                f"material {name!r}: its normal map {statement.file!r} needs texture coordinates (vt) and normals (vn); ignored"
            )
            continue
        if statement.file not in decoded:
            data = fetch(resolver, statement.file)
            image = None
            if data is None:
                warnings.append(f"normal map {statement.file!r} of material {name!r} not found; ignored")
            else:
                try:
                    image = texture_rgba(PIL.Image.open(io.BytesIO(data)), max_pixels, f"normal map {statement.file!r}")
                except IMAGE_ERRORS as error:
                    warnings.append(
                        f"normal map {statement.file!r} of material {name!r} could not be decoded ({type(error).__name__}: {error}); ignored"
                    )
            decoded[statement.file] = image
        if decoded[statement.file] is None:
            continue
        scale = 1.0
        if "bm" in statement.options:
            try:
                scale = float(statement.options["bm"][0])
            except ValueError:
                warnings.append(
                    f"material {name!r}: norm option -bm {statement.options['bm'][0]!r} is not a number; 1 used"
                )
        out[key] = (decoded[statement.file], scale)
    return out


def _scalar_map(image: PIL.Image.Image, channel: str | None) -> np.ndarray:
    """(h, w) uint8 of a scalar MTL map: the channel ``-imfchan`` names (r, g, b, m), else luminance."""
    rgba = eight_bit(image).convert("RGBA")
    if channel in ("r", "g", "b", "m"):
        return np.asarray(rgba)[..., "rgbm".index(channel)].copy()
    return np.asarray(rgba.convert("L")).copy()


def _materials(
    scene: trimesh.Scene,
    maps: dict[str, dict[str, str]],
    values: dict[str, dict[str, object]],
    resolver: Resolver,
    max_pixels: int | None,
    warnings: list[str],
) -> dict[str, dict]:
    """Per geometry, the :class:`SceneObject` material fields of its material's PBR values and maps
    (module docstring; without ``material_uv``, which the object's uv gives), images decoded once."""
    out: dict[str, dict] = {}
    decoded: dict[tuple, object] = {}
    made: dict[str, dict] = {}

    def image(name: str, key: str):
        statement = map_statement(maps[name][key])
        cache = (statement.file, key)
        if cache not in decoded:
            data = fetch(resolver, statement.file)
            found = None
            if data is None:
                warnings.append(f"{key} {statement.file!r} of material {name!r} not found; ignored")
            else:
                try:
                    opened = PIL.Image.open(io.BytesIO(data))
                    # its size, from the header; a scalar map is counted here, an emissive one as it is kept
                    check_texels(opened.size, max_pixels, f"{key} {statement.file!r}", count=key != "map_ke")
                    channel = statement.options.get("imfchan", ("l",))[0].lower()
                    found = _scalar_map(opened, channel) if key != "map_ke" else texture_rgba(opened, max_pixels, key)
                except IMAGE_ERRORS as error:
                    warnings.append(
                        f"{key} {statement.file!r} of material {name!r} could not be decoded "
                        f"({type(error).__name__}: {error}); ignored"
                    )
            decoded[cache] = found
        return decoded[cache]

    for key, mesh in scene.geometry.items():
        material = getattr(getattr(mesh, "visual", None), "material", None)
        name = getattr(material, "name", None)
        if not isinstance(name, str) or (name not in values and not any(k in maps.get(name, {}) for k in PBR_MAPS)):
            continue
        if name not in made:
            given, files = values.get(name, {}), maps.get(name, {})
            fields: dict = {}
            scalars = {k: image(name, k) for k in ("map_pr", "map_pm") if k in files}
            scalars = {k: v for k, v in scalars.items() if v is not None}
            if len(scalars) == 2 and scalars["map_pr"].shape != scalars["map_pm"].shape:
                warnings.append(f"material {name!r}: map_Pm's size differs from map_Pr's; map_Pm ignored")
                del scalars["map_pm"]
            fields["roughness_factor"] = float(np.clip(given.get("pr", 1.0), 0.0, 1.0))
            fields["metallic_factor"] = float(np.clip(given.get("pm", 1.0 if "map_pm" in scalars else 0.0), 0.0, 1.0))
            if scalars:
                shape = next(iter(scalars.values())).shape
                packed = np.full(shape + (4,), 255, dtype=np.uint8)
                packed[..., 1] = scalars.get("map_pr", 255)
                packed[..., 2] = scalars.get("map_pm", 255)
                packed.flags.writeable = False
                fields["metallic_roughness_texture"] = packed
            glow = image(name, "map_ke") if "map_ke" in files else None
            ke = given.get("ke", (1.0, 1.0, 1.0) if glow is not None else (0.0, 0.0, 0.0))
            fields["emissive_factor"] = np.maximum(np.asarray(ke, dtype=np.float64), 0.0)
            if glow is not None and fields["emissive_factor"].any():
                fields["emissive_texture"] = glow
            made[name] = fields
        out[key] = made[name]
    return out


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


# A 0 (or -0) among a face's (or line's) indices: OBJ counts from 1 (negative indices count back from the face),
# so 0 names no vertex; trimesh would read it as the last one, a silent wrong triangle.
_ZERO_INDEX = re.compile(r"^[ \t]*[fl][ \t][^\n]*?(?<![\w.+-])-?0(?=[/ \t\r]|$)", re.MULTILINE)


def material_libraries(text: str) -> list[str]:
    """The material library files an OBJ text names, in order, each once: those of every ``mtllib``
    statement, which may name several (``mtllib a.mtl b.mtl``, the specification's "mtllib filename1
    filename2 ..."; three.js's OBJLoader takes the rest of the line as one name).  Its words are
    several files where each ends in ``.mtl``, else the rest of the line is one name with spaces.

    >>> material_libraries("mtllib a.mtl B.MTL\\nmtllib my materials.mtl\\nmtllib a.mtl\\n")
    ['a.mtl', 'B.MTL', 'my materials.mtl']
    """
    out: list[str] = []
    for rest in _MTLLIB.findall(text):
        words = rest.split()
        names = words if len(words) > 1 and all(w.lower().endswith(".mtl") for w in words) else [rest]
        out += [name for name in names if name not in out]
    return out


# The name under which trimesh is given the material libraries of a file that names several.
_LIBRARIES = "farfield-material-libraries.mtl"
_USEMTL = re.compile(r"^usemtl[ \t]+(.*\S)", re.MULTILINE)


class _Libraries(Resolver):
    """A resolver that gives ``mtl`` (every library of a file, one after the other) for
    :data:`_LIBRARIES` and asks ``inner`` for any other file."""

    def __init__(self, inner: Resolver, mtl: bytes) -> None:
        self.inner, self.mtl = inner, mtl
        self.parent = getattr(inner, "parent", "")

    def get(self, name: str) -> bytes:
        return self.mtl if name == _LIBRARIES else self.inner.get(name)

    def keys(self):
        return self.inner.keys()

    def namespaced(self, namespace: str) -> Resolver:
        return self.inner.namespaced(namespace)

    def write(self, name: str, data) -> None:
        raise OSError("a scene's files are read, not written")


def _undefined_materials(text: str, mtl: str) -> list[str]:
    """A warning per ``usemtl`` name no ``newmtl`` of the material libraries defines (its faces get
    the default colour, as in a viewer)."""
    defined = {" ".join(words[1:]) for words in map(str.split, mtl.splitlines()) if words[:1] == ["newmtl"]}
    missing = sorted({name for name in _USEMTL.findall(text) if name not in defined})
    return [
        f"material {name!r} (usemtl) is defined in no material library; its faces use the default colour"
        for name in missing
    ]


def _check_indices(text: str) -> None:
    """Raise SceneLoadError naming the first face with a 0 index (module docstring of the rule)."""
    found = _ZERO_INDEX.search(text)
    if found is not None:
        line = text.count("\n", 0, found.start()) + 1
        end = text.find("\n", found.start())
        statement = text[found.start() : end if end >= 0 else len(text)].strip()
        raise SceneLoadError(
            f"line {line}: {statement[:60]!r} has the index 0; OBJ indices start at 1 "
            "(negative ones count back from the last vertex before the face)"
        )


def load(
    data: bytes,
    extension: str,
    name: str,
    resolver: Resolver,
    limits: SceneLimits = DEFAULT_LIMITS,
    sides: str = DEFAULT_SIDES,
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

    sides : str
        ``"one"`` (the default: one-sided objects, as engines draw the format) or ``"both"``.

    Raises
    ------
    SceneLoadError
        Binary data, or trimesh could not parse it (e.g. a face index beyond the vertices).
    """
    text = plain_statements(decode_text(data))
    _check_indices(text)  # before the relative indices' rewrite, which would read -0 as one past the face's last
    text = absolute_indices(text)
    text = complete_normals(text)
    warnings: list[str] = []
    maps: dict[str, dict[str, str]] = {}
    values: dict[str, dict[str, object]] = {}
    libraries = material_libraries(text)
    found: list[str] = []
    for library in libraries:
        mtl = fetch(resolver, library)
        if mtl is None:
            warnings.append(f"material library {library!r} not found; objects use the default colour")
        elif b"\x00" in mtl:
            warnings.append(f"material library {library!r} is binary, not MTL text; texture maps not checked")
        else:
            found.append(decode_text(mtl))
    if found:
        mtl_text = "\n".join(found)
        maps, values = texture_maps(mtl_text), pbr_values(mtl_text)
        warnings.extend(_undefined_materials(text, mtl_text))
    parsed = text  # the file's lines, as its messages name them
    if len(libraries) > 1:  # trimesh reads one library: it is given them all as one
        parsed = f"mtllib {_LIBRARIES}\n" + _MTLLIB.sub("", text)
        resolver = _Libraries(resolver, "\n".join(found).encode("utf-8"))
    try:
        scene = parse(
            paired_indices(split_concave(parsed, warnings)).encode("utf-8"),  # linear without vt/vn (obj_no_uv.py)
            extension,
            resolver,
            split_objects=True,
            group_material=True,
        )
    except SceneLoadError as error:
        raise (beyond_the_end(text) or error) from error
    budget = limits.texel_budget()  # every texture of this load counts against one total
    warnings.extend(_textures(scene, maps, resolver, budget))
    normals = {key: found for key, mesh in scene.geometry.items() if (found := file_normals(mesh)) is not None}
    normal_maps = _normal_maps(scene, maps, normals, resolver, budget, warnings)
    materials = _materials(scene, maps, values, resolver, budget, warnings)
    objects, more = objects_from_trimesh(
        scene,
        rename=_short_names(scene),
        double_sided=double_sided(sides),
        max_texture_pixels=budget,
        normals=normals,
        normal_maps=normal_maps,
        materials=materials,
    )
    return objects, tuple(warnings) + more

"""glTF 2.0 materials -> farfield's colour sources: base colour, texture with its uv, alpha mode, sidedness.

What glTF says (Khronos, glTF 2.0, §3.9 "Materials", §3.8 "Textures", §5.26 "sampler") and what
farfield does with it:

* base colour = ``baseColorFactor`` x ``baseColorTexture`` (sRGB) x ``COLOR_0``, in linear light,
  as :mod:`farfield.core.scene` defines it; ``KHR_materials_pbrSpecularGlossiness``'s
  ``diffuseFactor``/``diffuseTexture`` where a material has no metallic-roughness block.
* ``texCoord`` picks the uv set; ``KHR_texture_transform`` (offset, rotation, scale, its own
  ``texCoord``) is applied to the uv on load, which is exact (the transform is affine and uv are
  interpolated linearly).
* sampler wrap modes: a farfield texture repeats, so the other modes are expressed in repeat's
  terms on load, exactly at full resolution: ``MIRRORED_REPEAT`` appends the image's mirror
  image along that axis and halves the coordinate; ``CLAMP_TO_EDGE`` pads the image with copies of
  its edge texels over the range the object's uv reach (a power of two texels, at least one, so
  that the objects of one image share a few copies and bilinear
  filtering at the edge does not wrap) and maps the coordinate into it.  Where padding would make
  the image both more than :data:`MAX_CLAMP_GROWTH` times larger and larger than
  :data:`MAX_CLAMP_TEXELS` the uv are clamped instead (exact but for triangles that straddle the
  edge), with a warning.
* ``alphaMode``: ``OPAQUE`` ignores alpha, ``MASK`` cuts at ``alphaCutoff`` (0.5), ``BLEND`` is
  drawn as a mask at 0.5 with a warning (an impostor is opaque or cut).
* ``doubleSided`` (default false) becomes :attr:`SceneObject.double_sided`.
* Filters: farfield filters bilinearly (trilinear where it builds mipmaps) whatever the sampler
  says; a ``NEAREST`` magnification filter is warned about.
* The metallic-roughness material (§3.9.2, §3.9.4, §3.9.5): ``metallicFactor`` and
  ``roughnessFactor`` (default 1 and 1, the default material's too), ``metallicRoughnessTexture``
  (linear, B metallic, G roughness), ``occlusionTexture`` (linear, R) with its ``strength``
  (default 1), ``emissiveTexture`` (sRGB) and ``emissiveFactor`` (default 0), multiplied by
  ``KHR_materials_emissive_strength``'s ``emissiveStrength``.  These only shade: a texture that
  cannot be read is left out with a warning (its factor kept), a factor out of range is clamped
  with a warning.  ``KHR_materials_pbrSpecularGlossiness`` materials keep the matte default
  (metallic 0, roughness 1, farfield's reading of a diffuse colour).
* ``KHR_materials_transmission`` (glass: a window, a display case) is not drawn: such a material
  is opaque, as an impostor's texels are, and a warning names it (the interior behind the pane
  is hidden; three.js draws the pane see-through).
"""

from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np
import PIL.Image

from farfield.core.errors import SceneLoadError, SceneTooCostlyError
from farfield.core.exchange.gltf.document import Buffers, item
from farfield.core.exchange.trimesh_scene import DEFAULT_ALPHA_CUTOFF, IMAGE_ERRORS, DecodedTexture, texture_rgba

REPEAT, CLAMP_TO_EDGE, MIRRORED_REPEAT = 10497, 33071, 33648
NEAREST = 9728
WRAP_NAMES = {REPEAT: "REPEAT", CLAMP_TO_EDGE: "CLAMP_TO_EDGE", MIRRORED_REPEAT: "MIRRORED_REPEAT"}

# The most a CLAMP_TO_EDGE image may grow by padding before its uv are clamped instead: both more
# than this factor and more than MAX_CLAMP_TEXELS (a small image is always padded exactly).
MAX_CLAMP_GROWTH = 4.0
MAX_CLAMP_TEXELS = 1 << 22
# How far a colour factor may stray outside 0..1 (exporters' float rounding) before it is refused.
FACTOR_SLACK = 1e-3

# Image sources of texture extensions that PIL decodes (EXT_texture_webp); KTX2 (KHR_texture_basisu)
# and DDS are not decodable here, so their textures fall back to ``source``.
_DECODABLE_SOURCES = ("EXT_texture_webp",)


def _number(value: object, default: float, where: str) -> float:
    if value is None:
        return default
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise SceneLoadError(f"{where} is {value!r}, not a number")
    return float(value)


def _factor(value: object, default: tuple, where: str) -> np.ndarray:
    if value is None:
        return np.array(default, dtype=np.float64)
    if not isinstance(value, list) or len(value) != len(default):
        raise SceneLoadError(f"{where} is {value!r}, not {len(default)} numbers")
    out = np.array([_number(v, 0.0, where) for v in value], dtype=np.float64)
    if out.min() < -FACTOR_SLACK or out.max() > 1.0 + FACTOR_SLACK:
        raise SceneLoadError(f"{where} {value!r} is not in 0..1")
    return np.clip(out, 0.0, 1.0)  # exporters' rounding (1.0000001) is not worth refusing a file


@dataclass(frozen=True)
class TextureRef:
    """A material's base-colour texture: which image, uv set, sampler and transform."""

    texture: int  # index into the document's textures
    image: int | None  # index into images, None when no decodable source
    tex_coord: int  # TEXCOORD_n
    wrap: tuple[int, int]  # (wrapS, wrapT)
    nearest: bool  # magFilter NEAREST
    transform: np.ndarray | None  # (3, 3) float64 in glTF's uv space, or None


@dataclass(frozen=True)
class Material:
    """The colour-relevant part of a glTF material."""

    name: str
    base_color: np.ndarray  # (4,) linear
    texture: TextureRef | None
    alpha_cutoff: float | None
    double_sided: bool
    blend: bool  # alphaMode BLEND, drawn as a mask
    normal: TextureRef | None = None  # normalTexture (§3.9.3): tangent space, linear
    normal_scale: float = 1.0
    metallic: float = 1.0  # metallicFactor (the specification's default)
    roughness: float = 1.0  # roughnessFactor
    metallic_roughness: TextureRef | None = None  # metallicRoughnessTexture: B metallic, G roughness, linear
    occlusion: TextureRef | None = None  # occlusionTexture: R, linear
    occlusion_strength: float = 1.0
    emissive: TextureRef | None = None  # emissiveTexture: sRGB
    emissive_factor: np.ndarray = (0.0, 0.0, 0.0)  # emissiveFactor x emissiveStrength, linear

    def material_textures(self) -> tuple[tuple[str, TextureRef], ...]:
        """(field, ref) of the material textures it has, in the order the first one sets the
        material uv: metallic-roughness, occlusion, emissive."""
        found = (
            ("metallic_roughness_texture", self.metallic_roughness),
            ("occlusion_texture", self.occlusion),
            ("emissive_texture", self.emissive),
        )
        return tuple((key, ref) for key, ref in found if ref is not None and ref.image is not None)


DEFAULT_MATERIAL = Material("default", np.ones(4), None, None, False, False)


def _transform(extension: object, where: str) -> tuple[np.ndarray, int | None]:
    """(3, 3) matrix and texCoord override of a ``KHR_texture_transform`` object
    (``translation * rotation * scale``)."""
    if not isinstance(extension, dict):
        raise SceneLoadError(f"{where}: KHR_texture_transform is not an object")
    offset = extension.get("offset", [0.0, 0.0])
    scale = extension.get("scale", [1.0, 1.0])
    if not (isinstance(offset, list) and len(offset) == 2 and isinstance(scale, list) and len(scale) == 2):
        raise SceneLoadError(f"{where}: KHR_texture_transform offset/scale are not two numbers")
    ox, oy = (_number(v, 0.0, f"{where} offset") for v in offset)
    sx, sy = (_number(v, 1.0, f"{where} scale") for v in scale)
    angle = _number(extension.get("rotation"), 0.0, f"{where} rotation")
    c, s = math.cos(angle), math.sin(angle)
    translation = np.array([[1.0, 0.0, ox], [0.0, 1.0, oy], [0.0, 0.0, 1.0]])
    # Counter-clockwise in glTF's uv space, whose v points down: u' = c u + s v, v' = -s u + c v.
    # The GLSL listing of the extension's README has the transpose; the Khronos sample model
    # TextureTransformTest, three.js, Babylon.js and Blender use this one (KhronosGroup/glTF
    # issue 1563, pull request 1624), and so does the three.js check of tests/test_threejs.py.
    rotation = np.array([[c, s, 0.0], [-s, c, 0.0], [0.0, 0.0, 1.0]])
    scaling = np.diag([sx, sy, 1.0])
    tex_coord = extension.get("texCoord")
    if tex_coord is not None and (isinstance(tex_coord, bool) or not isinstance(tex_coord, int) or tex_coord < 0):
        raise SceneLoadError(f"{where}: KHR_texture_transform texCoord {tex_coord!r} is not an index")
    return translation @ rotation @ scaling, tex_coord


def _texture_ref(document: dict, info: object, where: str, warnings: list[str]) -> TextureRef | None:
    if info is None:
        return None
    if not isinstance(info, dict):
        raise SceneLoadError(f"{where} is not a textureInfo object")
    index = info.get("index")
    texture = item(document, "textures", index)
    image = texture.get("source")
    extensions = texture.get("extensions") if isinstance(texture.get("extensions"), dict) else {}
    for name in _DECODABLE_SOURCES:
        found = extensions.get(name)
        if isinstance(found, dict) and isinstance(found.get("source"), int):
            image = found["source"]
            break
    if image is not None:
        item(document, "images", image)  # checked
    else:
        kinds = ", ".join(sorted(extensions)) or "none"
        warnings.append(f"{where}: texture {index} has no image farfield can decode (sources: {kinds})")
    wrap, nearest = (REPEAT, REPEAT), False
    if "sampler" in texture:
        sampler = item(document, "samplers", texture["sampler"])
        wrap = (sampler.get("wrapS", REPEAT), sampler.get("wrapT", REPEAT))
        if any(isinstance(w, bool) or not isinstance(w, int) or w not in WRAP_NAMES for w in wrap):
            raise SceneLoadError(
                f"glTF sampler {texture['sampler']}: wrap mode {wrap!r} is not one of {sorted(WRAP_NAMES)}"
            )
        nearest = sampler.get("magFilter") == NEAREST
    tex_coord = info.get("texCoord", 0)
    if isinstance(tex_coord, bool) or not isinstance(tex_coord, int) or tex_coord < 0:
        raise SceneLoadError(f"{where}: texCoord {tex_coord!r} is not an index")
    matrix = None
    info_extensions = info.get("extensions")
    if isinstance(info_extensions, dict) and "KHR_texture_transform" in info_extensions:
        matrix, override = _transform(info_extensions["KHR_texture_transform"], where)
        if override is not None:
            tex_coord = override
    return TextureRef(int(index), image, int(tex_coord), wrap, nearest, matrix)


def material(document: dict, index: object, warnings: list[str]) -> Material:
    """Material ``index`` of ``document`` (the default material, glTF §3.9.6, when None).

    Raises
    ------
    SceneLoadError
        Malformed values (factors out of range, bad indices).
    """
    if index is None:
        return DEFAULT_MATERIAL
    spec = item(document, "materials", index)
    where = f"glTF material {index}"
    name = spec.get("name") if isinstance(spec.get("name"), str) else f"material{index}"
    pbr = spec.get("pbrMetallicRoughness")
    extensions = spec.get("extensions") if isinstance(spec.get("extensions"), dict) else {}
    gloss = extensions.get("KHR_materials_pbrSpecularGlossiness")
    if isinstance(gloss, dict):  # a client that reads it draws it, even beside a metallic-roughness block
        factor = _factor(gloss.get("diffuseFactor"), (1.0, 1.0, 1.0, 1.0), f"{where} diffuseFactor")
        texture = _texture_ref(document, gloss.get("diffuseTexture"), f"{where} diffuseTexture", warnings)
    else:
        pbr = pbr if isinstance(pbr, dict) else {}
        factor = _factor(pbr.get("baseColorFactor"), (1.0, 1.0, 1.0, 1.0), f"{where} baseColorFactor")
        texture = _texture_ref(document, pbr.get("baseColorTexture"), f"{where} baseColorTexture", warnings)
    mode = spec.get("alphaMode", "OPAQUE")
    if mode not in ("OPAQUE", "MASK", "BLEND"):
        raise SceneLoadError(f"{where}: alphaMode {mode!r} is not OPAQUE, MASK or BLEND")
    cutoff = None
    if mode == "MASK":
        cutoff = _number(spec.get("alphaCutoff"), DEFAULT_ALPHA_CUTOFF, f"{where} alphaCutoff")
        if not 0.0 <= cutoff <= 1.0:
            raise SceneLoadError(f"{where}: alphaCutoff {cutoff} is not in 0..1")
    elif mode == "BLEND":
        cutoff = DEFAULT_ALPHA_CUTOFF
    double = spec.get("doubleSided", False)
    if not isinstance(double, bool):
        raise SceneLoadError(f"{where}: doubleSided {double!r} is not true or false")
    normal_info = spec.get("normalTexture")
    try:  # a normal map only shades: one that cannot be read is left out, with a warning
        normal = _texture_ref(document, normal_info, f"{where} normalTexture", warnings)
    except SceneLoadError as error:
        warnings.append(f"{error}; the normal texture is ignored")
        normal = None
    scale = _number(
        normal_info.get("scale") if isinstance(normal_info, dict) else None, 1.0, f"{where} normalTexture scale"
    )
    # Specular-glossiness and unlit materials (KHR_materials_unlit: the author wants the base colour
    # as it is, and a glTF that leaves metallicFactor out would otherwise be metal) are matte.
    matte = isinstance(gloss, dict) or "KHR_materials_unlit" in extensions
    shading = _shading(document, spec, None if matte else pbr, extensions, where, warnings)
    transmission = extensions.get("KHR_materials_transmission")
    if isinstance(transmission, dict) and _see_through(transmission.get("transmissionFactor")):
        warnings.append(
            f"{where} ({name!r}) lets light through (KHR_materials_transmission, glass): it is drawn "
            "opaque, as an impostor has no transparency, and hides what lies behind it"
        )
    return Material(name, factor, texture, cutoff, double, mode == "BLEND", normal, scale, **shading)


def _see_through(factor: object) -> bool:
    """Whether a ``transmissionFactor`` (default 0) lets light through."""
    return isinstance(factor, int | float) and not isinstance(factor, bool) and factor > 0.0


def _unit(value: object, default: float, where: str, warnings: list[str]) -> float:
    """A shading factor in 0..1 (default ``default``): one out of range is clamped with a warning,
    one that is not a number is replaced by the default with a warning (it only shades)."""
    try:
        number = _number(value, default, where)
    except SceneLoadError as error:
        warnings.append(f"{error}; {default:g} is used")
        return default
    if not 0.0 <= number <= 1.0:
        warnings.append(f"{where} {number:g} is not in 0..1; clamped")
    return min(max(number, 0.0), 1.0)


def _shading_texture(document: dict, info: object, where: str, warnings: list[str]) -> TextureRef | None:
    """A material texture's reference, or None with a warning where it cannot be read."""
    try:
        return _texture_ref(document, info, where, warnings)
    except SceneLoadError as error:
        warnings.append(f"{error}; the texture is ignored")
        return None


def _shading(document: dict, spec: dict, pbr: dict | None, extensions: dict, where: str, warnings: list[str]) -> dict:
    """The metallic-roughness fields of :class:`Material` (module docstring); ``pbr`` None for a
    specular-glossiness or unlit material (matte)."""
    out: dict = {}
    if pbr is None:
        out["metallic"], out["roughness"] = 0.0, 1.0
    else:
        out["metallic"] = _unit(pbr.get("metallicFactor"), 1.0, f"{where} metallicFactor", warnings)
        out["roughness"] = _unit(pbr.get("roughnessFactor"), 1.0, f"{where} roughnessFactor", warnings)
        out["metallic_roughness"] = _shading_texture(
            document, pbr.get("metallicRoughnessTexture"), f"{where} metallicRoughnessTexture", warnings
        )
    occlusion = spec.get("occlusionTexture")
    out["occlusion"] = _shading_texture(document, occlusion, f"{where} occlusionTexture", warnings)
    if isinstance(occlusion, dict):
        out["occlusion_strength"] = _unit(
            occlusion.get("strength"), 1.0, f"{where} occlusionTexture strength", warnings
        )
    out["emissive"] = _shading_texture(document, spec.get("emissiveTexture"), f"{where} emissiveTexture", warnings)
    emissive = spec.get("emissiveFactor")
    factor = np.zeros(3)
    if emissive is not None:
        if isinstance(emissive, list) and len(emissive) == 3:
            factor = np.array([_unit(v, 0.0, f"{where} emissiveFactor", warnings) for v in emissive])
        else:
            warnings.append(f"{where} emissiveFactor is {emissive!r}, not 3 numbers; no emission")
    strength = extensions.get("KHR_materials_emissive_strength")
    if isinstance(strength, dict):
        try:
            value = _number(strength.get("emissiveStrength"), 1.0, f"{where} emissiveStrength")
        except SceneLoadError as error:
            warnings.append(f"{error}; 1 is used")
            value = 1.0
        if value < 0.0:
            warnings.append(f"{where} emissiveStrength {value:g} is negative; 0 is used")
            value = 0.0
        factor = factor * value
    out["emissive_factor"] = factor
    return out


def _pad(texels: float) -> int:
    """Texels of padding for ``texels`` beyond an edge: the next power of two, at least 1 (one texel
    keeps bilinear filtering at the edge from wrapping)."""
    if texels <= 1.0:
        return 1
    return 1 << min(62, math.ceil(math.log2(texels)))


class Images:
    """Decoded images of a document, each decoded once, and their wrapped variants.

    Parameters
    ----------
    buffers : Buffers
        Where the images' bytes are.
    """

    def __init__(self, buffers: Buffers, max_pixels: int | None = None) -> None:
        self.buffers = buffers
        self.max_pixels = max_pixels
        self._decoded: dict[int, DecodedTexture | None] = {}
        self._wrapped: dict[tuple, DecodedTexture] = {}

    def decoded(self, index: int, warnings: list[str]) -> DecodedTexture | None:
        """Image ``index`` decoded (None, with a warning, where missing or undecodable)."""
        if index not in self._decoded:
            data = self.buffers.image(index)
            texture = None
            if data is None:
                uri = self.buffers.document["images"][index].get("uri", "")
                warnings.append(f"texture {uri!r} not found; objects using it fall back to their material colour")
            else:
                texture = self._decode(index, data, warnings)
            self._decoded[index] = texture
        return self._decoded[index]

    def _decode(self, index: int, data: bytes, warnings: list[str]) -> DecodedTexture | None:
        """Image ``index`` from its bytes; its size is checked from its header before it is decoded."""
        try:
            image = PIL.Image.open(io.BytesIO(data))
            return DecodedTexture.of(texture_rgba(image, self.max_pixels, f"glTF image {index}"))
        except PIL.Image.DecompressionBombError as error:  # PIL's own bound, past ours
            raise SceneTooCostlyError(f"glTF image {index}: {error}") from error
        except IMAGE_ERRORS as error:
            warnings.append(
                f"glTF image {index} could not be decoded ({type(error).__name__}: {error}); "
                "objects using it fall back to their material colour"
            )
            return None

    def wrapped(
        self, ref: TextureRef, uv: np.ndarray, name: str, warnings: list[str]
    ) -> tuple[DecodedTexture, np.ndarray] | None:
        """(texture, uv) for an object: ``uv`` (glTF space, (v, 2), already transformed) with the
        sampler's wrap modes expressed as repeat (module docstring); uv still in glTF space."""
        base = self.decoded(ref.image, warnings) if ref.image is not None else None
        if base is None:
            return None
        rgba, uv = base.rgba, np.array(uv, dtype=np.float64)
        key: list = [ref.image]
        plan = []
        for axis, mode in enumerate(ref.wrap):  # axis 0: u (columns), 1: v (rows, glTF's v grows down)
            size = rgba.shape[1 - axis]
            if mode == MIRRORED_REPEAT:
                plan.append(("mirror", axis, 0, 0))
            elif mode == CLAMP_TO_EDGE:
                reach = uv[:, axis]
                if not np.isfinite(reach).all():
                    raise SceneLoadError(f"object {name!r}: non-finite texture coordinates")
                # Padding in whole powers of two texels, so the objects of one image share a few copies.
                low = _pad(max(0.0, -float(reach.min())) * size)
                high = _pad(max(0.0, float(reach.max()) - 1.0) * size)
                across = rgba.shape[axis]  # texels along the other axis
                grown = (size + low + high) * across
                if grown > MAX_CLAMP_GROWTH * size * across and grown > MAX_CLAMP_TEXELS:
                    warnings.append(
                        f"object {name!r}: its uv reach far beyond a CLAMP_TO_EDGE texture "
                        f"({float(reach.min()):.3g}..{float(reach.max()):.3g}); uv are clamped to 0..1 instead"
                    )
                    uv[:, axis] = np.clip(reach, 0.0, 1.0)
                    low = high = 1
                plan.append(("clamp", axis, low, high))
        key += plan
        for _kind, axis, low, high in plan:
            size = rgba.shape[1 - axis]
            if _kind == "mirror":
                uv[:, axis] = uv[:, axis] / 2.0
            else:
                uv[:, axis] = (uv[:, axis] * size + low) / (size + low + high)
        key = tuple(key)
        if key not in self._wrapped:
            for _kind, axis, low, high in plan:
                along = 1 - axis  # array axis: 1 for u (columns), 0 for v (rows)
                if _kind == "mirror":
                    rgba = np.concatenate([rgba, np.flip(rgba, axis=along)], axis=along)
                else:
                    pad = [(0, 0), (0, 0), (0, 0)]
                    pad[along] = (low, high)
                    rgba = np.pad(rgba, pad, mode="edge")
            self._wrapped[key] = base if not plan else DecodedTexture.of(rgba)
        return self._wrapped[key], uv

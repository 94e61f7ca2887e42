"""Scenes written as GLB: :func:`to_trimesh` (one node per object, glTF materials) and :func:`scene_glb`.

What ``farfield scenes demo`` writes and what tests upload: every object keeps its name, geometry,
UVs, vertex colours, shading normals (where it has them), base colour, texture, alpha cutoff,
sidedness and metallic-roughness material, so a GLB written here loads back as the same scene
(vertex colours within their 8-bit quantisation, normals within float32).  The material's
textures are written where they map through the object's uv (a glTF primitive written here has
one uv set), else left out (their factors kept); an occlusion strength below 1 is baked into the
occlusion image, and an emissive factor above 1 is scaled to 1 (no
``KHR_materials_emissive_strength`` is written).
"""

from __future__ import annotations

import numpy as np
import PIL.Image
import trimesh
from trimesh.visual.material import PBRMaterial

from farfield.core.colour_space import srgb_to_linear
from farfield.core.scene import Scene


def texture_image(texture: np.ndarray) -> PIL.Image.Image:
    """PIL RGBA image of a (h, w, 4) uint8 texture, top row first."""
    return PIL.Image.fromarray(np.ascontiguousarray(texture), "RGBA")


def to_trimesh(scene: Scene) -> trimesh.Scene:
    """A trimesh.Scene with one node per object, named after it, identity transforms; each mesh's
    ``extras`` hold ``{"farfield_object": name}`` (viewers rename nodes: three.js drops dots,
    colons and slashes, so a runtime matches a database's object names through the extras).

    Every object gets a glTF material with its ``baseColorFactor``, ``metallicFactor`` 0 and
    ``roughnessFactor`` 1 (a rough dielectric, as the lit evaluation shades it) and ``doubleSided`` as the object
    is (:attr:`farfield.core.scene.SceneObject.double_sided`), a ``baseColorTexture`` where it is
    textured (and ``alphaMode: MASK`` when ``alpha_cutoff`` is set), and vertex colours as
    ``COLOR_0`` where it has them.
    Colours go in glTF's spaces: the factor linear as it is, vertex colours decoded from sRGB to
    linear bytes (so they come back within the 8-bit quantisation, not bit for bit).
    """
    out = trimesh.Scene()
    for obj in scene.objects:
        # Every object gets a material, vertex-coloured ones too: without one a glTF primitive takes
        # the default material, which is one-sided (doubleSided false) and white.
        material = PBRMaterial(
            name=f"{obj.name}_material",
            baseColorFactor=np.array(obj.base_color),  # trimesh writes into its inputs
            # the object's own factors: a matte object (metallic 0, roughness 1) is written so, as
            # glTF's defaults (metallic 1 and roughness 1) would make it metal
            metallicFactor=float(obj.metallic_factor),
            roughnessFactor=float(obj.roughness_factor),
            **_material_extras(obj),
            baseColorTexture=None if obj.texture is None else texture_image(obj.texture),
            alphaMode=None if obj.alpha_cutoff is None else "MASK",
            alphaCutoff=obj.alpha_cutoff,
            doubleSided=obj.double_sided,
        )
        uv = obj.uv if obj.uv is not None else (obj.material_uv if _maps_through_uv(obj) else None)
        visual = trimesh.visual.TextureVisuals(uv=None if uv is None else np.array(uv), material=material)
        if obj.vertex_colors is not None:
            linear = np.array(obj.vertex_colors)
            linear[:, :3] = np.round(srgb_to_linear(linear[:, :3] / 255.0) * 255.0)
            visual.vertex_attributes["color"] = linear  # written as COLOR_0
        mesh = trimesh.Trimesh(
            np.array(obj.vertices),
            np.array(obj.faces),
            visual=visual,
            vertex_normals=None if obj.normals is None else np.array(obj.normals),  # written as NORMAL
            process=False,
        )
        mesh.metadata["farfield_object"] = obj.name
        out.add_geometry(mesh, geom_name=obj.name, node_name=obj.name)
    return out


def _maps_through_uv(obj) -> bool:
    """Whether ``obj``'s material textures can be written over the primitive's one uv set."""
    if obj.material_uv is None:
        return False
    return obj.uv is None or obj.material_uv is obj.uv or np.array_equal(obj.material_uv, obj.uv)


def _material_extras(obj) -> dict:
    """The PBRMaterial arguments of ``obj``'s emission and material textures (none for a matte
    object, whose material is written as before)."""
    out: dict = {}
    if obj.emissive_factor.any():
        factor = np.array(obj.emissive_factor, dtype=np.float64)
        out["emissiveFactor"] = factor / max(1.0, float(factor.max()))
    if not _maps_through_uv(obj):
        return out
    if obj.metallic_roughness_texture is not None:
        out["metallicRoughnessTexture"] = texture_image(obj.metallic_roughness_texture)
    if obj.occlusion_texture is not None:
        occlusion = obj.occlusion_texture
        if obj.occlusion_strength != 1.0:  # glTF's 1 + strength (R - 1), baked into R
            occlusion = occlusion.copy()
            red = occlusion[..., 0].astype(np.float64) / 255.0
            occlusion[..., 0] = np.round(255.0 * (1.0 + obj.occlusion_strength * (red - 1.0)))
        out["occlusionTexture"] = texture_image(occlusion)
    if obj.emissive_texture is not None and "emissiveFactor" in out:
        out["emissiveTexture"] = texture_image(obj.emissive_texture)
    return out


def scene_glb(scene: Scene) -> bytes:
    """``scene`` as the bytes of a GLB file."""
    data = to_trimesh(scene).export(file_type="glb")
    return data if isinstance(data, bytes) else data.encode()

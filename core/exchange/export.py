"""Scenes written as GLB: :func:`to_trimesh` (one node per object, glTF materials) and :func:`scene_glb`.

What ``farfield scenes demo`` writes and what tests upload: every object keeps its name, geometry,
UVs, vertex colours, shading normals (where it has them), base colour, texture, alpha cutoff and
sidedness, so a GLB written here loads back as the same scene (vertex colours within their 8-bit
quantisation, normals within float32).
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
            # farfield keeps no material channels yet: every object is a rough dielectric, as the lit
            # evaluation shades it (glTF's defaults, metallic 1 and roughness 1, would make it metal)
            metallicFactor=0.0,
            roughnessFactor=1.0,
            baseColorTexture=None if obj.texture is None else texture_image(obj.texture),
            alphaMode=None if obj.alpha_cutoff is None else "MASK",
            alphaCutoff=obj.alpha_cutoff,
            doubleSided=obj.double_sided,
        )
        visual = trimesh.visual.TextureVisuals(uv=None if obj.uv is None else np.array(obj.uv), material=material)
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


def scene_glb(scene: Scene) -> bytes:
    """``scene`` as the bytes of a GLB file."""
    data = to_trimesh(scene).export(file_type="glb")
    return data if isinstance(data, bytes) else data.encode()

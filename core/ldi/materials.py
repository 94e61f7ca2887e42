"""glTF materials of LDI samples and points: (m, 4) uint8 ORM bytes and (m, 4) uint8 emission bytes,
one per sample (point-based and LDI impostors keep them with ``channels="albedo+normal+material"``).

The material channels of a layered impostor's texel (:mod:`farfield.core.layering.recording`) computed
for a sample on the CPU, as :mod:`farfield.core.ldi.normals` computes its normal: the object's factors
times its material textures at the sample's material uv, interpolated with its barycentric
coordinates in its triangle.  glTF's ORM packing, linear: R occlusion ``1 + strength * (R - 1)``, G
roughness ``G * roughness_factor``, B metallic ``B * metallic_factor``, alpha 255; the emission
``emissive_factor * texture`` (the texture sRGB-decoded) sRGB-encoded, alpha 255.  The textures are
read at their nearest texel (:func:`farfield.core.scene.sample_texture`), not filtered over the
sample's footprint as a layer texel's are, and without the Toksvig roughness (a sample keeps its
triangle's vertex normals, never a normal map's).
"""

from __future__ import annotations

import numpy as np

from farfield.core.colour_space import linear_to_srgb, srgb_to_linear
from farfield.core.ldi.normals import barycentric
from farfield.core.scene import SceneObject, sample_texture


def object_material(obj: SceneObject, uv: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """((m, 4) uint8 ORM, (m, 4) uint8 sRGB emission) of ``obj`` at material uvs ``uv`` (m, 2)
    (None: an object without material textures, whose factors hold everywhere; m = 1).

    >>> quad = SceneObject("q", np.zeros((3, 3)), np.array([[0, 1, 2]]), metallic_factor=0.5, roughness_factor=0.5)
    >>> [a.tolist() for a in object_material(quad, None)]
    [[[255, 128, 128, 255]], [[0, 0, 0, 255]]]
    """
    m = 1 if uv is None else uv.shape[0]
    occlusion, roughness = np.ones(m), np.full(m, float(obj.roughness_factor))
    metallic, emission = np.full(m, float(obj.metallic_factor)), np.tile(obj.emissive_factor, (m, 1))
    if uv is not None and obj.metallic_roughness_texture is not None:
        texels = sample_texture(obj.metallic_roughness_texture, uv) / 255.0
        roughness, metallic = roughness * texels[:, 1], metallic * texels[:, 2]
    if uv is not None and obj.occlusion_texture is not None:
        occlusion = 1.0 + float(obj.occlusion_strength) * (
            sample_texture(obj.occlusion_texture, uv)[:, 0] / 255.0 - 1.0
        )
    if uv is not None and obj.emissive_texture is not None:
        emission = emission * srgb_to_linear(sample_texture(obj.emissive_texture, uv)[:, :3] / 255.0)
    orm = np.stack([occlusion, roughness, metallic, np.ones(m)], axis=1)
    orm = np.clip(np.rint(np.clip(orm, 0.0, 1.0) * 255.0), 0, 255).astype(np.uint8)
    emissive = np.full((m, 4), 255, np.uint8)
    emissive[:, :3] = np.clip(np.rint(linear_to_srgb(emission) * 255.0), 0, 255).astype(np.uint8)
    return orm, emissive


def sample_material(
    objects: list[SceneObject] | tuple[SceneObject, ...],
    obj: np.ndarray,
    triangle: np.ndarray,
    positions: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """((m, 4) uint8 ORM, (m, 4) uint8 sRGB emission) of samples on triangle ``triangle`` (m,) of
    ``objects[obj]`` (m,) at world ``positions`` (m, 3), as the module docstring says.

    >>> tri = SceneObject("t", np.array([[0.0, 0, 5], [1, 0, 5], [0, 1, 5]]), np.array([[0, 1, 2]]),
    ...                   roughness_factor=0.4, emissive_factor=np.array([1.0, 0.0, 0.0]))
    >>> [a.tolist() for a in sample_material([tri], np.array([0]), np.array([0]), np.array([[0.2, 0.2, 5.0]]))]
    [[[255, 102, 0, 255]], [[255, 0, 0, 255]]]
    """
    obj, triangle = np.asarray(obj, dtype=np.int64), np.asarray(triangle, dtype=np.int64)
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    orm = np.zeros((positions.shape[0], 4), np.uint8)
    emissive = np.zeros((positions.shape[0], 4), np.uint8)
    for k in np.unique(obj):
        mine = np.flatnonzero(obj == k)
        o = objects[int(k)]
        textured = o.material_uv is not None and any(
            t is not None for t in (o.metallic_roughness_texture, o.occlusion_texture, o.emissive_texture)
        )
        uv = None
        if textured:
            faces = o.faces[triangle[mine]]
            weights = barycentric(positions[mine], o.vertices[faces])
            uv = np.einsum("mkc,mk->mc", o.material_uv[faces], weights)
        orm[mine], emissive[mine] = object_material(o, uv)
    return orm, emissive

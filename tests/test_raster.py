"""The mesh renderer's shader variants (``core/render/raster.py::mesh_variant``).

Each object is drawn by a variant built for what it has: no vertex colours, texture coordinates or
clip distances are computed or interpolated where the object has none.  An object drawn that way
must look exactly as the same object given neutral extras (white vertex colours, a white texture,
an alpha cut no texel falls under) and drawn by the variant that has them all.
"""

from __future__ import annotations

import itertools
from dataclasses import replace

import numpy as np
import pytest
import trimesh

from farfield.core.render.raster import MeshRenderer, mesh_variant
from farfield.core.scene import SceneObject
from farfield.core.techniques.envmap.runtime import camera_at


def _sphere() -> SceneObject:
    """A sphere with vertex colours, texture coordinates, a texture with a cut-out band, and an
    alpha cut: everything ``mesh.frag`` can multiply or discard by."""
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    vertices = np.asarray(mesh.vertices, dtype=np.float64)
    rng = np.random.default_rng(1)
    uv = np.stack([0.5 + np.arctan2(vertices[:, 2], vertices[:, 0]) / (2 * np.pi), 0.5 + 0.5 * vertices[:, 1]], axis=1)
    texture = rng.integers(0, 256, (32, 32, 4), dtype=np.uint8)
    texture[..., 3] = 255
    texture[12:18, :, 3] = 40  # under the cut: a band of holes
    colours = rng.integers(60, 256, (len(vertices), 4), dtype=np.uint8)
    colours[:, 3] = 255
    return SceneObject(
        "sphere",
        vertices,
        np.asarray(mesh.faces, dtype=np.int64),
        uv=uv,
        vertex_colors=colours,
        texture=texture,
        alpha_cutoff=0.5,
        base_color=np.array([0.9, 0.7, 0.8, 1.0]),
    )


def _without(obj: SceneObject, colours: bool, texture: bool, cut: bool) -> SceneObject:
    """``obj`` keeping only the features named True."""
    return replace(
        obj,
        vertex_colors=obj.vertex_colors if colours else None,
        texture=obj.texture if texture else None,
        uv=obj.uv if texture else None,
        alpha_cutoff=obj.alpha_cutoff if cut else None,
    )


def _neutral(obj: SceneObject) -> SceneObject:
    """``obj`` with each missing feature added as one that changes nothing."""
    n = obj.vertices.shape[0]
    return replace(
        obj,
        vertex_colors=obj.vertex_colors if obj.vertex_colors is not None else np.full((n, 4), 255, np.uint8),
        texture=obj.texture if obj.texture is not None else np.full((1, 1, 4), 255, np.uint8),
        uv=obj.uv if obj.uv is not None else np.zeros((n, 2)),
        alpha_cutoff=obj.alpha_cutoff if obj.alpha_cutoff is not None else 0.0,
    )


@pytest.mark.parametrize("clipping", ["whole", "clip planes", "open faces"])
def test_each_variant_draws_what_the_full_shader_draws(clipping):
    sphere = _sphere()
    camera = camera_at([0.3, 0.4, -3.0], [-0.1, -0.13, 1.0], 50.0, 96, 0.1, 10.0)
    cube = (np.array([0.0, 0.45, 0.0]), 0.85)  # cuts the front, sides and bottom
    clipped = clipping != "whole"
    clip = (
        None if not clipped else [cube] if clipping == "clip planes" else [(*cube, ("+z",))]
    )  # open behind the sphere
    extra = {"whole": (), "clip planes": ("CLIP_PLANES",), "open faces": ("OPEN_FACES",)}[clipping]
    images = {}
    for features in itertools.product([False, True], repeat=3):
        lean = _without(sphere, *features)
        full = _neutral(lean)
        assert mesh_variant(full, clipping == "clip planes", clipping == "open faces") == (
            "VERTEX_COLOURS",
            "TEXTURED",
            "ALPHA_CUT",
            *extra,
        )
        with MeshRenderer([lean], clip) as a, MeshRenderer([full], clip) as b:
            images[features] = a.render(camera)
            np.testing.assert_array_equal(
                images[features], b.render(camera), err_msg=f"colours, texture, cut = {features}"
            )
    # Every feature shows: dropping any one changes the image, so a variant that ignored it would
    # be caught (the cut shows only with the texture's alpha).
    every = images[(True, True, True)]
    assert (every[..., 3] > 0).sum() > 1500
    for k in range(3):
        assert (images[tuple(i != k for i in range(3))] != every).any(axis=2).sum() > 100, k
    with MeshRenderer([sphere]) as whole:
        drawn = whole.render(camera)[..., 3] > 0
    assert (drawn.sum() > (every[..., 3] > 0).sum() + 100) == clipped
    if clipping == "open faces":  # the face opened behind the sphere lets its back through
        with MeshRenderer([sphere], [cube]) as closed:
            assert (every[..., 3] > 0).sum() > (closed.render(camera)[..., 3] > 0).sum() + 50

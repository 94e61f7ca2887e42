"""Shader programs keyed by their shader files, cached on the process's context, and context bookkeeping.

Shaders live as ``.vert`` / ``.geom`` / ``.frag`` files in ``core/render/shaders``; a line
``#include "name.glsl"`` is replaced by that file of the same folder (one level, no guards), and a
program may be built with ``defines`` (``#define NAME`` lines after ``#version``) to select a
variant of the same files.
"""

from __future__ import annotations

import re
from pathlib import Path

import moderngl
import numpy as np

SHADERS = Path(__file__).resolve().parent / "shaders"


def context_cache(ctx: moderngl.Context) -> dict:
    """The dict of long-lived objects owned by ``ctx`` (programs, the parking framebuffer)."""
    if not isinstance(ctx.extra, dict):
        ctx.extra = {}
    return ctx.extra


_INCLUDE = re.compile(r'^#include "([\w.-]+)"\s*$', re.MULTILINE)


def shader_source(name: str, defines: tuple[str, ...] = ()) -> str:
    """The text of shader file ``name`` with its ``#include`` lines expanded and a ``#define`` line
    for each of ``defines`` after its ``#version`` line.

    >>> shader_source("mesh.frag", ("ALPHA_CUT",)).splitlines()[:2]
    ['#version 330', '#define ALPHA_CUT']
    """
    text = _INCLUDE.sub(lambda m: (SHADERS / m.group(1)).read_text(), (SHADERS / name).read_text())
    if defines:
        version, _, rest = text.partition("\n")
        text = "\n".join([version, *(f"#define {d}" for d in defines), rest])
    return text


def program(
    ctx: moderngl.Context, vertex: str, fragment: str, geometry: str | None = None, defines: tuple[str, ...] = ()
) -> moderngl.Program:
    """The program made of the named shader files (e.g. ``"mesh.vert"``) with ``defines`` (see
    :func:`shader_source`), compiled once per context."""
    key = ("program", vertex, geometry, fragment, tuple(defines))
    cache = context_cache(ctx)
    if key not in cache:
        cache[key] = ctx.program(
            vertex_shader=shader_source(vertex, defines),
            geometry_shader=shader_source(geometry, defines) if geometry else None,
            fragment_shader=shader_source(fragment, defines),
        )
    return cache[key]


def park_framebuffer(ctx: moderngl.Context) -> None:
    """Bind a persistent 1x1 framebuffer before releasing the one in use.

    Releasing the bound framebuffer leaves moderngl's next ``use()`` of another one failing with
    GL_INVALID_OPERATION (seen with Mesa 22.3 EGL); parking first avoids the dangling binding.
    """
    cache = context_cache(ctx)
    if "parking" not in cache:
        cache["parking"] = ctx.framebuffer([ctx.renderbuffer((1, 1), 4)])
    cache["parking"].use()


# GL_SRGB8_ALPHA8: the GL decodes texels to linear before filtering (and builds mipmaps in linear).
SRGB8_ALPHA8 = 0x8C43


def _texture(ctx: moderngl.Context, rgba: np.ndarray, mipmaps: bool, internal_format: int | None) -> moderngl.Texture:
    """(h, w, 4) uint8 ``rgba``, top row first, as a GL texture: rows flipped to GL's order, bilinear
    (trilinear over mipmaps built when ``mipmaps``), repeating."""
    image = np.ascontiguousarray(rgba[::-1])
    texture = ctx.texture((image.shape[1], image.shape[0]), 4, image.tobytes(), internal_format=internal_format)
    if mipmaps:
        texture.build_mipmaps()
        texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
    else:
        texture.filter = (moderngl.LINEAR, moderngl.LINEAR)
    return texture


def srgb_texture(ctx: moderngl.Context, rgba: np.ndarray, mipmaps: bool = False) -> moderngl.Texture:
    """A base-colour texture of (h, w, 4) uint8 sRGB-encoded RGBA, top row first: rows flipped to
    GL's order, sampled as linear light, bilinear (trilinear over mipmaps built when ``mipmaps``),
    repeating (glTF's default sampler)."""
    return _texture(ctx, rgba, mipmaps, SRGB8_ALPHA8)


def linear_texture(ctx: moderngl.Context, rgba: np.ndarray, mipmaps: bool = False) -> moderngl.Texture:
    """A data texture (a normal map) of (h, w, 4) uint8, top row first, not colour-managed: rows
    flipped to GL's order, bilinear (trilinear over mipmaps built when ``mipmaps``), repeating."""
    return _texture(ctx, rgba, mipmaps, None)


def material_uniforms(prog: moderngl.Program, obj, texture: moderngl.Texture | None) -> dict:
    """The unlit-material uniforms every farfield shader shares (glTF's base colour rule), as
    name -> value: ``base_color`` (linear), ``alpha_cutoff`` (-1: opaque) and ``has_texture``
    (each only where ``prog`` has it) and, with a texture, ``base_texture`` on unit 0 (the caller binds
    ``texture``, an :func:`srgb_texture`, there).

    ``obj`` is a :class:`farfield.core.scene.SceneObject`; ``texture`` its uploaded base-colour texture.
    """
    uniforms = {"base_color": tuple(float(c) for c in obj.base_color)}
    if prog.get("has_texture", None) is not None:  # absent from a variant built for its object
        uniforms["has_texture"] = texture is not None
    if prog.get("alpha_cutoff", None) is not None:  # absent from a variant that never discards
        uniforms["alpha_cutoff"] = float(obj.alpha_cutoff) if obj.alpha_cutoff is not None else -1.0
    if texture is not None:
        uniforms["base_texture"] = 0
    return uniforms


def set_material(prog: moderngl.Program, obj, texture: moderngl.Texture | None) -> None:
    """Set :func:`material_uniforms` on ``prog`` and bind ``texture`` (if any) to unit 0."""
    for name, value in material_uniforms(prog, obj, texture).items():
        prog[name].value = value
    if texture is not None:
        texture.use(0)

"""Shader programs keyed by their shader files, cached on the process's context, and context bookkeeping.

Shaders live as ``.vert`` / ``.geom`` / ``.frag`` files in ``core/render/shaders``.
"""

from __future__ import annotations

from pathlib import Path

import moderngl

SHADERS = Path(__file__).resolve().parent / "shaders"


def context_cache(ctx: moderngl.Context) -> dict:
    """The dict of long-lived objects owned by ``ctx`` (programs, the parking framebuffer)."""
    if not isinstance(ctx.extra, dict):
        ctx.extra = {}
    return ctx.extra


def program(ctx: moderngl.Context, vertex: str, fragment: str, geometry: str | None = None) -> moderngl.Program:
    """The program made of the named shader files (e.g. ``"mesh.vert"``), compiled once per context."""
    key = ("program", vertex, geometry, fragment)
    cache = context_cache(ctx)
    if key not in cache:
        cache[key] = ctx.program(
            vertex_shader=(SHADERS / vertex).read_text(),
            geometry_shader=(SHADERS / geometry).read_text() if geometry else None,
            fragment_shader=(SHADERS / fragment).read_text(),
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


def set_material(prog: moderngl.Program, obj, texture: moderngl.Texture | None) -> None:
    """Set the unlit-material uniforms every farfield shader shares (glTF's base colour rule):
    ``base_color``, ``alpha_cutoff`` (-1: opaque), ``has_texture`` and ``base_texture`` on unit 0.

    ``obj`` is a :class:`core.scene.SceneObject`; ``texture`` its uploaded base-colour texture.
    """
    prog["base_color"].value = tuple(float(c) for c in obj.base_color)
    prog["alpha_cutoff"].value = float(obj.alpha_cutoff) if obj.alpha_cutoff is not None else -1.0
    prog["has_texture"].value = texture is not None
    if texture is not None:
        texture.use(0)
        prog["base_texture"].value = 0

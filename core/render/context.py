"""The process's one OpenGL context: a moderngl standalone context on EGL, created lazily.

This module is the only place a GL context is created (after moderngl's own tests).  The context
is made on first use, in the process that uses it, and is never inherited across ``fork``: a
forked child that finds its parent's context gets a clear error instead of a corrupted driver
state.  On a CPU machine EGL gives Mesa's llvmpipe; on a GPU machine, the NVIDIA driver.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import moderngl

from farfield.core.errors import LayerPlanError, RenderBackendError

# OpenGL 3.3 core is enough for everything farfield draws (instancing, texelFetch); llvmpipe
# offers 4.5 and the NVIDIA driver 4.6.
REQUIRED_GL = 330

_context: moderngl.Context | None = None
_owner_pid: int | None = None
_device_index: int | None = None


@dataclass(frozen=True, slots=True)
class RendererInfo:
    """What the context runs on, for logs, report headers and evaluation records."""

    vendor: str
    renderer: str
    version: str
    device_index: int | None

    @property
    def is_software(self) -> bool:
        return "llvmpipe" in self.renderer.lower() or "softpipe" in self.renderer.lower()


def gl_context(device_index: int | None = None) -> moderngl.Context:
    """The process's EGL context, created on the first call.

    Parameters
    ----------
    device_index : int, optional
        EGL device to use (one per GPU); the first call fixes it for the life of the process.

    Raises
    ------
    RenderBackendError
        EGL is not available, or the context was created before this process forked.
    """
    global _context, _owner_pid, _device_index
    if _context is not None:
        if _owner_pid != os.getpid():
            raise RenderBackendError(
                "a GL context was created in a parent process before fork; create it only in the "
                "process that renders (workers create theirs on first use)"
            )
        return _context
    kwargs = {"standalone": True, "backend": "egl", "require": REQUIRED_GL}
    if device_index is not None:
        kwargs["device_index"] = int(device_index)
    try:
        ctx = moderngl.create_context(**kwargs)
    except Exception as error:  # moderngl/glcontext raise bare Exception for every EGL failure
        raise RenderBackendError(
            f"no usable EGL OpenGL {REQUIRED_GL // 100}.{REQUIRED_GL % 100 // 10} context: {error}"
        ) from error
    ctx.gc_mode = "context_gc"
    _context, _owner_pid, _device_index = ctx, os.getpid(), device_index
    return ctx


def renderer_info() -> RendererInfo:
    """Vendor, renderer and version strings of the process's context (creating it if needed)."""
    ctx = gl_context()
    info = ctx.info
    return RendererInfo(info["GL_VENDOR"], info["GL_RENDERER"], info["GL_VERSION"], _device_index)


def largest_target_side(ctx: moderngl.Context) -> int:
    """Texels per side of the largest texture the context renders into: the least of its
    ``GL_MAX_TEXTURE_SIZE``, ``GL_MAX_RENDERBUFFER_SIZE`` and ``GL_MAX_VIEWPORT_DIMS`` (16384 on
    llvmpipe)."""
    info = ctx.info
    return int(min(info["GL_MAX_TEXTURE_SIZE"], info["GL_MAX_RENDERBUFFER_SIZE"], *info["GL_MAX_VIEWPORT_DIMS"]))


def check_target_size(ctx: moderngl.Context, width: int, height: int, what: str) -> None:
    """Raise LayerPlanError (bad input: HTTP 422, exit code 2) when a ``width`` x ``height`` render
    target passes :func:`largest_target_side`, before the driver refuses it with an incomplete
    framebuffer.  A layer plan may ask for up to ``TOL.max_texture_resolution`` texels per side, more
    than a renderer draws: a view cell very close to its part at a high resolution."""
    largest = largest_target_side(ctx)
    if max(int(width), int(height)) > largest:
        raise LayerPlanError(
            f"{what} of {int(width)} x {int(height)} texels is larger than this renderer draws "
            f"({largest} per side): the view cell is too close to the part for the output resolution; "
            "lower the resolution, raise max_error_px, or move the view cell away from the part"
        )


def release_context() -> None:
    """Release the process's context (tests, and workers before they exit)."""
    global _context, _owner_pid, _device_index
    if _context is not None and _owner_pid == os.getpid():
        _context.release()
    _context, _owner_pid, _device_index = None, None, None

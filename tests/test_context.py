"""The one EGL context: lazy creation, fork safety, and create-and-release of each resource kind."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

from farfield.core.errors import RenderBackendError
from farfield.core.render.context import gl_context, renderer_info
from farfield.core.render.programs import park_framebuffer, program
from farfield.core.render.raster import Camera, MeshRenderer
from farfield.core.scene import SceneObject
from tests.scenes import checker


@pytest.fixture()
def ctx(gl):
    context = gl
    assert context.error == "GL_NO_ERROR"
    yield context
    assert context.error == "GL_NO_ERROR"


def test_one_context_per_process(ctx):
    assert gl_context() is ctx
    info = renderer_info()
    assert info.renderer and info.version


def test_a_forked_child_refuses_the_parents_context(ctx):
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # child: must not touch the parent's driver state
        os.close(read)
        try:
            gl_context()
            message = b"no error"
        except RenderBackendError as error:
            message = str(error).encode()
        os.write(write, message)
        os._exit(0)
    os.close(write)
    os.waitpid(pid, 0)
    with os.fdopen(read, "rb") as pipe:
        assert b"before fork" in pipe.read()


@pytest.mark.parametrize("kind", ["buffer", "texture", "depth_texture", "framebuffer", "vertex_array"])
def test_create_and_release_each_resource_kind(ctx, kind):
    prog = program(ctx, "mesh.vert", "mesh.frag", defines=("VERTEX_COLOURS", "TEXTURED"))
    made = []
    if kind == "buffer":
        made.append(ctx.buffer(reserve=1024))
    elif kind == "texture":
        made.append(ctx.texture((16, 8), 4))
    elif kind == "depth_texture":
        made.append(ctx.depth_texture((16, 8)))
    elif kind == "framebuffer":
        colour, depth = ctx.texture((16, 8), 4), ctx.depth_texture((16, 8))
        fbo = ctx.framebuffer([colour], depth)
        fbo.use()
        made += [fbo, colour, depth]
    else:
        vbo = ctx.buffer(np.zeros((3, 9), "<f4").tobytes())
        made += [ctx.vertex_array(prog, [(vbo, "3f 2f 4f", "in_position", "in_uv", "in_color")]), vbo]
    park_framebuffer(ctx)
    for resource in made:
        resource.release()
    assert ctx.error == "GL_NO_ERROR"


def test_renderer_releases_everything_it_made(ctx):
    quad = SceneObject(
        "quad", np.array([[-1.0, -1, 5], [1, -1, 5], [1, 1, 5], [-1, 1, 5]]), np.array([[0, 1, 2], [0, 2, 3]])
    )
    camera = Camera.look_at([0, 0, 0], [0, 0, 5], np.radians(60), 32, 1.0, 10.0)
    for _ in range(3):  # repeated use leaves no error and no stale binding
        with MeshRenderer([quad]) as renderer:
            image = renderer.render(camera)
        assert image[16, 16, 3] == 255 and image[0, 0, 3] == 0
    assert ctx.error == "GL_NO_ERROR"


def test_each_draw_keeps_its_own_matrix_and_material(ctx):
    # The renderer builds every draw's eye matrix in one go and sets each draw's material from
    # values made once: drawn together, objects at their own places, with their own colours, a
    # texture and an alpha cut, must look as each one drawn alone (they do not overlap on screen).
    rng = np.random.default_rng(4)
    quad = np.array([[0.0, 0.0, 0.0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    uv = np.array([[0.0, 0.0], [1, 0], [1, 1], [0, 1]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    texture = checker(8)
    cut = checker(8)
    cut[:4, :, 3] = 0
    objects = []
    for i in range(9):
        place = np.array([(i % 3) * 1.5 - 2.0, (i // 3) * 1.5 - 2.0, 6.0 + 0.5 * i])
        kind = i % 3
        objects.append(
            SceneObject(
                f"q{i}", quad * (0.8 + 0.1 * i) + place, faces, uv=uv if kind else None, base_color=(*rng.uniform(0.2, 1.0, 3), 1.0),
                texture=(texture if kind == 1 else cut) if kind else None, alpha_cutoff=0.5 if kind == 2 else None,
            )
        )  # fmt: skip
    camera = Camera.look_at([0.0, 0.0, 0.0], [0.0, 0.0, 6.0], np.radians(70), 96, 0.5, 50.0)
    with MeshRenderer(objects) as together:
        image = together.render(camera)
    alone = []
    for obj in objects:
        with MeshRenderer([obj]) as one:
            alone.append(one.render(camera))
    covered = np.stack([a[..., 3] > 0 for a in alone])
    assert covered.sum(axis=0).max() == 1 and all(c.sum() > 30 for c in covered), covered.sum(axis=(1, 2))
    np.testing.assert_array_equal(image, np.sum([a.astype(np.int64) for a in alone], axis=0).astype(np.uint8))
    assert len({tuple(a[c][0]) for a, c in zip(alone, covered)}) == len(objects)  # nine different looks


@pytest.mark.gpu
@pytest.mark.skipif(not Path("/dev/nvidiactl").exists(), reason="needs an NVIDIA GPU (no /dev/nvidiactl here)")
def test_egl_uses_the_nvidia_driver_on_a_gpu_machine():
    assert "nvidia" in (renderer_info().vendor + renderer_info().renderer).lower()

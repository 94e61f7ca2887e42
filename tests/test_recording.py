"""Gap-free layer recording on the real EGL context (llvmpipe on CPU machines)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh

from core.layers import plan_layers
from core.recording import layer_buckets, record_layers
from core.render.context import gl_context
from core.scene import Scene, SceneObject
from core.viewcells import BoxCell


def forest(count: int = 30, radius: float = 0.02, seed: int = 1) -> Scene:
    """Thin cylinders, far narrower than a texel from the view cell below."""
    rng = np.random.default_rng(seed)
    objects = []
    for i in range(count):
        c = trimesh.creation.cylinder(radius=radius, height=8.0, sections=6)
        c.apply_translation([rng.uniform(60, 90), rng.uniform(-20, 20), rng.uniform(-1, 1)])
        objects.append(SceneObject(name=f"tree{i}", vertices=c.vertices, faces=c.faces))
    return Scene.from_objects(objects, "forest")


def touched_texels(scene: Scene, plan, spacing: float = 0.2) -> np.ndarray:
    """(h, w) bool: texels that points sampled on every triangle (edges every ``spacing`` texels,
    plus a barycentric grid inside) project to; an independent CPU subset of the touched texels."""
    res = plan.texture_resolution.astype(np.float64)
    frame = np.stack([plan.u, plan.v, plan.axis])
    hit = np.zeros((int(res[1]), int(res[0])), dtype=bool)

    def project(points):
        e = (points - plan.reference_viewpoint) @ frame.T
        return (e[:, :2] / (e[:, 2:3] * plan.frustum_half_tangents) * 0.5 + 0.5) * res

    for obj in scene.objects:
        tri = obj.vertices[obj.faces]  # (f, 3, 3)
        px = project(tri.reshape(-1, 3)).reshape(-1, 3, 2)
        samples = []
        for a, b in ((0, 1), (1, 2), (2, 0)):
            n = int(np.ceil(np.max(np.linalg.norm(px[:, a] - px[:, b], axis=1)) / spacing)) + 1
            t = np.linspace(0.0, 1.0, n + 1)[None, :, None]
            samples.append((tri[:, a, None] * (1 - t) + tri[:, b, None] * t).reshape(-1, 3))
        w = np.array([[i, j, 8 - i - j] for i in range(9) for j in range(9 - i)], dtype=np.float64) / 8.0
        samples.append(np.einsum("sk,fkd->fsd", w, tri).reshape(-1, 3))
        p = np.floor(project(np.concatenate(samples))).astype(np.int64)
        ok = (p[:, 0] >= 0) & (p[:, 1] >= 0) & (p[:, 0] < res[0]) & (p[:, 1] < res[1])
        hit[p[ok, 1], p[ok, 0]] = True
    return hit


@pytest.fixture(scope="module")
def ctx():
    context = gl_context()
    yield context
    assert context.error == "GL_NO_ERROR"


def test_conservative_recording_loses_no_thin_geometry_and_the_standard_rule_does(ctx):
    scene = forest()
    plan = plan_layers(BoxCell.from_center([0, 0, 0], 10.0), scene.bounds, math.radians(45), 256)
    truth = touched_texels(scene, plan)
    conservative = record_layers(scene, plan, conservative=True).coverage.any(axis=0)
    standard = record_layers(scene, plan, conservative=False).coverage.any(axis=0)
    assert ctx.error == "GL_NO_ERROR"
    assert truth.sum() > 500
    assert not np.any(truth & ~conservative), "conservative recording missed touched texels"
    assert np.sum(truth & ~standard) > 0.5 * truth.sum(), "the standard rule should lose most of the forest"
    assert np.all(conservative[standard])
    # Conservative, not bloated: within one texel of what the geometry touches.
    grown = truth.copy()
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            grown |= np.roll(np.roll(truth, dy, axis=0), dx, axis=1)
    assert not np.any(conservative & ~grown)


def test_clipping_edges_are_written_into_both_adjacent_layers(ctx):
    """A slanted ground plane spans many layers; neighbouring slabs share its clipping edge."""
    ground = trimesh.creation.box(extents=[40.0, 30.0, 0.01])
    ground.apply_transform(trimesh.transformations.rotation_matrix(0.3, [0, 1, 0]))
    ground.apply_translation([70.0, 0.0, -4.0])
    scene = Scene.from_objects([SceneObject(name="ground", vertices=ground.vertices, faces=ground.faces)], "ground")
    plan = plan_layers(BoxCell.from_center([0, 0, 0], 10.0), scene.bounds, math.radians(45), 128)
    rec = record_layers(scene, plan)
    cov = rec.coverage
    assert plan.count > 5
    truth = touched_texels(scene, plan)
    assert not np.any(truth & ~cov.any(axis=0))
    for i in range(plan.count - 1):
        if cov[i].any() and cov[i + 1].any():
            assert np.any(cov[i] & cov[i + 1]), f"layers {i} and {i + 1} share no clipping-edge texels"


def test_layers_draw_only_the_triangles_their_slab_needs():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.0, 100.0, 3000)
    faces = rng.integers(0, 3000, (2000, 3))
    borders = np.sort(rng.uniform(-5.0, 105.0, 41))
    order, offsets = layer_buckets(depth, faces, borders)
    z = depth[faces]
    zmin, zmax = z.min(axis=1), z.max(axis=1)
    for i in range(40):
        expected = np.flatnonzero((zmin <= borders[i + 1]) & (zmax >= borders[i]))
        np.testing.assert_array_equal(np.sort(order[offsets[i] : offsets[i + 1]]), expected)
    assert offsets[-1] == order.shape[0] < faces.shape[0] * 40


def test_recording_is_deterministic(ctx):
    scene = forest(count=8)
    plan = plan_layers(BoxCell.from_center([0, 0, 0], 10.0), scene.bounds, math.radians(45), 128)
    a = record_layers(scene, plan).rgba
    b = record_layers(scene, plan).rgba
    np.testing.assert_array_equal(a, b)

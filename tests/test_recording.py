"""Gap-free layer recording on the real EGL context (llvmpipe on CPU machines)."""

from __future__ import annotations

import json
import math
import subprocess
import sys

import numpy as np
import pytest
import trimesh

from farfield.core.layering.plan import plan_layers
from farfield.core.layering.recording import (
    clip_to_slab,
    eye_coordinates,
    facing_the_image,
    layer_buckets,
    record_layers,
    slab_instances,
    texel_coordinates,
    texel_rectangles,
)
from farfield.core.scene import Scene, SceneObject
from farfield.core.viewcells import BoxCell


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
def ctx(gl):
    context = gl
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


def test_triangles_of_zero_area_are_not_recorded_and_the_scene_keeps_them(ctx):
    """Three collinear corners draw nothing in any renderer, but the conservative rule wrote the
    texels along them (an OBJ of one such triangle: a layered impostor of 184 texels, all bloat).
    The recording leaves them out; the object keeps them (face indices count for clusters)."""
    ground = trimesh.creation.box(extents=[40.0, 30.0, 0.01])
    ground.apply_translation([70.0, 0.0, -4.0])
    line = np.array([[65.0, -10.0, -8.0], [70.0, 0.0, -6.0], [75.0, 10.0, -4.0]])  # collinear, across the ground's view
    vertices = np.concatenate([ground.vertices, line])
    n = len(ground.vertices)
    with_line = SceneObject(name="ground", vertices=vertices, faces=np.concatenate([[[n, n + 1, n + 2]], ground.faces]))
    without = SceneObject(name="ground", vertices=vertices, faces=ground.faces)
    plan = plan_layers(BoxCell.from_center([0, 0, 0], 10.0), with_line.bounds, math.radians(45), 128)
    a = record_layers(Scene.from_objects([with_line], "a"), plan)
    b = record_layers(Scene.from_objects([without], "b"), plan)
    assert with_line.faces.shape[0] == without.faces.shape[0] + 1
    np.testing.assert_array_equal(a.rgba, b.rgba)
    alone = SceneObject(name="line", vertices=line, faces=np.array([[0, 1, 2]]))
    assert not record_layers(Scene.from_objects([alone], "c"), plan).coverage.any()


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


@pytest.mark.slow
def test_triangles_beyond_an_image_edge_are_dropped_before_pairing_and_would_have_drawn_nothing():
    rng = np.random.default_rng(3)
    half_tan, resolution = np.array([0.7, 0.5]), np.array([64, 48])
    # Vertices spread well past the frustum on every side, some behind the eye, and 400 exactly on
    # the image's four edges (texel 0 or the resolution there), in triplets on the same edge.
    n, m = 3000, 400
    centre = np.stack(
        [rng.uniform(-3.0, 3.0, n // 3), rng.uniform(-3.0, 3.0, n // 3), rng.uniform(-0.5, 4.0, n // 3)], axis=1
    )
    loose = (centre[:, None, :] + rng.uniform(-0.3, 0.3, (n // 3, 3, 3))).reshape(n, 3)  # small triangles
    z = rng.uniform(0.3, 4.0, m)
    side = rng.integers(0, 4, m // 3).repeat(3)[:m]
    side = np.concatenate([side, np.zeros(m - side.shape[0], dtype=side.dtype)])
    axis, sign = side // 2, np.where(side % 2 == 0, -1.0, 1.0)
    on_edge = np.stack([rng.uniform(-0.6, 0.6, m) * z, rng.uniform(-0.4, 0.4, m) * z, z], axis=1)
    on_edge[np.arange(m), axis] = sign * half_tan[axis] * z
    eye = np.concatenate([loose, on_edge])
    faces = np.concatenate(
        [np.arange(n).reshape(-1, 3), rng.integers(0, n + m, (1000, 3)), n + np.arange(m - m % 3).reshape(-1, 3)]
    )
    borders = np.linspace(0.2, 4.2, 17)
    texel = texel_coordinates(eye.T, half_tan, resolution)
    seen = facing_the_image(texel, eye[:, 2], faces, resolution)
    dropped = np.setdiff1d(np.arange(faces.shape[0]), seen)
    assert 500 < dropped.shape[0] < faces.shape[0] - 500
    assert np.isin(np.arange(2000, faces.shape[0]), seen).all()  # triangles lying on an edge stay

    assert _reaching(eye, faces, borders, half_tan, resolution, dropped) == set()
    instances = slab_instances(eye, faces, borders, half_tan, resolution)
    layers = np.repeat(np.arange(16), np.diff(instances.offsets))
    assert set(zip(instances.triangle.tolist(), layers.tolist())) == _reaching(
        eye, faces, borders, half_tan, resolution, np.arange(faces.shape[0])
    )


def test_the_edge_slack_keeps_triangles_whose_clipped_pieces_round_back_onto_the_image():
    # Vertices up to ~5e-13 texel beyond the right edge: whole triangles there reach no texel, but
    # a piece clipped to a slab is computed from new points, which can round onto the edge itself,
    # where the rectangle rule takes in the last column.  Without the slack those are dropped.
    rng = np.random.default_rng(5)
    half_tan, resolution = np.array([0.7, 0.5]), np.array([512, 384])
    z = rng.uniform(0.3, 4.0, 30000)
    eye = np.stack(
        [half_tan[0] * z * (1.0 + rng.uniform(0.0, 2e-15, z.shape[0])), rng.uniform(-0.4, 0.4, z.shape[0]) * z, z],
        axis=1,
    )
    faces = np.arange(z.shape[0]).reshape(-1, 3)
    borders = np.linspace(0.2, 4.2, 5)
    texel = texel_coordinates(eye.T, half_tan, resolution)
    assert (texel[0] > resolution[0]).mean() > 0.5
    seen = facing_the_image(texel, eye[:, 2], faces, resolution)
    reaching = {t for t, _ in _reaching(eye, faces, borders, half_tan, resolution, np.arange(faces.shape[0]))}
    assert len(reaching) > 1000 and reaching <= set(seen.tolist())


def test_the_pairing_kernel_gives_the_numpy_clipping_bit_for_bit():
    """slab_instances pairs, clips and bounds in one numba kernel; every field it keeps equals, bit for
    bit, what clip_to_slab, texel_coordinates and texel_rectangles give (the reference the layers
    were recorded with before), and it keeps exactly the pairs they keep."""
    rng = np.random.default_rng(7)
    half_tan, resolution = np.array([0.7, 0.5]), np.array([64, 48])
    borders = np.linspace(0.2, 4.2, 17)
    z = rng.uniform(0.05, 4.5, 6000)
    on_border = rng.random(z.shape[0]) < 0.2  # corners on slab borders (every border), edges in them
    z[on_border] = rng.choice(borders, int(on_border.sum()))
    eye = np.stack(
        [rng.uniform(-1.3, 1.3, z.shape[0]) * half_tan[0] * z, rng.uniform(-1.3, 1.3, z.shape[0]) * half_tan[1] * z, z],
        axis=1,
    )
    small = (eye[:900, None, :] + rng.uniform(-0.05, 0.05, (900, 3, 3))).reshape(-1, 3)
    eye = np.concatenate([eye, small, [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]])  # and a point triangle
    faces = np.concatenate(
        [rng.integers(0, 6000, (3000, 3)), 6000 + np.arange(2700).reshape(-1, 3), [[8700, 8701, 8702]]]
    )
    inst = slab_instances(eye, faces, borders, half_tan, resolution)
    layer = np.repeat(np.arange(16), np.diff(inst.offsets))
    assert inst.triangle.shape[0] > 3000
    reaching = _reaching(eye, faces, borders, half_tan, resolution, np.arange(faces.shape[0]))
    assert set(zip(inst.triangle.tolist(), layer.tolist())) == reaching
    # In the order layer_buckets gives (by layer, then by face), which is the draw order that
    # settles equal depths.
    with np.errstate(invalid="ignore"):
        seen = facing_the_image(texel_coordinates(eye.T, half_tan, resolution), eye[:, 2], faces, resolution)
    order, offsets = layer_buckets(eye[:, 2], faces[seen], borders)
    bucketed = zip(seen[order].tolist(), np.repeat(np.arange(16), np.diff(offsets)).tolist())
    assert list(zip(inst.triangle.tolist(), layer.tolist())) == [pair for pair in bucketed if pair in reaching]
    polygon, count = clip_to_slab(np.take(eye.T, faces[inst.triangle].T, axis=1), borders[layer], borders[layer + 1])
    texel = texel_coordinates(polygon, half_tan, resolution)
    np.testing.assert_array_equal(inst.count, count)
    assert inst.polygon.tobytes() == texel.tobytes()
    np.testing.assert_array_equal(inst.rect, texel_rectangles(texel.min(axis=1), texel.max(axis=1), resolution))
    with np.errstate(divide="ignore"):
        at_vertex = np.concatenate([texel_coordinates(eye.T, half_tan, resolution), 1.0 / eye.T[2:]])
    assert inst.vertices.tobytes() == np.take(at_vertex, faces[inst.triangle].T, axis=1).tobytes()


def test_objects_of_every_material_variant_record_in_one_scene_as_each_does_alone(ctx):
    """Each object is drawn with the slab.frag variant of its material (plain, vertex colours with
    an alpha cut but no texture, textured, textured with an alpha cut), all in one layer pass: the
    scene's layers are, texel for texel, what each object records alone with the same plan (the
    four lie apart in the image), so no variant's inputs or uniforms leak into another's."""
    rng = np.random.default_rng(4)
    texture = rng.integers(0, 256, (16, 16, 4)).astype(np.uint8)
    cut_texture = texture.copy()
    cut_texture[..., 3] = np.where(rng.random((16, 16)) < 0.5, 0, 255)
    card = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    uv = card[:, :2] * 3.0 - 1.0  # repeating

    def at(x, y):
        return card + np.array([x, y, 0.0])

    colours = rng.integers(0, 256, (4, 4)).astype(np.uint8)
    colours[:, 3] = [40, 255, 90, 60]  # the second triangle's largest alpha misses the cut
    objects = [
        SceneObject("plain", at(-2.0, -2.0), faces, base_color=(0.2, 0.6, 0.9, 1.0)),
        SceneObject("vertex-cut", at(1.0, -2.0), faces, vertex_colors=colours, alpha_cutoff=0.5),
        SceneObject("textured", at(-2.0, 1.0), faces, uv=uv, texture=texture),
        SceneObject("textured-cut", at(1.0, 1.0), faces, uv=uv, texture=cut_texture, alpha_cutoff=0.5),
    ]
    scene = Scene.from_objects(objects, "variants")
    plan = plan_layers(BoxCell.from_center([0.0, 0.0, -8.0], 1.0), scene.bounds, math.radians(60), 128)
    together = record_layers(scene, plan).rgba
    alone = [record_layers(Scene.from_objects([obj], obj.name), plan).rgba for obj in objects]
    covered = [a[..., 3] > 0 for a in alone]
    assert all(c.sum() > 100 for c in covered)
    assert not np.any(np.sum(covered, axis=0) > 1)  # apart in every layer
    expected = np.zeros_like(together)
    for image, mask in zip(alone, covered):
        expected[mask] = image[mask]
    np.testing.assert_array_equal(together, expected)


WARM_CHECK = """
import json, numpy as np
import farfield.core.layering.atlas as atlas
import farfield.core.layering.recording as recording
from farfield.core.procedural import city
from farfield.core.render.context import gl_context
from farfield.core.techniques.layered import BakeOptions, bake_layered
from farfield.core.viewcells import BoxCell
def signatures():
    return [len(recording._pair_kernel.signatures), len(atlas._fill_page.signatures)]
before = signatures()
recording.warm_kernels()
warmed = signatures()
scene = city(4)
lo, hi = scene.bounds
with gl_context():
    bake_layered(scene, BoxCell(np.array([lo[0] - 60, lo[1], lo[2]]), np.array([lo[0] - 40, lo[1] + 20, lo[2] + 20])), BakeOptions(resolution=64))
print(json.dumps({"before": before, "warmed": warmed, "baked": signatures()}))
"""


def test_warming_compiles_the_pairing_kernel_with_the_types_a_bake_runs_it_with():
    """What a render worker does when it starts (``farfield.workers.tasks.warm_worker``), in a fresh process:
    after :func:`warm_kernels` a real layered bake adds no compiled signature to the pairing
    kernel or the atlas's placement kernel, so none compiles (or loads from the cache) during a cell."""
    out = subprocess.run([sys.executable, "-c", WARM_CHECK], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-3000:]
    counts = json.loads(out.stdout.strip().splitlines()[-1])
    assert counts == {"before": [0, 0], "warmed": [1, 1], "baked": [1, 1]}


def test_a_layer_texture_larger_than_the_renderer_draws_is_refused_as_bad_input(ctx):
    """A cell very close to a wide part: the plan asks for 1102 x 22023 texels, under the plan's
    own limit (TOL.max_texture_resolution) but over llvmpipe's 16384; the bake says so as bad
    input (exit code 2, HTTP 422) instead of the driver's incomplete framebuffer (a traceback in
    the CLI, an internal error retried three times in a job)."""
    from farfield.core.constants import TOL
    from farfield.core.errors import LayerPlanError, error_kind
    from farfield.core.procedural import box_object
    from farfield.core.render.context import largest_target_side
    from farfield.core.techniques.layered import BakeOptions, bake_layered

    scene = Scene.from_objects([box_object("wall", [-20.0, -1.0, 2.0], [20.0, 1.0, 3.0])], "wall")
    cell = BoxCell([-0.01] * 3, [0.01] * 3)
    plan = plan_layers(cell, scene.bounds, math.radians(45), 512, "min", texel_share=0.7)
    assert largest_target_side(ctx) < max(plan.texture_resolution) <= TOL.max_texture_resolution
    with pytest.raises(LayerPlanError, match="larger than this renderer draws") as caught:
        bake_layered(scene, cell, BakeOptions())
    assert error_kind(caught.value).exit_code == 2 and error_kind(caught.value).http_status == 422


def test_a_slab_border_at_or_behind_the_eye_is_refused():
    eye = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 2.0]])
    with pytest.raises(ValueError, match="in front of the eye"):
        slab_instances(eye, np.array([[0, 1, 2]]), np.array([0.0, 1.5, 2.5]), np.ones(2), np.array([4, 4]))


def _reaching(eye, faces, borders, half_tan, resolution, triangles: np.ndarray) -> set:
    """(triangle, layer) pairs whose piece clipped to the layer's slab reaches a texel, every
    layer tried, as ``slab_instances`` decides it but without dropping anything first."""
    k = borders.shape[0] - 1
    tri, layer = np.repeat(triangles, k), np.tile(np.arange(k), triangles.shape[0])
    polygon, count = clip_to_slab(np.take(eye.T, faces[tri].T, axis=1), borders[layer], borders[layer + 1])
    with np.errstate(divide="ignore", invalid="ignore"):  # pairs that miss their slab have no polygon
        polygon = texel_coordinates(polygon, half_tan, resolution)
        rect = texel_rectangles(polygon.min(axis=1), polygon.max(axis=1), resolution)
    keep = (count > 0) & (rect[0] < rect[2]) & (rect[1] < rect[3])
    return set(zip(tri[keep].tolist(), layer[keep].tolist()))


def test_recording_is_deterministic(ctx):
    scene = forest(count=8)
    plan = plan_layers(BoxCell.from_center([0, 0, 0], 10.0), scene.bounds, math.radians(45), 128)
    a = record_layers(scene, plan).rgba
    b = record_layers(scene, plan).rgba
    np.testing.assert_array_equal(a, b)


def _depth_fraction(z: np.ndarray, t: float, closed: bool) -> float:
    """Fraction of a triangle's area with depth <= t (closed) or < t, from its corner depths z (3,).

    Depth is linear over the triangle, so the fraction is piecewise quadratic in t; independent of
    any clipping code.
    """
    z0, z1, z2 = np.sort(z)
    if (t >= z2) if closed else (t > z2):
        return 1.0
    if (t < z0) if closed else (t <= z0):
        return 0.0
    if t <= z1:
        return 0.0 if t <= z0 else (t - z0) ** 2 / ((z2 - z0) * (z1 - z0))
    return 1.0 - (z2 - t) ** 2 / ((z2 - z0) * (z2 - z1))


def test_slab_clipping_keeps_exactly_the_part_of_each_triangle_inside_the_closed_slab():
    rng = np.random.default_rng(7)
    n = 600
    tri = rng.uniform(-5.0, 5.0, (n, 3, 3))
    tri[..., 2] = rng.uniform(1.0, 10.0, (n, 3))
    near = rng.uniform(1.0, 9.0, n)
    far = near + rng.choice([0.0, 0.3, 2.0, 8.0], n)
    # Corners exactly on a border (some triangles get an edge in a border plane).
    snap = rng.random((n, 3)) < 0.15
    border = np.where(rng.random((n, 3)) < 0.5, near[:, None], far[:, None])
    tri[..., 2] = np.where(snap, border, tri[..., 2])
    polygon, count = clip_to_slab(tri.transpose(2, 1, 0), near, far)
    polygon = polygon.transpose(2, 1, 0)  # (n, 5, 3)
    z = tri[..., 2]
    np.testing.assert_array_equal(count == 0, (z.max(axis=1) < near) | (z.min(axis=1) > far))
    assert count.max() <= 5
    samples = rng.dirichlet(np.ones(3), 400)  # (s, 3) barycentric points
    for i in range(n):
        a, b, c = tri[i]
        area = 0.5 * np.linalg.norm(np.cross(b - a, c - a))
        expected = area * (_depth_fraction(z[i], far[i], True) - _depth_fraction(z[i], near[i], False))
        p = polygon[i, : count[i]]
        if count[i] == 0:
            assert expected == 0.0
            continue
        assert np.all((p[:, 2] >= near[i]) & (p[:, 2] <= far[i])), "polygon leaves the closed slab"
        # Every vertex lies on the triangle: its barycentric coordinates are >= 0 and sum to 1.
        basis = np.stack([b - a, c - a], axis=1)
        uv = np.linalg.lstsq(basis, (p - a).T, rcond=None)[0]
        assert np.all(uv >= -1e-9) and np.all(uv.sum(axis=0) <= 1 + 1e-9)
        np.testing.assert_allclose(basis @ uv + a[:, None], p.T, atol=1e-9)
        # A convex polygon whose vertices lie in the clipped region and whose area equals the
        # region's (area of a wrongly ordered polygon comes out smaller) is the clipped region.
        got = 0.5 * np.linalg.norm(np.cross(p, np.roll(p, -1, axis=0)).sum(axis=0))
        assert got == pytest.approx(expected, rel=1e-9, abs=1e-9 * area)
        # Sampled points of the triangle inside the slab are inside the polygon (in the plane's
        # coordinates, on the inner side of every edge of non-zero length).
        points = samples @ tri[i]
        inside = points[(points[:, 2] >= near[i]) & (points[:, 2] <= far[i])]
        if inside.size == 0 or got <= 1e-12 * area:
            continue
        q = uv.T  # (m, 2) polygon in the plane's coordinates
        s = np.linalg.lstsq(basis, (inside - a).T, rcond=None)[0].T
        edge = np.roll(q, -1, axis=0) - q
        orientation = np.sign(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1]))
        side = orientation * (edge[:, 0] * (s[:, None, 1] - q[:, 1]) - edge[:, 1] * (s[:, None, 0] - q[:, 0]))
        side = np.where(np.linalg.norm(edge, axis=1) > 1e-12, side, 0.0)
        assert np.all(side >= -1e-9), "a point of the triangle inside the slab lies outside the polygon"


def exact_coverage(scene: Scene, plan) -> np.ndarray:
    """(k, h, w) bool: per layer, the texels whose closed square meets one of the clipped polygons
    of :func:`slab_instances`, by a float64 separating-axis test on the CPU."""
    res_x, res_y = (int(r) for r in plan.texture_resolution)
    borders = plan.borders + plan.reference_offset
    out = np.zeros((plan.count, res_y, res_x), dtype=bool)
    for obj in scene.objects:
        inst = slab_instances(
            eye_coordinates(plan, obj.vertices), obj.faces, borders, plan.frustum_half_tangents, plan.texture_resolution
        )
        layer = np.repeat(np.arange(plan.count), np.diff(inst.offsets))
        x0, y0, x1, y1 = inst.rect
        size = (x1 - x0) * (y1 - y0)
        pair = np.repeat(np.arange(size.shape[0]), size)
        local = np.arange(size.sum()) - np.repeat(np.cumsum(size) - size, size)
        tx = x0[pair] + local % (x1 - x0)[pair]
        ty = y0[pair] + local // (x1 - x0)[pair]
        centre = np.stack([tx + 0.5, ty + 0.5], axis=1)
        poly = inst.polygon.transpose(2, 1, 0)[pair]  # (m, 5, 2); unused slots repeat vertex 0
        count = inst.count[pair]
        hit = np.all((poly.min(axis=1) <= centre + 0.5) & (poly.max(axis=1) >= centre - 0.5), axis=1)
        for i in range(5):
            edge = poly[np.arange(pair.shape[0]), (i + 1) % count] - poly[:, i]
            normal = np.stack([-edge[:, 1], edge[:, 0]], axis=1)
            length = np.linalg.norm(normal, axis=1)
            active = (i < count) & (length > 0)
            normal /= np.where(active, length, 1.0)[:, None]
            along = np.einsum("mk,mjk->mj", normal, poly)
            reach = 0.5 * np.abs(normal).sum(axis=1)
            at = np.einsum("mk,mk->m", normal, centre)
            hit &= ~(active & ((at - reach > along.max(axis=1)) | (at + reach < along.min(axis=1))))
        out[layer[pair[hit]], ty[hit], tx[hit]] = True
    return out


def test_every_layer_holds_the_texels_its_clipped_triangles_touch(ctx):
    """Exact per-layer coverage, far clipping edges included (their texels take the far border's
    depth, which must not lose against the cleared depth buffer)."""
    scene = forest(count=12)
    ground = trimesh.creation.box(extents=[40.0, 30.0, 0.01])
    ground.apply_transform(trimesh.transformations.rotation_matrix(0.3, [0, 1, 0]))
    ground.apply_translation([70.0, 0.0, -4.0])
    plane = SceneObject(name="ground", vertices=ground.vertices, faces=ground.faces)
    scene = Scene.from_objects([*scene.objects, plane], "mix")
    plan = plan_layers(BoxCell.from_center([0, 0, 0], 10.0), scene.bounds, math.radians(45), 128)
    recorded = record_layers(scene, plan).coverage
    truth = exact_coverage(scene, plan)
    assert ctx.error == "GL_NO_ERROR"
    assert truth.sum() > 1000
    missing = np.argwhere(truth & ~recorded)
    assert missing.size == 0, f"{len(missing)} touched texels not written, e.g. (layer, y, x) {missing[:5].tolist()}"
    # The shader's 1e-4 texel slack may add a texel where a polygon all but touches it; no more.
    assert np.sum(recorded & ~truth) <= 1e-3 * truth.sum()


def test_recording_at_continental_offsets_matches_the_same_part_at_the_origin(ctx):
    """A part and its view cell 5,000 km from the origin record exactly as they do at the origin."""
    sphere = trimesh.creation.icosphere(subdivisions=3, radius=6.0)
    sphere.apply_translation([300.0, 25.0, 4.0])
    objects = [*forest(count=10).objects, SceneObject(name="dome", vertices=sphere.vertices, faces=sphere.faces)]
    offset = np.array([4e6, -3e6, 1e3])
    moved = [SceneObject(name=o.name, vertices=o.vertices + offset, faces=o.faces) for o in objects]
    here, there = Scene.from_objects(objects, "here"), Scene.from_objects(moved, "there")
    fov = math.radians(45)
    plan = plan_layers(BoxCell.from_center([0, 0, 0], 10.0), here.bounds, fov, 256)
    moved_plan = plan_layers(BoxCell.from_center(offset, 10.0), there.bounds, fov, 256)
    assert moved_plan.count == plan.count
    np.testing.assert_array_equal(moved_plan.texture_resolution, plan.texture_resolution)
    a = record_layers(here, plan).coverage
    b = record_layers(there, moved_plan).coverage
    assert ctx.error == "GL_NO_ERROR"
    assert a.sum() > 500
    np.testing.assert_array_equal(a, b)


def _bilinear_alpha(texture: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """(n,) alpha of ``texture`` (h, w, 4) uint8, top row first, at ``uv`` (n, 2) as GL_LINEAR with
    GL_REPEAT samples it (v up, texel centres at half-integers)."""
    alpha = texture[::-1, :, 3].astype(np.float64) / 255.0
    h, w = alpha.shape
    q = uv * (w, h) - 0.5
    i, j = np.floor(q).astype(np.int64).T
    fx, fy = (q - np.floor(q)).T

    def at(di, dj):
        return alpha[(j + dj) % h, (i + di) % w]

    return (1 - fy) * ((1 - fx) * at(0, 0) + fx * at(1, 0)) + fy * ((1 - fx) * at(0, 1) + fx * at(1, 1))


@pytest.mark.parametrize("size", [8, 128])
def test_alpha_cut_keeps_exactly_the_texels_where_filtered_alpha_passes_the_cut(size, ctx):
    """A quad facing the reference viewpoint with a random alpha texture, magnified (8 texels) and
    about 1:1 (128 texels): the layer holds a texel exactly where the filtered alpha reaches the cut
    somewhere on the quad's part of its square, not where a neighbour's opaque texel merely lies
    within reach.  The quad is parallel to the layer and axis-aligned, so a texel's part of it is a
    rectangle in texture space, on which the filter, linear along each axis between texel centres,
    is largest at a corner, where an edge crosses a line of texel centres, or at a centre."""
    rng = np.random.default_rng(7)
    texture = np.zeros((size, size, 4), dtype=np.uint8)
    texture[..., :3] = 200
    texture[..., 3] = rng.choice(np.array([0, 0, 0, 96, 160, 255], dtype=np.uint8), size=(size, size))
    half = 4.0
    vertices = np.array([[-half, -half, 0.0], [half, -half, 0.0], [half, half, 0.0], [-half, half, 0.0]])
    quad = SceneObject(
        "card",
        vertices,
        np.array([[0, 1, 2], [0, 2, 3]]),
        uv=(vertices[:, :2] + half) / (2 * half),
        texture=texture,
        alpha_cutoff=0.5,
    )
    scene = Scene.from_objects([quad], "card")
    plan = plan_layers(BoxCell.from_center([0.0, 0.0, -60.0], 2.0), scene.bounds, math.radians(45), 384)
    assert plan.count == 1
    kept = record_layers(scene, plan).coverage[0]  # GL rows: row 0 at the bottom
    res = plan.texture_resolution
    frame = np.stack([plan.u, plan.v, plan.axis])
    depth = float(-plan.reference_viewpoint @ plan.axis)  # of the plane z = 0, parallel to the layer

    def uv_at(tx, ty):  # texel coordinates -> uv on the plane z = 0
        eye = np.stack(
            [
                (tx / res[0] * 2 - 1) * plan.frustum_half_tangents[0] * depth,
                (ty / res[1] * 2 - 1) * plan.frustum_half_tangents[1] * depth,
                np.full(np.shape(tx), depth),
            ],
            -1,
        )
        return ((plan.reference_viewpoint + eye @ frame)[..., :2] + half) / (2 * half)

    ty, tx = np.indices(kept.shape).astype(np.float64)
    a, b = uv_at(tx, ty), uv_at(tx + 1, ty + 1)
    lo, hi = np.clip(np.minimum(a, b), 0.0, 1.0), np.clip(np.maximum(a, b), 0.0, 1.0)
    best = np.zeros(kept.shape)
    for index in zip(*np.nonzero(np.all(hi > lo, axis=-1))):
        axes = []
        for k in range(2):
            centres = (np.arange(size) + 0.5) / size
            axes.append(
                np.concatenate(
                    [[lo[index][k], hi[index][k]], centres[(centres > lo[index][k]) & (centres < hi[index][k])]]
                )
            )
        u, v = np.meshgrid(*axes)
        best[index] = _bilinear_alpha(texture, np.column_stack([u.ravel(), v.ravel()])).max()
    sure = np.abs(best - 0.5) > 0.01
    assert (best >= 0.5).sum() > 100 and (best < 0.5).sum() > 100
    np.testing.assert_array_equal(kept[sure], (best >= 0.5)[sure])

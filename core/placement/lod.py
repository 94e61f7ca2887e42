"""Simplified geometry as a placement candidate: QEM levels of detail of an element (issue 57, item 3).

Seed 000 §2.2.3 surveys geometric simplification (the quadric error metric of Garland and Heckbert,
[Garl97], "most widely used today") and §1.5.2 asks that impostor placement combine with visibility
culling and geometric simplification; the thesis's placement (ch. 5) chooses impostors only.  Here a node of the
object hierarchy (its elements' merged mesh, equal positions welded; its open border kept where it
holds some but not all clusters of a split object, so that it meets its neighbours without a crack,
:func:`keeps_border`) gets a chain of levels from a maintained quadric-error simplifier (``fast-simplification``, Garland and Heckbert's QEM as in
Sven Forstmann's Fast-Quadric-Mesh-Simplification), each level a quarter of the previous one's
triangles, each simplified from the one before.

**Error.**  The simplifier does not report its error, so each level measures it, both ways: the
farthest any vertex of the full mesh lies from the simplified surface, and the farthest a point of
the simplified surface (its vertices and, on each triangle, a barycentric grid spaced at the full
mesh's median edge length) lies from the full surface (:class:`MeshError`).  Each point's distance
is first bounded above by the triangles around the vertex it was collapsed into (or, back to the
full mesh, its nearest full vertex) and, full to simplified, the eight triangles of nearest centroids
(``scipy.spatial.cKDTree``) (the collapses are replayed, ``fast_simplification.replay_simplification``,
and the mappings of the chain composed; point-triangle distances after Ericson's *Real-Time
Collision Detection* §5.1.5, in numba); then, in falling order of bound while a bound exceeds the
farthest distance found so far, measured against every triangle that can hold its nearest point:
those whose bounding box lies within its bound, listed by a uniform grid of the triangles' bounding
boxes (about one cell a triangle), one point after another in numba, a point left as soon as a
triangle lies no farther than the farthest found (it cannot raise it).  The result is the largest
of the points' exact distances whatever the bounds and the order, so the grid (since 2026-12-07;
before, a ball of centroids within the bound plus the farthest a corner lies from its centroid, its
triangles listed in Python: 59 M of them, most of the planning time on downtown) changed no level's
error.
The bound alone was loose (3.4-6.4x the measured distance on a park statue's 81,920- to
1,280-triangle levels: a few vertices whose nearest triangle is neither around their simplified
vertex nor among the eight), and a level's error sets how near it may be drawn; one side alone
missed the simplifier's spikes (a statue's simplified vertex 26.7 mm off the full surface, whose
full vertices all lie within 2.2 mm of the level).  The surfaces are sampled, so it is the samples'
distance, not that of every point between them: the tests compare images against the full scene.

**Spikes.**  The simplifier now and then places a vertex well off the surface (a statue's level
of 81,920 triangles had one 26.7 mm off, its full vertices all within 2.2 mm of the level), and
the next levels, simplified from it, keep it.  So each level's vertices that lie farther from the
full surface than any full vertex lies from the level are moved to their nearest point on the full
surface (:meth:`MeshError.spikes_moved`) before the level is measured and the next one simplified
from it; the runtime's rebuild (:func:`level_for`) moves the same vertices.

**Where a level may be drawn.**  A displacement ``e`` seen from at least ``d`` away spans at most
``e / d`` radians; held to the impostors' pixel budget ``max_error_px`` (seed 000 §3.3's budget, the
technique's option) at the output resolution and field of view, with the smallest pixel angle of
the image (:func:`farfield.core.pixel_angles.pixel_angle`), a level serves every problem view whose
region's nearest point is at least ``d = e / (max_error_px * pixel_angle)`` from the node's bounds.
Its recorded view cell is the outside of the sphere of radius ``d`` around the node's centre
(:class:`~farfield.core.viewcells.SphereOutsideCell`): it holds every view the level serves, but
also views nearer than ``d`` to the bounds where the level is not within the budget; no
:mod:`farfield.core.viewcells` kind is "beyond a distance from a box", and a runtime draws a level
only in the problem views it was chosen for.

**Memory** is the level's vertex and index bytes as the reference runtime uploads them
(:func:`farfield.core.render.raster.upload`: no normals, the colour pass is unlit): per vertex
a float32 position and a float32 RGBA colour (28 bytes), per triangle three uint32 indices (12
bytes).  (A leaner runtime would store 16 bytes a vertex, an RGBA8 colour, and uint16 indices under
65,536 vertices; this model charges what the reference runtime holds.)
**Time** is the cost model's for geometry: one draw call, the level's triangles and the node's
pixels in the CPV (:meth:`farfield.core.placement.cost_model.CostModel.geometry_time`).

Colour: the simplified mesh carries per-vertex colours, each the mean of the full mesh's vertices
collapsed into it (an object's vertex colours, else its base colour; a texture is reduced to its
mean colour: a weakness for textured scenes).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from farfield.core.colour_space import linear_to_srgb, srgb_to_linear
from farfield.core.pixel_angles import pixel_angle
from farfield.core.scene import Scene, SceneObject
from farfield.core.viewcells import SphereOutsideCell

LOD_TECHNIQUE = "lod"  # what a placement's entry of simplified geometry names as its technique
VERTEX_BYTES = 28  # float32 position and float32 RGBA colour (the reference runtime's upload)
TRIANGLE_BYTES = 12  # three uint32 indices
REDUCTION = 0.75  # each level keeps a quarter of the previous one's triangles
MIN_TRIANGLES = 256  # a node with fewer triangles gets no level of detail
# A node of several elements with more triangles than this gets none either: every node up to the
# root would be simplified (and measured) again, the whole scene once per level of the hierarchy.
MAX_NODE_TRIANGLES = 1 << 13
FLOOR_TRIANGLES = 32  # the chain stops below this many triangles
NEAR_TRIANGLES = 8  # triangles of nearest centroids searched besides the fan (error bound)
MAX_STEPS = 256  # the finest grid of samples on a simplified triangle (error, back to the full mesh)


@dataclass(frozen=True, slots=True, eq=False)
class LodLevel:
    """One level of detail of a node's mesh: its vertices, triangles and per-vertex colours, and
    ``error`` (world units): a bound of the farthest a full-mesh vertex lies from its surface."""

    level: int  # 1: the first simplification
    vertices: np.ndarray  # (v, 3) float64
    faces: np.ndarray  # (t, 3) int64
    colours: np.ndarray  # (v, 4) uint8, RGB sRGB-encoded
    error: float

    @property
    def triangles(self) -> int:
        return int(self.faces.shape[0])

    @property
    def memory_bytes(self) -> int:
        """Vertex and index bytes (module docstring)."""
        return VERTEX_BYTES * int(self.vertices.shape[0]) + TRIANGLE_BYTES * self.triangles

    def distance(self, fov: float, resolution: int, max_error_px: float) -> float:
        """The nearest distance from the node's bounds at which this level is within ``max_error_px``
        (module docstring)."""
        return self.error / (max_error_px * pixel_angle(fov, resolution, "min"))

    def scene_object(self, name: str) -> SceneObject:
        """The level as a scene object (vertex-coloured) for a renderer."""
        return SceneObject(name, self.vertices, self.faces, vertex_colors=self.colours)


def _object_colours(obj: SceneObject) -> np.ndarray:
    """(v, 4) uint8 sRGB colour of each vertex of ``obj`` (module docstring)."""
    n = obj.vertices.shape[0]
    if obj.vertex_colors is not None:
        return np.asarray(obj.vertex_colors, dtype=np.uint8)
    linear = np.asarray(obj.base_color, dtype=np.float64).copy()
    if obj.texture is not None:  # its mean colour (decoded), times the factor
        texel = np.asarray(obj.texture, dtype=np.float64).reshape(-1, 4) / 255.0
        linear[:3] *= srgb_to_linear(texel[:, :3]).mean(axis=0)
        linear[3] *= texel[:, 3].mean()
    rgba = np.concatenate([np.asarray(linear_to_srgb(np.clip(linear[:3], 0.0, 1.0))), np.clip(linear[3:], 0.0, 1.0)])
    return np.broadcast_to(np.round(255.0 * rgba).astype(np.uint8), (n, 4)).copy()


def node_mesh(scene: Scene) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(vertices, faces, colours) of every object of ``scene`` merged, vertices of equal position
    welded (the first one's colour kept), so that the simplifier sees connected surfaces."""
    vertices, faces, colours, offset = [], [], [], 0
    for obj in scene.objects:
        vertices.append(np.asarray(obj.vertices, dtype=np.float64))
        faces.append(np.asarray(obj.faces, dtype=np.int64) + offset)
        colours.append(_object_colours(obj))
        offset += obj.vertices.shape[0]
    v, f, c = np.concatenate(vertices), np.concatenate(faces), np.concatenate(colours)
    _, first, inverse = np.unique(v, axis=0, return_index=True, return_inverse=True)
    order = np.argsort(first, kind="stable")  # welded vertices in order of first appearance
    slot = np.empty(first.size, dtype=np.int64)
    slot[order] = np.arange(first.size)
    return v[first[order]], slot[inverse.reshape(-1)][f], c[first[order]]


def lod_chain(
    vertices: np.ndarray,
    faces: np.ndarray,
    colours: np.ndarray,
    keep_border: bool = False,
    measure: bool = True,
    levels: int | None = None,
) -> list[LodLevel]:
    """The levels of detail of a mesh, finest first (module docstring); [] below ``MIN_TRIANGLES``.
    A triangle of no area that the simplifier leaves is measured by its edges (:func:`_degenerate_uv`);
    a level whose replay drops a full-mesh vertex ends the chain.
    ``keep_border``: no edge at an open border collapses (a cluster of a split object, whose cut
    edges meet its neighbours' drawn at full detail or at another level: no crack between them).
    ``measure`` False: no level's error is measured (NaN; a runtime drawing a chosen level needs
    none; its spikes are still found and moved, as the planner's were); ``levels``: at most this
    many, the first."""
    import fast_simplification

    if faces.shape[0] < MIN_TRIANGLES:
        return []
    full = np.asarray(vertices, dtype=np.float64)
    points, tris = full, np.ascontiguousarray(faces, dtype=np.int64)
    errors = MeshError(full, tris)
    owner = np.arange(full.shape[0])  # full-mesh vertex -> vertex of the current level
    out: list[LodLevel] = []
    while tris.shape[0] >= 4 * FLOOR_TRIANGLES and (levels is None or len(out) < levels):
        _, _, collapses = fast_simplification.simplify(
            points, tris, target_reduction=REDUCTION, return_collapses=True, preserve_border=keep_border
        )
        points_next, tris_next, mapping = fast_simplification.replay_simplification(
            points, tris.astype(np.int32), collapses
        )
        tris_next = np.asarray(tris_next, dtype=np.int64)
        if tris_next.shape[0] == 0 or tris_next.shape[0] >= tris.shape[0]:
            break
        owner = np.asarray(mapping, dtype=np.int64)[owner]
        if np.any(owner < 0):  # a full-mesh vertex the replay dropped: not a level
            break
        points = np.asarray(points_next, dtype=np.float64)
        count = np.bincount(owner, minlength=points.shape[0]).astype(np.float64)
        mean = np.stack(
            [np.bincount(owner, weights=colours[:, k], minlength=points.shape[0]) for k in range(4)], axis=1
        )
        shade = np.round(mean / np.maximum(count, 1.0)[:, None]).astype(np.uint8)
        used, tris = np.unique(tris_next, return_inverse=True)  # drop vertices no triangle uses
        tris = tris.reshape(-1, 3)
        remap = np.full(points.shape[0], -1, dtype=np.int64)
        remap[used] = np.arange(used.size)
        points, shade = points[used], shade[used]
        owner = remap[owner]
        if np.any(owner < 0):  # a full-mesh vertex collapsed into a vertex no triangle keeps: not a level
            break
        points, forward = errors.spikes_moved(owner, points, tris)
        error = errors.of(owner, points, tris, forward) if measure else math.nan
        out.append(LodLevel(len(out) + 1, points, tris, shade, error))
    return out


def _surface_samples(points: np.ndarray, tris: np.ndarray, spacing: float) -> np.ndarray:
    """Points of the surface ``points``, ``tris`` about ``spacing`` apart: its vertices and, on each
    triangle, the points of a barycentric grid of ``ceil(longest edge / spacing)`` steps a side."""
    corners = points[tris]
    longest = np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2).max(axis=1)
    steps = np.clip(np.ceil(longest / spacing), 1, MAX_STEPS).astype(np.int64)
    out = [points]
    for n in np.unique(steps[steps > 1]):
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        inner = (i + j <= n) & (i < n) & (j < n) & (i + j > 0)  # the corners are the vertices
        a, b = i[inner] / n, j[inner] / n
        weights = np.stack([a, b, 1.0 - a - b], axis=1)  # (p, 3)
        out.append(np.einsum("pk,tkc->tpc", weights, corners[steps == n]).reshape(-1, 3))
    return np.concatenate(out)


@njit(cache=True, nogil=True)
def _triangle_uv(p, a, b, c):
    """(u, v): the point of triangle ``abc`` ((3,) each) nearest ``p`` is ``a + u (b - a) + v (c - a)``
    (Ericson, *Real-Time Collision Detection*, §5.1.5), in scalars (no temporaries)."""
    abx, aby, abz = b[0] - a[0], b[1] - a[1], b[2] - a[2]
    acx, acy, acz = c[0] - a[0], c[1] - a[1], c[2] - a[2]
    ab2, ac2, abac = (
        abx * abx + aby * aby + abz * abz,
        acx * acx + acy * acy + acz * acz,
        abx * acx + aby * acy + abz * acz,
    )
    if ab2 * ac2 - abac * abac <= 1e-12 * ab2 * ac2:  # |ab x ac|^2: no area (a simplifier leaves such now and then)
        return _degenerate_uv(p, a, b, c)
    apx, apy, apz = p[0] - a[0], p[1] - a[1], p[2] - a[2]
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    bpx, bpy, bpz = p[0] - b[0], p[1] - b[1], p[2] - b[2]
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    cpx, cpy, cpz = p[0] - c[0], p[1] - c[1], p[2] - c[2]
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    vc, vb, va = d1 * d4 - d3 * d2, d5 * d2 - d1 * d6, d3 * d6 - d5 * d4
    u, v = 0.0, 0.0  # the closest point a + u ab + v ac
    if d1 <= 0.0 and d2 <= 0.0:
        pass
    elif d3 >= 0.0 and d4 <= d3:
        u = 1.0
    elif vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        u = d1 / (d1 - d3)
    elif d6 >= 0.0 and d5 <= d6:
        v = 1.0
    elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        v = d2 / (d2 - d6)
    elif va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        u, v = 1.0 - w, w
    else:
        denom = 1.0 / (va + vb + vc)
        u, v = vb * denom, vc * denom
    return u, v


@njit(cache=True, nogil=True)
def _degenerate_uv(p, a, b, c):
    """(u, v) of :func:`_triangle_uv` for a triangle of zero area (collinear or coincident
    corners, which a simplifier leaves now and then): the nearest point of its edges ab, ac, bc."""
    best, bu, bv = np.inf, 0.0, 0.0
    for k in range(3):  # edge from s to e; the point s + t (e - s) as (u, v)
        s = a if k < 2 else b
        e = b if k == 0 else c
        ex, ey, ez = e[0] - s[0], e[1] - s[1], e[2] - s[2]
        length2 = ex * ex + ey * ey + ez * ez
        t = 0.0
        if length2 > 0.0:
            t = min(1.0, max(0.0, ((p[0] - s[0]) * ex + (p[1] - s[1]) * ey + (p[2] - s[2]) * ez) / length2))
        dx, dy, dz = p[0] - s[0] - t * ex, p[1] - s[1] - t * ey, p[2] - s[2] - t * ez
        d = dx * dx + dy * dy + dz * dz
        if d < best:
            best = d
            if k == 0:
                bu, bv = t, 0.0
            elif k == 1:
                bu, bv = 0.0, t
            else:
                bu, bv = 1.0 - t, t
    return bu, bv


@njit(cache=True, nogil=True)
def _point_triangle(p, a, b, c) -> float:
    """Distance from point ``p`` to triangle ``abc`` ((3,) each)."""
    u, v = _triangle_uv(p, a, b, c)
    dx = p[0] - a[0] - u * (b[0] - a[0]) - v * (c[0] - a[0])
    dy = p[1] - a[1] - u * (b[1] - a[1]) - v * (c[1] - a[1])
    dz = p[2] - a[2] - u * (b[2] - a[2]) - v * (c[2] - a[2])
    return math.sqrt(dx * dx + dy * dy + dz * dz)


@njit(cache=True, nogil=True)
def _closest_points(at, which, points, tris, offsets, found) -> np.ndarray:
    """(k, 3): per point ``at[which[j]]``, its nearest point on the nearest of the triangles
    ``found[offsets[j]:offsets[j + 1]]``."""
    out = np.empty((which.shape[0], 3))
    for j in range(which.shape[0]):
        p = at[which[j]]
        best, near = np.inf, found[offsets[j]]
        for k in range(offsets[j], offsets[j + 1]):
            t = found[k]
            d = _point_triangle(p, points[tris[t, 0]], points[tris[t, 1]], points[tris[t, 2]])
            if d < best:
                best, near = d, t
        a, b, c = points[tris[near, 0]], points[tris[near, 1]], points[tris[near, 2]]
        u, v = _triangle_uv(p, a, b, c)
        for x in range(3):
            out[j, x] = a[x] + u * (b[x] - a[x]) + v * (c[x] - a[x])
    return out


@njit(cache=True, nogil=True)
def _fan_bounds(full, owner, points, tris, starts, fan, near) -> np.ndarray:
    """Per vertex of ``full``: its distance to the nearest of the triangles around
    ``points[owner]`` and the triangles ``near`` (one row per vertex), an upper bound of its
    distance to the surface."""
    out = np.empty(full.shape[0])
    for i in range(full.shape[0]):
        v = owner[i]
        best = np.inf
        for k in range(starts[v], starts[v + 1]):
            t = fan[k]
            best = min(best, _point_triangle(full[i], points[tris[t, 0]], points[tris[t, 1]], points[tris[t, 2]]))
        for t in near[i]:
            best = min(best, _point_triangle(full[i], points[tris[t, 0]], points[tris[t, 1]], points[tris[t, 2]]))
        out[i] = best
    return out


@njit(cache=True, nogil=True)
def _grid_build(points, tris, lo, size, dims):
    """A uniform grid of cells of side ``size`` from ``lo``, ``dims`` cells an axis: per cell
    (x-major) the triangles whose bounding box meets it, as (starts, triangles), and every
    triangle's bounding box (lo, hi)."""
    m = tris.shape[0]
    box_lo, box_hi = np.empty((m, 3)), np.empty((m, 3))
    span = np.empty((m, 6), dtype=np.int64)
    counts = np.zeros(dims[0] * dims[1] * dims[2] + 1, dtype=np.int64)
    for t in range(m):
        for x in range(3):
            a, b, c = points[tris[t, 0], x], points[tris[t, 1], x], points[tris[t, 2], x]
            box_lo[t, x], box_hi[t, x] = min(a, b, c), max(a, b, c)
            span[t, x] = min(max(int((box_lo[t, x] - lo[x]) / size), 0), dims[x] - 1)
            span[t, 3 + x] = min(max(int((box_hi[t, x] - lo[x]) / size), 0), dims[x] - 1)
        for i in range(span[t, 0], span[t, 3] + 1):
            for j in range(span[t, 1], span[t, 4] + 1):
                for k in range(span[t, 2], span[t, 5] + 1):
                    counts[(i * dims[1] + j) * dims[2] + k + 1] += 1
    starts = np.cumsum(counts)
    fill = starts[:-1].copy()
    cell_tris = np.empty(starts[-1], dtype=np.int64)
    for t in range(m):
        for i in range(span[t, 0], span[t, 3] + 1):
            for j in range(span[t, 1], span[t, 4] + 1):
                for k in range(span[t, 2], span[t, 5] + 1):
                    c = (i * dims[1] + j) * dims[2] + k
                    cell_tris[fill[c]] = t
                    fill[c] += 1
    return starts, cell_tris, box_lo, box_hi


@njit(cache=True, nogil=True)
def _grid_farthest(at, falling, bound, points, tris, lo, size, dims, starts, cell_tris, box_lo, box_hi) -> float:
    """The farthest any point ``at[falling[j]]`` lies from the surface, ``falling`` in falling order of
    ``bound`` (an upper bound of each point's distance): each point's distance is the nearest of the
    triangles whose bounding box lies within its bound of it (a superset of those that can hold its
    nearest point: the same minimum as any such superset), stopped once it is no farther than the
    farthest found (it cannot raise it); the points stop at the first bound no larger."""
    m = tris.shape[0]
    stamp = np.full(m, -1, dtype=np.int64)
    worst = 0.0
    for j in range(falling.shape[0]):
        i = falling[j]
        b = bound[i]
        if not b > worst:
            break
        p = at[i]
        reach = b * (1.0 + 1e-9) + 1e-12 * size  # rounding: the bounding triangle itself stays in
        cells = np.empty(6, dtype=np.int64)
        for x in range(3):
            cells[x] = int(min(max((p[x] - reach - lo[x]) / size, 0.0), dims[x] - 1.0))
            cells[3 + x] = int(min(max((p[x] + reach - lo[x]) / size, 0.0), dims[x] - 1.0))
        best = np.inf
        for ci in range(cells[0], cells[3] + 1):
            for cj in range(cells[1], cells[4] + 1):
                for ck in range(cells[2], cells[5] + 1):
                    c = (ci * dims[1] + cj) * dims[2] + ck
                    for k in range(starts[c], starts[c + 1]):
                        t = cell_tris[k]
                        if stamp[t] == j:
                            continue
                        stamp[t] = j
                        if (
                            p[0] < box_lo[t, 0] - reach
                            or p[0] > box_hi[t, 0] + reach
                            or p[1] < box_lo[t, 1] - reach
                            or p[1] > box_hi[t, 1] + reach
                            or p[2] < box_lo[t, 2] - reach
                            or p[2] > box_hi[t, 2] + reach
                        ):
                            continue
                        best = min(best, _point_triangle(p, points[tris[t, 0]], points[tris[t, 1]], points[tris[t, 2]]))
                        if best <= worst:
                            break
                    if best <= worst:
                        break
                if best <= worst:
                    break
            if best <= worst:
                break
        if best == np.inf:  # no box within the bound (cannot happen but by rounding): every triangle
            for t in range(m):
                best = min(best, _point_triangle(p, points[tris[t, 0]], points[tris[t, 1]], points[tris[t, 2]]))
        worst = max(worst, best)
    return worst


class _Surface:
    """A triangle mesh to measure distances to (module docstring, *Error*): the triangles around each
    vertex, a tree of the triangles' centroids, the farthest a corner lies from its centroid and, when first
    needed, a grid of the triangles' bounding boxes (:meth:`_grid`)."""

    def __init__(self, points: np.ndarray, tris: np.ndarray) -> None:
        self.points, self.tris = points, np.ascontiguousarray(tris, dtype=np.int64)
        corner = self.tris.reshape(-1)
        order = np.argsort(corner, kind="stable")
        self.starts = np.searchsorted(corner[order], np.arange(points.shape[0] + 1))
        self.fan = order // 3  # the triangles around each vertex, vertex by vertex
        centroids = points[self.tris].mean(axis=1)
        self.tree = cKDTree(centroids)
        # A triangle lies within ``reach`` of its centroid, so a point's nearest triangle (no
        # farther than a bound) has its centroid within the bound + reach of it.
        self.reach = float(np.linalg.norm(points[self.tris] - centroids[:, None, :], axis=2).max())
        self._cells = None  # the grid of the exact step (:meth:`_grid`), built when first needed

    def farthest(self, at: np.ndarray, owner: np.ndarray, near: int) -> float:
        """The farthest any point of ``at`` lies from the surface: bounded per point by the
        triangles around vertex ``owner`` of it and the ``near`` of nearest centroids, then, in
        falling order of bound while a bound exceeds the farthest found, measured against every
        triangle whose bounding box lies within its bound (:func:`_grid_farthest`: those that can
        hold its nearest point)."""
        k = min(near, self.tris.shape[0])
        close = (
            self.tree.query(at, k=k)[1].reshape(at.shape[0], k).astype(np.int64)
            if k
            else np.zeros((at.shape[0], 0), dtype=np.int64)
        )
        bound = _fan_bounds(at, owner, self.points, self.tris, self.starts, self.fan, close)
        falling = np.argsort(-bound, kind="stable")
        return _grid_farthest(at, falling, bound, self.points, self.tris, *self._grid())

    def _grid(self):
        """(lo, side, dims, starts, triangles, box lo, box hi) of a uniform grid of the triangles'
        bounding boxes (:func:`_grid_build`), about one cell a triangle, built once."""
        if self._cells is None:
            lo, hi = self.points.min(axis=0), self.points.max(axis=0)
            extent = np.maximum(hi - lo, 1e-9 * max(float((hi - lo).max()), 1e-300))
            size = max(float(np.prod(extent) / self.tris.shape[0]) ** (1.0 / 3.0), float(extent.max()) / 256.0)
            dims = np.minimum(np.floor(extent / size).astype(np.int64) + 1, 256)
            self._cells = (lo, size, dims, *_grid_build(self.points, self.tris, lo, size, dims))
        return self._cells


class MeshError:
    """The error of simplified versions of one full mesh (module docstring, *Error*): the farthest a
    full vertex lies from the simplified surface, or a point of the simplified surface (its vertices
    and its triangles sampled at the full mesh's median edge length) from the full one."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray) -> None:
        self.vertices = np.asarray(vertices, dtype=np.float64)
        faces = np.ascontiguousarray(faces, dtype=np.int64)
        self.surface, self.vertex_tree = _Surface(self.vertices, faces), cKDTree(self.vertices)
        edges = self.vertices[faces] - self.vertices[np.roll(faces, 1, axis=1)]
        self.spacing = float(np.median(np.linalg.norm(edges, axis=2)))

    def spikes_moved(self, owner: np.ndarray, points: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, float]:
        """(``points`` with each vertex farther from the full surface than any full vertex lies from
        the surface ``points``, ``tris`` moved to its nearest point on the full surface (module
        docstring, *Spikes*), that farthest full vertex's distance: NaN where a vertex moved);
        ``owner`` as in :meth:`of`."""
        forward = _Surface(points, tris).farthest(self.vertices, owner, NEAR_TRIANGLES)
        full = self.surface
        hint = self.vertex_tree.query(points)[1].astype(np.int64)
        bound = _fan_bounds(
            points, hint, full.points, full.tris, full.starts, full.fan, np.zeros((points.shape[0], 0), dtype=np.int64)
        )
        which = np.flatnonzero(bound > forward)  # the others lie within ``forward`` of the full surface
        if which.size == 0:
            return points, forward
        lists = full.tree.query_ball_point(points[which], bound[which] + full.reach)
        offsets = np.concatenate([[0], np.cumsum([len(found) for found in lists])]).astype(np.int64)
        found = np.fromiter((t for found in lists for t in found), dtype=np.int64, count=int(offsets[-1]))
        nearest = _closest_points(points, which, full.points, full.tris, offsets, found)
        far = np.linalg.norm(nearest - points[which], axis=1) > forward
        if not far.any():
            return points, forward
        moved = points.copy()
        moved[which[far]] = nearest[far]
        return moved, math.nan

    def of(self, owner: np.ndarray, points: np.ndarray, tris: np.ndarray, forward: float = math.nan) -> float:
        """The error of the surface ``points``, ``tris``; ``owner``: the vertex of ``points`` each
        full vertex was collapsed into (a hint: its triangles are searched first); ``forward``: the
        farthest a full vertex lies from it where known (:meth:`spikes_moved`)."""
        if math.isnan(forward):
            forward = _Surface(points, tris).farthest(
                self.vertices, owner, NEAR_TRIANGLES
            )  # full vertices to the level
        samples = _surface_samples(points, tris, self.spacing)
        hint = self.vertex_tree.query(samples)[1].astype(np.int64)
        return max(forward, self.surface.farthest(samples, hint, 0))  # and the level's points back


class NodeLods:
    """Levels of detail of hierarchy nodes, built when first asked (only nodes some solvable
    problem view sees are asked: :func:`farfield.core.placement.candidates.generate_candidates`),
    and their view cells for output images of ``resolution`` pixels over ``fov`` radians held to
    ``max_error_px``."""

    def __init__(self, scene: Scene, elements, hierarchy, fov: float, resolution: int, max_error_px: float) -> None:
        self.scene, self.elements, self.hierarchy = scene, elements, hierarchy
        self.fov, self.resolution, self.max_error_px = float(fov), int(resolution), float(max_error_px)
        self._chains: dict[int, list[LodLevel]] = {}
        self.built = 0  # nodes simplified

    def cells(self, node: int, bounds: np.ndarray) -> list[tuple[LodLevel, float, SphereOutsideCell]]:
        """(level, the nearest distance from ``bounds`` (2, 3) it may be seen from, its recorded
        cell) of node ``node``, finest first (module docstring)."""
        centre = 0.5 * (bounds[0] + bounds[1])
        out = []
        for level in self.of(node):
            d = level.distance(self.fov, self.resolution, self.max_error_px)
            out.append((level, d, SphereOutsideCell(centre, max(d, 1e-9))))
        return out

    def of(self, node: int) -> list[LodLevel]:
        """The levels of node ``node``: of its elements' merged mesh (as the runtime draws it), its
        open border kept where it holds part of a split object (:func:`keeps_border`); none under
        ``MIN_TRIANGLES`` or, for a node of several elements, over ``MAX_NODE_TRIANGLES``."""
        if node not in self._chains:
            ids = self.hierarchy.elements_of(node)
            triangles = int(self.elements.triangles[ids].sum())
            if triangles < MIN_TRIANGLES or (ids.size > 1 and triangles > MAX_NODE_TRIANGLES):
                self._chains[node] = []
            else:
                part = self.elements.scene_of(self.scene, ids)
                self._chains[node] = lod_chain(*node_mesh(part), keep_border=keeps_border(self.elements, ids))
                self.built += 1
        return self._chains[node]


def keeps_border(elements, ids) -> bool:
    """Whether the level of detail of elements ``ids`` keeps its open border: where one of them is a
    cluster of a split object whose other clusters are not all among them (its cut edges meet
    clusters drawn at full detail or at another level).  A node that holds every cluster of its
    split objects (a whole tower) is simplified as whole objects are."""
    ids = np.asarray(ids, dtype=np.int64).reshape(-1)
    split = np.unique(elements.object_index[[i for i in ids.tolist() if elements.faces[i] is not None]])
    if split.size == 0:
        return False
    return bool(np.any(~np.isin(np.flatnonzero(np.isin(elements.object_index, split)), ids)))


def level_for(scene: Scene, level: int, keep_border: bool = False) -> LodLevel:
    """Level ``level`` (1-based) of the merged mesh of ``scene`` (the element a LOD replaces), as
    the planner built it: the same chain from the same triangles (``keep_border`` for a cluster), up
    to that level and its error not measured (NaN)."""
    chain = lod_chain(*node_mesh(scene), keep_border=keep_border, measure=False, levels=max(int(level), 1))
    if not 1 <= level <= len(chain):
        from farfield.core.placement.hierarchy import PlacementError

        whole = len(lod_chain(*node_mesh(scene), keep_border=keep_border, measure=False))
        raise PlacementError(f"the elements have {whole} levels of detail, not level {level}")
    return chain[level - 1]

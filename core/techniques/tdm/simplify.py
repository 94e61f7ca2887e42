"""numba kernels of the textured depth mesh: triangle-box tests and the voxel-covering simplification.

Seed 003 §6 (seed 000 §4.5).  All edges go into a priority queue by length in the uniform voxel
grid; the shortest is taken, and it is contracted (v2 into v1, or, failing that, v1 into v2) only if

1. the mesh stays a mesh: the contraction keeps the link condition (the two vertices share no
   neighbour but the ones opposite the edge), makes no triangle degenerate and flips none;
2. the boundary neither shrinks nor grows (Figs. 13-14): a boundary vertex is only contracted into
   a boundary vertex along a boundary edge ("contractions involving boundary vertices are only
   allowed towards a boundary vertex"), and the new boundary edge must be covered by the union of
   its intervals inside the enlarged voxel boxes (no empty edge interval), unless the removed vertex
   lies on it (a straight run: the boundary does not change).  farfield adds one rule
   the figures imply but the text does not state: the removed boundary vertex must not be a convex
   corner, neither in 3D (the angles of its triangles at it sum to less than 180 degrees) nor in
   the image from the reference viewpoint (its triangles, projected to the grid's x-y, cover the
   corner the new edge would cut off), unless it lies within (f - 1) / 2 of the new edge; the new
   straight edge would otherwise cut the corner off inside the voxels, a shrink the interval test
   cannot see (measured: up to 15 hole pixels per view at f = 3 without the 3D test; 1 at f = 1 on
   the house at 250 m, 512 px, without the image test, where a corner folded across a depth step
   is convex in the image but not in 3D);
3. every voxel stored with the triangles around the removed vertex meets one of the triangles
   around the kept vertex afterwards (polygon-box test against the voxel's box enlarged by the
   factor f around its centre, but not for the voxels on the part's outline: :func:`box_half_sizes`);
   the voxels are then stored with the triangle that covers them.

After a contraction the edges around the kept vertex are pushed again with their new lengths; an
edge that failed is only reconsidered when it is pushed again that way.  Every voxel stays stored
with a triangle that meets its enlarged box, so after the queue empties every voxel of the initial
field is covered (what ``farfield.core.techniques.tdm.technique`` checks again directly).

Everything is in float64 voxel units.  The triangle-box test is the separating-axis test of
Akenine-Möller (2001): the box's three axes, the triangle's normal and the nine edge cross products.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numba import njit

from farfield.core.cores import usable_cores
from farfield.core.errors import InternalError

EPS = 1e-9

# Outcomes of one contraction attempt (codes returned by the kernel, names for reports and tests).
OK, STALE, NON_MANIFOLD, BOUNDARY_AWAY, BOUNDARY_INTERVAL, FLIP, UNCOVERED = range(7)
OUTCOMES = ("ok", "stale", "non_manifold", "boundary_away", "boundary_interval", "flip", "uncovered")


@njit(cache=True)
def _axis_separates(x0, y0, z0, x1, y1, z1, x2, y2, z2, ax, ay, az, h, hz):
    a = x0 * ax + y0 * ay + z0 * az
    b = x1 * ax + y1 * ay + z1 * az
    c = x2 * ax + y2 * ay + z2 * az
    lo = min(a, min(b, c))
    hi = max(a, max(b, c))
    r = h * (abs(ax) + abs(ay)) + hz * abs(az)
    return lo > r + EPS or hi < -r - EPS


@njit(cache=True)
def _edge_separates(x0, y0, z0, x1, y1, z1, x2, y2, z2, ex, ey, ez, h, hz):
    """Does one of the cross products of the edge (ex, ey, ez) with the box's axes separate?"""
    return (
        _axis_separates(x0, y0, z0, x1, y1, z1, x2, y2, z2, 0.0, -ez, ey, h, hz)
        or _axis_separates(x0, y0, z0, x1, y1, z1, x2, y2, z2, ez, 0.0, -ex, h, hz)
        or _axis_separates(x0, y0, z0, x1, y1, z1, x2, y2, z2, -ey, ex, 0.0, h, hz)
    )


@njit(cache=True)
def tri_box(v0, v1, v2, cx, cy, cz, h):
    """Does the triangle (v0, v1, v2) meet the closed cube of half size ``h`` around (cx, cy, cz)?"""
    return tri_slab(v0, v1, v2, cx, cy, cz, h, h)


@njit(cache=True)
def tri_slab(v0, v1, v2, cx, cy, cz, h, hz):
    """Does the triangle (v0, v1, v2) meet the closed box around (cx, cy, cz) of half size ``h``
    across (x, y) and ``hz`` along the layers?"""
    return _tri_slab(v0[0], v0[1], v0[2], v1[0], v1[1], v1[2], v2[0], v2[1], v2[2], cx, cy, cz, h, hz)


@njit(cache=True)
def _vertex_slab(vertices, a, b, c, cx, cy, cz, h, hz):
    """:func:`tri_slab` for the triangle of vertices a, b and c of ``vertices``."""
    return _tri_slab(vertices[a, 0], vertices[a, 1], vertices[a, 2], vertices[b, 0], vertices[b, 1], vertices[b, 2],
                     vertices[c, 0], vertices[c, 1], vertices[c, 2], cx, cy, cz, h, hz)  # fmt: skip


@njit(cache=True)
def _tri_slab(ax_, ay_, az_, bx_, by_, bz_, qx, qy, qz, cx, cy, cz, h, hz):
    """:func:`tri_slab` on scalars.  The simplification's inner loops pass scalars throughout:
    an array (a view of a row included) costs reference counting, atomic operations that took a
    fifth of its time."""
    x0, y0, z0 = ax_ - cx, ay_ - cy, az_ - cz
    x1, y1, z1 = bx_ - cx, by_ - cy, bz_ - cz
    x2, y2, z2 = qx - cx, qy - cy, qz - cz
    if min(x0, min(x1, x2)) > h + EPS or max(x0, max(x1, x2)) < -h - EPS:
        return False
    if min(y0, min(y1, y2)) > h + EPS or max(y0, max(y1, y2)) < -h - EPS:
        return False
    if min(z0, min(z1, z2)) > hz + EPS or max(z0, max(z1, z2)) < -hz - EPS:
        return False
    ax, ay, az = x1 - x0, y1 - y0, z1 - z0  # e0
    bx, by, bz = x2 - x1, y2 - y1, z2 - z1  # e1
    cx_, cy_, cz_ = x0 - x2, y0 - y2, z0 - z2  # e2
    nx = ay * bz - az * by
    ny = az * bx - ax * bz
    nz = ax * by - ay * bx
    d = nx * x0 + ny * y0 + nz * z0
    r = h * (abs(nx) + abs(ny)) + hz * abs(nz)
    scale = abs(nx) + abs(ny) + abs(nz)
    if abs(d) > r + EPS * max(scale, 1.0):
        return False
    return not (
        _edge_separates(x0, y0, z0, x1, y1, z1, x2, y2, z2, ax, ay, az, h, hz)
        or _edge_separates(x0, y0, z0, x1, y1, z1, x2, y2, z2, bx, by, bz, h, hz)
        or _edge_separates(x0, y0, z0, x1, y1, z1, x2, y2, z2, cx_, cy_, cz_, h, hz)
    )


@njit(cache=True)
def assign_voxels(vertices, triangles, centres, pair_voxel, pair_quad, voxel_count):
    """Per voxel, the first triangle of its (voxel, quad) pairs (quad i = triangles 2i, 2i + 1) that
    meets its unit box; -1 where none does."""
    owner = np.full(voxel_count, -1, dtype=np.int64)
    for p in range(pair_voxel.shape[0]):
        v = pair_voxel[p]
        if owner[v] >= 0:
            continue
        for t in (2 * pair_quad[p], 2 * pair_quad[p] + 1):
            if _vertex_slab(
                vertices,
                triangles[t, 0],
                triangles[t, 1],
                triangles[t, 2],
                centres[v, 0],
                centres[v, 1],
                centres[v, 2],
                0.5,
                0.5,
            ):
                owner[v] = t
                break
    return owner


@njit(cache=True)
def covered_by(vertices, triangles, tri_index, centres, half, voxels):
    """(n,) bool: voxel voxels[i] meets triangle tri_index[i] (boxes of half sizes ``half``, one
    per voxel of the field)."""
    out = np.zeros(voxels.shape[0], dtype=np.bool_)
    for i in range(voxels.shape[0]):
        t, v = tri_index[i], voxels[i]
        out[i] = _vertex_slab(
            vertices,
            triangles[t, 0],
            triangles[t, 1],
            triangles[t, 2],
            centres[v, 0],
            centres[v, 1],
            centres[v, 2],
            half[v, 0],
            half[v, 1],
        )
    return out


@njit(cache=True)
def covered_by_any(vertices, triangles, centres, h):
    """(n,) bool: voxel i's cube (half size ``h``) meets some triangle (every pair tested: for
    checks on small meshes, independent of which triangle stores which voxel)."""
    out = np.zeros(centres.shape[0], dtype=np.bool_)
    for i in range(centres.shape[0]):
        c = centres[i]
        for t in range(triangles.shape[0]):
            tri = triangles[t]
            if tri_box(vertices[tri[0]], vertices[tri[1]], vertices[tri[2]], c[0], c[1], c[2], h):
                out[i] = True
                break
    return out


# ------------------------------------------------------------------------------------------------
# The simplification state: per-vertex triangle lists and per-triangle voxel lists live in pools
# that only grow (a rewritten list is appended; the pool is compacted when full).
# ------------------------------------------------------------------------------------------------


@njit(cache=True)
def _compact(start, length, pool, alive_mask):
    total = 0
    for i in range(start.shape[0]):
        if alive_mask[i]:
            total += length[i]
    fresh = np.empty(max(2 * total + 1024, pool.shape[0] // 2 + 1024), dtype=np.int64)
    top = 0
    for i in range(start.shape[0]):
        if not alive_mask[i]:
            length[i] = 0
            start[i] = 0
            continue
        s = start[i]
        for j in range(length[i]):
            fresh[top + j] = pool[s + j]
        start[i] = top
        top += length[i]
    return fresh, top


@njit(cache=True)
def _reserve(pool, top, extra, start, length, alive_mask):
    """A pool with room for ``extra`` more entries after ``top`` (compacting or growing it)."""
    if top + extra <= pool.shape[0]:
        return pool, top
    pool, top = _compact(start, length, pool, alive_mask)
    if top + extra > pool.shape[0]:
        bigger = np.empty(2 * (top + extra) + 1024, dtype=np.int64)
        bigger[:top] = pool[:top]
        pool = bigger
    return pool, top


@njit(cache=True)
def _heap_push(keys, items, size, key, a, b, va, vb):
    if size >= keys.shape[0]:
        new_keys = np.empty(2 * keys.shape[0] + 16)
        new_items = np.empty((2 * keys.shape[0] + 16, 4), dtype=np.int32)
        new_keys[:size] = keys[:size]
        new_items[:size] = items[:size]
        keys, items = new_keys, new_items
    i = size
    keys[i] = key
    items[i, 0] = a
    items[i, 1] = b
    items[i, 2] = va
    items[i, 3] = vb
    while i > 0:
        parent = (i - 1) // 2
        if keys[parent] <= keys[i]:
            break
        keys[parent], keys[i] = keys[i], keys[parent]
        for c in range(4):
            items[parent, c], items[i, c] = items[i, c], items[parent, c]
        i = parent
    return keys, items, size + 1


@njit(cache=True)
def _heap_pop(keys, items, size):
    a, b, va, vb = np.int64(items[0, 0]), np.int64(items[0, 1]), np.int64(items[0, 2]), np.int64(items[0, 3])
    size -= 1
    keys[0] = keys[size]
    for c in range(4):
        items[0, c] = items[size, c]
    i = 0
    while True:
        left = 2 * i + 1
        if left >= size:
            break
        child = left
        if left + 1 < size and keys[left + 1] < keys[left]:
            child = left + 1
        if keys[i] <= keys[child]:
            break
        keys[child], keys[i] = keys[i], keys[child]
        for c in range(4):
            items[child, c], items[i, c] = items[i, c], items[child, c]
        i = child
    return a, b, va, vb, size


@njit(cache=True)
def _vertex_tris(v, vt_start, vt_len, vt_pool, tri_alive, out):
    n = 0
    s = vt_start[v]
    for j in range(vt_len[v]):
        t = vt_pool[s + j]
        if tri_alive[t]:
            out[n] = t
            n += 1
    return n


@njit(cache=True)
def _neighbours(v, tris, n_tris, triangles, nbr, cnt):
    """Distinct neighbours of ``v`` over its triangles and how many of them share each edge."""
    m = 0
    for i in range(n_tris):
        t = tris[i]
        for c in range(3):
            w = triangles[t, c]
            if w == v:
                continue
            found = -1
            for j in range(m):
                if nbr[j] == w:
                    found = j
                    break
            if found < 0:
                nbr[m] = w
                cnt[m] = 1
                m += 1
            else:
                cnt[found] += 1
    return m


@njit(cache=True)
def _is_boundary(m, cnt):
    for j in range(m):
        if cnt[j] != 2:
            return True
    return False


@njit(cache=True)
def _normal(vertices, a, b, c):
    """The (unnormalised) normal of the triangle of vertices a, b and c, as three scalars."""
    e0x, e0y, e0z = vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1], vertices[b, 2] - vertices[a, 2]
    e1x, e1y, e1z = vertices[c, 0] - vertices[a, 0], vertices[c, 1] - vertices[a, 1], vertices[c, 2] - vertices[a, 2]
    return e0y * e1z - e0z * e1y, e0z * e1x - e0x * e1z, e0x * e1y - e0y * e1x


@njit(cache=True)
def _distance(vertices, a, b):
    """Distance between vertices a and b."""
    return np.sqrt(
        (vertices[a, 0] - vertices[b, 0]) ** 2
        + (vertices[a, 1] - vertices[b, 1]) ** 2
        + (vertices[a, 2] - vertices[b, 2]) ** 2
    )


@njit(cache=True)
def _segment_distance(vertices, p, a, b):
    """Distance from vertex p to the segment between vertices a and b."""
    d0, d1, d2 = vertices[b, 0] - vertices[a, 0], vertices[b, 1] - vertices[a, 1], vertices[b, 2] - vertices[a, 2]
    length2 = d0**2 + d1**2 + d2**2
    t = 0.0
    if length2 > 0.0:
        t = min(
            1.0,
            max(
                0.0,
                (
                    (vertices[p, 0] - vertices[a, 0]) * d0
                    + (vertices[p, 1] - vertices[a, 1]) * d1
                    + (vertices[p, 2] - vertices[a, 2]) * d2
                )
                / length2,
            ),
        )
    e0 = vertices[a, 0] + t * d0 - vertices[p, 0]
    e1 = vertices[a, 1] + t * d1 - vertices[p, 1]
    e2 = vertices[a, 2] + t * d2 - vertices[p, 2]
    return np.sqrt(e0**2 + e1**2 + e2**2)


@njit(cache=True)
def _fan_angle(v, tris, n_tris, triangles, vertices):
    """Sum of the angles at ``v`` of its triangles."""
    total = 0.0
    for i in range(n_tris):
        t = tris[i]
        k = 0
        while triangles[t, k] != v:
            k += 1
        p, q = triangles[t, (k + 1) % 3], triangles[t, (k + 2) % 3]
        a0, a1, a2 = vertices[p, 0] - vertices[v, 0], vertices[p, 1] - vertices[v, 1], vertices[p, 2] - vertices[v, 2]
        b0, b1, b2 = vertices[q, 0] - vertices[v, 0], vertices[q, 1] - vertices[v, 1], vertices[q, 2] - vertices[v, 2]
        na = np.sqrt(a0**2 + a1**2 + a2**2)
        nb = np.sqrt(b0**2 + b1**2 + b2**2)
        c = (a0 * b0 + a1 * b1 + a2 * b2) / max(na * nb, 1e-300)
        total += np.arccos(min(1.0, max(-1.0, c)))
    return total


@njit(cache=True)
def _inside_cone(e1x, e1y, e2x, e2y, dx, dy):
    """Does direction d point strictly inside the angle (< 180 degrees) between e1 and e2?"""
    c = e1x * e2y - e1y * e2x
    if abs(c) <= 1e-12 * (e1x * e1x + e1y * e1y + e2x * e2x + e2y * e2y):
        return False
    return c * (e1x * dy - e1y * dx) > 0.0 and c * (dx * e2y - dy * e2x) > 0.0


@njit(cache=True)
def _covers_corner(v2, v1, other, tris, n_tris, triangles, vertices):
    """Does the mesh cover, in the image from the reference viewpoint (the grid's x-y projection),
    the corner at ``v2`` that the new boundary edge (v1, other) would cut off: the triangle
    (v1, v2, other) next to v2?  Read from the image projections of v2's own triangles, whichever
    way each faces: contractions that keep the 3D normals may still fold a triangle over in the
    image, so the winding of the triangle on the boundary edge does not tell the mesh's side
    (measured on the house at 250 m, 512 px: read from that winding, the cut corners left 2 texel
    centres of the recording uncovered in the reference image at f = 1 and 15 at f = 2; none read
    this way).  Probed along three directions into the corner near v2."""
    ox, oy = vertices[v2, 0], vertices[v2, 1]
    ux = vertices[v1, 0] - ox
    uy = vertices[v1, 1] - oy
    wx = vertices[other, 0] - ox
    wy = vertices[other, 1] - oy
    nu = np.sqrt(ux * ux + uy * uy)
    nw = np.sqrt(wx * wx + wy * wy)
    if nu <= EPS or nw <= EPS:
        return False  # v2 sits on v1 or other in the image: the boundary's image does not change
    ux, uy, wx, wy = ux / nu, uy / nu, wx / nw, wy / nw
    cross = ux * wy - uy * wx
    if abs(cross) <= 1e-12:
        return ux * wx + uy * wy > 0.0  # a spike: taken as cut off, unprobed; straight: no change
    for k in range(3):
        a = 1.0 + 2.0 * (k == 1)
        b = 1.0 + 2.0 * (k == 2)
        dx = a * ux + b * wx
        dy = a * uy + b * wy
        for i in range(n_tris):
            t = tris[i]
            j = 0
            while triangles[t, j] != v2:
                j += 1
            p, q = triangles[t, (j + 1) % 3], triangles[t, (j + 2) % 3]
            if _inside_cone(vertices[p, 0] - ox, vertices[p, 1] - oy, vertices[q, 0] - ox, vertices[q, 1] - oy, dx, dy):
                return True
    return False


@njit(cache=True)
def _segment_covered(vertices, p, q, centres, half, voxels, n_vox, lo, hi):
    """Is the segment from vertex p to vertex q inside the union of the cubes (half sizes ``half``)
    of voxels[:n_vox]?  The union of the segment's intervals inside each cube must be [0, 1] (seed
    003 Fig. 14)."""
    m = 0
    for i in range(n_vox):
        v = voxels[i]
        t0, t1 = 0.0, 1.0
        empty = False
        for k in range(3):
            r = half[v, 0 if k < 2 else 1]
            a = centres[v, k] - r - EPS
            b = centres[v, k] + r + EPS
            pk = vertices[p, k]
            dk = vertices[q, k] - pk
            if abs(dk) < 1e-15:
                if pk < a or pk > b:
                    empty = True
                    break
            else:
                ta = (a - pk) / dk
                tb = (b - pk) / dk
                if ta > tb:
                    ta, tb = tb, ta
                t0 = max(t0, ta)
                t1 = min(t1, tb)
                if t0 > t1:
                    empty = True
                    break
        if not empty:
            lo[m] = t0
            hi[m] = t1
            m += 1
    if m == 0:
        return False
    order = np.argsort(lo[:m])
    reach = 0.0
    for j in range(m):
        i = order[j]
        if lo[i] > reach + 1e-9:
            return False
        reach = max(reach, hi[i])
    return reach >= 1.0 - 1e-9


@njit(cache=True)
def _attempt(
    v2,
    v1,
    vertices,
    triangles,
    tri_alive,
    vt_start,
    vt_len,
    vt_pool,
    tv_start,
    tv_len,
    tv_pool,
    centres,
    half,
    shrink,
    scratch_t2,
    scratch_t1,
    nbr2,
    cnt2,
    nbr1,
    cnt1,
    vox,
    assign,
    cand,
    lo,
    hi,
    corner,
):
    """Try to contract v2 into v1 (v1 stays); returns (outcome, number of voxels re-stored, the
    vertex besides v2 and v1 whose triangles it read or -1 (v2's other boundary neighbour), whether
    the outcome reads no enlargement factor).  A failure that reads none (a stale edge, a non-manifold
    result, a boundary vertex moved off the boundary, a flip) stands at any larger factor: the
    convex-corner rule before the flip test only lets more through as the factor grows."""
    n2 = _vertex_tris(v2, vt_start, vt_len, vt_pool, tri_alive, scratch_t2)
    n1 = _vertex_tris(v1, vt_start, vt_len, vt_pool, tri_alive, scratch_t1)
    # Triangles on the edge.
    shared = 0
    for i in range(n2):
        t = scratch_t2[i]
        if triangles[t, 0] == v1 or triangles[t, 1] == v1 or triangles[t, 2] == v1:
            shared += 1
    if shared == 0:
        return STALE, 0, -1, True
    if shared > 2:
        return NON_MANIFOLD, 0, -1, True
    m2 = _neighbours(v2, scratch_t2, n2, triangles, nbr2, cnt2)
    m1 = _neighbours(v1, scratch_t1, n1, triangles, nbr1, cnt1)
    common = 0
    for i in range(m2):
        for j in range(m1):
            if nbr2[i] == nbr1[j]:
                common += 1
    if common != shared:
        return NON_MANIFOLD, 0, -1, True
    b2 = _is_boundary(m2, cnt2)
    b1 = _is_boundary(m1, cnt1)
    boundary_edge = shared == 1
    other = -1  # v2's other boundary neighbour when the edge is a boundary edge
    offset = 0.0  # v2's distance from the new boundary edge (v1, other)
    if b2:
        # Seed 003 Fig. 13: a boundary vertex may only go towards a boundary vertex, along the boundary.
        if not b1 or not boundary_edge:
            return BOUNDARY_AWAY, 0, -1, True
        for j in range(m2):
            if cnt2[j] > 2:
                return NON_MANIFOLD, 0, -1, True
            if cnt2[j] == 1 and nbr2[j] != v1:
                if other >= 0:
                    return NON_MANIFOLD, 0, -1, True
                other = nbr2[j]
        if other < 0:
            return NON_MANIFOLD, 0, -1, True
        offset = _segment_distance(vertices, v2, v1, other)
        # No shrinking at convex corners either: the straight edge (v1, other) would cut the corner
        # off.  v2 may go only where the boundary runs straight or bends outwards there, both in 3D
        # (the angles of its triangles at it sum to at least 180 degrees) and in the image (its
        # triangles do not cover the corner the new edge cuts off).
        if offset > shrink and (
            _fan_angle(v2, scratch_t2, n2, triangles, vertices) < np.pi * (1.0 - 1e-9)
            or _covers_corner(v2, v1, other, scratch_t2, n2, triangles, vertices)
        ):
            return BOUNDARY_AWAY, 0, -1, False
    # The triangles after the contraction: v2's (not on the edge) moved onto v1, and v1's own.
    nc = 0
    for i in range(n2):
        t = scratch_t2[i]
        p, q, r = triangles[t, 0], triangles[t, 1], triangles[t, 2]
        if p == v1 or q == v1 or r == v1:
            continue
        bx, by, bz = _normal(vertices, p, q, r)
        ax, ay, az = _normal(vertices, v1 if p == v2 else p, v1 if q == v2 else q, v1 if r == v2 else r)
        if np.sqrt(ax * ax + ay * ay + az * az) < 1e-12 or bx * ax + by * ay + bz * az <= 0.0:
            return FLIP, 0, -1, True
        cand[nc] = t
        nc += 1
    for i in range(n1):
        t = scratch_t1[i]
        if triangles[t, 0] == v2 or triangles[t, 1] == v2 or triangles[t, 2] == v2:
            continue
        cand[nc] = t
        nc += 1
    # The voxels stored with v2's triangles.
    nv = 0
    for i in range(n2):
        t = scratch_t2[i]
        s = tv_start[t]
        for j in range(tv_len[t]):
            vox[nv] = tv_pool[s + j]
            nv += 1
    # Seed 003 Fig. 14: the new boundary edge (v1, other) may not leave the enlarged voxels of the
    # triangles around it (those of v2, v1 and other).
    # Where v2 lies on the straight line between v1 and its other boundary neighbour the boundary
    # does not change: the new edge is the union of the two old ones and covers no new interval.
    # (The old edges may themselves cross empty layers, as the edges of step walls between
    # non-adjacent layers do; testing their union again would keep every vertex of such a run.)
    read = -1  # v2's other boundary neighbour, if its triangles were read
    if b2 and offset > EPS:
        read = other
        extra = nv
        around = np.empty(vt_len[v1] + vt_len[other], dtype=np.int64)
        for vv in (v1, other):
            n_extra = _vertex_tris(vv, vt_start, vt_len, vt_pool, tri_alive, around)
            for i in range(n_extra):
                t = around[i]
                s = tv_start[t]
                for j in range(tv_len[t]):
                    if extra < vox.shape[0]:
                        vox[extra] = tv_pool[s + j]
                        extra += 1
        if not _segment_covered(vertices, v1, other, centres, half, vox, extra, lo, hi):
            return BOUNDARY_INTERVAL, 0, read, False
    # Every voxel must meet a triangle after the contraction (v2 read as v1): the corners of the
    # triangles after it, once.
    for j in range(nc):
        for k in range(3):
            w = triangles[cand[j], k]
            w = v1 if w == v2 else w
            for a in range(3):
                corner[j, 3 * k + a] = vertices[w, a]
    last = 0
    for i in range(nv):
        v = vox[i]
        cx, cy, cz, h, hz = centres[v, 0], centres[v, 1], centres[v, 2], half[v, 0], half[v, 1]
        hit = -1
        for r in range(nc):
            j = (last + r) % nc
            if _tri_slab(corner[j, 0], corner[j, 1], corner[j, 2], corner[j, 3], corner[j, 4], corner[j, 5],
                         corner[j, 6], corner[j, 7], corner[j, 8], cx, cy, cz, h, hz):  # fmt: skip
                hit = j
                break
        if hit < 0:
            return UNCOVERED, 0, read, False
        assign[i] = hit
        last = hit
    return OK, nv, read, False


@njit(cache=True, nogil=True)  # nogil: the strips of :func:`strip_pass` run in threads
def _simplify(
    vertices,
    triangles,
    edge_keys,
    tri_voxel_offsets,
    tri_voxels,
    centres,
    half,
    shrink,
    max_valence,
    touch_before,
    remembered,
    clock,
    new_factor,
    locked,
):
    nv_total = vertices.shape[0]
    nt = triangles.shape[0]
    triangles = triangles.copy()
    tri_alive = np.ones(nt, dtype=np.bool_)
    vert_alive = np.zeros(nv_total, dtype=np.bool_)
    version = np.zeros(nv_total, dtype=np.int64)
    # Vertex -> triangles (CSR into a growable pool).
    vt_len = np.zeros(nv_total, dtype=np.int64)
    for t in range(nt):
        for k in range(3):
            vt_len[triangles[t, k]] += 1
            vert_alive[triangles[t, k]] = True
    vt_start = np.zeros(nv_total, dtype=np.int64)
    acc = 0
    for v in range(nv_total):
        vt_start[v] = acc
        acc += vt_len[v]
    vt_pool = np.empty(2 * acc + 1024, dtype=np.int64)
    fill = vt_start.copy()
    for t in range(nt):
        for k in range(3):
            v = triangles[t, k]
            vt_pool[fill[v]] = t
            fill[v] += 1
    vt_top = acc
    # Triangle -> voxels.
    tv_start = tri_voxel_offsets[:-1].copy()
    tv_len = np.diff(tri_voxel_offsets)
    tv_pool = np.empty(2 * tri_voxels.shape[0] + 1024, dtype=np.int64)
    tv_pool[: tri_voxels.shape[0]] = tri_voxels
    tv_top = tri_voxels.shape[0]
    n_vox_total = tri_voxels.shape[0]

    # Scratch (valence and voxel lists grow; sized generously and grown on demand).
    cap_t = max_valence
    scratch_t2 = np.empty(cap_t, dtype=np.int64)
    scratch_t1 = np.empty(cap_t, dtype=np.int64)
    nbr2 = np.empty(2 * cap_t, dtype=np.int64)
    cnt2 = np.empty(2 * cap_t, dtype=np.int64)
    nbr1 = np.empty(2 * cap_t, dtype=np.int64)
    cnt1 = np.empty(2 * cap_t, dtype=np.int64)
    cand = np.empty(2 * cap_t, dtype=np.int64)
    corner = np.empty((2 * cap_t, 9))
    per = np.zeros(2 * cap_t, dtype=np.int64)
    vox = np.empty(3 * n_vox_total + 16, dtype=np.int64)
    assign = np.empty(3 * n_vox_total + 16, dtype=np.int64)
    lo = np.empty(3 * n_vox_total + 16)
    hi = np.empty(3 * n_vox_total + 16)
    counts = np.zeros(7, dtype=np.int64)

    # The queue: every edge once, room for one and a half times as many pushed again (the first pass
    # of the 327,680-triangle sphere of benchmarks/bench_tdm_scale.py peaked at 2.2 times its 5.1 M
    # edges), the entries' vertices and versions in 32 bits: a smaller heap reads fewer cache lines
    # and touches fewer fresh pages.
    n_edges = edge_keys.shape[0]
    keys = np.empty(5 * n_edges // 2 + 16)
    items = np.empty((5 * n_edges // 2 + 16, 4), dtype=np.int32)
    size = 0
    for e in range(n_edges):
        a = edge_keys[e] // nv_total
        b = edge_keys[e] % nv_total
        # An entry of the first edges carries -(its index + 1) for a's version (0).
        keys, items, size = _heap_push(keys, items, size, _distance(vertices, a, b), a, b, -(e + 1), 0)

    # The memory of failures (see :class:`PassMemory`): ``clock`` counts contractions, ``touch_time``
    # is each vertex's last.  A failure is (the clock, the vertex besides a and b each attempt read
    # or -1, 1 if neither outcome read the factor): in ``remembered`` for an entry of the first
    # edges, else in ``log`` after a and b (a < b).  (The first entry of an edge goes stale before
    # any entry pushed again, so the log's failures come after.)
    touch_time = touch_before.copy()
    log = np.empty((n_edges // 8 + 16, 6), dtype=np.int32)
    n_log = 0
    while size > 0:
        a, b, va, vb, size = _heap_pop(keys, items, size)
        e = -1
        if va < 0:
            e, va = -va - 1, 0
        if not vert_alive[a] or not vert_alive[b] or version[a] != va or version[b] != vb:
            continue
        if locked[a] or locked[b]:  # (strip_pass) an edge near a strip's border waits for the whole mesh
            continue
        # An edge whose last attempts failed fails again if nothing they read changed since (and,
        # at a larger factor, if neither outcome read the factor): the triangles and their voxels
        # around its two vertices and around the boundary neighbours the boundary test read.  A
        # contraction touches every vertex of the triangles it changes, removes or moves.  (An edge
        # pushed again in this pass has a vertex just touched.)
        if e >= 0 and remembered[e, 0] >= 0 and (remembered[e, 3] or not new_factor):
            t_e, r0, r1 = remembered[e, 0], remembered[e, 1], remembered[e, 2]
            if (
                touch_time[a] <= t_e
                and touch_time[b] <= t_e
                and (r0 < 0 or touch_time[r0] <= t_e)
                and (r1 < 0 or touch_time[r1] <= t_e)
            ):
                continue
        if vt_len[a] > cap_t // 2 or vt_len[b] > cap_t // 2:
            cap_t = 2 * max(vt_len[a], vt_len[b]) + 16
            scratch_t2 = np.empty(cap_t, dtype=np.int64)
            scratch_t1 = np.empty(cap_t, dtype=np.int64)
            nbr2 = np.empty(2 * cap_t, dtype=np.int64)
            cnt2 = np.empty(2 * cap_t, dtype=np.int64)
            nbr1 = np.empty(2 * cap_t, dtype=np.int64)
            cnt1 = np.empty(2 * cap_t, dtype=np.int64)
            cand = np.empty(2 * cap_t, dtype=np.int64)
            corner = np.empty((2 * cap_t, 9))
            per = np.zeros(2 * cap_t, dtype=np.int64)
        done = False
        read0 = read1 = -1
        fixed = True
        for attempt in range(2):
            v2, v1 = (b, a) if attempt == 0 else (a, b)
            outcome, nv, read, free = _attempt(v2, v1, vertices, triangles, tri_alive, vt_start, vt_len, vt_pool, tv_start, tv_len,
                                   tv_pool, centres, half, shrink, scratch_t2, scratch_t1, nbr2, cnt2, nbr1, cnt1, vox, assign,
                                   cand, lo, hi, corner)  # fmt: skip
            counts[outcome] += 1
            fixed = fixed and free
            if attempt == 0:
                read0 = read
            else:
                read1 = read
            if outcome == STALE:
                break
            if outcome != OK:
                continue
            # Commit: triangles on the edge die, v2's others move onto v1.
            n2 = _vertex_tris(v2, vt_start, vt_len, vt_pool, tri_alive, scratch_t2)
            n1 = _vertex_tris(v1, vt_start, vt_len, vt_pool, tri_alive, scratch_t1)
            nc = 0
            for i in range(n2):
                t = scratch_t2[i]
                if triangles[t, 0] == v1 or triangles[t, 1] == v1 or triangles[t, 2] == v1:
                    tri_alive[t] = False
                    continue
                cand[nc] = t
                nc += 1
            moved = nc
            for i in range(n1):
                t = scratch_t1[i]
                if tri_alive[t]:
                    cand[nc] = t
                    nc += 1
            clock += 1  # (fewer contractions than vertices: int32)
            for i in range(n2):
                for k in range(3):
                    touch_time[triangles[scratch_t2[i], k]] = clock
            for i in range(nc):
                t = cand[i]
                for k in range(3):
                    w = triangles[t, k]
                    touch_time[w] = clock
                    if w == v2:
                        triangles[t, k] = v1
            vert_alive[v2] = False
            # v1's triangle list.
            vt_pool, vt_top = _reserve(vt_pool, vt_top, nc, vt_start, vt_len, vert_alive)
            for i in range(nc):
                vt_pool[vt_top + i] = cand[i]
            vt_start[v1] = vt_top
            vt_len[v1] = nc
            vt_top += nc
            # Voxel lists: moved triangles keep exactly the voxels assigned to them; v1's own add theirs.
            per[:nc] = 0
            for i in range(nv):
                per[assign[i]] += 1
            need = nv
            for i in range(moved, nc):
                if per[i] > 0:
                    need += tv_len[cand[i]]
            tv_pool, tv_top = _reserve(tv_pool, tv_top, need, tv_start, tv_len, tri_alive)
            for i in range(nc):
                t = cand[i]
                is_moved = i < moved  # the moved triangles come first in cand (from v2's list)
                start = tv_top
                length = 0
                if not is_moved:
                    if per[i] == 0:
                        continue
                    s = tv_start[t]
                    for j in range(tv_len[t]):
                        tv_pool[tv_top + length] = tv_pool[s + j]
                        length += 1
                for j in range(nv):
                    if assign[j] == i:
                        tv_pool[tv_top + length] = vox[j]
                        length += 1
                tv_start[t] = start
                tv_len[t] = length
                tv_top += length
            version[v1] += 1
            # Push v1's edges again with their new lengths.
            m1 = _neighbours(v1, cand, nc, triangles, nbr1, cnt1)
            for j in range(m1):
                w = nbr1[j]
                keys, items, size = _heap_push(
                    keys, items, size, _distance(vertices, v1, w), v1, w, version[v1], version[w]
                )
            done = True
            break
        if not done and e >= 0:
            remembered[e, 0] = clock
            remembered[e, 1] = read0
            remembered[e, 2] = read1
            remembered[e, 3] = 1 if fixed else 0
        elif not done:
            if n_log == log.shape[0]:
                bigger = np.empty((2 * n_log, 6), dtype=np.int32)
                bigger[:n_log] = log
                log = bigger
            log[n_log, 0] = min(a, b)
            log[n_log, 1] = max(a, b)
            log[n_log, 2] = clock
            log[n_log, 3] = read0
            log[n_log, 4] = read1
            log[n_log, 5] = 1 if fixed else 0
            n_log += 1
    # Output: live triangles with their voxels.
    live = np.flatnonzero(tri_alive)
    out_offsets = np.zeros(live.shape[0] + 1, dtype=np.int64)
    for i in range(live.shape[0]):
        out_offsets[i + 1] = out_offsets[i] + tv_len[live[i]]
    out_voxels = np.empty(out_offsets[-1], dtype=np.int64)
    for i in range(live.shape[0]):
        s = tv_start[live[i]]
        for j in range(tv_len[live[i]]):
            out_voxels[out_offsets[i] + j] = tv_pool[s + j]
    return triangles[live], out_offsets, out_voxels, counts, touch_time, log[:n_log], clock


def corner_shrink(enlargement: float) -> float:
    """How far (voxel units) a convex boundary corner may be cut for the factor: (f - 1) / 2, the
    distance the enlarged boxes reach beyond a voxel."""
    return 0.5 * (float(enlargement) - 1.0)


def box_half_sizes(count: int, enlargement: float, silhouette: np.ndarray | None = None) -> np.ndarray:
    """(count, 2) float64 half sizes of the voxels' boxes, across the image (x, y) and along the
    layers: f / 2 both ways, but min(f, 1) / 2 both ways for the voxels flagged in ``silhouette``
    (see :attr:`farfield.core.techniques.tdm.voxel_field.VoxelField.silhouette`).

    Seed 003 §6 enlarges every box alike.  At the part's outline that lets a triangle one voxel
    inside "cover" an outline voxel, and the outline retreats by up to a voxel: measured on
    ``tests/scenes.py::house`` at 250 m, f = 2, 512 px, that opened 2-3 hole pixels seen from the
    cell's top corners.  Boxes kept at the voxel's own width across the image closed them there,
    but an outline voxel whose box was still enlarged in depth could be kept by a triangle up to
    f / 2 layers in front of or behind it, which other viewpoints see shifted off the outline:
    a single hole pixel at 250 m and 315 pixels bloated beyond one pixel at 140 m (both f = 2).
    Outline voxels at their own size both ways: no hole pixel in 22 bakes from 200 to 300 m at f =
    2 and 3 (9 views each; at most 3 pixels bloated beyond one at f = 2, 19 at f = 3), none
    at 90-1000 m and no pixel bloated beyond one at 140 m for any f from 1 to 3, for 1.05-1.3 times
    the triangles at 90-250 m, f = 2.  At f = 1 nothing changes (the boxes are the voxels), and a
    triangle that meets only part of an outline voxel's box still keeps it: one hole pixel at 250 m.
    """
    half = np.full((int(count), 2), 0.5 * float(enlargement))
    if silhouette is not None:
        half[np.asarray(silhouette, dtype=bool)] = 0.5 * min(float(enlargement), 1.0)
    return half


@dataclass(frozen=True, slots=True)
class PassMemory:
    """The failures a pass of :func:`simplify` leaves for the next pass on its result.

    ``clock`` counts contractions since the first pass; ``touch_time`` (v,) int32 is the clock of
    each vertex's last touch (0: none), a contraction touching every vertex of the triangles it
    changes, removes or moves.  ``keys`` (sorted) are edges ``a * v + b`` (a < b) whose last
    attempts failed; ``failures`` (k, 4) int32 their clock then (-1: forgotten), the vertex besides
    a and b whose triangles each of the two attempts read (v2's other boundary neighbour, in the
    boundary test; -1: none), and 1 if neither outcome read the factor.  ``enlargement`` is the
    factor of the pass."""

    touch_time: np.ndarray
    keys: np.ndarray
    failures: np.ndarray
    clock: int
    enlargement: float

    @classmethod
    def empty(cls, count: int, enlargement: float) -> PassMemory:
        return cls(np.zeros(count, np.int32), np.zeros(0, np.int64), np.zeros((0, 4), np.int32), 0, float(enlargement))

    def renumbered(self, kept: np.ndarray) -> PassMemory:
        """The memory for the vertices ``kept`` (old numbers, ascending), numbered 0, 1, ... in
        order.  A failure that read a vertex not kept is forgotten: that vertex lost its triangles
        after it (a touch), so the failure could not be skipped anyway."""
        old, new = len(self.touch_time), len(kept)
        number = np.full(old + 1, -1, np.int32)  # number[-1]: the -1 of no vertex read stays -1
        number[kept] = np.arange(new)
        a, b = number[self.keys // old].astype(np.int64), number[self.keys % old]
        keep = (a >= 0) & (b >= 0)
        failures = self.failures[keep]
        reads = number[failures[:, 1:3]]
        failures[~((reads >= 0) | (failures[:, 1:3] < 0)).all(axis=1), 0] = -1
        failures[:, 1:3] = reads
        return PassMemory(self.touch_time[kept], a[keep] * new + b[keep], failures, self.clock, self.enlargement)


def simplify(
    vertices,
    triangles,
    voxel_offsets,
    voxels,
    centres,
    enlargement,
    silhouette=None,
    memory: PassMemory | None = None,
    locked: np.ndarray | None = None,
):
    """Simplify a covering mesh (see the module docstring); ``silhouette`` flags the voxels whose
    boxes are not enlarged.

    ``memory``: the :class:`PassMemory` of the pass whose result this is, if any, with the same
    vertices, ``centres`` and ``silhouette`` (:func:`farfield.core.techniques.tdm.technique.simplify_mesh` keeps them;
    only the vertex count and the factor are checked).  An attempt reads
    only the triangles around the edge's two vertices and, at a boundary, around the other boundary
    neighbour of the vertex it removes (their voxels included), and a failed one changes nothing;
    so an edge whose last attempts failed, with none of those vertices touched since, fails again,
    at the same factor, and at a larger one if neither outcome read the factor
    (:func:`_attempt`).  The pass skips such edges, counting their failures no more.  It pops the
    same heap entries as without skipping, so it makes the same mesh (up to the order in which a
    fan's angles are summed, which a new pass's rebuilt triangle lists may change: a sum within
    rounding of 180 degrees could tip, as it could with the skipping of earlier versions).  Measured on the
    327,680-triangle sphere of ``benchmarks/bench_tdm_scale.py`` (3.4 M initial triangles, 143,481
    kept, 23 passes): skipping in the repeats at one factor the edges with no vertex around them
    touched in the previous pass or this one (the memory of earlier versions), the cascade took 54 s
    instead of 80 s; see the README for each edge's own memory.

    ``locked``: (v,) bool, vertices no contraction may touch (an edge with one is skipped, not
    attempted): :func:`strip_pass` locks the vertices near its strips' borders.

    Returns (triangles (t, 3) int64 into the same vertices, voxel_offsets, voxels, outcome counts
    as a dict, the pass's :class:`PassMemory`).
    """
    triangles = np.ascontiguousarray(triangles, dtype=np.int64)
    if len(vertices) >= 2**31:  # the queue keeps vertex numbers and edge indices in 32 bits
        raise InternalError(f"a mesh of {len(vertices):,} vertices is past the simplification's 2**31")
    valence = np.bincount(triangles.ravel(), minlength=len(vertices)).max(initial=1)
    # Each edge once: one int64 key a * n + b (a < b) per edge, sorted, repeats dropped (np.unique
    # of the keys hashes them first, 0.4 s a pass for 800k edges).  A stable sort (timsort) merges
    # the ascending runs the mesh's order leaves: 26.5 M keys of the scan's initial mesh in
    # 0.25-0.7 s instead of 1.8 s (benchmarks/bench_tdm_scale.py --scene scan).
    n = max(len(vertices), 1)
    first, second = triangles, triangles[:, [1, 2, 0]]
    keys = np.sort((np.minimum(first, second) * n + np.maximum(first, second)).ravel(), kind="stable")
    keys = keys[np.concatenate([[True], keys[1:] != keys[:-1]])] if keys.size else keys
    if len(keys) >= 2**31:  # the queue's first entries carry their edge's index in 32 bits
        raise InternalError(f"a mesh of {len(keys):,} edges is past the simplification's 2**31")
    if memory is None:
        memory = PassMemory.empty(len(vertices), enlargement)
    elif len(memory.touch_time) != len(vertices) or enlargement < memory.enlargement:
        raise InternalError(
            f"a pass memory of {len(memory.touch_time):,} vertices at f = {memory.enlargement} for a mesh of {len(vertices):,} at f = {enlargement}"
        )
    # Each edge's failure, if remembered (one row an edge: the kernel reads it in one cache line).
    remembered = np.full((len(keys), 4), -1, np.int32)  # the kernel writes this pass's into it
    if len(memory.keys):
        at = np.minimum(np.searchsorted(memory.keys, keys), len(memory.keys) - 1)
        known = memory.keys[at] == keys
        remembered[known] = memory.failures[at[known]]
    tris, offsets, vox, counts, touch_time, log, clock = _simplify(
        np.ascontiguousarray(vertices, dtype=np.float64), triangles, keys,
        np.ascontiguousarray(voxel_offsets, dtype=np.int64), np.ascontiguousarray(voxels, dtype=np.int64),
        np.ascontiguousarray(centres, dtype=np.float64), box_half_sizes(len(centres), enlargement, silhouette),
        corner_shrink(enlargement), int(4 * valence + 64), np.ascontiguousarray(memory.touch_time, dtype=np.int32),
        remembered, int(memory.clock), bool(enlargement > memory.enlargement),
        np.zeros(len(vertices), np.bool_) if locked is None else np.ascontiguousarray(locked, dtype=np.bool_),
    )  # fmt: skip
    # The memory after: each edge's last failure (the log's last, else ``remembered``'s), between
    # live vertices.
    log_keys = log[:, 0].astype(np.int64) * n + log[:, 1]
    order = np.argsort(log_keys, kind="stable")
    log_keys = log_keys[order]
    last = np.append(log_keys[1:] != log_keys[:-1], True) if log_keys.size else np.zeros(0, bool)
    log_keys, log_failures = log_keys[last], log[order[last], 2:]
    failed = remembered[:, 0] >= 0
    merged_keys, failures = keys[failed], remembered[failed]
    at = np.minimum(np.searchsorted(merged_keys, log_keys), max(len(merged_keys) - 1, 0))
    again = merged_keys[at] == log_keys if len(merged_keys) else np.zeros(len(log_keys), bool)
    failures[at[again]] = log_failures[again]
    merged_keys, failures = (
        np.concatenate([merged_keys, log_keys[~again]]),
        np.concatenate([failures, log_failures[~again]]),
    )
    order = np.argsort(merged_keys, kind="stable")  # two sorted runs: merged in linear time
    live = np.bincount(tris.ravel(), minlength=n) > 0
    merged_keys, failures = merged_keys[order], failures[order]
    between = live[merged_keys // n] & live[merged_keys % n]
    memory = PassMemory(touch_time, merged_keys[between], failures[between], int(clock), float(enlargement))
    return tris, offsets, vox, dict(zip(OUTCOMES, (int(c) for c in counts))), memory


# The cascade of a large mesh runs on this many strips, in threads (:func:`strip_pass`).  A fixed
# count, not the machine's cores: the mesh must not depend on where it was baked.
STRIPS = 8
STRIP_MIN_TRIANGLES = 1_000_000  # below this the cascade runs on the whole mesh (the house: 0.3 M)


def strip_pass(vertices, triangles, voxel_offsets, voxels, centres, enlargement, silhouette=None, strips=STRIPS):
    """:func:`simplify` on ``strips`` strips of the mesh at once, in threads: the contractions that
    do not need the whole mesh.  ``enlargement``: one factor (one pass), or a cascade of them
    (:func:`farfield.core.techniques.tdm.technique.schedule`), each factor's passes repeated in each
    strip until they contract nothing more.

    The strips are ranges of x (the image's columns) holding equal numbers of triangles (by their
    first vertex).  A triangle with vertices in two strips is in none and is kept as it is; its
    vertices and their neighbours are locked (:func:`simplify`'s ``locked``).  A contraction of two
    unlocked vertices reads only triangles of its own strip: the triangles around the two vertices
    and around their neighbours (the boundary test's other neighbour), with the voxels they store.
    It never makes an unlocked vertex a neighbour of a border vertex (the removed vertex was none,
    else it were locked), so this holds for every later pass too.  So each strip's passes make
    only contractions the whole mesh allows, every voxel stays stored with a triangle that meets
    its box, and the strips change disjoint triangles.  The edges left (at the borders, and those
    the strips' order did not reach) are the next pass's, on the whole mesh.

    Returns (triangles, voxel_offsets, voxels, outcome counts summed over the strips, the
    :class:`PassMemory` of the strips' failures at the last factor, for the next pass at it), the
    triangles indexing the same ``vertices``: each strip's, in order, then those across borders.
    """
    triangles = np.asarray(triangles, dtype=np.int64)
    voxel_offsets = np.asarray(voxel_offsets, dtype=np.int64)
    n = len(vertices)
    cuts = np.quantile(vertices[triangles[:, 0], 0], np.arange(1, strips) / strips)
    side = np.searchsorted(cuts, vertices[:, 0])
    corner_side = side[triangles]
    strip = np.where(corner_side.min(axis=1) == corner_side.max(axis=1), corner_side[:, 0], -1)
    border = np.zeros(n, bool)
    border[triangles[strip < 0].ravel()] = True
    locked = border.copy()
    locked[triangles[border[triangles].any(axis=1)].ravel()] = True
    lengths = np.diff(voxel_offsets)

    def rows_of(rows):
        """The triangles ``rows`` with their voxels: (triangles, offsets, voxels)."""
        counts = lengths[rows]
        offsets = np.concatenate([[0], np.cumsum(counts)])
        gather = np.repeat(voxel_offsets[rows] - offsets[:-1], counts) + np.arange(offsets[-1])
        return triangles[rows], offsets, voxels[gather]

    factors = tuple(np.atleast_1d(np.asarray(enlargement, dtype=np.float64)).tolist())

    def one(k):
        tri, offsets, vox = rows_of(np.flatnonzero(strip == k))
        used = np.zeros(n, bool)
        used[tri.ravel()] = True
        used = np.flatnonzero(used)
        number = np.zeros(n, np.int64)
        number[used] = np.arange(used.size)  # ascending: the same edge order as in the whole mesh
        out, verts, lock = number[tri], vertices[used], locked[used]
        memory, totals = None, {}
        for factor in factors:
            while True:
                before = out.shape[0]
                out, offsets, vox, counts, memory = simplify(
                    verts, out, offsets, vox, centres, factor, silhouette, memory, lock
                )
                for key, value in counts.items():
                    totals[key] = totals.get(key, 0) + value
                if len(factors) == 1 or out.shape[0] == before:
                    break
                # The vertices left, renumbered in their order (technique.py::_kept_vertices).
                kept = np.flatnonzero(np.bincount(out.ravel(), minlength=len(verts)))
                if kept.size < 0.75 * len(verts):
                    renumber = np.zeros(len(verts), np.int64)
                    renumber[kept] = np.arange(kept.size)
                    out, verts, lock, used = renumber[out], verts[kept], lock[kept], used[kept]
                    memory = memory.renumbered(kept)
        return used[out], offsets, vox, totals, (used, memory)

    # The strips with the most voxels first (their work follows them: on the scan of
    # benchmarks/bench_tdm_scale.py 4.6-6.3 s of CPU a strip, the outer two the largest), so that the
    # threads end together; the order of the work does not change the result.
    voxel_count = np.bincount(strip[strip >= 0], weights=lengths[strip >= 0], minlength=strips)
    order = np.argsort(-voxel_count, kind="stable")
    with ThreadPoolExecutor(max_workers=min(strips, usable_cores())) as pool:
        done = dict(zip(order.tolist(), pool.map(one, order.tolist())))
    parts = [done[k] for k in range(strips)]
    parts.append((*rows_of(np.flatnonzero(strip < 0)), {}, None))
    totals: dict[str, int] = {}
    for _, _, _, counts, _ in parts:
        for key, value in counts.items():
            totals[key] = totals.get(key, 0) + value
    lengths = np.concatenate([np.diff(offsets) for _, offsets, _, _, _ in parts])
    return (
        np.concatenate([tri for tri, *_ in parts]),
        np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        np.concatenate([vox for _, _, vox, _, _ in parts]),
        totals,
        _merged_memory(n, [memory for *_, memory in parts[:-1]], factors[-1]),
    )


def _merged_memory(n: int, strips: list, enlargement: float) -> PassMemory:
    """One :class:`PassMemory` for the whole mesh from the strips' (``(used, memory)`` each, in
    their own vertex numbers): the strips' clocks laid one after the other.  Their vertices are
    disjoint (a vertex is in its own strip's triangles only), and each failure read only its own
    strip, so a failure stays true until the whole mesh's passes touch what it read."""
    touch = np.zeros(n, np.int32)
    keys, failures = [], []
    clock = 0
    for used, memory in strips:
        m = len(used)
        touch[used] = np.where(memory.touch_time > 0, memory.touch_time + clock, 0)
        a, b = used[memory.keys // m], used[memory.keys % m]
        failed = memory.failures.copy()
        failed[:, 0] = np.where(failed[:, 0] >= 0, failed[:, 0] + clock, -1)
        failed[:, 1:3] = np.where(failed[:, 1:3] >= 0, used[np.maximum(failed[:, 1:3], 0)], -1)
        keys.append(a * n + b)
        failures.append(failed)
        clock += memory.clock
    keys = np.concatenate(keys) if keys else np.zeros(0, np.int64)
    failures = np.concatenate(failures) if failures else np.zeros((0, 4), np.int32)
    order = np.argsort(keys, kind="stable")
    return PassMemory(touch, keys[order], failures[order].astype(np.int32), clock, float(enlargement))


def contraction_outcome(
    vertices, triangles, voxel_offsets, voxels, centres, enlargement, v2, v1, silhouette=None
) -> str:
    """The outcome of contracting ``v2`` into ``v1`` in a mesh (without changing it), for tests and
    inspection: one of :data:`OUTCOMES`."""
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    triangles = np.ascontiguousarray(triangles, dtype=np.int64)
    nt = triangles.shape[0]
    vt = [[] for _ in range(len(vertices))]
    for t, tri in enumerate(triangles):
        for v in tri:
            vt[int(v)].append(t)
    vt_len = np.array([len(x) for x in vt], dtype=np.int64)
    vt_start = np.concatenate([[0], np.cumsum(vt_len)[:-1]]).astype(np.int64)
    vt_pool = np.array([t for x in vt for t in x] + [0], dtype=np.int64)
    voxel_offsets = np.asarray(voxel_offsets, dtype=np.int64)
    cap = 4 * int(vt_len.max(initial=1)) + 64
    n = 3 * len(voxels) + 16
    outcome, _, _, _ = _attempt(
        int(v2), int(v1), vertices, triangles, np.ones(nt, dtype=np.bool_), vt_start, vt_len, vt_pool,
        voxel_offsets[:-1].copy(), np.diff(voxel_offsets), np.ascontiguousarray(voxels, dtype=np.int64),
        np.ascontiguousarray(centres, dtype=np.float64), box_half_sizes(len(centres), enlargement, silhouette),
        corner_shrink(enlargement), np.empty(cap, np.int64), np.empty(cap, np.int64), np.empty(2 * cap, np.int64), np.empty(2 * cap, np.int64),
        np.empty(2 * cap, np.int64), np.empty(2 * cap, np.int64), np.empty(n, np.int64), np.empty(n, np.int64),
        np.empty(2 * cap, np.int64), np.empty(n), np.empty(n), np.empty((2 * cap, 9)),
    )  # fmt: skip
    return OUTCOMES[outcome]

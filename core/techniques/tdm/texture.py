"""Textures of a textured depth mesh: shared charts resampled from the voxel field (seed 003 §7).

**What the paper does.**  Seed 003 §7 generates a texture for every polygon of the simplified
mesh, "so that the texel size approximately corresponds to the side length of a voxel, and the
extents of the texture are slightly larger than the polygon in order to ensure that all texels
needed for rasterization are present, even when bilinear texture filtering is used", and stores
the textures in a texture atlas.  Every texel centre is averaged from the ``n`` closest voxel
centres weighted by distance (``n`` is the oversampling option).

**farfield deviation: shared charts instead of per-polygon textures.**  A simplified TDM is mostly
long slivers, and a rectangle around a sliver is mostly empty: on the house benchmark at 90 m
(512 px) 6,605 triangles covering ~100k texels took 966k texels as per-triangle tiles (252k as
shared charts; on the later mesh of 1,169 triangles and ~51k texels, 237k against 133k), and no
vertex could be shared.  farfield therefore textures *charts*: the connected components of
triangles that share an edge and whose voxel-space normals have the same signed dominant axis
(+-x, +-y or +-layer; a sign change means the surface folds back), each projected onto the plane of
the two other axes at one texel per voxel unit.  Along the surface a texel then spans at most
``1 / |n_axis| <= sqrt(3)`` voxel units (``n`` the unit normal), so the texel density stays
"approximately" the paper's; a group of one or two triangles between charts facing other ways
joins a neighbouring chart if its normal follows that chart's axis by at least 0.3
(:func:`adopt_axes`; its texels then span up to 3.3 voxel units one way), and a triangle still
left a chart of its own is laid out unfolded beside a neighbouring chart, across their shared
edge (:func:`unfold_lone_triangles`).  A chart's tile is its
bounding rectangle grown by ``margin`` texels, its corner shifted by an integer so that texel
centres sit on the voxel centres' coordinates (x + 1/2, y + 1/2, whole layers;
:data:`VOXEL_SHIFT`).  The projection of a connected group can fold over; a texel centre that two
triangles of one chart both contain (a shared edge or vertex is claimed once, by a top-left rule)
moves the later triangles into a chart of their own until every chart is one-to-one, and charts
wider than :data:`MAX_CHART` texels are cut into pieces.  Triangles of one chart share their vertices and texture coordinates,
so the mesh is indexed: geometry is counted per distinct (vertex, chart) pair.

**Which texels get a colour.**  A texel is *needed* when its centre lies within ``margin`` texels
(Chebyshev distance, i.e. the bilinear footprint for ``margin = 1``) of one of the chart's
triangles: inside a triangle it is sampled at its own point; outside all of them, at the point of
the nearest triangle (clamped barycentric coordinates: never an extrapolation along a sliver).
Only needed texels are stored: each chart's needed texels form a mask that :mod:`farfield.core.techniques.tdm.mask_atlas`
packs onto the atlas pages (a chart's bounding rectangle is mostly empty: on the house benchmark
at 90 m, 133k texels of rectangles for 72k needed).  Every other page texel (gaps between charts,
between the arms of a concave chart) copies the colour of the nearest needed texel, so that pages
are opaque and coarser mip levels keep their alpha and mostly a chart's own colours.  Every texel colour is the paper's inverse-distance average; farfield
searches one k-d tree of the whole field for every texel (the paper restricts interior texels to
the polygon's own voxels; the whole field finds those too, as the query point lies on the surface).

**How the texture meets standard viewers (seed 003 §8).**  The paper turns perspective correction
off, because its textures are laid out in the image of the reference viewpoint.  A glTF viewer
cannot be told to do that.  farfield instead samples the texture *through the world triangle*: a
texel at barycentric coordinates b of its chart triangle takes the colour seen at the world point
``b . (W_A, W_B, W_C)`` of the reprojected triangle (the §8 reprojection of the vertices, its
voxel-space position found by projecting it back, :meth:`farfield.core.techniques.tdm.voxel_field.VoxelField.from_world`).
Perspective-correct interpolation, which every viewer does, interpolates texture coordinates
affinely over the world triangle, and the chart map is affine on each triangle, so it lands on
exactly that texel: the GLB is right in any viewer with no subdivision and no projective
coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import distance_transform_edt
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from farfield.core.impostor.impostor import decode_normals, encode_normals
from farfield.core.techniques.tdm.mask_atlas import MaskLayout
from farfield.core.techniques.tdm.voxel_field import VoxelField

# Largest chart tile side in texels before a chart is cut into pieces (the packer's pages are at
# most 8192 texels wide; a chart a quarter of that still packs with others).
MAX_CHART = 2048

# Groups of at most this many triangles facing one way may join a neighbouring chart
# (:func:`adopt_axes`) whose axis their unit normals follow by at least ADOPT_SCORE.
ADOPT_TRIANGLES = 2
ADOPT_SCORE = 0.3

# Lengths (voxel units) below which an edge or a triangle's height counts as none.
EPS = 1e-9

# The plane of each dominant axis: voxel-space axes (x, y, layer) kept as the chart's (u, v).
PLANES = np.array([[1, 2], [0, 2], [0, 1]])

# Added to voxel-space points before projecting, so that texel centres (half units of the chart)
# fall on voxel centres (x + 0.5, y + 0.5, layer).
VOXEL_SHIFT = np.array([0.0, 0.0, 0.5])


@dataclass(frozen=True, slots=True)
class Charts:
    """The charts of a triangle mesh and its needed texels (see the module docstring).

    ``position`` are the vertices' texel positions inside their chart's tile (texel edges at
    integers, so texel (row, col) spans [col, col + 1) x [row, row + 1)); the texels are one
    record per needed texel: its chart, row and column in the tile, the triangle it is sampled
    from, and whether its centre lies inside that triangle.
    """

    chart: np.ndarray  # (t,) int64 chart of each triangle
    axis: np.ndarray  # (t,) int64 signed projection axis of each triangle (see adopt_axes)
    position: np.ndarray  # (t, 3, 2) float64 vertex positions in the chart's tile, texels
    sizes: np.ndarray  # (c, 2) int64 tile width, height
    texel_chart: np.ndarray  # (m,) int64
    texel_row: np.ndarray  # (m,) int64
    texel_col: np.ndarray  # (m,) int64
    texel_triangle: np.ndarray  # (m,) int64
    texel_inside: np.ndarray  # (m,) bool

    @property
    def count(self) -> int:
        return int(self.sizes.shape[0])

    @property
    def tile_texels(self) -> int:
        """Texels of all tiles together (their bounding rectangles, margins included)."""
        return int(self.sizes.prod(axis=1).sum())


def dominant_axes(points: np.ndarray) -> np.ndarray:
    """(t,) int64 signed dominant axis of each triangle's normal, ``points`` (t, 3, 3): 2 * axis of
    its largest component (0 x, 1 y, 2 layer), + 1 where that component is negative.

    >>> dominant_axes(np.array([[[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[0, 0, 0], [0, 0, 1], [0, 1, 0]]], float)).tolist()
    [4, 1]
    """
    normal = np.cross(points[:, 1] - points[:, 0], points[:, 2] - points[:, 0])
    axis = np.argmax(np.abs(normal), axis=1)
    negative = np.take_along_axis(normal, axis[:, None], axis=1)[:, 0] < 0
    return (2 * axis + negative).astype(np.int64)


def edge_neighbours(triangles: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """(p, 2) int64 pairs of triangles (of (t, 3) vertex indices) that share an edge and a dominant
    axis; a non-manifold edge links its triangles in a chain.

    >>> edge_neighbours(np.array([[0, 1, 2], [2, 1, 3], [3, 1, 4]]), np.array([2, 2, 0])).tolist()
    [[0, 1]]
    """
    t = triangles.shape[0]
    if t == 0:
        return np.zeros((0, 2), np.int64)
    a = triangles[:, [0, 1, 2]].reshape(-1)
    b = triangles[:, [1, 2, 0]].reshape(-1)
    lo, hi = np.minimum(a, b).astype(np.int64), np.maximum(a, b).astype(np.int64)
    owner = np.repeat(np.arange(t, dtype=np.int64), 3)
    order = np.lexsort((owner, axis[owner], hi, lo))
    lo, hi, owner = lo[order], hi[order], owner[order]
    same = (lo[1:] == lo[:-1]) & (hi[1:] == hi[:-1]) & (axis[owner[1:]] == axis[owner[:-1]]) & (owner[1:] != owner[:-1])
    return np.stack([owner[:-1][same], owner[1:][same]], axis=1)


def adopt_axes(triangles: np.ndarray, corners: np.ndarray, axis: np.ndarray) -> np.ndarray:
    """The signed projection axis of every triangle: its dominant ``axis``, except that a triangle
    of a group of at most :data:`ADOPT_TRIANGLES` edge-connected triangles sharing an axis takes
    the axis of an edge neighbour in a larger group where its unit normal's component along that
    axis (same sign) is at least :data:`ADOPT_SCORE` (the largest such; three rounds).

    A lone sliver between charts facing other ways otherwise becomes a chart of its own, with its
    own bilinear ring and padding on the atlas: on the house benchmark at 140 m (512 px, f = 2) 121
    of 156 charts held fewer than 60 texels.  Adopted, it joins its neighbour's chart, its texels
    spanning up to 1 / ADOPT_SCORE voxel units along the surface instead of sqrt(3).

    A sliver rising two layers over one texel (its normal 63 degrees off the layer axis) beside a
    chart facing the layers joins it:

    >>> pts = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0], [2, 2, 0], [5, 0, 2], [5, 4, 2]], float)
    >>> tris = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4], [1, 5, 6], [1, 6, 2]])
    >>> dominant_axes(pts[tris]).tolist(), adopt_axes(tris, pts[tris], dominant_axes(pts[tris])).tolist()
    ([4, 4, 4, 4, 1, 1], [4, 4, 4, 4, 4, 4])
    >>> build_charts(pts, tris, 1).chart.tolist()
    [0, 0, 0, 0, 0, 0]
    """
    t = triangles.shape[0]
    normal = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    unit = normal / np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    pairs = edge_neighbours(triangles, np.zeros(t, np.int64))
    pairs = np.concatenate([pairs, pairs[:, ::-1]])
    axis = axis.copy()
    for _ in range(3):
        group = _components(t, edge_neighbours(triangles, axis), np.zeros(t, np.int64))
        size = np.bincount(group)
        i, j = pairs[:, 0], pairs[:, 1]
        small = (size[group[i]] <= ADOPT_TRIANGLES) & (size[group[j]] > size[group[i]]) & (axis[i] != axis[j])
        i, wanted = i[small], axis[j[small]]
        score = unit[i, wanted // 2] * np.where(wanted % 2 == 1, -1.0, 1.0)
        good = score >= ADOPT_SCORE
        i, wanted, score = i[good], wanted[good], score[good]
        if not i.size:
            break
        order = np.lexsort((-score, i))
        best = np.ones(order.size, bool)
        best[1:] = i[order][1:] != i[order][:-1]
        axis[i[order][best]] = wanted[order][best]
    return axis


def _components(t: int, pairs: np.ndarray, label: np.ndarray) -> np.ndarray:
    """Connected components of ``t`` triangles linked by ``pairs`` whose ``label`` agree."""
    keep = label[pairs[:, 0]] == label[pairs[:, 1]]
    p = pairs[keep]
    graph = coo_matrix((np.ones(len(p), np.int8), (p[:, 0], p[:, 1])), shape=(t, t))
    return connected_components(graph, directed=False)[1].astype(np.int64)


def rasterize(plane: np.ndarray, margin: int) -> tuple[np.ndarray, ...]:
    """The texels near 2D triangles ``plane`` (t, 3, 2) (texel centres at half units).

    Returns (triangle, u, v, inside, distance) per texel whose centre lies within Chebyshev
    distance ``margin`` of the triangle: the texel's integer column u and row v (centre at
    u + 0.5, v + 0.5), whether the triangle claims the centre (inside it; on an edge only by a
    top-left rule, so a centre on an edge shared by two triangles on either side is claimed once),
    and the Chebyshev distance to the farthest edge line the centre lies outside of (0 inside);
    triangle by triangle, in order.

    >>> tri, u, v, inside, dist = rasterize(np.array([[[0, 0], [2, 0], [0, 2]]], float), 0)
    >>> sorted(zip(u[inside].tolist(), v[inside].tolist()))
    [(0, 0)]
    >>> tri, u, v, inside, dist = rasterize(np.array([[[0, 0], [2, 0], [0, 2]], [[2, 0], [2, 2], [0, 2]]], float), 0)
    >>> sorted(zip(u[inside].tolist(), v[inside].tolist(), tri[inside].tolist()))
    [(0, 0, 0), (0, 1, 1), (1, 0, 1), (1, 1, 1)]
    """
    t = plane.shape[0]
    m = float(margin)
    d1, d2 = plane[:, 1] - plane[:, 0], plane[:, 2] - plane[:, 0]
    area = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    # Orient every triangle positively (interior where every edge function is > 0).
    q = np.where((area < 0)[:, None, None], plane[:, [0, 2, 1]], plane)
    scale = np.abs(plane).max(initial=0.0) + 1.0
    valid = np.abs(area) > 1e-12 * scale * scale
    e = q[:, [1, 2, 0]] - q  # (t, 3, 2) edge vectors
    l1 = np.abs(e).sum(axis=2)  # (t, 3): the edge function's gradient in the L1 norm
    lo, hi = q.min(axis=1) - m, q.max(axis=1) + m  # (t, 2)

    # Rows whose centre line meets the grown bounding box, then the span of columns on each row
    # where the square of half side ``margin`` meets every edge's half-plane (separating axes).
    row0 = np.ceil(lo[:, 1] - 0.5 - 1e-9).astype(np.int64)
    row1 = np.floor(hi[:, 1] - 0.5 + 1e-9).astype(np.int64)
    rows = np.maximum(row1 - row0 + 1, 0)
    rt = np.repeat(np.arange(t, dtype=np.int64), rows)
    ry = _ranges(row0, rows)
    cy = ry + 0.5
    x0, x1 = lo[rt, 0].copy(), hi[rt, 0].copy()
    use = valid[rt]
    for k in range(3):
        ex, ey, qx, qy, length = e[rt, k, 0], e[rt, k, 1], q[rt, k, 0], q[rt, k, 1], l1[rt, k]
        # E(x) = ex (cy - qy) - ey (x - qx) >= -margin * l1  <=>  -ey x >= -margin * l1 - ex (cy - qy) - ey qx
        rhs = -m * length - ex * (cy - qy) - ey * qx
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = rhs / -ey
        x0 = np.where(use & (ey < 0), np.maximum(x0, bound), x0)
        x1 = np.where(use & (ey > 0), np.minimum(x1, bound), x1)
        x1 = np.where(use & (ey == 0) & (rhs > 1e-9 * scale * length), -np.inf, x1)
    col0 = np.ceil(np.nan_to_num(x0, neginf=0.0, posinf=0.0) - 0.5 - 1e-6).astype(np.int64)
    col1 = np.floor(np.nan_to_num(x1, neginf=-1e9, posinf=0.0) - 0.5 + 1e-6).astype(np.int64)
    cols = np.maximum(col1 - col0 + 1, 0)
    tri = np.repeat(rt, cols)
    v = np.repeat(ry, cols)
    u = _ranges(col0, cols)

    # The exact tests per texel, one edge after the other (per-triangle values gathered per edge:
    # reductions over an axis of 3 are slow).
    cx, cy = u + 0.5, v + 0.5
    use = valid[tri]
    tol = 1e-12 * scale * l1
    owns = (e[:, :, 1] < 0) | ((e[:, :, 1] == 0) & (e[:, :, 0] > 0))  # (t, 3) top-left edges
    grad = np.where(l1 > 0, l1, 1.0)
    inside, distance = use, np.full(tri.size, -np.inf)
    for k in range(3):
        fn = e[tri, k, 0] * (cy - q[tri, k, 1]) - e[tri, k, 1] * (cx - q[tri, k, 0])
        limit = tol[tri, k]
        inside = inside & ((fn > limit) | ((np.abs(fn) <= limit) & owns[tri, k]))
        with np.errstate(divide="ignore", invalid="ignore"):
            distance = np.maximum(distance, np.where(use, -fn / grad[tri, k], 0.0))
    distance = np.where(inside, 0.0, np.maximum(distance, 0.0))
    near = (distance <= m + 1e-9) & (cx >= lo[tri, 0] - 1e-9) & (cx <= hi[tri, 0] + 1e-9)
    return tri[near], u[near], v[near], inside[near], distance[near]


def build_charts(points: np.ndarray, triangles: np.ndarray, margin: int) -> Charts:
    """The charts of the mesh with voxel-space ``points`` (n, 3) and ``triangles`` (t, 3) (see the
    module docstring): grouped by shared edges and dominant axis, split where a chart folds over or
    grows wider than :data:`MAX_CHART`; then the triangles left alone go unfolded into a
    neighbour's chart (:func:`unfold_lone_triangles`).

    Two triangles forming a 4 x 3 rectangle share one 6 x 5 tile (margin 1):

    >>> pts = np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0], [0, 3, 0]], float)
    >>> ch = build_charts(pts, np.array([[0, 1, 2], [0, 2, 3]]), 1)
    >>> ch.chart.tolist(), ch.sizes.tolist(), int(ch.texel_inside.sum())
    ([0, 0], [[6, 5]], 12)
    """
    triangles = np.asarray(triangles, dtype=np.int64)
    t = triangles.shape[0]
    corners = points[triangles]
    axis = adopt_axes(triangles, corners, dominant_axes(corners))
    # Texel centres on voxel centres: those lie at half units in x and y but on whole layers.
    plane = np.take_along_axis(corners + VOXEL_SHIFT, PLANES[axis // 2][:, None, :], axis=2)  # (t, 3, 2)
    tri, u, v, inside, distance = rasterize(plane, margin)
    pairs = edge_neighbours(triangles, axis)
    claim_tri, claim_u, claim_v = tri[inside], u[inside], v[inside]
    base = min(int(u.min(initial=0)), int(v.min(initial=0)))
    span = max(int(u.max(initial=0)), int(v.max(initial=0))) - base + 1
    centroid = plane.mean(axis=1)

    label = np.zeros(t, np.int64)
    while True:
        chart = _components(t, pairs, label)
        count = int(chart.max(initial=-1)) + 1
        # Folds: a texel centre claimed by two triangles of one chart.  All but the first claimer
        # leave (greedy); the leavers regroup among themselves on the next round.
        key = (chart[claim_tri] * span + (claim_v - base)) * span + (claim_u - base)
        order = np.argsort(key, kind="stable")  # then by triangle: rasterize emits by triangle
        dup = np.zeros(order.size, bool)
        dup[1:] = key[order][1:] == key[order][:-1]
        evicted = np.zeros(t, np.int64)
        evicted[claim_tri[order][dup]] = 1
        # Oversized charts: cut into cells of half the limit by triangle centroid.
        low, high = _extents(chart, plane, count)
        too_big = np.any(high - low + 2 * margin + 1 > MAX_CHART, axis=1)
        cell = np.where(too_big[chart][:, None], np.floor((centroid - low[chart]) / (MAX_CHART // 2)), 0).astype(
            np.int64
        )
        cell -= cell.min(axis=0, initial=0)
        rows = np.ravel_multi_index(
            (chart, evicted, cell[:, 0], cell[:, 1]), (count, 2, *(cell.max(axis=0, initial=0) + 1))
        )
        refined = np.unique(rows, return_inverse=True)[1].reshape(-1)  # the (chart, evicted, cell) rows in order
        if int(refined.max(initial=-1)) + 1 == count:
            break
        label = refined

    chart, plane = unfold_lone_triangles(points, triangles, chart, plane, margin, (tri[inside], u[inside], v[inside]))
    tri, u, v, inside, distance = rasterize(plane, margin)
    low, high = _extents(chart, plane, int(chart.max(initial=-1)) + 1)

    # Tiles: each chart's rectangle grown by the margin, its corner moved by an integer.
    offset = margin - np.floor(low).astype(np.int64)  # (c, 2)
    sizes = np.maximum(np.ceil(high + offset + margin - 1e-9), 1).astype(np.int64)
    position = plane + offset[chart][:, None, :]
    texel_chart = chart[tri]
    col, row = u + offset[texel_chart, 0], v + offset[texel_chart, 1]
    ok = (col >= 0) & (row >= 0) & (col < sizes[texel_chart, 0]) & (row < sizes[texel_chart, 1])
    tri, col, row, inside, distance, texel_chart = tri[ok], col[ok], row[ok], inside[ok], distance[ok], texel_chart[ok]
    # One record per texel: the claiming triangle, else the nearest one (then the lowest index).
    first = np.concatenate([[0], np.cumsum(sizes.prod(axis=1))[:-1]])
    flat = first[texel_chart] + row * sizes[texel_chart, 0] + col
    order = np.lexsort((distance, 2 * flat + ~inside))  # stable, and rasterize emits by triangle
    keep = np.ones(order.size, bool)
    keep[1:] = flat[order][1:] != flat[order][:-1]
    pick = order[keep]
    return Charts(
        chart=chart,
        axis=axis,
        position=position,
        sizes=sizes,
        texel_chart=texel_chart[pick],
        texel_row=row[pick],
        texel_col=col[pick],
        texel_triangle=tri[pick],
        texel_inside=inside[pick],
    )


def _extents(chart: np.ndarray, plane: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """(count, 2) lowest and highest texel positions of each chart's vertices (``plane`` (t, 3, 2))."""
    low = np.full((count, 2), np.inf)
    high = np.full((count, 2), -np.inf)
    for k in range(2):  # faster than (count, 2) at once or a vertex at a time
        np.minimum.at(low[:, k], chart, plane[:, :, k].min(axis=1))
        np.maximum.at(high[:, k], chart, plane[:, :, k].max(axis=1))
    return low, high


def unfold_lone_triangles(points, triangles, chart, plane, margin, claimed):
    """Move each triangle that is a chart of its own into the chart of a neighbour across one of
    its edges, laid out *unfolded* there: the shared edge keeps the neighbour's texel positions,
    the third vertex goes to the other side of it at its true distance from the edge (voxel units,
    one texel each).  Returns the new (chart, plane); charts are renumbered.

    A lone triangle is one that faces another way than every neighbour (the mesh folds over
    there, or turns through a right angle) or that was moved out of its chart because its
    projection overlapped the chart's (:func:`build_charts`).  Each such chart pays a bilinear ring
    all round and the atlas gap: on the house benchmark at 180 m (512 px, f = 2) 51 of 91 charts
    held one triangle each, with 4,415 of the 17,161 needed texels.  Unfolded, a lone triangle
    shares its edge texels with its neighbour and its ring there: 40 charts and 15,475 needed
    texels there, and 13-16 % less memory at 90-180 m (same meshes and colour error within 0.06).

    A move is refused where the third vertex is already in that chart (one texture position per
    vertex and chart), where the shared edge appears shorter than ``ADOPT_SCORE`` times its length
    in the neighbour's chart (its texels would stretch along it), where the triangle would claim
    a texel centre the chart already claims (``claimed``: (triangle, u, v) of the claimed centres,
    as :func:`rasterize` gives them), and where it would take the chart's tile past
    :data:`MAX_CHART`.  The largest lone triangles go first; a triangle moved makes its lone
    neighbours movable in the next round.

    A triangle folded back over a square's chart goes to the square's right side:

    >>> pts = np.array([[0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0], [2, 2, 1]], float)
    >>> tris = np.array([[0, 1, 2], [0, 2, 3], [1, 4, 2]])
    >>> ch = build_charts(pts, tris, 1)
    >>> ch.chart.tolist(), np.round(ch.position[2, 1] - ch.position[2, 0], 3).tolist()
    ([0, 0, 0], [2.236, 2.0])

    Each round lists every candidate move at once (:func:`_unfoldings`), rasterizes them together
    and accepts them one after the other in that order where the checks above, on the charts as
    the moves before left them, allow it (:class:`_Unfolding`).
    """
    state = _Unfolding(points, triangles, chart, plane, claimed)
    edges = _edge_index(triangles, points.shape[0])
    geometry = _edge_geometry(points, triangles)
    corners = points[triangles]
    area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    largest_first = np.argsort(-area, kind="stable")
    while True:
        # Every way a lone triangle could go, largest triangles first, rasterized together.
        lone = largest_first[state.size[state.chart[largest_first]] == 1]
        candidates = _unfoldings(triangles, state.chart, state.plane, state.size, lone, edges, geometry)
        if not candidates[0].size or not state.move(margin, *candidates):
            break
    return np.unique(state.chart, return_inverse=True)[1].reshape(-1).astype(np.int64), state.plane


class _Unfolding:
    """The charts while :func:`unfold_lone_triangles` moves triangles: each triangle's chart and
    texel positions, each chart's triangle count and vertex extents, the claimed texel centres
    (integer keys, :meth:`keys`) and those of each triangle, and how many triangles of each chart
    use each vertex (key chart * n + vertex, n the vertex count).  What the greedy loop reads is
    kept in flat Python lists, sets and dicts of numbers (no numpy scalars, no small lists for the
    garbage collector to walk)."""

    def __init__(self, points, triangles, chart, plane, claimed):
        self.n, self.vertices = points.shape[0], triangles.reshape(-1).tolist()  # triangle s: [3 s, 3 s + 3)
        self.chart, self.plane = chart.copy(), plane.copy()
        count = int(chart.max(initial=-1)) + 1
        self.size = np.bincount(chart, minlength=count)
        low, high = _extents(chart, plane, count)
        self.extent = np.concatenate([low, high], axis=1).reshape(-1).tolist()  # chart c: low u, v, high u, v at 4 c
        uses, times = np.unique(np.repeat(chart, 3) * self.n + triangles.reshape(-1), return_counts=True)
        self.uses = dict(zip(uses.tolist(), times.tolist()))
        # Every centre looked up lies in a chart's tile, which keeps the chart's own triangles (a
        # chart that takes triangles has two or more, which never leave) and stays within
        # MAX_CHART texels: the keys' window reaches that far beyond every position.
        tri, u, v = claimed
        known = plane[np.isfinite(plane)]
        self.base = (
            min(int(np.floor(known.min(initial=0.0))), int(u.min(initial=0)), int(v.min(initial=0))) - MAX_CHART - 2
        )
        self.span = (
            max(int(np.ceil(known.max(initial=0.0))), int(u.max(initial=0)), int(v.max(initial=0)))
            + MAX_CHART
            + 3
            - self.base
        )
        order = np.argsort(tri, kind="stable")
        self.owned = self.keys(chart[tri[order]], u[order], v[order]).tolist()  # triangle s: from owned_from[s]
        self.owned_from = np.searchsorted(tri[order], np.arange(chart.size + 1)).tolist()
        self.claim = set(self.owned)

    def keys(self, chart: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
        """int64 keys of texel centres (u, v) of ``chart``, one to one inside the window."""
        return (chart * self.span + (v - self.base)) * self.span + (u - self.base)

    def move(self, margin, lone, across, third, new) -> bool:
        """Move each lone triangle into the chart of the triangle ``across`` from it, its vertex
        ``third`` off their shared edge and its texel positions ``new`` (m, 3, 2), one candidate
        after the other where allowed (see :func:`unfold_lone_triangles`); whether any moved."""
        tri, u, v, inside, _ = rasterize(new, margin)
        tri, u, v = tri[inside], u[inside], v[inside]
        bounds = np.searchsorted(tri, np.arange(lone.size + 1)).tolist()  # rasterize emits by triangle
        source, target = self.chart[lone], self.chart[across]
        keys = self.keys(
            target[tri], u, v
        ).tolist()  # those outside the window are of moves past MAX_CHART, never looked up
        size, extent, uses, claim, n, moved = self.size.tolist(), self.extent, self.uses, self.claim, self.n, []
        candidates = zip(
            lone.tolist(),
            source.tolist(),
            target.tolist(),
            third.tolist(),
            *new.min(axis=1).T.tolist(),
            *new.max(axis=1).T.tolist(),
        )
        for i, (s, own, other, apex, new_lu, new_lv, new_hu, new_hv) in enumerate(candidates):
            # Not moved already (its chart would be empty), and the vertex not in that chart.
            if size[own] != 1 or uses.get(other * n + apex, 0) > 0:
                continue
            at = 4 * other
            lu, lv, hu, hv = (
                min(extent[at], new_lu),
                min(extent[at + 1], new_lv),
                max(extent[at + 2], new_hu),
                max(extent[at + 3], new_hv),
            )
            if hu - lu + 2 * margin + 1 > MAX_CHART or hv - lv + 2 * margin + 1 > MAX_CHART:
                continue
            mine = keys[bounds[i] : bounds[i + 1]]
            if not claim.isdisjoint(mine):
                continue
            # A triangle moved stays in a chart of two or more: its claims are never looked up again.
            claim.difference_update(self.owned[self.owned_from[s] : self.owned_from[s + 1]])
            claim.update(mine)
            for vertex in self.vertices[3 * s : 3 * s + 3]:
                uses[own * n + vertex] -= 1
                uses[other * n + vertex] = uses.get(other * n + vertex, 0) + 1
            size[own], size[other] = 0, size[other] + 1
            extent[at : at + 4] = lu, lv, hu, hv
            moved.append(i)
        self.chart[lone[moved]], self.plane[lone[moved]] = target[moved], new[moved]
        self.size = np.array(size, np.int64)
        return bool(moved)


def _edge_index(triangles: np.ndarray, n: int) -> tuple[int, np.ndarray, np.ndarray]:
    """The triangles across every edge of the (t, 3) ``triangles`` (of vertices < ``n``): ``n``,
    the sorted keys of their edges (:func:`_edge_keys`) and the triangle of each, ascending within
    a key (twice where a triangle has the edge twice)."""
    key = _edge_keys(triangles.reshape(-1), triangles[:, [1, 2, 0]].reshape(-1), n)
    order = np.argsort(key, kind="stable")
    return n, key[order], order // 3


def _edge_keys(a: np.ndarray, b: np.ndarray, n: int) -> np.ndarray:
    """Keys of the edges from vertices ``a`` to ``b`` (< ``n``), the same either way."""
    return np.minimum(a, b) * n + np.maximum(a, b)


def _edge_geometry(points: np.ndarray, triangles: np.ndarray) -> tuple[np.ndarray, ...]:
    """(t, 3) length, along and height of the edge e of each triangle, from its vertex e to the
    next: the edge's length, the third vertex's distance along it (a fraction of its length) and
    from it (voxel units)."""
    a = points[triangles]
    edge, off = a[:, [1, 2, 0]] - a, a[:, [2, 0, 1]] - a
    length = np.sqrt(_dot(edge, edge))
    with np.errstate(divide="ignore", invalid="ignore"):
        along = _dot(off, edge) / (length * length)
    rest = off - along[..., None] * edge
    return length, along, np.sqrt(_dot(rest, rest))


def _dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Sums of ``x * y`` over the last axis, added in order, as ``@`` and :func:`numpy.linalg.norm`
    add a 2- or 3-vector: the vectorized unfoldings round as one unfolding at a time would."""
    total = x[..., 0] * y[..., 0]
    for k in range(1, x.shape[-1]):
        total = total + x[..., k] * y[..., k]
    return total


def _ranges(start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """The integers start[i], ..., start[i] + count[i] - 1 for every i, one after the other."""
    return np.arange(count.sum()) - np.repeat(np.cumsum(count) - count - start, count)


def _unfoldings(triangles, chart, plane, size, lone, edges, geometry):
    """Every way the ``lone`` triangles can go, in their order, then by edge, then by neighbour:
    across each edge (:func:`_edge_index`) into each neighbour's chart of two or more triangles
    (``size``) where the edge appears at least ``ADOPT_SCORE`` times its length, unfolded by the
    edges' ``geometry`` (:func:`_edge_geometry`).  Returns arrays (lone triangle, neighbour, the
    lone triangle's vertex off the shared edge, its unfolded texel positions (m, 3, 2))."""
    n, edge_key, edge_triangle = edges
    length, along, height = geometry
    s, e = np.repeat(lone, 3), np.tile(np.arange(3), lone.size)
    keep = ~(length[s, e] <= EPS) & ~(height[s, e] <= EPS)
    s, e = s[keep], e[keep]
    a, b, c = triangles[s, e], triangles[s, (e + 1) % 3], triangles[s, (e + 2) % 3]
    key = _edge_keys(a, b, n)
    first = np.searchsorted(edge_key, key)
    count = np.searchsorted(edge_key, key, side="right") - first
    j = edge_triangle[_ranges(first, count)]
    s, e, a, b, c = (np.repeat(x, count) for x in (s, e, a, b, c))
    keep = (j != s) & (size[chart[j]] >= 2)
    s, e, a, b, c, j = (x[keep] for x in (s, e, a, b, c, j))
    # The shared edge and the third vertex in the neighbour's chart.
    ka, kb = np.argmax(triangles[j] == a[:, None], axis=1), np.argmax(triangles[j] == b[:, None], axis=1)
    pa, pb, opposite = plane[j, ka], plane[j, kb], plane[j, 3 - ka - kb]
    flat = pb - pa
    shown = np.sqrt(_dot(flat, flat))
    keep = ~(shown < ADOPT_SCORE * length[s, e])
    s, e, c, j, pa, pb, opposite, flat, shown = (x[keep] for x in (s, e, c, j, pa, pb, opposite, flat, shown))
    # The edge's normal away from the neighbour's third vertex.
    normal = np.stack([-flat[:, 1], flat[:, 0]], axis=1) / shown[:, None]
    normal = np.where((_dot(opposite - pa, normal) > 0)[:, None], -normal, normal)
    new = np.empty((s.size, 3, 2))
    row = np.arange(s.size)
    new[row, e], new[row, (e + 1) % 3] = pa, pb
    new[row, (e + 2) % 3] = pa + along[s, e][:, None] * flat + height[s, e][:, None] * normal
    return s, j, c, new


def chart_masks(charts: Charts) -> list[np.ndarray]:
    """One (h, w) boolean mask per chart: its needed texels, the shape :func:`farfield.core.techniques.tdm.mask_atlas.pack_masks` places.

    >>> pts = np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0], [0, 3, 0]], float)
    >>> chart_masks(build_charts(pts, np.array([[0, 1, 2], [0, 2, 3]]), 1))[0].astype(int).sum(), (5, 6)
    (np.int64(30), (5, 6))
    """
    masks = [np.zeros((int(h), int(w)), bool) for w, h in charts.sizes]
    order = np.argsort(charts.texel_chart, kind="stable")
    bounds = np.searchsorted(charts.texel_chart[order], np.arange(charts.count + 1))
    for i, mask in enumerate(masks):
        pick = order[bounds[i] : bounds[i + 1]]
        mask[charts.texel_row[pick], charts.texel_col[pick]] = True
    return masks


def chart_colours(field: VoxelField, world: np.ndarray, charts: Charts, oversampling: int) -> np.ndarray:
    """The colours of the needed texels of ``charts`` (in the order of ``charts.texel_chart``),
    sampled from ``field`` through the world triangles ``world`` (t, 3, 3): :func:`chart_pages`
    before the atlas layout places them (so the bake computes them while the packer runs)."""
    owner = charts.texel_triangle
    p = charts.position[owner]  # (m, 3, 2)
    cx, cy = charts.texel_col + 0.5, charts.texel_row + 0.5
    d1, d2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    det = np.where(np.abs(det) < 1e-300, 1.0, det)
    qx, qy = cx - p[:, 0, 0], cy - p[:, 0, 1]
    b1 = (qx * d2[:, 1] - qy * d2[:, 0]) / det
    b2 = (d1[:, 0] * qy - d1[:, 1] * qx) / det
    # Texels outside the triangle take the colour at (about) its nearest point: clamped and
    # renormalized barycentrics, never an extrapolation far along a sliver.
    b = np.clip(np.stack([1.0 - b1 - b2, b1, b2], axis=1), 0.0, None)
    b /= np.maximum(b.sum(axis=1, keepdims=True), 1e-300)
    points = np.einsum("mk,mkc->mc", b, world[owner])
    return sample_field(field, field.from_world(points), oversampling)


def chart_pages(
    field: VoxelField,
    world: np.ndarray,
    charts: Charts,
    layout: MaskLayout,
    oversampling: int,
    colours: np.ndarray | None = None,
) -> list[np.ndarray]:
    """The (H, W, 4) uint8 atlas pages of ``charts`` placed by ``layout``: every needed texel
    coloured from the voxel field through the world triangles ``world`` (t, 3, 3) (see the module
    docstring), every other texel copied from the nearest needed one, so that every texel is
    opaque and coarser mip levels bleed a chart's own colours into its gap.

    Where the field keeps normals (:attr:`VoxelField.normal`) the pages are (H, W, 8): colour, then
    the normal channel sampled alike (:func:`sample_field`), for
    :func:`farfield.core.layering.tiles.split_channels`.  ``colours``: :func:`chart_colours` of the
    same arguments, if the caller has them already (they do not depend on ``layout``)."""
    if colours is None:
        colours = chart_colours(field, world, charts, oversampling)
    page_of = layout.page[charts.texel_chart]
    rows = layout.y[charts.texel_chart] + charts.texel_row
    cols = layout.x[charts.texel_chart] + charts.texel_col
    pages = []
    for k, (w, h) in enumerate(layout.page_sizes.tolist()):
        page = np.zeros((h, w, colours.shape[1]), np.uint8)
        here = page_of == k
        page[rows[here], cols[here]] = colours[here]
        empty = np.ones((h, w), bool)
        empty[rows[here], cols[here]] = False
        if empty.any() and not empty.all():
            index = distance_transform_edt(empty, return_distances=False, return_indices=True)
            page = page[index[0], index[1]]
        pages.append(page)
    return pages


def sample_field(field: VoxelField, positions: np.ndarray, n: int) -> np.ndarray:
    """(m, 4) uint8 colours at voxel-space ``positions`` (m, 3): the ``n`` nearest voxel centres
    averaged with inverse-distance weights; alpha 255.

    Where the field keeps normals, (m, 8): the colour, then the normal (encoded as
    :func:`~farfield.core.impostor.impostor.encode_normals`) of the same voxels with the same
    weights, renormalized (one voxel's normal is copied as recorded); where it keeps the material,
    (m, 12) or (m, 16): then the material (and emissive) channels, the same weighted mean of the
    stored bytes (the emission's sRGB bytes averaged as they are, which errs by at most the sRGB
    curve's bend between neighbouring voxels)."""
    tree = cKDTree(field.centres)
    k = min(int(n), field.count)
    distance, index = tree.query(positions, k=k)
    if k == 1:
        rgb = field.rgba[index, :3].astype(np.float64)
    else:
        weight = 1.0 / np.maximum(distance, 1e-6)
        weight /= weight.sum(axis=1, keepdims=True)
        rgb = np.einsum("mk,mkc->mc", weight, field.rgba[index, :3].astype(np.float64))
    out = np.empty((positions.shape[0], 4), dtype=np.uint8)
    out[:, :3] = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    out[:, 3] = 255
    if field.normal is None:
        return out
    if k == 1:
        normal = field.normal[index]
    else:  # the mean direction (a zero mean, opposite normals cancelling, decodes as none)
        normal = encode_normals(_unit(np.einsum("mk,mkc->mc", weight, decode_normals(field.normal[index]))))
    if field.material is None:
        return np.concatenate([out, normal], axis=1)
    # The material (and emissive) channels: the same weighted mean of the stored values, alpha 255.
    if k == 1:
        material = field.material[index]
    else:
        mean = np.einsum("mk,mkc->mc", weight, field.material[index].astype(np.float64))
        material = np.clip(np.rint(mean), 0, 255).astype(np.uint8)
    return np.concatenate([out, normal, material], axis=1)


def _unit(v: np.ndarray) -> np.ndarray:
    """Rows of ``v`` (m, 3) scaled to unit length; zero rows stay zero."""
    length = np.linalg.norm(v, axis=1, keepdims=True)
    return np.divide(v, length, out=np.zeros_like(v), where=length > 0.0)


def chart_uvs(charts: Charts, layout: MaskLayout) -> np.ndarray:
    """(t, 3, 2) page UVs (glTF: (0, 0) the page's top-left) of every triangle's vertices.

    >>> pts = np.array([[0, 0, 0], [4, 0, 0], [4, 3, 0], [0, 3, 0]], float)
    >>> ch = build_charts(pts, np.array([[0, 1, 2], [0, 2, 3]]), 1)
    >>> lay = MaskLayout(np.array([0]), np.array([2]), np.array([0]), np.array([[8, 10]]))
    >>> chart_uvs(ch, lay)[0].tolist()  # tile positions (1, 1), (5, 1), (5, 4), moved right 2
    [[0.375, 0.1], [0.875, 0.1], [0.875, 0.4]]
    """
    offset = np.stack([layout.x, layout.y], axis=1)[charts.chart]  # (t, 2)
    size = layout.page_sizes[layout.page[charts.chart]]  # (t, 2) W, H
    return (charts.position + offset[:, None, :]) / size[:, None, :]

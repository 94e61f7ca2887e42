"""Gap-free layer recording: a scene and a LayerPlan in, (k, h, w, 4) uint8 RGBA layers out.

Seed 000 §3.3.2.  Every layer is rendered from the plan's reference viewpoint with a frustum that
tightly encloses the part, clipped to the layer's closed depth slab.  Coverage is conservative: a
texel is written when its closed square meets the clipped triangle, not only when its centre is
covered, so sub-texel geometry is never lost and a clipping edge on a border is written into both
adjacent layers with the same texels (the closed slabs share it), diagonals included.  The thesis
did this with explicit clipping, outlines, points and a 2x2 fix-up pass; farfield clips every
(triangle, layer) pair on the CPU in float64 (:func:`slab_instances`), draws each pair as one
instanced texel-aligned rectangle, and tests the texel square against the clipped polygon exactly
in the fragment shader (shaders/slab_instanced.vert, slab.frag), which gives the same guarantee in
one pass.

Each layer draws only the triangles whose depth range meets its slab: triangles are bucketed once
by layer (cost O(triangles + layers + spans)), never drawn for every layer.

Deviation from an earlier farfield: the clipping ran in a geometry shader on float32 eye
coordinates.  Clipping on the CPU in float64 keeps the polygons exact at any world offset and makes
them testable without GL; one numba kernel pairs, clips and bounds (:func:`_pair_kernel`, bit for
bit the numpy functions below).  Each object is drawn with the slab.frag variant of its material
(:func:`slab_variant`).  On llvmpipe, the benchmark's untextured 100k-triangle part at 512 (61
layers of 685 x 590 texels, 152k pairs) spends ~0.045 s pairing and ~0.25 s in the GL, of which
~0.05 s draws the rectangles with a constant fragment shader (README, "Recording against its
lower bound").  Drawing each triangle once instead, and sorting its texels into slabs with image
atomics, keeps this coverage but was 1.1-1.7x slower on llvmpipe (``benchmarks/bench_recording.py
--once``; docs/measurements/layered.md, "Drawing each triangle once").
"""

from __future__ import annotations

import time
import warnings
from collections import OrderedDict
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import closing
from dataclasses import dataclass
from itertools import chain

import moderngl
import numpy as np
from numba import njit

from farfield.core.layering.atlas import pack
from farfield.core.layering.plan import LayerPlan
from farfield.core.render.alpha_mips import max_alpha_texture
from farfield.core.render.context import check_target_size, gl_context
from farfield.core.render.cut_colours import cut_weighted_linear
from farfield.core.render.programs import linear_texture, park_framebuffer, program, set_material, srgb_texture
from farfield.core.render.raster import mesh_variant
from farfield.core.scene import Scene, SceneObject, emits
from farfield.core.sidedness import faces_seen

# Most vertices a triangle keeps after clipping to a slab: each of the two planes adds at most one.
MAX_POLYGON = 5

# Per-instance record of shaders/slab_instanced.vert, float32: rect 4, polygon 10 + count + 1 unused,
# triangle 3 x (texel x, texel y, 1 / depth), uv 3 x 2, colour 3 x 4.
INSTANCE_FORMAT = "4f 4f 4f 4f 3f 3f 3f 4f 2f 4f 4f 4f /i"
INSTANCE_ATTRIBUTES = (
    "i_rect", "i_poly01", "i_poly23", "i_poly4", "i_tri0", "i_tri1", "i_tri2",
    "i_uv01", "i_uv2", "i_color0", "i_color1", "i_color2",
)  # fmt: skip
INSTANCE_FLOATS = 43
# With the normal channel (the NORMALS variant): three world shading normals appended.
NORMAL_FORMAT, NORMAL_ATTRIBUTES, NORMAL_FLOATS = ("3f", "3f", "3f"), ("i_normal0", "i_normal1", "i_normal2"), 9
# With a normal map besides (the NORMAL_MAP variant): its uv and the tangents at the three vertices
# after the normals, and one float of padding, read as seven vec4 (a GL guarantees 16 vertex inputs;
# the variant does not read the vertex colours, whose floats it skips).
MAP_FORMAT, MAP_ATTRIBUTES, MAP_FLOATS = ("4f",) * 7, tuple(f"i_map{k}" for k in range(7)), 19
# With a material uv of its own and no normal map (the MATERIAL_UV_OWN variant): that uv after the
# normals and one float of padding, the normals and it read as four vec4 in the normals' place.
OWN_FORMAT, OWN_ATTRIBUTES, OWN_FLOATS = ("4f",) * 4, tuple(f"i_own{k}" for k in range(4)), 7


@dataclass(frozen=True, slots=True)
class RecordedLayers:
    """The recorded layers of one plan, nearest first."""

    rgba: np.ndarray  # (k, h, w, 4) uint8 (8 with normals); row 0 the bottom image row (GL order), alpha 255 = covered
    eye_borders: np.ndarray  # (k + 1,) float64 slab borders, eye depth from the reference viewpoint
    drawn_triangles: np.ndarray  # (k,) int64 triangles drawn per layer (clipped pairs with a rectangle)

    @property
    def coverage(self) -> np.ndarray:
        """(k, h, w) bool: texels written in each layer."""
        return self.rgba[..., 3] > 0


@dataclass(frozen=True, slots=True)
class SlabInstances:
    """The n (triangle, layer) pairs of one object to draw, grouped by layer, in texel coordinates.

    Point arrays are coordinate-first, (coordinate, vertex, pair), like everything the clipping
    touches: numpy then loops along the long pair axis; reducing over a trailing axis of 3 or 5 runs
    ~30x slower.
    """

    triangle: np.ndarray  # (n,) int64 face index of each pair
    offsets: np.ndarray  # (k + 1,) int64; layer i draws pairs offsets[i]:offsets[i+1]
    rect: np.ndarray  # (4, n) int64 texel rectangle x0, y0, x1, y1 (exclusive ends), inside the image
    polygon: np.ndarray  # (2, 5, n) float64 clipped polygon, texel coordinates; unused slots repeat vertex 0
    count: np.ndarray  # (n,) int64 polygon vertices, 1..5
    vertices: np.ndarray  # (3, 3, n) float64 unclipped triangle: texel x, texel y, 1 / eye depth


def eye_coordinates(plan: LayerPlan, points: np.ndarray) -> np.ndarray:
    """(n, 3) float64 eye-frame coordinates (along u, v, axis; z = eye depth) of world ``points`` (n, 3).

    Differences to the reference viewpoint are taken first, in float64, so that continental
    offsets cancel before anything is rotated (or, later, narrowed).
    """
    frame = np.stack([plan.u, plan.v, plan.axis])  # (3, 3) rows u, v, axis
    return (np.asarray(points, dtype=np.float64) - plan.reference_viewpoint) @ frame.T


def layer_buckets(eye_depth: np.ndarray, faces: np.ndarray, eye_borders: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Group triangles by the layers whose closed slab their depth range meets.

    Parameters
    ----------
    eye_depth : (v,) float64 vertex depths from the reference viewpoint.
    faces : (f, 3) int64.
    eye_borders : (k + 1,) float64 ascending slab borders.

    Returns
    -------
    order : (n,) int64 triangle indices, grouped by layer (a triangle spanning layers repeats).
    offsets : (k + 1,) int64; layer i draws ``order[offsets[i]:offsets[i+1]]``.
    """
    k = eye_borders.shape[0] - 1
    z = eye_depth[faces.T]  # (3, f): reducing over the leading axis is ~10x faster than the trailing one
    zmin, zmax = z.min(axis=0), z.max(axis=0)
    first = np.searchsorted(eye_borders[1:], zmin, side="left")
    last = np.searchsorted(eye_borders[:-1], zmax, side="right") - 1
    first, last = np.clip(first, 0, k - 1), np.clip(last, 0, k - 1)
    keep = (zmax >= eye_borders[0]) & (zmin <= eye_borders[-1]) & (first <= last)
    tri = np.flatnonzero(keep)
    spans = (last - first + 1)[tri]
    repeated = np.repeat(tri, spans)
    starts = np.repeat(np.cumsum(spans) - spans, spans)
    layer = np.repeat(first[tri], spans) + (np.arange(repeated.shape[0]) - starts)
    order = np.argsort(layer, kind="stable")
    offsets = np.concatenate([[0], np.cumsum(np.bincount(layer, minlength=k))])
    return repeated[order].astype(np.int64), offsets.astype(np.int64)


def _lerp_at(a: np.ndarray, b: np.ndarray, plane: np.ndarray) -> np.ndarray:
    """The points (3, n) where lines a -> b (3, n) reach depth ``plane`` (n,); z is the plane exactly."""
    t = (plane - a[2]) / (b[2] - a[2])
    point = a + t * (b - a)
    # On the plane exactly, so that no rounding moves a crossing out of the closed slab.
    point[2] = plane
    return point


def clip_to_slab(triangles: np.ndarray, near: np.ndarray, far: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Clip n eye-space triangles (3, 3, n) (coordinate, corner, triangle) to closed depth slabs.

    The polygon is the one Sutherland-Hodgman gives against z >= near, then z <= far: the corners
    inside the slab and the crossings of the edges with the two planes (an edge crosses a plane where
    its ends lie on different sides of it), in order around the triangle.  Vectorised without
    per-edge candidate lists: with the corners sorted by depth, z0 <= z1 <= z2, the boundary is the
    path v0 -> v1 -> v2 (A) and the edge v2 -> v0 (B), on each of which depth is monotonic, so the
    polygon is always [lowest point of A, v1 if inside, highest point of A, far crossing of B if
    z2 > far, near crossing of B if z0 < near]: at most 5 vertices.  Its orientation may be the
    reverse of the triangle's, which coverage does not depend on.

    Parameters
    ----------
    triangles : (3, 3, n) float64 eye-frame corners, coordinate-first (z = eye depth).
    near, far : (n,) float64 eye depths, near <= far; the slab of each triangle.

    Returns
    -------
    polygon : (3, 5, n) float64 convex polygons; slots past ``count`` repeat vertex 0.  Crossings
        lie on their plane exactly.
    count : (n,) int64 vertices, 0 where the triangle misses its slab.

    >>> tri = np.array([[[0.0, 0.0, 1.0], [2.0, 0.0, 3.0], [0.0, 2.0, 3.0]]]).T  # one triangle
    >>> polygon, count = clip_to_slab(tri, np.array([2.0]), np.array([2.5]))
    >>> int(count[0]), polygon[:, :4, 0].T.tolist()
    (4, [[1.0, 0.0, 2.0], [1.5, 0.0, 2.5], [0.0, 1.5, 2.5], [0.0, 1.0, 2.0]])
    >>> int(clip_to_slab(tri, np.array([3.5]), np.array([4.0]))[1][0])  # misses the slab
    0
    """
    near = np.asarray(near, dtype=np.float64)
    far = np.asarray(far, dtype=np.float64)
    v = [np.array(corner, dtype=np.float64) for corner in np.moveaxis(np.asarray(triangles), 1, 0)]  # 3 x (3, n)
    for i, j in ((0, 1), (1, 2), (0, 1)):  # sorting network on depth; keeps the cyclic order or reverses it
        swap = v[i][2] > v[j][2]
        v[i], v[j] = np.where(swap, v[j], v[i]), np.where(swap, v[i], v[j])
    v0, v1, v2 = v
    z0, z1, z2 = v0[2], v1[2], v2[2]
    below, above = z0 < near, z2 > far  # v0 in front of the slab, v2 behind it
    middle = (z1 >= near) & (z1 <= far)
    with np.errstate(divide="ignore", invalid="ignore"):  # crossings that do not exist are discarded
        low_a = np.where(below, _lerp_at(np.where(z1 >= near, v0, v1), np.where(z1 >= near, v1, v2), near), v0)
        high_a = np.where(above, _lerp_at(np.where(z1 <= far, v1, v0), np.where(z1 <= far, v2, v1), far), v2)
        far_b = _lerp_at(v0, v2, far)
        near_b = _lerp_at(v0, v2, near)
    # Compact [low_a, v1?, high_a, far_b?, near_b?] in order; unused slots take vertex 0.
    tail = np.where(above, far_b, near_b)  # first of B's crossings
    last = np.where(above & below, near_b, low_a)  # second of B's crossings
    polygon = np.stack(
        [
            low_a,
            np.where(middle, v1, high_a),
            np.where(middle, high_a, np.where(above | below, tail, low_a)),
            np.where(middle, np.where(above | below, tail, low_a), last),
            np.where(middle & above & below, near_b, low_a),
        ],
        axis=1,
    )
    count = 2 + middle.astype(np.int64) + above + below
    count[(z2 < near) | (z0 > far)] = 0
    return polygon, count


def texel_coordinates(eye: np.ndarray, half_tan: np.ndarray, resolution: np.ndarray) -> np.ndarray:
    """(2, ...) float64 texel coordinates (origin at the image's lower-left corner) of eye points (3, ...).

    Coordinate-first, like :func:`clip_to_slab`; the shader's old ``to_texel``.

    >>> eye = np.array([[0.0, 0.0, 2.0], [2.0, -1.0, 2.0]]).T
    >>> texel_coordinates(eye, np.array([1.0, 1.0]), np.array([8, 4])).T.tolist()
    [[4.0, 2.0], [8.0, 1.0]]
    """
    scale = np.reshape(np.asarray(half_tan, dtype=np.float64), (2,) + (1,) * (eye.ndim - 1))
    size = np.reshape(np.asarray(resolution, dtype=np.float64), scale.shape)
    return (eye[:2] / (eye[2] * scale) * 0.5 + 0.5) * size


def texel_rectangles(lo: np.ndarray, hi: np.ndarray, resolution: np.ndarray) -> np.ndarray:
    """(4, n) int64 rectangles x0, y0, x1, y1 (ends exclusive) of the texels whose closed squares
    meet the boxes [lo, hi] (2, n) in texel coordinates, clamped to the image.

    A bound exactly on a texel edge takes in the texel on the other side too, so that a polygon
    that touches a texel only along its edge still reaches the fragment shader there.  An empty
    rectangle (x0 >= x1 or y0 >= y1) means the box lies outside the image.

    >>> lo = np.array([[2.5, 3.0], [-2.0, 1.5]]).T
    >>> texel_rectangles(lo, lo, np.array([8, 8])).T.tolist()
    [[2, 2, 3, 4], [0, 1, 0, 2]]
    """
    size = np.asarray(resolution, dtype=np.float64)[:, None]
    first = np.floor(lo)
    first -= first == lo
    last = np.floor(hi) + 1.0
    return np.concatenate([np.clip(first, 0.0, size), np.clip(last, 0.0, size)]).astype(np.int64)


def facing_the_image(texel: np.ndarray, depth: np.ndarray, faces: np.ndarray, resolution: np.ndarray) -> np.ndarray:
    """Indices (ascending) of the triangles that may reach the image: all but those whose three
    vertices lie in front of the eye and beyond the same edge of the image.

    Such a triangle lies in the half-space beyond that edge's frustum plane (a linear condition in
    eye space), and so does every piece of it a slab clips, whose texel rectangle is then empty:
    dropping it first spares the slab pairing and clipping (a cube face of an envmap sees about a
    sixth of the scene around it) and changes nothing recorded.  The slack, a millionth of a texel
    plus a billionth of the coordinate, keeps triangles whose rounding could put them on the edge.

    Parameters
    ----------
    texel : (2, v) float64 texel coordinates of the vertices (:func:`texel_coordinates`).
    depth : (v,) float64 eye depths of the vertices.
    faces : (f, 3) int64.
    resolution : (2,) int64 texels along u and v.

    >>> texel = np.array([[-3.0, -1.0, 2.0, 9.0, 10.0], [1.0, 1.0, 1.0, 1.0, 1.0]])
    >>> faces = np.array([[0, 1, 1], [0, 1, 2], [3, 4, 4], [0, 3, 4]])
    >>> facing_the_image(texel, np.ones(5), faces, np.array([8, 8])).tolist()
    [1, 3]
    >>> facing_the_image(texel, np.array([1.0, -1.0, 1.0, 1.0, 1.0]), faces, np.array([8, 8])).tolist()  # one behind the eye
    [0, 1, 3]
    """
    size = np.asarray(resolution, dtype=np.float64)[:, None]
    with np.errstate(invalid="ignore"):  # NaN or infinite coordinates (behind or on the eye plane) are masked below
        slack = 1e-6 + 1e-9 * np.abs(texel)
        low, high = texel < -slack, texel > size + slack
    beyond = (low[0] * np.uint8(1)) | (high[0] * np.uint8(2)) | (low[1] * np.uint8(4)) | (high[1] * np.uint8(8))
    beyond[~(depth > 0.0)] = 0
    corner = beyond[faces.T]  # (3, f)
    return np.flatnonzero((corner[0] & corner[1] & corner[2]) == 0)


@njit(cache=True)
def _bucket_kernel(depth, faces, triangles, eye_borders):
    """:func:`layer_buckets` of ``faces[triangles]`` by counting instead of sorting: the same pairs
    in the same order (by layer, then as in ``triangles``), as face indices, with each pair's layer."""
    k = eye_borders.shape[0] - 1
    upper, lower = eye_borders[1:], eye_borders[:-1]
    n = triangles.shape[0]
    first, last = np.empty(n, np.int64), np.empty(n, np.int64)
    offsets = np.zeros(k + 1, np.int64)
    for m in range(n):
        t = triangles[m]
        z0, z1, z2 = depth[faces[t, 0]], depth[faces[t, 1]], depth[faces[t, 2]]
        zmin, zmax = min(z0, min(z1, z2)), max(z0, max(z1, z2))
        f = min(max(np.searchsorted(upper, zmin, side="left"), 0), k - 1)
        g = min(max(np.searchsorted(lower, zmax, side="right") - 1, 0), k - 1)
        if not (zmax >= eye_borders[0] and zmin <= eye_borders[k] and f <= g):
            f, g = 1, 0  # meets no slab
        first[m], last[m] = f, g
        for i in range(f, g + 1):
            offsets[i + 1] += 1
    for i in range(k):
        offsets[i + 1] += offsets[i]
    order, layer = np.empty(offsets[k], np.int64), np.empty(offsets[k], np.int64)
    at = offsets[:k].copy()
    for m in range(n):
        for i in range(first[m], last[m] + 1):
            order[at[i]], layer[at[i]] = triangles[m], i
            at[i] += 1
    return order, layer, offsets


@njit(cache=True, error_model="numpy")  # a crossing that does not exist divides by zero; it is never used
def _lerp_into(out, slot, a, b, plane):
    """out[:, slot] = the point where line a -> b (3,) reaches depth ``plane``; :func:`_lerp_at`'s
    arithmetic, one pair at a time."""
    t = (plane - a[2]) / (b[2] - a[2])
    for c in range(2):
        out[c, slot] = a[c] + t * (b[c] - a[c])
    out[2, slot] = plane


@njit(cache=True, error_model="numpy")
def _pair_kernel(
    eye,
    at_vertex,
    faces,
    pairs,
    layers,
    eye_borders,
    half_tan,
    resolution,
    triangle,
    layer,
    rect,
    polygon,
    count,
    vertices,
):
    """Clip, project and bound every (triangle, layer) pair (:func:`clip_to_slab`,
    :func:`texel_coordinates` and :func:`texel_rectangles` fused, the same float64 operations in
    the same order, so the records are bit for bit theirs); writes the kept pairs to the front of
    the outputs, in input order, and returns how many were kept."""
    kept = 0
    v = np.empty((3, 3))  # (corner, coordinate), sorted by depth
    poly = np.empty((3, 5))  # (coordinate, slot): the clipped polygon in eye coordinates
    low_a, high_a, far_b, near_b = np.empty((3, 1)), np.empty((3, 1)), np.empty((3, 1)), np.empty((3, 1))
    size_x, size_y = float(resolution[0]), float(resolution[1])
    for n in range(pairs.shape[0]):
        f, i = pairs[n], layers[n]
        near, far = eye_borders[i], eye_borders[i + 1]
        for j in range(3):
            for c in range(3):
                v[j, c] = eye[c, faces[f, j]]
        for i0, i1 in ((0, 1), (1, 2), (0, 1)):  # the sorting network of clip_to_slab
            if v[i0, 2] > v[i1, 2]:
                for c in range(3):
                    v[i0, c], v[i1, c] = v[i1, c], v[i0, c]
        z0, z1, z2 = v[0, 2], v[1, 2], v[2, 2]
        if z2 < near or z0 > far:
            continue
        below, above = z0 < near, z2 > far
        middle = z1 >= near and z1 <= far
        if below:
            if z1 >= near:
                _lerp_into(low_a, 0, v[0], v[1], near)
            else:
                _lerp_into(low_a, 0, v[1], v[2], near)
        else:
            low_a[:, 0] = v[0]
        if above:
            if z1 <= far:
                _lerp_into(high_a, 0, v[1], v[2], far)
            else:
                _lerp_into(high_a, 0, v[0], v[1], far)
        else:
            high_a[:, 0] = v[2]
        _lerp_into(far_b, 0, v[0], v[2], far)
        _lerp_into(near_b, 0, v[0], v[2], near)
        tail = far_b if above else near_b
        last = near_b if above and below else low_a
        either = tail if above or below else low_a
        poly[:, 0] = low_a[:, 0]
        poly[:, 1] = v[1] if middle else high_a[:, 0]
        poly[:, 2] = high_a[:, 0] if middle else either[:, 0]
        poly[:, 3] = either[:, 0] if middle else last[:, 0]
        poly[:, 4] = near_b[:, 0] if middle and above and below else low_a[:, 0]
        lo_x = lo_y = np.inf
        hi_x = hi_y = -np.inf
        finite = True
        for k in range(5):
            x = (poly[0, k] / (poly[2, k] * half_tan[0]) * 0.5 + 0.5) * size_x
            y = (poly[1, k] / (poly[2, k] * half_tan[1]) * 0.5 + 0.5) * size_y
            finite = finite and np.isfinite(x) and np.isfinite(y)
            polygon[0, k, kept], polygon[1, k, kept] = x, y
            lo_x, hi_x, lo_y, hi_y = min(lo_x, x), max(hi_x, x), min(lo_y, y), max(hi_y, y)
        x0, y0 = np.floor(lo_x), np.floor(lo_y)
        x0 -= x0 == lo_x
        y0 -= y0 == lo_y
        box = (
            min(max(x0, 0.0), size_x),
            min(max(y0, 0.0), size_y),
            min(max(np.floor(hi_x) + 1.0, 0.0), size_x),
            min(max(np.floor(hi_y) + 1.0, 0.0), size_y),
        )
        if not finite or not (box[0] < box[2] and box[1] < box[3]):
            continue
        for c in range(4):
            rect[c, kept] = int(box[c])
        for j in range(3):
            for c in range(3):
                vertices[c, j, kept] = at_vertex[c, faces[f, j]]
        triangle[kept], layer[kept] = f, i
        count[kept] = 2 + middle + above + below
        kept += 1
    return kept


# id -> (object, faces_with_area) of the last few objects.  It holds the objects (so an id cannot be
# reused under it), so it is kept small: a worker's scene cache decides which scenes stay in memory,
# and a small object is cheap to test again.
_AREA_CACHE: OrderedDict[int, tuple[SceneObject, np.ndarray | None]] = OrderedDict()
_AREA_CACHED = 8


def faces_with_area(obj: SceneObject) -> np.ndarray | None:
    """Indices (ascending) of ``obj``'s triangles whose corners are not collinear in float64 world
    coordinates, or None when every one has an area (the usual case).

    No renderer draws a triangle of zero area, but the conservative recording would write the
    texels along its segment: a line the source never shows (an OBJ of one such triangle baked
    184 texels, all of them bloat).  The scene keeps them (face indices are what clusters and
    near-field ranges count); the recording leaves them out.  Cached for the last few objects: an
    envmap cell records each object for six faces.

    >>> flat = SceneObject("flat", np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2], [0, 1, 3]]))
    >>> faces_with_area(flat).tolist(), faces_with_area(SceneObject("one", flat.vertices, flat.faces[1:]))
    ([1], None)
    """
    cached = _AREA_CACHE.get(id(obj))
    if cached is not None and cached[0] is obj:
        _AREA_CACHE.move_to_end(id(obj))
        return cached[1]
    v, f = obj.vertices, obj.faces
    a = v[f[:, 0]]
    area = np.cross(v[f[:, 1]] - a, v[f[:, 2]] - a).any(axis=1)
    kept = None if area.all() else np.flatnonzero(area)
    _AREA_CACHE[id(obj)] = (obj, kept)
    while len(_AREA_CACHE) > _AREA_CACHED:
        _AREA_CACHE.popitem(last=False)
    return kept


def slab_instances(
    eye_vertices: np.ndarray,
    faces: np.ndarray,
    eye_borders: np.ndarray,
    half_tan: np.ndarray,
    resolution: np.ndarray,
    drawn: np.ndarray | None = None,
) -> SlabInstances:
    """Every (triangle, layer) pair of one object, clipped to the layer's closed slab and projected.

    Parameters
    ----------
    eye_vertices : (v, 3) float64 eye-frame vertices (:func:`eye_coordinates`).
    faces : (f, 3) int64.
    eye_borders : (k + 1,) float64 ascending slab borders, eye depth; the first is > 0.
    half_tan : (2,) float64 tangents of the frustum's half angles along u and v.
    resolution : (2,) int64 texels along u and v.

    Pairs whose clipped polygon is empty or whose rectangle misses the image are dropped, and so
    are pairs with a coordinate that is not finite (a polygon point on the eye plane, which a first
    border > 0 rules out).  ``drawn`` (ascending face indices, or None for all) leaves the other
    triangles out (:func:`faces_with_area`).
    """
    k = eye_borders.shape[0] - 1
    if not eye_borders[0] > 0.0:
        raise ValueError(f"the first slab border must lie in front of the eye, not at eye depth {eye_borders[0]!r}")
    eye = np.ascontiguousarray(eye_vertices.T)  # (3, v)
    with np.errstate(divide="ignore", invalid="ignore"):  # vertices behind the eye belong to no pair
        texel = texel_coordinates(eye, half_tan, resolution)
        at_vertex = np.concatenate([texel, 1.0 / eye[2:]])  # (3, v)
    seen = facing_the_image(texel, eye[2], faces, resolution)
    if drawn is not None:
        seen = np.intersect1d(seen, drawn, assume_unique=True)
    order, layers, offsets = _bucket_kernel(np.ascontiguousarray(eye[2]), faces, seen, eye_borders)
    n = order.shape[0]
    triangle, layer, count = np.empty(n, np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    rect, polygon, vertices = np.empty((4, n), np.int64), np.empty((2, MAX_POLYGON, n)), np.empty((3, 3, n))
    kept = _pair_kernel(eye, at_vertex, faces, order, layers, eye_borders, np.asarray(half_tan, np.float64), np.asarray(resolution, np.int64),
                        triangle, layer, rect, polygon, count, vertices)  # fmt: skip
    triangle, layer, count = triangle[:kept], layer[:kept], count[:kept]
    rect, polygon, vertices = (np.ascontiguousarray(a[..., :kept]) for a in (rect, polygon, vertices))
    offsets = np.concatenate([[0], np.cumsum(np.bincount(layer, minlength=k))]).astype(np.int64)
    return SlabInstances(triangle, offsets, rect, polygon, count, vertices)


def warm_kernels() -> float:
    """Compile (or load from numba's cache) the bucketing and pairing kernels of :func:`slab_instances` on one
    triangle and the atlas's placement kernel on two tiles, without GL; the seconds it took.  A render worker calls it when it starts, beside the
    other techniques' (:mod:`farfield.workers.tasks`), so the first layered or envmap cell does not pay it."""
    start = time.perf_counter()
    faces = np.array([[0, 1, 2]], dtype=np.int64)
    faces.flags.writeable = False  # as a SceneObject holds them: numba compiles read-only arrays apart
    slab_instances(
        np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 2.0]]),
        faces,
        np.array([0.5, 1.5, 2.5]),
        np.ones(2),
        np.array([4, 4]),
    )
    pack(np.array([[1, 1], [2, 1]]))  # the atlas's placement kernel (layered, envmap and TDM pages)
    return time.perf_counter() - start


def pair_normals(obj: SceneObject, triangle: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
    """(3, 3, n) float64 world shading normals (coordinate, corner, pair) of ``obj``'s triangles
    ``triangle`` (n,), on the side a viewer at ``viewpoint`` sees.

    The vertex normals where the object has them, else each triangle's face normal (glTF: flat
    shading where ``NORMAL`` is missing).  A double-sided triangle whose back faces ``viewpoint``
    has them reversed, as glTF draws the back of a double-sided material; a one-sided one keeps
    its front's.

    >>> tri = SceneObject("t", np.array([[0.0, 0, 5], [1, 0, 5], [0, 1, 5]]), np.array([[0, 1, 2]]))
    >>> (pair_normals(tri, np.array([0]), np.zeros(3))[:, 0, 0] + 0.0).tolist()  # its front (+z) faces away
    [0.0, 0.0, -1.0]
    >>> from dataclasses import replace
    >>> pair_normals(replace(tri, double_sided=False), np.array([0]), np.zeros(3))[:, 0, 0].tolist()
    [0.0, 0.0, 1.0]
    """
    corners = obj.faces[triangle].T  # (3, n)
    v = obj.vertices
    a, b, c = v[corners[0]], v[corners[1]], v[corners[2]]
    face = np.cross(b - a, c - a)  # (n, 3)
    if obj.normals is not None:
        normals = np.take(obj.normals.T, corners, axis=1)  # (3, 3, n)
    else:
        with np.errstate(invalid="ignore", divide="ignore"):
            unit = face / np.linalg.norm(face, axis=1, keepdims=True)
        normals = np.repeat(np.nan_to_num(unit).T[:, None, :], 3, axis=1)
    return np.where(_behind(obj, face, (a + b + c) / 3.0, viewpoint)[None, None, :], -normals, normals)


def records_normal_map(obj: SceneObject) -> bool:
    """Whether the normal channel of ``obj`` is recorded through its normal map: where it has one
    and no vertex colours (the NORMAL_MAP variant reuses their vertex inputs; such an object keeps
    its vertex normals, which the docs say)."""
    return obj.normal_texture is not None and obj.normals is not None and obj.vertex_colors is None


def _behind(obj: SceneObject, face: np.ndarray, centre: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
    """(n,) bool: the double-sided triangles (face normals (n, 3), centres (n, 3)) whose back faces
    ``viewpoint``, whose shading frame is reversed (glTF: the back of a double-sided material)."""
    if not obj.double_sided:
        return np.zeros(face.shape[0], dtype=bool)
    return np.einsum("ij,ij->i", face, centre - viewpoint) > 0.0


def pair_tangents(obj: SceneObject, triangle: np.ndarray, viewpoint: np.ndarray) -> np.ndarray:
    """(4, 3, n) float64 tangents and handedness (coordinate, corner, pair) of ``obj``'s normal map
    at its triangles ``triangle``, all four reversed where :func:`pair_normals` reverses the
    normals: three.js and glTF turn the whole tangent frame of a back face, so the mapped normal
    is reversed as a whole."""
    corners = obj.faces[triangle].T
    v = obj.vertices
    a, b, c = v[corners[0]], v[corners[1]], v[corners[2]]
    tangents = np.take(obj.tangents.T, corners, axis=1)  # (4, 3, n)
    behind = _behind(obj, np.cross(b - a, c - a), (a + b + c) / 3.0, viewpoint)
    return np.where(behind[None, None, :], -tangents, tangents)


def _instance_records(
    instances: SlabInstances, obj: SceneObject, viewpoint: np.ndarray | None = None, material: bool = False
) -> np.ndarray:
    """(n, 43) float32 records for the GL upload, in the layout of INSTANCE_FORMAT; (n, 52) with
    the normals seen from ``viewpoint`` appended (:func:`pair_normals`) when it is given.  With
    ``material``, an object whose material textures take the uv's place (:func:`material_uv_source`
    ``"uv slot"``) has its material uv in the uv fields, and one with a uv of its own (``"own"``)
    has it after the normals, (n, 59)."""
    n = instances.triangle.shape[0]
    corners = obj.faces[instances.triangle].T  # (3, n)
    mapped = viewpoint is not None and records_normal_map(obj)
    own = material and viewpoint is not None and material_uv_source(obj) == "own"
    extra = (NORMAL_FLOATS if viewpoint is not None else 0) + (MAP_FLOATS if mapped else 0) + (OWN_FLOATS if own else 0)
    records = np.empty((INSTANCE_FLOATS + extra, n), dtype="<f4")  # filled row by row, transposed once
    records[0:4] = instances.rect
    records[4:14] = instances.polygon.transpose(1, 0, 2).reshape(10, n)  # x0, y0, x1, y1, ...
    records[14] = instances.count
    records[15] = 0.0
    records[16:25] = instances.vertices.transpose(1, 0, 2).reshape(9, n)
    uv = obj.material_uv if material and material_uv_source(obj) == "uv slot" else obj.uv
    if uv is not None:
        records[25:31] = np.take(uv.T, corners, axis=1).transpose(1, 0, 2).reshape(6, n)
    else:
        records[25:31] = 0.0
    if obj.vertex_colors is not None:
        records[31:43] = (np.take(obj.vertex_colors.T, corners, axis=1) / 255.0).transpose(1, 0, 2).reshape(12, n)
    else:
        records[31:43] = 1.0
    if viewpoint is not None:
        records[43:52] = pair_normals(obj, instances.triangle, viewpoint).transpose(1, 0, 2).reshape(9, n)
    if mapped:
        records[52:58] = np.take(obj.normal_uv.T, corners, axis=1).transpose(1, 0, 2).reshape(6, n)
        records[58:70] = pair_tangents(obj, instances.triangle, viewpoint).transpose(1, 0, 2).reshape(12, n)
        records[70] = 0.0
    if own:
        records[52:58] = np.take(obj.material_uv.T, corners, axis=1).transpose(1, 0, 2).reshape(6, n)
        records[58] = 0.0
    return np.ascontiguousarray(records.T)


def has_material_textures(obj: SceneObject) -> bool:
    """Whether ``obj`` has a metallic-roughness, occlusion or emissive texture."""
    return any(t is not None for t in (obj.metallic_roughness_texture, obj.occlusion_texture, obj.emissive_texture))


def material_uv_source(obj: SceneObject) -> str:
    """Which of the recorded uvs ``obj``'s material textures are read at (:func:`iter_layers` with
    ``material``): ``"uv"`` (its ``material_uv`` is its ``uv``, or equal to it, or it has no material
    texture), ``"uv slot"`` (it has no base-colour texture, so the material uv takes the uv's
    fields), ``"normal uv"`` (its normal map is recorded and shares the material uv), ``"own"`` (no
    normal map is recorded: the material uv is packed with the normals, the MATERIAL_UV_OWN
    variant) or ``"fallback"``: a recorded normal map with a third uv; a GL guarantees only 16
    vertex inputs, which the recording then fills (slab_instanced.vert), so the material textures
    are read at the base-colour uv, which :func:`iter_layers` warns of.

    >>> quad = SceneObject("q", np.zeros((3, 3)), np.array([[0, 1, 2]]))
    >>> material_uv_source(quad)
    'uv'
    """
    if not has_material_textures(obj) or obj.material_uv is None:
        return "uv"
    if obj.uv is not None and (obj.material_uv is obj.uv or np.array_equal(obj.material_uv, obj.uv)):
        return "uv"
    if obj.texture is None:
        return "uv slot"
    if not records_normal_map(obj):
        return "own"
    if np.array_equal(obj.material_uv, obj.normal_uv):
        return "normal uv"
    return "fallback"


def material_variant(obj: SceneObject, emissive: bool) -> tuple[str, ...]:
    """The ``slab.frag`` defines that record ``obj``'s material channel (and, with ``emissive``,
    the emissive channel), after :func:`slab_variant`'s and the normals'."""
    defines = ("MATERIAL",) + (("EMISSIVE",) if emissive else ())
    if has_material_textures(obj):
        defines += ("MATERIAL_MAPS",)
        source = material_uv_source(obj)
        defines += ("MATERIAL_UV_NORMAL",) if source == "normal uv" else ("MATERIAL_UV_OWN",) if source == "own" else ()
    return defines


def recorded_emission(objects: Sequence[SceneObject]) -> bool:
    """Whether a recording of ``objects`` with the material keeps the emissive channel: where one emits."""
    return any(emits(obj) for obj in objects)


def _unit_normal_map(normal_map: np.ndarray, scale: float) -> np.ndarray:
    """(h, w, 4) float32 normal map of unit normals, ``scale`` applied to x and y, encoded
    n * 0.5 + 0.5: the upload of a material recording, whose mips average the normals themselves
    (an 8-bit texel's normal is a hundredth off unit length, which the Toksvig roughness would
    take for spread)."""
    m = normal_map[..., :3].astype(np.float64) / 255.0 * 2.0 - 1.0
    m[..., :2] *= scale
    length = np.linalg.norm(m, axis=-1, keepdims=True)
    m = np.where(length > 1e-12, m / np.maximum(length, 1e-12), np.array([0.0, 0.0, 1.0]))
    out = np.ones(normal_map.shape[:2] + (4,), dtype=np.float32)
    out[..., :3] = m * 0.5 + 0.5
    return out


def _float_texture(ctx: moderngl.Context, rgba: np.ndarray) -> moderngl.Texture:
    """(h, w, 4) float32 ``rgba``, top row first, as a mipmapped, trilinear, repeating float texture."""
    image = np.ascontiguousarray(rgba[::-1], dtype="<f4")
    texture = ctx.texture((image.shape[1], image.shape[0]), 4, image.tobytes(), dtype="f4")
    texture.build_mipmaps()
    texture.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
    return texture


WHITE = np.full((1, 1, 4), 255, dtype=np.uint8)


def _material_textures(ctx: moderngl.Context, obj: SceneObject, cache: dict, owned: list) -> tuple:
    """The GL textures of ``obj``'s metallic-roughness, occlusion and emissive textures (mipmapped;
    a missing one a 1x1 white), shared through ``cache`` by id, each appended to ``owned`` once."""
    out = []
    for array, srgb in (
        (obj.metallic_roughness_texture, False),
        (obj.occlusion_texture, False),
        (obj.emissive_texture, True),
    ):
        array = WHITE if array is None else array
        key = (id(array), srgb)
        if key not in cache:
            cache[key] = (srgb_texture if srgb else linear_texture)(ctx, array, mipmaps=True)
            owned.append(cache[key])
        out.append(cache[key])
    return tuple(out)


def slab_variant(obj: SceneObject) -> tuple[str, ...]:
    """The defines of the ``slab.frag`` variant that records ``obj`` (the two of ``mesh_variant``'s it
    has): its texture reads only where it has a texture, its alpha cut only where it has one
    (llvmpipe runs a uniform's untaken branch with its lanes masked off, texture reads included:
    0.60 s against 0.21 s of GL time for the untextured 102,400-triangle benchmark part at 512,
    README "Recording against its lower bound").

    >>> quad = SceneObject("q", np.zeros((3, 3)), np.array([[0, 1, 2]]))
    >>> slab_variant(quad)
    ()
    >>> from dataclasses import replace
    >>> slab_variant(replace(quad, uv=np.zeros((3, 2)), texture=np.zeros((2, 2, 4), np.uint8), alpha_cutoff=0.5))
    ('TEXTURED', 'ALPHA_CUT')
    """
    return tuple(d for d in mesh_variant(obj, planes=False, open_faces=False) if d in ("TEXTURED", "ALPHA_CUT"))


def _instance_format(
    prog: moderngl.Program, normals: bool = False, mapped: bool = False, own: bool = False
) -> tuple[str, ...]:
    """INSTANCE_FORMAT (with the normals when ``normals``, and the normal map's uv and tangents
    when ``mapped``) and the attribute names for ``prog``: attributes its variant does not read
    (the compiler removed them) become padding."""
    formats, names = [], []
    extra, named = (
        (MAP_FORMAT, MAP_ATTRIBUTES) if mapped else (NORMAL_FORMAT, NORMAL_ATTRIBUTES) if normals else ((), ())
    )
    if own:  # the normals and the material uv, four vec4 (MATERIAL_UV_OWN)
        extra, named = OWN_FORMAT, OWN_ATTRIBUTES
    fields = (*INSTANCE_FORMAT.split()[:-1], *extra)
    attributes = (*INSTANCE_ATTRIBUTES, *named)
    for fmt, name in zip(fields, attributes, strict=True):
        if name in prog:
            formats.append(fmt)
            names.append(name)
        else:
            formats.append(f"{4 * int(fmt[:-1])}x")
    return (" ".join(formats) + " /i", *names)


def _map_key(obj: SceneObject, material: bool):
    """The key of ``obj``'s uploaded normal map: its array's id (the 8-bit upload), with its scale
    in a material recording (:func:`_unit_normal_map`)."""
    return (id(obj.normal_texture), float(obj.normal_scale)) if material else id(obj.normal_texture)


def _set_material_channel(prog: moderngl.Program, obj: SceneObject, ctx, cache: dict, owned: list) -> None:
    """Set the MATERIAL uniforms of ``obj`` on ``prog`` and bind its material textures (units 5-7)."""
    prog["metallic_factor"].value = float(obj.metallic_factor)
    prog["roughness_factor"].value = float(obj.roughness_factor)
    if "occlusion_strength" in prog:
        prog["occlusion_strength"].value = float(obj.occlusion_strength)
    if "emissive_factor" in prog:
        prog["emissive_factor"].value = tuple(float(e) for e in obj.emissive_factor)
    if not has_material_textures(obj):
        return
    names = ("metallic_roughness", "occlusion", "emissive")
    for unit, (name, texture) in enumerate(zip(names, _material_textures(ctx, obj, cache, owned)), start=5):
        if f"{name}_map" not in prog:  # the emissive map without EMISSIVE
            continue
        texture.use(unit)
        prog[f"{name}_map"].value = unit
        prog[f"{name}_size"].value = (float(texture.width), float(texture.height))


def _object_textures(ctx: moderngl.Context, obj: SceneObject):
    """The object's base-colour texture, and for an alpha-cut one its mipmapped cut-weighted
    colours (:mod:`farfield.core.render.cut_colours`), max-alpha mip chain and alpha alone (one channel, the
    texels ``slab.frag``'s exact footprint walk reads); None where it has none."""
    texture = cut = alpha = texels = None
    if obj.texture is not None:
        texture = srgb_texture(ctx, obj.texture)
        if obj.alpha_cutoff is not None:
            # The cut on the texture's own alpha: slab.frag keeps a point where base alpha x
            # vertex alpha x texture alpha reaches the cutoff (vertex alphas taken as 1 here).
            base_alpha = float(obj.base_color[3])
            cut = obj.alpha_cutoff / base_alpha if base_alpha > 0.0 else 2.0
            image = np.ascontiguousarray(cut_weighted_linear(obj.texture, cut)[::-1])
            cut = ctx.texture((image.shape[1], image.shape[0]), 4, image.tobytes(), dtype="f2")
            cut.build_mipmaps()
            cut.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
            alpha = max_alpha_texture(ctx, obj.texture[..., 3])
            texels = ctx.texture(
                (texture.width, texture.height), 1, np.ascontiguousarray(obj.texture[::-1, :, 3]).tobytes()
            )
            texels.filter = (moderngl.LINEAR, moderngl.LINEAR)  # the footprint a gather reads is GL_LINEAR's
    return texture, cut, alpha, texels


def iter_layers(
    scene: Scene | Sequence[SceneObject],
    plan: LayerPlan,
    conservative: bool = True,
    normals: bool = False,
    depth: bool = False,
    material: bool = False,
) -> Iterator[tuple[int, np.ndarray, int]]:
    """Record the layers of ``plan`` one at a time: yields ``(i, rgba, drawn)`` nearest first.

    ``scene`` is a :class:`Scene` or its objects as a view cell sees them
    (:func:`farfield.core.sidedness.seen_from_cell`, which every technique applies before it
    records: a one-sided triangle whose back faces the whole cell is not recorded); every
    triangle given is recorded from both sides.

    ``plan`` is a :class:`LayerPlan` or anything with its recording fields (``count``, ``borders``,
    ``reference_offset``, ``reference_viewpoint``, ``axis``, ``u``, ``v``,
    ``frustum_half_tangents``, ``texture_resolution``), such as a cube face of
    :class:`farfield.core.techniques.envmap.technique.FacePlan`.  A layer no triangle meets is yielded without drawing.

    ``rgba`` is the (h, w, 4) uint8 layer i (row 0 is the bottom image row, GL order; alpha 255 =
    covered), valid until the next step; ``drawn`` the triangles drawn for it.  Only one layer is
    held at a time, so a consumer that keeps what it needs runs in memory that grows with the
    kept texels, not with layers x image.  GL resources are released when the generator finishes
    or is closed.  ``conservative=False`` uses the standard "texel centre inside" rule instead; it
    exists to show (in tests) the holes the conservative rule prevents.

    ``normals=True`` records the normal channel too: ``rgba`` is then (h, w, 8), its last four
    channels the world shading normal of the point each texel shows (:func:`pair_normals`, the
    same point as its colour), encoded ``n * 0.5 + 0.5`` in RGB, alpha 255 where covered.
    ``depth=True`` (with ``normals``; channel sets with depth) writes in that alpha instead the
    point's eye depth within layer i's slab, ``round(255 (d - near) / (far - near))``
    (:mod:`farfield.core.impostor.depth`).

    ``material=True`` (with ``normals``) records the material channel after it: (h, w, 12), glTF's
    ORM packing of the same point (occlusion ``1 + strength * (R - 1)``, roughness ``G * factor``,
    metallic ``B * factor``, linear; the textures read at the footprint's mip level, as the normal
    map is; alpha 255), and, where an object of ``scene`` emits (:func:`recorded_emission`),
    (h, w, 16) with its linear emission (factor x texture) sRGB-encoded in the last four.  An object
    without material records the defaults (occlusion 1, its factors).  Where a texel's normal comes
    from a normal map's mip, the normals' spread under it raises the recorded roughness (Toksvig,
    the vMF form: slab.frag).  The material textures are read at the material uv where the
    recording's vertex inputs can carry it (:func:`material_uv_source`), else, with a warning, at
    the base-colour uv.
    """
    with closing(iter_views(scene, (plan,), conservative, normals, depth, material)) as views:
        for _, i, layer, drawn in views:
            yield i, layer, drawn


def iter_views(
    scene: Scene | Sequence[SceneObject],
    plans: Iterable,
    conservative: bool = True,
    normals: bool = False,
    depth: bool = False,
    material: bool = False,
    cull: bool = False,
    skip_known: bool = False,
) -> Iterator[tuple[int, int, np.ndarray, int]]:
    """The layers of several ``plans`` (each as :func:`iter_layers` records one; all of one
    ``texture_resolution``) on one set of GL resources: yields ``(view, i, rgba, drawn)``, plan by
    plan, nearest layer first, each object's programs and textures made once for every plan (the
    octahedral frames record many one-slab plans of one part: :mod:`farfield.core.techniques.octahedral.frames`).
    ``cull`` leaves out the triangles of a one-sided object whose back faces the plan's reference
    viewpoint, as a camera there draws the object (:mod:`farfield.core.sidedness`); without it every
    triangle given is recorded from both sides.  ``skip_known``: each plan has a ``known`` (h, w)
    bool mask (row 0 the bottom row), read when its layers are drawn; its texels are left empty
    without running the fragment shader's tests (the SKIP_KNOWN variant).
    """
    material = bool(material and normals)
    objects = list(scene.objects if isinstance(scene, Scene) else scene)
    emissive = material and recorded_emission(objects)
    ctx = gl_context()
    depth_channel = bool(normals and depth)  # before ``depth`` names the depth texture below
    plans = iter(plans)
    first = next(plans, None)
    if first is None:
        return
    res_x, res_y = (int(r) for r in first.texture_resolution)
    check_target_size(ctx, res_x, res_y, "the layer texture")

    colour = ctx.texture((res_x, res_y), 4)
    extra = int(normals) + int(material) + int(emissive)
    targets = [colour] + [ctx.texture((res_x, res_y), 4) for _ in range(extra)]
    depth = ctx.depth_texture((res_x, res_y))
    fbo = ctx.framebuffer(targets, depth)
    owned = [*targets, depth, fbo]
    # One buffer for every draw: moderngl has no base instance, so each (object, layer) draw
    # writes its own instances to the start of a freshly orphaned store.  It grows (and the
    # vertex arrays over it are made again) when a plan needs more than the plans before.
    stream, arrays = None, {}  # the buffer; defines -> the vertex array of that variant over it
    known = None  # the skip_known mask's texture
    try:
        variants = {}  # defines -> (program, its vertex array's format)
        normal_maps = {}  # id of a normal map array -> its GL texture
        material_maps = {}  # (id of a material texture, sRGB) -> its GL texture
        warned = set()
        passes, uploaded = {}, {}  # objects sharing a texture (and its cut) share its GL textures
        for view, plan in enumerate(chain((first,), plans)):
            if tuple(int(r) for r in plan.texture_resolution) != (res_x, res_y):
                raise ValueError(
                    f"plans of one recording share a texture resolution; {(res_x, res_y)} then {tuple(plan.texture_resolution)}"
                )
            k = plan.count
            eye_borders = plan.borders + plan.reference_offset
            slabs = eye_borders.astype("<f4")
            draws = []
            for index, obj in enumerate(objects):
                eye = eye_coordinates(plan, obj.vertices)
                drawn_faces = faces_with_area(obj)
                if cull and not obj.double_sided:
                    seen = np.flatnonzero(
                        faces_seen(obj.vertices, obj.faces, np.asarray(plan.reference_viewpoint, np.float64)[None])
                    )
                    drawn_faces = seen if drawn_faces is None else np.intersect1d(seen, drawn_faces, assume_unique=True)
                instances = slab_instances(
                    eye, obj.faces, eye_borders, plan.frustum_half_tangents, plan.texture_resolution, drawn_faces
                )
                if instances.triangle.size:
                    viewpoint = np.asarray(plan.reference_viewpoint, dtype=np.float64) if normals else None
                    draws.append(
                        (index, obj, instances.offsets, _instance_records(instances, obj, viewpoint, material))
                    )
            largest = max((int(np.diff(offsets).max()) for _, _, offsets, _ in draws), default=0)
            floats = max((records.shape[1] for _, _, _, records in draws), default=INSTANCE_FLOATS)
            if stream is None or stream.size < max(largest, 1) * floats * 4:
                for array in arrays.values():
                    array.release()
                if stream is not None:
                    stream.release()
                stream, arrays = ctx.buffer(reserve=max(largest, 1) * floats * 4, dynamic=True), {}
            for index, obj, _, _ in draws:
                if index in passes:
                    continue
                mapped = normals and records_normal_map(obj)
                defines = slab_variant(obj) + (("NORMALS",) if normals else ()) + (("NORMAL_MAP",) if mapped else ())
                defines += ("DEPTH_CHANNEL",) if depth_channel else ()
                defines += ("SKIP_KNOWN",) if skip_known else ()
                if material:
                    defines += material_variant(obj, emissive)
                    if material_uv_source(obj) == "fallback" and obj.name not in warned:
                        warned.add(obj.name)
                        warnings.warn(
                            f"object {obj.name!r}: its material textures' uv differs from its base-colour uv "
                            "(and its normal map's), and the recording has no vertex input left for a third: "
                            "its material textures are read at the base-colour uv",
                            stacklevel=3,
                        )
                if defines not in variants:
                    prog = program(ctx, "slab_instanced.vert", "slab.frag", defines=defines)
                    prog["resolution"].value = (float(res_x), float(res_y))
                    prog["conservative"].value = bool(conservative)
                    own = "MATERIAL_UV_OWN" in defines
                    variants[defines] = (prog, _instance_format(prog, normals, mapped, own))
                if mapped and material and _map_key(obj, material) not in normal_maps:
                    texture = _float_texture(ctx, _unit_normal_map(obj.normal_texture, float(obj.normal_scale)))
                    normal_maps[_map_key(obj, material)] = texture
                    owned.append(texture)
                if mapped and _map_key(obj, material) not in normal_maps:
                    normal_maps[id(obj.normal_texture)] = linear_texture(ctx, obj.normal_texture, mipmaps=True)
                    owned.append(normal_maps[id(obj.normal_texture)])
                key = None if obj.texture is None else (id(obj.texture), obj.alpha_cutoff, float(obj.base_color[3]))
                if key not in uploaded:
                    uploaded[key] = _object_textures(ctx, obj)
                    owned += [t for t in uploaded[key] if t is not None]
                passes[index] = (defines, uploaded[key])
            for defines, _ in passes.values():
                if defines not in arrays:
                    prog, fmt = variants[defines]
                    arrays[defines] = ctx.vertex_array(prog, [(stream, *fmt)])
            if skip_known:
                mask = np.ascontiguousarray(np.where(plan.known, 255, 0).astype(np.uint8))
                if known is None:
                    known = ctx.texture((res_x, res_y), 1)
                    known.filter = (moderngl.NEAREST, moderngl.NEAREST)
                    owned.append(known)
                known.write(mask.tobytes())
                known.use(8)
                for prog, _ in variants.values():
                    prog["known"].value = 8
            per_layer = np.zeros(k, dtype=np.int64)
            for _, _, offsets, _ in draws:
                per_layer += np.diff(offsets)
            empty = np.zeros((res_y, res_x, 4 * len(targets)), dtype=np.uint8)
            empty.flags.writeable = False
            for i in range(k):
                if per_layer[i] == 0:  # nothing meets this slab: no draw, no read-back
                    yield view, i, empty, 0
                    continue
                # Re-established every layer: the consumer may render on this context between layers.
                fbo.use()
                ctx.viewport = (0, 0, res_x, res_y)
                ctx.enable(moderngl.DEPTH_TEST)
                # slab.frag clamps depth into the slab, so a texel whose nearest polygon point lies on
                # the far plane gets depth 1.0, the cleared value: with "<" it would fail the test and
                # the far clipping edge would lose texels.  Ties keep the last fragment drawn.
                ctx.depth_func = "<="
                ctx.disable(moderngl.CULL_FACE | moderngl.BLEND)
                fbo.clear(0.0, 0.0, 0.0, 0.0, depth=1.0)
                if known is not None:
                    known.use(8)
                for prog, _ in variants.values():
                    prog["slab"].value = (float(slabs[i]), float(slabs[i + 1]))
                drawn = 0
                for index, obj, offsets, records in draws:
                    count = int(offsets[i + 1] - offsets[i])
                    if count == 0:
                        continue
                    defines, (texture, cut, alpha, texels) = passes[index]
                    prog, vao = variants[defines][0], arrays[defines]
                    set_material(prog, obj, texture)
                    if normals and records_normal_map(obj):
                        normal_map = normal_maps[_map_key(obj, material)]
                        normal_map.use(4)
                        prog["normal_map"].value = 4
                        prog["normal_map_size"].value = (float(normal_map.width), float(normal_map.height))
                        # A material recording's map has the scale applied (_unit_normal_map).
                        prog["normal_scale"].value = 1.0 if material else float(obj.normal_scale)
                    if material:
                        _set_material_channel(prog, obj, ctx, material_maps, owned)
                    if cut is not None:
                        prog["texture_size"].value = (float(texture.width), float(texture.height))
                        cut.use(2)
                        prog["cut_texture"].value = 2
                    if alpha is not None:
                        texels.use(3)
                        prog["alpha_texels"].value = 3
                        alpha.use(1)
                        prog["alpha_mip"].value = 1
                        prog["alpha_mip_size"].value = (float(alpha.width), float(alpha.height))
                        prog["alpha_mip_levels"].value = int(np.log2(max(alpha.width, alpha.height))) + 1
                    stream.orphan()
                    stream.write(records[offsets[i] : offsets[i + 1]])
                    vao.render(moderngl.TRIANGLE_STRIP, vertices=4, instances=count)
                    drawn += count
                layer = np.frombuffer(colour.read(), dtype=np.uint8).reshape(res_y, res_x, 4)
                if normals:
                    layer = np.concatenate(
                        [
                            layer,
                            *(np.frombuffer(t.read(), dtype=np.uint8).reshape(res_y, res_x, 4) for t in targets[1:]),
                        ],
                        axis=2,
                    )
                ctx.depth_func = "<"  # the GL default, which every other pass on this context assumes
                yield view, i, layer, drawn
    finally:
        ctx.depth_func = "<"
        park_framebuffer(ctx)
        for resource in (*arrays.values(), *([stream] if stream is not None else []), *owned):
            resource.release()


def record_layers(
    scene: Scene | Sequence[SceneObject],
    plan: LayerPlan,
    conservative: bool = True,
    on_layer: Callable[[int], None] | None = None,
    normals: bool = False,
    depth: bool = False,
    material: bool = False,
) -> RecordedLayers:
    """Every layer of ``plan`` at once (see :func:`iter_layers`; this holds k x h x w x 4 bytes,
    8 with ``normals``).

    ``on_layer(i)`` is called after layer i.
    """
    res_x, res_y = (int(r) for r in plan.texture_resolution)
    objects = scene.objects if isinstance(scene, Scene) else scene
    channels = 4 * (1 + int(normals) + int(material and normals) * (1 + int(recorded_emission(objects))))
    out = np.zeros((plan.count, res_y, res_x, channels), dtype=np.uint8)
    drawn = np.zeros(plan.count, dtype=np.int64)
    for i, layer, count in iter_layers(scene, plan, conservative, normals, depth=depth, material=material):
        out[i], drawn[i] = layer, count
        if on_layer is not None:
            on_layer(i)
    return RecordedLayers(out, plan.borders + plan.reference_offset, drawn)

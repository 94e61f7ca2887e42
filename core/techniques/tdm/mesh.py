"""The initial mesh of a textured depth mesh: a voxel field in, a fine triangle mesh covering it out.

Seed 003 §5 (seed 000 §4.4, Fig. 4.4).  Every voxel carries four vertices on its sampling layer, one
near each corner of its texel, so the vertices of a layer form a grid of two per texel: vertex
(X, Y) sits at (X // 2 + o(X), Y // 2 + o(Y)) with o = INSET for even and 1 - INSET for odd indices.

Deviation: the paper distributes the four vertices evenly (INSET = 1/4), which leaves the mesh a
quarter texel inside the texels it covers.  At the edge of the recording frustum, where a part's
silhouette lies exactly on a texel border, that quarter texel added to the one-pixel parallax error
showed up as two hole pixels seen from a view-cell corner (box building, 256 pixels).  farfield puts
the vertices 1/16 texel inside the corners: the same topology and rules, bridges between
neighbouring voxels 1/8 texel wide (they are the shortest edges and go first), and a mesh that
covers its texels almost exactly, like the layered impostor's quads.  A *cell* of that grid, (X, Y) to (X + 1, Y + 1), touches one
voxel (X, Y both even: the voxel's own square), two (a bridge to the right or below neighbour) or
four (the centre of a 2x2 block); it is *filled* in a layer when all the voxels it touches are.
The paper's three rule sets then read, per layer l and its previous (nearer) layer l - 1:

(a) connections in the current layer: a cell filled in l but not in l - 1 becomes a quad on layer l
    ("the current voxel is connected to itself, to the right, to the bottom and to all 3
    neighbours if those voxels are filled in the current layer but at least one of them is not in
    the previous one");
(b, c) sealing off: a cell filled in both l - 1 and l is sealed towards each side whose neighbour
    cell is not filled in l - 1, by a quad standing on that side between the two layers (rule set
    (b) for a voxel's own cell, (c) for the bridges of voxel pairs, "if any of the 2 facing voxels
    in the previous layer is transparent").

A voxel that none of these quads meets (it and its previous-layer twin are filled, and so are
its previous-layer side neighbours, but a diagonal one is not, so culling kept it) gets the quad
of its own cell on its layer: counted as ``fallback_quads``.

**Steep surfaces (farfield's additions).**  A surface seen nearly edge-on from the reference
viewpoint (the house's side walls, seen from the cell's outer part) records as stacks: each texel
column holds a run of several layers, and the next column's run starts one or two layers deeper.
The paper's rules seal every run on both sides into a fin of its own, and runs that do not share a
layer never connect, so the wall becomes one folded fin per column whose two walls can never be
contracted onto each other: measured on the house at 90 m, 512 pixels, f = 2, 6,605 triangles, most
of them fins.  farfield therefore

* fills *step voxels* (:func:`step_voxels`) between side-neighbouring runs one or two layers apart,
  so neighbouring runs share a layer and the rules join them into one staircase.  Step voxels only
  shape the initial mesh: they are not in the field, so nothing has to cover them, and the
  simplification may straighten the staircase into the plane it samples;
* leaves out the *back wall* of a fin: a run whose first layer joins the neighbour cell on one side
  but not on the opposite side is sealed only on that opposite side.  Its voxels are covered by the
  wall that is kept, and the dropped one would hang from the edge where the run meets its neighbour,
  three triangles on one edge.

Measured (same case): 1,169 triangles, 4 s instead of 12 s, no hole pixels; and a synthetic steep
plane (``tests/test_tdm.py``) becomes one mesh of 5 triangles at f = 3 where the paper's rules
leave 8 fins of 42.  (Since the outline rules of :mod:`farfield.core.techniques.tdm.simplify`: 1,450 triangles, and
8-10 for the steep plane, whose rim is all outline.)

**Slits (farfield's addition).**  Where the runs of neighbouring texel columns overlap in depth,
the sealing walls of their voxels can surround a cell of the vertex grid across a run of layers
that no layer caps: a tube 1/8 texel square at the corner of four texels, or a gap of no width
between two walls in one plane, standing along the view direction.  Each is a boundary loop of
the mesh that encloses (almost) no area in the image, yet its rim is boundary the simplification
must keep (seed 003 Figs. 13-14): measured on the house at 90 m, 512 pixels, f = 2, 31 slits kept
870 triangles after simplification where 660 remain once they are closed.  :func:`close_slits`
closes every loop whose closing triangles (ear clipping, nearest neighbours first) cover at most
:data:`SLIT_AREA` texels of the image, except a mesh's rim; the closing triangles store no
voxels, so they hide nothing the recording saw from the reference viewpoint.  Seen from elsewhere
in the cell, what lay behind such a slit shows the closing triangles' texture instead, and the
vertices freed near the outline can fold the mesh over it in the image: the benchmark's pixels
bloated beyond a pixel (README) count that.

**Meshes that store no voxel (farfield's addition).**  Every voxel is stored with one quad that
meets it, and a stray sealing wall can lose all its voxels to the quads of a neighbouring mesh;
standing on its own, it then covers nothing the recording needs and is left out (measured on the
house at 90 m, 512 pixels: 5 of 13 meshes, 354 triangles of walls seen edge-on that simplified to
2 triangles each).

Each quad is two triangles.  Every voxel is stored with exactly one triangle that meets its box
(checked with the exact triangle-box test), which is what the simplification keeps covered.  Mesh
connectivity (the paper's vertex table and mesh merging) is the connected components of the
triangles through their shared vertices: no more meshes than occlusion and disjoint parts need.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from farfield.core.techniques.tdm.simplify import assign_voxels
from farfield.core.techniques.tdm.voxel_field import VoxelField

INSET = 1.0 / 16.0  # texels from a voxel's corner to its nearest vertex (the paper: 1/4)
SLIT_AREA = 0.25  # texels squared: the most image area the triangles closing a slit may cover


@dataclass(frozen=True, slots=True)
class TdmMesh:
    """A triangle mesh in voxel space with the voxels each triangle stores."""

    vertices: np.ndarray  # (v, 3) float64 voxel units: x, y (down), layer
    triangles: np.ndarray  # (t, 3) int64
    voxel_offsets: np.ndarray  # (t + 1,) int64: triangle i stores voxels[voxel_offsets[i]:voxel_offsets[i+1]]
    voxels: np.ndarray  # (n,) int64 indices into the VoxelField
    stats: dict

    @property
    def triangle_count(self) -> int:
        return int(self.triangles.shape[0])


def cell_grid(filled: np.ndarray) -> np.ndarray:
    """(2h - 1, 2w - 1) bool filled cells of the half-texel vertex grid of an (h, w) voxel layer.

    >>> cell_grid(np.array([[True, True], [True, False]])).astype(int)
    array([[1, 1, 1],
           [1, 0, 0],
           [1, 0, 0]])
    """
    h, w = filled.shape
    cells = np.zeros((2 * h - 1, 2 * w - 1), dtype=bool)
    cells[0::2, 0::2] = filled
    cells[0::2, 1::2] = filled[:, :-1] & filled[:, 1:]
    cells[1::2, 0::2] = filled[:-1] & filled[1:]
    cells[1::2, 1::2] = filled[:-1, :-1] & filled[:-1, 1:] & filled[1:, :-1] & filled[1:, 1:]
    return cells


# Sides of a cell: (neighbour offset dY, dX), and the two corners of the shared edge as (dX, dY)
# from the cell's top-left vertex, in the order the quad walks them.
_SIDES = (
    ((0, 1), ((1, 0), (1, 1))),  # right: edge X + 1, Y .. Y + 1
    ((0, -1), ((0, 1), (0, 0))),  # left: edge X, Y + 1 .. Y
    ((1, 0), ((1, 1), (0, 1))),  # bottom: edge Y + 1, X + 1 .. X
    ((-1, 0), ((0, 0), (1, 0))),  # top: edge Y, X .. X + 1
)


def step_voxels(occupied: np.ndarray) -> np.ndarray:
    """(k, h, w) bool: the step voxels that join the stacks of a steep surface (farfield's addition
    to the rule sets, see the module docstring); :func:`layer_steps` of every layer.

    Two side-neighbouring voxel columns whose stacks end and begin one or two layers apart get the
    layers between filled so that they share one: with the near column holding l and not l + 1, and
    the far one holding l + 1 and not l, the near one steps into l + 1; with one empty layer between
    (near holds l - 1 and l, far holds l + 2 and l + 3, neither holds l + 1), both take l + 1.  The
    second case asks for stacks of two on both sides, the mark of a steep surface: a lone voxel
    beside a deeper stack is a silhouette over whatever lies behind, and joining it made skirts.

    >>> occ = np.zeros((6, 1, 3), bool)
    >>> occ[0:2, 0, 0] = occ[3:5, 0, 1] = occ[5, 0, 2] = True
    >>> np.argwhere(step_voxels(occ)).tolist()  # columns 0, 1 share layer 2; column 1 steps into 5
    [[2, 0, 0], [2, 0, 1], [5, 0, 1]]
    """
    k = occupied.shape[0]
    return np.stack([layer_steps(occupied.__getitem__, l, k) for l in range(k)]) if k else np.zeros_like(occupied)


def layer_steps(layer, l: int, k: int) -> np.ndarray:
    """(h, w) bool: the step voxels (:func:`step_voxels`) of layer ``l`` of ``k``, from
    ``layer(j)``, the (h, w) occupancy of layer j, read for j in l - 2 .. l + 2 only: a bake
    builds its initial mesh one layer at a time, never holding layers x rows x columns."""
    current = layer(l)
    steps = np.zeros_like(current)
    before = layer(l - 1) if l >= 1 else None
    two_apart = k >= 5 and 2 <= l <= k - 3
    if two_apart:
        window = (layer(l - 2), before, current, layer(l + 1), layer(l + 2))
    for axis in (0, 1):
        n = current.shape[axis]

        def pairs(a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
            first, second = [slice(None)] * 2, [slice(None)] * 2
            first[axis], second[axis] = slice(0, n - 1), slice(1, n)
            return a[tuple(first)], a[tuple(second)]

        cur = pairs(current)
        prev = pairs(before) if before is not None else None
        win = [pairs(a) for a in window] if two_apart else None
        for near, far in ((0, 1), (1, 0)):
            # One layer apart: near holds l - 1 and not l, far holds l and not l - 1.
            if prev is not None:
                _add_side(steps, prev[near] & ~prev[far] & cur[far] & ~cur[near], axis, near)
            # Two layers apart, stacks of two: near holds l - 2, l - 1; far holds l + 1, l + 2.
            if two_apart:
                (n2, f2), (n1, f1), (n0, f0), (p1n, p1f), (p2n, p2f) = ((w[near], w[far]) for w in win)
                marked = n2 & n1 & ~f1 & ~n0 & ~f0 & p1f & ~p1n & p2f
                _add_side(steps, marked, axis, near)
                _add_side(steps, marked, axis, far)
    return steps & ~current


def _add_side(steps: np.ndarray, added: np.ndarray, axis: int, side: int) -> None:
    """OR ``added`` (one column pair per entry along ``axis``) into the first (side 0) or second
    (side 1) column of each pair."""
    n = steps.shape[axis]
    index = [slice(None)] * steps.ndim
    index[axis] = slice(0, n - 1) if side == 0 else slice(1, n)
    steps[tuple(index)] |= added


def _cell_keys(filled: np.ndarray) -> np.ndarray:
    """The filled cells of :func:`cell_grid` of ``filled`` as sorted keys Y * (2w - 1) + X, found
    from the filled texels alone (each cell from the texel at its top left).

    >>> _cell_keys(np.array([[True, True], [True, False]])).tolist()  # cells (0, 0..2), (1, 0), (2, 0)
    [0, 1, 2, 3, 6]
    """
    h, w = filled.shape
    ty, tx = np.nonzero(filled)
    right = np.zeros(ty.size, dtype=bool)
    down = np.zeros(ty.size, dtype=bool)
    inside = tx + 1 < w
    right[inside] = filled[ty[inside], tx[inside] + 1]
    inside = ty + 1 < h
    down[inside] = filled[ty[inside] + 1, tx[inside]]
    diagonal = right & down
    diagonal[diagonal] = filled[ty[diagonal] + 1, tx[diagonal] + 1]
    key = 2 * ty * (2 * w - 1) + 2 * tx
    return np.sort(np.concatenate([key, key[right] + 1, key[down] + 2 * w - 1, key[diagonal] + 2 * w]))


def _neighbour_not_filled(grid: np.ndarray, grid_w: int, keys: np.ndarray, dy: int, dx: int) -> np.ndarray:
    """Whether the neighbour (Y + dy, X + dx) of each cell ``keys`` (Y * grid_w + X) is not filled in
    the flat cell ``grid`` of width ``grid_w``, or lies outside it.

    >>> grid = cell_grid(np.array([[True, True], [True, False]])).ravel()
    >>> _neighbour_not_filled(grid, 3, np.array([0, 1, 3]), 0, 1).tolist()  # right of (0,0), (0,1), (1,0)
    [False, False, True]
    """
    y, x = np.divmod(keys, grid_w)
    y, x = y + dy, x + dx
    inside = (y >= 0) & (y < grid.size // grid_w) & (x >= 0) & (x < grid_w)
    out = np.ones(keys.size, dtype=bool)
    out[inside] = ~grid[y[inside] * grid_w + x[inside]]
    return out


def _cell_voxels(cy: np.ndarray, cx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(c, 4) voxel rows and columns a cell touches (repeats where it touches fewer than four)."""
    y0, y1 = cy // 2, (cy + 1) // 2
    x0, x1 = cx // 2, (cx + 1) // 2
    return np.stack([y0, y0, y1, y1], axis=1), np.stack([x0, x1, x0, x1], axis=1)


def layer_quads(field: VoxelField) -> tuple[np.ndarray, np.ndarray, int, int, int]:
    """The quads of seed 003 §5's rule sets for ``field``, layer by layer: (q, 4, 3) int64 corners
    (X, Y, layer) in the half-texel grid of the voxels' bounding box, (q, 8) int64 indices of the
    voxels each quad touches (-1 at a texel without one; repeats allowed), the step voxels added,
    and the box's corner x0, y0.  Voxel indices are read from per-layer grids, not searched for
    (a search of 13.6 M touches took 1.4 s on benchmarks/bench_tdm_scale.py)."""
    k = field.plan.count
    # Work inside the bounding box of the voxels, one grid of layers x rows x columns.
    x0, y0 = int(field.x.min()), int(field.y.min())
    w, h = int(field.x.max()) - x0 + 1, int(field.y.max()) - y0 + 1
    # One layer at a time (the field is sorted by layer): a layer and its step voxels need the
    # occupancy of the two layers on either side, never the whole layers x rows x columns grid.
    starts = np.searchsorted(field.layer, np.arange(k + 1))
    recent: dict[int, tuple[np.ndarray, np.ndarray]] = {}
    index_type = np.int32 if field.count < 2**31 else np.int64  # seven layers' grids are cached

    def grids(j: int) -> tuple[np.ndarray, np.ndarray]:
        """Layer j's occupancy and the index of its voxel at each texel (-1 where none)."""
        if j not in recent:
            if len(recent) > 6:
                recent.pop(min(recent))
            index = np.full((h, w), -1, dtype=index_type)
            index[field.y[starts[j] : starts[j + 1]] - y0, field.x[starts[j] : starts[j + 1]] - x0] = np.arange(
                starts[j], starts[j + 1]
            )
            recent[j] = (index >= 0, index)
        return recent[j]

    def layer(j: int) -> np.ndarray:
        return grids(j)[0]

    # Layers that can hold a voxel or a step voxel: a step needs voxels on the layer or on both
    # layers next to it.
    has = np.diff(starts) > 0
    near = has.copy()
    near[1:-1] |= has[:-2] & has[2:]
    step_count = 0

    quads = []  # each (q, 4, 3) int64 corner (X, Y, layer) in the half-texel grid
    touches = []  # each (q, 8) int64 index of a voxel the quad touches, -1 for none (repeats allowed)
    # The cells are kept as sorted lists of their keys Y * (2w - 1) + X (row-major, the order
    # np.nonzero gives), looked up in two grids that are set and cleared at those keys only: a
    # layer holds ~1 % of its cells here, and whole-grid operations (some 25 a layer) cost 3-4 s
    # of this bake (benchmarks/bench_tdm_scale.py).
    grid_w = 2 * w - 1
    current_grid = np.zeros((2 * h - 1) * grid_w, dtype=bool)
    previous_grid = np.zeros_like(current_grid)
    previous = np.zeros(0, np.int64)
    previous_layer = -2
    # Per side: was the neighbour cell filled in the first layer of the cell's current run?
    joined_at_top = np.zeros((len(_SIDES), current_grid.size), dtype=bool)
    for l in np.flatnonzero(near):
        steps = layer_steps(layer, int(l), k)
        step_count += int(steps.sum())
        filled = layer(int(l)) | steps
        cells = _cell_keys(filled)
        if not cells.size:
            continue
        current_grid[cells] = True
        adjacent = previous_layer == l - 1
        in_before = previous_grid[cells] if adjacent else np.zeros(cells.size, dtype=bool)
        start = cells[~in_before]
        for side, ((dy, dx), _) in enumerate(_SIDES):
            joined_at_top[side, start] = ~_neighbour_not_filled(current_grid, grid_w, start, dy, dx)
        # (a) quads in the current layer where the previous layer's cell is not filled.
        if start.size:
            cy, cx = np.divmod(start, grid_w)
            corner = np.stack(
                [
                    np.stack([cx, cy], 1),
                    np.stack([cx + 1, cy], 1),
                    np.stack([cx + 1, cy + 1], 1),
                    np.stack([cx, cy + 1], 1),
                ],
                axis=1,
            )
            quads.append(np.concatenate([corner, np.full(corner.shape[:2] + (1,), l)], axis=2))
            vy, vx = _cell_voxels(cy, cx)
            touch = grids(int(l))[1][vy, vx].astype(np.int64)
            touches.append(np.concatenate([touch, touch], axis=1))
        # (b), (c) sealing off cells filled in both layers towards sides not filled in the previous one.
        both = cells[in_before]
        if both.size:
            for side, ((dy, dx), ((ax, ay), (bx, by))) in enumerate(_SIDES):
                # The back wall of a fin: the run joined this side's neighbour at its top and the
                # opposite side carries the wall down (farfield's addition, module docstring).
                back = joined_at_top[side, both] & ~joined_at_top[side ^ 1, both]
                sealed = both[_neighbour_not_filled(previous_grid, grid_w, both, dy, dx) & ~back]
                if not sealed.size:
                    continue
                cy, cx = np.divmod(sealed, grid_w)
                a = np.stack([cx + ax, cy + ay], 1)
                b = np.stack([cx + bx, cy + by], 1)
                lay = np.full((cy.size, 1), l)
                quads.append(np.stack([
                    np.concatenate([a, lay - 1], 1), np.concatenate([b, lay - 1], 1),
                    np.concatenate([b, lay], 1), np.concatenate([a, lay], 1),
                ], axis=1))  # fmt: skip
                vy, vx = _cell_voxels(cy, cx)
                if dx:  # only the voxels on that side of the cell meet the standing quad
                    vx = np.where(dx > 0, (cx + 1) // 2, cx // 2)[:, None].repeat(4, 1)
                else:
                    vy = np.where(dy > 0, (cy + 1) // 2, cy // 2)[:, None].repeat(4, 1)
                touches.append(
                    np.concatenate([grids(int(l))[1][vy, vx], grids(int(l) - 1)[1][vy, vx]], axis=1).astype(np.int64)
                )
        previous_grid[previous] = False
        previous_grid, current_grid = current_grid, previous_grid
        previous, previous_layer = cells, l
    quads_arr = np.concatenate(quads) if quads else np.zeros((0, 4, 3), np.int64)
    touch_arr = np.concatenate(touches) if touches else np.zeros((0, 8), np.int64)
    return quads_arr, touch_arr, step_count, x0, y0


def initial_mesh(field: VoxelField) -> TdmMesh:
    """The covering mesh of ``field`` by the rule sets of seed 003 §5 (see the module docstring)."""
    quads_arr, touch_voxel, step_count, x0, y0 = layer_quads(field)
    centres = field.centres
    corners = _Corners(quads_arr, 2 * int(max(field.x.max() - x0, field.y.max() - y0)) + 3)
    vertices, triangles = corners.mesh(x0, y0)
    pair_voxel = touch_voxel.ravel()
    pair_quad = np.repeat(np.arange(quads_arr.shape[0]), 8)
    keep = pair_voxel >= 0
    owner = assign_voxels(vertices, triangles, centres, pair_voxel[keep], pair_quad[keep], field.count)

    # Fallback: voxels no rule covered get the quad of their own cell on their layer.
    missing = np.flatnonzero(owner < 0)
    fallback = 0
    if missing.size:
        mx, my, ml = field.x[missing] - x0, field.y[missing] - y0, field.layer[missing]
        cx, cy = 2 * mx, 2 * my
        extra = np.stack(
            [
                np.stack([cx, cy, ml], 1),
                np.stack([cx + 1, cy, ml], 1),
                np.stack([cx + 1, cy + 1, ml], 1),
                np.stack([cx, cy + 1, ml], 1),
            ],
            axis=1,
        )
        quads_arr = np.concatenate([quads_arr, extra])
        corners.add(extra)
        vertices, triangles = corners.mesh(x0, y0)
        first = 2 * (quads_arr.shape[0] - missing.size)
        owner[missing] = first + 2 * np.arange(missing.size)
        fallback = int(missing.size)

    meshes = mesh_labels(vertices.shape[0], triangles)
    # Meshes that store no voxel go (module docstring).
    stored = np.bincount(meshes[owner], minlength=int(meshes.max(initial=-1)) + 1)
    kept = stored[meshes] > 0
    empty = int((stored == 0).sum())
    if empty:
        owner = np.cumsum(kept)[owner] - 1
        triangles, meshes = triangles[kept], sorted_unique(meshes[kept], inverse=True)[1]
    slits, slit_triangles = close_slits(vertices, triangles, meshes)  # joins no two meshes
    triangles = np.concatenate([triangles, slit_triangles])

    order = np.argsort(owner, kind="stable")
    counts = np.bincount(owner, minlength=triangles.shape[0])  # slit triangles store no voxels
    offsets = np.concatenate([[0], np.cumsum(counts)])
    stats = {
        "initial_quads": int(quads_arr.shape[0]),
        "initial_triangles": int(triangles.shape[0]),
        "initial_vertices": int(
            np.count_nonzero(np.bincount(triangles.ravel(), minlength=vertices.shape[0]))
        ),  # those of the meshes left out stay unused
        "fallback_quads": fallback,
        "step_voxels": step_count,
        "slits_closed": slits,
        "slit_triangles": int(slit_triangles.shape[0]),
        "initial_meshes": int(meshes.max(initial=-1) + 1),
        "empty_meshes_dropped": empty,
    }
    return TdmMesh(vertices, triangles, offsets.astype(np.int64), order.astype(np.int64), stats)


def sorted_unique(keys: np.ndarray, inverse: bool = False, counts: bool = False):
    """``np.unique`` of the 1-D integer ``keys`` (the distinct keys ascending, then, if asked, each
    key's index among them and how often each occurs), the same arrays, by a stable sort.  The
    mesh's keys come in long ascending runs (quads and triangles are made layer by layer), which
    the stable sort (timsort) merges instead of sorting afresh as ``np.unique``'s quicksort does: on
    the 17.6 M corner keys of ``benchmarks/bench_tdm_scale.py --scene scan`` the argsort took 0.2-0.5 s
    instead of 1.3 s, on its 26.5 M edge keys the sort 0.25 s instead of 2.0 s.

    >>> [a.tolist() for a in sorted_unique(np.array([3, 1, 3, 2]), inverse=True, counts=True)]
    [[1, 2, 3], [2, 0, 2, 1], [1, 1, 2]]
    """
    keys = np.asarray(keys).reshape(-1)
    order = np.argsort(keys, kind="stable") if inverse else None
    ordered = keys[order] if inverse else np.sort(keys, kind="stable")
    first = np.empty(ordered.size, bool)
    first[:1] = True
    np.not_equal(ordered[1:], ordered[:-1], out=first[1:])
    out = [ordered[first]]
    if inverse:
        at = np.empty(keys.size, np.intp)
        at[order] = np.cumsum(first) - 1
        out.append(at)
    if counts:
        out.append(np.diff(np.append(np.flatnonzero(first), ordered.size)))
    return tuple(out) if len(out) > 1 else out[0]


def boundary_loops(triangles: np.ndarray) -> list[np.ndarray]:
    """The boundary loops of a triangle mesh as vertex cycles, in order along each loop; loops
    through a vertex with more than two boundary edges (a pinch) are left out.

    >>> [loop.tolist() for loop in boundary_loops(np.array([[0, 1, 2], [0, 2, 3]]))]
    [[0, 1, 2, 3]]
    """
    if not triangles.size:
        return []
    size = int(triangles.max()) + 1
    return _loops(*sorted_unique(_edge_keys(triangles, size), counts=True), size)


def _loops(keys: np.ndarray, count: np.ndarray, size: int) -> list[np.ndarray]:
    """:func:`boundary_loops` from the mesh's distinct edge keys (:func:`_edge_keys`) and how many
    triangles share each."""
    single = keys[count == 1]
    if not single.size:
        return []
    boundary = np.stack([single // size, single % size], axis=1)
    ends = np.concatenate([boundary, boundary[:, ::-1]])  # (vertex, neighbour) both ways
    ends = ends[np.argsort(ends[:, 0], kind="stable")]
    vertex, first, degree = np.unique(ends[:, 0], return_index=True, return_counts=True)
    graph = coo_matrix((np.ones(boundary.shape[0]), (boundary[:, 0], boundary[:, 1])), shape=(size, size))
    _, label = connected_components(graph, directed=False)
    pinched = np.zeros(size, dtype=bool)
    pinched[label[vertex[degree != 2]]] = True
    nbr = np.full((size, 2), -1, dtype=np.int64)
    simple = degree == 2
    nbr[vertex[simple], 0] = ends[first[simple], 1]
    nbr[vertex[simple], 1] = ends[first[simple] + 1, 1]
    loops, seen = [], set()
    for start in vertex[simple].tolist():
        if start in seen or pinched[label[start]]:
            continue
        cycle, previous, current = [start], start, int(nbr[start, 0])
        while current != start:
            cycle.append(current)
            a, b = nbr[current]
            previous, current = current, int(b if a == previous else a)
        seen.update(cycle)
        loops.append(np.array(cycle, dtype=np.int64))
    return loops


def _edge_keys(triangles: np.ndarray, size: int) -> np.ndarray:
    """(3t,) int64 key min * size + max of every triangle edge (vertices below ``size``), edges
    (0, 1), (1, 2), (2, 0) of each triangle in turn (minimum and maximum: a row sort of the 26 M
    edges of ``benchmarks/bench_tdm_scale.py --scene scan`` took 2 s).

    >>> _edge_keys(np.array([[2, 0, 1]]), 3).tolist()
    [2, 1, 5]
    """
    a, b = triangles.reshape(-1), triangles[:, [1, 2, 0]].reshape(-1)
    return np.minimum(a, b) * size + np.maximum(a, b)


def _image_area(vertices: np.ndarray, triangles: np.ndarray) -> float:
    """Total area of ``triangles`` in the image (the grid's x-y projection), texels squared."""
    p = vertices[triangles][:, :, :2]
    e1, e2 = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    return float(0.5 * np.abs(e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]).sum())


def ear_clip(loop: np.ndarray, vertices: np.ndarray, edge_keys: np.ndarray, size: int) -> np.ndarray | None:
    """Triangles closing ``loop``: each step cuts off the vertex whose neighbours are nearest each
    other, among those that make a proper triangle and whose new edge is not an edge already (which
    would make the mesh non-manifold).  None where no such vertex is left."""
    out = np.empty((max(loop.size - 2, 0), 3), dtype=np.int64)
    return out if _ear_clip_kernel(np.ascontiguousarray(loop, dtype=np.int64), vertices, edge_keys, size, out) else None


@njit(cache=True)
def _ear_clip_kernel(loop, vertices, edge_keys, size, out):
    """:func:`ear_clip` into ``out`` ((n - 2, 3)); False where it stops short.  A tie in the chord
    goes to the earliest vertex of the ring, as a stable sort would; a ring of three is the last
    triangle, as it stands, if its first vertex makes a proper one."""
    ring = loop.copy()
    n = ring.size
    added = np.empty(max(n, 1), dtype=np.int64)
    n_added = 0
    made = 0
    while n >= 3:
        best, best_chord = -1, np.inf
        for i in range(n):
            p, v, q = ring[(i - 1) % n], ring[i], ring[(i + 1) % n]
            ab = vertices[v] - vertices[p]
            ac = vertices[q] - vertices[p]
            cx = ab[1] * ac[2] - ab[2] * ac[1]
            cy = ab[2] * ac[0] - ab[0] * ac[2]
            cz = ab[0] * ac[1] - ab[1] * ac[0]
            if not np.sqrt(cx * cx + cy * cy + cz * cz) > 1e-9:
                if n == 3:
                    return False
                continue
            if n == 3:  # the last triangle, in the ring's order
                out[made, 0], out[made, 1], out[made, 2] = ring[0], ring[1], ring[2]
                return True
            chord = np.sqrt(ac[0] * ac[0] + ac[1] * ac[1] + ac[2] * ac[2])
            if chord >= best_chord:
                continue
            key = min(p, q) * size + max(p, q)
            found = np.searchsorted(edge_keys, key)
            if found < edge_keys.size and edge_keys[found] == key:
                continue
            taken = False
            for j in range(n_added):
                if added[j] == key:
                    taken = True
                    break
            if taken:
                continue
            best, best_chord = i, chord
        if best < 0:
            return False
        p, v, q = ring[(best - 1) % n], ring[best], ring[(best + 1) % n]
        out[made, 0], out[made, 1], out[made, 2] = p, v, q
        made += 1
        added[n_added] = min(p, q) * size + max(p, q)
        n_added += 1
        ring[best : n - 1] = ring[best + 1 : n]
        n -= 1
    return True


def close_slits(
    vertices: np.ndarray, triangles: np.ndarray, meshes: np.ndarray, max_area: float = SLIT_AREA, max_width: float = 1.0
) -> tuple[int, np.ndarray]:
    """(number of slits, their closing triangles (s, 3) int64): the boundary loops of the mesh
    that enclose (almost) no area in the image (see the module docstring); ``meshes``: the
    triangles' :func:`mesh_labels`."""
    size = int(vertices.shape[0])
    edge_keys, count = sorted_unique(_edge_keys(triangles, size), counts=True)
    loops = _loops(edge_keys, count, size)
    # A mesh's rim (its loop of largest extent) stays open even where it is seen edge-on: closing
    # it would lay a second sheet over the mesh.
    part = np.zeros(size, dtype=np.int64)
    part[triangles.reshape(-1)] = np.repeat(meshes, 3)
    extent = [float(np.ptp(vertices[loop], axis=0).sum()) for loop in loops]
    rim: dict[int, int] = {}
    for i, loop in enumerate(loops):
        p = int(part[loop[0]])
        if p not in rim or extent[i] > extent[rim[p]]:
            rim[p] = i
    closed = []
    for i, loop in enumerate(loops):
        xy = vertices[loop, :2]
        if rim[int(part[loop[0]])] == i or (xy.max(axis=0) - xy.min(axis=0)).min() > max_width:
            continue
        fill = ear_clip(loop, vertices, edge_keys, size)
        if fill is None or _image_area(vertices, fill) > max_area:
            continue
        closed.append(fill)  # (its new edges join vertices of this loop only: no other loop's)
    if not closed:
        return 0, np.zeros((0, 3), dtype=np.int64)
    return len(closed), np.concatenate(closed)


class _Corners:
    """The distinct corners of quads (X, Y, layer in the half-texel grid of the crop) numbered in
    (layer, Y, X) order, and each quad's four: :meth:`mesh` makes the shared vertices and
    triangles, :meth:`add` appends quads, numbering all corners as if they had come at once (the
    fallback quads come after the rules' 1.7 M on benchmarks/bench_tdm_scale.py: a second sort of
    all 6.8 M corners cost 0.7 s)."""

    def __init__(self, quads: np.ndarray, span: int):
        self.span = span  # more than any X or Y: keys sort as (layer, Y, X) do
        self.keys, self.inverse = sorted_unique(self._keys(quads), inverse=True)

    def _keys(self, quads: np.ndarray) -> np.ndarray:
        corners = quads.reshape(-1, 3).astype(np.int64, copy=False)
        return (corners[:, 2] * self.span + corners[:, 1]) * self.span + corners[:, 0]

    def add(self, quads: np.ndarray) -> None:
        extra = self._keys(quads)
        # The new keys inserted where they sort (np.union1d hashes all of them: 1.8 s for 6.8 M).
        fresh = np.unique(extra)
        at = np.searchsorted(self.keys, fresh)
        known = at < self.keys.size
        known[known] = self.keys[at[known]] == fresh[known]
        keys = np.insert(self.keys, at[~known], fresh[~known])
        self.inverse = np.concatenate(
            [np.searchsorted(keys, self.keys)[self.inverse.reshape(-1)], np.searchsorted(keys, extra)]
        )
        self.keys = keys

    def mesh(self, x0: int, y0: int) -> tuple[np.ndarray, np.ndarray]:
        """Shared vertices (v, 3) float64 and triangles (2q, 3) int64 (quad i -> 2i, 2i + 1)."""
        layer, rest = np.divmod(self.keys, self.span * self.span)
        grid = np.stack(np.divmod(rest, self.span)[::-1], axis=1)  # X, Y
        offset = np.where(grid % 2 == 0, INSET, 1.0 - INSET)
        xy = grid // 2 + offset + [x0, y0]
        vertices = np.concatenate([xy, layer[:, None].astype(np.float64)], axis=1)
        idx = self.inverse.reshape(-1, 4)
        triangles = np.empty((2 * idx.shape[0], 3), dtype=np.int64)
        triangles[0::2] = idx[:, [0, 1, 2]]
        triangles[1::2] = idx[:, [0, 2, 3]]
        return vertices, triangles


def mesh_labels(vertex_count: int, triangles: np.ndarray) -> np.ndarray:
    """(t,) int64 mesh of each triangle: its connected component through shared vertices, numbered
    from 0 in order of first appearance.

    Union-find over the vertices in one numba pass (:func:`_component_labels`): on the 8.8 M initial
    triangles of ``benchmarks/bench_tdm_scale.py --scene scan`` the sparse graph and scipy's
    connected components it replaces (with a sort to number them) took several seconds.

    >>> mesh_labels(7, np.array([[4, 5, 6], [0, 1, 2], [1, 2, 3]])).tolist()
    [0, 1, 1]
    """
    if triangles.shape[0] == 0:
        return np.zeros(0, np.int64)
    return _component_labels(int(vertex_count), np.ascontiguousarray(triangles, dtype=np.int64))


@njit(cache=True)
def _find(parent, v):
    root = v
    while parent[root] != root:
        root = parent[root]
    while parent[v] != root:  # path compression
        parent[v], v = root, parent[v]
    return root


@njit(cache=True)
def _component_labels(vertex_count, triangles):
    """:func:`mesh_labels`' kernel: union the corners of each triangle, then number the roots in
    the order their first triangle comes."""
    parent = np.arange(vertex_count)
    for t in range(triangles.shape[0]):
        a = _find(parent, triangles[t, 0])
        for k in (1, 2):
            b = _find(parent, triangles[t, k])
            if a != b:
                if a < b:
                    parent[b] = a
                else:
                    parent[a] = b
                    a = b
    number = np.full(vertex_count, -1, np.int64)
    labels = np.empty(triangles.shape[0], np.int64)
    count = 0
    for t in range(triangles.shape[0]):
        root = _find(parent, triangles[t, 0])
        if number[root] < 0:
            number[root] = count
            count += 1
        labels[t] = number[root]
    return labels

"""Impostor candidates (seed 000 §5.6): view cells for every node of the object hierarchy.

**Shafts** (§5.6, §5.8.1): for each node, shafts with the apex at the node's centre, apex angles
11.25°, 22.5°, 45° and 90°, directions on a grid of 11.25° steps (rings of constant elevation
11.25° apart, each ring's azimuth step as close to 11.25° as a whole number of steps allows) and
minimum distances 1, 2, 4, ... 2^10 times the node's size (its bounding-box diagonal, so no shaft
meets the node).  A shaft serves a CPV whose 3D region lies inside it, tested conservatively: the
region's bounding sphere inside the circular cone inscribed in the square shaft, and beyond the
minimum distance.

**Boxes** (§5.6): every region of the 3D view-space hierarchy with CPVs is a box view cell for
every node it does not meet; it serves the CPVs of its leaf regions.

**Pruning** ("Candidates are not considered if they serve no CPV ... or the combination of VC and
OC allows no impostor generation", §5.6).  A candidate is kept only if it serves a solvable CPV
whose enclosing frustum meets the node, and the technique's estimate accepts the cell.  Among the
nested candidates of one node, a candidate that serves exactly the CPVs of a smaller cell of the
same node is dropped (the smaller cell needs no more memory): a shaft whose next larger minimum
distance or next smaller apex angle serves the same regions, a box one of whose halves holds all
the regions it serves.

Every kept candidate carries its estimated memory and quads (the cost model over the technique's
layer estimate: layers x texels per layer, §5.8.1); no rendering and no full layer plan.

**Outside-sphere candidates** (not in the thesis): a technique whose impostor serves every view
beyond a distance from its part (octahedral, ``Technique.outside_estimate``) gives each node one
candidate, the outside-sphere cell of that distance around the node's centre, serving every CPV
whose whole region lies in it; its memory and quads are the technique's own (exact for octahedral:
its atlas, one card), not the cost model's layer law, and it covers the square card around the
node's bounding sphere (``4 / pi`` of the disc the CPV's pixels count, at most a frame).  Several
sources of candidates compete in one greedy (``source``: 0 for ``estimate``'s shafts and boxes,
``k + 1`` for ``outside[k]``).

**Instances share an atlas** (issue 56; :mod:`farfield.core.placement.node_instances`): a node
that is exactly one instance of a prototype gets, from an outside source that moves with instances
(``outside_instances``), the prototype's candidate moved by the instance matrix: the estimate of
the prototype's local bounds, its cell's centre moved and its radius scaled by the matrix's
uniform scale (the accuracy distance scales with the instance,
:mod:`farfield.core.techniques.octahedral.instancing`), so every instance's cell is the same cell
of the prototype and one bake serves them all.  Such a candidate records its atlas
(``prototype``: an index into ``prototypes``, one per source and prototype key) and its scale;
the greedy charges each atlas once.

**Simplified geometry** (issue 57 item 3; :mod:`farfield.core.placement.lod`): with ``lod``, a
node that some solvable CPV sees (of 256 triangles or more; of several elements, at most
``lod.MAX_NODE_TRIANGLES``) gets one candidate per QEM level of detail of its elements' merged
mesh (built when the node is first seen), kind ``lod``, serving the CPVs whose region's nearest point to the node's
bounds is far enough for the level's measured error to be within the impostors' pixel budget; its memory is
the level's vertex and index bytes, its time in a CPV the cost model's geometry time of one draw call
of its triangles over the node's pixels there (``layers`` holds the level, ``texels`` its
triangles, ``quads`` 0).  A finer level serving exactly the CPVs a coarser one serves is dropped.
It is the last source (``len(outside) + 1``).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from farfield.core.errors import FarfieldError
from farfield.core.placement.cell_table import CellTable
from farfield.core.placement.cost_model import CostModel
from farfield.core.placement.hierarchy import Hierarchy, PlacementError
from farfield.core.placement.part_estimates import ShaftFrames, Views, box_views, estimate_views, shaft_views
from farfield.core.placement.view_space import CpvGeometry, ProblemViews, box_gap
from farfield.core.viewcells import BoxCell, ShaftCell, SphereOutsideCell

APEX_ANGLES_DEG = (11.25, 22.5, 45.0, 90.0)
DIRECTION_STEP_DEG = 11.25
DISTANCE_STEPS = 11  # minimum distances 2^0 .. 2^10 x the node's size

# "leaf-boxes": only the leaf regions as box view cells, one impostor per cell and node (seed 000
# Table 5.1 test 14, "per rectangular view cell": the placement without Obs. 5.2.2)
CellKinds = ("shafts", "boxes", "both", "leaf-boxes")
# estimate(cell, bounds) -> (layers, texels per layer); raises FarfieldError where no impostor exists
Estimate = Callable[[object, np.ndarray], tuple[float, float]]
# outside(bounds) -> an estimate with ``cell``, ``serves(lo, hi)``, ``memory_bytes``, ``quads``, ``layers``,
# ``texels`` (farfield.core.techniques.octahedral.estimate.OutsideEstimate); raises FarfieldError where none exists
Outside = Callable[[np.ndarray], object]
KIND_NAMES = ("shaft", "box", "outside-sphere", "lod")  # Candidates.kind
OUTSIDE_SPHERE = 2  # the kind of an outside candidate (KIND_NAMES)
LOD = 3  # the kind of a simplified-geometry candidate (KIND_NAMES)
# The CPV index of a (candidate, CPV) row: 4 bytes (a view space has far fewer than 2^31 CPVs).  A
# large city has tens of millions of rows (38 M for 164,001 candidates of a 265,070-triangle city):
# with the two float64 times, 20 bytes a row instead of 24 (the times stay float64: the greedy's
# ranks, and so the placement, are exact sums of them).
CPV_INDEX = np.int32


def direction_grid(step_deg: float = DIRECTION_STEP_DEG) -> np.ndarray:
    """(k, 3) unit directions about ``step_deg`` apart: rings of elevation ``step_deg`` apart (poles included).

    >>> direction_grid().shape
    (328, 3)
    """
    step = math.radians(step_deg)
    rings = int(round(math.pi / step))
    out = []
    for r in range(rings + 1):
        elevation = -0.5 * math.pi + r * math.pi / rings
        count = max(1, int(round(2.0 * math.pi * math.cos(elevation) / step)))
        azimuth = np.arange(count) * (2.0 * math.pi / count)
        ce = math.cos(elevation)
        out.append(np.column_stack([ce * np.cos(azimuth), ce * np.sin(azimuth), np.full(count, math.sin(elevation))]))
    d = np.concatenate(out)
    return d / np.linalg.norm(d, axis=1, keepdims=True)


@dataclass(frozen=True, slots=True, eq=False)
class Candidates:
    """Every kept candidate; the CPVs each serves in CSR form (``served_offsets``), with the node's
    geometry time ``g`` and the impostor's time ``ti`` in each (only CPVs where ``g > ti``: a CPV
    where the impostor saves nothing is never served, and savings only fall, §5.7.4)."""

    node: np.ndarray  # (m,)
    kind: np.ndarray  # (m,) 0 shaft, 1 box, 2 outside-sphere, 3 lod (KIND_NAMES)
    cells: Sequence  # (m,) ShaftCell | BoxCell | SphereOutsideCell (a CellTable: each made when read)
    memory: np.ndarray  # (m,) bytes, estimated
    layers: np.ndarray  # (m,) estimated
    texels: np.ndarray  # (m,) per layer
    quads: np.ndarray  # (m,)
    served_offsets: np.ndarray  # (m + 1,)
    served: np.ndarray  # (total,) CPV indices (CPV_INDEX), ascending within a candidate
    g: np.ndarray  # (total,) the node's geometry time in that CPV
    ti: np.ndarray  # (total,) the impostor's time there
    stats: dict
    source: np.ndarray | None = None  # (m,) 0: the estimate's shafts and boxes, k + 1: outside[k]; None: all 0
    prototype: np.ndarray | None = None  # (m,) the shared atlas (index into ``prototypes``), -1: its own; None: all -1
    prototypes: tuple = ()  # (source, prototype key) of each shared atlas
    scale: np.ndarray | None = None  # (m,) the instance's uniform scale of a shared candidate, else 1

    @property
    def count(self) -> int:
        return int(self.node.shape[0])

    def source_of(self, i: int) -> int:
        """Which source candidate ``i`` came from (see the module docstring)."""
        return 0 if self.source is None else int(self.source[i])

    def atlas_of(self, i: int) -> int:
        """The shared atlas candidate ``i`` draws from (an index into ``prototypes``), -1: its own."""
        return -1 if getattr(self, "prototype", None) is None else int(self.prototype[i])


@dataclass(frozen=True, slots=True)
class NodeCells:
    """A node's shafts or boxes and the regions each serves, in CSR form (``offsets`` into ``served``,
    ascending within a cell): shafts' ``keys`` (m, 3) are (apex angle index, direction index,
    distance step), boxes' ``lo`` and ``hi`` (m, 3) their corners."""

    offsets: np.ndarray  # (m + 1,) int64
    served: np.ndarray  # (total,) region indices
    keys: np.ndarray | None = None  # (m, 3) int64: shafts
    lo: np.ndarray | None = None  # (m, 3): boxes
    hi: np.ndarray | None = None

    @property
    def count(self) -> int:
        return int(self.offsets.shape[0] - 1)

    def regions(self, i: int) -> np.ndarray:
        return self.served[self.offsets[i] : self.offsets[i + 1]]

    @staticmethod
    def none(shaft: bool) -> NodeCells:
        empty = np.zeros((0, 3), dtype=np.int64 if shaft else np.float64)
        return NodeCells(
            np.zeros(1, dtype=np.int64), np.zeros(0, dtype=np.int64), *((empty,) if shaft else (None, empty, empty))
        )


def _csr(mask: np.ndarray, regions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(counts, served) of the cells that are ``mask``'s columns (regions x cells): each column's
    ``regions`` in ascending order, one column after another."""
    cell, row = np.nonzero(mask.T)
    return np.bincount(cell, minlength=mask.shape[1]), regions[row]


def _shaft_cells(
    n: int,
    centre: np.ndarray,
    size: float,
    regions: np.ndarray,
    region_centre,
    region_radius,
    grid,
    halves,
    distance_steps,
):
    """Node ``n``'s shafts (a :class:`NodeCells` with ``keys``; :func:`_shaft_cell` makes one a
    cell), with the dominance pruning (see the module docstring); ``regions`` are those where the
    node is in some solvable CPV's frustum.  Every apex angle's shafts at once: the served regions
    of all its (direction, distance) pairs from one (regions x pairs) mask."""
    considered = 0
    vec = region_centre[regions] - centre
    dist = np.linalg.norm(vec, axis=1)
    far = dist > region_radius[regions]
    regions, vec, dist = regions[far], vec[far], dist[far]
    if regions.size == 0:
        return NodeCells.none(True), considered
    unit = vec / dist[:, None]
    radius = region_radius[regions]
    gamma = np.arcsin(np.minimum(radius / dist, 1.0))
    need = np.arccos(np.clip(unit @ grid.T, -1.0, 1.0)) + gamma[:, None]  # (r, k) half-angle a shaft needs
    a_index = np.searchsorted(halves, need, side="left")  # smallest apex angle holding the region
    along = dist[:, None] * np.cos(np.minimum(need, 0.5 * math.pi)) - radius[:, None]
    with np.errstate(divide="ignore", invalid="ignore"):
        k_index = np.floor(np.log2(np.clip(np.where(along > 0.0, along / size, 0.5), 0.5, 2.0**62))).astype(np.int64)
    k_index = np.minimum(k_index, distance_steps - 1)  # the largest k with 2^k size <= along, or -1
    ok = (a_index < len(halves)) & (k_index >= 0)
    steps = np.int64(distance_steps + 1)
    keys, counts, served = [], [], []
    for a in range(len(halves)):
        fits = ok & (a_index <= a)
        # (a, d, k) serves the regions with k_index >= k: only the k some region has exactly differ
        # from k + 1's (each (d, k) a region of direction d has, ascending), and unless a region
        # needing angle a has k_index >= k, the next smaller angle serves the same.
        rows, cols = np.nonzero(fits)
        pairs = np.unique(cols * steps + k_index[rows, cols])
        considered += int(pairs.size)
        ds, ks = pairs // steps, pairs % steps
        if a > 0:
            reach = np.where(fits & (a_index == a), k_index, -1).max(axis=0)
            keep = reach[ds] >= ks
            ds, ks = ds[keep], ks[keep]
        if ds.size == 0:
            continue
        c, r = _csr(fits[:, ds] & (k_index[:, ds] >= ks), regions)
        keys.append(np.column_stack([np.full(ds.size, a), ds, ks]))
        counts.append(c)
        served.append(r)
    if not keys:
        return NodeCells.none(True), considered
    offsets = np.concatenate([[0], np.cumsum(np.concatenate(counts))]).astype(np.int64)
    return NodeCells(offsets, np.concatenate(served), keys=np.concatenate(keys).astype(np.int64)), considered


def _shaft_cell(
    centre: np.ndarray, size: float, grid: np.ndarray, halves: np.ndarray, a: int, d: int, k: int
) -> ShaftCell:
    """The shaft ``(a, d, k)`` of :func:`_shaft_cells` of a node at ``centre`` of ``size``."""
    return ShaftCell(centre, grid[d], 2.0 * halves[a], float(2.0**k) * size)


def _leaf_box_cells(pv: ProblemViews, lo: np.ndarray, hi: np.ndarray, region_relevant: np.ndarray):
    """A box cell (:class:`NodeCells` with ``lo``, ``hi``) for every leaf region apart from the node where it is relevant."""
    span = pv.region_hi - pv.region_lo
    pad = np.where(span > 0.0, 0.0, np.maximum(1e-6 * span.max(axis=1, keepdims=True), 1e-9))
    apart = box_gap(pv.region_lo, pv.region_hi, lo, hi) > 0.0
    chosen = np.flatnonzero(region_relevant & apart)
    cells = NodeCells(
        np.arange(chosen.size + 1, dtype=np.int64), chosen.astype(np.int64), lo=pv.region_lo[chosen] - pad[chosen],
        hi=pv.region_hi[chosen] + pad[chosen],
    )  # fmt: skip
    return cells, int(chosen.size)


def _box_cells(pv: ProblemViews, lo: np.ndarray, hi: np.ndarray, region_relevant: np.ndarray):
    """A node's box candidates (:class:`NodeCells` with ``lo``, ``hi``): view-space hierarchy regions
    apart from the node holding relevant leaf regions, unless one of their halves holds them all."""
    counts = np.concatenate([[0], np.cumsum(region_relevant)])
    cnt = counts[pv.tree_last] - counts[pv.tree_first]
    apart = box_gap(pv.tree_lo, pv.tree_hi, lo, hi) > 0.0
    child = pv.tree_parent >= 0
    same = child & apart & (cnt == cnt[np.maximum(pv.tree_parent, 0)])
    dominated = np.zeros(cnt.shape, dtype=bool)
    dominated[pv.tree_parent[same]] = True
    span = pv.tree_hi - pv.tree_lo
    # A flat view space (a walking plane) has flat regions: their box cells get a sliver of
    # thickness (a millionth of their largest side), which only enlarges the cell.
    pad = np.where(span > 0.0, 0.0, np.maximum(1e-6 * span.max(axis=1, keepdims=True), 1e-9))
    chosen = np.flatnonzero((cnt > 0) & apart & ~dominated)
    # each chosen region's relevant leaf regions (tree_first .. tree_last), ascending
    relevant = np.flatnonzero(region_relevant)
    first = np.searchsorted(relevant, pv.tree_first[chosen], side="left")
    last = np.searchsorted(relevant, pv.tree_last[chosen], side="left")
    cells = NodeCells(
        np.concatenate([[0], np.cumsum(last - first)]).astype(np.int64), relevant[_ragged(first, last - first)],
        lo=pv.tree_lo[chosen] - pad[chosen], hi=pv.tree_hi[chosen] + pad[chosen],
    )  # fmt: skip
    return cells, int(np.sum((cnt > 0) & apart))


ROW_BLOCK = 1 << 23  # (candidate, CPV) rows per block of _RowColumns: 32-64 MiB a column, each its own mapping


class _RowColumns:
    """The (candidate, CPV) rows' columns (``served``, ``g``, ``ti``), appended into blocks of
    ``block`` rows and made one array per column at the end, each block let go as it is copied.

    A large city has hundreds of millions of rows (281 M for the 922,909 candidates of an
    11.5 M-triangle city); kept as the nodes' small chunks, freed memory stayed with the process
    (fragmented), and concatenating a column held it twice.  Blocks this large are mapped and
    unmapped whole, so the peak is about the rows themselves plus a block."""

    DTYPES = {"served": CPV_INDEX, "g": np.float64, "ti": np.float64}

    def __init__(self, block: int | None = None) -> None:
        self.block, self.total, self.used = int(ROW_BLOCK if block is None else block), 0, 0
        self.blocks: dict[str, list] = {k: [] for k in self.DTYPES}

    def add(self, served: np.ndarray, g: np.ndarray, ti: np.ndarray) -> None:
        columns = (np.asarray(served), np.asarray(g, dtype=np.float64), np.asarray(ti, dtype=np.float64))
        n, at = int(columns[0].shape[0]), 0
        while at < n:
            if not self.blocks["served"] or self.used == self.blocks["served"][-1].shape[0]:
                for k, dtype in self.DTYPES.items():
                    self.blocks[k].append(np.empty(self.block, dtype=dtype))
                self.used = 0
            take = min(n - at, self.block - self.used)
            for k, values in zip(self.DTYPES, columns):
                self.blocks[k][-1][self.used : self.used + take] = values[at : at + take]
            self.used += take
            at += take
        self.total += n

    def flat(self, name: str) -> np.ndarray:
        """Column ``name`` in one array; its blocks are let go as they are copied."""
        out = np.empty(self.total, dtype=self.DTYPES[name])
        blocks, at = self.blocks[name], 0
        for j in range(len(blocks)):
            n = min(blocks[j].shape[0], self.total - at)
            out[at : at + n] = blocks[j][:n]
            blocks[j] = None  # unmapped now, before the next block's copy
            at += n
        self.blocks[name] = []
        return out


class _Rows:
    """The kept candidates, gathered in chunks (one candidate or a node's batch at a time); their
    (candidate, CPV) rows in :class:`_RowColumns`."""

    FIELDS = ("node", "kind", "layers", "texels", "source", "memory", "quads", "atlas", "scale", "count")

    def __init__(self) -> None:
        self.chunks = {f: [] for f in self.FIELDS}
        self.cells: list[CellTable] = []
        self.rows = _RowColumns()

    def add(self, cells: list | CellTable, served: np.ndarray, g: np.ndarray, ti: np.ndarray, **columns) -> None:
        """Candidates ``cells`` (their ``columns``, arrays or scalars; ``count``: each one's served
        CPVs, whose rows ``served``, ``g``, ``ti`` follow one another)."""
        k = len(cells)
        for f in self.FIELDS:
            self.chunks[f].append(np.broadcast_to(np.asarray(columns[f]), (k,)))
        self.cells.append(cells if isinstance(cells, CellTable) else CellTable.of(cells))
        self.rows.add(served, g, ti)

    def column(self, name: str, dtype) -> np.ndarray:
        parts = self.chunks[name]
        return np.concatenate(parts).astype(dtype) if parts else np.empty(0, dtype=dtype)

    def flat(self, name: str) -> np.ndarray:
        """The rows' column ``name`` (served, g or ti) in one array (:meth:`_RowColumns.flat`)."""
        return self.rows.flat(name)


def _region_rows(cpv_regions: np.ndarray, regions_count: int) -> tuple[np.ndarray, np.ndarray]:
    """(start, end) of each region's rows in ``cpv_regions`` (non-decreasing: a leaf region's CPVs
    follow one another, :func:`~farfield.core.placement.view_space.problem_view_space`)."""
    at = np.arange(regions_count)
    return np.searchsorted(cpv_regions, at, side="left"), np.searchsorted(cpv_regions, at, side="right")


def _ragged(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The concatenation of ``arange(starts[i], starts[i] + lengths[i])`` over ``i``."""
    total = int(lengths.sum())
    return np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(lengths) - lengths - starts, lengths)


def generate_candidates(
    hierarchy: Hierarchy,
    pv: ProblemViews,
    model: CostModel,
    estimate: Estimate,
    frame_pixels: float,
    cells: str = "shafts",
    apex_angles_deg=APEX_ANGLES_DEG,
    direction_step_deg: float = DIRECTION_STEP_DEG,
    distance_steps: int = DISTANCE_STEPS,
    progress: Callable[[int, int], None] | None = None,
    max_bytes: float = math.inf,
    outside: tuple[Outside, ...] = (),
    outside_instances: tuple[dict, ...] = (),
    part_options=None,
    lod=None,
    nodes: range | None = None,
) -> Candidates:
    """The candidates of every hierarchy node for the solvable CPVs of ``pv`` (see the module docstring).

    ``nodes``: only these hierarchy nodes' candidates (a part of the planning that another process
    may compute, :mod:`farfield.core.placement.candidate_parts`); None: every node.

    ``max_bytes``: a cell whose impostor the model expects to take more memory than this is not a
    candidate (counted in ``stats["refused_by_memory"]``): its bake would take long and its memory
    would be most of the placement's.  ``estimate`` None: no shafts or boxes (only ``outside``'s
    candidates, one per node and source).  ``outside_instances[k]``: node -> NodeInstance
    (:func:`~farfield.core.placement.node_instances.node_instances`) of the nodes whose
    ``outside[k]`` candidate is their prototype's, moved (module docstring).

    ``part_options``: when ``estimate`` is :func:`~farfield.core.techniques.part.estimate_part_cell`
    with these options, a node's shafts and boxes are estimated together
    (:mod:`farfield.core.placement.part_estimates`, the same numbers) and only the kept ones become
    cells; None: ``estimate`` is called cell by cell (the reference the tests compare with).

    ``lod``: a :class:`~farfield.core.placement.lod.NodeLods` whose levels of detail compete too
    (module docstring); None: none."""
    if cells not in CellKinds:
        raise PlacementError(f"cells must be one of {list(CellKinds)}, got {cells!r}")
    halves = np.radians(np.asarray(apex_angles_deg, dtype=np.float64)) * 0.5
    if halves.size == 0 or np.any(~((halves > 0.0) & (halves < 0.5 * math.pi))) or np.any(np.diff(halves) <= 0):
        raise PlacementError(
            f"shaft apex angles must be increasing and lie in (0, 180) degrees, got {list(apex_angles_deg)}"
        )
    solvable = np.flatnonzero(~pv.unsolvable)
    regions_count = pv.region_lo.shape[0]
    geometry = CpvGeometry(pv, hierarchy)
    region_centre = 0.5 * (pv.region_lo + pv.region_hi)
    region_radius = 0.5 * np.linalg.norm(pv.region_hi - pv.region_lo, axis=1)
    node_centre = 0.5 * (hierarchy.lo + hierarchy.hi)
    size = np.maximum(hierarchy.diagonal, 1e-300)
    grid = direction_grid(direction_step_deg)
    batch = (
        None
        if part_options is None or estimate is None
        else (ShaftFrames.of(grid), [math.tan(0.5 * float(2.0 * h)) for h in halves])
    )
    rows, atlases, reached = _Rows(), {}, {}
    counts = {"considered": 0, "refused_by_technique": 0, "refused_by_memory": 0}
    nodes = range(hierarchy.count) if nodes is None else nodes
    for done, n in enumerate(nodes, 1):
        g_all, pixels_all = geometry.of(np.full(solvable.size, n), solvable)
        seen = g_all > 0.0
        if not seen.any():
            continue
        cpvs, g_n, pixels_n = solvable[seen], g_all[seen], np.minimum(pixels_all[seen], frame_pixels)
        cpv_regions = pv.cpv_region[cpvs]
        region_relevant = np.bincount(cpv_regions, minlength=regions_count) > 0
        shafts, boxes = NodeCells.none(True), NodeCells.none(False)
        if estimate is not None and cells in ("shafts", "both"):
            shafts, c = _shaft_cells(
                n, node_centre[n], float(size[n]), np.flatnonzero(region_relevant), region_centre, region_radius, grid, halves, distance_steps,
            )  # fmt: skip
            counts["considered"] += c
        if estimate is not None and cells in ("boxes", "both", "leaf-boxes"):
            boxes, c = (_leaf_box_cells if cells == "leaf-boxes" else _box_cells)(
                pv, hierarchy.lo[n], hierarchy.hi[n], region_relevant
            )
            counts["considered"] += c
        bounds = np.stack([hierarchy.lo[n], hierarchy.hi[n]])
        floor = np.asarray(model.impostor_time(pixels_n, 0.0), dtype=np.float64).reshape(-1)  # no quads: a lower bound
        node = (n, cpvs, g_n, pixels_n, cpv_regions, bounds, floor)
        if batch is not None:
            _node_batch(
                rows,
                counts,
                node,
                shafts,
                boxes,
                batch,
                (node_centre[n], float(size[n]), grid, halves),
                model,
                part_options,
                max_bytes,
                regions_count,
            )
        else:
            found = [
                (
                    0,
                    _shaft_cell(node_centre[n], float(size[n]), grid, halves, *shafts.keys[i].tolist()),
                    shafts.regions(i),
                )
                for i in range(shafts.count)
            ]
            found += [(1, BoxCell(boxes.lo[i], boxes.hi[i]), boxes.regions(i)) for i in range(boxes.count)]
            _node_cells(rows, counts, node, found, model, estimate, max_bytes)
        for k, reach in enumerate(outside):
            counts["considered"] += 1
            inst = outside_instances[k].get(n) if k < len(outside_instances) else None
            try:
                far = reach(bounds) if inst is None else _moved(_once(reached, k, reach, inst.local_bounds), inst)
            except FarfieldError:
                counts["refused_by_technique"] += 1
                continue
            if float(far.memory_bytes) > max_bytes:
                counts["refused_by_memory"] += 1
                continue
            in_cell = np.isin(cpv_regions, np.flatnonzero(far.serves(pv.region_lo, pv.region_hi)))
            card = np.minimum(pixels_n * (4.0 / math.pi), frame_pixels)  # the square card around the disc
            ti = np.asarray(model.impostor_time(card, float(far.quads)), dtype=np.float64).reshape(-1)
            keep = in_cell & (g_n > ti)
            if not keep.any():
                continue
            atlas = -1 if inst is None else atlases.setdefault((k + 1, inst.prototype), len(atlases))
            rows.add([far.cell], cpvs[keep], g_n[keep], ti[keep], node=n, kind=OUTSIDE_SPHERE, layers=far.layers, texels=far.texels,
                     source=k + 1, memory=far.memory_bytes, quads=far.quads, atlas=atlas, scale=1.0 if inst is None else inst.scale,
                     count=int(keep.sum()))  # fmt: skip
        if lod is not None:
            _lod_cells(rows, counts, node, lod, model, max_bytes, pv, len(outside) + 1)
        if progress is not None:
            progress(done, len(nodes))
    layers_a, texels_a = rows.column("layers", np.float64), rows.column("texels", np.float64)
    own_memory, own_quads = rows.column("memory", np.float64), rows.column("quads", np.float64)
    return Candidates(
        node=rows.column("node", np.int64),
        kind=rows.column("kind", np.int64),
        cells=CellTable.concat(rows.cells),
        memory=np.where(
            np.isnan(own_memory),
            np.asarray(model.memory_bytes(layers_a, texels_a), dtype=np.float64).reshape(-1),
            own_memory,
        ),
        layers=layers_a,
        texels=texels_a,
        quads=np.where(
            np.isnan(own_quads), np.asarray(model.quads(layers_a, texels_a), dtype=np.float64).reshape(-1), own_quads
        ),
        served_offsets=np.concatenate([[0], np.cumsum(rows.column("count", np.int64))]).astype(np.int64),
        served=rows.flat("served"),
        g=rows.flat("g"),
        ti=rows.flat("ti"),
        stats=counts,
        source=rows.column("source", np.int64),
        prototype=rows.column("atlas", np.int64),
        prototypes=tuple(atlases),
        scale=rows.column("scale", np.float64),
    )


def _node_cells(rows: _Rows, counts: dict, node, found, model: CostModel, estimate: Estimate, max_bytes: float) -> None:
    """Node ``node``'s shafts and boxes ``found`` ((kind, cell, served regions)), estimated one
    cell at a time by ``estimate``."""
    n, cpvs, g_n, pixels_n, cpv_regions, bounds, floor = node
    for kind, cell, served_regions in found:
        in_cell = np.isin(cpv_regions, served_regions)
        if not np.any(in_cell & (g_n > floor)):
            continue  # saves nothing in any CPV it serves, whatever its layers: not worth estimating
        try:
            layers, per_layer = estimate(cell, bounds)
        except FarfieldError:
            counts["refused_by_technique"] += 1
            continue
        if float(model.memory_bytes(layers, per_layer)) > max_bytes:
            counts["refused_by_memory"] += 1
            continue
        ti = np.asarray(model.impostor_time(pixels_n, model.quads(layers, per_layer)), dtype=np.float64).reshape(-1)
        keep = in_cell & (g_n > ti)
        if not keep.any():
            continue
        rows.add([cell], cpvs[keep], g_n[keep], ti[keep], node=n, kind=kind, layers=layers, texels=per_layer, source=0,
                 memory=np.nan, quads=np.nan, atlas=-1, scale=1.0, count=int(keep.sum()))  # fmt: skip


def _node_batch(rows: _Rows, counts: dict, node, shafts: NodeCells, boxes: NodeCells, batch, shape, model: CostModel,
                options, max_bytes: float, regions_count: int) -> None:  # fmt: skip
    """What :func:`_node_cells` does, for all of a node's shafts and boxes (:class:`NodeCells`) at
    once (:mod:`farfield.core.placement.part_estimates`): the same candidates, the same numbers, in
    the same order."""
    n, cpvs, g_n, pixels_n, cpv_regions, bounds, floor = node
    frames, half_tans = batch
    centre, size, grid, halves = shape
    ns = shafts.count
    lengths = np.concatenate([np.diff(shafts.offsets), np.diff(boxes.offsets)])
    if lengths.size == 0:
        return
    flat = np.concatenate([shafts.served, boxes.served])
    starts = np.concatenate([[0], np.cumsum(lengths)[:-1]])
    owner = np.repeat(np.arange(lengths.size), lengths)
    # Pruned as cell by cell: a cell saving nothing where it serves, whatever its layers, is not estimated.
    helps = np.bincount(cpv_regions[g_n > floor], minlength=regions_count) > 0
    worth = np.bincount(owner, weights=helps[flat], minlength=lengths.size) > 0
    si = np.flatnonzero(worth[:ns])
    bi = np.flatnonzero(worth[ns:])
    if si.size + bi.size == 0:
        return
    parts = []
    if si.size:
        abk = shafts.keys[si]
        angle = 2.0 * halves[abk[:, 0]]
        parts.append(
            shaft_views(
                bounds, centre, frames, abk[:, 1], angle, np.asarray(half_tans)[abk[:, 0]], (2.0 ** abk[:, 2]) * size
            )
        )
    if bi.size:
        parts.append(box_views(bounds, boxes.lo[bi], boxes.hi[bi]))
    which = np.concatenate([si, ns + bi])
    layers, texels, ok = estimate_views(Views.concat(parts), options)
    counts["refused_by_technique"] += int(np.sum(~ok))
    memory = np.asarray(model.memory_bytes(layers, texels), dtype=np.float64).reshape(-1)
    large = ok & (memory > max_bytes)
    counts["refused_by_memory"] += int(np.sum(large))
    use = np.flatnonzero(ok & ~large)
    if use.size == 0:
        return
    which, layers, texels = which[use], layers[use], texels[use]
    quads = np.asarray(model.quads(layers, texels), dtype=np.float64).reshape(-1)
    # Every (cell, CPV) row of the cells left: the node's CPVs of each served region, in order.
    start, end = _region_rows(cpv_regions, regions_count)
    reg = flat[_ragged(starts[which], lengths[which])]
    reg_owner = np.repeat(np.arange(which.size), lengths[which])
    span = end[reg] - start[reg]
    entry = _ragged(start[reg], span)
    entry_owner = np.repeat(reg_owner, span)
    ti = np.asarray(model.impostor_time(pixels_n[entry], quads[entry_owner]), dtype=np.float64).reshape(-1)
    keep = g_n[entry] > ti
    kept = np.bincount(entry_owner[keep], minlength=which.size)
    good = kept > 0
    if not good.any():
        return
    made = which[good]  # shafts first, then boxes (as ``which``): their cells made when read (CellTable)
    abk = shafts.keys[made[made < ns]].reshape(-1, 3)
    box = made[made >= ns] - ns
    made = CellTable.concat([
        CellTable.shafts(centre, grid[abk[:, 1]], 2.0 * halves[abk[:, 0]], (2.0 ** abk[:, 2]) * size),
        CellTable.boxes(boxes.lo[box].reshape(-1, 3), boxes.hi[box].reshape(-1, 3)),
    ])  # fmt: skip
    rows.add(made, cpvs[entry[keep]], g_n[entry[keep]], ti[keep], node=n, kind=(which[good] >= ns).astype(np.int64),
             layers=layers[good], texels=texels[good], source=0, memory=np.nan, quads=np.nan, atlas=-1, scale=1.0, count=kept[good])  # fmt: skip


def _lod_cells(
    rows: _Rows, counts: dict, node, lod, model: CostModel, max_bytes: float, pv: ProblemViews, source: int
) -> None:
    """Node ``node``'s levels of detail as candidates (module docstring), coarsest first."""
    n, cpvs, g_n, pixels_n, cpv_regions, bounds, floor = node
    if not np.any(g_n > floor):
        return  # nothing is faster than its geometry anywhere: not worth simplifying
    served = None
    for level, distance, cell in reversed(lod.cells(n, bounds)):
        counts["considered"] += 1
        if float(level.memory_bytes) > max_bytes:
            counts["refused_by_memory"] += 1
            continue
        outside = box_gap(pv.region_lo, pv.region_hi, bounds[0], bounds[1]) >= distance  # nearest point of each region
        ti = np.asarray(model.geometry_time(1.0, float(level.triangles), pixels_n), dtype=np.float64).reshape(-1)
        keep = outside[cpv_regions] & (g_n > ti)
        if not keep.any() or (served is not None and np.array_equal(cpvs[keep], served)):
            continue
        served = cpvs[keep]
        rows.add([cell], served, g_n[keep], ti[keep], node=n, kind=LOD, layers=float(level.level), texels=float(level.triangles),
                 source=source, memory=float(level.memory_bytes), quads=0.0, atlas=-1, scale=1.0, count=int(keep.sum()))  # fmt: skip


def _once(memo: dict, k: int, reach: Outside, bounds: np.ndarray):
    """``reach(bounds)`` of outside source ``k``, computed once per source and bounds (every
    instance of a prototype asks with its local bounds; an octahedral accuracy distance takes a
    tenth of a second), its FarfieldError raised again each time."""
    key = (k, np.asarray(bounds, dtype=np.float64).tobytes())
    if key not in memo:
        try:
            memo[key] = reach(bounds)
        except FarfieldError as error:
            memo[key] = error
    found = memo[key]
    if isinstance(found, FarfieldError):
        raise found
    return found


def _moved(far, inst):
    """The outside estimate ``far`` of a prototype (in its local space) moved to instance ``inst``:
    its cell's centre moved by the matrix, its radius scaled by the matrix's uniform scale."""
    cell = far.cell
    return replace(
        far, cell=SphereOutsideCell(inst.world_point(cell.centre), cell.radius * inst.scale, cell.hemisphere)
    )

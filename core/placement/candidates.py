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
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np

from farfield.core.errors import FarfieldError
from farfield.core.placement.cost_model import CostModel
from farfield.core.placement.hierarchy import Hierarchy, PlacementError
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
KIND_NAMES = ("shaft", "box", "outside-sphere")  # Candidates.kind
OUTSIDE_SPHERE = 2  # the kind of an outside candidate (KIND_NAMES)


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
    kind: np.ndarray  # (m,) 0 shaft, 1 box, 2 outside-sphere (KIND_NAMES)
    cells: tuple  # (m,) ShaftCell | BoxCell | SphereOutsideCell
    memory: np.ndarray  # (m,) bytes, estimated
    layers: np.ndarray  # (m,) estimated
    texels: np.ndarray  # (m,) per layer
    quads: np.ndarray  # (m,)
    served_offsets: np.ndarray  # (m + 1,)
    served: np.ndarray  # (total,) CPV indices, ascending within a candidate
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
    """(cell, served regions) of node ``n``'s shafts (see the module docstring), with the dominance
    pruning; ``regions`` are those where the node is in some solvable CPV's frustum."""
    out, considered = [], 0
    vec = region_centre[regions] - centre
    dist = np.linalg.norm(vec, axis=1)
    far = dist > region_radius[regions]
    regions, vec, dist = regions[far], vec[far], dist[far]
    if regions.size == 0:
        return out, considered
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
    for a in range(len(halves)):
        fits = ok & (a_index <= a)
        for d in np.flatnonzero(fits.any(axis=0)):
            col = fits[:, d]
            ks, exact_a = k_index[col, d], a_index[col, d] == a
            # (a, d, k) serves the regions with k_index >= k: only the k some region has exactly
            # differ from k + 1's, and unless a region needs angle a, the next smaller angle serves the same.
            for k in np.unique(ks):
                considered += 1
                sel = ks >= k
                if a > 0 and not np.any(exact_a & sel):
                    continue
                out.append((ShaftCell(centre, grid[d], 2.0 * halves[a], float(2.0**k) * size), regions[col][sel]))
    return out, considered


def _leaf_box_cells(pv: ProblemViews, lo: np.ndarray, hi: np.ndarray, region_relevant: np.ndarray):
    """(cell, [region]) for every leaf region apart from the node where it is relevant."""
    span = pv.region_hi - pv.region_lo
    pad = np.where(span > 0.0, 0.0, np.maximum(1e-6 * span.max(axis=1, keepdims=True), 1e-9))
    apart = box_gap(pv.region_lo, pv.region_hi, lo, hi) > 0.0
    chosen = np.flatnonzero(region_relevant & apart)
    return [(BoxCell(pv.region_lo[r] - pad[r], pv.region_hi[r] + pad[r]), np.array([r])) for r in chosen], int(
        chosen.size
    )


def _box_cells(pv: ProblemViews, lo: np.ndarray, hi: np.ndarray, region_relevant: np.ndarray):
    """(cell, served regions) of a node's box candidates: view-space hierarchy regions apart from
    the node holding relevant leaf regions, unless one of their halves holds them all."""
    counts = np.concatenate([[0], np.cumsum(region_relevant)])
    cnt = counts[pv.tree_last] - counts[pv.tree_first]
    apart = box_gap(pv.tree_lo, pv.tree_hi, lo, hi) > 0.0
    child = pv.tree_parent >= 0
    same = child & apart & (cnt == cnt[np.maximum(pv.tree_parent, 0)])
    dominated = np.zeros(cnt.shape, dtype=bool)
    dominated[pv.tree_parent[same]] = True
    out = []
    span = pv.tree_hi - pv.tree_lo
    # A flat view space (a walking plane) has flat regions: their box cells get a sliver of
    # thickness (a millionth of their largest side), which only enlarges the cell.
    pad = np.where(span > 0.0, 0.0, np.maximum(1e-6 * span.max(axis=1, keepdims=True), 1e-9))
    for q in np.flatnonzero((cnt > 0) & apart & ~dominated):
        served = pv.tree_first[q] + np.flatnonzero(region_relevant[pv.tree_first[q] : pv.tree_last[q]])
        out.append((BoxCell(pv.tree_lo[q] - pad[q], pv.tree_hi[q] + pad[q]), served))
    return out, int(np.sum((cnt > 0) & apart))


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
) -> Candidates:
    """The candidates of every hierarchy node for the solvable CPVs of ``pv`` (see the module docstring).

    ``max_bytes``: a cell whose impostor the model expects to take more memory than this is not a
    candidate (counted in ``stats["refused_by_memory"]``): its bake would take long and its memory
    would be most of the placement's.  ``estimate`` None: no shafts or boxes (only ``outside``'s
    candidates, one per node and source).  ``outside_instances[k]``: node -> NodeInstance
    (:func:`~farfield.core.placement.node_instances.node_instances`) of the nodes whose
    ``outside[k]`` candidate is their prototype's, moved (module docstring)."""
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
    node_l, kind_l, cell_l, layer_l, texel_l, served_l, g_l, ti_l = [], [], [], [], [], [], [], []
    source_l, memory_l, quads_l, atlas_l, scale_l, atlases = [], [], [], [], [], {}
    considered = refused = too_large = 0
    for n in range(hierarchy.count):
        g_all, pixels_all = geometry.of(np.full(solvable.size, n), solvable)
        seen = g_all > 0.0
        if not seen.any():
            continue
        cpvs, g_n, pixels_n = solvable[seen], g_all[seen], np.minimum(pixels_all[seen], frame_pixels)
        cpv_regions = pv.cpv_region[cpvs]
        region_relevant = np.bincount(cpv_regions, minlength=regions_count) > 0
        found = []
        if estimate is not None and cells in ("shafts", "both"):
            more, c = _shaft_cells(
                n,
                node_centre[n],
                float(size[n]),
                np.flatnonzero(region_relevant),
                region_centre,
                region_radius,
                grid,
                halves,
                distance_steps,
            )
            found += [(0, cell, served) for cell, served in more]
            considered += c
        if estimate is not None and cells in ("boxes", "both", "leaf-boxes"):
            boxes = _leaf_box_cells if cells == "leaf-boxes" else _box_cells
            more, c = boxes(pv, hierarchy.lo[n], hierarchy.hi[n], region_relevant)
            found += [(1, cell, served) for cell, served in more]
            considered += c
        bounds = np.stack([hierarchy.lo[n], hierarchy.hi[n]])
        floor = np.asarray(model.impostor_time(pixels_n, 0.0), dtype=np.float64).reshape(-1)  # no quads: a lower bound
        for kind, cell, served_regions in found:
            in_cell = np.isin(cpv_regions, served_regions)
            if not np.any(in_cell & (g_n > floor)):
                continue  # saves nothing in any CPV it serves, whatever its layers: not worth estimating
            try:
                layers, per_layer = estimate(cell, bounds)
            except FarfieldError:
                refused += 1
                continue
            if float(model.memory_bytes(layers, per_layer)) > max_bytes:
                too_large += 1
                continue
            ti = np.asarray(model.impostor_time(pixels_n, model.quads(layers, per_layer)), dtype=np.float64).reshape(-1)
            keep = in_cell & (g_n > ti)
            if not keep.any():
                continue
            (
                node_l.append(n),
                kind_l.append(kind),
                cell_l.append(cell),
                layer_l.append(layers),
                texel_l.append(per_layer),
            )
            source_l.append(0), memory_l.append(np.nan), quads_l.append(np.nan), atlas_l.append(-1), scale_l.append(1.0)
            served_l.append(cpvs[keep]), g_l.append(g_n[keep]), ti_l.append(ti[keep])
        for k, reach in enumerate(outside):
            considered += 1
            inst = outside_instances[k].get(n) if k < len(outside_instances) else None
            try:
                far = reach(bounds) if inst is None else _moved(reach(inst.local_bounds), inst)
            except FarfieldError:
                refused += 1
                continue
            if float(far.memory_bytes) > max_bytes:
                too_large += 1
                continue
            in_cell = np.isin(cpv_regions, np.flatnonzero(far.serves(pv.region_lo, pv.region_hi)))
            card = np.minimum(pixels_n * (4.0 / math.pi), frame_pixels)  # the square card around the disc
            ti = np.asarray(model.impostor_time(card, float(far.quads)), dtype=np.float64).reshape(-1)
            keep = in_cell & (g_n > ti)
            if not keep.any():
                continue
            node_l.append(n), kind_l.append(OUTSIDE_SPHERE), cell_l.append(far.cell), layer_l.append(far.layers)
            (
                texel_l.append(far.texels),
                source_l.append(k + 1),
                memory_l.append(far.memory_bytes),
                quads_l.append(far.quads),
            )
            served_l.append(cpvs[keep]), g_l.append(g_n[keep]), ti_l.append(ti[keep])
            atlas_l.append(-1 if inst is None else atlases.setdefault((k + 1, inst.prototype), len(atlases)))
            scale_l.append(1.0 if inst is None else inst.scale)
        if progress is not None:
            progress(n + 1, hierarchy.count)
    layers_a, texels_a = np.asarray(layer_l, dtype=np.float64), np.asarray(texel_l, dtype=np.float64)
    flat = lambda rows, dtype: np.concatenate(rows).astype(dtype) if rows else np.empty(0, dtype=dtype)  # noqa: E731
    own_memory, own_quads = np.asarray(memory_l, dtype=np.float64), np.asarray(quads_l, dtype=np.float64)
    return Candidates(
        node=np.asarray(node_l, dtype=np.int64),
        kind=np.asarray(kind_l, dtype=np.int64),
        cells=tuple(cell_l),
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
        served_offsets=np.concatenate([[0], np.cumsum([r.size for r in served_l])]).astype(np.int64),
        served=flat(served_l, np.int64),
        g=flat(g_l, np.float64),
        ti=flat(ti_l, np.float64),
        stats={"considered": considered, "refused_by_technique": refused, "refused_by_memory": too_large},
        source=np.asarray(source_l, dtype=np.int64),
        prototype=np.asarray(atlas_l, dtype=np.int64),
        prototypes=tuple(atlases),
        scale=np.asarray(scale_l, dtype=np.float64),
    )


def _moved(far, inst):
    """The outside estimate ``far`` of a prototype (in its local space) moved to instance ``inst``:
    its cell's centre moved by the matrix, its radius scaled by the matrix's uniform scale."""
    cell = far.cell
    return replace(
        far, cell=SphereOutsideCell(inst.world_point(cell.centre), cell.radius * inst.scale, cell.hemisphere)
    )

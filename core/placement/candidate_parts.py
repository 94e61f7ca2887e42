"""The candidate step of a placement (seed 000 §5.6) cut into parts other processes can compute.

A part is a contiguous range of hierarchy nodes (preorder): a node's candidates depend only on the
node and on the problem views (its shafts' and boxes' served regions span the whole view space,
and the dominance pruning compares the cells of one node), so each range is computed alone
(:func:`candidate_part`, a pure function of :class:`PartInputs` and the range) and the parts,
concatenated in node order (:func:`merge_candidates`), are the candidates of
:func:`~farfield.core.placement.candidates.generate_candidates` over every node: the same arrays,
cells, counts and shared atlases (numbered by first use, as one pass numbers them).  The greedy
(§5.7) then runs on the merged candidates in one process.

A placement job fans the parts out to the render workers
(:mod:`farfield.service.placement.candidate_fanout`); :func:`node_ranges` cuts the nodes.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from farfield.core.placement.candidates import CPV_INDEX, Candidates, generate_candidates
from farfield.core.placement.cell_table import CellTable
from farfield.core.placement.hierarchy import Hierarchy
from farfield.core.placement.part_inputs import PartInputs
from farfield.core.placement.view_space import ProblemViews


def node_ranges(inputs: PartInputs, parts: int) -> list[range]:
    """``parts`` (at most one per node) contiguous ranges of hierarchy nodes of about equal work:
    the cuts balance each node's (CPV, element) rows among the solvable CPVs, what a node's
    candidates cost grows with.

    >>> import math
    >>> from farfield.core import procedural
    >>> from farfield.core.placement.cost_model import primitive_model
    >>> from farfield.core.placement.hierarchy import Elements
    >>> from farfield.core.placement.planner import PlacementSettings
    >>> from farfield.core.placement.view_space import problem_view_space
    >>> scene = procedural.city(9, seed=0, detail=4)
    >>> e = Elements.of(scene); h = Hierarchy.build(e)
    >>> lo, hi = np.array([0.0, 1.0, 0.0]), np.array([40.0, 2.0, 40.0])
    >>> pv = problem_view_space(e, h, lo, hi, primitive_model(), 1.0, math.radians(45), 64, 20.0)
    >>> ranges = node_ranges(PartInputs(PlacementSettings(1.0, primitive_model()), h, pv, (), 64), 3)
    >>> len(ranges), ranges[0].start, ranges[-1].stop == h.count
    (3, 0, True)
    """
    count = inputs.hierarchy.count
    parts = max(1, min(int(parts), count))
    if parts == 1:
        return [range(count)]
    work = node_work(inputs.hierarchy, inputs.pv)
    cum = np.cumsum(work + 1.0)  # + 1: a node of no rows still costs a little
    cuts = np.searchsorted(cum, cum[-1] * np.arange(1, parts) / parts, side="right")
    edges = np.unique(np.concatenate([[0], np.clip(cuts, 1, count - 1), [count]]))
    return [range(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def node_work(hierarchy: Hierarchy, pv: ProblemViews) -> np.ndarray:
    """(nodes,) how many (CPV, element) rows of the solvable CPVs fall in each node's subtree."""
    solvable = ~pv.unsolvable
    rows = np.repeat(solvable, np.diff(pv.offsets))
    positions = np.sort(pv.positions[rows])
    return (np.searchsorted(positions, hierarchy.end) - np.searchsorted(positions, hierarchy.start)).astype(np.float64)


def candidate_part(inputs: PartInputs, nodes: range, progress: Callable[[int, int], None] | None = None) -> Candidates:
    """The candidates of hierarchy ``nodes`` (what :func:`~farfield.core.placement.planner.place`
    generates for them; pure: equal inputs give equal parts in any process)."""
    from farfield.core.placement.planner import candidate_techniques, part_options, technique_sources

    s = inputs.settings
    techniques = candidate_techniques(s)
    estimate, outside, _ = technique_sources(techniques)
    return generate_candidates(
        inputs.hierarchy, inputs.pv, s.model, estimate, float(inputs.resolution) ** 2, s.cells, s.apex_angles_deg, s.direction_step_deg,
        s.distance_steps, progress, s.max_impostor_bytes, outside, inputs.shared, part_options(techniques), nodes=nodes,
    )  # fmt: skip


def merge_candidates(parts: list[Candidates]) -> Candidates:
    """The parts of consecutive node ranges as one :class:`Candidates`, equal to one pass over all
    the nodes: columns and rows concatenated, served offsets shifted, counts summed, and shared
    atlases renumbered in order of first use."""
    if len(parts) == 1:
        return parts[0]
    atlases: dict = {}
    prototype = []
    for part in parts:
        local = np.array([atlases.setdefault(key, len(atlases)) for key in part.prototypes], dtype=np.int64)
        atlas = part.prototype
        prototype.append(np.where(atlas >= 0, local[np.maximum(atlas, 0)] if local.size else -1, -1))
    lengths = np.concatenate([np.diff(p.served_offsets) for p in parts])
    stats: dict = {}
    for part in parts:
        for key, value in part.stats.items():
            stats[key] = stats.get(key, 0) + value
    cat = lambda name, dtype: np.concatenate([getattr(p, name) for p in parts], dtype=dtype)  # noqa: E731
    return Candidates(
        node=cat("node", np.int64), kind=cat("kind", np.int64), cells=CellTable.concat([p.cells if isinstance(p.cells, CellTable) else CellTable.of(list(p.cells)) for p in parts]),
        memory=cat("memory", np.float64), layers=cat("layers", np.float64), texels=cat("texels", np.float64),
        quads=cat("quads", np.float64), served_offsets=np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64),
        served=cat("served", CPV_INDEX), g=cat("g", np.float64), ti=cat("ti", np.float64), stats=stats,
        source=cat("source", np.int64), prototype=np.concatenate(prototype).astype(np.int64), prototypes=tuple(atlases),
        scale=cat("scale", np.float64),
    )  # fmt: skip

"""Potentially visible sets of view-space regions (seed 000 §2.2.2, §5.5.1), sampled from points with id cube maps.

A region's PVS is the set of elements of the object hierarchy that some view from inside the region
may see.  It is computed by sampling: element-id cube maps (:mod:`farfield.core.visibility.id_cubes`)
from the points of a lattice over the view space, the PVS of a region being the union of what its
lattice points see, plus every element whose bounds lie within ``margin`` of the region.

**The lattice** follows the problem view space's regions (:func:`farfield.core.placement.view_space.problem_view_space`
halves the view space along its longest side down to the CPV size, so along each axis the smallest
regions are ``span / 2^m``): its step is the longest side of a smallest region / ``samples_per_side``,
rounded down per axis so that each region's side holds whole steps.  Every region's corners are
lattice points, and with 2 (the default) the centres of its long edges, faces and itself.  A parent
region is the union of its children, and so is its PVS: the planner's children test only elements
their parent kept.  Points are rendered on first use and kept.  ``levels`` > 0 refines a lattice
cell whose corners disagree at its midpoints (:class:`RegionVisibility`; off by default).

**Density from the output resolution.**  A cube face has ``face_resolution_for(resolution, fov,
texel_pixels)`` texels a side, so that one of its texels spans ``texel_pixels`` pixels of the output
frame (2 by default: 128 texels for 128 px at 45°); a feature that covers no texel centre of any
sample's cube map is lost, so a missing element covers little more than ``texel_pixels²`` output
pixels from the sampled points.

**Occluder erosion** (the default): each point's cube map is drawn with its occluders shrunk in
image space by ``erosion`` (default: half the diagonal of a lattice cell, so that every eye of the
view space is within it of a lattice point) and up to ``peels`` (default 4) layers drawn behind
them, each eroded in turn (:mod:`farfield.core.visibility.id_cubes`; seed 000 §2.2.2, [Wonk00]'s
occluder shrinking): a point then sees what any eye near it may see, so elements seen only through
gaps between the points, or past several occluders in a row, are kept.  ``erosion=0`` is plain
point sampling (the earlier default, refined with ``levels=1``).

**How conservative.**  Not strictly: the erosion is done on at most ``peels`` + 1 layers (see
:mod:`~farfield.core.visibility.id_cubes` for what it misses), and a feature that covers no texel
centre of any sample's cube map is lost.  Near the region, where parallax is largest, the ``margin``
(default: one lattice step) keeps every element regardless of the samples.  The false-invisible rate
is measured against a denser lattice of plain points (:func:`false_invisible`), and hole pixels on
walkthroughs, reported in docs/placement/visibility.md.  Conservative object-space methods (occluder
shadows, Wonka et al. 2000, the thesis's §5.8) only work for 2.5D scenes; this works for any
triangles.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from farfield.core.placement.hierarchy import Elements
from farfield.core.placement.view_space import box_gap
from farfield.core.scene import Scene
from farfield.core.visibility.id_cubes import IdCubeRenderer, VisibilityError, face_resolution_for

DEFAULT_SAMPLES_PER_SIDE = 2  # lattice steps per side of a smallest region: corners, edge/face centres, centre
DEFAULT_TEXEL_PIXELS = 2.0  # output pixels per cube-map texel (a side)
DEFAULT_LEVELS = 0  # adaptive refinements of a lattice cell whose corners disagree (eroded samples need none)
DEFAULT_PEELS = 4  # layers drawn behind an eroded point's first surfaces, each eroded in turn
DEFAULT_REFINE_TEXELS = 16  # texels an element seen by some corners only must cover to refine
MAX_POINTS = 200_000  # a guard against a lattice no machine renders in reasonable time
_TOL = 1e-9


def halvings(span: float, region_size: float) -> int:
    """How many times the problem view space halves an axis of ``span`` to reach ``region_size``
    (splits stop at ``region_size * (1 + 1e-9)``, as :func:`~farfield.core.placement.view_space.problem_view_space`'s).

    >>> halvings(100.0, 25.0), halvings(100.0, 30.0), halvings(10.0, 25.0), halvings(0.0, 1.0)
    (2, 2, 0, 0)
    """
    m = 0
    while span / 2**m > region_size * (1.0 + _TOL):
        m += 1
    return m


@dataclass(frozen=True, slots=True)
class SampleLattice:
    """Points ``lo + k * step(level)`` over the view space: level 0 has ``counts`` points per axis,
    each finer level halves the steps (``(counts - 1) * 2^level + 1`` points), up to ``levels``.
    Points are keyed by their flat index on the finest level, so a point of two levels is one."""

    lo: np.ndarray  # (3,)
    hi: np.ndarray  # (3,)
    counts: np.ndarray  # (3,) int64 points per axis on level 0
    levels: int = 0

    @classmethod
    def for_regions(cls, lo, hi, region_size: float, samples_per_side: int, levels: int = 0) -> SampleLattice:
        """The lattice of the problem view space's regions (see the module docstring): the step is
        the longest side of a smallest region / ``samples_per_side``, rounded down per axis so that
        every smallest region's side holds a whole number of steps.

        >>> SampleLattice.for_regions([0, 0, 0], [100, 10, 100], 25.0, 2).counts.tolist()
        [9, 2, 9]
        """
        lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
        if not (isinstance(samples_per_side, int) and 1 <= samples_per_side <= 64):
            raise VisibilityError(f"samples per region side must be an integer in 1..64, got {samples_per_side!r}")
        if not (isinstance(levels, int) and 0 <= levels <= 4):
            raise VisibilityError(f"refinement levels must be an integer in 0..4, got {levels!r}")
        if not (math.isfinite(region_size) and region_size > 0.0):
            raise VisibilityError(f"the region size must be > 0, got {region_size!r}")
        span = hi - lo
        splits = np.array([2 ** halvings(float(s), region_size) for s in span], dtype=np.float64)
        leaf = span / splits
        step = float(np.max(leaf)) / samples_per_side
        per_leaf = np.ceil(leaf / step * (1.0 - _TOL)) if step > 0 else np.zeros(3)
        counts = np.where(span > 0.0, splits * np.maximum(per_leaf, 1.0) + 1.0, 1.0).astype(np.int64)
        finest = np.where(counts > 1, (counts - 1) * 2**levels + 1, 1)
        if float(np.prod(counts.astype(np.float64))) > MAX_POINTS or float(np.prod(finest.astype(np.float64))) > 2**62:
            raise VisibilityError(
                f"a visibility lattice of {counts.tolist()} points is over {MAX_POINTS:,}; use a larger CPV size or fewer samples"
            )
        return cls(lo, hi, counts, levels)

    def counts_at(self, level: int) -> np.ndarray:
        return np.where(self.counts > 1, (self.counts - 1) * 2**level + 1, 1)

    def step_at(self, level: int) -> np.ndarray:
        """(3,) distance between neighbouring points per axis on ``level`` (0 along a flat axis)."""
        n = self.counts_at(level)
        return np.where(n > 1, (self.hi - self.lo) / np.maximum(n - 1, 1), 0.0)

    @property
    def step(self) -> np.ndarray:
        return self.step_at(0)

    @property
    def count(self) -> int:
        return int(np.prod(self.counts))

    def points(self, ijk: np.ndarray, level: int = 0) -> np.ndarray:
        """(k, 3) positions of the points ``ijk`` (k, 3) of ``level``."""
        return self.lo + np.asarray(ijk, dtype=np.int64).reshape(-1, 3) * self.step_at(level)

    def keys(self, ijk: np.ndarray, level: int = 0) -> np.ndarray:
        """(k,) flat indices on the finest level of the points ``ijk`` (k, 3) of ``level``."""
        scale = np.where(self.counts > 1, 2 ** (self.levels - level), 0)
        return np.ravel_multi_index(
            tuple((np.asarray(ijk, dtype=np.int64).reshape(-1, 3) * scale).T), tuple(self.counts_at(self.levels))
        )

    def inside(self, r_lo, r_hi, level: int = 0) -> np.ndarray:
        """(k, 3) indices on ``level`` of the points in the closed box ``r_lo``..``r_hi``."""
        ranges = []
        counts, step = self.counts_at(level), self.step_at(level)
        for axis in range(3):
            n = int(counts[axis])
            if n == 1:
                ranges.append(np.zeros(1, dtype=np.int64))
                continue
            tol = _TOL * max(1.0, float(self.hi[axis] - self.lo[axis]))
            first = max(0, math.ceil((float(r_lo[axis]) - self.lo[axis] - tol) / float(step[axis])))
            last = min(n - 1, math.floor((float(r_hi[axis]) - self.lo[axis] + tol) / float(step[axis])))
            ranges.append(np.arange(first, last + 1, dtype=np.int64))
        grid = np.meshgrid(*ranges, indexing="ij")
        return np.column_stack([g.ravel() for g in grid]).reshape(-1, 3)


def _cells(ijk: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """(c, 3) lower corners of the lattice cells whose every corner is among the points ``ijk`` (a box of them)."""
    if ijk.size == 0:
        return ijk
    top = ijk.max(axis=0)
    keep = np.all((ijk < top) | (counts[None, :] == 1), axis=1)
    return ijk[keep]


class RegionVisibility:
    """The PVS of any region of the view space ``view_lo``..``view_hi`` (see the module docstring);
    called as ``visible(region_lo, region_hi, element_indices)`` it is the planner's visibility hook
    (:data:`farfield.core.placement.view_space.Visibility`): the given elements that are in the PVS.

    ``levels`` > 0 refines adaptively (after Nirenstein and Blake 2004): a lattice cell whose corners
    disagree (an element some corner sees and another does not covers more than ``refine_texels``
    texels of that corner's cube map) is sampled again at its level's midpoints, up to ``levels`` times."""

    def __init__(
        self,
        scene: Scene,
        elements: Elements,
        view_lo,
        view_hi,
        region_size: float,
        resolution: int,
        fov: float,
        samples_per_side: int = DEFAULT_SAMPLES_PER_SIDE,
        texel_pixels: float = DEFAULT_TEXEL_PIXELS,
        margin: float | None = None,
        levels: int = DEFAULT_LEVELS,
        refine_texels: int = DEFAULT_REFINE_TEXELS,
        renderer: IdCubeRenderer | None = None,
        erosion: float | None = None,
        peels: int = DEFAULT_PEELS,
    ) -> None:
        self.elements = elements
        self.lattice = SampleLattice.for_regions(view_lo, view_hi, region_size, samples_per_side, levels)
        # Every eye of a lattice cell is within half its diagonal of one of its corners.
        self.erosion = 0.5 * float(np.linalg.norm(self.lattice.step)) if erosion is None else float(erosion)
        self.margin = float(np.max(self.lattice.step)) if margin is None else float(margin)
        if not (math.isfinite(self.margin) and self.margin >= 0.0):
            raise VisibilityError(f"the margin must be >= 0, got {margin!r}")
        self.refine_texels = int(refine_texels)
        self.texel_pixels = float(texel_pixels)
        face = face_resolution_for(resolution, fov, texel_pixels)
        self.renderer = renderer if renderer is not None else IdCubeRenderer(scene, elements, face, self.erosion, peels)
        self._owns_renderer = renderer is None
        self._seen: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # finest key -> (ids, texels)
        self._split: dict[tuple[int, int], bool] = {}  # (level, key of the cell's low corner) -> refine
        self.seconds = 0.0
        self.queries = 0

    @property
    def points_rendered(self) -> int:
        return len(self._seen)

    def _render(self, ijk: np.ndarray, level: int) -> np.ndarray:
        """Keys of the points ``ijk`` of ``level``, rendering those not seen yet."""
        keys = self.lattice.keys(ijk, level)
        todo = np.array(sorted({int(k) for k in keys.tolist()} - self._seen.keys()), dtype=np.int64)
        if todo.size:
            started = time.perf_counter()
            finest = np.column_stack(np.unravel_index(todo, tuple(self.lattice.counts_at(self.lattice.levels))))
            sight = self.renderer.see(self.lattice.points(finest, self.lattice.levels))
            for k, key in enumerate(todo.tolist()):
                self._seen[key] = sight.of(k)
            self.seconds += time.perf_counter() - started
        return keys

    def render_lattice(self, progress: Callable[[int, int], None] | None = None) -> None:
        """Render every level-0 lattice point not seen yet (the points any query of the whole view
        space renders first), a renderer batch at a time, calling ``progress(done, total)`` after
        each: a planner reports it, and a cancelled job stops here, between batches, not minutes
        later when the whole lattice is done (the batches and the sets are those of one call)."""
        ijk = np.indices(tuple(self.lattice.counts)).reshape(3, -1).T
        total = ijk.shape[0]
        step = max(1, int(getattr(self.renderer, "batch", total)))
        if progress is not None:
            progress(0, total)
        for start in range(0, total, step):
            self._render(ijk[start : start + step], 0)
            if progress is not None:
                progress(min(start + step, total), total)

    def _disagree(self, keys: np.ndarray) -> bool:
        """Whether the corners ``keys`` of a cell disagree (see the class docstring)."""
        sets = [self._seen[int(k)] for k in keys.tolist()]
        common = sets[0][0]
        for ids, _ in sets[1:]:
            common = np.intersect1d(common, ids, assume_unique=True)
        return any(int(texels[~np.isin(ids, common)].max(initial=0)) > self.refine_texels for ids, texels in sets)

    def sampled(self, r_lo, r_hi) -> np.ndarray:
        """(e,) bool: the elements some lattice point of the region sees (without the margin)."""
        r_lo, r_hi = np.asarray(r_lo, dtype=np.float64), np.asarray(r_hi, dtype=np.float64)
        out = np.zeros(self.elements.count, dtype=bool)
        ijk = self.lattice.inside(r_lo, r_hi, 0)
        if ijk.size == 0:  # a region between lattice points (not one of the planner's): its centre
            started = time.perf_counter()
            sight = self.renderer.see((0.5 * (r_lo + r_hi))[None, :])
            self.seconds += time.perf_counter() - started
            out[sight.of(0)[0]] = True
            return out
        keys = self._render(ijk, 0)
        counts = self.lattice.counts
        flat = counts > 1
        corners = np.array([c for c in np.ndindex(2, 2, 2) if not np.any(np.array(c)[~flat])], dtype=np.int64)
        cells = _cells(ijk, counts)
        for level in range(self.lattice.levels):
            finer = []
            corner_ijk = cells[:, None, :] + corners[None, :, :]  # (c, k, 3)
            self._render(corner_ijk.reshape(-1, 3), level)
            for cell, c_ijk in zip(cells, corner_ijk):
                key = (level, int(self.lattice.keys(cell, level)[0]))
                if key not in self._split:
                    self._split[key] = self._disagree(self.lattice.keys(c_ijk, level))
                if self._split[key]:
                    finer.append(2 * cell[None, :] + corners)  # its sub-cells on the next level
            if not finer:
                break
            cells = np.concatenate(finer)
            sub = (cells[:, None, :] + corners[None, :, :]).reshape(-1, 3)
            keys = np.concatenate([keys, self._render(sub, level + 1)])
        for key in np.unique(keys).tolist():
            out[self._seen[key][0]] = True
        return out

    def near(self, r_lo, r_hi) -> np.ndarray:
        """(e,) bool: the elements within the margin of the region, kept whatever the samples see."""
        b = self.elements.bounds
        return (
            box_gap(b[:, 0], b[:, 1], np.asarray(r_lo, dtype=np.float64), np.asarray(r_hi, dtype=np.float64))
            <= self.margin
        )

    def pvs(self, r_lo, r_hi) -> np.ndarray:
        """Sorted element indices of the region's potentially visible set."""
        return np.flatnonzero(self.sampled(r_lo, r_hi) | self.near(r_lo, r_hi))

    def sights(self, r_lo, r_hi) -> list[tuple[np.ndarray, np.ndarray]]:
        """(ids, texels) of every level-0 point of the region (rendering them if needed)."""
        keys = self._render(self.lattice.inside(r_lo, r_hi, 0), 0)
        return [self._seen[int(k)] for k in keys.tolist()]

    def __call__(self, r_lo, r_hi, element_indices) -> np.ndarray:
        self.queries += 1
        cand = np.asarray(element_indices, dtype=np.int64)
        keep = self.sampled(r_lo, r_hi) | self.near(r_lo, r_hi)
        return cand[keep[cand]]

    def stats(self) -> dict:
        return {
            "lattice": self.lattice.counts.tolist(),
            "levels": self.lattice.levels,
            "points_rendered": self.points_rendered,
            "face_resolution": self.renderer.face,
            "margin": self.margin,
            "erosion": self.renderer.erosion,
            "peels": self.renderer.peels,
            "queries": self.queries,
            "seconds": self.seconds,
        }

    def release(self) -> None:
        if self._owns_renderer:
            self.renderer.release()


def false_invisible(sparse: RegionVisibility, dense: RegionVisibility, regions) -> dict:
    """How often ``sparse`` (the PVS as the planner uses it) misses an element that ``dense`` (the
    same view space sampled more densely; the same margin) sees, over ``regions`` (a list of
    ``(lo, hi)`` boxes): per region the elements in the dense PVS missing from the sparse one, and
    the cube-map texels they cover in the dense points' cube maps (each point's sum; the largest).

    Returns totals: ``regions``, ``dense_pvs`` (mean size), ``sparse_pvs`` (mean size), ``missing``
    (elements summed over regions), ``missing_share`` (of the dense PVS entries), ``regions_missing``
    (regions with any), ``max_missing_texels`` (the most texels missing elements cover in one
    dense point's cube map) and ``max_missing_pixels`` (the same in output pixels: texels x
    ``texel_pixels²``, the nominal ratio at the frame's centre).
    """
    missing = dense_total = sparse_total = regions_missing = 0
    worst = 0
    for r_lo, r_hi in regions:
        d, s = dense.pvs(r_lo, r_hi), sparse.pvs(r_lo, r_hi)
        lost = np.setdiff1d(d, s, assume_unique=True)
        dense_total += d.size
        sparse_total += s.size
        missing += lost.size
        if lost.size:
            regions_missing += 1
            for ids, texels in dense.sights(r_lo, r_hi):
                worst = max(worst, int(texels[np.isin(ids, lost)].sum()))
    n = max(1, len(regions))
    return {
        "regions": len(regions),
        "dense_pvs": dense_total / n,
        "sparse_pvs": sparse_total / n,
        "missing": missing,
        "missing_share": missing / max(1, dense_total),
        "regions_missing": regions_missing,
        "max_missing_texels": worst,
        "max_missing_pixels": worst * dense.texel_pixels**2,
    }

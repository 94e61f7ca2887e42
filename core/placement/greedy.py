"""The greedy choice of impostors with lazy re-ranking (seed 000 §5.7).

For a candidate ``i`` (node ``n``, view cell, memory ``m_i``) and a CPV ``p`` it serves
(Eqs. 5.4-5.6)::

    dt_p(i) = max(0, t_p - max(t_p^i, t_max)),  t_p^i = t_p - (t_o - t_i)
    score(i) = sum_p dt_p(i) / m_i

where ``t_p`` is the CPV's current time, ``t_o`` the time of what currently represents the node's
part in ``p`` and ``t_i`` the impostor's time in ``p`` (``e * pixels + f * quads + g``, pixels
those of the node's elements in the CPV's frustum).  Overlapping clusters (§5.7.5) follow from
treating chosen impostors as the objects they represent: where an ancestor's impostor (or the
node's own) is already drawn, ``i`` gains nothing; where descendants' impostors are drawn,
``t_o`` is the node's geometry less what they already saved, and choosing ``i`` removes them from
``p``.  An impostor left in no CPV is deleted and its memory regained.

The best candidate is chosen and assigned to every CPV it accelerates (as the thesis does, §5.8.2:
a CPV already solved is drawn faster still, at no memory); each CPV's time falls by the whole
saving ``t_o - t_i`` there (what drawing the impostor changes), not by the clipped gain of
Eq. 5.4, which only ranks.  Unsolvable CPVs (what meets their region exceeds ``t_max`` alone) take
no part: no impostor is assigned to them, and none gains there.  The scores
of the candidates serving them fall too: no score ever increases (§5.7.4), so a heap of stale
scores is re-ranked lazily: the top is re-scored and chosen if it is still on top, else pushed
back.  Ties go to the smaller candidate index.  ``lazy=False`` re-scores every candidate at every
step (the reference the lazy form must equal; tested).

**Shared atlases** (issue 56): candidates of instances of one prototype draw from one atlas
(``Candidates.prototype``).  The first of them chosen pays the atlas's memory; while an impostor
of that atlas is drawn, every other candidate of it costs 0 bytes, so its score is infinite
(ranked among such free candidates by its saving).  That is the one way a score rises: when a
choice pays an atlas, its other candidates are pushed on the heap again with their new scores
(their old entries, popped later, are re-scored and found stale).
"""

from __future__ import annotations

import heapq
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from farfield.core.placement.candidates import Candidates
from farfield.core.placement.hierarchy import Hierarchy
from farfield.core.placement.view_space import ProblemViews


@dataclass(slots=True)
class Chosen:
    """One impostor of the result: its candidate, its CPVs, and its time in each."""

    candidate: int
    node: int
    cpvs: dict  # cpv -> (geometry time of the node there, impostor time there)
    order: int  # when it was chosen


class Greedy:
    """The optimisation state: CPV times, the impostors drawn in each CPV, the chosen impostors."""

    def __init__(self, hierarchy: Hierarchy, pv: ProblemViews, cand: Candidates, t_max: float) -> None:
        self.h, self.pv, self.cand, self.t_max = hierarchy, pv, cand, float(t_max)
        self.size = hierarchy.size
        self.g, self.ti = cand.g, cand.ti  # flat, aligned with cand.served
        self.nodes = np.int64(hierarchy.count)
        self._keys = np.empty(0, dtype=np.int64)
        self._saved = np.empty(0, dtype=np.float64)
        self._cum: np.ndarray | None = None
        self.t = pv.time.copy()
        self.t[pv.unsolvable] = -np.inf  # unsolvable CPVs are left alone: no impostor gains there
        self.drawn: list[list[int]] = [[] for _ in range(pv.count)]  # per CPV: chosen impostor ids
        self.chosen: list[Chosen] = []
        self.deleted: set[int] = set()
        self.rescored = 0
        atlas = getattr(cand, "prototype", None)
        self.atlas = np.full(cand.count, -1, dtype=np.int64) if atlas is None else atlas
        self.atlas_users: dict[int, list[int]] = {}  # shared atlas -> chosen impostor ids drawing from it

    def paid(self, atlas: int) -> bool:
        """Whether an impostor drawing from shared ``atlas`` is drawn: its memory is counted."""
        return atlas >= 0 and any(o not in self.deleted for o in self.atlas_users.get(atlas, ()))

    def memory_now(self) -> np.ndarray:
        """(m,) every candidate's memory now: 0 for one whose shared atlas is paid."""
        memory = self.cand.memory.astype(np.float64, copy=True)
        for atlas in self.atlas_users:
            if self.paid(atlas):
                memory[self.atlas == atlas] = 0.0
        return memory

    def _drawn_index(self) -> tuple[np.ndarray, np.ndarray]:
        """Sorted keys ``cpv * nodes + node`` of every drawn impostor and the running sum of what
        each saves there (``g - t``), kept up to date by :meth:`choose` in time linear in the keys
        (numpy), not in Python.  In one CPV the drawn nodes never include an ancestor of another
        (choosing an ancestor removes its descendants, §5.7.5)."""
        if self._cum is None:
            self._cum = np.concatenate([[0.0], np.cumsum(self._saved)])
        return self._keys, self._cum

    def _gains(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(cpvs, saving, gain) of candidate ``i`` now; saving is -inf where an ancestor's impostor
        (or the node's own) is drawn, and the gain is 0 where it saves nothing."""
        a, b = self.cand.served_offsets[i], self.cand.served_offsets[i + 1]
        cpvs = self.cand.served[a:b]
        geometry = self.g[a:b]
        node = int(self.cand.node[i])
        if self.chosen:
            keys, cum = self._drawn_index()
            base = cpvs * self.nodes
            # descendants drawn here: what they already save is no longer the node's to save
            lo = np.searchsorted(keys, base + node + 1)
            hi = np.searchsorted(keys, base + node + int(self.size[node]))
            geometry = geometry - (cum[hi] - cum[lo])
            # the nearest drawn node at or before this one in preorder: an ancestor (or itself) if its subtree holds it
            at = np.searchsorted(keys, base + node, side="right") - 1
            found = keys[np.maximum(at, 0)]
            other = found - base
            blocked = (
                (at >= 0)
                & (other >= 0)
                & (other <= node)
                & (other + self.size[np.clip(other, 0, self.nodes - 1)] > node)
            )
            geometry = np.where(blocked, -np.inf, geometry)
        saving = geometry - self.ti[a:b]
        gain = np.maximum(0.0, np.minimum(saving, self.t[cpvs] - self.t_max))
        return cpvs, saving, gain

    def rank(self, i: int) -> tuple[float, float]:
        """(score, tie-break) of candidate ``i`` now: gain per byte and 0, or, for a candidate whose
        shared atlas is paid (0 bytes), infinity and its gain; (0, 0) where it gains nothing."""
        self.rescored += 1
        gain = float(self._gains(i)[2].sum())
        if gain <= 0.0:
            return 0.0, 0.0
        if self.paid(int(self.atlas[i])):
            return np.inf, gain
        return gain / float(self.cand.memory[i]), 0.0

    def score(self, i: int) -> float:
        return self.rank(i)[0]

    def initial_ranks(self) -> tuple[np.ndarray, np.ndarray]:
        """Every candidate's :meth:`rank` (vectorised; with what is chosen so far only as far as
        scores go: they are upper bounds, the lazy heap re-scores)."""
        gain = np.maximum(0.0, np.minimum(self.g - self.ti, self.t[self.cand.served] - self.t_max))
        owner = np.repeat(np.arange(self.cand.count), np.diff(self.cand.served_offsets))
        total = np.bincount(owner, weights=gain, minlength=self.cand.count)
        memory = self.memory_now()
        free = (memory <= 0.0) & (total > 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            score = np.where(free, np.inf, total / np.where(memory > 0.0, memory, 1.0))
        return score, np.where(free, total, 0.0)

    def initial_scores(self) -> np.ndarray:
        """Every candidate's score with nothing chosen (vectorised)."""
        return self.initial_ranks()[0]

    def choose(self, i: int) -> int:
        """Choose candidate ``i``; returns the shared atlas this choice pays (its other candidates'
        memory falls to 0), else -1."""
        cpvs, saving, _ = self._gains(i)
        atlas = int(self.atlas[i])
        pays = atlas >= 0 and not self.paid(atlas)
        a = self.cand.served_offsets[i]
        node, me = int(self.cand.node[i]), len(self.chosen)
        imp = Chosen(i, node, {}, me)
        self.chosen.append(imp)
        if atlas >= 0:
            self.atlas_users.setdefault(atlas, []).append(me)
        removed, added, added_saved = [], [], []
        for k in np.flatnonzero(saving > 0.0):
            p = int(cpvs[k])
            kept = []
            for other_id in self.drawn[p]:
                other = self.chosen[other_id]
                if node < other.node < node + self.size[node]:  # replaced by this impostor here
                    del other.cpvs[p]
                    removed.append(p * self.nodes + other.node)
                    if not other.cpvs:
                        self.deleted.add(other_id)
                else:
                    kept.append(other_id)
            kept.append(me)
            self.drawn[p] = kept
            g_p, t_p = float(self.g[a + k]), float(self.ti[a + k])
            imp.cpvs[p] = (g_p, t_p)
            added.append(p * self.nodes + node)
            added_saved.append(g_p - t_p)
            self.t[p] -= float(saving[k])
        if removed:
            keep = ~np.isin(self._keys, np.asarray(removed, dtype=np.int64))
            self._keys, self._saved = self._keys[keep], self._saved[keep]
        if added:
            new = np.asarray(added, dtype=np.int64)  # ascending: cpvs are
            at = np.searchsorted(self._keys, new)
            self._keys = np.insert(self._keys, at, new)
            self._saved = np.insert(self._saved, at, np.asarray(added_saved, dtype=np.float64))
        self._cum = None
        return atlas if pays else -1

    def run(self, lazy: bool = True, progress: Callable[[int, float], None] | None = None) -> None:
        scores, ties = self.initial_ranks()
        if not lazy:
            ranks = {int(j): (scores[j], ties[j]) for j in np.flatnonzero(scores > 0.0)}
            while ranks:
                best = max(ranks, key=lambda j: (*ranks[j], -j))
                self.choose(best)
                del ranks[best]
                ranks = {j: r for j in ranks if (r := self.rank(j))[0] > 0.0}
            return
        heap = [(-float(s), -float(t), int(j)) for j, (s, t) in enumerate(zip(scores, ties)) if s > 0.0]
        heapq.heapify(heap)
        while heap:
            _, _, j = heapq.heappop(heap)
            s, t = self.rank(j)
            if s <= 0.0:
                continue  # every CPV it serves is solved, or taken by an ancestor (§5.7.4)
            if heap and (-s, -t, j) > heap[0]:
                heapq.heappush(heap, (-s, -t, j))
                continue
            paid = self.choose(j)
            if paid >= 0:  # its other candidates cost nothing now: their scores rose
                for k in np.flatnonzero(self.atlas == paid):
                    if k != j:
                        s, t = self.rank(int(k))
                        if s > 0.0:
                            heapq.heappush(heap, (-s, -t, int(k)))
            if progress is not None:
                progress(len(self.chosen), float(np.max(self.t, initial=-np.inf)))

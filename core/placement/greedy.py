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
step, summing each one's row gains with numpy (the reference the lazy form must equal; tested).

**In numba** (issue 57 item 5): the heap is three flat arrays (score, tie-break, item), and the
loop that pops, re-scores and pushes back until the top is still on top runs in one kernel
(:func:`_settle`) over the candidates' CSR rows; only a choice, and an item whose rank depends on
which shared atlases are paid (a group, a candidate of a shared atlas), come back to Python.  A
row of a CPV already within ``t_max`` gains nothing and is not looked up; the others search the
drawn (CPV, node) keys of their own CPV only.  Every gain is the same floating-point number as
numpy's (the row gains summed pairwise as ``ndarray.sum``), and the heap orders entries as
Python's heapq orders the same tuples, so the choices, their order and ``rescored`` are unchanged.
On a 265,070-triangle city (164,001 candidates, 38 M rows) the greedy took 35.2 CPU seconds in
Python and takes 2.8 (docs/measurements/placement.md, "Planning time").

**Shared atlases** (issue 56): candidates of instances of one prototype draw from one atlas
(``Candidates.prototype``).  The first of them chosen pays the atlas's memory; while an impostor
of that atlas is drawn, every other candidate of it costs 0 bytes, so its score is infinite
(ranked among such free candidates by its saving).  While no impostor of an atlas is drawn, its
candidates are ranked **as a group**, not one by one (one by one, the first instance would pay the
whole atlas for its own saving, and an atlas no single instance justifies would never be taken,
however many instances would share it): the group's gain is, per CPV its candidates serve, their
savings there summed and clipped at ``t_p - t_max`` (Eq. 5.4 for the set), over the atlas's bytes
(the members' memory: an octahedral candidate's memory is its atlas, its card adds no texture).
Its gain only falls while the atlas is unpaid (each member's saving and every ``t_p`` do), so the
group sits on the lazy heap like a candidate.  When the group is on top, its member of the largest
gain is chosen: that pays the atlas, and its other candidates, now free, are pushed on the heap
again with their new scores and taken next wherever they still gain (their old entries, popped
later, are re-scored and found stale).  A group's gain is at least any member's, and a member of
an unpaid atlas is ranked only through its group (its own rank is 0).  Should every impostor of a
paid atlas be deleted (replaced everywhere by ancestors'), the atlas is unpaid again and its group
goes back on the heap.  The stopping rule is the thesis's: the greedy ends when no candidate gains
anything, so a CPV stays unsolved only where no candidate left can lower it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numba
import numpy as np

from farfield.core.placement.candidates import Candidates
from farfield.core.placement.hierarchy import Hierarchy
from farfield.core.placement.view_space import ProblemViews


@numba.njit(cache=True, nogil=True)
def _block_sum(a: np.ndarray, lo: int, n: int) -> float:
    """numpy's sum of ``a[lo:lo + n]`` for ``n <= 128``: eight accumulators, then the rest in order."""
    if n < 8:
        res = 0.0
        for i in range(n):
            res += a[lo + i]
        return res
    r0, r1, r2, r3 = a[lo], a[lo + 1], a[lo + 2], a[lo + 3]
    r4, r5, r6, r7 = a[lo + 4], a[lo + 5], a[lo + 6], a[lo + 7]
    i = 8
    while i < n - (n % 8):
        r0 += a[lo + i]
        r1 += a[lo + i + 1]
        r2 += a[lo + i + 2]
        r3 += a[lo + i + 3]
        r4 += a[lo + i + 4]
        r5 += a[lo + i + 5]
        r6 += a[lo + i + 6]
        r7 += a[lo + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += a[lo + i]
        i += 1
    return res


@numba.njit(cache=True, nogil=True)
def _pairwise_sum(a: np.ndarray) -> float:
    """``a.sum()`` as numpy sums a contiguous float64 array (pairwise: halves cut at multiples of 8
    down to blocks of 128, :func:`_block_sum`), to the bit; without recursion."""
    n = a.size
    if n <= 128:
        return _block_sum(a, 0, n)
    todo_lo, todo_n, todo_join = np.empty(256, np.int64), np.empty(256, np.int64), np.empty(256, np.bool_)
    sums = np.empty(128)
    top, done = 0, 0
    todo_lo[0], todo_n[0], todo_join[0] = 0, n, False
    top = 1
    while top > 0:
        top -= 1
        lo, m, join = todo_lo[top], todo_n[top], todo_join[top]
        if join:  # both halves summed: left + right
            done -= 1
            sums[done - 1] = sums[done - 1] + sums[done]
        elif m <= 128:
            sums[done] = _block_sum(a, lo, m)
            done += 1
        else:
            half = m // 2
            half -= half % 8
            todo_lo[top], todo_n[top], todo_join[top] = lo, m, True
            todo_lo[top + 1], todo_n[top + 1], todo_join[top + 1] = lo + half, m - half, False
            todo_lo[top + 2], todo_n[top + 2], todo_join[top + 2] = lo, half, False
            top += 3
    return sums[0]


@numba.njit(cache=True, nogil=True)
def _search(keys: np.ndarray, lo: int, hi: int, value: int, right: bool) -> int:
    """``lo + np.searchsorted(keys[lo:hi], value, side)`` (``keys`` ascending)."""
    while lo < hi:
        mid = (lo + hi) >> 1
        if keys[mid] < value or (right and keys[mid] == value):
            lo = mid + 1
        else:
            hi = mid
    return lo


@numba.njit(cache=True, nogil=True)
def _gain_total(served, g, ti, a, b, node, keys, cum, starts, size, nodes, t, t_max, chosen, own=0) -> float:
    """``Greedy._gains(i)[2].sum()`` of the candidate whose rows are ``a:b``, in one pass and the
    same floating-point operations (the lazy heap's re-scoring, most of the greedy's time).

    A row whose CPV is solved (``t_p <= t_max``) gains 0 whatever its saving, so its drawn
    impostors are not looked up; the others are looked up among the keys of their CPV alone
    (``starts``: where each CPV's keys begin in ``keys``), the sums taken from the one running sum
    ``cum`` as :meth:`Greedy._drawn_less` takes them, so every row's gain is the same number."""
    gain = np.empty(b - a)
    for r in range(a, b):
        cpv = served[r]
        over = t[cpv] - t_max
        if not over > 0.0:
            gain[r - a] = 0.0  # min(saving, over) <= 0: nothing to gain here
            continue
        geometry = g[r]
        if chosen:
            w0, w1 = starts[cpv], starts[cpv + 1]
            if w1 > w0:  # impostors are drawn in this CPV
                base = cpv * nodes
                lo = _search(keys, w0, w1, base + node + 1 - own, False)
                hi = _search(keys, w0, w1, base + node + size[node], False)
                geometry = geometry - (cum[hi] - cum[lo])
                at = _search(keys, w0, w1, base + node - own, True) - 1
                if at >= w0:
                    other = keys[at] - base
                    if other <= node - own and other + size[other] > node:
                        geometry = -np.inf
        saving = geometry - ti[r]
        low = saving if saving < over else over
        gain[r - a] = low if low > 0.0 else 0.0
    return _pairwise_sum(gain)


@numba.njit(cache=True, nogil=True)
def _initial_gains(served, g, ti, offsets, t, t_max) -> np.ndarray:
    """Each candidate's gain with nothing chosen: ``np.bincount(owner, weights=gain)`` of the rows'
    ``max(0, min(g - ti, t_p - t_max))``, summed in row order as bincount does (the same numbers)."""
    m = offsets.size - 1
    total = np.zeros(m)
    for i in range(m):
        acc = 0.0
        for r in range(offsets[i], offsets[i + 1]):
            saving = g[r] - ti[r]
            over = t[served[r]] - t_max
            low = saving if saving < over else over
            acc += low if low > 0.0 else 0.0
        total[i] = acc
    return total


# The lazy heap: entries (-score, -tie-break, item) in three arrays, a binary min-heap on the tuple
# order (Python's heapq on the same tuples pops the same sequence: the order is total, and equal
# entries are the same entry).


@numba.njit(cache=True, nogil=True)
def _before(hs, ht, hx, i, j) -> bool:
    """Entry ``i`` orders before entry ``j`` (tuple order)."""
    if hs[i] != hs[j]:
        return hs[i] < hs[j]
    if ht[i] != ht[j]:
        return ht[i] < ht[j]
    return hx[i] < hx[j]


@numba.njit(cache=True, nogil=True)
def _swap(hs, ht, hx, i, j) -> None:
    hs[i], hs[j] = hs[j], hs[i]
    ht[i], ht[j] = ht[j], ht[i]
    hx[i], hx[j] = hx[j], hx[i]


@numba.njit(cache=True, nogil=True)
def _sift_down(hs, ht, hx, n, i) -> None:
    while True:
        c = 2 * i + 1
        if c >= n:
            return
        if c + 1 < n and _before(hs, ht, hx, c + 1, c):
            c += 1
        if not _before(hs, ht, hx, c, i):
            return
        _swap(hs, ht, hx, c, i)
        i = c


@numba.njit(cache=True, nogil=True)
def _heap_push(hs, ht, hx, n, s, t, x) -> int:
    """Push (s, t, x) on the heap of ``n`` entries (room for one more); returns the new size."""
    hs[n], ht[n], hx[n] = s, t, x
    i = n
    while i > 0:
        parent = (i - 1) >> 1
        if not _before(hs, ht, hx, i, parent):
            break
        _swap(hs, ht, hx, i, parent)
        i = parent
    return n + 1


@numba.njit(cache=True, nogil=True)
def _heap_pop(hs, ht, hx, n):
    """Pop the first of ``n`` entries: (s, t, x, new size)."""
    s, t, x = hs[0], ht[0], hx[0]
    n -= 1
    if n > 0:
        hs[0], ht[0], hx[0] = hs[n], ht[n], hx[n]
        _sift_down(hs, ht, hx, n, 0)
    return s, t, x, n


@numba.njit(cache=True, nogil=True)
def _heapify(hs, ht, hx, n) -> None:
    for i in range(n // 2 - 1, -1, -1):
        _sift_down(hs, ht, hx, n, i)


@numba.njit(cache=True, nogil=True)
def _settle(hs, ht, hx, n, served, g, ti, offsets, node_of, memory, atlas, keys, cum, starts, size, nodes, t, t_max,
            chosen, own):  # fmt: skip
    """The lazy heap's loop up to its next decision: pop the top and re-score it; a candidate that
    gains nothing is dropped, one no longer on top pushed back, one still on top returned to be
    chosen.  A heap item numba does not rank (a group, or a candidate of a shared atlas: their rank
    depends on which atlases are paid, :meth:`Greedy.rank_item`) is returned unranked.

    Returns (status, item, size, re-scorings): status 0 the heap is empty, 1 ``item`` is to be
    chosen, 2 ``item`` was popped unranked."""
    m = offsets.size - 1
    rescored = 0
    while n > 0:
        _, _, x, n = _heap_pop(hs, ht, hx, n)
        if x >= m or atlas[x] >= 0:
            return 2, x, n, rescored
        rescored += 1
        a, b = offsets[x], offsets[x + 1]
        gain = _gain_total(served, g, ti, a, b, node_of[x], keys, cum, starts, size, nodes, t, t_max, chosen, own)
        if gain <= 0.0:
            continue  # every CPV it serves is solved, or taken by an ancestor (§5.7.4)
        s = -(gain / memory[x])
        if n > 0:  # still on top? ((-score, -0.0, x) > heap[0], as tuples compare)
            if s != hs[0]:
                later = s > hs[0]
            elif 0.0 != ht[0]:
                later = 0.0 > ht[0]
            else:
                later = x > hx[0]
            if later:
                n = _heap_push(hs, ht, hx, n, s, -0.0, x)
                continue
        return 1, x, n, rescored
    return 0, -1, n, rescored


@dataclass(slots=True)
class Chosen:
    """One impostor of the result: its candidate, its CPVs, and its time in each."""

    candidate: int
    node: int
    cpvs: dict  # cpv -> (geometry time of the node there, impostor time there)
    order: int  # when it was chosen


class Greedy:
    """The optimisation state: CPV times, the impostors drawn in each CPV, the chosen impostors."""

    # Defaults for a state pickled before groups (PlannerState.loads): grouped, nothing pending.
    groups: bool = True
    unpaid_again: tuple[int, ...] = ()
    # 1: a candidate may replace the node's own drawn impostor in a CPV where it is faster (its
    # saving counted from the drawn one's time, as from descendants'), as simplified geometry needs
    # (farfield.core.placement.lod); 0: the node's own drawn impostor blocks it, as an ancestor's does.
    own: int = 0

    def __init__(
        self, hierarchy: Hierarchy, pv: ProblemViews, cand: Candidates, t_max: float, groups: bool = True
    ) -> None:
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
        self.groups = groups  # False: an unpaid atlas's candidates ranked one by one, each paying it (myopic)
        self.unpaid_again = ()  # shared atlases whose last drawn impostor :meth:`choose` deleted

    def members(self, atlas: int) -> np.ndarray:
        """The candidates drawing from shared ``atlas`` (ascending; found once)."""
        cache = self.__dict__.setdefault("_members", {})
        if atlas not in cache:
            cache[atlas] = np.flatnonzero(self.atlas == atlas)
        return cache[atlas]

    def atlases(self) -> np.ndarray:
        """Every shared atlas some candidate draws from."""
        return np.unique(self.atlas[self.atlas >= 0])

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

    def memory_bytes(self) -> float:
        """The memory of the impostors drawn now: each one's own, each shared atlas once."""
        drawn = [c.candidate for k, c in enumerate(self.chosen) if k not in self.deleted]
        own = sum(float(self.cand.memory[i]) for i in drawn if self.atlas[i] < 0)
        atlases = {int(self.atlas[i]) for i in drawn if self.atlas[i] >= 0}
        return own + sum(float(self.cand.memory[self.members(a)].max()) for a in atlases)

    def _drawn_index(self) -> tuple[np.ndarray, np.ndarray]:
        """Sorted keys ``cpv * nodes + node`` of every drawn impostor and the running sum of what
        each saves there (``g - t``), kept up to date by :meth:`choose` in time linear in the keys
        (numpy), not in Python.  In one CPV the drawn nodes never include an ancestor of another
        (choosing an ancestor removes its descendants, §5.7.5)."""
        if self._cum is None or self.__dict__.get("_starts") is None:
            self._cum = np.concatenate([[0.0], np.cumsum(self._saved)])
            # where each CPV's keys begin (and the last one's end): the re-scoring searches there alone
            self._starts = np.searchsorted(self._keys, np.arange(self.pv.count + 1, dtype=np.int64) * self.nodes)
        return self._keys, self._cum

    def _kernel_index(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(keys, running sum, per-CPV starts) of :meth:`_drawn_index` for :func:`_gain_total`."""
        if not self.chosen:
            return self._keys, self._saved, np.zeros(1, dtype=np.int64)  # not read: nothing chosen
        keys, cum = self._drawn_index()
        return keys, cum, self._starts

    def _key_owners(self) -> dict[int, int]:
        """Key ``cpv * nodes + node`` of :meth:`_drawn_index` -> the chosen impostor drawn there
        (entries for keys no longer drawn may linger: only keys found in ``_keys`` are looked up)."""
        owners = self.__dict__.get("_owners")
        if owners is None:  # a state pickled before it: from what is drawn
            owners = {p * int(self.nodes) + self.chosen[o].node: o for p, ids in enumerate(self.drawn) for o in ids}
            self._owners = owners
        return owners

    def _gains(self, i: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(cpvs, saving, gain) of candidate ``i`` now; saving is -inf where an ancestor's impostor
        (or the node's own) is drawn, and the gain is 0 where it saves nothing."""
        # _gains_of for one candidate, on slices (the lazy heap re-scores one at a time: most of the greedy)
        a, b = int(self.cand.served_offsets[i]), int(self.cand.served_offsets[i + 1])
        cpvs, geometry, node = self.cand.served[a:b], self.g[a:b], int(self.cand.node[i])
        if self.chosen:
            geometry = self._drawn_less(cpvs, geometry, node)
        saving = geometry - self.ti[a:b]
        return cpvs, saving, np.maximum(0.0, np.minimum(saving, self.t[cpvs] - self.t_max))

    def _drawn_less(self, cpvs: np.ndarray, geometry: np.ndarray, node) -> np.ndarray:
        """``geometry`` of ``node`` (a number, or one per row) in ``cpvs`` less what its drawn
        descendants save there, -inf where an ancestor's impostor (or its own) is drawn."""
        keys, cum = self._drawn_index()
        base = cpvs * self.nodes
        # descendants drawn here: what they already save is no longer the node's to save
        lo = np.searchsorted(keys, base + node + 1 - self.own)
        hi = np.searchsorted(keys, base + node + self.size[node])
        geometry = geometry - (cum[hi] - cum[lo])
        # the nearest drawn node at or before this one in preorder: an ancestor (or itself) if its subtree holds it
        at = np.searchsorted(keys, base + node - self.own, side="right") - 1
        found = keys[np.maximum(at, 0)]
        other = found - base
        blocked = (
            (at >= 0)
            & (other >= 0)
            & (other <= node - self.own)
            & (other + self.size[np.clip(other, 0, self.nodes - 1)] > node)
        )
        return np.where(blocked, -np.inf, geometry)

    def _gains_of(self, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(owner, cpvs, saving, gain) of the candidates ``idx`` now, one row per CPV each serves,
        ``owner`` the row's position in ``idx`` (:meth:`_gains`, for several candidates at once)."""
        a, b = self.cand.served_offsets[idx], self.cand.served_offsets[idx + 1]
        lengths = b - a
        owner = np.repeat(np.arange(idx.size), lengths)
        flat = np.arange(int(lengths.sum()), dtype=np.int64) - np.repeat(np.cumsum(lengths) - lengths, lengths)
        flat += np.repeat(a, lengths)
        cpvs = self.cand.served[flat]
        geometry = self.g[flat]
        node = np.repeat(self.cand.node[idx], lengths)
        if self.chosen:
            geometry = self._drawn_less(cpvs, geometry, node)
        saving = geometry - self.ti[flat]
        gain = np.maximum(0.0, np.minimum(saving, self.t[cpvs] - self.t_max))
        return owner, cpvs, saving, gain

    def rank(self, i: int, reference: bool = False) -> tuple[float, float]:
        """(score, tie-break) of candidate ``i`` now: gain per byte and 0, or, for a candidate whose
        shared atlas is paid (0 bytes), infinity and its gain; (0, 0) where it gains nothing, and
        for a candidate of an unpaid shared atlas (its group ranks it: :meth:`group_rank`).
        ``reference``: the gain summed by numpy over :meth:`_gains` instead of the kernel."""
        self.rescored += 1
        atlas = int(self.atlas[i])
        paid = self.paid(atlas)
        if atlas >= 0 and not paid and self.groups:
            return 0.0, 0.0
        if reference:  # numpy over the candidate's rows (the straightforward form the kernel must equal)
            gain = float(self._gains(i)[2].sum())
        else:
            keys, cum, starts = self._kernel_index()
            a, b = int(self.cand.served_offsets[i]), int(self.cand.served_offsets[i + 1])
            gain = _gain_total(self.cand.served, self.g, self.ti, a, b, int(self.cand.node[i]), keys, cum, starts,
                               self.size, int(self.nodes), self.t, self.t_max, bool(self.chosen), self.own)  # fmt: skip
        if gain <= 0.0:
            return 0.0, 0.0
        if paid:
            return np.inf, gain
        return gain / float(self.cand.memory[i]), 0.0

    def group_gain(self, atlas: int) -> tuple[np.ndarray, float]:
        """(members, gain) of unpaid shared ``atlas``: per CPV its members serve, their savings
        there summed and clipped at ``t_p - t_max``, summed over the CPVs (module docstring)."""
        members = self.members(atlas)
        _, cpvs, saving, _ = self._gains_of(members)
        cpv, at = np.unique(cpvs, return_inverse=True)
        total = np.bincount(at, weights=np.maximum(saving, 0.0), minlength=cpv.size)
        return members, float(np.maximum(0.0, np.minimum(total, self.t[cpv] - self.t_max)).sum())

    def group_rank(self, atlas: int) -> tuple[float, float]:
        """(score, 0) of unpaid shared ``atlas`` as a group: its :meth:`group_gain` over its bytes;
        (0, 0) once paid (its members are ranked one by one then) or where it gains nothing."""
        self.rescored += 1
        if self.paid(atlas) or not self.groups:
            return 0.0, 0.0
        members, gain = self.group_gain(atlas)
        if gain <= 0.0:
            return 0.0, 0.0
        return gain / float(self.cand.memory[members].max()), 0.0

    def group_pick(self, atlas: int) -> int:
        """The member of unpaid ``atlas`` to choose when its group wins: the largest gain, ties to
        the smaller index."""
        members = self.members(atlas)
        owner, _, _, gain = self._gains_of(members)
        return int(members[int(np.argmax(np.bincount(owner, weights=gain, minlength=members.size)))])

    def rank_item(self, x: int, reference: bool = False) -> tuple[float, float]:
        """The rank of a heap item: candidate ``x`` below ``cand.count``, else the group of shared
        atlas ``x - cand.count``."""
        m = self.cand.count
        return self.rank(x, reference) if x < m else self.group_rank(x - m)

    def score(self, i: int) -> float:
        return self.rank(i)[0]

    def initial_ranks(self) -> tuple[np.ndarray, np.ndarray]:
        """Every candidate's :meth:`rank` (vectorised; with what is chosen so far only as far as
        scores go: they are upper bounds, the lazy heap re-scores)."""
        total = _initial_gains(self.cand.served, self.g, self.ti, self.cand.served_offsets, self.t, self.t_max)
        memory = self.memory_now()
        free = (memory <= 0.0) & (total > 0.0)
        with np.errstate(divide="ignore", invalid="ignore"):
            score = np.where(free, np.inf, total / np.where(memory > 0.0, memory, 1.0))
        grouped = (self.atlas >= 0) & (memory > 0.0) & self.groups  # an unpaid shared atlas's: ranked by its group
        return np.where(grouped, 0.0, score), np.where(free, total, 0.0)

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
        keys, owners = self._keys, self._key_owners()
        for k in np.flatnonzero(saving > 0.0):
            p = int(cpvs[k])
            base = p * int(self.nodes)
            # the impostors drawn here for this node's descendants (keys base + node + 1 .. + size - 1): replaced here
            lo, hi = np.searchsorted(keys, [base + node + 1 - self.own, base + node + int(self.size[node])])
            gone = set()
            for key in keys[lo:hi].tolist():
                other_id = owners[key]
                other = self.chosen[other_id]
                del other.cpvs[p]
                removed.append(key)
                gone.add(other_id)
                if not other.cpvs:
                    self.deleted.add(other_id)
                    lost = int(self.atlas[other.candidate])
                    if lost >= 0 and lost != atlas and not self.paid(lost):
                        self.unpaid_again = (*self.unpaid_again, lost)
            if gone:
                self.drawn[p] = [o for o in self.drawn[p] if o not in gone]
            self.drawn[p].append(me)
            owners[base + node] = me
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

    def _take(self, x: int) -> list[int]:
        """Choose heap item ``x`` (a candidate, or a group's :meth:`group_pick`); returns the items
        whose rank rose: the other candidates of the atlas the choice paid, and the groups of
        atlases it left unpaid."""
        m = self.cand.count
        j = x if x < m else self.group_pick(x - m)
        paid = self.choose(j)
        rose = [int(k) for k in self.members(paid) if k != j] if paid >= 0 else []
        rose += [m + a for a in self.unpaid_again]
        self.unpaid_again = ()
        return rose

    def run(self, lazy: bool = True, progress: Callable[[int, float], None] | None = None) -> None:
        """Choose until no candidate gains anything (module docstring).  ``lazy=False``: every
        item's rank again at every step, by numpy (the reference the lazy heap must equal)."""
        scores, ties = self.initial_ranks()
        m = self.cand.count
        if not lazy:
            # Every item's rank again at every step; one that may rise (a candidate of a shared
            # atlas, a group) stays in the pool at 0.
            items = [(float(s), float(t), int(j)) for j, (s, t) in enumerate(zip(scores, ties)) if s > 0.0]
            items += [(*self.group_rank(int(a)), m + int(a)) for a in self.atlases()]
            may_rise = {int(j) for j in np.flatnonzero(self.atlas >= 0)} | {m + int(a) for a in self.atlases()}
            pool = {x for s, _, x in items if s > 0.0} | may_rise
            ranks = {x: r for x in pool if (r := self.rank_item(x, True))[0] > 0.0}
            while ranks:
                best = max(ranks, key=lambda x: (*ranks[x], -x))
                self._take(best)
                pool = {x for x in pool if x in ranks or x in may_rise}
                ranks = {x: r for x in pool if (r := self.rank_item(x, True))[0] > 0.0}
            return
        heap = _Heap.of(scores, ties)
        for a in self.atlases():
            s, t = self.group_rank(int(a))
            if s > 0.0:
                heap.push(s, t, m + int(a))
        node_of, memory = self.cand.node, self.cand.memory.astype(np.float64, copy=False)
        while True:
            keys, cum, starts = self._kernel_index()
            status, x, heap.n, rescored = _settle(
                heap.s, heap.t, heap.x, heap.n, self.cand.served, self.g, self.ti, self.cand.served_offsets, node_of, memory,
                self.atlas, keys, cum, starts, self.size, int(self.nodes), self.t, self.t_max, bool(self.chosen), self.own,
            )  # fmt: skip
            self.rescored += rescored
            if status == 0:
                return
            x = int(x)
            if status == 2:  # a group or a shared atlas's candidate: ranked here
                s, t = self.rank_item(x)
                if s <= 0.0:
                    continue
                if heap.n and heap.after_top(-s, -t, x):
                    heap.push(s, t, x)
                    continue
            for k in self._take(x):  # their ranks rose: pushed again (older entries are found stale)
                s, t = self.rank_item(k)
                if s > 0.0:
                    heap.push(s, t, k)
            if progress is not None:
                progress(len(self.chosen), float(np.max(self.t, initial=-np.inf)))


class _Heap:
    """The lazy heap of :meth:`Greedy.run`: entries ``(-score, -tie-break, item)`` in arrays
    (:func:`_settle` pops and pushes them in numba), the order of Python's heapq on those tuples."""

    def __init__(self, s: np.ndarray, t: np.ndarray, x: np.ndarray, n: int) -> None:
        self.s, self.t, self.x, self.n = s, t, x, n

    @classmethod
    def of(cls, scores: np.ndarray, ties: np.ndarray) -> _Heap:
        """The heap of every candidate with a positive score."""
        keep = np.flatnonzero(scores > 0.0)
        n = int(keep.size)
        heap = cls(np.empty(n + 16), np.empty(n + 16), np.empty(n + 16, dtype=np.int64), n)
        heap.s[:n], heap.t[:n], heap.x[:n] = -scores[keep], -ties[keep], keep
        _heapify(heap.s, heap.t, heap.x, n)
        return heap

    def push(self, score: float, tie: float, item: int) -> None:
        if self.n == self.s.size:  # full: twice the room
            grow = max(16, self.n)
            self.s = np.concatenate([self.s, np.empty(grow)])
            self.t = np.concatenate([self.t, np.empty(grow)])
            self.x = np.concatenate([self.x, np.empty(grow, dtype=np.int64)])
        self.n = _heap_push(self.s, self.t, self.x, self.n, -float(score), -float(tie), int(item))

    def after_top(self, s: float, t: float, x: int) -> bool:
        """``(s, t, x) > heap[0]`` as Python compares tuples."""
        return (s, t, x) > (float(self.s[0]), float(self.t[0]), int(self.x[0]))

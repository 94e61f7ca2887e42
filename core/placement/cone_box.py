"""(v,) circular cones with their apex at the origin against (k,) axis-aligned boxes: which meet, (v, k) bool.

A cone is a unit axis ``a`` and a half-angle ``h``: the points ``p`` with ``angle(p, a) <= h``.  For
``h < 90°`` the cone is convex, and a box ``B`` that does not hold the origin meets it exactly when

* the axis ray ``s a`` (``s >= 0``) hits ``B`` (a slab test), or
* some edge of ``B`` comes within ``h`` of ``a``.

Why the edges suffice: if ``B`` meets the cone but the ray misses it, the segment from a point of
``B`` in the cone to a far point of the ray stays in the (convex) cone and leaves ``B`` through a
face ``F``; the cone's section by ``F``'s plane is convex, and were it inside ``F`` without touching
an edge it would be bounded, an ellipse about the point where the ray crosses the plane, which
would then lie in ``F``: the ray would hit ``B``.  A tangent plane's section is a ray from the apex,
unbounded, so it leaves ``F`` through an edge.  On an edge ``p(t) = p0 + t d``, ``t`` in ``[0, 1]``,
``cos angle(p(t), a) = (alpha + t beta) / sqrt(A + 2 B t + C t^2)`` (``alpha = a.p0``,
``beta = a.d``, ``A = |p0|^2``, ``B = p0.d``, ``C = |d|^2``); its derivative vanishes at a single
``t* = (alpha B - beta A) / (beta B - alpha C)``, so the largest cosine on the edge is at an end or
at ``t*``.

:mod:`farfield.core.placement.view_space` first tests each box through its bounding sphere (cheap,
looser) and refines with :func:`refine_cone_box` only the pairs the sphere lets through.  Cones of
``h >= 90°`` (not convex) keep the sphere's answer, and a cosine within ``TOL.cone_cos`` of the
limit counts as meeting (the critical point is found in floating point), so the refinement only
removes pairs that truly do not meet: it stays conservative.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from farfield.core.constants import TOL


def refine_cone_box(
    axes: np.ndarray, half_angles: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray, mask: np.ndarray
) -> np.ndarray:
    """(v, k) bool: ``mask`` with every pair (cone ``v``, box ``k``) that does not meet cleared.

    ``axes`` (v, 3) unit, ``half_angles`` (v,) radians, ``box_lo``/``box_hi`` (k, 3), ``mask`` (v, k)
    bool (the pairs to test; the others stay false).  Boxes holding the origin always meet."""
    out = np.array(mask, dtype=np.bool_, copy=True)
    if out.size:
        _refine(
            np.ascontiguousarray(axes, dtype=np.float64), np.ascontiguousarray(half_angles, dtype=np.float64),
            np.ascontiguousarray(box_lo, dtype=np.float64), np.ascontiguousarray(box_hi, dtype=np.float64),
            out, 0.5 * math.pi, TOL.cone_cos,
        )  # fmt: skip
    return out


@njit(cache=True, nogil=True)
def _ray_hits(a, lo, hi):
    """Whether the ray ``s a``, ``s >= 0``, hits the box ``lo``..``hi`` (slab test)."""
    t0, t1 = 0.0, np.inf
    for i in range(3):
        ai = a[i]
        if ai == 0.0:
            if lo[i] > 0.0 or hi[i] < 0.0:
                return False
            continue
        u, w = lo[i] / ai, hi[i] / ai
        if u > w:
            u, w = w, u
        t0, t1 = max(t0, u), min(t1, w)
        if t0 > t1:
            return False
    return True


@njit(cache=True, nogil=True)
def _box_meets(a, cos_h, lo, hi, slack):
    if lo[0] <= 0.0 <= hi[0] and lo[1] <= 0.0 <= hi[1] and lo[2] <= 0.0 <= hi[2]:
        return True
    if _ray_hits(a, lo, hi):
        return True
    limit = cos_h - slack
    p = np.empty(3)
    for i in range(3):  # edges along axis i
        j, k = (i + 1) % 3, (i + 2) % 3
        length = hi[i] - lo[i]
        for c in range(4):
            p[i] = lo[i]
            p[j] = lo[j] if c & 1 == 0 else hi[j]
            p[k] = lo[k] if c & 2 == 0 else hi[k]
            alpha = a[0] * p[0] + a[1] * p[1] + a[2] * p[2]
            big_a = p[0] * p[0] + p[1] * p[1] + p[2] * p[2]
            if alpha >= limit * math.sqrt(big_a):  # the edge's start (a corner)
                return True
            if length <= 0.0:
                continue
            beta, big_b, big_c = a[i] * length, p[i] * length, length * length
            end = big_a + 2.0 * big_b + big_c
            if alpha + beta >= limit * math.sqrt(end):  # its end
                return True
            den = beta * big_b - alpha * big_c
            if den != 0.0:
                t = (alpha * big_b - beta * big_a) / den
                if 0.0 < t < 1.0:
                    d2 = big_a + t * (2.0 * big_b + t * big_c)
                    if alpha + t * beta >= limit * math.sqrt(max(d2, 0.0)):
                        return True
    return False


@njit(cache=True, nogil=True)
def _refine(axes, half_angles, box_lo, box_hi, out, right_angle, slack):
    for v in range(axes.shape[0]):
        if half_angles[v] >= right_angle:
            continue  # not convex: the sphere's answer stands
        cos_h = math.cos(half_angles[v])
        a = axes[v]
        for k in range(box_lo.shape[0]):
            if out[v, k] and not _box_meets(a, cos_h, box_lo[k], box_hi[k], slack):
                out[v, k] = False

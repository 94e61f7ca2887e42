"""The depth channel of quad impostors (layered, envmap; channel sets with ``depth``, issue 55).

**Encoding.**  A quad lies on its layer's plane, perpendicular to the recording axis at eye depth
D from the reference viewpoint V, inside its layer's slab [near, far] (eye depths; an envmap
face's last slab ends at the farthest geometry along the face's axis).  Each texel of the quad
shows the surface point where the ray from V through the texel's centre P (on the quad) meets
the surface in that slab (``slab.frag``; a texel kept by the conservative rule at a triangle's
rim takes the depth of the triangle's point nearest its centre).  Its eye depth d is written,
quantised to 8 bits over the slab, in the **alpha of the normal page**:

    a = round(255 (d - near) / (far - near))

The quad's own range is kept as two **ray scales**, ``s0 = near / D`` and ``s1 = far / D``
(:attr:`farfield.core.impostor.impostor.QuadPayload.depth_range`, (q, 2)), so that a decoder
needs neither the axis nor the plane:

    X = V + (P - V) (s0 + a / 255 (s1 - s0))

A texel's point is then within (s1 - s0) |P - V| / 510 of the recorded one along its ray (half a
quantisation step), plus the recording's float32 rounding.  In the GLB, V is the node's origin
(POSITION is relative to it), so X = POSITION (s0 + a / 255 (s1 - s0)) in the node's frame.

Texels of a tile that keep no colour (alpha 0) take their nearest kept texel's depth, as their
normal (:func:`farfield.core.layering.atlas.fill_nearest_rgb`); texels between tiles hold 0.  An
envmap texel copied from the closer layer by the gap fill (seed 002 §5.1) lies in front of its
new slab and takes a = 0, the slab's near border (:func:`fill_gaps_with_depth`).

**Not for the other techniques.**  A textured depth mesh's triangles are its depth, a point's
position and an LDI sample's float32 eye depth are exact: they refuse ``+depth``
(:func:`refuse_depth`).
"""

from __future__ import annotations

import numpy as np

from farfield.core.errors import LayerPlanError

# The GLB's extension (extensionsUsed, never extensionsRequired: a viewer without it draws the
# lit card) and the vertex attribute holding each quad's ray scales (glTF: application-specific
# attribute semantics start with an underscore).
DEPTH_EXTENSION = "FARFIELD_impostor_depth"
DEPTH_ATTRIBUTE = "_DEPTH_RANGE"

# Why a technique with exact geometry keeps no depth channel.
_EXACT = {
    "tdm": "a textured depth mesh's triangles already lie on the surface its texels show",
    "points": "each point already keeps its exact position",
    "ldi": "each LDI sample already keeps its float32 eye depth",
}


def refuse_depth(technique: str, channels: str) -> None:
    """Raise :class:`LayerPlanError` when ``channels`` keeps depth for a technique with exact geometry.

    >>> refuse_depth("tdm", "albedo+normal")
    >>> refuse_depth("points", "albedo+normal+depth")
    Traceback (most recent call last):
    ...
    farfield.core.errors.LayerPlanError: channels=albedo+normal+depth: points keep no depth channel (each point already keeps its exact position); use albedo+normal
    """
    from farfield.core.impostor.impostor import wants_depth

    if wants_depth(channels):
        kept = str(channels).replace("+depth", "")
        raise LayerPlanError(
            f"channels={channels}: {technique} keep{'s' if technique != 'points' else ''} no depth channel "
            f"({_EXACT[technique]}); use {kept}"
        )


def layer_depth_ranges(plan, index: int, count: int) -> np.ndarray:
    """(count, 2) float64 ray scales (near / D, far / D) of ``count`` quads on layer ``index`` of
    ``plan`` (a :class:`~farfield.core.layering.plan.LayerPlan` or an envmap face plan: eye depth D
    = distance + reference offset, the slab its borders + reference offset).

    >>> from types import SimpleNamespace
    >>> plan = SimpleNamespace(distances=np.array([2.0, 4.0]), borders=np.array([1.0, 3.0, 6.0]), reference_offset=0.0)
    >>> layer_depth_ranges(plan, 1, 2).tolist()
    [[0.75, 1.5], [0.75, 1.5]]
    """
    offset = float(plan.reference_offset)
    plane = float(plan.distances[index]) + offset
    near, far = float(plan.borders[index]) + offset, float(plan.borders[index + 1]) + offset
    return np.tile([near / plane, far / plane], (int(count), 1))


def fill_gaps_with_depth(closer: np.ndarray, farther: np.ndarray) -> tuple[np.ndarray, int]:
    """:func:`farfield.core.techniques.envmap.gap_fill.fill_gaps` of layers recorded with depth:
    a texel copied from the closer layer lies in front of the farther slab, so its depth code
    becomes 0 (the slab's near border, the nearest depth the slab holds).

    >>> near = np.zeros((1, 3, 8), np.uint8); near[0, 1] = (9, 9, 9, 255, 1, 2, 3, 200)
    >>> far = np.zeros((1, 3, 8), np.uint8); far[0, 2] = (5, 5, 5, 255, 1, 2, 3, 77)
    >>> filled, added = fill_gaps_with_depth(near, far)
    >>> filled[0, :, 7].tolist(), added
    ([0, 0, 77], 1)
    """
    from farfield.core.techniques.envmap.gap_fill import fill_gaps

    out, added = fill_gaps(closer, farther)
    copied = np.any(out != farther, axis=-1)
    out[copied, 7] = 0
    return out, added


def keeps_depth(impostor) -> bool:
    """Whether ``impostor`` keeps the depth channel (a quad payload with its ``depth_range``)."""
    return getattr(impostor.payload, "depth_range", None) is not None


def quad_texels(impostor, quad: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The texels of quad ``quad``'s tile on its page: (rows (n,), columns (n,), world points (n, 3)
    of their centres on the quad).  The quad's corners (TL, TR, BR, BL) and uvs define an affine
    map from page uv to the quad's plane (a tile may be stored rotated)."""
    payload = impostor.payload
    page = impostor.pages[int(payload.page[quad])]
    h, w = page.shape[:2]
    c, t = payload.corners[quad], payload.uv[quad] * [w, h]  # uv in texels
    x0, x1 = (int(np.floor(v + 0.5)) for v in (t[:, 0].min(), t[:, 0].max()))
    y0, y1 = (int(np.floor(v + 0.5)) for v in (t[:, 1].min(), t[:, 1].max()))
    ys, xs = np.mgrid[y0:y1, x0:x1]
    d = np.stack([t[1] - t[0], t[3] - t[0]], axis=1)  # (2, 2) columns: TL->TR, TL->BL in texels
    ab = np.linalg.solve(d, np.stack([xs.ravel() + 0.5 - t[0, 0], ys.ravel() + 0.5 - t[0, 1]]))  # (2, n)
    points = c[0] + ab[0][:, None] * (c[1] - c[0]) + ab[1][:, None] * (c[3] - c[0])
    return ys.ravel(), xs.ravel(), points


def depth_points(impostor, kept_only: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """The 3D points the depth channel places the texels at: (points (n, 3) world, quad (n,)), for
    every texel of every quad's tile whose colour is kept (alpha > 0; ``kept_only=False``: every
    texel of the tiles).  Raises ValueError for an impostor without depth."""
    if not keeps_depth(impostor):
        raise ValueError(f"this {impostor.technique} impostor keeps no depth channel")
    payload = impostor.payload
    normal_pages = impostor.channels["normal"]
    viewpoint = np.asarray(impostor.reference_viewpoint, dtype=np.float64)
    out, owner = [], []
    for q in range(payload.count):
        rows, cols, on_quad = quad_texels(impostor, q)
        p = int(payload.page[q])
        keep = impostor.pages[p][rows, cols, 3] > 0 if kept_only else np.ones(rows.size, bool)
        code = normal_pages[p][rows[keep], cols[keep], 3].astype(np.float64) / 255.0
        s0, s1 = payload.depth_range[q]
        scale = s0 + code * (s1 - s0)
        out.append(viewpoint + (on_quad[keep] - viewpoint) * scale[:, None])
        owner.append(np.full(int(keep.sum()), q, np.int64))
    if not out:
        return np.zeros((0, 3)), np.zeros(0, np.int64)
    return np.concatenate(out), np.concatenate(owner)

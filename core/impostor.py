"""The impostor: world-space quads (q, 4, 3) float64 textured from RGBA atlas pages (H, W, 4) uint8.

This is the in-memory form every technique produces and every consumer (bundle writer, GLB writer,
evaluation renderer, service) reads.  Conventions:

* Image arrays (layers, tiles, atlas pages) are **top row first**, as PNG and glTF store them.
* Texel rectangles are ``[x0, y0, x1, y1)`` integer texel indices in such an image (x right, y down).
* Quad corners are ordered top-left, top-right, bottom-right, bottom-left as seen from the
  reference viewpoint, and each corner's UV is in glTF's convention: (0, 0) is the top-left of
  the page, (1, 1) the bottom-right.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from core.layers import LayerPlan

TECHNIQUES = ("layered", "envmap", "tdm", "points", "ldi", "billboard")


@dataclass(frozen=True, slots=True)
class Impostor:
    """One impostor of one part for one view cell."""

    technique: str
    viewcell: dict  # BoxCell.to_dict() / ShaftCell.to_dict()
    reference_viewpoint: np.ndarray  # (3,) float64 world
    resolution: int  # output image pixels per side it was made for
    fov_deg: float  # output field of view it was made for
    quad_corners: np.ndarray  # (q, 4, 3) float64 world: TL, TR, BR, BL
    quad_uv: np.ndarray  # (q, 4, 2) float64 page UV, glTF convention, same corner order
    quad_page: np.ndarray  # (q,) int64 atlas page of each quad
    quad_layer: np.ndarray  # (q,) int64 layer of each quad
    pages: tuple[np.ndarray, ...]  # each (H, W, 4) uint8, top row first
    layers: list[dict] = field(default_factory=list)  # per layer: distance, depth range (eye depth), texels kept
    stats: dict = field(default_factory=dict)  # counts, memory, timings per stage
    parameters: dict = field(default_factory=dict)  # every knob that made it
    code_version: str = ""

    @property
    def quad_count(self) -> int:
        return int(self.quad_corners.shape[0])

    @property
    def texture_bytes(self) -> int:
        """Uncompressed RGBA bytes of all atlas pages."""
        return int(sum(p.shape[0] * p.shape[1] * 4 for p in self.pages))


def texel_rect_corners(plan: LayerPlan, layer_distance: float, rects: np.ndarray) -> np.ndarray:
    """World corners (q, 4, 3) float64 of texel rectangles (q, 4) int ``[x0, y0, x1, y1)`` on one layer.

    The layer plane lies ``layer_distance`` from the view cell's near border (the plan's t), i.e.
    at eye depth ``t + s`` from the reference viewpoint, and spans the recording frustum.  Image x
    runs along ``plan.u``, image y (top row first) against ``plan.v``.
    """
    rects = np.asarray(rects, dtype=np.float64).reshape(-1, 4)
    res = plan.texture_resolution.astype(np.float64)
    depth = float(layer_distance) + plan.reference_offset
    x = np.stack([rects[:, 0], rects[:, 2], rects[:, 2], rects[:, 0]], axis=1)  # TL TR BR BL
    y = np.stack([rects[:, 1], rects[:, 1], rects[:, 3], rects[:, 3]], axis=1)
    ndc_x = x / res[0] * 2.0 - 1.0
    ndc_y = 1.0 - y / res[1] * 2.0
    ex = ndc_x * plan.frustum_half_tangents[0] * depth
    ey = ndc_y * plan.frustum_half_tangents[1] * depth
    return (
        plan.reference_viewpoint
        + ex[..., None] * plan.u
        + ey[..., None] * plan.v
        + depth * plan.axis
    )

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

from core.errors import BundleFormatError
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
    def triangle_count(self) -> int:
        """Triangles drawn: two per quad, one per quad whose fourth corner repeats its third (a
        textured depth mesh's triangle, see :mod:`core.tdm`)."""
        corners = self.quad_corners
        return int(2 * corners.shape[0] - np.count_nonzero(np.all(corners[:, 3] == corners[:, 2], axis=1)))

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


def check_impostor(impostor: Impostor) -> None:
    """Raise unless the impostor's arrays have the shapes and dtypes every writer relies on.

    Parameters
    ----------
    impostor : Impostor
        ``reference_viewpoint`` (3,) finite, ``quad_corners`` (q, 4, 3) finite, ``quad_uv``
        (q, 4, 2) finite, ``quad_page`` and ``quad_layer`` (q,) integers, every ``quad_page`` an
        index into ``pages``, every page (H, W, 4) uint8 with H, W >= 1.

    Raises
    ------
    BundleFormatError
        Naming the first field that does not fit.

    Examples
    --------
    >>> import numpy as np
    >>> bad = Impostor("layered", {}, np.zeros(3), 64, 60.0, np.zeros((1, 4, 3)),
    ...                np.zeros((1, 4, 2)), np.zeros(1, np.int64), np.zeros(1, np.int64),
    ...                (np.zeros((2, 2, 4), np.float32),))
    >>> check_impostor(bad)
    Traceback (most recent call last):
    ...
    core.errors.BundleFormatError: page 0 is (2, 2, 4) float32, expected (H, W, 4) uint8
    """
    viewpoint = np.asarray(impostor.reference_viewpoint)
    if viewpoint.shape != (3,) or not np.all(np.isfinite(viewpoint)):
        raise BundleFormatError(f"reference_viewpoint must be 3 finite numbers, got {viewpoint!r}")
    corners = np.asarray(impostor.quad_corners)
    q = corners.shape[0] if corners.ndim == 3 else -1
    expected = {
        "quad_corners": (q, 4, 3),
        "quad_uv": (q, 4, 2),
        "quad_page": (q,),
        "quad_layer": (q,),
    }
    for name, shape in expected.items():
        array = np.asarray(getattr(impostor, name))
        if q < 0 or array.shape != shape:
            raise BundleFormatError(f"{name} has shape {array.shape}, expected {shape}")
        if name in ("quad_corners", "quad_uv"):
            if not np.issubdtype(array.dtype, np.floating) or not np.all(np.isfinite(array)):
                raise BundleFormatError(f"{name} must be finite floats, got dtype {array.dtype}")
        elif not np.issubdtype(array.dtype, np.integer):
            raise BundleFormatError(f"{name} must be integers, got dtype {array.dtype}")
    for index, page in enumerate(impostor.pages):
        if not isinstance(page, np.ndarray) or page.dtype != np.uint8 or page.ndim != 3 or page.shape[2] != 4:
            shape = getattr(page, "shape", None)
            raise BundleFormatError(
                f"page {index} is {shape} {getattr(page, 'dtype', type(page).__name__)}, "
                "expected (H, W, 4) uint8"
            )
        if page.shape[0] < 1 or page.shape[1] < 1:
            raise BundleFormatError(f"page {index} is empty: {page.shape}")
    page_of_quad = np.asarray(impostor.quad_page)
    if q > 0 and (page_of_quad.min() < 0 or page_of_quad.max() >= len(impostor.pages)):
        raise BundleFormatError(
            f"quad_page spans [{page_of_quad.min()}, {page_of_quad.max()}] "
            f"but there are {len(impostor.pages)} pages"
        )

"""Layer images cut into tiles and packed into atlas pages: the stages layered impostors and
environment-map faces share (seed 000 §3.5 box-grown quads, §3.6 atlas packing), and the
impostor's ``layers`` entries.

A tile is an RGBA image (h, w, 4) uint8, top row first, whose rectangle ``[x0, y0, x1, y1)`` in its
layer image is one quad.
"""

from __future__ import annotations

import numpy as np

from farfield.core.atlas import MAX_PAGE, compose, fill_nearest_rgb, pack, tile_uvs
from farfield.core.errors import LayerPlanError
from farfield.core.quads import grow_quads

# Bytes of one quad's geometry as drawn: 4 vertices x (3 position + 2 uv) float32 + 6 uint32 indices.
QUAD_GEOMETRY_BYTES = 4 * 5 * 4 + 6 * 4


def layer_tiles(image: np.ndarray, kept: np.ndarray, grid_cell: int, fill_threshold: float) -> tuple[np.ndarray, list[np.ndarray]]:
    """Box-grown rectangles (q, 4) of a layer's kept texels (§3.5) and their tiles: each its own
    array (not a view that would keep the layer alive), transparent texels coloured from the
    nearest opaque one so that bilinear filtering and mipmaps never pull black into the edges."""
    rects = grow_quads(kept, grid_cell, fill_threshold)
    texels = image.copy()
    texels[..., 3] = np.where(kept, texels[..., 3], 0)
    return rects, [fill_nearest_rgb(texels[y0:y1, x0:x1]) for x0, y0, x1, y1 in rects]


def layer_records(plan, layer_ids, texels) -> list[dict]:
    """The impostor's ``layers`` entries of the layers ``layer_ids`` of ``plan`` that keep
    ``texels`` texels each: index, distance, depth range (recording and eye frame), texels."""
    eye = plan.borders + plan.reference_offset
    return [
        {
            "index": int(i),
            "distance": float(plan.distances[i]),
            "depth_range": [float(plan.borders[i]), float(plan.borders[i + 1])],
            "eye_depth_range": [float(eye[i]), float(eye[i + 1])],
            "texels": int(n),
        }
        for i, n in zip(layer_ids, texels)
    ]


def check_power_of_two_pages(max_page: int) -> None:
    """Refuse a largest page side the power-of-two packer (:func:`farfield.core.atlas.pack`) cannot use.

    >>> check_power_of_two_pages(3000)
    Traceback (most recent call last):
    ...
    farfield.core.errors.LayerPlanError: max_page must be a power of two for these atlas pages, got 3000
    """
    if max_page < 1 or max_page & (max_page - 1):
        raise LayerPlanError(f"max_page must be a power of two for these atlas pages, got {max_page}")


def pack_tiles(tiles: list[np.ndarray], padding: int, max_page: int = MAX_PAGE) -> tuple[tuple[np.ndarray, ...], np.ndarray, np.ndarray, int]:
    """Atlas pages (§3.6) of ``tiles``, none wider or taller than ``max_page``: (pages, quad uv
    (q, 4, 2), quad page (q,), tile bytes)."""
    if not tiles:
        return (), np.zeros((0, 4, 2)), np.zeros(0, np.int64), 0
    sizes = np.array([[t.shape[1], t.shape[0]] for t in tiles], dtype=np.int64)
    layout = pack(sizes, padding=padding, max_page=max_page)
    pages = compose(layout, tiles, padding, bleed=0)
    return tuple(pages), tile_uvs(layout), layout.page.astype(np.int64), int(sizes.prod(axis=1).sum() * 4)

"""Layer images cut into tiles and packed into atlas pages: the stages layered impostors and
environment-map faces share (seed 000 §3.5 box-grown quads, §3.6 atlas packing), and the
impostor's ``layers`` entries.

A tile is an RGBA image (h, w, 4) uint8, top row first, whose rectangle ``[x0, y0, x1, y1)`` in its
layer image is one quad.
"""

from __future__ import annotations

import numpy as np

from farfield.core.errors import LayerPlanError
from farfield.core.layering.atlas import MAX_PAGE, compose, fill_nearest_rgb, pack, tile_uvs
from farfield.core.layering.quads import grow_quads

# Bytes of one quad's geometry as drawn: 4 vertices x (3 position + 2 uv) float32 + 6 uint32 indices.
QUAD_GEOMETRY_BYTES = 4 * 5 * 4 + 6 * 4


def split_rects(rects: np.ndarray, largest: int) -> np.ndarray:
    """``rects`` (q, 4) ``[x0, y0, x1, y1)``, each one wider or taller than ``largest`` cut into a
    grid of pieces of at most ``largest`` a side (row by row, in place of it); the others as they are.

    >>> split_rects(np.array([[0, 0, 5, 2], [10, 10, 12, 12]]), 2).tolist()
    [[0, 0, 2, 2], [2, 0, 4, 2], [4, 0, 5, 2], [10, 10, 12, 12]]
    """
    rects = np.asarray(rects, dtype=np.int64).reshape(-1, 4)
    if not rects.size or (np.max(rects[:, 2:] - rects[:, :2]) <= largest):
        return rects
    pieces = []
    for x0, y0, x1, y1 in rects.tolist():
        for ya in range(y0, y1, largest):
            for xa in range(x0, x1, largest):
                pieces.append((xa, ya, min(xa + largest, x1), min(ya + largest, y1)))
    return np.array(pieces, dtype=np.int64)


def layer_tiles(image: np.ndarray, kept: np.ndarray, grid_cell: int, fill_threshold: float, max_page: int = MAX_PAGE,
                padding: int = 0) -> tuple[np.ndarray, list[np.ndarray]]:  # fmt: skip
    """Box-grown rectangles (q, 4) of a layer's kept texels (§3.5) and their tiles: each its own
    array (not a view that would keep the layer alive), transparent texels coloured from the
    nearest opaque one so that bilinear filtering and mipmaps never pull black into the edges.
    A rectangle that would not fit a page of ``max_page`` with its ``padding`` is cut into pieces
    that do (:func:`split_rects`), each holding a kept texel its own quad."""
    grown = grow_quads(kept, grid_cell, fill_threshold)
    rects = split_rects(grown, max_page - 2 * padding)
    if len(rects) != len(grown):  # cut: a piece of a box's empty cells keeps no texel, and is no quad
        rects = rects[np.array([kept[y0:y1, x0:x1].any() for x0, y0, x1, y1 in rects], dtype=bool)]
    return rects, [_tile(image, kept, y0, y1, x0, x1) for x0, y0, x1, y1 in rects]


def _tile(image: np.ndarray, kept: np.ndarray, y0: int, y1: int, x0: int, x1: int) -> np.ndarray:
    """The tile of rectangle ``[x0, y0, x1, y1)``: its texels, alpha 0 where not kept, then
    :func:`~farfield.core.layering.atlas.fill_nearest_rgb`.  Only the rectangle's texels are read:
    the layer is not copied (a 1024 px bake's layers took 0.2 s of copies for tiles covering 2 % of them)."""
    texels = image[y0:y1, x0:x1].copy()
    texels[..., 3] = np.where(kept[y0:y1, x0:x1], texels[..., 3], 0)
    return fill_nearest_rgb(texels)


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


def check_pages(max_page: int, padding: int) -> None:
    """Refuse a largest page side the power-of-two packer (:func:`farfield.core.layering.atlas.pack`) cannot
    use, or one that its padding leaves no texel of.

    >>> check_pages(3000, 2)
    Traceback (most recent call last):
    ...
    farfield.core.errors.LayerPlanError: max_page must be a power of two for these atlas pages, got 3000
    >>> check_pages(64, 32)
    Traceback (most recent call last):
    ...
    farfield.core.errors.LayerPlanError: padding 32 on both sides of a tile leaves no texel of a page of 64 (max_page); give padding < 32 or a larger max_page
    """
    if max_page < 1 or max_page & (max_page - 1):
        raise LayerPlanError(f"max_page must be a power of two for these atlas pages, got {max_page}")
    if 2 * padding >= max_page:
        raise LayerPlanError(f"padding {padding} on both sides of a tile leaves no texel of a page of {max_page} (max_page); "
                             f"give padding < {max_page // 2} or a larger max_page")  # fmt: skip


def split_channels(pages: tuple[np.ndarray, ...]) -> tuple[tuple[np.ndarray, ...], dict]:
    """Pages of 8 channels (colour, then normals: tiles cut from layers recorded with normals) as
    the colour pages and the impostor's ``channels`` (``{"normal": pages}``); pages of 4 as they are;
    of 12 (the material after the normals) or 16 (and the emission), ``{"normal": ..., "material":
    ..., "emissive": ...}``.

    >>> colour, channels = split_channels((np.zeros((2, 2, 8), np.uint8),))
    >>> colour[0].shape, channels["normal"][0].shape
    ((2, 2, 4), (2, 2, 4))
    """
    if not pages or pages[0].shape[2] == 4:
        return tuple(pages), {}
    colour = tuple(np.ascontiguousarray(p[..., :4]) for p in pages)
    if pages[0].shape[2] > 8:  # the material channel (and the emissive one) after the normals
        names = ("normal", "material", "emissive")[: pages[0].shape[2] // 4 - 1]
        return colour, {
            n: tuple(np.ascontiguousarray(p[..., 4 * k + 4 : 4 * k + 8]) for p in pages) for k, n in enumerate(names)
        }
    return colour, {"normal": tuple(np.ascontiguousarray(p[..., 4:]) for p in pages)}


def pack_tiles(
    tiles: list[np.ndarray], padding: int, max_page: int = MAX_PAGE
) -> tuple[tuple[np.ndarray, ...], np.ndarray, np.ndarray, int]:
    """Atlas pages (§3.6) of ``tiles``, none wider or taller than ``max_page``: (pages, quad uv
    (q, 4, 2), quad page (q,), tile bytes)."""
    if not tiles:
        return (), np.zeros((0, 4, 2)), np.zeros(0, np.int64), 0
    sizes = np.array([[t.shape[1], t.shape[0]] for t in tiles], dtype=np.int64)
    layout = pack(sizes, padding=padding, max_page=max_page)
    pages = compose(layout, tiles, padding, bleed=0)
    return tuple(pages), tile_uvs(layout), layout.page.astype(np.int64), int(sizes.prod(axis=1).sum() * 4)

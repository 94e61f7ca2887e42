"""Textures of a textured depth mesh, resampled from the voxel field per triangle (seed 003 §7).

Each triangle gets its own tile: a chart in the triangle's plane in the uniform voxel grid, one
texel per voxel unit ("the texel size approximately corresponds to the side length of a voxel"),
grown by a margin of texels on every side so that bilinear filtering at the edges reads valid
colours ("the extents of the texture are slightly larger than the polygon").  Every texel centre
is averaged from the ``n`` nearest voxel centres weighted by inverse distance ("n closest voxel
centers ... according to distance"; ``n`` is the oversampling option).  farfield searches one k-d
tree of the whole field for every texel (the paper restricts interior texels to the polygon's own
voxels; the whole field finds those too, as the query point lies on the surface).

**How the texture meets standard viewers (seed 003 §8).**  The paper turns perspective correction
off, because its textures are laid out in the image of the reference viewpoint.  A glTF viewer
cannot be told to do that.  farfield instead samples the texture *through the world triangle*: a
texel at barycentric coordinates b of the chart triangle takes the colour seen at the world point
``b . (W_A, W_B, W_C)`` of the reprojected triangle (its voxel-space position found by projecting
it back, :meth:`core.voxel_field.VoxelField.from_world`).  Perspective-correct interpolation, which
every viewer does, interpolates texture coordinates affinely over the world triangle, so it lands
on exactly that texel: the GLB is right in any viewer with no subdivision and no projective
coordinates, and the texel density stays about one texel per voxel.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from core.voxel_field import VoxelField


def triangle_charts(points: np.ndarray, margin: int) -> tuple[np.ndarray, np.ndarray]:
    """Chart of each voxel-space triangle (t, 3, 3): 2D vertex positions (t, 3, 2) in texels inside
    its tile, and tile sizes (t, 2) int64 (width, height), both with ``margin`` texels around.

    >>> xy, size = triangle_charts(np.array([[[0, 0, 0], [4, 0, 0], [0, 3, 0]]], float), 1)
    >>> xy[0].tolist(), size[0].tolist()
    ([[1.0, 1.0], [5.0, 1.0], [1.0, 4.0]], [6, 5])
    """
    a, b, c = points[:, 0], points[:, 1], points[:, 2]
    ab, ac = b - a, c - a
    length = np.linalg.norm(ab, axis=1)
    e1 = ab / np.maximum(length, 1e-300)[:, None]
    cx = np.einsum("ij,ij->i", ac, e1)
    perpendicular = ac - cx[:, None] * e1
    cy = np.linalg.norm(perpendicular, axis=1)
    xs = np.stack([np.zeros_like(cx), length, cx], axis=1)
    ys = np.stack([np.zeros_like(cy), np.zeros_like(cy), cy], axis=1)
    xs = xs - xs.min(axis=1, keepdims=True) + margin
    ys = ys + margin
    width = np.maximum(np.ceil(xs.max(axis=1) + margin - 1e-9), 1).astype(np.int64)
    height = np.maximum(np.ceil(ys.max(axis=1) + margin - 1e-9), 1).astype(np.int64)
    return np.stack([xs, ys], axis=2), np.stack([width, height], axis=1)


def resample_tiles(
    field: VoxelField, world: np.ndarray, chart: np.ndarray, sizes: np.ndarray, oversampling: int
) -> list[np.ndarray]:
    """One (h, w, 4) uint8 tile per triangle: its texels coloured from the voxel field through the
    world triangle ``world`` (t, 3, 3) (see the module docstring).  ``chart`` and ``sizes`` come from
    :func:`triangle_charts`."""
    t = world.shape[0]
    areas = sizes[:, 0] * sizes[:, 1]
    owner = np.repeat(np.arange(t), areas)
    first = np.concatenate([[0], np.cumsum(areas)[:-1]])
    local = np.arange(owner.size) - first[owner]
    col = local % sizes[owner, 0] + 0.5
    row = local // sizes[owner, 0] + 0.5
    # Barycentric coordinates of each texel centre in its chart triangle (extrapolated outside).
    p0, p1, p2 = chart[owner, 0], chart[owner, 1], chart[owner, 2]
    d1, d2 = p1 - p0, p2 - p0
    det = d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]
    det = np.where(np.abs(det) < 1e-300, 1.0, det)
    qx, qy = col - p0[:, 0], row - p0[:, 1]
    b1 = (qx * d2[:, 1] - qy * d2[:, 0]) / det
    b2 = (d1[:, 0] * qy - d1[:, 1] * qx) / det
    b0 = 1.0 - b1 - b2
    # Margin texels outside the triangle take the colour at the nearest point of it (approximately:
    # clamped and renormalized barycentrics), never an extrapolation far along a sliver.
    b = np.clip(np.stack([b0, b1, b2], axis=1), 0.0, None)
    b /= b.sum(axis=1, keepdims=True)
    b0, b1, b2 = b.T
    w = world[owner]
    points = b0[:, None] * w[:, 0] + b1[:, None] * w[:, 1] + b2[:, None] * w[:, 2]
    colours = sample_field(field, field.from_world(points), oversampling)
    tiles = []
    for i in range(t):
        tile = colours[first[i] : first[i] + areas[i]].reshape(sizes[i, 1], sizes[i, 0], 4)
        tiles.append(tile)
    return tiles


def sample_field(field: VoxelField, positions: np.ndarray, n: int) -> np.ndarray:
    """(m, 4) uint8 colours at voxel-space ``positions`` (m, 3): the ``n`` nearest voxel centres
    averaged with inverse-distance weights; alpha 255."""
    tree = cKDTree(field.centres)
    k = min(int(n), field.count)
    distance, index = tree.query(positions, k=k)
    if k == 1:
        rgb = field.rgba[index, :3].astype(np.float64)
    else:
        weight = 1.0 / np.maximum(distance, 1e-6)
        weight /= weight.sum(axis=1, keepdims=True)
        rgb = np.einsum("mk,mkc->mc", weight, field.rgba[index, :3].astype(np.float64))
    out = np.empty((positions.shape[0], 4), dtype=np.uint8)
    out[:, :3] = np.clip(np.rint(rgb), 0, 255).astype(np.uint8)
    out[:, 3] = 255
    return out


def chart_uvs(chart: np.ndarray, sizes: np.ndarray, corner_uv: np.ndarray) -> np.ndarray:
    """(t, 3, 2) page UVs of the triangles' vertices from their tile positions ``chart`` (t, 3, 2),
    tile ``sizes`` (t, 2) and the tiles' corner UVs TL, TR, BR, BL ``corner_uv`` (t, 4, 2) (which
    follow a tile the packer stored rotated)."""
    fx = chart[..., 0] / sizes[:, None, 0]
    fy = chart[..., 1] / sizes[:, None, 1]
    tl, tr, bl = corner_uv[:, None, 0], corner_uv[:, None, 1], corner_uv[:, None, 3]
    return tl + fx[..., None] * (tr - tl) + fy[..., None] * (bl - tl)

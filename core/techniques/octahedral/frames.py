"""Octahedral frames: a part drawn orthographically from each direction of the frame grid, into
one atlas page (H, W, 4) uint8 of ``n x n`` cells (and, with normals, a parallel normal page).

Frame ``k`` looks along ``-directions[k]`` at the part's bounding sphere (centre ``c``, radius
``r``); its image spans ``[-r, r]`` on its ``right`` and ``up`` axes (:func:`frame_axes`, the
orientation :meth:`farfield.core.render.raster.Camera.look_at` gives a camera looking that way),
``frame_resolution`` texels a side, top row first.  It is drawn by the evaluation's own
:class:`~farfield.core.render.raster.MeshRenderer` through a perspective camera
:data:`ORTHO_DISTANCE` radii away, whose magnification varies by ``±1 / ORTHO_DISTANCE`` over the
sphere's depth (0.06 texel at the edge of a 128-texel frame): orthographic for every purpose here.

Recording is conservative (as the layered recording, seed 000 §3.3.2, in spirit): each texel is
drawn with ``samples x samples`` samples and counts as covered when any of them is, its colour the
mean of the covered ones in linear light (:func:`farfield.core.quality.evaluation.downsample`), so a
twig thinner than a texel is kept, at most one texel too wide.  A texel's depth is the nearest of
its covered samples', stored as the height above the card plane through ``c`` along the frame's
direction, ``h in [-r, r]``, in the normal page's alpha: ``round((h / r * 0.5 + 0.5) * 254) + 1``
(0: nothing there).

With the material (``materials``), each texel keeps glTF's ORM packing of the same samples
(:meth:`MeshRenderer.render_material`: occlusion, roughness, metallic; their mean over the covered
samples, linear bytes, alpha 255 where covered) and, with ``emissive``, their mean linear emission,
sRGB-encoded: the material and emissive pages of docs/lit-impostors.md, laid out as the colour.

Atlas cells are ``frame_resolution + 2 * padding`` texels a side, the frame in its middle, laid
out in frame order on as few pages of at most ``max_page`` texels as hold them (:func:`pages_layout`); the colour is dilated into every empty texel of
the cell (alpha stays 0: :func:`farfield.core.layering.atlas.fill_nearest_rgb`), so bilinear
filtering and mip levels up to ``log2(padding)`` never mix two frames (docs/techniques/octahedral.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from farfield.core.colour_space import linear_to_srgb
from farfield.core.errors import AtlasOverflowError
from farfield.core.impostor.impostor import encode_normals
from farfield.core.layering.atlas import fill_nearest_rgb
from farfield.core.quality.evaluation import downsample
from farfield.core.render.raster import Camera, MeshRenderer

# The frames' camera stands this many bounding radii from the centre (module docstring).
ORTHO_DISTANCE = 1000.0
# A depth byte: 0 = no surface; 1..255 = height -r..r above the card plane.
DEPTH_LEVELS = 254


@dataclass(frozen=True, slots=True)
class Sphere:
    """A part's bounding sphere: centre (3,) float64 world, radius float, world units."""

    centre: np.ndarray
    radius: float

    @classmethod
    def of_objects(cls, objects) -> Sphere:
        """The sphere around the objects' bounding-box centre through their farthest vertex.

        >>> from farfield.core.procedural import box_object
        >>> s = Sphere.of_objects([box_object("b", [0, 0, 0], [2, 2, 2])])
        >>> s.centre.tolist(), round(s.radius, 6)
        ([1.0, 1.0, 1.0], 1.732051)
        """
        lo = np.min([o.bounds[0] for o in objects], axis=0)
        hi = np.max([o.bounds[1] for o in objects], axis=0)
        centre = 0.5 * (lo + hi)
        radius = max(float(np.linalg.norm(o.vertices - centre, axis=1).max()) for o in objects)
        return cls(centre, radius)


def frame_axes(directions: np.ndarray) -> np.ndarray:
    """(n, 3, 3) float64: per frame direction (n, 3) (towards the viewer) its image's ``right``,
    ``up`` and the direction itself, as :meth:`Camera.look_at` orients a camera looking along
    ``-direction`` (world +z up unless the view is within 8° of vertical, then +y).

    >>> frame_axes(np.array([[1.0, 0.0, 0.0]])).tolist()
    [[[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]]
    """
    d = np.asarray(directions, dtype=np.float64).reshape(-1, 3)
    forward = -d
    hint = np.where(np.abs(forward[:, 2:3]) < 0.99, [0.0, 0.0, 1.0], [0.0, 1.0, 0.0])
    right = np.cross(forward, hint)
    right /= np.linalg.norm(right, axis=1, keepdims=True)
    up = np.cross(right, forward)
    return np.stack([right, up, d], axis=1)


def frame_camera(sphere: Sphere, direction: np.ndarray, resolution: int) -> Camera:
    """The near-orthographic camera of a frame (module docstring)."""
    r = sphere.radius
    eye = sphere.centre + ORTHO_DISTANCE * r * np.asarray(direction, dtype=np.float64)
    fov = 2.0 * math.atan(1.0 / ORTHO_DISTANCE)
    return Camera.look_at(eye, sphere.centre, fov, resolution, (ORTHO_DISTANCE - 1.5) * r, (ORTHO_DISTANCE + 1.5) * r)


@dataclass(frozen=True, slots=True)
class Frames:
    """The recorded frames of one part."""

    colour: np.ndarray  # (k, f, f, 4) uint8 sRGB colour + alpha (0 or 255), top row first
    normal: np.ndarray | None  # (k, f, f, 4) uint8 world normals (encode_normals), alpha = depth byte; None: not kept
    depth_extent: float  # world units: the largest |height| of a covered texel over every frame
    material: np.ndarray | None = (
        None  # (k, f, f, 4) uint8 linear occlusion, roughness, metallic, alpha 255 where covered
    )
    emissive: np.ndarray | None = None  # (k, f, f, 4) uint8 sRGB-encoded linear emission, alpha 255 where covered


def _block_sum(values: np.ndarray, covered: np.ndarray, samples: int) -> np.ndarray:
    """(f, f, c) float64 sums of the covered ``values`` (f*s, f*s, c) over each texel's ``samples``² samples."""
    f = covered.shape[0] // samples
    masked = values.astype(np.float64) * covered[..., None]
    return masked.reshape(f, samples, f, samples, values.shape[-1]).sum(axis=(1, 3))


def _material_texels(material: np.ndarray, covered: np.ndarray, samples: int, emissive: bool):
    """((f, f, 4) uint8 ORM, (f, f, 4) uint8 sRGB emission or None) of one frame's (f*s, f*s, 6)
    material G-buffer: the mean of each texel's covered samples (module docstring)."""
    count = _block_sum(np.ones(covered.shape + (1,)), covered, samples)
    mean = _block_sum(material, covered, samples) / np.maximum(count, 1.0)
    hit = count[..., 0] > 0
    alpha = np.where(hit, 255, 0).astype(np.uint8)[..., None]
    orm = np.concatenate([np.rint(np.clip(mean[..., :3], 0.0, 1.0) * 255.0).astype(np.uint8), alpha], axis=-1)
    if not emissive:
        return orm, None
    light = np.rint(linear_to_srgb(mean[..., 3:6]) * 255.0).astype(np.uint8)
    return orm, np.concatenate([light, alpha], axis=-1)


def record_frames(
    objects,
    sphere: Sphere,
    directions: np.ndarray,
    resolution: int,
    samples: int = 2,
    normals: bool = False,
    materials: bool = False,
    emissive: bool = False,
) -> Frames:
    """Draw the part's ``objects`` in every frame of ``directions`` (k, 3) (module docstring);
    ``materials`` (with ``normals``) keeps the ORM frames, ``emissive`` (with ``materials``) the
    emission frames too."""
    k = directions.shape[0]
    fine = resolution * samples
    materials = bool(materials and normals)
    colour = np.zeros((k, resolution, resolution, 4), np.uint8)
    normal = np.zeros((k, resolution, resolution, 4), np.uint8) if normals else None
    orm = np.zeros((k, resolution, resolution, 4), np.uint8) if materials else None
    light = np.zeros((k, resolution, resolution, 4), np.uint8) if materials and emissive else None
    extent = 0.0
    with MeshRenderer(objects, normals=normals, materials=materials) as renderer:
        for index, direction in enumerate(directions):
            camera = frame_camera(sphere, direction, fine)
            if materials:
                image, world, material = renderer.render_material(camera)
            elif normals:
                image, world = renderer.render_normals(camera)
            else:
                image, world = renderer.render(camera), None
            height = ORTHO_DISTANCE * sphere.radius - renderer.last_depth(camera)
            covered = image[..., 3] > 0
            colour[index] = downsample(image, samples)
            blocks = (resolution, samples, resolution, samples)
            top = np.where(covered, height, -np.inf).reshape(blocks).max(axis=(1, 3))
            hit = np.isfinite(top)
            if hit.any():
                extent = max(extent, float(np.abs(top[hit]).max()))
            if orm is not None:
                texels, emitted = _material_texels(material, covered, samples, light is not None)
                orm[index] = texels
                if light is not None:
                    light[index] = emitted
            if normal is not None:
                summed = _block_sum(world, covered, samples)
                length = np.linalg.norm(summed, axis=-1, keepdims=True)
                unit = np.divide(summed, length, out=np.zeros_like(summed), where=length > 0)
                texels = encode_normals(unit)
                level = np.clip(np.round((top / sphere.radius * 0.5 + 0.5) * DEPTH_LEVELS), 0, DEPTH_LEVELS) + 1
                texels[..., 3] = np.where(hit, level, 0).astype(np.uint8)
                normal[index] = texels
    return Frames(colour, normal, extent, orm, light)


def cell_size(resolution: int, padding: int) -> int:
    """Texels a side of one atlas cell: the frame and ``padding`` on each side.

    >>> cell_size(128, 4)
    136
    """
    return int(resolution) + 2 * int(padding)


def pages_layout(n: int, resolution: int, padding: int, max_page: int) -> tuple[np.ndarray, np.ndarray, list[int]]:
    """Where the ``n * n`` frames go: ((n*n,) int64 page, (n*n, 2) int64 first texel of each frame
    in its page (x right, y down), each page's side).  Frame ``j * n + i`` takes its place in
    frame order, row by row, ``max_page // s`` cells of ``s`` (:func:`cell_size`) a row; a page
    holds as many rows as fit, the last page as many as it needs (square pages).

    >>> page, texel, sides = pages_layout(2, 8, 1, 64)
    >>> page.tolist(), texel.tolist(), sides
    ([0, 0, 0, 0], [[1, 1], [11, 1], [1, 11], [11, 11]], [20])
    >>> page, texel, sides = pages_layout(3, 8, 1, 25)
    >>> page.tolist(), sides
    ([0, 0, 0, 0, 1, 1, 1, 1, 2], [20, 20, 10])
    >>> pages_layout(2, 64, 4, 64)
    Traceback (most recent call last):
    ...
    farfield.core.errors.AtlasOverflowError: a frame of 64 texels with 4 padding needs a cell of 72 texels, more than a page of 64
    """
    s = cell_size(resolution, padding)
    if s > max_page:
        raise AtlasOverflowError(
            f"a frame of {resolution} texels with {padding} padding needs a cell of {s} texels, more than a page of {max_page}"
        )
    across = min(max_page // s, n)
    per_page = across * across
    index = np.arange(n * n, dtype=np.int64)
    page, slot = np.divmod(index, per_page)
    texel = np.stack([slot % across * s + padding, slot // across * s + padding], axis=1)
    sides = []
    for p in range(int(page.max()) + 1):
        count = int((page == p).sum())
        sides.append(s * max(min(count, across), -(-count // across)))
    return page, texel, sides


def compose_atlas(
    frames: np.ndarray,
    page: np.ndarray,
    texel: np.ndarray,
    sides: list[int],
    padding: int,
    mask: np.ndarray | None = None,
) -> tuple[np.ndarray, ...]:
    """The (side, side, 4) uint8 pages of ``frames`` (k, f, f, 4) laid out by :func:`pages_layout`
    (``page``, ``texel``, ``sides``), each frame in its cell of ``s = f + 2 * padding`` with its
    RGB dilated over the whole cell (alpha kept; ``mask`` (k, f, f) bool, default the frames' own
    alpha, says which texels hold a surface).

    >>> f = np.zeros((1, 2, 2, 4), np.uint8); f[0, 0, 0] = (10, 20, 30, 255)
    >>> (out,) = compose_atlas(f, np.zeros(1, int), np.array([[1, 1]]), [4], 1)
    >>> out.shape, int(out[..., 3].sum()) // 255, out[3, 3].tolist()
    ((4, 4, 4), 1, [10, 20, 30, 0])
    """
    k, res = frames.shape[0], frames.shape[1]
    s = cell_size(res, padding)
    pages = [np.zeros((side, side, 4), np.uint8) for side in sides]
    for index in range(k):
        cell = np.zeros((s, s, 4), np.uint8)
        cell[padding : padding + res, padding : padding + res] = frames[index]
        covered = np.zeros((s, s), bool)
        covered[padding : padding + res, padding : padding + res] = (
            frames[index][..., 3] > 0 if mask is None else mask[index]
        )
        alpha = cell[..., 3].copy()
        cell[..., 3] = np.where(covered, 255, 0)
        cell = fill_nearest_rgb(cell)
        cell[..., 3] = alpha
        x, y = texel[index] - padding
        pages[int(page[index])][y : y + s, x : x + s] = cell
    return tuple(pages)


def closed(objects) -> bool:
    """Whether every object is a closed surface drawn whole (watertight once its vertices are
    merged, no alpha cut): then along any line the surfaces alternate entering and leaving solid.

    >>> from farfield.core.procedural import box_object
    >>> closed([box_object("b", [0, 0, 0], [1, 1, 1])])
    True
    """
    import trimesh

    return all(obj.alpha_cutoff is None and trimesh.Trimesh(obj.vertices, obj.faces).is_watertight for obj in objects)


def internal_gap(objects, sphere: Sphere, directions: np.ndarray, resolution: int) -> float:
    """World units: the longest stretch, along the lines of the frames of ``directions`` (k, 3) at
    ``resolution`` rays a side, between two consecutive surfaces of the part with nothing solid in
    between (:func:`farfield.core.render.peeling.peel`): every surface gap, or for a part of
    :func:`closed` objects only the gaps outside its solids (from an exit to the next entry; where
    solids overlap, a stretch inside both may count too, never the other way round).  A point of a
    frame pair's column (docs/techniques/octahedral.md) is within half of it of the part, along the
    line.  0 where no line meets two surfaces with a gap."""
    from farfield.core.render.peeling import peel

    solid = closed(objects)
    gap = 0.0
    for direction in directions:
        camera = frame_camera(sphere, direction, resolution)
        hits, _ = peel(objects, camera, max_layers=1024)
        depth = hits[..., 0]  # (layers, h, w) eye depth, NaN past a ray's last surface
        if depth.shape[0] < 2:
            continue
        spans = np.diff(depth, axis=0)
        if solid:
            spans = spans[1::2]  # exit -> next entry
        if np.isfinite(spans).any():
            gap = max(gap, float(np.nanmax(spans)))
    return gap

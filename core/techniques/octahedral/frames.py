"""Octahedral frames: a part drawn orthographically from each direction of the frame grid, into
one atlas page (H, W, 4) uint8 of ``n x n`` cells (and, with normals, a parallel normal page).

Frame ``k`` looks along ``-directions[k]`` at the part's bounding sphere (centre ``c``, radius
``r``); its image spans ``[-r, r]`` on its ``right`` and ``up`` axes (:func:`frame_axes`, the
orientation :meth:`farfield.core.render.raster.Camera.look_at` gives a camera looking that way),
``frame_resolution`` texels a side, top row first.  It is drawn by the evaluation's own
:class:`~farfield.core.render.raster.MeshRenderer` through a perspective camera
:data:`ORTHO_DISTANCE` radii away, whose magnification varies by ``±1 / ORTHO_DISTANCE`` over the
sphere's depth (0.06 texel at the edge of a 128-texel frame): orthographic for every purpose here.

Recording is exactly conservative, as the layered recording is (seed 000 §3.3.2): besides the
frame's image, each frame is recorded as one slab of the layer recording
(:func:`farfield.core.layering.recording.iter_views`, :func:`frame_plan`), whose fragment shader
(``slab.frag``) writes a texel exactly where the texel's closed square meets a triangle (and, for
an alpha-cut material, where a point of the triangle under it may pass the cut), so a twig of any
width is kept, at most one texel too wide.  The image is drawn with ``samples x samples`` samples
per texel, which only antialias: a texel a sample covers takes their colour, the mean of the
covered ones in linear light (:func:`farfield.core.quality.evaluation.downsample`), and their
normal and depth; a texel only the exact test covers (a feature between the samples) takes the
slab's, the triangle's at the point nearest the texel's centre (the slab is drawn after the
samples, skipping the texels they cover: ``skip_known``).  A texel's depth is the nearest of
its covered samples' (or the slab's), stored as the height above the card plane through ``c``
along the frame's direction, ``h in [-r, r]``, in the normal page's alpha:
``round((h / r * 0.5 + 0.5) * 254) + 1`` (0: nothing there); the slab spans ``255`` such steps from
the sphere's near side (:func:`frame_plan`), so its 8-bit depth ``g`` is the level ``255 - g``.

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
from contextlib import closing
from dataclasses import dataclass, replace

import numpy as np

from farfield.core.colour_space import linear_to_srgb
from farfield.core.errors import AtlasOverflowError
from farfield.core.impostor.impostor import encode_normals
from farfield.core.layering.atlas import fill_nearest_rgb
from farfield.core.layering.recording import iter_views
from farfield.core.quality.evaluation import downsample
from farfield.core.render.raster import Camera, MeshRenderer

# The frames' camera stands this many bounding radii from the centre (module docstring).
ORTHO_DISTANCE = 1000.0
# A depth byte: 0 = no surface; 1..255 = height -r..r above the card plane.
DEPTH_LEVELS = 254
# Slabs across the sphere that bound the columns of texels only the exact test covers (column_gap).
GAP_SLABS = 127


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
class CameraPlan:
    """A camera's view as one slab of the layer recording (what
    :func:`farfield.core.layering.recording.iter_views` records): eye depths ``borders`` (2,)."""

    reference_viewpoint: np.ndarray  # (3,) float64 world: the eye
    axis: np.ndarray  # (3,) forward
    u: np.ndarray  # (3,) image x (right)
    v: np.ndarray  # (3,) image y (up)
    borders: np.ndarray  # (2,) float64 near, far eye depth
    frustum_half_tangents: np.ndarray  # (2,) float64
    texture_resolution: np.ndarray  # (2,) int64
    reference_offset: float = 0.0
    count: int = 1
    known: np.ndarray | None = None  # (h, w) bool, row 0 the bottom row: texels iter_views(skip_known=True) leaves out

    @classmethod
    def of_camera(cls, camera: Camera, near: float | None = None, far: float | None = None) -> CameraPlan:
        """The slab ``near``..``far`` (default the camera's) of ``camera`` (square, on axis)."""
        half = math.tan(0.5 * camera.fov)
        borders = np.array([camera.near if near is None else near, camera.far if far is None else far], np.float64)
        res = np.array([camera.resolution, camera.resolution], np.int64)
        return cls(camera.eye, camera.forward, camera.right, camera.up, borders, np.array([half, half]), res)


def frame_plan(sphere: Sphere, direction: np.ndarray, resolution: int) -> CameraPlan:
    """Frame ``direction``'s slab (module docstring): from the sphere's near side ``255`` depth
    steps of ``2 r / 254``, so that 8-bit depth ``g`` in it is height ``r - 2 r g / 254``.

    >>> p = frame_plan(Sphere(np.zeros(3), 1.0), np.array([0.0, 0.0, 1.0]), 16)
    >>> (p.borders - ORTHO_DISTANCE).round(6).tolist(), p.axis.tolist()
    ([-1.0, 1.007874], [0.0, 0.0, -1.0])
    """
    r = sphere.radius
    near = (ORTHO_DISTANCE - 1.0) * r
    far = near + 2.0 * r * (DEPTH_LEVELS + 1) / DEPTH_LEVELS
    return CameraPlan.of_camera(frame_camera(sphere, direction, resolution), near, far)


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
    exact_only: np.ndarray | None = None  # (k, f, f) bool: texels the exact test covers and no sample does


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
    exact: bool = True,
) -> Frames:
    """Draw the part's ``objects`` in every frame of ``directions`` (k, 3) (module docstring);
    ``materials`` (with ``normals``) keeps the ORM frames, ``emissive`` (with ``materials``) the
    emission frames too; ``exact=False`` keeps only the texels a sample covers (no slab pass)."""
    k = directions.shape[0]
    fine = resolution * samples
    materials = bool(materials and normals)
    colour = np.zeros((k, resolution, resolution, 4), np.uint8)
    normal = np.zeros((k, resolution, resolution, 4), np.uint8) if normals else None
    orm = np.zeros((k, resolution, resolution, 4), np.uint8) if materials else None
    light = np.zeros((k, resolution, resolution, 4), np.uint8) if materials and emissive else None
    exact_only = np.zeros((k, resolution, resolution), bool)
    extent = 0.0
    r = sphere.radius
    shown = np.zeros((resolution, resolution), bool)  # the frame's texels a sample covers, set below

    def plans():  # drawn lazily, each after its frame's samples: their texels are skipped
        for direction in directions:
            yield replace(frame_plan(sphere, direction, resolution), known=shown[::-1].copy())

    exact_frames = (
        iter_views(objects, plans(), normals=True, depth=True, material=materials, cull=True, skip_known=True)
        if exact
        else _no_slabs(len(directions), resolution, 16 if materials else 8)
    )
    with MeshRenderer(objects, normals=normals, materials=materials) as renderer, closing(exact_frames):
        for index, direction in enumerate(directions):
            camera = frame_camera(sphere, direction, fine)
            if materials:
                image, world, material = renderer.render_material(camera)
            elif normals:
                image, world = renderer.render_normals(camera)
            else:
                image, world = renderer.render(camera), None
            height = ORTHO_DISTANCE * r - renderer.last_depth(camera)
            covered = image[..., 3] > 0
            sampled = downsample(image, samples)
            shown[:] = sampled[..., 3] > 0  # a sample covers it: the samples' colour, normal and depth
            _, _, layer, _ = next(exact_frames)
            exact = layer[::-1]  # top row first: colour, normal + depth, ORM, emission (iter_views)
            missed = (exact[..., 3] > 0) & ~shown  # between the samples: the exact slab's
            exact_only[index] = missed
            colour[index] = np.where(shown[..., None], sampled, np.where(missed[..., None], exact[..., :4], 0))
            blocks = (resolution, samples, resolution, samples)
            top = np.where(covered, height, -np.inf).reshape(blocks).max(axis=(1, 3))
            top = np.where(missed, r - 2.0 * r * exact[..., 7] / DEPTH_LEVELS, top)
            hit = np.isfinite(top)
            if hit.any():
                extent = max(extent, float(np.abs(top[hit]).max()))
            if orm is not None:
                texels, emitted = _material_texels(material, covered, samples, light is not None)
                orm[index] = np.where(missed[..., None], exact[..., 8:12], texels)
                if light is not None:
                    light[index] = np.where(missed[..., None], exact[..., 12:16], emitted)
            if normal is not None:
                summed = _block_sum(world, covered, samples)
                length = np.linalg.norm(summed, axis=-1, keepdims=True)
                unit = np.divide(summed, length, out=np.zeros_like(summed), where=length > 0)
                texels = np.where(missed[..., None], exact[..., 4:8], encode_normals(unit))
                level = np.clip(np.round((top / r * 0.5 + 0.5) * DEPTH_LEVELS), 0, DEPTH_LEVELS) + 1
                texels[..., 3] = np.where(hit, level, 0).astype(np.uint8)
                normal[index] = texels
    return Frames(colour, normal, extent, orm, light, exact_only)


def _no_slabs(count: int, resolution: int, channels: int):
    """What :func:`iter_views` yields for ``count`` views when no slab pass runs: empty layers."""
    empty = np.zeros((resolution, resolution, channels), np.uint8)
    for view in range(count):
        yield view, 0, empty, None


def column_gap(objects, sphere: Sphere, directions: np.ndarray, resolution: int, frames: Frames, pairs) -> float:
    """World units: a gap that bounds, along the line, how far a point of a frame pair's column
    lies from the part, at the texels of the frame pairs ``pairs`` ((k, opposite k) indices into
    ``directions`` and ``frames``) that the exact test alone covers in either frame
    (:attr:`Frames.exact_only`: a feature between the samples, which the lines
    :func:`internal_gap` peels pass by).  Each such pair's frame ``k`` is recorded again as
    :data:`GAP_SLABS` slabs of ``δ = 2r / GAP_SLABS`` across the sphere (every triangle, both
    sides), each exactly conservative: a texel of a slab is covered where the part meets the
    slab's part of the texel's column.  A point of the column in slab ``i`` lies within
    ``(j + 1) δ`` of the part along the line (and within the texel across it), ``j`` the slabs to
    the nearest covered one, so the gap is twice the largest such distance over the column's slabs,
    or the column's length where shorter (its ends are points of the part): at most ``2r``, the
    bound :func:`~farfield.core.techniques.octahedral.estimate.estimate_octahedral` assumes.  For a
    missed texel of one convex solid (every slab of its column covered): ``2δ`` at most.  0 without
    depth or such texels.

    The opposite frame's texel grid mirrors this one's across its vertical middle line (its
    ``right`` axis is reversed, its ``up`` the same: :func:`frame_axes`).
    """
    if frames.normal is None or frames.exact_only is None:
        return 0.0
    r, f = sphere.radius, resolution
    step = 2.0 * r / GAP_SLABS
    chosen = []
    for k, o in pairs:
        only = (frames.exact_only[k] | frames.exact_only[o, :, ::-1]) & (frames.normal[k, ..., 3] > 0)
        if only.any():
            chosen.append((k, o, only))
    if not chosen:
        return 0.0
    plans = []
    for k, _, _ in chosen:
        plan = frame_plan(sphere, directions[k], f)
        near = plan.borders[0]
        plans.append(replace(plan, borders=near + step * np.arange(GAP_SLABS + 1), count=GAP_SLABS))
    occupied = np.zeros((GAP_SLABS, f, f), bool)
    gap = 0.0
    slab = np.arange(GAP_SLABS, dtype=np.float64)[:, None]
    with closing(iter_views(objects, plans)) as views:
        for view, i, layer, _ in views:
            occupied[i] = layer[::-1, :, 3] > 0
            if i + 1 < GAP_SLABS:
                continue
            k, o, only = chosen[view]
            # Slabs from each slab to the nearest occupied one, down the column and up it.
            far = float(GAP_SLABS)
            down, up = np.full((f, f), far), np.full((f, f), far)
            to_near, to_far = np.empty((GAP_SLABS, f, f)), np.empty((GAP_SLABS, f, f))
            for j in range(GAP_SLABS):
                down = np.where(occupied[j], 0.0, down + 1.0)
                to_near[j] = down
                up = np.where(occupied[GAP_SLABS - 1 - j], 0.0, up + 1.0)
                to_far[GAP_SLABS - 1 - j] = up
            nearest = np.minimum(to_near, to_far)[:, only]  # (slabs, texels)
            top = ((frames.normal[k, ..., 3][only] - 1.0) / DEPTH_LEVELS * 2.0 - 1.0) * r
            bottom = -((frames.normal[o, :, ::-1, 3][only] - 1.0) / DEPTH_LEVELS * 2.0 - 1.0) * r
            # Slab j spans heights r - (j + 1) δ .. r - j δ: those the column [bottom, top] meets.
            inside = (slab * step <= r - bottom) & ((slab + 1.0) * step >= r - top)
            worst = np.where(inside, nearest, 0.0).max(axis=0)
            # The column's ends are points of the part: no point of it is farther than half its length.
            gap = max(gap, float(np.minimum(2.0 * step * (worst + 1.0), np.maximum(top - bottom, 0.0)).max()))
    return gap


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

"""The ``"octahedral"`` payload: a frame grid over one atlas page, drawn as one camera-facing card.

Arrays (:class:`OctahedralPayload`):

``axes`` (k, 3, 3) float64
    Per frame (``k = n * n``, frame ``j * n + i`` at grid point ``(i, j)``,
    :mod:`farfield.core.techniques.octahedral.mapping`) its image's ``right`` and ``up`` and its
    direction (from the part towards the viewer), world unit vectors.
``texel`` (k, 2) int64
    The frame's first (top-left) texel in its atlas page (x right, y down).
``page`` (k,) int64
    Its atlas page (0: one page today).
``sphere`` (4,) float64
    The part's bounding sphere: centre x, y, z and radius, world units; every frame spans
    ``[-radius, radius]`` on its right and up axes.
``grid`` (5,) int64
    ``n`` (frames per side), ``frame_resolution`` (texels a side), ``padding`` (texels around each
    frame in its cell), ``hemisphere`` (1: the hemi-octahedral map), ``depth`` (1: the normal
    page's alpha holds each texel's height, :mod:`farfield.core.techniques.octahedral.frames`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np

from farfield.core.errors import BundleFormatError
from farfield.core.impostor.glb import OCTAHEDRAL_EXTENSION  # on the fallback card's primitive, used, never required
from farfield.core.impostor.impostor import (
    PAYLOAD_KINDS,
    Impostor,
    QuadPayload,
    _canonical,
    _check_arrays,
    _PayloadBase,
    register_payload_kind,
)
from farfield.core.techniques.octahedral.frames import cell_size


@dataclass(frozen=True, slots=True)
class OctahedralPayload(_PayloadBase):
    """A frame grid (module docstring).

    >>> p = OctahedralPayload.empty()
    >>> p.kind, p.counts(), p.triangle_count, list(p.arrays())
    ('octahedral', {'frames': 0}, 0, ['axes', 'texel', 'page', 'sphere', 'grid'])
    """

    axes: np.ndarray  # (k, 3, 3) float64 right, up, direction per frame
    texel: np.ndarray  # (k, 2) int64 first texel of each frame in its page
    page: np.ndarray  # (k,) int64 atlas page of each frame
    sphere: np.ndarray  # (4,) float64 centre, radius
    grid: np.ndarray  # (5,) int64 n, frame_resolution, padding, hemisphere, depth

    kind: ClassVar[str] = "octahedral"
    ARRAYS: ClassVar[tuple] = (
        ("axes", "f", ("k", 3, 3)),
        ("texel", "i", ("k", 2)),
        ("page", "i", ("k",)),
        ("sphere", "f", (4,)),
        ("grid", "i", (5,)),
    )

    def __post_init__(self) -> None:
        for name, _, _ in self.ARRAYS:
            object.__setattr__(self, name, _canonical(getattr(self, name)))

    @classmethod
    def empty(cls) -> OctahedralPayload:
        """A payload of no frames (nothing drawn), as every kind's ``empty()``."""
        return cls(np.zeros((0, 3, 3)), np.zeros((0, 2), np.int64), np.zeros(0, np.int64), np.array([0.0, 0.0, 0.0, 1.0]),
                   np.zeros(5, np.int64))  # fmt: skip

    @property
    def n(self) -> int:
        return int(self.grid[0])

    @property
    def frame_resolution(self) -> int:
        return int(self.grid[1])

    @property
    def padding(self) -> int:
        return int(self.grid[2])

    @property
    def hemisphere(self) -> bool:
        return bool(self.grid[3])

    @property
    def depth(self) -> bool:
        return bool(self.grid[4])

    @property
    def centre(self) -> np.ndarray:
        return self.sphere[:3]

    @property
    def radius(self) -> float:
        return float(self.sphere[3])

    @property
    def count(self) -> int:
        """Frames."""
        return int(self.axes.shape[0])

    @property
    def triangle_count(self) -> int:
        """Triangles drawn: one card of two (none without frames)."""
        return 2 if self.count else 0

    def counts(self) -> dict[str, int]:
        return {"frames": self.count}

    def world_points(self) -> np.ndarray:
        """(8, 3) float64 the corners of the cube around the bounding sphere, world units."""
        signs = np.array([[x, y, z] for z in (-1, 1) for y in (-1, 1) for x in (-1, 1)], dtype=np.float64)
        return self.centre + self.radius * signs

    def check(self, page_count: int) -> None:
        """Raise :class:`BundleFormatError` unless the arrays fit and agree with ``grid``."""
        _check_arrays(self, page_count)
        n, res, pad, hemi, depth = (int(v) for v in self.grid)
        if n < 2 or res < 1 or pad < 0 or hemi not in (0, 1) or depth not in (0, 1) or self.count != n * n:
            raise BundleFormatError(f"octahedral payload: grid {self.grid.tolist()} does not fit {self.count} frames")
        if not self.radius > 0.0:
            raise BundleFormatError(f"octahedral payload: radius must be > 0, got {self.radius}")
        if not np.allclose(np.einsum("kab,kcb->kac", self.axes, self.axes), np.eye(3), atol=1e-6):
            raise BundleFormatError("octahedral payload: each frame's axes must be orthonormal")

    def check_pages(self, pages: tuple[np.ndarray, ...]) -> None:
        """Every frame's cell lies on its page."""
        s = cell_size(self.frame_resolution, self.padding)
        for index, page in enumerate(pages):
            mine = self.texel[self.page == index]
            if mine.size and (
                mine.min() < self.padding or (mine.max(axis=0) - self.padding + s > page.shape[1::-1]).any()
            ):
                raise BundleFormatError(f"octahedral payload: a frame's cell lies outside page {index} {page.shape}")

    def card(self, frame: int, page_size: tuple[int, int], page: int = 0) -> QuadPayload:
        """Frame ``frame`` as one quad through the centre, facing its direction, textured with its
        texel rectangle of its page (``page_size``: (width, height)), page index ``page``: what a
        viewer without the runtime draws (the GLB's fallback)."""
        right, up, _ = self.axes[frame]
        c, r = self.centre, self.radius
        corners = np.array(
            [c - r * right + r * up, c + r * right + r * up, c + r * right - r * up, c - r * right - r * up]
        )
        w, h = page_size
        x0, y0 = self.texel[frame].astype(np.float64)
        x1, y1 = x0 + self.frame_resolution, y0 + self.frame_resolution
        uv = np.array([[x0 / w, y0 / h], [x1 / w, y0 / h], [x1 / w, y1 / h], [x0 / w, y1 / h]])
        return QuadPayload(corners[None], uv[None], np.full(1, page, np.int64), np.zeros(1, np.int64))

    def nearest_frame(self, direction) -> int:
        """The frame whose direction is nearest ``direction`` (3,)."""
        d = np.asarray(direction, dtype=np.float64)
        return int(np.argmax(self.axes[:, 2] @ (d / np.linalg.norm(d))))

    def fallback(self, impostor: Impostor) -> Impostor:
        """What a glTF viewer without the runtime draws, as an impostor of its own: the frame nearest
        the reference viewpoint's direction as one card (:meth:`card`) over its page (and its
        normal page), a quad payload; what the GLB holds."""
        from dataclasses import replace

        frame = self.nearest_frame(np.asarray(impostor.reference_viewpoint) - self.centre)
        index = int(self.page[frame])
        pages = impostor.pages[index : index + 1]
        channels = {name: pages_[index : index + 1] for name, pages_ in impostor.channels.items()}
        return replace(impostor, pages=pages, payload=self.card(frame, pages[0].shape[1::-1]), channels=channels)

    def glb_parts(self, impostor: Impostor, glb) -> Any:
        """The fallback a glTF viewer draws (:meth:`fallback`: one card, lit with the normal page
        where kept) over every page, its primitive carrying the frame grid for a runtime that blends
        (:data:`OCTAHEDRAL_EXTENSION`, :func:`octahedral_extension`)."""
        from dataclasses import replace

        frame = self.nearest_frame(np.asarray(impostor.reference_viewpoint) - self.centre)
        page = int(self.page[frame])
        card = self.card(frame, impostor.pages[page].shape[1::-1], page)
        parts = card.glb_parts(replace(impostor, payload=card), glb)
        return octahedral_extension(self, impostor, glb, parts)

    def renderer(self, impostor: Impostor):
        """The reference runtime: :class:`farfield.core.techniques.octahedral.runtime.OctahedralRenderer`."""
        from farfield.core.techniques.octahedral.runtime import OctahedralRenderer

        return OctahedralRenderer(impostor)

    def gbuffer(self, impostor: Impostor, normals: bool = True):
        """The runtime as a G-buffer (:meth:`OctahedralRenderer.render_normals
        <farfield.core.techniques.octahedral.runtime.OctahedralRenderer.render_normals>`): the
        three frames' normals blended as their colours are, where ``normals`` and the impostor keeps
        them, else the card's, facing the eye; a material G-buffer (``render_material``, their
        material and emissive pages blended alike) where the impostor keeps the material channel."""
        from farfield.core.techniques.octahedral.runtime import OctahedralRenderer

        return OctahedralRenderer(impostor, gbuffer=True, normal_pages=normals)


# glTF enums (spec, "accessor.componentType").
_UNSIGNED_SHORT, _FLOAT = 5123, 5126
# The GLB's image names (core/impostor/glb.py) -> the extension's page sets: the colour pages are
# the fallback's base-colour textures, the material and emissive pages (where kept) its own.
_PAGE_SETS = (("atlas-", "colour"), ("material-", "material"), ("emissive-", "emissive"))


def _accessor(glb, values: np.ndarray, dtype: str, component: int, kind: str) -> int:
    """A glTF accessor of ``values`` (count rows of ``kind``) in the GLB's BIN chunk; its index."""
    view = glb.binary.add(np.ascontiguousarray(values, dtype=dtype).tobytes())
    glb.accessors.append({"bufferView": view, "componentType": component, "count": int(values.shape[0]), "type": kind})
    return len(glb.accessors) - 1


def octahedral_extension(payload: OctahedralPayload, impostor: Impostor, glb, parts):
    """``parts`` (the fallback card's :class:`farfield.core.impostor.glb.GlbParts` over every page)
    with the frame grid as :data:`OCTAHEDRAL_EXTENSION` on the card's primitive (as ``FARFIELD_point_appearance``: the validator warns of an unlit material with another extension):
    the grid's figures, the sphere in the node's frame, per frame its axes (``MAT3`` float32, columns
    right, up, direction), first texel (``VEC2`` uint16) and page (``SCALAR`` uint16) as accessors,
    and the texture indices of each page set (textures are the images, one to one): ``colour``,
    ``material``, ``emissive`` as the fallback's images, and ``normal``, the raw normal pages (world
    normals ``n * 0.5 + 0.5``, alpha the depth byte with depth), added here, as the fallback's
    normal textures are tangent-space."""
    from farfield.core.impostor.glb import GlbParts

    images = list(parts.images)
    sets: dict[str, list[int]] = {}
    for prefix, name in _PAGE_SETS:
        found = [index for index, image in enumerate(images) if image.get("name", "").startswith(prefix)]
        if found:
            sets[name] = found
    if "normal" in impostor.channels:
        first = len(images)
        images += [
            {"bufferView": glb.binary.add(data), "mimeType": "image/png", "name": f"frames-normal-{i:03d}"}
            for i, data in enumerate(glb.pngs.encode(impostor.channels["normal"]))
        ]
        sets["normal"] = list(range(first, len(images)))
    extension = {
        "grid": payload.n,
        "hemisphere": payload.hemisphere,
        "frameResolution": payload.frame_resolution,
        "padding": payload.padding,
        "depth": payload.depth and "normal" in impostor.channels,
        "centre": [float(x) for x in payload.centre - glb.viewpoint],
        "radius": payload.radius,
        "frames": {
            "axes": _accessor(glb, payload.axes.reshape(-1, 9), "<f4", _FLOAT, "MAT3"),
            "texels": _accessor(glb, payload.texel, "<u2", _UNSIGNED_SHORT, "VEC2"),
            "pages": _accessor(glb, payload.page, "<u2", _UNSIGNED_SHORT, "SCALAR"),
        },
        "pages": sets,
    }
    primitives = [dict(p) for p in parts.primitives]  # one: the card's
    for primitive in primitives:
        primitive["extensions"] = {**primitive.get("extensions", {}), OCTAHEDRAL_EXTENSION: extension}
    return GlbParts(primitives, parts.materials, images, (*parts.extensions, OCTAHEDRAL_EXTENSION))


if OctahedralPayload.kind not in PAYLOAD_KINDS:
    register_payload_kind(OctahedralPayload)

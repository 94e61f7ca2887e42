"""A layered depth image stored as atlas pages (seed 004 §6 stored its LDIs gzip'd): two pages per layer.

Page ``2k`` is layer ``k``'s colour: (n, n, 4) sRGB bytes, alpha 255 where the layer has a sample
and 0 elsewhere.  Page ``2k + 1`` is its depth: each texel's four bytes are the sample's float32
eye depth along the LDI's forward axis, little-endian, and zero where there is no sample.  The
bundle stores pages as PNG, so both are compressed losslessly.  The payload
(:class:`farfield.core.impostor.impostor.LdiPayload`) holds the LDI's camera.

With normals (``channels="albedo+normal"``) the impostor's ``normal`` channel
(:attr:`farfield.core.impostor.impostor.Impostor.channels`) holds pages parallel to these
(:func:`normal_pages`): page ``2k`` layer ``k``'s samples' world normals, encoded n * 0.5 + 0.5 with
alpha 255 where the layer has a sample (as the colour page's alpha), page ``2k + 1`` empty (all
zero: a depth page has no normals of its own; it stays for the channel's pages to pair with the
colour pages one to one).

For standard viewers the GLB holds only the first layer, as one textured quad in the LDI's image
plane (:func:`preview_quad`).  That is a billboard, right from the LDI's centre of projection and
flat from anywhere else.  The splatted LDI is what farfield's drawer shows.
"""

from __future__ import annotations

import math

import numpy as np

from farfield.core.impostor.impostor import Impostor, LdiPayload, encode_normals
from farfield.core.ldi.image import LayeredDepthImage
from farfield.core.render.raster import Camera
from farfield.core.scene import SceneObject


def ldi_payload_and_pages(ldi: LayeredDepthImage) -> tuple[LdiPayload, tuple[np.ndarray, ...]]:
    """The payload (camera, layer and sample counts, image quad) and pages of ``ldi``."""
    cam = ldi.camera
    pages = []
    for k in range(ldi.layers):
        present = np.isfinite(ldi.depth[k])
        colour = np.where(present[..., None], ldi.colour[k], 0).astype(np.uint8)
        colour[..., 3] = np.where(present, 255, 0)
        depth = np.where(present, ldi.depth[k], 0.0).astype("<f4")
        pages += [np.ascontiguousarray(colour), np.ascontiguousarray(depth.view(np.uint8).reshape(depth.shape + (4,)))]
    payload = LdiPayload(
        cam.eye, np.stack([cam.right, cam.up, cam.forward]), np.array([math.tan(0.5 * cam.fov), cam.offset[0], cam.offset[1], cam.near, cam.far]),
        np.array([cam.resolution, ldi.layers, ldi.count]), image_quad(cam),
    )  # fmt: skip
    return payload, tuple(pages)


def normal_pages(ldi: LayeredDepthImage, normals: np.ndarray) -> tuple[np.ndarray, ...]:
    """The ``normal`` channel's pages (module docstring) of ``ldi`` whose samples (in the order of
    :meth:`~farfield.core.ldi.image.LayeredDepthImage.samples`) have unit world ``normals`` (m, 3)."""
    present = np.isfinite(ldi.depth)
    encoded = np.zeros(ldi.depth.shape + (4,), np.uint8)
    encoded[present] = encode_normals(normals)  # argwhere's order: layer, row, column, as samples()
    empty = np.zeros(ldi.depth.shape[1:] + (4,), np.uint8)
    return tuple(page for k in range(ldi.layers) for page in (np.ascontiguousarray(encoded[k]), empty.copy()))


def sample_pages(ldi: LayeredDepthImage, values: np.ndarray) -> tuple[np.ndarray, ...]:
    """A channel's pages laid out as :func:`normal_pages` (layer ``k``'s on page ``2k``, an empty page
    after it) of ``ldi`` whose samples (in the order of :meth:`~farfield.core.ldi.image.LayeredDepthImage.samples`)
    have the (m, 4) uint8 ``values`` (the material and emissive channels, :mod:`farfield.core.ldi.materials`)."""
    present = np.isfinite(ldi.depth)
    encoded = np.zeros(ldi.depth.shape + (4,), np.uint8)
    encoded[present] = values
    empty = np.zeros(ldi.depth.shape[1:] + (4,), np.uint8)
    return tuple(page for k in range(ldi.layers) for page in (np.ascontiguousarray(encoded[k]), empty.copy()))


def image_quad(camera: Camera) -> np.ndarray:
    """(4, 3) world corners of the LDI's window on its near plane: top-left, top-right, bottom-right,
    bottom-left as seen from its eye."""
    t = math.tan(0.5 * camera.fov)
    ox, oy = camera.offset
    d = camera.near
    return np.stack(
        [
            camera.eye + d * (camera.forward + (ox + a) * camera.right + (oy + b) * camera.up)
            for a, b in ((-t, t), (t, t), (t, -t), (-t, -t))
        ]
    )


def preview_quad(impostor: Impostor) -> tuple[np.ndarray, np.ndarray]:
    """((4, 3) corners, (4, 2) glTF UVs) of the GLB's fallback quad: the first layer's colour page on
    the LDI's window (module docstring)."""
    return np.asarray(impostor.payload.quad), np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def preview_objects(impostor: Impostor) -> list[SceneObject]:
    """The fallback quad as a drawable object, alpha-cut at 0.5 as the GLB asks (what a standard viewer shows)."""
    corners, uv = preview_quad(impostor)
    uv = uv.copy()
    uv[:, 1] = 1.0 - uv[:, 1]  # glTF (top-left origin) -> scene convention (bottom-left)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    return [SceneObject("ldi-preview", corners, faces, uv=uv, texture=impostor.pages[0], alpha_cutoff=0.5)]

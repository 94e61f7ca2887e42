"""sRGB and linear colour values: the two transfer functions, on arrays of any shape in 0..1.

farfield draws in linear light and stores sRGB, as glTF 2.0 prescribes (§3.9.2, "Metallic-Roughness
Material": ``baseColorFactor`` and ``COLOR_0`` are linear, ``baseColorTexture`` is sRGB-encoded):

* :class:`farfield.core.scene.SceneObject` holds ``base_color`` **linear** (a glTF factor as it is; an
  OBJ/MTL ``Kd``, a PLY or face colour decoded from sRGB, the way those formats are authored and
  shown), ``vertex_colors`` and ``texture`` **sRGB-encoded** uint8 (a glTF ``COLOR_0`` is encoded
  on load with :data:`LINEAR_TO_SRGB_U8`);
* the shaders (``core/render/shaders/colour.glsl``) decode texture and vertex colours, multiply in
  linear light, filter in linear light (sRGB textures) and encode what they write, so atlas pages
  are sRGB, as glTF requires of a ``baseColorTexture``.

The functions are IEC 61966-2-1's piecewise curves (the ones the GL ``SRGB8_ALPHA8`` format uses).
"""

from __future__ import annotations

import numpy as np


def srgb_to_linear(value):
    """Linear values (float64) of sRGB-encoded ``value`` in 0..1.

    >>> round(float(srgb_to_linear(0.5)), 4), float(srgb_to_linear(1.0))
    (0.214, 1.0)
    """
    v = np.asarray(value, dtype=np.float64)
    return np.where(v <= 0.04045, v / 12.92, ((v + 0.055) / 1.055) ** 2.4)


def linear_to_srgb(value):
    """sRGB-encoded values (float64) of linear ``value`` in 0..1.

    >>> round(float(linear_to_srgb(0.502)) * 255, 1), float(linear_to_srgb(0.0))
    (187.9, 0.0)
    """
    v = np.clip(np.asarray(value, dtype=np.float64), 0.0, 1.0)
    return np.where(v <= 0.0031308, v * 12.92, 1.055 * v ** (1.0 / 2.4) - 0.055)


# uint8 linear -> uint8 sRGB, rounded (a glTF COLOR_0 stored or read as normalized bytes).
LINEAR_TO_SRGB_U8 = np.round(linear_to_srgb(np.arange(256) / 255.0) * 255.0).astype(np.uint8)


def encode_rgba_u8(linear_rgba: np.ndarray) -> np.ndarray:
    """(..., 4) uint8 of (..., 4) uint8 linear RGBA: RGB sRGB-encoded, alpha (always linear) kept.

    >>> encode_rgba_u8(np.array([[128, 64, 200, 255]], dtype=np.uint8)).tolist()
    [[188, 137, 229, 255]]
    """
    out = np.array(linear_rgba, dtype=np.uint8, copy=True)
    out[..., :3] = LINEAR_TO_SRGB_U8[out[..., :3]]
    return out

"""The six faces of an axis-aligned cube, named as the CLI and the API name them (seed 002's cube
of layers around a view cell): each face's axis index and sign, in one canonical order."""

from __future__ import annotations

import numpy as np

# name -> (axis index, sign); the dict's order is the canonical order of faces everywhere.
FACES: dict[str, tuple[int, int]] = {
    "+x": (0, 1),
    "-x": (0, -1),
    "+y": (1, 1),
    "-y": (1, -1),
    "+z": (2, 1),
    "-z": (2, -1),
}


def face_normal(name: str) -> np.ndarray:
    """(3,) float64 outward unit normal of face ``name``.

    >>> face_normal("-y").tolist()
    [0.0, -1.0, 0.0]
    """
    axis, sign = FACES[name]
    normal = np.zeros(3)
    normal[axis] = sign
    return normal

"""PLY vertex colours are read by their declared type (issue 54): trimesh truncated ``ushort``
colours to their low byte (32768 became 0), which the three.js check of ``tests/test_threejs.py``
found; uchar, ushort, short and float colours of the same values load alike, ASCII and binary."""

from __future__ import annotations

import numpy as np
import pytest

from farfield.core.exchange import load_scene_bytes

UNIT = np.array([[1.0, 0.5, 0.0], [0.0, 0.25, 1.0], [0.2, 0.9, 0.4]])
EXPECTED = np.round(UNIT * 255).astype(int)


def _ply(kind: str, form: str) -> bytes:
    top = {"uchar": 255, "ushort": 65535, "short": 32767, "float": 1.0}[kind]
    values = UNIT * top if kind == "float" else np.round(UNIT * top)
    header = [
        "ply",
        f"format {form} 1.0",
        "element vertex 3",
        "property float x",
        "property float y",
        "property float z",
    ]
    header += [f"property {kind} {c}" for c in ("red", "green", "blue")]
    header += ["element face 1", "property list uchar int vertex_indices", "end_header"]
    points = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
    if form == "ascii":
        rows = [" ".join(f"{v:g}" for v in (*p, *c)) for p, c in zip(points, values)]
        return ("\n".join(header + rows + ["3 0 1 2"]) + "\n").encode()
    code = {"uchar": "u1", "ushort": "<u2", "short": "<i2", "float": "<f4"}[kind]
    table = np.zeros(3, dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("r", code), ("g", code), ("b", code)])
    table["x"], table["y"], table["z"] = points.T
    table["r"], table["g"], table["b"] = values.T
    face = np.array([3], np.uint8).tobytes() + np.array([0, 1, 2], "<i4").tobytes()
    return ("\n".join(header) + "\n").encode() + table.tobytes() + face


@pytest.mark.parametrize("form", ["ascii", "binary_little_endian"])
@pytest.mark.parametrize("kind", ["uchar", "ushort", "short", "float"])
def test_vertex_colours_of_every_type_read_alike(kind, form):
    (obj,) = load_scene_bytes(_ply(kind, form), "ply", f"{kind}.ply", sides="both").objects
    assert np.abs(obj.vertex_colors[:, :3].astype(int) - EXPECTED).max() <= 1, obj.vertex_colors

"""PLY vertex colours by their declared type: what trimesh 4.12 gets wrong.

trimesh casts every integer colour property to uint8 by truncation, so a ``ushort`` colour keeps
its low byte (32768 becomes 0, 58982 becomes 102; found by the three.js check of
``tests/test_threejs.py``, whose PLYLoader scales by type).  The PLY format states no colour
range; the convention of its writers and readers (three.js, Open3D, MeshLab) is the type's full
range for integers (``uchar`` 0..255, ``ushort`` 0..65535) and 0..1 for floats.  This module reads
the vertex element's colour properties itself, by type, when they are not ``uchar``; the vertex
element must be the file's first (as in every writer we know), since a binary element after one
with list properties has no fixed offset.
"""

from __future__ import annotations

import io

import numpy as np

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
    "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_CHANNELS = (
    ("red", "diffuse_red", "r"),
    ("green", "diffuse_green", "g"),
    ("blue", "diffuse_blue", "b"),
    ("alpha", "a"),
)


def _header(data: bytes) -> tuple[str, list[tuple[str, int, list[tuple[str, str | None]]]], int] | None:
    """(format, [(element, count, [(property, type or None for a list)])], offset of the data)."""
    end = data.find(b"end_header")
    if end < 0:
        return None
    stop = data.find(b"\n", end)
    if stop < 0:
        return None
    form, elements = None, []
    for raw in data[:end].decode("ascii", "replace").splitlines():
        words = raw.split()
        if not words:
            continue
        if words[0] == "format" and len(words) > 1:
            form = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements and len(words) >= 3:
            elements[-1][2].append((words[-1], None if words[1] == "list" else words[1]))
    return (form, elements, stop + 1) if form else None


def vertex_colours(data: bytes) -> np.ndarray | None:
    """(v, 4) uint8 RGBA of a PLY's vertex colours when they are declared with a type trimesh
    misreads (any but ``uchar``), scaled by that type; None when they are ``uchar``, absent, or not
    readable here (the vertex element not first, or a list property in it)."""
    parsed = _header(data)
    if parsed is None:
        return None
    form, elements, offset = parsed
    if not elements or elements[0][0] != "vertex":
        return None
    _, count, properties = elements[0]
    if any(kind is None or kind not in _TYPES for _, kind in properties):
        return None
    types = {name: kind for name, kind in properties}
    found = [next((n for n in names if n in types), None) for names in _CHANNELS]
    if any(f is None for f in found[:3]) or all(_TYPES[types[f]] == "u1" for f in found if f is not None):
        return None
    order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(form)
    if order is not None:
        dtype = np.dtype([(name, order + _TYPES[kind]) for name, kind in properties])
        if offset + count * dtype.itemsize > len(data):
            return None
        table = np.frombuffer(data, dtype=dtype, count=count, offset=offset)
        columns = {name: table[name] for name, _ in properties}
    elif form == "ascii":
        try:
            values = np.loadtxt(io.BytesIO(data[offset:]), max_rows=count, ndmin=2, usecols=range(len(properties)))
        except ValueError:
            return None
        if len(values) != count:
            return None
        columns = {name: values[:, i] for i, (name, _) in enumerate(properties)}
    else:
        return None
    out = np.full((count, 4), 255, dtype=np.uint8)
    for channel, name in enumerate(found):
        if name is None:
            continue
        code = _TYPES[types[name]]
        values = np.asarray(columns[name], dtype=np.float64)
        if code[0] == "f":
            unit = values
        else:
            info = np.iinfo(np.dtype(code))
            unit = values / float(info.max)
        out[:, channel] = np.round(np.clip(unit, 0.0, 1.0) * 255.0).astype(np.uint8)
    return out

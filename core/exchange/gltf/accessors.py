"""glTF 2.0 accessors -> float64 / int64 numpy arrays (Khronos, glTF 2.0, §3.6.2 "Accessors").

Every rule of the specification that changes the numbers is followed:

* component types 5120 (byte), 5121 (unsigned byte), 5122 (short), 5123 (unsigned short),
  5125 (unsigned int), 5126 (float), little-endian;
* ``byteStride`` of the buffer view (interleaved attributes) and the accessor's ``byteOffset``;
* ``normalized``: integers map to 0..1 (unsigned, ``c / (2^n - 1)``) or -1..1 (signed,
  ``max(c / (2^(n-1) - 1), -1)``) (§3.11 "Animations"/"Meshes" equations, as in
  ``KHR_mesh_quantization``); integer attributes that are not normalized are taken as they are;
* matrix columns are padded to 4-byte boundaries (§3.6.2.4 "Data alignment");
* an accessor without a ``bufferView`` is zeros, and ``sparse`` substitutes its listed elements.
"""

from __future__ import annotations

import numpy as np

from farfield.core.errors import SceneLoadError
from farfield.core.exchange.gltf.document import Buffers, item

COMPONENTS = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}


def _dtype(code: object, where: str) -> np.dtype:
    if not isinstance(code, int) or code not in COMPONENTS:
        raise SceneLoadError(f"{where}: componentType {code!r} is not one of glTF's {sorted(COMPONENTS)}")
    return np.dtype(COMPONENTS[code]).newbyteorder("<")


def _rows(data: memoryview, offset: int, count: int, row_bytes: int, stride: int | None, where: str) -> np.ndarray:
    """(count, row_bytes) uint8 rows starting at ``offset``, ``stride`` apart (packed when None)."""
    step = row_bytes if stride is None else stride
    if count == 0:
        return np.zeros((0, row_bytes), dtype=np.uint8)
    end = offset + (count - 1) * step + row_bytes
    if offset < 0 or end > len(data):
        raise SceneLoadError(
            f"{where}: its {count} elements need bytes {offset}..{end}, its buffer view has {len(data)}"
        )
    flat = np.frombuffer(data, dtype=np.uint8, count=end - offset, offset=offset)
    return np.lib.stride_tricks.as_strided(flat, shape=(count, row_bytes), strides=(step, 1), writeable=False)


def _elements(data: memoryview, offset: int, count: int, kind: str, dtype: np.dtype, stride, where) -> np.ndarray:
    """(count, width) raw components, matrix column padding removed."""
    width = WIDTHS[kind]
    size = dtype.itemsize
    if kind.startswith("MAT") and size < 4:
        n = int(kind[3])
        column = -(-n * size // 4) * 4  # each column starts on a 4-byte boundary
        rows = _rows(data, offset, count, column * n, stride, where)
        picked = np.concatenate([rows[:, c * column : c * column + n * size] for c in range(n)], axis=1)
        return np.ascontiguousarray(picked).view(dtype).reshape(count, width)
    rows = _rows(data, offset, count, width * size, stride, where)
    return np.ascontiguousarray(rows).view(dtype).reshape(count, width)


def _normalized(values: np.ndarray) -> np.ndarray:
    """Normalized integers as float64 (glTF 2.0 §3.11, "normalized" conversion)."""
    info = np.iinfo(values.dtype)
    if info.min == 0:
        return values.astype(np.float64) / float(info.max)
    return np.maximum(values.astype(np.float64) / float(info.max), -1.0)


# The most elements an accessor without a buffer view (zeros, maybe sparse) may have: its count is
# otherwise bounded by nothing but the JSON (a count of 10^12 in a 1 KB file).
MAX_ZERO_ELEMENTS = 1 << 26


def _size(value: object, what: str, where: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise SceneLoadError(f"{where}: {what} {value!r} is not a size")
    return value


def read(document: dict, buffers: Buffers, index: object, as_float: bool = True, indices: bool = False) -> np.ndarray:
    """Accessor ``index`` as a (count, width) array: float64 (normalized integers converted) or,
    with ``as_float=False``, int64; ``indices``: it must be unsigned integer scalars (§3.7.2.1).

    Raises
    ------
    SceneLoadError
        An unknown type or component type, a count that is not a size, bytes past the buffer view,
        a sparse index out of range.
    """
    spec = item(document, "accessors", index)
    where = f"glTF accessor {index}"
    kind, count = spec.get("type"), spec.get("count")
    if not isinstance(kind, str) or kind not in WIDTHS:
        raise SceneLoadError(f"{where}: type {kind!r} is not one of {sorted(WIDTHS)}")
    count = _size(count, "count", where)
    dtype = _dtype(spec.get("componentType"), where)
    offset = _size(spec.get("byteOffset", 0), "byteOffset", where)
    if indices and (kind != "SCALAR" or dtype.kind != "u"):
        raise SceneLoadError(f"{where}: indices must be unsigned integer scalars, not {kind} of {dtype.name}")
    if "bufferView" in spec:
        data, stride = buffers.view(spec["bufferView"])
        values = np.array(_elements(data, offset, count, kind, dtype, stride, where))
    else:
        if count * WIDTHS[kind] > MAX_ZERO_ELEMENTS:
            raise SceneLoadError(
                f"{where}: {count} elements without a bufferView (at most {MAX_ZERO_ELEMENTS} components)"
            )
        values = np.zeros((count, WIDTHS[kind]), dtype=dtype)
    sparse = spec.get("sparse")
    if isinstance(sparse, dict):
        _apply_sparse(document, buffers, sparse, values, kind, dtype, where)
    if not as_float:
        return values.astype(np.int64)
    if spec.get("normalized") and dtype.kind in "iu":
        return _normalized(values)
    return values.astype(np.float64)


def _apply_sparse(document, buffers, sparse: dict, values: np.ndarray, kind: str, dtype, where: str) -> None:
    """Substitute a sparse accessor's listed elements into ``values`` (in place)."""
    count = sparse.get("count")
    indices, substitutes = sparse.get("indices"), sparse.get("values")
    if isinstance(count, bool) or not isinstance(count, int) or count < 1:
        raise SceneLoadError(f"{where}: sparse count {count!r} is not a positive size")
    if not isinstance(indices, dict) or not isinstance(substitutes, dict):
        raise SceneLoadError(f"{where}: sparse needs 'indices' and 'values' objects")
    index_type = _dtype(indices.get("componentType"), f"{where} sparse indices")
    if index_type.kind != "u":
        raise SceneLoadError(f"{where}: sparse indices must be unsigned integers")
    data, _ = buffers.view(indices.get("bufferView"))
    start = _size(indices.get("byteOffset", 0), "sparse indices byteOffset", where)
    at = _elements(data, start, count, "SCALAR", index_type, None, where)[:, 0].astype(np.int64)
    if len(at) and (at.min() < 0 or at.max() >= len(values)):
        raise SceneLoadError(f"{where}: sparse index {int(at.max())} is out of range for {len(values)} elements")
    data, _ = buffers.view(substitutes.get("bufferView"))
    start = _size(substitutes.get("byteOffset", 0), "sparse values byteOffset", where)
    values[at] = _elements(data, start, count, kind, dtype, None, where)

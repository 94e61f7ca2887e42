"""Seeded procedural scenes: a :class:`core.scene.Scene` of box buildings on a grid, from ``np.random.default_rng``.

The city is the scene ``farfield calibrate`` measures when given none, and a scene tests and
benchmarks may build without files.  Buildings are boxes whose faces are cut into ``n x n`` grids
of quads (``12 n^2`` triangles, ``n`` varying between districts and within them), so that a
cluster's triangle count does not follow from its number of objects: a regression on draw calls
and triangles (seed 000 §5.8.1) can tell the two apart.  World +y is up, as in glTF; lengths in metres.
"""

from __future__ import annotations

import numpy as np

from farfield.core.scene import Scene, SceneObject

# Face of the unit cube as (fixed axis, value 0 or 1, axis u, axis v), with u x v pointing outward.
_FACES = ((0, 1, 1, 2), (0, 0, 2, 1), (1, 1, 2, 0), (1, 0, 0, 2), (2, 1, 0, 1), (2, 0, 1, 0))


def subdivided_box(low, high, n: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(v, 3) float64 vertices and (12 n^2, 3) int64 outward, counter-clockwise faces of the box
    ``low``..``high`` ((3,) each) whose six faces are each an ``n x n`` grid of quads (vertices on
    the edges are repeated per face).

    >>> v, f = subdivided_box([0, 0, 0], [1, 2, 3], 2)
    >>> v.shape, f.shape, v.min(axis=0).tolist(), v.max(axis=0).tolist()
    ((54, 3), (48, 3), [0.0, 0.0, 0.0], [1.0, 2.0, 3.0])
    >>> e = v[f]; bool(np.isclose(np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1] - e[:, 0], e[:, 2] - e[:, 0])).sum() / 6, 6.0))
    True
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"a box face needs n >= 1 quads per side, got {n}")
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    s = np.linspace(0.0, 1.0, n + 1)
    gu, gv = (g.reshape(-1) for g in np.meshgrid(s, s, indexing="ij"))  # u slowest
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]  # quad (iu, iv) -> its low-low vertex
    i = i.reshape(-1)
    quad = np.stack([i, i + n + 1, i + n + 2, i + 1], axis=1)  # (u0 v0) (u1 v0) (u1 v1) (u0 v1): counter-clockwise in (u, v)
    vertices, faces = [], []
    for k, (axis, value, u, v) in enumerate(_FACES):
        unit = np.zeros((gu.size, 3))
        unit[:, axis], unit[:, u], unit[:, v] = value, gu, gv
        vertices.append(low + unit * (high - low))
        base = k * gu.size
        faces.append(np.concatenate([quad[:, [0, 1, 2]], quad[:, [0, 2, 3]]]) + base)
    return np.concatenate(vertices), np.concatenate(faces).astype(np.int64)


def city(buildings: int = 300, seed: int = 0, detail: int = 1, spacing: float = 20.0) -> Scene:
    """A city of ``buildings`` box buildings on a square grid of lots ``spacing`` apart, plus a
    ground plane, material colours; deterministic for ``seed``.

    Footprints 0.3..0.8 of ``spacing``, heights log-normal around 0.75 ``spacing``; each building's
    faces are grids of ``n x n`` quads, ``n`` log-uniform in ``1..m`` with ``m`` log-uniform in
    ``1..detail`` per district of 4 x 4 lots (``detail=1``: 12-triangle boxes).

    >>> s = city(10, seed=3, detail=8)
    >>> s.object_count, s.names[:2], 12 * 10 + 2 <= s.triangle_count <= 12 * 64 * 10 + 2
    (11, ('ground', 'building_0000'), True)
    >>> city(10, seed=3, detail=8).content_hash == s.content_hash
    True
    """
    if int(buildings) < 1 or int(detail) < 1:
        raise ValueError(f"a city needs buildings >= 1 and detail >= 1, got {buildings}, {detail}")
    buildings = int(buildings)
    rng = np.random.default_rng(seed)
    side = int(np.ceil(np.sqrt(buildings)))
    lots = np.stack(np.meshgrid(np.arange(side), np.arange(side), indexing="ij"), axis=-1).reshape(-1, 2)[:buildings]
    footprint = rng.uniform(0.3, 0.8, size=(buildings, 2)) * spacing
    height = rng.lognormal(np.log(0.75 * spacing), 0.6, size=buildings)
    grey = rng.uniform(0.35, 0.9, size=buildings)
    # Each district of 4 x 4 lots has its own largest n (log-uniform in 1..detail) and each building
    # a log-uniform n up to it, so compact clusters differ in triangles per object, not only in size.
    district = (lots[:, 0] // 4) * (side // 4 + 1) + lots[:, 1] // 4
    most = np.exp(rng.uniform(0.0, np.log(detail), size=int(district.max()) + 1))
    cuts = np.maximum(np.rint(np.exp(rng.uniform(0.0, 1.0, size=buildings) * np.log(most[district]))), 1).astype(int)
    objects = []
    for i in range(buildings):
        centre = lots[i] * spacing
        low = (centre[0] - footprint[i, 0] / 2, 0.0, centre[1] - footprint[i, 1] / 2)
        high = (centre[0] + footprint[i, 0] / 2, height[i], centre[1] + footprint[i, 1] / 2)
        vertices, faces = subdivided_box(low, high, cuts[i])
        objects.append(SceneObject(f"building_{i:04d}", vertices, faces, base_color=(grey[i], grey[i], grey[i] * 0.95, 1.0)))
    lo, hi = -0.5 * spacing, (side - 0.5) * spacing
    ground = SceneObject(
        "ground",
        np.array([[lo, 0.0, lo], [lo, 0.0, hi], [hi, 0.0, hi], [hi, 0.0, lo]]),
        np.array([[0, 1, 2], [0, 2, 3]]),  # counter-clockwise seen from +y
        base_color=(0.3, 0.5, 0.25, 1.0),
    )
    return Scene.from_objects([ground, *objects], source=f"city-{buildings}-{seed}-{detail}")

"""Seeded procedural scenes from ``np.random.default_rng``: a city of box buildings on a grid, a house, a
forest of thin trunks (``farfield scenes demo``).

The city is the scene ``farfield calibrate`` measures when given none, and a scene tests and
benchmarks may build without files.  Buildings are boxes whose faces are cut into ``n x n`` grids
of quads (``12 n^2`` triangles, ``n`` varying between districts and within them), so that a
cluster's triangle count does not follow from its number of objects: a regression on draw calls
and triangles (seed 000 §5.8.1) can tell the two apart.  World +y is up, as in glTF; lengths in metres.
"""

from __future__ import annotations

import functools

import numpy as np
import trimesh

from farfield.core.scene import Scene, SceneObject, instances_of, prototype_key

# Face of the unit cube as (fixed axis, value 0 or 1, axis u, axis v), with u x v pointing outward.
_FACES = ((0, 1, 1, 2), (0, 0, 2, 1), (1, 1, 2, 0), (1, 0, 0, 2), (2, 1, 0, 1), (2, 0, 1, 0))


def subdivided_box(low, high, n: int = 1, relief: float = 0.0, seed=0) -> tuple[np.ndarray, np.ndarray]:
    """(v, 3) float64 vertices and (12 n^2, 3) int64 outward, counter-clockwise faces of the box
    ``low``..``high`` ((3,) each) whose six faces are each an ``n x n`` grid of quads (vertices on
    the edges are repeated per face).

    ``relief`` > 0 recesses each face's inner vertices by a seeded uniform depth in ``0..relief``
    (at most a quarter of the box's thinnest side) along the face's inward normal: a facade with
    detail a simplifier cannot remove within its error (flat faces lose every inner vertex at no
    error), while the edges, the silhouette and the bounds stay the box's.

    >>> v, f = subdivided_box([0, 0, 0], [4, 8, 4], 4, relief=0.5, seed=1)
    >>> v.min(axis=0).tolist(), v.max(axis=0).tolist(), bool((subdivided_box([0, 0, 0], [4, 8, 4], 4)[0] != v).any())
    ([0.0, 0.0, 0.0], [4.0, 8.0, 4.0], True)

    >>> v, f = subdivided_box([0, 0, 0], [1, 2, 3], 2)
    >>> v.shape, f.shape, v.min(axis=0).tolist(), v.max(axis=0).tolist()
    ((54, 3), (48, 3), [0.0, 0.0, 0.0], [1.0, 2.0, 3.0])
    >>> e = v[f]; bool(np.isclose(np.einsum("ij,ij->i", e[:, 0], np.cross(e[:, 1] - e[:, 0], e[:, 2] - e[:, 0])).sum() / 6, 6.0))
    True
    """
    n = int(n)
    if n < 1:
        raise ValueError(f"a box face needs n >= 1 quads per side, got {n}")
    if not relief >= 0.0:
        raise ValueError(f"a box's relief must be >= 0, got {relief}")
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    depth = min(float(relief), 0.25 * float(np.min(high - low)))
    rng = np.random.default_rng(seed) if depth > 0.0 else None
    s = np.linspace(0.0, 1.0, n + 1)
    gu, gv = (g.reshape(-1) for g in np.meshgrid(s, s, indexing="ij"))  # u slowest
    i = np.arange(n)[:, None] * (n + 1) + np.arange(n)[None, :]  # quad (iu, iv) -> its low-low vertex
    i = i.reshape(-1)
    quad = np.stack(
        [i, i + n + 1, i + n + 2, i + 1], axis=1
    )  # (u0 v0) (u1 v0) (u1 v1) (u0 v1): counter-clockwise in (u, v)
    vertices, faces = [], []
    for k, (axis, value, u, v) in enumerate(_FACES):
        unit = np.zeros((gu.size, 3))
        unit[:, axis], unit[:, u], unit[:, v] = value, gu, gv
        corners = low + unit * (high - low)
        if rng is not None:
            inner = (gu > 0.0) & (gu < 1.0) & (gv > 0.0) & (gv < 1.0)
            inward = 1.0 if value == 0 else -1.0  # the face at 0 recedes towards +axis
            corners[inner, axis] += inward * rng.uniform(0.0, depth, size=int(inner.sum()))
        vertices.append(corners)
        base = k * gu.size
        faces.append(np.concatenate([quad[:, [0, 1, 2]], quad[:, [0, 2, 3]]]) + base)
    return np.concatenate(vertices), np.concatenate(faces).astype(np.int64)


def city(buildings: int = 300, seed: int = 0, detail: int = 1, spacing: float = 20.0, relief: float = 0.0) -> Scene:
    """A city of ``buildings`` box buildings on a square grid of lots ``spacing`` apart, plus a
    ground plane, material colours; deterministic for ``seed``.

    Footprints 0.3..0.8 of ``spacing``, heights log-normal around 0.75 ``spacing``; each building's
    faces are grids of ``n x n`` quads, ``n`` log-uniform in ``1..m`` with ``m`` log-uniform in
    ``1..detail`` per district of 4 x 4 lots (``detail=1``: 12-triangle boxes); ``relief`` (m) recesses
    the facades' inner vertices (:func:`subdivided_box`), detail a simplifier must keep.

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
        vertices, faces = subdivided_box(low, high, cuts[i], relief, seed=(seed, i))
        objects.append(
            SceneObject(f"building_{i:04d}", vertices, faces, base_color=(grey[i], grey[i], grey[i] * 0.95, 1.0))
        )
    lo, hi = -0.5 * spacing, (side - 0.5) * spacing
    ground = SceneObject(
        "ground",
        np.array([[lo, 0.0, lo], [lo, 0.0, hi], [hi, 0.0, hi], [hi, 0.0, lo]]),
        np.array([[0, 1, 2], [0, 2, 3]]),  # counter-clockwise seen from +y
        base_color=(0.3, 0.5, 0.25, 1.0),
    )
    relief_tag = f"-relief{relief:g}" if relief > 0.0 else ""
    return Scene.from_objects([ground, *objects], source=f"city-{buildings}-{seed}-{detail}{relief_tag}")


@functools.cache
def _unit_box() -> tuple[np.ndarray, np.ndarray]:
    """(8, 3) float64 corners of the unit cube [0, 1]^3 and (12, 3) int64 outward faces."""
    box = trimesh.creation.box(bounds=[[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]])
    return np.asarray(box.vertices, dtype=np.float64), np.asarray(box.faces, dtype=np.int64)


def box_object(name: str, low, high, base_color=(0.8, 0.8, 0.8, 1.0)) -> SceneObject:
    """An axis-aligned box from corner ``low`` to ``high`` ((3,) float64), material-coloured."""
    vertices, faces = _unit_box()
    low, high = np.asarray(low, dtype=np.float64), np.asarray(high, dtype=np.float64)
    return SceneObject(name, low + vertices * (high - low), faces, base_color=base_color)


def forest(trees: int = 200, seed: int = 1) -> Scene:
    """A forest of ``trees`` thin vertical cylinders (trunks) with brown-to-green vertex colours.

    Radii 0.05..0.2, heights 4..12 units, scattered over a 100 x 100 square.
    """
    rng = np.random.default_rng(seed)
    unit = trimesh.creation.cylinder(radius=1.0, height=1.0, sections=8)  # z in -0.5..0.5
    vertices = np.asarray(unit.vertices, dtype=np.float64)
    faces = np.asarray(unit.faces, dtype=np.int64)
    up = vertices[:, 2] + 0.5  # 0 at the foot, 1 at the top
    colours = np.empty((len(vertices), 4), dtype=np.uint8)
    colours[:, :3] = np.round((1 - up)[:, None] * (100, 70, 40) + up[:, None] * (40, 140, 50))
    colours[:, 3] = 255
    radius = rng.uniform(0.05, 0.2, size=trees)
    height = rng.uniform(4.0, 12.0, size=trees)
    where = rng.uniform(0.0, 100.0, size=(trees, 2))
    objects = []
    for i in range(trees):
        scaled = vertices * (radius[i], radius[i], height[i])
        # z-up cylinder to y-up world: (x, y, z) -> (x, z + h/2, -y), a proper rotation.
        world = np.column_stack([scaled[:, 0] + where[i, 0], scaled[:, 2] + height[i] / 2, -scaled[:, 1] + where[i, 1]])
        objects.append(SceneObject(f"tree_{i:03d}", world, faces, vertex_colors=colours))
    return Scene.from_objects(objects, source=f"forest-{trees}-{seed}")


def _tree_prototypes(count: int, rng, detail: int = 1) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``count`` tree meshes (vertices with the foot at the origin, world +y up; faces; vertex
    colours): a trunk (a cylinder) under a crown (a cone, or a sphere for every third), of seeded
    sizes, ``6..12 x detail`` sections (a sphere subdivided ``1 + log2(detail)`` times, at most 4)."""
    out = []
    for k in range(count):
        sections = int(rng.integers(6, 13)) * int(detail)
        height, crown = float(rng.uniform(6.0, 14.0)), float(rng.uniform(1.5, 3.5))
        trunk = trimesh.creation.cylinder(
            radius=float(rng.uniform(0.15, 0.35)), height=0.45 * height, sections=sections
        )
        trunk.apply_translation([0.0, 0.0, 0.225 * height])
        if k % 3 == 2:
            top = trimesh.creation.icosphere(subdivisions=min(1 + int(np.log2(detail)), 4), radius=crown)
            top.apply_translation([0.0, 0.0, height - crown])
        else:
            top = trimesh.creation.cone(radius=crown, height=0.65 * height, sections=sections)
            top.apply_translation([0.0, 0.0, 0.35 * height])
        v = np.concatenate([trunk.vertices, top.vertices])
        f = np.concatenate([trunk.faces, top.faces + len(trunk.vertices)])
        c = np.empty((len(v), 4), dtype=np.uint8)
        c[: len(trunk.vertices)] = (110, 75, 45, 255)
        c[len(trunk.vertices) :] = (40 + 12 * k, 120 + 8 * k, 50, 255)
        out.append((np.column_stack([v[:, 0], v[:, 2], -v[:, 1]]), np.asarray(f, dtype=np.int64), c))  # z-up -> y-up
    return out


def tree_forest(
    instances: int = 10_000, prototypes: int = 5, size: float = 1000.0, seed: int = 2, detail: int = 1
) -> Scene:
    """A forest of ``instances`` trees of ``prototypes`` tree meshes (:func:`_tree_prototypes`: trunk
    and crown, 6-14 m tall, about 60-180 triangles times ``detail``), each turned about the vertical and scaled 0.8-1.2,
    scattered over a ``size`` x ``size`` m terrain plane (``ground``, y = 0); world +y up.  Every
    tree is an instance of its prototype (``tree<k>_<i>``: prototype ``k``; :func:`~farfield.core.scene.instances_of`,
    its ``instance_matrix`` a turn about +y, a uniform scale and a move), with world coordinates: the scene
    the octahedral placement benchmark measures (benchmarks/bench_forest_placement.py)."""
    rng = np.random.default_rng(seed)
    shapes = _tree_prototypes(prototypes, rng, detail)
    kind = rng.integers(0, prototypes, instances)
    where = rng.uniform(0.0, size, (instances, 2))
    turn = rng.uniform(0.0, 2.0 * np.pi, instances)
    scale = rng.uniform(0.8, 1.2, instances)
    objects = [SceneObject("ground", np.array([[0.0, 0.0, 0.0], [size, 0.0, 0.0], [size, 0.0, size], [0.0, 0.0, size]]),
                           np.array([[0, 2, 1], [0, 3, 2]]), base_color=(0.35, 0.3, 0.2, 1.0))]  # fmt: skip
    locals_ = [SceneObject(f"tree{k}", v, f, vertex_colors=c) for k, (v, f, c) in enumerate(shapes)]
    cos, sin = np.cos(turn) * scale, np.sin(turn) * scale
    matrices = np.zeros((instances, 4, 4))
    matrices[:, 0, 0], matrices[:, 0, 2], matrices[:, 0, 3] = cos, -sin, where[:, 0]
    matrices[:, 1, 1], matrices[:, 2, 0], matrices[:, 2, 2], matrices[:, 2, 3] = scale, sin, cos, where[:, 1]
    matrices[:, 3, 3] = 1.0
    trees: list = [None] * instances
    for k, local in enumerate(locals_):  # each prototype's trees moved at once, then in tree order
        chosen = np.flatnonzero(kind == k)
        names = [f"tree{k}_{i:05d}" for i in chosen]
        for i, obj in zip(chosen, instances_of(local, names, matrices[chosen], prototype_key([local]))):
            trees[i] = obj
    return Scene.from_objects(objects + trees, source=f"tree-forest-{instances}-{prototypes}-{seed}-{detail}")


def statue_park(statues: int = 9, subdivisions: int = 7, spacing: float = 14.0, seed: int = 6) -> Scene:
    """A park of ``statues`` dense statues on a square grid ``spacing`` m apart around the origin
    (issue 57's statue park, in small): each an icosphere of ``20 * 4**subdivisions`` triangles
    (327,680 at 7) stretched to 2 m wide and 4 m tall, its surface moved by smooth bumps (up to 8 %
    of its radius, a product of sines of random phase: detail a simplifier can keep with few
    triangles, as an oversampled scan has), standing on y = 0 and coloured from the seed; world +y up.

    >>> park = statue_park(4, 2)
    >>> park.object_count, park.triangle_count
    (4, 1280)
    """
    rng = np.random.default_rng(seed)
    unit = trimesh.creation.icosphere(subdivisions=subdivisions)
    v0, faces = np.asarray(unit.vertices, dtype=np.float64), np.asarray(unit.faces, dtype=np.int64)
    side = int(np.ceil(np.sqrt(statues)))
    objects = []
    for i in range(statues):
        phase = rng.uniform(0.0, 2.0 * np.pi, 3)
        bumps = 1.0 + 0.08 * np.sin(4 * v0[:, 0] + phase[0]) * np.sin(5 * v0[:, 1] + phase[1]) * np.sin(
            3 * v0[:, 2] + phase[2]
        )
        centre = np.array([(i % side - 0.5 * (side - 1)) * spacing, 2.0, (i // side - 0.5 * (side - 1)) * spacing])
        vertices = v0 * bumps[:, None] * np.array([1.0, 2.0, 1.0]) + centre
        objects.append(SceneObject(f"statue_{i}", vertices, faces, base_color=(*rng.uniform(0.3, 0.9, 3), 1.0)))
    return Scene.from_objects(objects, source=f"statue-park-{statues}-{subdivisions}-{seed}")


def house(seed: int = 4) -> Scene:
    """A building-like object, 20 x 10 x 12 units under a gable roof, with window frames and a door
    standing out of its walls, a chimney and a porch roof: 1,220 triangles, material colours.

    The stand-in for the house model of seed 000 Table 4.1 (that model is not public).
    """
    rng = np.random.default_rng(seed)
    objects = [box_object("body", (0.0, 0.0, 0.0), (20.0, 10.0, 12.0), (0.85, 0.8, 0.7, 1.0))]
    # Gable roof: a triangular prism along x over the body, overhanging by 0.5.
    ridge = 15.0
    roof_v = np.array([
        [-0.5, 10.0, -0.5], [20.5, 10.0, -0.5], [20.5, ridge, 6.0], [-0.5, ridge, 6.0],
        [-0.5, 10.0, 12.5], [20.5, 10.0, 12.5],
    ])  # fmt: skip
    roof_f = np.array([[0, 2, 1], [0, 3, 2], [4, 5, 2], [4, 2, 3], [0, 4, 3], [1, 2, 5], [0, 1, 5], [0, 5, 4]])
    objects.append(SceneObject("roof", roof_v, roof_f, base_color=(0.6, 0.2, 0.15, 1.0)))
    objects.append(box_object("chimney", (14.0, 11.0, 3.0), (15.5, 16.5, 4.5), (0.5, 0.45, 0.45, 1.0)))
    # Window frames and sills on the front (z = 0) and back (z = 12) walls, two storeys.
    n = 0
    for z, out in ((0.0, -1.0), (12.0, 1.0)):
        for storey, y in enumerate((1.5, 6.0)):
            for x in np.arange(1.5, 19.0, 3.6):
                if z == 0.0 and storey == 0 and abs(x - 8.7) < 1.0:
                    continue  # the door goes here
                depth = 0.25 * out
                shade = rng.uniform(0.15, 0.3)
                for k, (lo, hi) in enumerate(
                    (
                        ((x, y, z), (x + 1.8, y + 0.2, z + depth)),  # sill
                        ((x, y + 2.3, z), (x + 1.8, y + 2.5, z + depth)),  # lintel
                        ((x, y, z), (x + 0.2, y + 2.5, z + depth)),
                        ((x + 1.6, y, z), (x + 1.8, y + 2.5, z + depth)),
                    )
                ):
                    lo, hi = np.minimum(lo, hi), np.maximum(lo, hi)
                    objects.append(box_object(f"frame_{n:03d}_{k}", lo, hi, (0.95, 0.95, 0.9, 1.0)))
                objects.append(
                    box_object(
                        f"glass_{n:03d}",
                        (x + 0.2, y + 0.2, z + 0.05 * out),
                        (x + 1.6, y + 2.3, z + 0.06 * out),
                        (shade, shade, shade + 0.2, 1.0),
                    )
                )
                n += 1
    objects.append(box_object("door", (8.2, 0.0, -0.2), (10.0, 3.2, 0.0), (0.35, 0.2, 0.1, 1.0)))
    objects.append(box_object("porch_roof", (7.2, 3.6, -2.0), (11.0, 3.8, 0.0), (0.3, 0.3, 0.3, 1.0)))
    for x in (7.3, 10.7):
        objects.append(box_object(f"porch_post_{x:g}", (x, 0.0, -2.0), (x + 0.2, 3.6, -1.8), (0.9, 0.9, 0.9, 1.0)))
    return Scene.from_objects(objects, source=f"house-{seed}")


DEMOS = {  # farfield scenes demo NAME: what the README's examples and the benchmarks start from
    "city": "a city of box buildings on a grid of lots 20 m apart, faces cut into quads (city(buildings, seed, detail))",
    "house": "a building-like object under a gable roof, 1,220 triangles (house(seed))",
    "forest": "thin vertical trunks over a 100 x 100 m square (forest(trees, seed))",
}


def demo_scene(name: str, size: int | None = None, seed: int | None = None, detail: int = 1) -> Scene:
    """The procedural scene ``name`` of :data:`DEMOS`; ``size`` counts buildings or trees."""
    if name == "city":
        return city(300 if size is None else size, seed=0 if seed is None else seed, detail=detail)
    if name == "house":
        return house(4 if seed is None else seed)
    if name == "forest":
        return forest(200 if size is None else size, seed=1 if seed is None else seed)
    raise ValueError(f"unknown demo scene {name!r}; one of {', '.join(DEMOS)}")

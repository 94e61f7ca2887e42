"""Towers next to the view space: their problem views are solved by simplified geometry of the
hierarchy's nodes of several elements (issue 57, downtown's unsolved problem views).

Three 60 m towers of 1,728 triangles (finely subdivided boxes, each split into 32 clusters of 54
triangles: no node of the object hierarchy holds one element), the nearest 1 m from the view space.
Layered impostors cannot serve views that close (a shaft starts one node diagonal away, a box cell
next to a tower needs more layers than it saves), and levels of detail were built only for nodes of
one element: every problem view stayed unsolved.  With a level of detail for every node of up to
``MAX_NODE_TRIANGLES`` (its open border kept only where the node holds part of a split object),
they are solved, and the runtime rebuilds exactly the level the planner measured.  Model only,
no wall-clock time asserted.
"""

from __future__ import annotations

import numpy as np
import pytest

from farfield.core import procedural
from farfield.core.placement.cost_model import LLVMPIPE_MODEL
from farfield.core.placement.hierarchy import Elements
from farfield.core.placement.lod import LOD_TECHNIQUE, keeps_border, level_for, lod_chain, node_mesh
from farfield.core.placement.planner import PlacementSettings, place
from farfield.core.scene import Scene, SceneObject

VIEW = (np.array([-41.0, 20.0, -14.0]), np.array([-1.0, 30.0, 26.0]))  # 1 m from the nearest tower


def _tower() -> Scene:
    """A tower touching the view space and two 8-10 m from it."""
    objects = []
    for k, (x, z) in enumerate(((0.0, 0.0), (8.0, 30.0), (8.0, -32.0))):
        v, f = procedural.subdivided_box((x, 0.0, z), (x + 12.0, 60.0, z + 12.0), 12)
        objects.append(SceneObject(f"tower_{k}", v, f, base_color=(0.4, 0.4, 0.5, 1.0)))
    return Scene.from_objects(objects, "towers")


def _settings(t_max: float, lod: bool) -> PlacementSettings:
    return PlacementSettings(t_max, LLVMPIPE_MODEL, options={"resolution": 128}, cpv_size=20.0, vdi_deg=45.0, lod=lod)


@pytest.fixture(scope="module")
def placed():
    scene = _tower()
    plain = place(scene, *VIEW, _settings(1e-6, False)).summary["worst_before"]  # every view a problem view
    t_max = 0.5 * plain
    return scene, place(scene, *VIEW, _settings(t_max, False)), place(scene, *VIEW, _settings(t_max, True))


def test_a_tower_beside_the_view_space_is_solved_by_simplified_nodes(placed):
    scene, layered, mixed = placed
    assert Elements.of(scene).count > 1  # the tower is split: no single-element node holds it
    assert layered.summary["cpvs_unsolved"] > 0  # what downtown showed: layered impostors cannot serve these views
    s = mixed.summary
    assert s["cpvs"] == layered.summary["cpvs"] and s["cpvs_unsolvable"] == 0
    assert s["cpvs_unsolved"] == 0
    lods = [imp for imp in mixed.impostors if imp["technique"] == LOD_TECHNIQUE and imp["cpvs"]]
    assert lods and any(len(imp["objects"]) > 1 for imp in lods)  # nodes of several clusters
    assert s["worst_after"] <= 0.5 * s["worst_before"] + 1e-9


def test_the_runtime_rebuilds_the_planned_level(placed):
    scene, _, mixed = placed
    elements = Elements.of(scene)
    index = {name: i for i, name in enumerate(elements.names)}
    lods = [imp for imp in mixed.impostors if imp["technique"] == LOD_TECHNIQUE and imp["cpvs"]]
    assert lods
    for imp in sorted(lods, key=lambda imp: -len(imp["objects"]))[:3]:
        ids = [index[name] for name in imp["objects"]]
        part = elements.scene_of(scene, ids)
        border = keeps_border(elements, ids)
        assert border == (len(ids) < elements.count)  # part of the split tower: its cut edges stay
        level = level_for(part, imp["level"], border)  # as the runtime draws it
        planned = lod_chain(*node_mesh(part), keep_border=border)[imp["level"] - 1]
        assert np.array_equal(level.vertices, planned.vertices) and np.array_equal(level.faces, planned.faces)
        assert level.triangles == imp["triangles"] < int(elements.triangles[ids].sum())


def test_a_node_of_every_cluster_of_its_object_is_simplified_whole():
    scene = _tower()
    elements = Elements.of(scene)
    assert not keeps_border(elements, np.arange(elements.count))
    assert keeps_border(elements, np.arange(elements.count - 1))
    whole = lod_chain(*node_mesh(elements.scene_of(scene, range(elements.count))))
    assert whole and whole[-1].triangles < 128 and whole[-1].error < 1e-6  # a flat-sided box: no error

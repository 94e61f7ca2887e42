"""The voxel field of a textured depth mesh: the gap-free layer recording, culled, as voxels.

Seed 003 §4 (seed 000 §4.3): every texel a layer keeps after culling is a voxel, defined by the
texel's square and the layer's depth range, coloured by the texel.  The non-uniformly spaced layers
are mapped to the uniform grid of seed 003 §4.3, where a voxel's centre is

    p^v = ((PIX_x + 0.5) / s_max, (PIX_y + 0.5) / s_max, l / s_max),   s_max = max(layers, RES_x, RES_y).

farfield keeps the grid in voxel units (``s_max`` times the normalized grid): one unit is one texel
across and one layer deep, so edge lengths, box sizes and the enlargement factor mean the same as
in the normalized grid (they all scale by the one constant ``s_max``), while coordinates stay exact
small integers and quarters.  Image y runs down (top row first), as everywhere in farfield.

The field is stored sparsely: sorted int64 keys ``(l * RES_y + y) * RES_x + x`` with their colours,
looked up by binary search (the compact hash-like structure of seed 000 §4.3), so memory grows with
the kept voxels, not with layers x image.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from farfield.core.errors import LayerPlanError
from farfield.core.layering.culled import culled_layers
from farfield.core.layering.culling import CullingMode
from farfield.core.layering.plan import LayerPlan
from farfield.core.layering.recording import eye_coordinates
from farfield.core.scene import Scene, SceneObject
from farfield.core.stage_clock import StageClock


@dataclass(frozen=True, slots=True)
class VoxelField:
    """The kept voxels of one recording, sorted by key (layer, then row, then column)."""

    plan: LayerPlan
    x: np.ndarray  # (n,) int64 texel column
    y: np.ndarray  # (n,) int64 texel row, top row first
    layer: np.ndarray  # (n,) int64 layer index, nearest first
    rgba: np.ndarray  # (n, 4) uint8 colour of each voxel
    stats: dict  # covered / culled / kept texels, triangles drawn, layers with voxels
    # (n, 4) uint8 world shading normal of each voxel's surface (encode_normals: n * 0.5 + 0.5,
    # alpha 255), or None where the recording kept no normal channel
    normal: np.ndarray | None = None
    # (n, 4) uint8 material channel of each voxel (glTF's ORM packing), (n, 8) with the emissive
    # channel after it (recording.iter_layers), or None where the recording kept no material
    material: np.ndarray | None = None

    @property
    def count(self) -> int:
        return int(self.x.shape[0])

    @property
    def shape(self) -> tuple[int, int, int]:
        """(layers, rows, columns) of the full grid."""
        res_x, res_y = (int(r) for r in self.plan.texture_resolution)
        return self.plan.count, res_y, res_x

    @property
    def keys(self) -> np.ndarray:
        _, res_y, res_x = self.shape
        return (self.layer * res_y + self.y) * res_x + self.x

    @property
    def centres(self) -> np.ndarray:
        """(n, 3) float64 voxel centres in voxel units (x + 0.5, y + 0.5, layer)."""
        return np.stack([self.x + 0.5, self.y + 0.5, self.layer.astype(np.float64)], axis=1)

    @property
    def silhouette(self) -> np.ndarray:
        """(n,) bool: the voxels with an empty column (no voxel on any layer) among the eight around
        theirs, where the image of the part ends against the background.  The simplification does
        not enlarge their boxes (:func:`farfield.core.techniques.tdm.simplify.box_half_sizes`), so the mesh's outline
        can neither retreat into them nor be held by a triangle in front of or behind them."""
        _, res_y, res_x = self.shape
        occupied = np.zeros((res_y + 2, res_x + 2), dtype=bool)
        occupied[self.y + 1, self.x + 1] = True
        full = np.ones_like(occupied)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                full[1:-1, 1:-1] &= occupied[1 + dy : res_y + 1 + dy, 1 + dx : res_x + 1 + dx]
        return ~full[self.y + 1, self.x + 1]

    def find(self, x, y, layer) -> np.ndarray:
        """Index of the voxel at each (x, y, layer), -1 where the field has none."""
        x, y, layer = (np.asarray(a, dtype=np.int64) for a in (x, y, layer))
        k, res_y, res_x = self.shape
        inside = (x >= 0) & (x < res_x) & (y >= 0) & (y < res_y) & (layer >= 0) & (layer < k)
        key = (layer * res_y + y) * res_x + x
        keys = self.keys
        at = np.clip(np.searchsorted(keys, key), 0, max(len(keys) - 1, 0))
        found = inside & (len(keys) > 0) & (keys[at] == key) if len(keys) else np.zeros(key.shape, bool)
        return np.where(found, at, -1)

    def to_world(self, points: np.ndarray) -> np.ndarray:
        """World positions (n, 3) float64 of voxel-space ``points`` (n, 3) lying on sampling layers
        (integer z).  Seed 003 §8: ``l_z = layer[v_z]``, ``v_x^w = 2 l_z tan(FOV/2) (v_x / RES_x - 1/2)``
        (and y, downwards here), ``v_z^w = l_z``, in the recording frame of the reference viewpoint."""
        p = np.asarray(points, dtype=np.float64)
        plan = self.plan
        layer = np.rint(p[:, 2]).astype(np.int64)
        if np.any(np.abs(p[:, 2] - layer) > 1e-9) or layer.min(initial=0) < 0 or layer.max(initial=0) >= plan.count:
            raise LayerPlanError("a voxel-space point to reproject does not lie on a sampling layer")
        depth = plan.distances[layer] + plan.reference_offset
        res = plan.texture_resolution.astype(np.float64)
        ex = (p[:, 0] / res[0] * 2.0 - 1.0) * plan.frustum_half_tangents[0] * depth
        ey = (1.0 - p[:, 1] / res[1] * 2.0) * plan.frustum_half_tangents[1] * depth
        return plan.reference_viewpoint + ex[:, None] * plan.u + ey[:, None] * plan.v + depth[:, None] * plan.axis

    def from_world(self, points: np.ndarray) -> np.ndarray:
        """Voxel-space positions (n, 3) float64 of world ``points``: the inverse of :meth:`to_world`,
        with z a fractional layer index interpolated between the sampling layers' depths (and
        extrapolated at the ends).  Points at or behind the reference viewpoint's plane are invalid."""
        plan = self.plan
        eye = eye_coordinates(plan, points)
        depth = eye[:, 2]
        if np.any(depth <= 0.0):
            raise LayerPlanError("a point to project lies behind the reference viewpoint")
        res = plan.texture_resolution.astype(np.float64)
        x = (eye[:, 0] / (depth * plan.frustum_half_tangents[0]) + 1.0) * 0.5 * res[0]
        y = (1.0 - eye[:, 1] / (depth * plan.frustum_half_tangents[1])) * 0.5 * res[1]
        layers = plan.distances + plan.reference_offset
        if plan.count == 1:
            z = np.zeros_like(depth)
        else:
            z = np.interp(depth, layers, np.arange(plan.count, dtype=np.float64))
            below, above = depth < layers[0], depth > layers[-1]
            z[below] = (depth[below] - layers[0]) / (layers[1] - layers[0])
            z[above] = plan.count - 1 + (depth[above] - layers[-1]) / (layers[-1] - layers[-2])
        return np.stack([x, y, z], axis=1)


def record_voxel_field(
    part: Scene | Sequence[SceneObject],
    plan: LayerPlan,
    culling: CullingMode,
    clock: StageClock,
    normals: bool = False,
    material: bool = False,
) -> VoxelField:
    """Record ``plan``'s layers of ``part`` (a scene, or its objects as the view cell sees them:
    :func:`farfield.core.sidedness.seen_from_cell`) (gap-free, seed 000 §3.3.2), cull the texels hidden from
    the whole view cell (seed 003 §4.2 via seed 000 §3.4.1) and keep the rest as voxels.

    Times ``record`` and ``cull`` on ``clock`` and reports each recorded layer.  ``normals`` records
    the normal channel too (:func:`farfield.core.layering.culled.culled_layers`): each voxel then
    keeps the world shading normal of the surface its texel shows (:attr:`VoxelField.normal`);
    ``material`` (with ``normals``) its material and emission too (:attr:`VoxelField.material`).
    """
    xs, ys, ls, colours, normal, materials = [], [], [], [], [], []
    covered = culled = drawn = 0
    for layer in culled_layers(part, plan, culling, clock, normals=normals, material=material):
        with clock("cull"):
            covered += layer.covered
            culled += layer.culled
            drawn += layer.drawn
            row, col = np.nonzero(layer.kept)  # row-major: sorted by (y, x) within the layer
            xs.append(col.astype(np.int64))
            ys.append(row.astype(np.int64))
            ls.append(np.full(row.shape, layer.index, dtype=np.int64))
            texels = layer.image[row, col]
            colours.append(texels[:, :4])
            normal.append(texels[:, 4:8])
            materials.append(texels[:, 8:])
        clock.report("record", layer.index + 1, plan.count)
    x = np.concatenate(xs) if xs else np.zeros(0, np.int64)
    if x.size == 0:
        raise LayerPlanError("the part left no visible texel in any layer (is it empty or fully transparent?)")
    layer = np.concatenate(ls)
    stats = {
        "texels_covered": covered,
        "texels_culled": culled,
        "voxels": int(x.size),
        "triangles_drawn": drawn,
        "layers": int(np.unique(layer).size),
    }
    return VoxelField(
        plan,
        x,
        np.concatenate(ys),
        layer,
        np.concatenate(colours),
        stats,
        np.concatenate(normal) if normals else None,
        np.concatenate(materials) if material and normals else None,
    )

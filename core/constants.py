"""Numeric tolerances and hard limits, in one place (after trimesh's ``tol``).

Each value carries the reason it is what it is.  Geometry is float64 throughout ``core``.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class Tolerances:
    # Relative tolerance for "touching": a distance below rel_touch * (scene extent) counts as zero.
    # float64 has ~16 significant digits; 1e-9 leaves room for a few hundred rounding steps.
    rel_touch: float = 1e-9
    # Largest coordinate magnitude a scene may have, in scene units.  Beyond 1e12 float64 keeps
    # fewer than 4 significant digits of millimetre detail at continental scale, and float32 GL
    # upload (7 digits) is meaningless; such files are corrupt or in the wrong units.
    max_coordinate: float = 1e12
    # Smallest positive extent (scene units) of a scene or view cell: below this the float64
    # relative error of differences of coordinates near max_coordinate exceeds the extent.
    min_extent: float = 1e-12
    # Relative slack before rounding a real number of texels up to an integer, so that values that
    # are integers in exact arithmetic do not round up to the next one after a rescaling (1 ulp).
    rel_round: float = 1e-12
    # Largest number of layers a plan may produce before it is refused as absurd (memory: every
    # layer is at least one texture page).
    max_layers: int = 100_000
    # Largest texture resolution (texels per side) a layer plan may ask for.
    max_texture_resolution: int = 65_536
    # Largest layer texture (texels per side) a placement may choose: the least GL_MAX_TEXTURE_SIZE,
    # GL_MAX_RENDERBUFFER_SIZE and GL_MAX_VIEWPORT_DIMS OpenGL 4.5 guarantees (llvmpipe's own), so that
    # whichever worker bakes a chosen impostor can draw its layers (render/context.check_target_size).
    drawable_texture_resolution: int = 16_384
    # Relative margin on the parallax budget of a shared one-pixel budget (core/layering/plan.py): the
    # largest parallax over the frustum is searched on a grid of rays, which found it to within
    # 4e-4 relative of a 16 times finer grid on every plan tried, wide frusta included.
    parallax_grid: float = 1e-3
    # Slack on the cosine limit of the exact cone-against-box test (core/placement/cone_box.py): a pair
    # within it of the limit counts as meeting, so that rounding (of the edge's critical point, about
    # 1e-16 relative, squared near the maximum) never drops an element a view can see.
    cone_cos: float = 1e-9


TOL = Tolerances()

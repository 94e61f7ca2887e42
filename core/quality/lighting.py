"""Deferred shading of (h, w) G-buffers: sRGB albedo and world-space unit normals per pixel, lit by
one directional light and an ambient term, to (h, w, 3) uint8 sRGB, as three.js draws it.

An impostor that carries normals is judged lit: the source geometry and the impostor are drawn
into G-buffers from the same camera and both are shaded here with the same lights
(:func:`default_lights`, one at a time, each with :data:`AMBIENT`).  A GLB viewer must then light
the impostor the same way, so :func:`shade` is the metallic-roughness BRDF of glTF 2.0
(Appendix B, "BRDF Implementation": Lambert diffuse, GGX microfacet specular with the
height-correlated Smith visibility, Schlick Fresnel, F0 = 0.04 for dielectrics) in the arithmetic
three.js r0.187 ``MeshStandardMaterial`` uses for a ``DirectionalLight`` and an ``AmbientLight``
with no environment map, no tone mapping and sRGB output (shader chunks ``common``,
``lights_pars_begin``, ``lights_physical_fragment``, ``lights_fragment_begin``,
``lights_physical_pars_fragment``, ``lights_fragment_end``, ``colorspace_pars_fragment``,
``meshphysical`` of ``src/renderers/shaders``).

Where three.js departs from the glTF appendix, this module follows three.js:

1. Diffuse weight.  glTF's ``fresnel_mix`` weights diffuse by ``1 - F`` with the dielectric
   Fresnel F = F_Schlick(0.04, 1, V·H): three.js does the same for direct light (RE_Direct_Physical:
   "glTF fresnel_mix"), with diffuse colour ``albedo * (1 - metallic)`` and F0 0.04 whatever the
   metalness (the metal's share is in its specular term).
2. Fresnel.  Not ``(1 - V·H)^5`` but Epic's fit ``exp2((-5.55473 V·H - 6.98316) V·H)`` (F_Schlick in
   ``common``): at most 0.0038 apart (near V·H = 0.055), 0.00017 at normal incidence.
3. Multi-scattering.  glTF has none.  three.js multiplies direct specular by
   ``1 + F0 (1 / (scale + bias) - 1)`` (Turquin 2019) from its DFG table at (roughness, N·V),
   :mod:`farfield.core.quality.dfg`, read bilinearly with clamp-to-edge as the GPU reads it (so
   roughness 1 reads the table's last texel centre, roughness 31/32).
4. Roughness.  Clamped to at least 0.045 (Filament's minimum), then three.js adds
   ``geometryRoughness``, the largest screen-space derivative of the unperturbed view-space normal
   (lights_physical_fragment), and clamps to 1.  That term depends on the mesh drawn, not on the
   material: on a flat impostor quad (a normal map over a plane) it is 0, on a smooth curved
   source it grows with curvature per pixel.  :func:`shade` takes it as ``geometry_roughness``
   (default 0, as three.js sees a normal-mapped impostor); :func:`geometry_roughness` computes
   three.js's value from a normal G-buffer where a test must match a curved mesh.
5. Ambient.  glTF defines no ambient light.  three.js's AmbientLight colour × intensity is an
   irradiance: it reaches the diffuse layer through Lambert's 1/π (RE_IndirectDiffuse_Physical),
   less the share the specular layer keeps, ``F_ss E_ss + F_ms E_ms`` with F0 0.04 (Fdez-Agüera
   2019, from the DFG table at N·V; three.js takes that share with F0 0.04 whatever the
   metalness).  With no environment map the indirect specular term is 0, so a metal (no diffuse
   layer) lit by ambient alone is black.
6. Directional light.  Irradiance is ``colour * intensity * saturate(N·L)`` (no π); N·L, N·V, N·H
   and V·H are clamped to 0..1 (``saturate``), so a normal facing away from the light gets
   ambient only and one facing away from the viewer is shaded as if seen at grazing (N·V = 0).
   three.js flips the normal of a back face of a double-sided material before shading; a
   G-buffer's normal is taken as given (flip it there if that is meant).
7. Occlusion and emission.  glTF's ``occlusionTexture`` is three.js's ``aoMap`` (channel R,
   ``aoMapIntensity`` = ``strength``; aomap_fragment): ``1 + strength (R - 1)`` multiplies the
   *indirect diffuse* term only (the ambient light's; indirect specular is 0 without an environment
   map), never direct light.  Emission (``emissive`` × ``emissiveMap`` × ``emissiveIntensity``,
   emissivemap_fragment) is added to the outgoing radiance, unlit and unoccluded.
   :func:`shade` takes both per pixel (``occlusion``, ``emissive``); with neither given the
   result is what it was before they existed, bit for bit.
8. Output.  Linear radiance clamped to 0..1 and encoded with the sRGB curve
   (:func:`farfield.core.colour_space.linear_to_srgb`; three.js's sRGBTransferOETF writes the
   exponent as 0.41666, within 1e-5 of 1/2.4), rounded to 8 bits as the canvas stores it.

Seed pointers: Khronos glTF 2.0 specification, Appendix B; three.js r0.187 (npm ``three`` 0.187.0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from farfield.core.colour_space import linear_to_srgb, srgb_to_linear
from farfield.core.quality.dfg import dfg

# three.js's constants (common, lights_physical_fragment, bsdfs), kept so the arithmetic matches.
MIN_ROUGHNESS = 0.045  # "punctual lights need a minimum roughness to show a highlight"
VISIBILITY_EPSILON = 1e-6  # EPSILON in V_GGX_SmithCorrelated's max(gv + gl, EPSILON)
DIELECTRIC_F0 = 0.04  # glTF Appendix B and three.js without IOR
F_AVERAGE = DIELECTRIC_F0 + (1.0 - DIELECTRIC_F0) / 21.0  # computeMultiscattering's Favg (F90 = 1)

# Lights of intensity 0.85π and an ambient irradiance of 0.15π: a diffuse surface facing the light
# reflects about its albedo (0.85 + 0.15, less Fresnel), one facing away 15% of it, so lit and shadowed
# sides both stay within 8-bit sRGB's resolution and diffuse white does not clip.
DIRECT_INTENSITY = 0.85 * math.pi
AMBIENT = np.full(3, 0.15 * math.pi)  # (3,) float64 linear RGB irradiance (three.js AmbientLight colour × intensity)


@dataclass(frozen=True, slots=True)
class DirectionalLight:
    """A light at infinity: ``direction`` (3,) float64 unit vector from the surface toward the
    light (world frame), ``colour`` (3,) float64 linear RGB, ``intensity`` (three.js's meaning: the
    irradiance on a surface facing the light is ``colour * intensity``)."""

    direction: np.ndarray  # (3,) float64, unit, toward the light
    colour: np.ndarray  # (3,) float64, linear RGB
    intensity: float


def default_lights(up=(0.0, 1.0, 0.0)) -> tuple[DirectionalLight, ...]:
    """The five test lights, white, of intensity :data:`DIRECT_INTENSITY`, around ``up`` (3,).

    Overhead (elevation 90°); three at 35° elevation, azimuths 0°, 120° and 240°, which light every
    side of an object from above as sun and sky do; and one grazing at 5° elevation, azimuth 60°,
    where N·L changes fastest with the normal, so that normal errors show most.  Azimuth 0 is the
    world axis least aligned with ``up`` made perpendicular to it (+x for the default), azimuth 90°
    is ``up × that``.  ``up`` defaults to +y: glTF's up, and the one farfield's procedural scenes
    use (``core/procedural.py``); pass (0, 0, 1) for a z-up scene.

    >>> lights = default_lights()
    >>> len(lights), lights[0].direction.round(6).tolist()
    (5, [0.0, 1.0, 0.0])
    >>> [round(math.degrees(math.asin(light.direction[1])), 3) for light in lights]
    [90.0, 35.0, 35.0, 35.0, 5.0]
    >>> default_lights((0, 0, 2))[1].direction.round(4).tolist()  # z up: azimuth 0 is +x
    [0.8192, 0.0, 0.5736]
    """
    up = np.asarray(up, dtype=np.float64)
    up = up / np.linalg.norm(up)
    axis = np.eye(3)[int(np.argmin(np.abs(up)))]
    east = axis - (axis @ up) * up
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    lights = []
    for elevation, azimuth in ((90.0, 0.0), (35.0, 0.0), (35.0, 120.0), (35.0, 240.0), (5.0, 60.0)):
        e, a = math.radians(elevation), math.radians(azimuth)
        d = math.cos(e) * (math.cos(a) * east + math.sin(a) * north) + math.sin(e) * up
        lights.append(DirectionalLight(d / np.linalg.norm(d), np.ones(3), DIRECT_INTENSITY))
    return tuple(lights)


def _dot(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(...) row-wise dot products of (..., 3) arrays."""
    return np.einsum("...i,...i->...", a, b)


def _saturate(x: np.ndarray) -> np.ndarray:
    return np.clip(x, 0.0, 1.0)


def f_schlick(f0, f90, dot_vh: np.ndarray) -> np.ndarray:
    """Fresnel reflectance (..., c) for ``f0`` (c,) or (..., c), ``f90`` and V·H (...): three.js's
    F_Schlick (Epic's exponential fit of Schlick's ``(1 - V·H)^5``).

    >>> f_schlick(0.04, 1.0, np.array([1.0, 0.5, 0.0])).round(4).tolist()
    [[0.0402], [0.0726], [1.0]]
    """
    fresnel = np.exp2((-5.55473 * dot_vh - 6.98316) * dot_vh)[..., None]
    return np.asarray(f0) * (1.0 - fresnel) + f90 * fresnel


def radiance(
    albedo: np.ndarray,
    normal: np.ndarray,
    view: np.ndarray,
    light: DirectionalLight,
    ambient=AMBIENT,
    roughness=1.0,
    metallic=0.0,
    geometry_roughness=0.0,
    occlusion=None,
    emissive=None,
) -> np.ndarray:
    """(h, w, 3) float64 linear outgoing radiance, unclamped, of the G-buffer lit by ``light`` and
    ``ambient``: what :func:`shade` encodes (its parameters are :func:`shade`'s).

    >>> n = np.array([[[0.0, 0.0, 1.0]]]); grey = np.full((1, 1, 3), 128, np.uint8)
    >>> behind = DirectionalLight(np.array([0.0, 0.0, -1.0]), np.ones(3), math.pi)
    >>> radiance(grey, n, n, behind, ambient=np.zeros(3)).tolist()
    [[[0.0, 0.0, 0.0]]]
    """
    base = srgb_to_linear(np.asarray(albedo, dtype=np.float64) / 255.0)  # (h, w, 3) material.diffuseColor
    n = np.asarray(normal, dtype=np.float64)
    v = np.asarray(view, dtype=np.float64)
    metal = np.asarray(metallic, dtype=np.float64)[..., None]  # (h, w, 1) or (1,)
    diffuse = base * (1.0 - metal)  # material.diffuseContribution
    f0 = DIELECTRIC_F0 * (1.0 - metal) + base * metal  # specularColorBlended = mix(0.04, base, metalness)
    # lights_physical_fragment: max(roughness, 0.045) + geometryRoughness, at most 1
    rough = np.minimum(
        np.maximum(np.asarray(roughness, dtype=np.float64), MIN_ROUGHNESS) + np.asarray(geometry_roughness), 1.0
    )
    rough = np.broadcast_to(rough, n.shape[:-1])
    dot_nv = _saturate(_dot(n, v))
    scale, bias = np.moveaxis(dfg(rough, dot_nv), -1, 0)  # material.dfg
    energy = scale + bias  # EssMs: single-scattering energy in a white furnace

    # direct light (RE_Direct_Physical)
    to_light = np.asarray(light.direction, dtype=np.float64)
    dot_nl = _saturate(_dot(n, to_light))
    irradiance = dot_nl[..., None] * (np.asarray(light.colour, dtype=np.float64) * float(light.intensity))
    half = to_light + v
    length = np.linalg.norm(half, axis=-1, keepdims=True)
    # normalize(L + V) is undefined where the light is straight behind the eye's ray; three.js's
    # result there is NaN in exact arithmetic, and N·L is 0 or N·V is 0: any unit vector will do.
    half = np.where(length > 0.0, half / np.where(length > 0.0, length, 1.0), n)
    dot_nh = _saturate(_dot(n, half))
    dot_vh = _saturate(_dot(v, half))
    alpha = np.maximum(rough, MIN_ROUGHNESS) ** 2  # BRDF_GGX: "UE4's roughness"
    a2 = alpha * alpha
    gv = dot_nl * np.sqrt(a2 + (1.0 - a2) * dot_nv**2)
    gl = dot_nv * np.sqrt(a2 + (1.0 - a2) * dot_nl**2)
    visibility = 0.5 / np.maximum(gv + gl, VISIBILITY_EPSILON)  # V_GGX_SmithCorrelated
    denom = dot_nh**2 * (a2 - 1.0) + 1.0
    distribution = a2 / (math.pi * denom**2)  # D_GGX
    compensation = 1.0 + f0 * (1.0 / energy[..., None] - 1.0)  # multiScatteringCompensation
    specular = f_schlick(f0, 1.0, dot_vh) * (visibility * distribution)[..., None] * compensation
    diffuse_weight = 1.0 - f_schlick(DIELECTRIC_F0, 1.0, dot_vh)  # glTF fresnel_mix
    direct = irradiance * (specular + diffuse / math.pi * diffuse_weight)

    # ambient light (RE_IndirectDiffuse_Physical with computeMultiscattering, F0 0.04, F90 1)
    single = DIELECTRIC_F0 * scale + bias  # FssEss
    lost = 1.0 - energy  # Ems
    multi = single * F_AVERAGE / (1.0 - lost * F_AVERAGE) * lost  # Fms * Ems
    indirect = np.asarray(ambient, dtype=np.float64) * diffuse / math.pi * (1.0 - single - multi)[..., None]
    if occlusion is not None:  # aomap_fragment: reflectedLight.indirectDiffuse *= ambientOcclusion
        indirect = indirect * np.asarray(occlusion, dtype=np.float64)[..., None]
    out = direct + indirect
    if emissive is not None:  # totalEmissiveRadiance, added unlit
        out = out + np.asarray(emissive, dtype=np.float64)
    return out


def shade(
    albedo: np.ndarray,
    normal: np.ndarray,
    view: np.ndarray,
    light: DirectionalLight,
    ambient=AMBIENT,
    roughness=1.0,
    metallic=0.0,
    geometry_roughness=0.0,
    occlusion=None,
    emissive=None,
) -> np.ndarray:
    """(h, w, 3) uint8 sRGB: the G-buffer lit by ``light`` and ``ambient`` as three.js's
    ``MeshStandardMaterial`` lights it (the module docstring lists where that departs from glTF).

    Parameters
    ----------
    albedo : (h, w, 3) uint8, sRGB-encoded base colour (texture × factor × vertex colour)
    normal : (h, w, 3) float, world-space unit shading normals
    view : (h, w, 3) float, world-space unit vectors from the surface toward the eye
        (:func:`view_directions`)
    light : DirectionalLight
    ambient : (3,) float, linear RGB irradiance (three.js AmbientLight colour × intensity)
    roughness, metallic : float or (h, w) float, glTF's perceptual roughness and metalness in 0..1
    geometry_roughness : float or (h, w) float
        three.js's screen-space ``geometryRoughness`` added to the roughness (0 for a flat
        normal-mapped quad; :func:`geometry_roughness` for a curved mesh).
    occlusion : None, float or (h, w) float
        Ambient occlusion in 0..1 (glTF ``1 + strength (R - 1)``), multiplying the ambient
        (indirect diffuse) term only, as three.js's aoMap does; None: 1.
    emissive : None or (3,) or (h, w, 3) float
        Linear emitted radiance (glTF ``emissiveFactor`` × decoded ``emissiveTexture``), added;
        None: 0.

    The light's term is 0 where N·L ≤ 0; a pixel there gets the ambient term only.

    >>> n = np.array([[[0.0, 0.0, 1.0]]]); white = np.full((1, 1, 3), 255, np.uint8)
    >>> up = DirectionalLight(np.array([0.0, 0.0, 1.0]), np.ones(3), math.pi)
    >>> shade(white, n, n, up, ambient=np.zeros(3)).tolist()  # white facing light and eye
    [[[252, 252, 252]]]
    >>> shade(white, n, n, up, ambient=np.zeros(3), roughness=0.2).tolist()  # the highlight clips
    [[[255, 255, 255]]]
    >>> down = DirectionalLight(np.array([0.0, 0.0, -1.0]), np.ones(3), math.pi)
    >>> shade(white, n, n, down, ambient=np.zeros(3)).tolist()  # lit from behind
    [[[0, 0, 0]]]
    """
    linear = radiance(
        albedo, normal, view, light, ambient, roughness, metallic, geometry_roughness, occlusion, emissive
    )
    return np.round(linear_to_srgb(linear) * 255.0).astype(np.uint8)


def view_directions(camera) -> np.ndarray:
    """(h, w, 3) float64 world-space unit vectors from each pixel's surface point toward the eye of
    ``camera`` (a :class:`farfield.core.render.raster.Camera`): minus the ray through the pixel's
    centre, top row first, ``offset`` included.

    >>> from farfield.core.render.raster import Camera
    >>> c = Camera.look_at(np.zeros(3), np.array([0.0, 5.0, 0.0]), math.radians(60.0), 5, 0.1, 10.0)
    >>> view_directions(c)[2, 2].round(6).tolist()  # the centre pixel: minus forward
    [-0.0, -1.0, -0.0]
    >>> d = view_directions(c); bool(d[0, 0] @ c.up < 0 and d[0, 0] @ c.right > 0)  # top left
    True
    """
    n = int(camera.resolution)
    t = math.tan(0.5 * camera.fov)
    centres = (np.arange(n) + 0.5) / n * 2.0 - 1.0  # -1..1 across the image
    tx = camera.offset[0] + centres * t  # (w,) left to right
    ty = camera.offset[1] - centres * t  # (h,) top row first
    rays = (
        np.asarray(camera.forward, dtype=np.float64)
        + tx[None, :, None] * np.asarray(camera.right, dtype=np.float64)
        + ty[:, None, None] * np.asarray(camera.up, dtype=np.float64)
    )
    return -rays / np.linalg.norm(rays, axis=-1, keepdims=True)


def geometry_roughness(normal: np.ndarray, camera) -> np.ndarray:
    """(h, w) float64 three.js's ``geometryRoughness`` of an (h, w, 3) world-normal G-buffer seen
    by ``camera``: the largest component of max(|dFdx n|, |dFdy n|) of the view-space normal
    (lights_physical_fragment), with derivatives taken as a GPU takes them, between the pixels of
    each 2 × 2 quad (per row and per column of the quad, "fine" derivatives).

    Quads are counted from the image's bottom-left pixel, as GL's window coordinates are; outside
    what was drawn (and at a silhouette, where a GPU uses helper pixels) the value means nothing.

    >>> from farfield.core.render.raster import Camera
    >>> c = Camera.look_at(np.zeros(3), np.array([0.0, 5.0, 0.0]), math.radians(60.0), 4, 0.1, 10.0)
    >>> flat = np.broadcast_to([0.0, -1.0, 0.0], (4, 4, 3))
    >>> float(geometry_roughness(flat, c).max())
    0.0
    """
    n = np.asarray(normal, dtype=np.float64)
    h, w = n.shape[:2]
    # view space (three.js): x right, y up, z toward the eye; the max of |components| depends on it
    rot = np.stack([camera.right, camera.up, -np.asarray(camera.forward, dtype=np.float64)])
    nv = (n @ rot.T)[::-1]  # bottom row first, as GL's quads are laid
    cols = np.arange(w)
    rows = np.arange(h)
    left, right = np.minimum(cols & ~1, w - 1), np.minimum(cols | 1, w - 1)
    low, high = np.minimum(rows & ~1, h - 1), np.minimum(rows | 1, h - 1)
    dx = np.abs(nv[:, right] - nv[:, left])
    dy = np.abs(nv[high] - nv[low])
    return np.maximum(dx, dy).max(axis=-1)[::-1]


def sun(azimuth_deg: float = 60.0, elevation_deg: float = 35.0) -> DirectionalLight:
    """One white sun of the lit evaluation's intensity (:data:`DIRECT_INTENSITY`),
    +y up, toward ``(cos e cos a, sin e, -cos e sin a)``: azimuth 0 along +x, 90° along up × x =
    -z, as :func:`default_lights` and the 3D view's ``?azimuth=`` and
    ``?elevation=`` (api/dashboard/viewer.js; its defaults, 60° and 35°, are these).

    >>> [bool(np.allclose(sun(a, 35.0).direction, d.direction)) for a, d in zip((0, 120, 240), default_lights()[1:4])]
    [True, True, True]
    >>> sun(0.0, 90.0).direction.round(6).tolist()
    [0.0, 1.0, -0.0]
    """
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    direction = np.array([math.cos(e) * math.cos(a), math.sin(e), -math.cos(e) * math.sin(a)])
    return DirectionalLight(direction / np.linalg.norm(direction), np.ones(3), DIRECT_INTENSITY)

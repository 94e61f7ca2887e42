"""Rendering-time and memory models of a placement (seed 000 §5.2.1, §5.8.1 "Parameter Estimation").

A :class:`CostModel` predicts, for the *target* renderer (ours after ``farfield calibrate``, or an
engine whose coefficients a user types):

* drawing geometry: ``t = a * draw_calls + b * triangles + c * pixels`` per object, plus ``d`` once
  per frame (the thesis found draw calls the bottleneck on its machine, §5.8.1);
* drawing an impostor: ``t = e * pixels + f * quads + g`` per impostor (fill-rate bound, §5.8.1);
* an impostor's memory: ``h * (layers * texels_per_layer) ** p + k`` bytes, the thesis's heuristic
  ("the resolution of the texture used for recording every impostor layer and the number of
  layers", §5.8.1), and its quads ``q * layers * texels_per_layer ** beta`` (for ``f``; ``beta``,
  ``quads_exponent``, is 0 in a model that predates it: a fixed ``quads_per_layer``).  ``p``
  (``memory_exponent``) is 1 unless a calibration fits it: on llvmpipe's measurements memory grew
  as about the 0.6th power of layers x texels over six orders of magnitude (a layer records only
  its slab of the part, and culling removes more of the texels the more layers there are), and a
  linear fit missed the small impostors by several times (:data:`LLVMPIPE_MODEL`).

``kind`` is ``"frame_ms"`` (times in milliseconds) or ``"primitives"`` (``t`` counts triangles: the
primitive budget of seed 004 and of the power-plant test, §5.8.3; an impostor costs its quads'
two triangles each).  Coefficients are fitted by non-negative least squares
(:func:`fit_linear`); a model is a small JSON document (:meth:`CostModel.to_dict`) tagged with the
GL renderer it was measured on.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
from scipy.optimize import nnls

from farfield.core.errors import FarfieldError

FORMAT = "farfield-cost-model"
VERSION = 1

Kind = Literal["frame_ms", "primitives"]

GEOMETRY_TERMS = ("draw_call", "triangle", "pixel", "frame")  # a, b, c, d
IMPOSTOR_TERMS = ("pixel", "quad", "impostor")  # e, f, g
MEMORY_TERMS = ("layer_texel", "impostor", "quads_per_layer")  # h, k, q


class CostModelError(FarfieldError):
    """A cost-model document or coefficient set that cannot be used."""


@dataclass(frozen=True, slots=True)
class LinearFit:
    """A least-squares fit ``y ~ X @ coefficients`` with its quality.

    ``r2`` on the samples fitted; ``holdout_rel_error_median`` / ``_p90`` the relative error
    ``|predicted - measured| / measured`` on the held-out samples (nan when none were held out).
    """

    coefficients: tuple[float, ...]
    names: tuple[str, ...]
    r2: float
    holdout_rel_error_median: float
    holdout_rel_error_p90: float
    samples: int
    holdout: int
    quantile: float | None = None  # fit_quantile's q; None: least squares
    holdout_share_above: float = math.nan  # held-out samples measured above the prediction

    def to_dict(self) -> dict:
        def num(x: float):
            return None if not math.isfinite(x) else float(x)

        fitted = {
            "coefficients": dict(zip(self.names, map(float, self.coefficients))),
            "r2": num(self.r2),
            "holdout_rel_error_median": num(self.holdout_rel_error_median),
            "holdout_rel_error_p90": num(self.holdout_rel_error_p90),
            "samples": self.samples,
            "holdout": self.holdout,
        }
        if self.quantile is not None:
            fitted |= {"quantile": self.quantile, "holdout_share_above": num(self.holdout_share_above)}
        return fitted


def fit_linear(features, target, names, holdout: float = 0.25, seed: int = 0) -> LinearFit:
    """Non-negative least squares of ``target`` (n,) on ``features`` (n, k) (a cost cannot be
    negative), fitted on a seeded random ``1 - holdout`` share of the rows and judged on the rest.

    >>> rng = np.random.default_rng(1)
    >>> x = rng.uniform(0, 100, (200, 3)); x[:, 2] = 1.0
    >>> fit = fit_linear(x, x @ np.array([0.5, 0.02, 3.0]), ("a", "b", "c"))
    >>> [round(c, 6) for c in fit.coefficients], round(fit.r2, 6), fit.holdout_rel_error_median < 1e-9
    ([0.5, 0.02, 3.0], 1.0, True)
    """
    x = np.asarray(features, dtype=np.float64)
    y = np.asarray(target, dtype=np.float64).reshape(-1)
    if x.ndim != 2 or x.shape[0] != y.shape[0] or x.shape[1] != len(names):
        raise CostModelError(f"features {x.shape} and target {y.shape} do not match {len(names)} names")
    if x.shape[0] < x.shape[1]:
        raise CostModelError(f"{x.shape[0]} samples cannot fit {x.shape[1]} coefficients")
    test, train = _holdout_split(x.shape[0], x.shape[1], holdout, seed)
    held = test.size
    # Scale columns to unit norm so that nnls treats per-pixel and per-draw-call terms alike.
    scale = np.linalg.norm(x[train], axis=0)
    scale[scale == 0.0] = 1.0
    solution, _ = nnls(x[train] / scale, y[train])
    coefficients = solution / scale
    residual = y[train] - x[train] @ coefficients
    total = float(np.sum((y[train] - y[train].mean()) ** 2))
    r2 = 1.0 - float(np.sum(residual**2)) / total if total > 0.0 else (1.0 if not residual.any() else 0.0)
    median, p90 = _relative_errors(x[test] @ coefficients, y[test])
    return LinearFit(tuple(float(c) for c in coefficients), tuple(names), r2, median, p90, int(train.size), int(held))


def fit_quantile(features, target, names, quantile: float, holdout: float = 0.25, seed: int = 0) -> LinearFit:
    """Non-negative linear quantile regression: the coefficients minimising the pinball loss of the
    relative error ``(target - prediction) / target`` (so a 0.1 ms frame weighs as a 10 ms one) as a
    linear program (HiGHS).  A frame-time budget is a promise: with ``quantile`` 0.9 the model's
    time is one that about nine frames in ten with those counts stay under, where least squares
    (:func:`fit_linear`) puts it at their mean.  ``target`` must be > 0.

    Exactly (the LP's optimum; raising the constant term is always allowed): at most a share
    ``1 - quantile`` of the training rows *weighted by 1 / target* are measured above the
    prediction.  Unweighted, that share is about ``1 - quantile`` where the relative spread is alike
    across rows, and larger where the slow rows are spikes (they weigh less): above a 0.9 fit of 60
    frames of 0.05-0.2 ms drawn while another process drew, 0.09-0.20 of the fitted frames (8 seeds).

    >>> rng = np.random.default_rng(2)
    >>> x = np.column_stack([rng.uniform(1, 100, 2000), np.ones(2000)])
    >>> y = (0.5 * x[:, 0] + 3.0) * rng.uniform(0.8, 1.2, 2000)  # +-20 % around the mean; its 0.9 quantile 1.16x
    >>> fit = fit_quantile(x, y, ("a", "d"), 0.9)
    >>> [round(c / 1.16, 1) for c in fit.coefficients], 0.85 < 1 - fit.holdout_share_above < 0.95
    ([0.5, 3.0], True)
    """
    from scipy.optimize import linprog
    from scipy.sparse import csr_matrix, hstack, identity

    x = np.asarray(features, dtype=np.float64)
    y = np.asarray(target, dtype=np.float64).reshape(-1)
    if x.ndim != 2 or x.shape[0] != y.shape[0] or x.shape[1] != len(names):
        raise CostModelError(f"features {x.shape} and target {y.shape} do not match {len(names)} names")
    if not 0.0 < quantile < 1.0:
        raise CostModelError(f"a quantile lies in (0, 1), got {quantile!r}")
    if not np.all(y > 0.0):
        raise CostModelError("a quantile fit of relative errors needs every measured value > 0")
    if x.shape[0] < x.shape[1]:
        raise CostModelError(f"{x.shape[0]} samples cannot fit {x.shape[1]} coefficients")
    test, train = _holdout_split(x.shape[0], x.shape[1], holdout, seed)
    rel = x[train] / y[train, None]  # prediction / measured per unit coefficient
    scale = np.linalg.norm(rel, axis=0)
    scale[scale == 0.0] = 1.0
    n, k = rel.shape
    # 1 - rel @ beta = above - below, above, below >= 0: minimise q * above + (1 - q) * below.
    a_eq = hstack([csr_matrix(rel / scale), identity(n, format="csr"), -identity(n, format="csr")], format="csr")
    cost = np.concatenate([np.zeros(k), np.full(n, quantile), np.full(n, 1.0 - quantile)])
    solved = linprog(cost, A_eq=a_eq, b_eq=np.ones(n), bounds=(0.0, None), method="highs")
    if solved.status != 0:
        raise CostModelError(f"the quantile fit failed: {solved.message}")
    coefficients = solved.x[:k] / scale
    residual = y[train] - x[train] @ coefficients
    total = float(np.sum((y[train] - y[train].mean()) ** 2))
    r2 = 1.0 - float(np.sum(residual**2)) / total if total > 0.0 else (1.0 if not residual.any() else 0.0)
    predicted = x[test] @ coefficients
    median, p90 = _relative_errors(predicted, y[test])
    above = float(np.mean(y[test] > predicted)) if test.size else math.nan
    return LinearFit(tuple(float(c) for c in coefficients), tuple(names), r2, median, p90, int(train.size), int(test.size),
                     float(quantile), above)  # fmt: skip


def _holdout_split(rows: int, coefficients: int, holdout: float, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """(test, train) row indices: a seeded random ``holdout`` share held out, none when the rest
    could not fit ``coefficients``."""
    order = np.random.default_rng(seed).permutation(rows)
    held = round(holdout * rows)
    held = held if rows - held >= coefficients else 0
    return order[:held], order[held:]


def _relative_errors(predicted: np.ndarray, measured: np.ndarray) -> tuple[float, float]:
    """Median and 90th percentile of ``|predicted - measured| / |measured|`` (nan, nan when empty)."""
    if measured.size == 0:
        return math.nan, math.nan
    rel = np.abs(predicted - measured) / np.maximum(np.abs(measured), 1e-300)
    return float(np.median(rel)), float(np.percentile(rel, 90))


def fit_power(
    x, target, names, holdout: float = 0.25, seed: int = 0, exponent: float | None = None, offset: bool = True
) -> LinearFit:
    """``target ~ h * x**p + k`` (``h > 0``, ``0 <= p <= 2``, ``k >= 0``) by least squares of the
    *logarithms*, fitted and judged like :func:`fit_linear`; ``coefficients`` are ``(h, p, k)``, less
    ``p`` when ``exponent`` fixes it and less ``k`` without ``offset``, named by ``names``; ``r2`` is
    that of ``log(target)``.

    For a positive quantity spanning orders of magnitude whose ratios matter (an impostor's memory,
    ranked by Δt/m, seed 000 Eq. 5.6): a linear least-squares fit is ruled by the largest samples,
    and weighting rows by ``1 / target`` biases it low (an over-estimate costs without bound, an
    under-estimate at most 1).

    >>> x = np.geomspace(1.0, 1e6, 40)
    >>> fit = fit_power(x, 300.0 * x**0.6 + 50.0, ("h", "p", "k"))
    >>> [round(c, 6) for c in fit.coefficients], fit.holdout_rel_error_median < 1e-6
    ([300.0, 0.6, 50.0], True)
    >>> [round(c, 6) for c in fit_power(x, 2.5 * x, ("q",), exponent=1.0, offset=False).coefficients]
    [2.5]
    """
    from scipy.optimize import least_squares

    x = np.asarray(x, dtype=np.float64).reshape(-1)
    y = np.asarray(target, dtype=np.float64).reshape(-1)
    free = 1 + (exponent is None) + bool(offset)
    if x.shape != y.shape or len(names) != free:
        raise CostModelError(f"x {x.shape} and target {y.shape} do not match {len(names)} names ({free} coefficients)")
    if not (np.all(np.isfinite(x) & (x > 0.0)) and np.all(np.isfinite(y) & (y > 0.0))):
        raise CostModelError("a power-law fit needs finite positive x and target")
    if x.size < free:
        raise CostModelError(f"{x.size} samples cannot fit {free} coefficients")
    test, train = _holdout_split(x.size, free, holdout, seed)
    lx, ly = np.log(x[train]), np.log(y[train])

    def unpack(v):  # v = (log h[, p][, k])
        p = v[1] if exponent is None else float(exponent)
        k = v[-1] if offset else 0.0
        return math.exp(v[0]), p, k

    def predict(v, at):
        h, p, k = unpack(v)
        return h * at**p + k

    # Start from the straight line through the log-log points (k = 0).
    p0 = (
        float(np.clip(np.polyfit(lx, ly, 1)[0], 0.0, 2.0))
        if exponent is None and np.ptp(lx) > 0.0
        else float(exponent or 1.0)
    )
    start = [float(np.mean(ly - p0 * lx))] + ([p0] if exponent is None else []) + ([0.0] if offset else [])
    lower = [-np.inf] + ([0.0] if exponent is None else []) + ([0.0] if offset else [])
    upper = [np.inf] + ([2.0] if exponent is None else []) + ([np.inf] if offset else [])
    v = least_squares(lambda v: np.log(predict(v, x[train])) - ly, start, bounds=(lower, upper), x_scale="jac").x
    h, p, k = unpack(v)
    coefficients = (h,) + ((p,) if exponent is None else ()) + ((k,) if offset else ())
    residual = np.log(predict(v, x[train])) - ly
    total = float(np.sum((ly - ly.mean()) ** 2))
    r2 = (
        1.0 - float(np.sum(residual**2)) / total
        if total > 0.0
        else (1.0 if not np.any(np.abs(residual) > 1e-12) else 0.0)
    )
    median, p90 = _relative_errors(predict(v, x[test]), y[test])
    return LinearFit(
        tuple(float(c) for c in coefficients), tuple(names), r2, median, p90, int(train.size), int(test.size)
    )


def _fit(value) -> dict:
    """A model document's ``fit`` section: an object (its fit statistics), or nothing."""
    if value is None:
        return {}
    if not isinstance(value, dict):
        raise CostModelError(f"cost model 'fit' must be an object, got {type(value).__name__}")
    return dict(value)


def _number(value, what: str) -> float:
    try:
        return float(value)
    except (TypeError, ValueError):
        raise CostModelError(f"cost model {what}: a number expected, got {value!r}") from None


@dataclass(frozen=True, slots=True)
class CostModel:
    """Coefficients of the time and memory models (see the module docstring)."""

    kind: Kind
    geometry: tuple[float, float, float, float]  # a (per draw call), b (per triangle), c (per pixel), d (per frame)
    impostor: tuple[float, float, float]  # e (per pixel), f (per quad), g (per impostor)
    memory: tuple[float, float, float]  # h (bytes per layer texel), k (bytes per impostor), q (quads per layer)
    renderer: str = "unspecified"
    fit: dict = field(default_factory=dict)  # the fits' quality, as calibration measured it
    source: str = "given"  # "calibration", "given", "builtin" or "primitives"
    memory_exponent: float = 1.0  # p of the memory model, in (0, 2]
    quads_exponent: float = 0.0  # quads per layer = q * texels_per_layer ** this, in [0, 1]

    def __post_init__(self) -> None:
        for name, values, size in (
            ("geometry", self.geometry, 4),
            ("impostor", self.impostor, 3),
            ("memory", self.memory, 3),
        ):
            values = tuple(float(v) for v in values)
            if len(values) != size or not all(math.isfinite(v) and v >= 0.0 for v in values):
                raise CostModelError(f"cost model {name} needs {size} finite coefficients >= 0, got {list(values)}")
            object.__setattr__(self, name, values)
        if self.kind not in ("frame_ms", "primitives"):
            raise CostModelError(f"cost model kind must be 'frame_ms' or 'primitives', got {self.kind!r}")
        if not any(self.geometry[:3]):
            raise CostModelError("cost model: drawing geometry costs nothing (a, b and c are all 0)")
        if self.memory[0] <= 0.0:
            raise CostModelError("cost model: memory per layer texel (h) must be > 0")
        exponent = float(self.memory_exponent)
        if not (math.isfinite(exponent) and 0.0 < exponent <= 2.0):
            raise CostModelError(f"cost model: memory exponent must lie in (0, 2], got {self.memory_exponent!r}")
        object.__setattr__(self, "memory_exponent", exponent)
        beta = float(self.quads_exponent)
        if not (math.isfinite(beta) and 0.0 <= beta <= 1.0):
            raise CostModelError(f"cost model: quads exponent must lie in [0, 1], got {self.quads_exponent!r}")
        object.__setattr__(self, "quads_exponent", beta)

    @property
    def unit(self) -> str:
        return "ms" if self.kind == "frame_ms" else "triangles"

    def geometry_time(self, draw_calls, triangles, pixels):
        """Time of drawing objects (per object; arrays broadcast), without the per-frame ``d``."""
        a, b, c, _ = self.geometry
        return (
            a * np.asarray(draw_calls, dtype=np.float64)
            + b * np.asarray(triangles, dtype=np.float64)
            + c * np.asarray(pixels, dtype=np.float64)
        )

    @property
    def frame_time(self) -> float:
        """``d``: what every frame costs before it draws anything."""
        return self.geometry[3]

    def impostor_time(self, pixels, quads):
        """Time of drawing impostors of ``pixels`` covered pixels and ``quads`` quads (arrays broadcast)."""
        e, f, g = self.impostor
        return e * np.asarray(pixels, dtype=np.float64) + f * np.asarray(quads, dtype=np.float64) + g

    def memory_bytes(self, layers, texels_per_layer):
        """Estimated bytes of an impostor of ``layers`` layers of ``texels_per_layer`` recorded texels:
        ``h * (layers * texels_per_layer) ** memory_exponent + k``."""
        h, k, _ = self.memory
        texels = np.asarray(layers, dtype=np.float64) * np.asarray(texels_per_layer, dtype=np.float64)
        return h * (texels if self.memory_exponent == 1.0 else texels**self.memory_exponent) + k

    def quads(self, layers, texels_per_layer):
        """Estimated quads of an impostor of ``layers`` layers of ``texels_per_layer`` texels:
        ``q * layers * texels_per_layer ** quads_exponent`` (a layer's box growing cuts more quads
        the larger the layer is on screen).

        >>> m = CostModel("frame_ms", (0.0, 1.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.5), quads_exponent=0.25)
        >>> float(m.quads(10, 10_000))
        50.0
        """
        layers = np.asarray(layers, dtype=np.float64)
        if self.quads_exponent == 0.0:
            return self.memory[2] * layers
        return self.memory[2] * layers * np.asarray(texels_per_layer, dtype=np.float64) ** self.quads_exponent

    def to_dict(self) -> dict:
        return {
            "format": FORMAT,
            "version": VERSION,
            "kind": self.kind,
            "unit": self.unit,
            "renderer": self.renderer,
            "source": self.source,
            "geometry": dict(zip(GEOMETRY_TERMS, self.geometry)),
            "impostor": dict(zip(IMPOSTOR_TERMS, self.impostor)),
            "memory": {
                **dict(zip(MEMORY_TERMS, self.memory)),
                "exponent": self.memory_exponent,
                "quads_exponent": self.quads_exponent,
            },
            "fit": self.fit,
        }

    @classmethod
    def from_dict(cls, data: dict) -> CostModel:
        """Inverse of :meth:`to_dict`; a clear error names what is missing or wrong."""
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise CostModelError(f"not a cost model: expected a JSON object with format {FORMAT!r}")
        if data.get("version") != VERSION:
            raise CostModelError(f"cost model version {data.get('version')!r} is not {VERSION}")

        def terms(section: str, names: tuple[str, ...]) -> tuple[float, ...]:
            values = data.get(section)
            if not isinstance(values, dict) or set(names) - set(values):
                raise CostModelError(f"cost model section {section!r} needs {list(names)}")
            try:
                return tuple(float(values[n]) for n in names)
            except (TypeError, ValueError):
                raise CostModelError(f"cost model section {section!r}: numbers expected") from None

        return cls(
            kind=data.get("kind", "frame_ms"),
            geometry=terms("geometry", GEOMETRY_TERMS),
            impostor=terms("impostor", IMPOSTOR_TERMS),
            memory=terms("memory", MEMORY_TERMS),
            renderer=str(data.get("renderer", "unspecified")),
            fit=_fit(data.get("fit")),
            source=str(data.get("source", "given")),
            memory_exponent=_number(data["memory"].get("exponent", 1.0), "memory exponent"),
            quads_exponent=_number(data["memory"].get("quads_exponent", 0.0), "quads exponent"),
        )

    @classmethod
    def load(cls, path: str | Path) -> CostModel:
        """Read a model written by ``farfield calibrate --out`` (or by hand)."""
        try:
            text = Path(path).read_bytes().decode("utf-8")
        except OSError as error:
            raise CostModelError(f"cannot read cost model {str(path)!r}: {error.strerror or error}") from None
        except UnicodeDecodeError:
            raise CostModelError(f"cost model {str(path)!r} is not JSON: not UTF-8 text") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as error:
            raise CostModelError(f"cost model {str(path)!r} is not JSON: {error}") from None
        return cls.from_dict(data)


# Memory of a layered impostor, ``h * (layers_est * texels_per_layer) ** p + k`` bytes, and quads per
# layer: (h, k, q) and p as ``farfield calibrate`` fitted them on llvmpipe (LLVMPIPE_MODEL below;
# they replaced the provisional linear (0.4, 4096, 12)).  Memory depends on the impostor technique's
# output, not on the renderer, so every model without a calibration of its own uses these.
DEFAULT_MEMORY = (97.75, 0.0, 0.290)
DEFAULT_MEMORY_EXPONENT = 0.6132
# Quads per layer, q * texels_per_layer ** DEFAULT_QUADS_EXPONENT: fitted (log of quads per estimated
# layer, least squares) on the 352 impostors that `bench_placement.py --walkthrough --size 49
# --detail 64 --resolution 128` baked on 2026-12-02 (box and shaft cells, 585 .. 411,445 texels per
# layer): q 0.290, exponent 0.251, r² 0.33, median error 1.36x.  The constant 1.27 quads per layer
# that calibration's far shaft impostors gave was 3.2x low on the placement's (median; 2.5 at 1e3 ..
# 1e4 texels, 5.6 above 1e5), and at 256 px about 4.9 per layer were baked against 1.27.
DEFAULT_QUADS_EXPONENT = 0.251


def primitive_model(memory: tuple[float, float, float] = DEFAULT_MEMORY, memory_exponent: float = DEFAULT_MEMORY_EXPONENT,
                    quads_exponent: float = DEFAULT_QUADS_EXPONENT) -> CostModel:  # fmt: skip
    """The primitive budget (seed 000 §5.8.3; seed 004): a view's cost is the triangles it draws,
    an impostor's the two triangles of each of its quads.

    >>> m = primitive_model()
    >>> float(m.geometry_time(1, 500, 10_000)), float(m.impostor_time(10_000, 30))
    (500.0, 60.0)
    """
    return CostModel("primitives", (0.0, 1.0, 0.0, 0.0), (0.0, 2.0, 0.0), memory, renderer="any (primitive count)", source="primitives", memory_exponent=memory_exponent,
                     quads_exponent=quads_exponent)  # fmt: skip


# The builtin model of this project's CPU machine, which a placement uses when the user gives no
# --cost-model.  Measured 2026-12-04 on a 2-core x86-64 machine with Mesa llvmpipe (LLVM 15.0.6,
# 256 bits) through EGL, with the shader variants of core/render/raster.py, by ``farfield calibrate
# --out model.json`` with the defaults: the procedural city (farfield.core.procedural.city(900, seed=0,
# detail=32): 901 objects, 163,862 triangles), 800 geometry views (200 clusters of 1..256 objects x
# 4), 96 layered impostors (14 random cells refused) drawn from 384 views, 256 px, 45°, seed 0; 24 s.
# Fit quality (R², held-out relative error median / p90): geometry 0.965, 19% / 44%; impostor 0.960,
# 21% / 90% (an impostor adds tenths of a millisecond to a frame, near the timing noise); memory
# 0.975 in log(bytes), 26% / 62%.  The estimate's layers over the planned layers: median 1.02 (0.83
# .. 2.66).  Four runs the same hour (seed 0 three times, seed 1) gave a 0.0127 .. 0.0162 ms per
# draw call, b 7.6e-5 .. 1.23e-4 ms per triangle, c 1.1e-5 .. 1.9e-5 ms per pixel, e 2.7e-5 .. 1.6e-4
# ms per impostor pixel.
# The model it replaces (2026-12-02: a 0.0445, b 4.9e-4, c 5.6e-5; 78 s) was 3.1 .. 4.5x slower in
# its geometry terms and 2.3 .. 8.9x in its impostor terms.  The renderer before the shader variants
# of core/render/raster.py, calibrated the same hour (b 1.58e-4, a 0.0173, c 2.5e-5; 29 s), shows
# the variants made a triangle 1.5x and a pixel 1.7x cheaper than in the run above; the rest is
# the machine, on which that renderer now calibrates 2.7x faster (78 s -> 29 s).  A model is a
# snapshot of its machine: run ``farfield calibrate`` where the budget matters.
# Checked 2026-12-07 against the frames of the benchmark walks (benchmarks/bench_estimate_split.py:
# street, downtown and above the roofs, 128 px, 100 views each, load 3-9): over exactly what a frame
# drew, with its covered pixels, these coefficients gave 1.0 .. 1.2x the measured frame (p50 per
# walk; over 1,500 PVS-culled plain frames p50 1.10, p95 2.05, 8 % under by > 30 %, where an NNLS
# refit on those frames, a 0.0090, b 2.4e-4, c 2.0e-5, d 0, gave p50 1.17 and 25 % under), so they stay; the walks' 3-4x over-estimate was what the estimate counts (pixels capped at 4
# frames where c is per covered pixel, now 1: view_space.DEFAULT_DEPTH_COMPLEXITY; and the CPV's
# enclosing frustum, docs/placement/visibility.md).  A quiet calibration the same morning at 256 px
# gave a 0.0104, b 7.6e-5, c 1.47e-5, d 0.150; two at 128 px (load 2-3) were unstable (c 2.1e-6 and
# 0, d 0, a 0.0091 and 0.0255; R² 0.84, 0.83): at 128 px a pixel is near the timing noise.
LLVMPIPE_MODEL = CostModel(
    "frame_ms",
    geometry=(0.01419, 0.0001076, 1.513e-05, 0.04332),  # ms per draw call, triangle, pixel; per frame
    impostor=(2.749e-05, 0.001199, 0.05759),  # ms per pixel, quad, impostor
    memory=DEFAULT_MEMORY,
    renderer="llvmpipe (LLVM 15.0.6, 256 bits)",
    fit={
        "geometry": {
            "r2": 0.965,
            "holdout_rel_error_median": 0.187,
            "holdout_rel_error_p90": 0.440,
            "samples": 600,
            "holdout": 200,
        },
        "impostor": {
            "r2": 0.960,
            "holdout_rel_error_median": 0.208,
            "holdout_rel_error_p90": 0.897,
            "samples": 288,
            "holdout": 96,
        },
        "memory": {
            "r2": 0.975,
            "r2_of": "log(bytes)",
            "holdout_rel_error_median": 0.260,
            "holdout_rel_error_p90": 0.617,
            "samples": 72,
            "holdout": 24,
        },
        "quads": {
            "r2": 0.328,
            "r2_of": "log(quads / layers_est)",
            "samples": 352,
            "holdout": 0,
            "source": "352 impostors of bench_placement.py --walkthrough --size 49 --detail 64 --resolution 128 (DEFAULT_QUADS_EXPONENT)",
        },
        "empty_frame_ms": 0.105,
        "command": "farfield calibrate --out model.json",
        "machine": "2-core x86-64, Mesa llvmpipe (LLVM 15.0.6, 256 bits), EGL",
        "date": "2026-12-04",
    },
    source="builtin",
    memory_exponent=DEFAULT_MEMORY_EXPONENT,
    quads_exponent=DEFAULT_QUADS_EXPONENT,
)

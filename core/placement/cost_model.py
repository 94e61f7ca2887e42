"""Rendering-time and memory models of a placement (seed 000 §5.2.1, §5.8.1 "Parameter Estimation").

A :class:`CostModel` predicts, for the *target* renderer (ours after ``farfield calibrate``, or an
engine whose coefficients a user types):

* drawing geometry: ``t = a * draw_calls + b * triangles + c * pixels`` per object, plus ``d`` once
  per frame (the thesis found draw calls the bottleneck on its machine, §5.8.1);
* drawing an impostor: ``t = e * pixels + f * quads + g`` per impostor (fill-rate bound, §5.8.1);
* an impostor's memory: ``h * layers * texels_per_layer + k`` bytes, the thesis's heuristic
  ("the resolution of the texture used for recording every impostor layer and the number of
  layers", §5.8.1), and ``quads_per_layer``, the quads a layer is cut into (for ``f``).

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

    def to_dict(self) -> dict:
        def num(x: float):
            return None if not math.isfinite(x) else float(x)

        return {
            "coefficients": dict(zip(self.names, map(float, self.coefficients))),
            "r2": num(self.r2),
            "holdout_rel_error_median": num(self.holdout_rel_error_median),
            "holdout_rel_error_p90": num(self.holdout_rel_error_p90),
            "samples": self.samples,
            "holdout": self.holdout,
        }


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
    order = np.random.default_rng(seed).permutation(x.shape[0])
    held = round(holdout * x.shape[0])
    held = held if x.shape[0] - held >= x.shape[1] else 0
    test, train = order[:held], order[held:]
    # Scale columns to unit norm so that nnls treats per-pixel and per-draw-call terms alike.
    scale = np.linalg.norm(x[train], axis=0)
    scale[scale == 0.0] = 1.0
    solution, _ = nnls(x[train] / scale, y[train])
    coefficients = solution / scale
    residual = y[train] - x[train] @ coefficients
    total = float(np.sum((y[train] - y[train].mean()) ** 2))
    r2 = 1.0 - float(np.sum(residual**2)) / total if total > 0.0 else (1.0 if not residual.any() else 0.0)
    if held:
        rel = np.abs(x[test] @ coefficients - y[test]) / np.maximum(np.abs(y[test]), 1e-300)
        median, p90 = float(np.median(rel)), float(np.percentile(rel, 90))
    else:
        median = p90 = math.nan
    return LinearFit(tuple(float(c) for c in coefficients), tuple(names), r2, median, p90, int(train.size), int(held))


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

    def __post_init__(self) -> None:
        for name, values, size in (("geometry", self.geometry, 4), ("impostor", self.impostor, 3), ("memory", self.memory, 3)):
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

    @property
    def unit(self) -> str:
        return "ms" if self.kind == "frame_ms" else "triangles"

    def geometry_time(self, draw_calls, triangles, pixels):
        """Time of drawing objects (per object; arrays broadcast), without the per-frame ``d``."""
        a, b, c, _ = self.geometry
        return a * np.asarray(draw_calls, dtype=np.float64) + b * np.asarray(triangles, dtype=np.float64) + c * np.asarray(pixels, dtype=np.float64)

    @property
    def frame_time(self) -> float:
        """``d``: what every frame costs before it draws anything."""
        return self.geometry[3]

    def impostor_time(self, pixels, quads):
        """Time of drawing impostors of ``pixels`` covered pixels and ``quads`` quads (arrays broadcast)."""
        e, f, g = self.impostor
        return e * np.asarray(pixels, dtype=np.float64) + f * np.asarray(quads, dtype=np.float64) + g

    def memory_bytes(self, layers, texels_per_layer):
        """Estimated bytes of an impostor of ``layers`` layers of ``texels_per_layer`` recorded texels."""
        h, k, _ = self.memory
        return h * np.asarray(layers, dtype=np.float64) * np.asarray(texels_per_layer, dtype=np.float64) + k

    def quads(self, layers):
        """Estimated quads of an impostor of ``layers`` layers."""
        return self.memory[2] * np.asarray(layers, dtype=np.float64)

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
            "memory": dict(zip(MEMORY_TERMS, self.memory)),
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
            fit=dict(data.get("fit") or {}),
            source=str(data.get("source", "given")),
        )

    @classmethod
    def load(cls, path: str | Path) -> CostModel:
        """Read a model written by ``farfield calibrate --out`` (or by hand)."""
        try:
            text = Path(path).read_text()
        except OSError as error:
            raise CostModelError(f"cannot read cost model {str(path)!r}: {error.strerror or error}") from None
        try:
            data = json.loads(text)
        except json.JSONDecodeError as error:
            raise CostModelError(f"cost model {str(path)!r} is not JSON: {error}") from None
        return cls.from_dict(data)


# Memory of a layered impostor per planned layer texel and quads per layer, used when no
# calibration gives them.  PROVISIONAL values, replaced by the calibration's fit.
DEFAULT_MEMORY = (0.4, 4096.0, 12.0)


def primitive_model(memory: tuple[float, float, float] = DEFAULT_MEMORY) -> CostModel:
    """The primitive budget (seed 000 §5.8.3; seed 004): a view's cost is the triangles it draws,
    an impostor's the two triangles of each of its quads.

    >>> m = primitive_model()
    >>> float(m.geometry_time(1, 500, 10_000)), float(m.impostor_time(10_000, 30))
    (500.0, 60.0)
    """
    return CostModel("primitives", (0.0, 1.0, 0.0, 0.0), (0.0, 2.0, 0.0), memory, renderer="any (primitive count)", source="primitives")

"""Which impostor to use: bundles of one part for one view cell, evaluated alike, side by side.

Seed 000 ch. 4 (Tables 4.1 and 4.2) weighs layered impostors against textured depth meshes by
polygons, memory and image quality; users choose between the techniques per scene part.  A
:class:`Candidate` is one baked impostor with the numbers that choice needs, every one measured the
same way for every technique:

* **triangles** drawn (two per layered quad, one per TDM triangle: :attr:`Impostor.triangle_count`)
  and **points** drawn (a point-based impostor's); the ``triangles`` preference weighs their sum,
  the **primitives** (a one-pixel point counted as one primitive, like a triangle);
* **memory**: the atlas pages as stored plus the geometry as drawn (``stats["geometry_bytes"]``);
* **hole pixels, pixels bloated beyond one pixel, colour error and SSIM** inside the view cell,
  from :func:`farfield.core.quality.evaluation.evaluate` with the same viewpoints (corners, reference viewpoint, the
  same seeded random points).  The colour error is the per-pixel difference where both cover (its
  mean decides the ``error`` preference; its 99th percentile and the SSIM are shown beside it);
* the **bake time** as recorded in the bundle (measured where it was baked).

:func:`choose` keeps the candidates with the fewest hole pixels (zero is the promise of both
techniques), then those within :data:`TIE` (5 %) of the smallest by the preferred measure, then by
each other one (memory, triangles, colour error), until one is left.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

from farfield.core.errors import ComparisonError
from farfield.core.impostor.impostor import Impostor
from farfield.core.quality.evaluation import Evaluation
from farfield.core.techniques import get_technique

PREFERENCES = ("memory", "triangles", "error")

# Measures within this fraction of the best count as equal, and the next measure decides.
TIE = 0.05

# Per preference: the Candidate field, the chosen one's merit and a rival's merit, in words.
_MEASURES = {
    "memory": ("memory_bytes", "the least memory", "takes less memory"),
    "triangles": ("primitives", "the fewest primitives", "draws fewer primitives"),
    "error": ("colour_error_mean", "the smallest colour error", "has a smaller colour error"),
}


@dataclass(frozen=True, slots=True)
class Candidate:
    """One impostor's numbers for the choice (see the module docstring)."""

    name: str  # how the user named it (the bundle's path)
    technique: str
    triangles: int
    memory_bytes: int
    bake_seconds: float | None
    hole_pixels: int
    bloat_beyond_1px: int
    colour_error_mean: float  # per pixel where both cover, max over RGB, 0..255
    colour_error_p99: float  # the worst viewpoint's 99th percentile of the same
    ssim: float  # mean over the viewpoints, over the union of coverage (1: equal)
    points: int = 0  # points drawn (a point-based impostor) or samples splatted (an LDI)

    @property
    def primitives(self) -> int:
        """Triangles and points drawn."""
        return self.triangles + self.points

    @classmethod
    def of(cls, name: str, impostor: Impostor, evaluation: Evaluation) -> Candidate:
        seconds = impostor.stats.get("seconds", {})
        totals = evaluation.totals
        return cls(
            name=name,
            technique=impostor.technique,
            triangles=impostor.triangle_count,
            memory_bytes=int(impostor.texture_bytes + impostor.stats.get("geometry_bytes", 0)),
            bake_seconds=float(seconds["total"]) if isinstance(seconds, dict) and "total" in seconds else None,
            hole_pixels=int(totals["hole_pixels"]),
            bloat_beyond_1px=int(totals["bloat_beyond_1px"]),
            colour_error_mean=float(totals["colour_error_mean"]),
            colour_error_p99=float(totals["colour_error_p99"]),
            ssim=float(totals["ssim"]),
            points=impostor.payload.point_count,
        )

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True, slots=True)
class Choice:
    """The chosen candidate's index and why, in one sentence."""

    index: int
    reason: str


def check_comparable(names: list[str], impostors: list[Impostor]) -> None:
    """Raise :class:`ComparisonError` unless every impostor is of one part (not an envmap of a whole
    scene), for one view cell, resolution and field of view: otherwise their numbers do not compare."""
    first = impostors[0]
    keys = {
        "view cell": lambda i: i.viewcell,
        "part": lambda i: sorted(i.parameters.get("objects") or []),
        "resolution or field of view": lambda i: (i.resolution, i.fov_deg),
    }
    for name, impostor in zip(names, impostors):
        if get_technique(impostor.technique).scope != "part":
            raise ComparisonError(
                f"{name} is an {impostor.technique} bundle (a whole scene around its cell); only impostors of one part compare side by side"
            )
        for what, key in keys.items():
            if key(impostor) != key(first):
                raise ComparisonError(
                    f"{name} and {names[0]} differ in their {what}: only bundles of the same part, view cell, resolution and field of view compare"
                )


def _say(field: str, value: float) -> str:
    if field == "memory_bytes":
        return f"{value / 1024:.1f} KiB"
    if field == "primitives":
        return f"{int(value):,}"
    return f"{value:.2f}"


def choose(candidates: list[Candidate], prefer: str = "memory") -> Choice:
    """The candidate to use (see the module docstring) and the reason, naming what the others do better.

    >>> a = Candidate("out/tdm", "tdm", 706, 475_000, 4.5, 0, 0, 1.33, 12.0, 0.97)
    >>> b = Candidate("out/layered", "layered", 538, 1_256_000, 0.2, 0, 0, 1.45, 14.0, 0.96)
    >>> c = Candidate("out/coarse", "tdm", 90, 45_000, 0.5, 3, 0, 3.3, 40.0, 0.9)
    >>> choice = choose([a, b, c])
    >>> choice.index
    0
    >>> print(choice.reason)
    out/tdm: no hole pixels inside the view cell and the least memory (463.9 KiB against 1226.6 KiB); out/coarse has 3 hole pixels; out/layered draws fewer primitives (538 against 706)
    >>> choose([a, b], prefer="triangles").index
    1

    Memory within 5 % of each other: the fewest primitives decide.

    >>> d = Candidate("out/layered", "layered", 254, 292_760, 0.3, 0, 5, 0.0, 0.0, 1.0)
    >>> e = Candidate("out/tdm", "tdm", 1080, 292_200, 2.5, 0, 11, 0.0, 0.0, 1.0)
    >>> print(choose([e, d]).reason)
    out/layered: no hole pixels inside the view cell and memory within 5% (285.9 KiB against 285.4 KiB), the fewest primitives (254 against 1,080); out/tdm takes less memory (285.4 KiB against 285.9 KiB)
    """
    if prefer not in PREFERENCES:
        raise ComparisonError(f"prefer must be one of {', '.join(PREFERENCES)}, got {prefer!r}")
    if not candidates:
        raise ComparisonError("nothing to choose from: no impostor given")
    order = [prefer, *(p for p in PREFERENCES if p != prefer)]
    fewest = min(c.hole_pixels for c in candidates)
    pool = [i for i, c in enumerate(candidates) if c.hole_pixels == fewest]
    eligible = list(pool)
    steps = []  # (measure, the pool it looked at, those it kept)
    for p in order:
        if len(pool) == 1:
            break
        field = _MEASURES[p][0]
        best = min(getattr(candidates[i], field) for i in pool)
        near = [i for i in pool if getattr(candidates[i], field) <= best + TIE * abs(best)]
        steps.append((p, pool, near))
        pool = near
    first = _MEASURES[order[0]][0]
    index = min(pool, key=lambda i: (getattr(candidates[i], first), i))
    chosen = candidates[index]
    holes = (
        "no hole pixels inside the view cell"
        if fewest == 0
        else f"the fewest hole pixels inside the view cell ({fewest}; none has zero)"
    )
    parts = [f"{chosen.name}: {holes}"]
    for p, looked, kept in steps:
        field, merit, _ = _MEASURES[p]
        tie = len(kept) == len(looked)
        # Against the others it kept if it left none out, else against those it left out.
        others = [i for i in kept if i != index] if tie else [i for i in looked if i not in kept]
        runner = min((candidates[i] for i in others), key=lambda c: getattr(c, field))
        mine, theirs = _say(field, getattr(chosen, field)), _say(field, getattr(runner, field))
        if tie:
            parts.append(f"{p} within {TIE:.0%} ({mine} against {theirs})")
        else:
            parts.append(f"{merit}{'' if len(kept) == 1 else f' within {TIE:.0%}'} ({mine} against {theirs})")
    reason = parts[0] + (" and " + ", ".join(parts[1:]) if len(parts) > 1 else "")
    notes = [f"{c.name} has {c.hole_pixels} hole pixels" for c in candidates if c.hole_pixels > fewest]
    for p in order:
        field, _, better = _MEASURES[p]
        ahead = [candidates[i] for i in eligible if getattr(candidates[i], field) < getattr(chosen, field)]
        if ahead:
            r = min(ahead, key=lambda c: getattr(c, field))
            notes.append(
                f"{r.name} {better} ({_say(field, getattr(r, field))} against {_say(field, getattr(chosen, field))})"
            )
    return Choice(index, "; ".join([reason, *notes]))

"""The potentially visible sets a placement database stores: one per smallest region of the view space, as compressed bitsets.

A placement planned with visibility (:class:`farfield.core.visibility.pvs.RegionVisibility`) keeps
the PVS of every *smallest* region of its problem view space, the regions
:func:`~farfield.core.placement.view_space.problem_view_space` reaches when it halves the view space
down to the CPV size: along each axis ``2^m`` regions of ``span / 2^m`` (:func:`~farfield.core.visibility.pvs.halvings`),
so they tile the view space as a regular grid and a view's region is found by division.  A larger
region the planner stopped at is the union of its smallest ones and so is its PVS: a runtime that
draws the smallest region's PVS draws no more than the planner estimated (seed 000 §5.5.1).

**Encoding** (the ``visibility`` section of a placement document and of a placement database's
``placement`` section; docs/formats.md)::

    {"encoding": "zlib-packbits-base64", "elements": n, "names": [n element names],
     "grid": {"lo": [3], "hi": [3], "counts": [3]},
     "sets": [one string per region, x slowest then y then z (C order of the counts)]}

each set being the region's ``n`` membership bits packed eight to a byte, the lowest element index
in the lowest bit (``numpy.packbits(..., bitorder="little")``), compressed with zlib (level 9) and
written in base64.  Bitsets rather than id ranges: a PVS is a scattered subset (at street level a
fifth of the elements), and zlib turns the long runs of a dense or sparse set into a few bytes.
"""

from __future__ import annotations

import base64
import binascii
import math
import zlib

import numpy as np

from farfield.core.placement.hierarchy import PlacementError

ENCODING = "zlib-packbits-base64"


def encode_set(members: np.ndarray, count: int) -> str:
    """The compact text of the set ``members`` (element indices in ``0..count-1``, see the module docstring).

    >>> encode_set(np.array([0, 2, 9]), 10) == encode_set(np.array([9, 2, 0]), 10)
    True
    >>> decode_set(encode_set(np.array([0, 2, 9]), 10), 10).tolist()
    [0, 2, 9]
    """
    mask = np.zeros(int(count), dtype=bool)
    mask[np.asarray(members, dtype=np.int64)] = True
    return base64.b64encode(zlib.compress(np.packbits(mask, bitorder="little").tobytes(), 9)).decode("ascii")


def decode_set(text: str, count: int) -> np.ndarray:
    """Sorted element indices of a set written by :func:`encode_set` for ``count`` elements; a
    PlacementError when the text does not decode to ``count`` bits.

    >>> decode_set("not base64!", 4)
    Traceback (most recent call last):
    ...
    farfield.core.placement.hierarchy.PlacementError: a stored potentially visible set does not decode: Only base64 data is allowed
    """
    try:
        raw = zlib.decompress(base64.b64decode(text.encode("ascii"), validate=True))
    except (binascii.Error, zlib.error, ValueError) as error:
        raise PlacementError(f"a stored potentially visible set does not decode: {error}") from error
    if len(raw) != (int(count) + 7) // 8:
        raise PlacementError(
            f"a stored potentially visible set has {len(raw)} bytes, not {(int(count) + 7) // 8} for {count} elements"
        )
    bits = np.unpackbits(np.frombuffer(raw, dtype=np.uint8), bitorder="little")[: int(count)]
    return np.flatnonzero(bits)


def region_grid(lo, hi, region_size: float) -> np.ndarray:
    """(3,) int64 smallest regions per axis of the view space ``lo``..``hi`` halved down to ``region_size``.

    >>> region_grid([0, 0, 0], [150, 1, 150], 37.5).tolist()
    [4, 1, 4]
    """
    from farfield.core.visibility.pvs import halvings

    span = np.asarray(hi, dtype=np.float64) - np.asarray(lo, dtype=np.float64)
    return np.array([2 ** halvings(float(s), float(region_size)) for s in span], dtype=np.int64)


def region_sets(visibility, names, lo, hi, region_size: float) -> dict:
    """The ``visibility`` section (module docstring) of ``visibility`` (a
    :class:`~farfield.core.visibility.pvs.RegionVisibility`, whose points the planner rendered) over
    the view space ``lo``..``hi`` in smallest regions of ``region_size``; ``names`` the element names."""
    lo, hi = np.asarray(lo, dtype=np.float64), np.asarray(hi, dtype=np.float64)
    counts = region_grid(lo, hi, region_size)
    size = (hi - lo) / counts
    count = len(names)
    sets = []
    for ijk in np.ndindex(*counts.tolist()):
        r_lo = lo + np.array(ijk) * size
        r_hi = np.where(np.array(ijk) + 1 == counts, hi, r_lo + size)
        sets.append(encode_set(visibility.pvs(r_lo, r_hi), count))
    return {
        "encoding": ENCODING,
        "elements": count,
        "names": list(names),
        "grid": {"lo": lo.tolist(), "hi": hi.tolist(), "counts": counts.tolist()},
        "sets": sets,
    }


class StoredSets:
    """A stored ``visibility`` section, read: :meth:`region_of` a position, :meth:`pvs` of a region
    (decoded once and kept)."""

    def __init__(self, section: dict) -> None:
        try:
            if section["encoding"] != ENCODING:
                raise PlacementError(
                    f"unknown potentially visible set encoding {section['encoding']!r} (this farfield reads {ENCODING!r})"
                )
            self.count = int(section["elements"])
            self.names = list(section.get("names") or [])
            grid = section["grid"]
            self.lo = np.asarray(grid["lo"], dtype=np.float64).reshape(3)
            self.hi = np.asarray(grid["hi"], dtype=np.float64).reshape(3)
            self.counts = np.asarray(grid["counts"], dtype=np.int64).reshape(3)
            self.sets = list(section["sets"])
        except (KeyError, TypeError, ValueError) as error:
            raise PlacementError(f"the stored potentially visible sets do not read: {error!r}") from error
        if int(np.prod(self.counts)) != len(self.sets) or np.any(self.counts < 1):
            raise PlacementError(
                f"{len(self.sets)} stored potentially visible sets for a grid of {self.counts.tolist()} regions"
            )
        if self.names and len(self.names) != self.count:
            raise PlacementError(
                f"{len(self.names)} element names for {self.count} elements in the stored potentially visible sets"
            )
        span = float(np.max(self.hi - self.lo))
        self.tol = 1e-9 * max(span, float(np.max(np.abs(np.concatenate([self.lo, self.hi])))), 1.0)
        self._decoded: dict[int, np.ndarray] = {}

    def region_of(self, position) -> int | None:
        """The flat index of the smallest region holding ``position`` (on a shared face, the upper
        one), or None outside the view space.

        >>> s = StoredSets({"encoding": ENCODING, "elements": 1, "grid": {"lo": [0, 0, 0], "hi": [4, 1, 4], "counts": [2, 1, 2]},
        ...                 "sets": [encode_set([], 1)] * 4})
        >>> s.region_of([1, 0.5, 3]), s.region_of([4, 1, 4]), s.region_of([5, 0, 0])
        (1, 3, None)
        """
        p = np.asarray(position, dtype=np.float64).reshape(3)
        if not np.all(np.isfinite(p)) or np.any(p < self.lo - self.tol) or np.any(p > self.hi + self.tol):
            return None
        with np.errstate(divide="ignore", invalid="ignore"):
            f = np.where(self.hi > self.lo, (p - self.lo) / (self.hi - self.lo), 0.0)
        ijk = np.clip(np.floor(f * self.counts).astype(np.int64), 0, self.counts - 1)
        return int(np.ravel_multi_index(tuple(ijk), tuple(self.counts)))

    def region_box(self, region: int) -> tuple[list[float], list[float]]:
        """[lo], [hi] of region ``region``."""
        ijk = np.array(np.unravel_index(int(region), tuple(self.counts)))
        size = (self.hi - self.lo) / self.counts
        r_lo = self.lo + ijk * size
        r_hi = np.where(ijk + 1 == self.counts, self.hi, r_lo + size)
        return r_lo.tolist(), r_hi.tolist()

    def pvs(self, region: int) -> np.ndarray:
        """Sorted element indices of region ``region``'s PVS."""
        if region not in self._decoded:
            self._decoded[region] = decode_set(self.sets[region], self.count)
        return self._decoded[region]

    def at(self, position) -> np.ndarray | None:
        """The PVS of the region holding ``position``, or None outside every region."""
        region = self.region_of(position)
        return None if region is None else self.pvs(region)


def stored_size(section: dict) -> int:
    """Bytes of the encoded sets (their base64 text), for reports.

    >>> stored_size({"sets": ["abcd", "ef=="]})
    8
    """
    return int(sum(len(s) for s in section.get("sets", [])))


def raw_size(section: dict) -> int:
    """Bytes the sets would take as uncompressed bitsets.

    >>> raw_size({"elements": 17, "sets": ["", ""]})
    6
    """
    return len(section.get("sets", [])) * int(math.ceil(int(section["elements"]) / 8))

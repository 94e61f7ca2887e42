"""The view cells of a placement's candidates as columns, each cell made only when it is read.

A placement keeps tens or hundreds of thousands of candidates and reads the cells of the few
hundred it chooses: making every :class:`~farfield.core.viewcells.ShaftCell` and
:class:`~farfield.core.viewcells.BoxCell` (each validated on construction) took a fifth of the
candidate step on a helmet and 137 s of a 10,000-tree forest's (docs/measurements/placement.md).
Shafts are kept as apex, direction, apex angle and minimum distance; boxes as their corners; any
other cell (an outside sphere, or a kind another module adds) as the object itself.  ``table[i]``
makes cell ``i`` from exactly the numbers the eager code passed, so it is the same cell.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence

import numpy as np

from farfield.core.viewcells import BoxCell, ShaftCell

SHAFT, BOX, OBJECT = 0, 1, 2


class CellTable(Sequence):
    """(m,) view cells: ``kind`` SHAFT (``a`` apex, ``b`` direction, ``angle``, ``distance``), BOX
    (``a`` lo, ``b`` hi) or OBJECT (``objects[i]``)."""

    __slots__ = ("kind", "a", "b", "angle", "distance", "objects")

    def __init__(self, kind, a, b, angle, distance, objects: dict | None = None) -> None:
        self.kind, self.a, self.b = (
            np.asarray(kind, dtype=np.int8),
            np.asarray(a, dtype=np.float64),
            np.asarray(b, dtype=np.float64),
        )
        self.angle, self.distance = np.asarray(angle, dtype=np.float64), np.asarray(distance, dtype=np.float64)
        self.objects = dict(objects or {})

    @classmethod
    def shafts(cls, apex: np.ndarray, direction: np.ndarray, angle: np.ndarray, distance: np.ndarray) -> CellTable:
        """Shafts from one ``apex`` (3,) along ``direction`` (k, 3)."""
        k = direction.shape[0]
        return cls(np.full(k, SHAFT), np.broadcast_to(apex, (k, 3)), direction, angle, distance)

    @classmethod
    def boxes(cls, lo: np.ndarray, hi: np.ndarray) -> CellTable:
        k = lo.shape[0]
        return cls(np.full(k, BOX), lo.reshape(k, 3), hi.reshape(k, 3), np.zeros(k), np.zeros(k))

    @classmethod
    def of(cls, cells: list) -> CellTable:
        """Cells already made, kept as they are."""
        k = len(cells)
        return cls(
            np.full(k, OBJECT), np.zeros((k, 3)), np.zeros((k, 3)), np.zeros(k), np.zeros(k), dict(enumerate(cells))
        )

    @classmethod
    def concat(cls, tables: list[CellTable]) -> CellTable:
        """The tables one after another.

        >>> t = CellTable.concat([CellTable.boxes(np.zeros((1, 3)), np.ones((1, 3))), CellTable.of(["x"])])
        >>> len(t), t[0].to_dict()["hi"], t[1]
        (2, [1.0, 1.0, 1.0], 'x')
        """
        if not tables:
            return cls.of([])
        objects, at = {}, 0
        for t in tables:
            objects.update({at + i: c for i, c in t.objects.items()})
            at += len(t)
        cat = lambda name: np.concatenate([getattr(t, name) for t in tables])  # noqa: E731
        return cls(cat("kind"), cat("a"), cat("b"), cat("angle"), cat("distance"), objects)

    def __len__(self) -> int:
        return int(self.kind.shape[0])

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self[j] for j in range(*i.indices(len(self)))]
        i = int(i)
        if i < 0:
            i += len(self)
        kind = self.kind[i]
        if kind == SHAFT:
            return ShaftCell(self.a[i], self.b[i], float(self.angle[i]), float(self.distance[i]))
        if kind == BOX:
            return BoxCell(self.a[i].copy(), self.b[i].copy())
        return self.objects[i]

    def __iter__(self) -> Iterator:
        return (self[i] for i in range(len(self)))

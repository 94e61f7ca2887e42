"""Reading an impostor database (a job's result): ``index.json`` plus one bundle folder per cell.

The layout is what ``GET /v1/jobs/{id}/database.zip`` serves and ``farfield submit --download``
unpacks::

    index.json              format "farfield-impostor-database": job, params, cells
    cells/00000/            the bundle of cell 0 (manifest.json, payload.bin, atlas-NNN.png, impostor.glb)
    cells/00001/ ...

Each cell entry of the index has its ``index``, ``grid`` position ``[i, j, k]`` (grid jobs),
``viewcell``, ``state``, ``bundle`` folder and, for grid jobs, ``neighbours``: the indices of the
(up to 26) cells around it, which a runtime prefetches (seed 002 §3, runtime step 2).
"""

from __future__ import annotations

import json
import tempfile
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from farfield.core.errors import BundleFormatError, NotFoundError
from farfield.core.impostor.bundle import read_bundle
from farfield.core.impostor.impostor import Impostor
from farfield.core.viewcells import BoxCell, ViewCell, viewcell_from_dict

DATABASE_FORMAT = "farfield-impostor-database"
INDEX_NAME = "index.json"


def grid_neighbours(grid: list[list[int] | None]) -> list[list[int]]:
    """For cells at grid positions ``grid`` (n entries of [i, j, k] or None), the indices of the
    cells at most one step away on every axis (the 26-neighbourhood), ascending.

    >>> grid_neighbours([[0, 0, 0], [1, 0, 0], [2, 0, 0], None])
    [[1], [0, 2], [1], []]
    """
    where = {tuple(g): n for n, g in enumerate(grid) if g is not None}
    out = []
    for g in grid:
        if g is None:
            out.append([])
            continue
        i, j, k = g
        found = [
            where[(i + di, j + dj, k + dk)]
            for dk in (-1, 0, 1) for dj in (-1, 0, 1) for di in (-1, 0, 1)
            if (di, dj, dk) != (0, 0, 0) and (i + di, j + dj, k + dk) in where
        ]  # fmt: skip
        out.append(sorted(found))
    return out


@dataclass(frozen=True, slots=True)
class DatabaseCell:
    """One cell of an impostor database."""

    index: int
    viewcell: ViewCell
    state: str
    bundle: Path | None  # the bundle folder, None when the cell has no result
    neighbours: tuple[int, ...]


class ImpostorDatabase:
    """An impostor database on disk (a folder, or a zip file unpacked to a temporary folder)."""

    def __init__(self, path: str | Path):
        path = Path(path)
        self._tmp = None
        if path.is_file() and zipfile.is_zipfile(path):
            self._tmp = tempfile.TemporaryDirectory(prefix="farfield-db-")
            with zipfile.ZipFile(path) as archive:
                archive.extractall(self._tmp.name)
            path = Path(self._tmp.name)
        index_path = path / INDEX_NAME
        if not index_path.is_file():
            raise NotFoundError(f"{path}: not an impostor database (no {INDEX_NAME})")
        try:
            index = json.loads(index_path.read_text())
        except (OSError, ValueError) as error:
            raise BundleFormatError(f"{index_path}: unreadable: {error}") from error
        if index.get("format") != DATABASE_FORMAT:
            raise BundleFormatError(f"{index_path}: format is {index.get('format')!r}, expected {DATABASE_FORMAT!r}")
        self.root = path
        self.index = index
        self.technique: str = index.get("technique", index.get("job_type", "layered"))
        # A placement database's section (farfield.core.placement.database): CPVs and what each draws; None otherwise.
        self.placement: dict | None = index.get("placement") if index.get("kind") == "placement" else None
        entries = index["cells"]
        neighbours = grid_neighbours([e.get("grid") for e in entries])
        self.cells = [
            DatabaseCell(
                index=int(e["index"]),
                viewcell=viewcell_from_dict(e["viewcell"]),
                state=e["state"],
                bundle=(path / e["bundle"]) if e.get("bundle") else None,
                neighbours=tuple(e.get("neighbours", neighbours[n])),
            )
            for n, e in enumerate(entries)
        ]
        self._by_index = {c.index: c for c in self.cells}
        self._impostors: dict[int, Impostor] = {}

    def close(self) -> None:
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None

    def __enter__(self) -> ImpostorDatabase:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def cell(self, index: int) -> DatabaseCell:
        return self._by_index[index]

    def find(self, point) -> DatabaseCell | None:
        """The cell whose view cell contains ``point`` (the lowest index where cells share a face)."""
        p = np.asarray(point, dtype=np.float64).reshape(1, 3)
        for cell in self.cells:
            if bool(cell.viewcell.contains(p, tol=0.0)[0]):
                return cell
        return None

    def impostor(self, index: int) -> Impostor:
        """The impostor of cell ``index`` (read once, then cached)."""
        if index not in self._impostors:
            cell = self._by_index[index]
            if cell.bundle is None:
                raise NotFoundError(f"cell {index} of the impostor database has no result (state {cell.state})")
            self._impostors[index] = read_bundle(cell.bundle)
        return self._impostors[index]

    def prefetch(self, index: int) -> int:
        """Read the bundles of cell ``index``'s neighbours ahead of need; returns how many were read."""
        read = 0
        for n in self._by_index[index].neighbours:
            if n not in self._impostors and self._by_index[n].bundle is not None:
                self.impostor(n)
                read += 1
        return read

    def bounds(self) -> np.ndarray:
        """(2, 3) float64 bounds of all box cells."""
        boxes = [c.viewcell for c in self.cells if isinstance(c.viewcell, BoxCell)]
        return np.array([np.min([b.lo for b in boxes], axis=0), np.max([b.hi for b in boxes], axis=0)])


def database_index(
    technique: str, params: dict, cells: list[dict], job: str | None = None, scene: str | None = None
) -> dict:
    """The index document of an impostor database, the one writer of its format (the service's jobs
    and :func:`write_database` both call it).

    ``cells`` holds per cell, in cell order: ``index``, ``grid`` (position or None), ``viewcell``,
    ``state`` and ``bundle`` (its folder, or None); each gets its ``neighbours`` (the indices of the
    cells of its 26-neighbourhood on the grid; [] for explicit cells).  ``job_type`` repeats
    ``technique`` for readers of the first version.
    """
    from farfield.core import __version__

    neighbours = grid_neighbours([c["grid"] for c in cells])
    positions = [c["index"] for c in cells]  # list positions -> cell indices (the same when all cells are there)
    return {
        "format": DATABASE_FORMAT, "format_version": 1, "code_version": __version__, "job": job, "scene": scene,
        "technique": technique, "job_type": technique, "params": params,
        "cells": [{**c, "neighbours": [positions[n] for n in near]} for c, near in zip(cells, neighbours)],
    }  # fmt: skip


def write_database(
    directory: str | Path, technique: str, params: dict, cells: list[tuple[list[int] | None, Impostor]]
) -> Path:
    """Write an impostor database folder from impostors baked in this process (benchmarks, tests,
    local use): ``index.json`` in the service's format plus ``cells/NNNNN/`` bundles.

    ``cells`` holds (grid position or None, impostor) per cell, in cell order.
    """
    from farfield.core.impostor.bundle import write_bundle

    root = Path(directory)
    root.mkdir(parents=True, exist_ok=True)
    entries = []
    for n, (grid, impostor) in enumerate(cells):
        write_bundle(impostor, root / "cells" / f"{n:05d}")
        entries.append(
            {"index": n, "grid": grid, "viewcell": impostor.viewcell, "state": "done", "bundle": f"cells/{n:05d}/"}
        )
    (root / INDEX_NAME).write_text(json.dumps(database_index(technique, params, entries), sort_keys=True, indent=1))
    return root

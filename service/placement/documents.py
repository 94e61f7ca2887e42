"""What the API serves of a placement job's database: its map (``/placement``), the view lookup's
placement part and the clusters (``/clusters``), from the job's index kept parsed in this process.

The parsed index and its lookup structure (the algorithm's
:meth:`~farfield.service.placement.base.Algorithm.read_index`) of recent placement jobs are kept
in a least-recently-used cache, as the ``/clusters`` answers are: keyed by the index blob's key and
the job's end (a retried job writes its index again under the same key), so a runtime polling the
lookup does not re-read the blob each call.
"""

from __future__ import annotations

import json
import threading
from collections import OrderedDict

from farfield.core.errors import ConflictError, InternalError, NotFoundError
from farfield.core.placement.hierarchy import PlacementError
from farfield.service.blobs import BlobStore
from farfield.service.db import Database, JobRow
from farfield.service.placement import Algorithm, job_algorithm

LOOKUP_CACHE_SIZE = 16  # placement databases (and /clusters answers) kept parsed in this process


class _LookupCache:
    """The parsed index and lookup structure of recent placement jobs, least recently used out first."""

    def __init__(self, size: int) -> None:
        self.size = size
        self.entries: OrderedDict[tuple, tuple[dict, object]] = OrderedDict()
        self.lock = threading.Lock()
        self.reads = 0  # blobs read and parsed (tests: a second call reads nothing)

    def get(self, blobs: BlobStore, job: JobRow, algorithm: Algorithm) -> tuple[dict, object]:
        key = (job.index_key, job.finished_at)
        with self.lock:
            if key in self.entries:
                self.entries.move_to_end(key)
                return self.entries[key]
        try:
            index = json.loads(blobs.read_bytes(job.index_key))
            found = (index, algorithm.read_index(index))
        except (ValueError, KeyError, TypeError, PlacementError) as error:
            # farfield wrote this index: one that does not read is a bug (500), not bad input
            raise InternalError(f"job {job.id!r}: its placement database index does not read: {error}") from error
        with self.lock:
            self.reads += 1
            self.entries[key] = found
            self.entries.move_to_end(key)
            while len(self.entries) > self.size:
                self.entries.popitem(last=False)
        return found


LOOKUPS = _LookupCache(LOOKUP_CACHE_SIZE)
_CLUSTERS: OrderedDict[tuple, dict] = OrderedDict()  # (index key, end) -> /clusters answer, the last few jobs used
_CLUSTERS_LOCK = threading.Lock()


def placement_database(blobs: BlobStore, job: JobRow) -> tuple[Algorithm, dict, object]:
    """A placement job's (algorithm, index, lookup structure): 404 for another kind of job, 409 before its index is written."""
    algorithm = job_algorithm(job)
    if algorithm is None:
        raise NotFoundError(
            f"job {job.id!r} is a {job.job_type} job, not a placement job: it has no placement (its cells are looked up by position alone)"
        )
    if job.index_key is None:
        raise ConflictError(
            f"job {job.id!r} is {job.state}; its placement database is written when its impostors are baked"
        )
    index, found = LOOKUPS.get(blobs, job, algorithm)
    return algorithm, index, found


def placement_document(blobs: BlobStore, job: JobRow) -> dict:
    """``GET /v1/jobs/{id}/placement``: the algorithm's map of its database."""
    algorithm, index, _ = placement_database(blobs, job)
    return algorithm.placement_document(job, index)


def placement_lookup(blobs: BlobStore, job: JobRow, eye, direction) -> tuple[dict, list[int]]:
    """A placement job's answer for a view, and the indices of the cells it lists (:meth:`Algorithm.lookup`)."""
    algorithm, index, found = placement_database(blobs, job)
    return algorithm.lookup(index, found, eye, direction)


def placement_clusters(db: Database, blobs: BlobStore, job: JobRow) -> dict:
    """``GET /v1/jobs/{id}/clusters`` (:meth:`Algorithm.clusters`), the last few answers kept."""
    algorithm, index, _ = placement_database(blobs, job)
    key = (job.index_key, job.finished_at)
    with _CLUSTERS_LOCK:
        found = _CLUSTERS.get(key)
        if found is not None:
            _CLUSTERS.move_to_end(key)
            return found
    found = algorithm.clusters(db, blobs, job, index)
    with _CLUSTERS_LOCK:
        _CLUSTERS[key] = found
        while len(_CLUSTERS) > LOOKUP_CACHE_SIZE:
            _CLUSTERS.popitem(last=False)
    return found

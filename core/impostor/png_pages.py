"""PNG bytes of (H, W, 4) uint8 RGBA pages: one fixed encoding, each page encoded once, several at a time.

A bundle's atlas pages are written twice, as ``atlas-NNN.png`` files and inside ``impostor.glb``
(:mod:`farfield.core.impostor.bundle`, :mod:`farfield.core.impostor.glb`); :class:`PagePngs` encodes each
page array once for both and encodes a batch of pages on a thread pool.  Pillow's encoder (zlib
underneath) releases the GIL while it compresses, so the threads run side by side: with a spinning
Python thread beside one encode, the spinner got as much CPU as the encoder, and none beside a C call
that holds the GIL (``benchmarks/bench_bundle.py``, part 1).

The encoding (:func:`page_png`): zlib level 6 with the ``Z_RLE`` strategy (run-length matches
only), Pillow's per-row filters, no optimiser search, no metadata chunks.  ``Z_RLE`` was chosen by
measurement over the pages of five bakes (``benchmarks/bench_bundle.py``, part 2; the layered
benchmark object at 512 and 1024 px, the envmap cell, the helmet's LDI at 256 and 512 px): 0.31-0.57x
the CPU seconds of the default strategy for 0.99-1.09x its bytes.  Levels 1-5 of the default strategy
saved less time for more bytes (level 4: 0.54-0.75x the time, 1.01-1.10x the bytes); level 9 took
2.7-6.7x the time for 0.96-0.99x the bytes.
"""

from __future__ import annotations

import io
import os
import zlib
from collections.abc import Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from PIL import Image

__all__ = ["PNG_COMPRESS_LEVEL", "PNG_STRATEGY", "PagePngs", "map_threads", "page_png", "thread_count"]

# Fixed PNG settings (see the module docstring for why these).
PNG_COMPRESS_LEVEL = 6
PNG_STRATEGY = zlib.Z_RLE


def page_png(page: np.ndarray) -> bytes:
    """Deterministic PNG bytes of one (H, W, 4) uint8 RGBA page, top row first.

    The same array gives the same bytes with the same zlib: fixed compression level and strategy,
    no optimiser search, no text or time chunks.

    >>> data = page_png(np.zeros((2, 3, 4), np.uint8))
    >>> data[:8] == b"\\x89PNG\\r\\n\\x1a\\n", data == page_png(np.zeros((2, 3, 4), np.uint8))
    (True, True)
    """
    buffer = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(page), mode="RGBA").save(
        buffer, "PNG", optimize=False, compress_level=PNG_COMPRESS_LEVEL, compress_type=PNG_STRATEGY
    )
    return buffer.getvalue()


def thread_count() -> int:
    """Threads to encode and write a bundle's files with: the cores this process may use, at least 4
    (a thread waiting on ``fsync`` takes no core, and ext4 commits concurrent syncs together)."""
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        cores = os.cpu_count() or 1
    return max(4, cores)


def map_threads(function, items: Sequence, workers: int | None = None) -> list:
    """``[function(item) for item in items]``, on up to ``workers`` threads (default
    :func:`thread_count`); 1 worker, or one item, runs in the calling thread.  Results in the
    items' order; the first exception is raised.

    >>> map_threads(len, ["a", "bb", "ccc"], workers=2)
    [1, 2, 3]
    """
    workers = thread_count() if workers is None else max(1, int(workers))
    if workers == 1 or len(items) < 2:
        return [function(item) for item in items]
    with ThreadPoolExecutor(min(workers, len(items))) as pool:
        return list(pool.map(function, items))


class PagePngs:
    """PNG bytes of page arrays (:func:`page_png`), each array encoded once while this object lives.

    Arrays are told apart by identity, and each one given is kept referenced until this object is
    dropped, so an address is never reused for another page meanwhile; a page must not change
    while it is here.  ``workers`` threads encode a batch (:meth:`encode`); 1 encodes in the
    calling thread, one page after the other.

    >>> pngs = PagePngs(workers=2)
    >>> a, b = np.zeros((2, 2, 4), np.uint8), np.full((2, 2, 4), 255, np.uint8)
    >>> pngs.encode([a, b]) == [page_png(a), page_png(b)], pngs(a) is pngs(a), pngs.encoded
    (True, True, 2)
    """

    def __init__(self, workers: int | None = None) -> None:
        self.workers = thread_count() if workers is None else max(1, int(workers))
        self._done: dict[int, tuple[np.ndarray, bytes]] = {}

    @property
    def encoded(self) -> int:
        """How many page arrays have been encoded."""
        return len(self._done)

    def __call__(self, page: np.ndarray) -> bytes:
        """The PNG bytes of ``page``, encoded now unless it was before."""
        return self.encode([page])[0]

    def encode(self, pages: Iterable[np.ndarray]) -> list[bytes]:
        """The PNG bytes of each of ``pages``, in their order; those not encoded before are encoded
        now, on up to ``workers`` threads."""
        pages = list(pages)
        todo = list({id(p): p for p in pages if id(p) not in self._done}.values())
        for page, data in zip(todo, map_threads(page_png, todo, self.workers)):
            self._done[id(page)] = (page, data)
        return [self._done[id(p)][1] for p in pages]

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
import weakref
import zlib
from collections.abc import Iterable, Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from PIL import Image

from farfield.core.cores import usable_cores

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
    return max(4, usable_cores())


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


# PNG bytes that a PagePngs(remember=True) encoded, by page id while the page lives (a weak
# reference whose callback forgets it): a technique that measures its pages' PNG size (envmap's
# ``png_bytes``) hands the bytes on to the bundle writer, which then encodes nothing again.
_REMEMBERED: dict[int, tuple[weakref.ref, bytes]] = {}


def _remembered(page: np.ndarray) -> bytes | None:
    entry = _REMEMBERED.get(id(page))
    return entry[1] if entry is not None and entry[0]() is page else None


def _remember(page: np.ndarray, data: bytes) -> None:
    key = id(page)
    _REMEMBERED[key] = (weakref.ref(page, lambda _ref, key=key: _REMEMBERED.pop(key, None)), data)


class PagePngs:
    """PNG bytes of page arrays (:func:`page_png`), each array encoded once while this object lives.

    Arrays are told apart by identity, and each one given is kept referenced until this object is
    dropped, so an address is never reused for another page meanwhile; a page must not change
    while it is here.  With ``remember`` the bytes also outlive this object for as long as their
    page does, and any PagePngs finds them there instead of encoding the page again (a page must
    then not change while it lives).  ``workers`` threads encode a batch (:meth:`encode`); 1 encodes in the
    calling thread, one page after the other.

    >>> pngs = PagePngs(workers=2)
    >>> a, b = np.zeros((2, 2, 4), np.uint8), np.full((2, 2, 4), 255, np.uint8)
    >>> pngs.encode([a, b]) == [page_png(a), page_png(b)], pngs(a) is pngs(a), pngs.encoded
    (True, True, 2)
    """

    def __init__(self, workers: int | None = None, remember: bool = False) -> None:
        self.workers = thread_count() if workers is None else max(1, int(workers))
        self._done: dict[int, tuple[np.ndarray, bytes]] = {}
        self._remember = remember

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
        todo = []
        for page in {id(p): p for p in pages if id(p) not in self._done}.values():
            data = _remembered(page)  # encoded by a remembering PagePngs while the page lived
            if data is None:
                todo.append(page)
            else:
                self._done[id(page)] = (page, data)
        for page, data in zip(todo, map_threads(page_png, todo, self.workers)):
            self._done[id(page)] = (page, data)
            if self._remember:
                _remember(page, data)
        return [self._done[id(p)][1] for p in pages]

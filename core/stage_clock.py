"""Seconds per named stage of a bake, and its progress callback: the one timing helper of every pipeline.

A pipeline makes a :class:`StageClock` with the progress callback it was given (or none), times
each stage in a ``with clock("name"):`` block (stages entered more than once add up) and reports
``clock.report(stage, done, total)``; its statistics' ``seconds`` are :meth:`StageClock.totals`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

Progress = Callable[[str, int, int], None]  # (stage, done, total)


def _ignore(stage: str, done: int, total: int) -> None:
    return None


class StageClock:
    """Accumulated seconds per stage (in first-timed order) and a progress callback.

    >>> clock = StageClock(("plan", "record"))
    >>> with clock("plan"):
    ...     pass
    >>> sorted(clock.totals())
    ['plan', 'record', 'total']
    """

    def __init__(self, stages: tuple[str, ...] = (), progress: Progress | None = None) -> None:
        self.seconds: dict[str, float] = dict.fromkeys(stages, 0.0)
        self.report: Progress = progress or _ignore

    @contextmanager
    def __call__(self, stage: str) -> Iterator[None]:
        start = time.perf_counter()
        try:
            yield
        finally:
            self.seconds[stage] = self.seconds.get(stage, 0.0) + time.perf_counter() - start

    def totals(self) -> dict[str, float]:
        """Each stage's seconds and their ``total``."""
        return {**self.seconds, "total": sum(self.seconds.values())}


def seconds_line(stats: dict) -> str:
    """``seconds: stage s ...`` of a bake's statistics, as the CLI prints them."""
    return "seconds: " + "  ".join(f"{k} {v:.3f}" for k, v in stats.get("seconds", {}).items())

"""Failed authentication is rate-limited per client (issue 59, item 11): the campaign tried 2,000
random keys at 230 requests/s and got 2,000 plain 401s.

:class:`FailedAuthLimiter` counts, per client address, the requests of the last ``window_s`` seconds
that presented credentials which did not authenticate (a wrong, revoked or malformed key; a request
with no ``Authorization`` header at all is not counted: it guessed nothing).  Once a client has
``max_failures`` of them, every request it makes that needs a key is refused with 429
(:class:`~farfield.core.errors.AuthRateError`, ``Retry-After`` the seconds until its oldest failure
leaves the window) *before* its key is checked, so guesses cannot be verified while it waits.

The count lives in the API process (one per ``farfield up``; several API processes each count
their own).  Behind a reverse proxy every client has the proxy's address: run uvicorn with
``--proxy-headers`` and ``--forwarded-allow-ips`` for the proxy so the client's own address is used,
or rate-limit at the proxy.
"""

from __future__ import annotations

import math
import threading
import time
from collections import OrderedDict, deque

from farfield.core.errors import AuthRateError

MAX_FAILURES = 20  # per client per window
WINDOW_S = 60.0
MAX_CLIENTS = 100_000  # addresses remembered at most (the least recently failed are forgotten first)


class FailedAuthLimiter:
    """Per-client counts of failed authentication over a sliding window (the module docstring).

    >>> limiter = FailedAuthLimiter(max_failures=2, window_s=60.0)
    >>> limiter.record("10.0.0.1", now=0.0); limiter.record("10.0.0.1", now=1.0)
    >>> limiter.check("10.0.0.2", now=2.0)  # another client is not affected
    >>> try:
    ...     limiter.check("10.0.0.1", now=2.0)
    ... except AuthRateError as error:
    ...     print(error.retry_after_s)
    58
    >>> limiter.check("10.0.0.1", now=60.5)  # the first failure has left the window
    """

    def __init__(self, max_failures: int = MAX_FAILURES, window_s: float = WINDOW_S, max_clients: int = MAX_CLIENTS):
        if max_failures < 1 or not window_s > 0.0:
            raise ValueError(
                f"a failed-auth limiter needs max_failures >= 1 and window_s > 0, got {max_failures}, {window_s}"
            )
        self.max_failures, self.window_s, self.max_clients = max_failures, window_s, max_clients
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()
        self._lock = threading.Lock()

    def _recent(self, client: str, now: float) -> deque[float] | None:
        times = self._failures.get(client)
        if times is not None:
            while times and times[0] <= now - self.window_s:
                times.popleft()
            if not times:
                del self._failures[client]
                return None
        return times

    def check(self, client: str, now: float | None = None) -> None:
        """Raise :class:`AuthRateError` when ``client`` has failed ``max_failures`` times in the window."""
        now = time.monotonic() if now is None else now
        with self._lock:
            times = self._recent(client, now)
            if times is not None and len(times) >= self.max_failures:
                wait = max(1, math.ceil(times[0] + self.window_s - now))
                raise AuthRateError(
                    f"too many requests with keys that do not authenticate from this address ({len(times)} in "
                    f"{self.window_s:g} s, FARFIELD_AUTH_FAILURES={self.max_failures}); try again in {wait} s",
                    retry_after_s=wait,
                )

    def record(self, client: str, now: float | None = None) -> None:
        """Count one failed authentication of ``client``."""
        now = time.monotonic() if now is None else now
        with self._lock:
            times = self._recent(client, now)
            if times is None:
                times = self._failures[client] = deque()
            self._failures.move_to_end(client)
            times.append(now)
            while len(times) > self.max_failures:
                times.popleft()
            while len(self._failures) > self.max_clients:
                self._failures.popitem(last=False)

"""Failed authentication is rate-limited per client (issue 59, item 11): the campaign tried 2,000
random keys at 230 requests/s and got 2,000 plain 401s.

:class:`FailedAuthLimiter` counts, per client address (an IPv6 address by its /64, which one host
is usually given whole), the requests of the last ``window_s`` seconds that presented credentials
which did not authenticate (a wrong, revoked or malformed key; a request with no ``Authorization``
header at all is not counted: it guessed nothing).  Past ``max_failures`` of them, each further
failure is answered 429 (:class:`~farfield.core.errors.AuthRateError`, ``Retry-After`` the seconds
until its oldest failure leaves the window) instead of 401, so a guesser is slowed and told so.
A key that authenticates always passes: a stranger on a shared address (a NAT, a proxy) cannot
lock its other users out, and a guess that would have to hit a 128-bit key needs no hiding.

The count lives in the API process (one per ``farfield up``; several API processes each count
their own).  Behind a reverse proxy every client has the proxy's address: give uvicorn the proxy's
address in ``FORWARDED_ALLOW_IPS`` (``farfield up`` passes its environment on; uvicorn then takes
the client's address from ``X-Forwarded-For``), or rate-limit at the proxy.
"""

from __future__ import annotations

import ipaddress
import math
import threading
import time
from collections import OrderedDict, deque

from farfield.core.errors import AuthRateError

MAX_FAILURES = 20  # per client per window
WINDOW_S = 60.0
MAX_CLIENTS = 100_000  # addresses remembered at most (the least recently failed are forgotten first)


def client_key(address: str) -> str:
    """What a client is counted by: its IPv4 address, or its IPv6 address's /64.

    >>> client_key("203.0.113.7"), client_key("2001:db8:1:2:3:4:5:6"), client_key("testclient")
    ('203.0.113.7', '2001:db8:1:2::/64', 'testclient')
    """
    try:
        ip = ipaddress.ip_address(address)
    except ValueError:
        return address
    if ip.version == 6:
        if ip.ipv4_mapped is not None:  # ::ffff:a.b.c.d is the IPv4 client a.b.c.d
            return str(ip.ipv4_mapped)
        return str(ipaddress.ip_network(f"{ip}/64", strict=False))
    return str(ip)


class FailedAuthLimiter:
    """Per-client counts of failed authentication over a sliding window (the module docstring).

    >>> limiter = FailedAuthLimiter(max_failures=2, window_s=60.0)
    >>> limiter.failed("10.0.0.1", now=0.0); limiter.failed("10.0.0.1", now=1.0)
    >>> limiter.failed("10.0.0.2", now=2.0)  # another client is not affected
    >>> try:
    ...     limiter.failed("10.0.0.1", now=2.0)
    ... except AuthRateError as error:
    ...     print(error.retry_after_s)
    58
    >>> limiter.failed("10.0.0.1", now=61.5)  # two have left the window (a refused guess counts too)
    """

    def __init__(self, max_failures: int = MAX_FAILURES, window_s: float = WINDOW_S, max_clients: int = MAX_CLIENTS):
        if max_failures < 1 or not window_s > 0.0:
            raise ValueError(
                f"a failed-auth limiter needs max_failures >= 1 and window_s > 0, got {max_failures}, {window_s}"
            )
        self.max_failures, self.window_s, self.max_clients = max_failures, window_s, max_clients
        self._failures: OrderedDict[str, deque[float]] = OrderedDict()
        self._lock = threading.Lock()

    def failed(self, address: str, now: float | None = None) -> None:
        """Count one failed authentication of the client at ``address``, and raise
        :class:`AuthRateError` when it has now failed more than ``max_failures`` times in the
        window (checked and counted in one step: simultaneous guesses cannot all slip under it)."""
        client = client_key(address)
        now = time.monotonic() if now is None else now
        with self._lock:
            times = self._failures.get(client)
            if times is None:
                times = self._failures[client] = deque()
            while times and times[0] <= now - self.window_s:
                times.popleft()
            self._failures.move_to_end(client)
            times.append(now)
            while len(times) > self.max_failures + 1:  # the count never needs more than the limit and one
                times.popleft()
            while len(self._failures) > self.max_clients:
                self._failures.popitem(last=False)
            if len(times) > self.max_failures:
                wait = max(1, math.ceil(times[0] + self.window_s - now))
                raise AuthRateError(
                    f"too many requests with keys that do not authenticate from this address (more than "
                    f"{self.max_failures} in {self.window_s:g} s, FARFIELD_AUTH_FAILURES); try again in {wait} s",
                    retry_after_s=wait,
                )

"""Read timeouts for the API's HTTP connections (issue 59, item 11): uvicorn's own HTTP/1.1 protocol
holds a connection whose request headers never finish for as long as the client likes (the campaign
held one for 90 s and more, and a few hundred such connections take every file descriptor), and a
body that stops arriving just as long.

:class:`TimedH11Protocol` is uvicorn's h11 protocol with two deadlines:

- **headers**: a request's line and headers must arrive within ``FARFIELD_HEADER_TIMEOUT_S``
  (default 10) of the connection opening or of the previous response ending (uvicorn's keep-alive
  timeout still closes a connection that sends nothing after a response);
- **body**: while a request body is being read, ``FARFIELD_BODY_IDLE_TIMEOUT_S`` (default 30) may
  pass at most without a byte of it (time the server itself stops reading, when the app is slow to
  consume, does not count).

Past either, the connection gets a 408 (JSON ``{detail, error}``) when no response to the request has
begun (a kept-alive connection's previous response does not count), and is closed; the route
reading the body sees the client gone.

A client that closes its sending side (``shutdown(SHUT_WR)``, ``nc -N``) is still answered: uvicorn
closed the whole connection at the end of its input, so a complete request so ended got no
response, and one whose body fell short of its ``Content-Length`` (or whose headers were cut) was
dropped without a word.  Now a request still missing bytes gets a JSON 400 saying so and the
connection is closed; a complete one gets its response, as does each request pipelined behind it
(a cut one its 400), then the connection is closed.  A client that trickles a byte of body
every few seconds is not caught (that would need a minimum rate); behind a reverse proxy its own
timeouts apply first.  ``farfield up`` runs uvicorn with ``--http farfield.api.read_timeouts:TimedH11Protocol``.
"""

from __future__ import annotations

import asyncio
import json
import os

import h11
from uvicorn.protocols.http.h11_impl import H11Protocol

HEADER_TIMEOUT_S = 10.0
BODY_IDLE_TIMEOUT_S = 30.0


def timeout_setting(name: str, default: float) -> float:
    """Seconds from the environment variable ``name`` (a positive number), else ``default``.

    >>> timeout_setting("FARFIELD_NO_SUCH_TIMEOUT", 7.0)
    7.0
    """
    raw = os.environ.get(name, "").strip()
    if not raw:
        return default
    try:
        value = float(raw)
    except ValueError:
        value = float("nan")
    if not value > 0.0 or value == float("inf"):
        raise ValueError(f"{name} must be a positive number of seconds, got {raw!r}")
    return value


def _closing_response(status: str, error: str, detail: str) -> bytes:
    body = json.dumps({"detail": detail, "error": error}).encode()
    head = (
        f"HTTP/1.1 {status}\r\ncontent-type: application/json\r\nconnection: close\r\n"
        f"content-length: {len(body)}\r\n\r\n"
    )
    return head.encode() + body


def _timeout_response(detail: str) -> bytes:
    return _closing_response("408 Request Timeout", "RequestTimeoutError", detail)


def _bad_request_response(detail: str) -> bytes:
    return _closing_response("400 Bad Request", "BadRequestError", detail)


class TimedH11Protocol(H11Protocol):
    """uvicorn's h11 protocol with a header deadline and a body idle timeout (the module docstring)."""

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self.header_timeout = timeout_setting("FARFIELD_HEADER_TIMEOUT_S", HEADER_TIMEOUT_S)
        self.body_timeout = timeout_setting("FARFIELD_BODY_IDLE_TIMEOUT_S", BODY_IDLE_TIMEOUT_S)
        self._read_timer: asyncio.TimerHandle | None = None
        self._client_ended = False  # the client closed its sending side (eof_received)

    def connection_made(self, transport) -> None:  # type: ignore[override]
        super().connection_made(transport)
        self._arm(self.header_timeout, self._headers_late)

    def connection_lost(self, exc: Exception | None) -> None:
        self._disarm()
        super().connection_lost(exc)

    def data_received(self, data: bytes) -> None:
        super().data_received(data)
        self._follow_state()

    def eof_received(self) -> bool:  # type: ignore[override]
        """The client closed its sending side: answer what it sent (the module docstring).  True keeps
        the transport open for the response; False lets asyncio close it (nothing to answer)."""
        self._client_ended = True
        return self._answer_the_rest()

    def _answer_the_rest(self) -> bool:
        """After the client's end of input: a 400 for a request it left incomplete; True while a
        response is on its way (:meth:`on_response_complete` looks again after it, for a request
        pipelined behind it); False when nothing is left to answer."""
        state, cycle = self.conn.their_state, self.cycle
        answering = cycle is not None and not cycle.response_complete
        if state is h11.SEND_BODY and answering and not cycle.response_started:
            length = dict(self.headers).get(b"content-length")
            expected = f" (Content-Length: {length.decode('latin-1')})" if length else ""
            self._close(
                f"the request's body ended before it was complete{expected}: the client closed its side of the "
                "connection; send the whole body",
                _bad_request_response,
            )
            return True
        if state is h11.IDLE and self.conn.trailing_data[0] and not answering:  # a request line or headers cut
            self._close("the request's line or headers ended before they were complete", _bad_request_response)
            return True
        return state in (h11.SEND_BODY, h11.DONE, h11.MUST_CLOSE) and answering  # the response is on its way

    def on_response_complete(self) -> None:
        super().on_response_complete()  # starts the cycle of a request pipelined behind, if one came whole
        self._disarm()  # uvicorn's keep-alive timeout takes over until the next request's first byte
        if self._client_ended and not self.transport.is_closing() and not self._answer_the_rest():
            self.transport.close()  # the client sent nothing more

    def _follow_state(self) -> None:
        """Arm the deadline that applies in the connection's state after new data."""
        if self.transport.is_closing():
            return
        state = self.conn.their_state
        if state is h11.IDLE:  # bytes of a request line or headers: the header deadline runs from the first
            if self._read_timer is None:
                self._arm(self.header_timeout, self._headers_late)
        elif state is h11.SEND_BODY:  # every byte of body restarts the idle timeout
            self._arm(self.body_timeout, self._body_idle)
        else:
            self._disarm()

    def _arm(self, delay: float, callback) -> None:
        self._disarm()
        self._read_timer = self.loop.call_later(delay, callback)

    def _disarm(self) -> None:
        if self._read_timer is not None:
            self._read_timer.cancel()
            self._read_timer = None

    def _headers_late(self) -> None:
        self._read_timer = None
        if self.conn.their_state is h11.IDLE and not self.transport.is_closing():
            self._close(
                f"the request's headers did not arrive within {self.header_timeout:g} s (FARFIELD_HEADER_TIMEOUT_S)"
            )

    def _body_idle(self) -> None:
        self._read_timer = None
        if self.conn.their_state is not h11.SEND_BODY or self.transport.is_closing():
            return
        if self.flow.read_paused:  # the server stopped reading (the app is slow): not the client's time
            self._arm(self.body_timeout, self._body_idle)
            return
        self._close(f"no byte of the request's body arrived for {self.body_timeout:g} s (FARFIELD_BODY_IDLE_TIMEOUT_S)")

    def _close(self, detail: str, response=None) -> None:
        if self.conn.their_state is h11.IDLE or self.cycle is None or not self.cycle.response_started:
            # No response begun to the request the client is on (IDLE: the previous one's is complete).
            self.transport.write((response or _timeout_response)(detail))
        self.logger.warning("closing a connection from %s: %s", self.client, detail)
        self.transport.close()

"""Security headers on every response (issue 59, item 11): the dashboard keeps an API key in
localStorage, so it must not be framed, sniffed into another type or fed a script from elsewhere.

* ``Content-Security-Policy``: scripts, styles, fetches and workers from this origin only; images
  also from ``blob:`` and ``data:`` (the atlas viewer's object URLs, GLB textures); the viewer's
  one inline script, its import map, is allowed by its SHA-256 (read from ``viewer.html``), no
  other inline script or ``eval``; no plugins, no ``<base>``, no framing, forms to this origin.
  FastAPI's ``/docs`` and ``/redoc`` pages (Swagger UI and ReDoc from a CDN) are left without it.
* ``X-Frame-Options: DENY`` (older browsers), ``X-Content-Type-Options: nosniff``,
  ``Referrer-Policy: no-referrer``.

The ``Server`` banner is not sent: ``farfield up`` runs uvicorn with ``--no-server-header``.
"""

from __future__ import annotations

import base64
import hashlib
import re
from pathlib import Path

_DASHBOARD = Path(__file__).resolve().parent / "dashboard"
_INLINE = re.compile(r"<script[^>]*>(.*?)</script>", re.DOTALL)


def inline_script_hashes(html: str) -> list[str]:
    """CSP source expressions (``'sha256-...'``) of the inline scripts of ``html`` (those with a
    body; an empty ``<script src>`` has none)."""
    return [
        "'sha256-" + base64.b64encode(hashlib.sha256(body.encode()).digest()).decode() + "'"
        for body in _INLINE.findall(html)
        if body.strip()
    ]


def content_security_policy() -> str:
    """The policy (module docstring), with the dashboard pages' inline scripts by hash."""
    hashes = []
    for page in sorted(_DASHBOARD.glob("*.html")):
        hashes += inline_script_hashes(page.read_text(encoding="utf-8"))
    return "; ".join(
        [
            "default-src 'self'",
            "script-src 'self' " + " ".join(hashes) if hashes else "script-src 'self'",
            "style-src 'self'",
            "img-src 'self' blob: data:",
            "connect-src 'self' blob: data:",  # three.js fetches a GLB's embedded images as blobs
            "worker-src 'self' blob:",
            "object-src 'none'",
            "base-uri 'none'",
            "frame-ancestors 'none'",
            "form-action 'self'",
        ]
    )


class SecurityHeaders:
    """ASGI middleware adding the headers of the module docstring to every HTTP response."""

    def __init__(self, app) -> None:
        self.app = app
        self.policy = (b"content-security-policy", content_security_policy().encode())
        self.headers = [
            (b"x-frame-options", b"DENY"),
            (b"x-content-type-options", b"nosniff"),
            (b"referrer-policy", b"no-referrer"),
        ]

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return

        # FastAPI's own /docs and /redoc pages load Swagger UI and ReDoc from a CDN with inline
        # scripts: they keep the other headers but not the policy.
        own_page = not scope["path"].startswith(("/docs", "/redoc"))
        headers = [self.policy, *self.headers] if own_page else self.headers

        async def with_headers(message):
            if message["type"] == "http.response.start":
                present = {name.lower() for name, _ in message.get("headers", [])}
                extra = [(name, value) for name, value in headers if name not in present]
                message = {**message, "headers": [*message.get("headers", []), *extra]}
            await send(message)

        await self.app(scope, receive, with_headers)

"""Request bodies are bounded while they arrive, and uploads are authenticated before they are read.

FastAPI reads (and Starlette spools to disk) a request's body before the route's dependencies run,
so neither a size check in the route nor its key check would stop a multi-gigabyte body from a
stranger.  :class:`BodyLimit` is plain ASGI middleware in front of everything: it refuses a declared
``Content-Length`` over the limit at once, counts the bytes of a body without one (chunked) as they
arrive and aborts past the limit (413), and checks the key of a scene upload before a byte of it
is read (401).
"""

from __future__ import annotations

import json

from fastapi import HTTPException
from starlette.concurrency import run_in_threadpool
from starlette.formparsers import MultiPartParser

from farfield.api.deps import client_address
from farfield.core.errors import AuthError, AuthRateError, BusyError

JSON_BODY_LIMIT = 8 * 2**20  # job specs: 10,000 explicit view cells fit with room to spare
MULTIPART_ENVELOPE = 64 * 1024

# Memory per multipart request (issue 59, item 8).  Starlette keeps each file part in memory up to
# 1 MiB before it spools it to disk, and takes 1,000 of them: 300 parts of 1 MiB raised the API's
# resident memory by 304 MiB.  A part now goes to disk past SPOOL_BYTES, and an upload has at most
# FORM_LIMITS["max_files"] parts (a scene, its MTL, buffers and textures; more in a .zip) and a few
# small text fields, so one request holds at most about 256 x 64 KiB = 16 MiB of parts in memory.
SPOOL_BYTES = 64 * 1024
FORM_LIMITS = {"max_files": 256, "max_fields": 16, "max_part_size": 64 * 1024}
MultiPartParser.spool_max_size = SPOOL_BYTES  # a class attribute: every form this process parses


class BodyLimit:
    """ASGI middleware: 413 past the limit of the route, 401 for an upload with a bad key."""

    def __init__(self, app, services) -> None:
        self.app, self.services = app, services

    def _limit(self, scope) -> int:
        if scope["method"] == "POST" and scope["path"] == "/v1/scenes":
            return self.services.settings.max_upload_bytes + MULTIPART_ENVELOPE
        return JSON_BODY_LIMIT

    async def _reply(self, send, status: int, detail: str, error: str, extra: dict | None = None) -> None:
        headers = [(b"content-type", b"application/json"), *(extra or {}).items()]
        if status == 401:
            headers.append((b"www-authenticate", b"Bearer"))
        await send({"type": "http.response.start", "status": status, "headers": headers})
        await send({"type": "http.response.body", "body": json.dumps({"detail": detail, "error": error}).encode()})

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        limit = self._limit(scope)
        headers = dict(scope["headers"])
        length = headers.get(b"content-length", b"").decode()
        if length.isdigit() and int(length) > limit:
            await self._reply(
                send,
                413,
                f"request body of {int(length)} bytes is larger than the limit of {limit} bytes",
                "UploadTooLargeError",
            )
            return
        if scope["method"] == "POST" and scope["path"] == "/v1/scenes":
            values = [v.decode(errors="replace") for k, v in scope["headers"] if k.lower() == b"authorization"]
            try:
                await run_in_threadpool(self.services.authenticate, client_address(scope), values)
            except AuthRateError as error:
                await self._reply(
                    send, 429, str(error), "AuthRateError", {b"retry-after": str(error.retry_after_s).encode()}
                )
                return
            except AuthError as error:
                await self._reply(send, 401, str(error), "AuthError")
                return
            # A place among the scene checks (service/scene_check.py) before a byte of the body is
            # read: a full gate refuses at once, and the upload is neither received nor spooled.
            try:
                place = self.services.scene_checks.admitted()
                place.__enter__()
            except BusyError as error:
                await self._reply(
                    send, 429, str(error), "BusyError", {b"retry-after": str(error.retry_after_s).encode()}
                )
                return
            try:
                await self.app(scope, self._counted(receive, limit), send)
            finally:
                place.__exit__(None, None, None)
            return
        await self.app(scope, self._counted(receive, limit), send)

    @staticmethod
    def _counted(receive, limit: int):
        """``receive`` counting the body's bytes: past ``limit``, a 413."""
        received = 0

        async def counted():
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    # An HTTPException passes through FastAPI's body parsing unchanged.
                    raise HTTPException(413, f"request body is larger than the limit of {limit} bytes")
            return message

        return counted

"""Error responses: one JSON body ``{"detail": str, "error": str}`` (:class:`farfield.api.openapi.ErrorBody`)
for every error the API returns, whoever raises it.

- a :class:`FarfieldError` from a service function: its HTTP status (``ErrorKind``), ``error`` its class name;
- a request that does not validate: 422 ``ValidationError``, one ``field: message, got value`` per problem;
- Starlette's own errors: 404 for a path that no route serves, 405 for a method a path does not
  have (with an ``Allow`` header listing every method of that path: Starlette lists only those of
  the one route it tried, so ``PUT /v1/scenes/{id}`` said ``Allow: GET`` although DELETE is there
  too: the methods come from the OpenAPI document, :func:`farfield.api.openapi.declared_methods`),
  400 for a multipart body that does not parse, 413 from :class:`farfield.api.limits.BodyLimit`.

OPTIONS is a method like any other here: no path declares it, so it is a 405 with ``Allow``.
"""

from __future__ import annotations

import json
import logging
import math

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException

from farfield.api.openapi import ErrorBody, declared_methods
from farfield.core.errors import ErrorKind, FarfieldError

# Starlette's HTTPException by status, named like the farfield errors of the same meaning.
HTTP_ERROR_NAMES = {
    400: "BadRequestError",
    404: "NotFoundError",
    405: "MethodNotAllowedError",
    413: "UploadTooLargeError",
}


def error_response(status: int, detail: str, error: str, headers: dict[str, str] | None = None) -> JSONResponse:
    return JSONResponse(ErrorBody(detail=detail, error=error).model_dump(), status_code=status, headers=headers)


def _shown(value) -> str | None:
    """A short, JSON-safe rendering of a rejected input value, or None when it is not worth showing."""
    if isinstance(value, float) and not math.isfinite(value):
        return "NaN" if math.isnan(value) else ("Infinity" if value > 0 else "-Infinity")
    if value is None or isinstance(value, (bool, int, float)):
        return json.dumps(value)
    if isinstance(value, str):
        return json.dumps(value if len(value) <= 60 else value[:57] + "...")
    return None


def validation_detail(errors) -> str:
    """One line per problem of a request's validation, ``field: message, got value``; the input is
    never echoed as JSON (a NaN or an infinity in it made FastAPI's own 422 body unencodable: 500).

    >>> validation_detail([{"loc": ("body", "resolution"), "msg": "Input should be a valid integer", "input": float("nan")}])
    'resolution: Input should be a valid integer, got NaN'
    """
    lines = []
    for problem in errors:
        where = ".".join(str(part) for part in problem.get("loc", ()) if part != "body")
        shown = _shown(problem.get("input"))
        lines.append(
            f"{where + ': ' if where else ''}{problem.get('msg', 'invalid')}{', got ' + shown if shown else ''}"
        )
    return "; ".join(lines)


QUOTA_RETRY_AFTER_S = 30  # Retry-After of a 429

# A multipart part without a filename is a text field: ``curl -F 'file=<scene.glb'`` sends the scene
# so.  Pydantic's "Expected UploadFile, received: <class 'str'>" (a small one) and the parser's "Part
# exceeded maximum size of 64KB." (a larger one) answered it without saying what to do.
TEXT_NOT_FILE = (
    "a multipart part without a filename is a text field (at most 64 KiB), not a file: send the scene "
    "as a file part, with a filename in its Content-Disposition (curl -F file=@scene.glb)"
)


NO_BODY = "the request has no body: send a JSON object (Content-Type: application/json)"


def _sent_as_text(problem) -> bool:
    """Whether a validation problem is a text field where the upload route takes a file."""
    loc = problem.get("loc", ())
    return len(loc) >= 2 and loc[:2] == ("body", "file") and "Expected UploadFile" in str(problem.get("msg", ""))


def install_error_handlers(app: FastAPI) -> None:
    """Answer every error of ``app`` with an :class:`ErrorBody`."""

    @app.exception_handler(FarfieldError)
    async def farfield_error(_request: Request, error: FarfieldError) -> JSONResponse:
        if error.kind is ErrorKind.INTERNAL:  # a bug (HTTP 500): keep its traceback
            logging.getLogger("farfield.api").error("internal error: %s", error, exc_info=error)
        headers = {"WWW-Authenticate": "Bearer"} if error.kind is ErrorKind.UNAUTHORIZED else None
        if error.kind is ErrorKind.OVER_QUOTA:  # the tenant's open work has to end first: a hint, not a promise
            headers = {"Retry-After": str(getattr(error, "retry_after_s", QUOTA_RETRY_AFTER_S))}
        return error_response(error.kind.http_status, str(error), type(error).__name__, headers)

    @app.exception_handler(RequestValidationError)
    async def validation_error(_request: Request, error: RequestValidationError) -> JSONResponse:
        if any(_sent_as_text(problem) for problem in error.errors()):
            return error_response(422, TEXT_NOT_FILE, "ValidationError")
        if any(tuple(p.get("loc", ())) == ("body",) and p.get("type") == "missing" for p in error.errors()):
            return error_response(422, NO_BODY, "ValidationError")  # was "Field required, got null"
        return error_response(422, validation_detail(error.errors()), "ValidationError")

    @app.exception_handler(HTTPException)
    async def http_error(request: Request, error: HTTPException) -> JSONResponse:
        status, detail, headers = error.status_code, str(error.detail), dict(error.headers or {})
        if status == 400 and detail.startswith("Part exceeded maximum size") and request.url.path == "/v1/scenes":
            detail = TEXT_NOT_FILE
        if status == 404 and detail == "Not Found":
            detail = f"no such path {request.url.path!r}"
        if status == 405:
            # Starlette's Allow lists the methods of the one route it tried; the path may have more.
            allowed = declared_methods(request.app.openapi(), request.url.path)
            if allowed is not None:
                headers["Allow"] = ", ".join(allowed)
            detail = f"{request.method} is not a method of {request.url.path!r}; it has {headers.get('Allow', '')}"
        return error_response(status, detail, HTTP_ERROR_NAMES.get(status, "HTTPError"), headers or None)

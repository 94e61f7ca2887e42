"""The OpenAPI document of the app: FastAPI's, completed with what the routes do not say themselves.

- every error status an operation can answer, each with :class:`ErrorBody`, the one body of every
  error response (:mod:`farfield.api.errors`),
  replacing FastAPI's 422 ``HTTPValidationError`` (an array the API never sends):

  - 401 (with ``WWW-Authenticate``) on every operation that needs a key (FastAPI lists the Bearer
    key as its ``security``, from :data:`farfield.api.deps.BEARER_KEY`),
  - 404 on every path with an id in it,
  - 422 on every operation with parameters or a body,
  - 413 on every body (:mod:`farfield.api.limits`), and 400 (one that does not parse: FastAPI's
    answer to a JSON body that is not UTF-8, Starlette's to a broken multipart form),
  - and the statuses of :data:`EXTRA_STATUSES`, which the shape of an operation does not tell;
- the media type of each file route (``.zip``, ``.png``, ...) instead of FastAPI's default JSON;
- the upload's ``file`` as required (the route answers its absence with its own 422);
- the job states as the values of ``GET /v1/jobs?state=`` (the service refuses any other).

A method that a path does not declare is a 405 whose ``Allow`` lists the path's declared methods
(:func:`declared_methods`; OPTIONS and HEAD are declared nowhere).  ``app.openapi`` is replaced by
:func:`openapi_document` (FastAPI's documented way to extend the document); ``tests/test_openapi.py``
runs schemathesis over the result.
"""

from __future__ import annotations

import re

from fastapi import FastAPI
from pydantic import BaseModel, Field

from farfield.service.db import JOB_STATES


class ErrorBody(BaseModel):
    """The body of every error response."""

    detail: str = Field(description="what is wrong, naming the offending field or value")
    error: str = Field(
        description="the kind of error: a farfield error class (NotFoundError, AuthError, ...) or ValidationError"
    )


ERROR_DESCRIPTIONS = {
    400: "The body does not parse (not text in its encoding, a broken multipart form)",
    401: "No valid API key: send 'Authorization: Bearer <key>'",
    404: "No such scene, job, cell, object or result for this key's tenant",
    409: "Not allowed in the current state of the job or scene",
    413: "The body, the upload or the scene's structure is over its limit",
    422: "The request is invalid; the detail names each offending field and value",
    429: "Too many requests with keys that do not authenticate from this address, over the tenant's limit of queued work, or every scene-check place taken; retry after Retry-After seconds",
}
# Statuses that the shape of an operation does not tell, by (method, path).
EXTRA_STATUSES = {
    ("post", "/v1/jobs"): {404},  # the scene or an object the body names
    ("delete", "/v1/scenes/{scene_id}"): {409},  # unfinished jobs use the scene
    ("post", "/v1/jobs/{job_id}/cancel"): {409},  # the job has ended
    ("post", "/v1/jobs/{job_id}/retry"): {409},  # the job has not failed
    ("get", "/v1/jobs/{job_id}/database.zip"): {409},  # the job has not ended
    ("get", "/v1/jobs/{job_id}/index.json"): {409},  # the index is written when the job ends
    ("get", "/v1/jobs/{job_id}/clusters"): {409},  # a placement job before its index is written
    ("get", "/v1/jobs/{job_id}/lookup"): {409},  # a placement job without its database yet
    ("get", "/v1/jobs/{job_id}/placement"): {409},  # the job has no database yet
}
FILE_MEDIA_TYPES = {
    ".zip": "application/zip",
    ".bin": "application/octet-stream",
    ".png": "image/png",
    ".glb": "model/gltf-binary",
}
# Multipart fields that a route takes as optional only to answer their absence with its own 422.
REQUIRED_FORM_FIELDS = {
    ("post", "/v1/scenes"): {
        "file": {"type": "string", "format": "binary", "description": "the scene file (glb, gltf, obj, ply, stl)"}
    }
}
# Values of query parameters that the route types as a plain string, by (method, path, name).
QUERY_VALUES = {("get", "/v1/jobs", "state"): list(JOB_STATES)}
FASTAPI_ERROR_SCHEMAS = ("HTTPValidationError", "ValidationError")
METHODS = ("get", "put", "post", "delete", "options", "head", "patch", "trace")


def _error_response(status: int) -> dict:
    response = {
        "description": ERROR_DESCRIPTIONS[status],
        "content": {"application/json": {"schema": {"$ref": "#/components/schemas/ErrorBody"}}},
    }
    if status == 401:
        response["headers"] = {"WWW-Authenticate": {"description": "Bearer", "schema": {"type": "string"}}}
    if status == 429:
        response["headers"] = {"Retry-After": {"description": "seconds to wait", "schema": {"type": "string"}}}
    return response


def error_statuses(method: str, path: str, operation: dict) -> set[int]:
    """The error statuses of an operation of the document (besides 405 and 500).

    >>> sorted(error_statuses("get", "/v1/scenes/{scene_id}", {"parameters": [{"name": "scene_id"}], "security": [{"BearerKey": []}]}))
    [401, 404, 422, 429]
    """
    statuses = set(EXTRA_STATUSES.get((method, path), ()))
    if operation.get("security"):
        statuses |= {401, 429}  # 429: the client's failed authentication (api/auth_failures.py)
    if "{" in path:
        statuses.add(404)
    if operation.get("parameters") or "requestBody" in operation:
        statuses.add(422)
    if "requestBody" in operation:
        statuses |= {400, 413}
    return statuses


def describe(document: dict) -> dict:
    """Complete FastAPI's ``document`` in place (see the module's docstring); returns it."""
    schemas = document.setdefault("components", {}).setdefault("schemas", {})
    for name in FASTAPI_ERROR_SCHEMAS:
        schemas.pop(name, None)
    schemas["ErrorBody"] = ErrorBody.model_json_schema()
    for path, item in document["paths"].items():
        media_type = FILE_MEDIA_TYPES.get("." + path.rpartition(".")[2])
        for method, operation in item.items():
            if method not in METHODS:
                continue
            responses = operation["responses"]
            for status in sorted(error_statuses(method, path, operation)):
                responses[str(status)] = _error_response(status)
            fields = REQUIRED_FORM_FIELDS.get((method, path))
            if fields:
                body = operation["requestBody"]
                form = body["content"]["multipart/form-data"]["schema"]
                form = schemas[form["$ref"].rpartition("/")[2]] if "$ref" in form else form
                form["properties"].update(fields)
                form["required"] = sorted(set(form.get("required", [])) | set(fields))
                body["required"] = True
            if media_type is not None and "200" in responses:
                responses["200"]["content"] = {media_type: {"schema": {"type": "string", "format": "binary"}}}
            for parameter in operation.get("parameters", []):
                values = QUERY_VALUES.get((method, path, parameter["name"]))
                if values is not None and parameter["in"] == "query":
                    parameter["schema"] = {
                        "type": "string",
                        "enum": values,
                        "title": parameter["schema"].get("title", parameter["name"]),
                    }
    return document


BOUND_KEYS = ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "multipleOf")


def integral_bounds(node):
    """Bounds written back as integers where they are whole: FastAPI's document model types them as
    floats (``minimum: 1.0``), and a generator then makes ``108574.0`` for an integer field, which
    the API's strict integers refuse.

    >>> integral_bounds({"type": "integer", "minimum": 1.0, "items": [{"maximum": 2.5}]})
    {'type': 'integer', 'minimum': 1, 'items': [{'maximum': 2.5}]}
    """
    if isinstance(node, dict):
        for key, value in node.items():
            if key in BOUND_KEYS and isinstance(value, float) and value.is_integer():
                node[key] = int(value)
            else:
                integral_bounds(value)
    elif isinstance(node, list):
        for value in node:
            integral_bounds(value)
    return node


def openapi_document(app: FastAPI) -> dict:
    """``app.openapi``: the completed document, built once."""
    if app.openapi_schema is None:
        integral_bounds(describe(FastAPI.openapi(app)))  # FastAPI's own, which it keeps as app.openapi_schema
    return app.openapi_schema


def _template(path: str) -> re.Pattern:
    return re.compile(
        "".join(r"[^/]+" if part.startswith("{") else re.escape(part) for part in re.split(r"(\{[^}]+\})", path))
        + r"\Z"
    )


def declared_methods(document: dict, path: str) -> list[str] | None:
    """The methods the document declares for the request path ``path`` (upper case, sorted), or
    None when no path of the document matches it.

    >>> document = {"paths": {"/v1/scenes/{scene_id}": {"get": {}, "delete": {}, "parameters": []}}}
    >>> declared_methods(document, "/v1/scenes/abc"), declared_methods(document, "/v1/scenes/abc/x")
    (['DELETE', 'GET'], None)
    """
    methods: set[str] = set()
    for template, item in document["paths"].items():
        if _template(template).match(path):
            methods |= {method.upper() for method in item if method in METHODS}
    return sorted(methods) if methods else None

"""A multipart form is taken only whole and unambiguous: it reaches its closing boundary, and a
field the route takes once is sent once.

- Starlette's parser (python-multipart) ends a body that stops before its closing ``--boundary--``
  silently: the parts it saw whole are the form, the cut one is dropped, so a truncated upload was
  answered "send the scene as multipart form field 'file'".  :func:`require_closing_boundary` makes
  such a body a 400 that says it was cut short.  An empty body is an empty form, not a cut one: the
  route then names the field it misses (a 422), as for a form without it.
- FastAPI reads a form field declared ``str`` as the last of its values, so two ``sides`` fields in
  one upload went through as the second.  :func:`one_value_per_field` (a dependency of every route)
  answers a 422 naming each single-valued field sent more than once; a route's list fields (the
  upload's ``file``) take any number.  The fields are read from the route's own declaration, so a
  form field added later is checked alike.
"""

from __future__ import annotations

import json
import types
import typing

from fastapi import Request
from fastapi.exceptions import RequestValidationError
from fastapi.params import Form
from python_multipart.multipart import parse_options_header
from starlette.datastructures import FormData
from starlette.formparsers import MultiPartException, MultiPartParser

CUT_SHORT = (
    "the multipart body ends before its closing boundary (--{boundary}--): it was cut short or is "
    "incomplete; send the whole body"
)
MANY = (list, tuple, set, frozenset)


def require_closing_boundary() -> None:
    """Make every :class:`MultiPartParser` of this process refuse a body without its closing
    boundary (a class-wide change, as :data:`farfield.api.limits.SPOOL_BYTES` is; idempotent).

    python-multipart calls ``on_end`` only when it reads the closing boundary; its ``finalize`` does
    not check (a TODO there), so the check is here, after the whole body was parsed."""
    if getattr(MultiPartParser, "_farfield_whole", False):
        return
    parse = MultiPartParser.parse

    def on_end(self) -> None:
        self._farfield_ended = True

    async def parse_whole(self):
        self._farfield_ended = False
        chunks = self.stream.__aiter__()
        first = b""
        async for chunk in chunks:
            if chunk:
                first = chunk
                break
        if not first:  # no byte at all: a form without parts (a missing boundary does not matter either)
            return FormData()

        async def whole():
            yield first
            async for chunk in chunks:
                yield chunk

        self.stream = whole()
        form = await parse(self)
        if not self._farfield_ended:
            for spooled in self._files_to_close_on_error:  # every file part, the cut one too: let them go
                spooled.close()
            boundary = parse_options_header(self.headers.get("Content-Type", ""))[1].get(b"boundary", b"BOUNDARY")
            raise MultiPartException(CUT_SHORT.format(boundary=boundary[:70].decode("latin-1")))
        return form

    MultiPartParser.on_end = on_end
    MultiPartParser.parse = parse_whole
    MultiPartParser._farfield_whole = True


def _takes_many(annotation) -> bool:
    """Whether a declared field type holds several values (``list[UploadFile] | None``: yes; ``str``: no)."""
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType):
        return any(_takes_many(arg) for arg in typing.get_args(annotation))
    return annotation in MANY or origin in MANY


def _quoted(value) -> str:
    text = value if isinstance(value, str) else f"a file part {getattr(value, 'filename', '')!r}"
    return json.dumps(text if len(text) <= 40 else text[:37] + "...")


def single_valued_fields(route) -> list[str]:
    """The names of the form fields (``Form``, ``File``) of ``route`` that take one value.  A JSON
    body's parameter (``/v1/jobs``' ``spec``) is none: its body is not read as a form (which would
    parse it before the route's own checks, its key among them)."""
    dependant = getattr(route, "dependant", None)
    params = getattr(dependant, "body_params", None) or ()
    return [p.alias for p in params if isinstance(p.field_info, Form) and not _takes_many(p.field_info.annotation)]


async def one_value_per_field(request: Request) -> None:
    """422 where a form field that the route takes once is sent more than once (every route's
    dependency; it reads the form FastAPI has already parsed, and nothing of a JSON body)."""
    kind = request.headers.get("content-type", "").split(";")[0].strip().lower()
    if kind not in ("multipart/form-data", "application/x-www-form-urlencoded"):
        return
    single = single_valued_fields(request.scope.get("route"))
    if not single:
        return
    form = await request.form()  # parsed already for the route's own fields: the same object
    problems = [
        {
            "type": "repeated",
            "loc": ("body", name),
            "msg": f"sent {len(values)} times ({', '.join(_quoted(v) for v in values)}); a single-valued field is sent once",
            "input": values,  # a list: not echoed again
        }
        for name in single
        if len(values := form.getlist(name)) > 1
    ]
    if problems:
        raise RequestValidationError(problems)

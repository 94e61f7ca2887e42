"""Paged listings: ``limit`` and ``offset`` query parameters, the body a JSON array of one page, the
paging in headers: ``X-Total-Count`` (entries in all pages) and an RFC 8288 ``Link`` with
``rel="next"`` (and ``rel="prev"``) where there is such a page.

Offsets, not cursors: every list is small per tenant or immutable (a scene's objects never change),
jobs were paged by offset already, and an offset lets a client (the dashboard, ``farfield jobs``)
jump to any page and say "n of total".  A row inserted between two requests shifts a newest-first
listing by one (an entry is seen twice, none is missed); a client that must not see one twice
dedupes by id.
"""

from __future__ import annotations

from typing import Annotated
from urllib.parse import urlencode

from fastapi import Query, Request, Response

MAX_PAGE = 1000
DEFAULT_PAGE = 100

Limit = Annotated[int, Query(ge=1, le=MAX_PAGE, description=f"entries per page (at most {MAX_PAGE})")]
Offset = Annotated[int, Query(ge=0, le=2**31 - 1, description="entries to skip (newest first)")]

PAGE_HEADERS = {
    "X-Total-Count": {"description": "entries in all pages", "schema": {"type": "integer"}},
    "Link": {
        "description": 'RFC 8288 links to the neighbouring pages: <url>; rel="next", <url>; rel="prev"',
        "schema": {"type": "string"},
    },
}
PAGED = {200: {"description": "one page, newest first; paging in the headers", "headers": PAGE_HEADERS}}


def page_links(path: str, query: dict[str, str], total: int, limit: int, offset: int) -> str:
    """The ``Link`` header value for the page ``offset``..``offset + limit`` of ``total`` entries
    (relative references: right behind a proxy as well).

    >>> page_links("/v1/scenes", {"state": "done"}, 250, 100, 100)
    '</v1/scenes?state=done&limit=100&offset=200>; rel="next", </v1/scenes?state=done&limit=100&offset=0>; rel="prev"'
    >>> page_links("/v1/scenes", {}, 100, 100, 0)
    ''
    """

    def link(at: int, rel: str) -> str:
        return f'<{path}?{urlencode({**query, "limit": limit, "offset": at})}>; rel="{rel}"'

    links = []
    if offset + limit < total:
        links.append(link(offset + limit, "next"))
    if offset > 0:
        links.append(link(max(0, min(offset, total) - limit), "prev"))
    return ", ".join(links)


def set_page_headers(request: Request, response: Response, total: int, limit: int, offset: int) -> None:
    """``X-Total-Count`` and ``Link`` on ``response`` for one page of a listing."""
    response.headers["X-Total-Count"] = str(total)
    query = {k: v for k, v in request.query_params.items() if k not in ("limit", "offset")}
    links = page_links(request.url.path, query, total, limit, offset)
    if links:
        response.headers["Link"] = links

"""Plain GETs of what is already in memory, answered before the framework.

A cached level or a stored stream costs a file server nothing but a send; through
FastAPI, the same answer paid for routing, dependency resolution, query and header
validation and the exception layers, several times the send itself (a cached level of
dragon: 0.18x the requests per second of a bare app serving the same bytes). This ASGI
middleware answers the plainest form of the two hot requests,

    GET /v1/meshes/{id}/lod?vertices=N&format=F
    GET /v1/meshes/{id}/splits?from=N1&to=N2

when the ready record and the level or stream are in memory (`ReadPath`), with exactly
the headers and bytes the routes give (they share `lod_headers` and `splits_answer`).
Everything else goes to the app unchanged: a miss, an unknown, repeated or malformed
parameter, a conditional or ranged request, a browser's cross-origin request (CORS
headers), HEAD, and every error, which the routes turn into problem details.
"""

from __future__ import annotations

import re
from urllib.parse import parse_qsl

from starlette.types import ASGIApp, Receive, Scope, Send

from qem_core import codecs

from .routes.meshes import clamp_count, lod_headers, splits_answer
from .schemas import LOD_FORMATS

__all__ = ["MemoryAnswers"]

_PATH = re.compile(r"^/v1/meshes/([0-9a-f]{16})/(lod|splits)$")
_COUNT = re.compile(r"^[1-9][0-9]{0,17}$")
_QUERY = {"lod": {"vertices", "format"}, "splits": {"from", "to"}}
# A request with any of these goes to the routes (they handle them).
_DELEGATED_HEADERS = {b"if-none-match", b"range", b"if-range", b"origin"}


class MemoryAnswers:
    """ASGI middleware; see the module's docstring."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        answer = None
        if scope["type"] == "http" and scope["method"] == "GET":
            answer = _answer(scope)
        if answer is None:
            await self.app(scope, receive, send)
            return
        media_type, headers, body = answer
        raw = [(b"content-type", media_type.encode()), (b"content-length", b"%d" % len(body))]
        raw += [(name.lower().encode(), value.encode("latin-1")) for name, value in headers.items()]
        # As the CORS layer marks every answer: a shared cache must not give this one,
        # which has no CORS headers, to a cross-origin request.
        raw.append((b"vary", b"Origin"))
        await send({"type": "http.response.start", "status": 200, "headers": raw})
        await send({"type": "http.response.body", "body": body})


def _answer(scope: Scope) -> tuple[str, dict[str, str], bytes] | None:
    match = _PATH.match(scope["path"])
    if match is None or any(name in _DELEGATED_HEADERS for name, _ in scope["headers"]):
        return None
    mesh_id, kind = match[1], match[2]
    query = _query(scope["query_string"], _QUERY[kind])
    reads = getattr(scope["app"].state, "reads", None)
    record = None if query is None or reads is None else reads.cached_record(mesh_id)
    if record is None:
        return None
    if kind == "lod":
        format = query.get("format", "ply")
        if format not in LOD_FORMATS or (
            "vertices" in query and not _COUNT.match(query["vertices"])
        ):
            return None
        n = clamp_count(record, int(query["vertices"]) if "vertices" in query else None)
        lod = reads.levels.cached_lod(record, n, format)
        if lod is None:
            return None
        return codecs.MEDIA_TYPES[format], lod_headers(record, n, lod), lod.content
    if any(not _COUNT.match(value) for value in query.values()):
        return None
    n1 = clamp_count(record, int(query.get("from", record.n_base)))
    n2 = clamp_count(record, int(query["to"]) if "to" in query else None)
    stream = reads.streams.cached(record)
    if n1 > n2 or stream is None:
        return None
    headers, body = splits_answer(record, stream, n1, n2)
    return "application/x-qem-splits", headers, body


def _query(query_string: bytes, known: set[str]) -> dict[str, str] | None:
    """The query as a dict, or None unless every name is known and given once."""
    try:
        pairs = parse_qsl(
            query_string.decode("ascii"), keep_blank_values=True, strict_parsing=False
        )
    except UnicodeDecodeError:
        return None
    query = dict(pairs)
    if len(query) != len(pairs) or not set(query) <= known:
        return None
    return query

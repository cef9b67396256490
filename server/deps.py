"""FastAPI dependencies: the services of the running app, and the write guard.

The services live on ``app.state`` (set by `create_app`'s lifespan); tests replace any of
these with ``app.dependency_overrides``.
"""

from __future__ import annotations

import hmac
from collections import Counter
from typing import Annotated

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer

from .jobs import JobQueue
from .problems import Problem
from .read_path import ReadPath
from .settings import Settings
from .storage import Storage

__all__ = [
    "JobsDep",
    "ReadsDep",
    "KnownQueryOnly",
    "SingleQueryValues",
    "SettingsDep",
    "StorageDep",
    "WriterDep",
    "app_settings",
    "read_path",
    "job_queue",
    "refuse_repeated_query",
    "refuse_unknown_query",
    "require_writer",
    "storage",
]


def app_settings(request: Request) -> Settings:
    return request.app.state.settings


def storage(request: Request) -> Storage:
    return request.app.state.storage


def job_queue(request: Request) -> JobQueue:
    return request.app.state.jobs


def read_path(request: Request) -> ReadPath:
    return request.app.state.reads


SettingsDep = Annotated[Settings, Depends(app_settings)]
StorageDep = Annotated[Storage, Depends(storage)]
JobsDep = Annotated[JobQueue, Depends(job_queue)]
ReadsDep = Annotated[ReadPath, Depends(read_path)]

_bearer = HTTPBearer(
    auto_error=False,
    description="Needed for uploads and deletes when the server has write tokens "
    "(QEM_TOKENS); reads are public.",
)


def require_writer(
    settings: SettingsDep,
    credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)],
) -> None:
    """Let the request through if writes are open or it carries a configured token."""
    if not settings.tokens:
        return
    challenge = {"WWW-Authenticate": 'Bearer realm="qem-lod"'}
    if credentials is None:
        raise Problem(
            "unauthorized",
            "this server needs a write token: send 'Authorization: Bearer <token>' "
            "(the qem command reads it from QEM_TOKEN)",
            headers=challenge,
        )
    given = credentials.credentials.encode()
    if not any(hmac.compare_digest(given, token.encode()) for token in settings.tokens):
        raise Problem(
            "forbidden",
            "the bearer token is not one of this server's write tokens",
            headers={"WWW-Authenticate": 'Bearer realm="qem-lod", error="invalid_token"'},
        )


WriterDep = Annotated[None, Depends(require_writer)]


def refuse_unknown_query(request: Request) -> None:
    """Refuse query parameters the endpoint does not take, as uploads do (their model
    forbids extras): a misspelt ``?vertex=500`` would otherwise get the full mesh with a
    200, and the client would never learn its parameter was dropped."""
    route = request.scope["route"]
    known = _query_names(route.dependant)
    unknown = sorted(set(request.query_params) - known)
    if unknown:
        takes = ", ".join(sorted(known)) or "none"
        raise Problem(
            "invalid-request",
            f"unknown query parameter(s) {', '.join(map(repr, unknown))}; "
            f"{route.path} takes: {takes}",
        )


def refuse_repeated_query(request: Request) -> None:
    """Refuse a query parameter given twice (``?vertices=10&vertices=20``): which one was
    meant is a guess, and taking the last would answer a question not asked."""
    counts = Counter(name for name, _ in request.query_params.multi_items())
    repeated = sorted(name for name, count in counts.items() if count > 1)
    if repeated:
        raise Problem(
            "invalid-request",
            f"query parameter(s) {', '.join(map(repr, repeated))} given more than once; "
            "give each once",
        )


def _query_names(dependant) -> set[str]:
    """The query parameter names (aliases) an endpoint and its dependencies declare."""
    names = {field.alias for field in dependant.query_params}
    for sub_dependant in dependant.dependencies:
        names |= _query_names(sub_dependant)
    return names


KnownQueryOnly = Depends(refuse_unknown_query)
SingleQueryValues = Depends(refuse_repeated_query)

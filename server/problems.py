"""Errors as RFC 9457 problem details (``application/problem+json``).

This is the only module that turns exceptions into HTTP error responses:

- `Problem`, raised by routes, for the service's own conditions (unknown mesh, not ready,
  upload too large, missing token...), by *kind* from the `PROBLEM_KINDS` table;
- `qem_core.QemError` subclasses, by the `QEM_ERRORS` table (nearest class in the MRO);
- FastAPI's `RequestValidationError` (bad query parameters) -> 422 with the list of errors;
- Starlette's `HTTPException` (unknown route, wrong method) -> its status;
- anything else -> 500 without internals (logged with its traceback).

Every body has ``type`` (``/problems/<kind>``, or ``about:blank`` for plain HTTP errors),
``title``, ``status``, ``detail`` and ``instance`` (the request path); validation errors add
``errors``.
"""

from __future__ import annotations

import logging
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.encoders import jsonable_encoder
from fastapi.exceptions import RequestValidationError
from fastapi.openapi.utils import get_openapi
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match

import qem_core

from .storage import StorageUnavailable

__all__ = [
    "PROBLEM_KINDS",
    "PROBLEM_MEDIA_TYPE",
    "Problem",
    "ProblemDetails",
    "install_problem_handlers",
    "problem_responses",
]

PROBLEM_MEDIA_TYPE = "application/problem+json"
# How long a client should wait before asking again a service whose storage does not
# answer (a 503's Retry-After).
RETRY_AFTER_S = 5

log = logging.getLogger("qem.server")

# kind -> (status, title). The type URI of a kind is /problems/<kind>.
PROBLEM_KINDS: dict[str, tuple[int, str]] = {
    "bad-upload": (400, "The upload could not be read"),
    "invalid-range": (400, "The Range header is not one byte range"),
    "unauthorized": (401, "A bearer token is required"),
    "forbidden": (403, "The bearer token is not valid"),
    "mesh-not-found": (404, "No such mesh"),
    "texture-not-found": (404, "The mesh has no texture"),
    "mesh-not-ready": (409, "The mesh is not built yet"),
    "mesh-failed": (409, "The mesh could not be built"),
    "upload-too-large": (413, "The upload is too large"),
    "range-not-satisfiable": (416, "The range is past the end"),
    "unsupported-format": (415, "Unsupported mesh format"),
    "invalid-request": (422, "Invalid request parameters"),
    "invalid-mesh": (422, "Invalid mesh"),
    "malformed-file": (422, "Malformed mesh file"),
    "invalid-options": (422, "Invalid build options"),
    "corrupt-data": (500, "Stored data is damaged"),
    "internal-error": (500, "Internal server error"),
    "not-ready": (503, "A part the service needs is not answering"),
}

# qem_core exception -> kind; the nearest class in the exception's MRO wins.
QEM_ERRORS: dict[type[qem_core.QemError], str] = {
    qem_core.MeshFormatError: "malformed-file",
    qem_core.InvalidMeshError: "invalid-mesh",
    qem_core.InvalidOptionsError: "invalid-options",
    # A .qpm we wrote ourselves is damaged: the server's fault, not the client's.
    qem_core.CorruptFileError: "corrupt-data",
    qem_core.QemError: "invalid-request",
}


class ProblemDetails(BaseModel):
    """RFC 9457 problem details."""

    model_config = ConfigDict(extra="allow")

    type: str = Field("about:blank", examples=["/problems/mesh-not-found"])
    title: str = Field(examples=["No such mesh"])
    status: int = Field(examples=[404])
    detail: str = Field("", examples=["no mesh has id '0123456789abcdef'"])
    instance: str = Field("", examples=["/v1/meshes/0123456789abcdef"])


class Problem(Exception):
    """An error response of the service.

    kind : a key of `PROBLEM_KINDS` (sets status, title and type).
    detail : what went wrong with this request and how to fix it.
    headers : extra response headers (``WWW-Authenticate``, ``Retry-After``).
    extensions : extra members of the body.
    """

    def __init__(
        self,
        kind: str,
        detail: str,
        *,
        headers: dict[str, str] | None = None,
        **extensions: Any,
    ) -> None:
        if kind not in PROBLEM_KINDS:
            raise KeyError(f"unknown problem kind {kind!r}")
        super().__init__(detail)
        self.kind = kind
        self.status, self.title = PROBLEM_KINDS[kind]
        self.detail = detail
        self.headers = headers or {}
        self.extensions = extensions


def problem_response(
    request: Request,
    *,
    status: int,
    title: str,
    detail: str,
    type_: str = "about:blank",
    headers: dict[str, str] | None = None,
    extensions: dict[str, Any] | None = None,
) -> JSONResponse:
    body = {
        "type": type_,
        "title": title,
        "status": status,
        "detail": detail,
        "instance": request.url.path,
        **(extensions or {}),
    }
    return JSONResponse(
        jsonable_encoder(body),
        status_code=status,
        headers=headers,
        media_type=PROBLEM_MEDIA_TYPE,
    )


def _kind_response(request: Request, kind: str, detail: str, **kwargs: Any) -> JSONResponse:
    status, title = PROBLEM_KINDS[kind]
    return problem_response(
        request, status=status, title=title, detail=detail, type_=f"/problems/{kind}", **kwargs
    )


async def _on_problem(request: Request, exc: Problem) -> JSONResponse:
    return _kind_response(
        request, exc.kind, exc.detail, headers=exc.headers, extensions=exc.extensions
    )


def qem_error_kind(exc: qem_core.QemError) -> str:
    """The problem kind of a qem_core exception."""
    for cls in type(exc).__mro__:
        if cls in QEM_ERRORS:
            return QEM_ERRORS[cls]
    return "invalid-request"


async def _on_qem_error(request: Request, exc: qem_core.QemError) -> JSONResponse:
    kind = qem_error_kind(exc)
    if PROBLEM_KINDS[kind][0] >= 500:
        log.error("%s on %s: %s", type(exc).__name__, request.url.path, exc)
    return _kind_response(request, kind, str(exc) or type(exc).__name__)


async def _on_validation_error(request: Request, exc: RequestValidationError) -> JSONResponse:
    errors = [
        {
            "loc": [str(part) for part in error.get("loc", ())],
            "msg": str(error.get("msg", "")),
            "type": str(error.get("type", "")),
        }
        for error in exc.errors()
    ]
    detail = "; ".join(f"{'.'.join(e['loc'][1:]) or e['loc'][0]}: {e['msg']}" for e in errors)
    return _kind_response(request, "invalid-request", detail, extensions={"errors": errors})


async def _on_http_exception(request: Request, exc: StarletteHTTPException) -> JSONResponse:
    status = exc.status_code
    title = HTTPStatus(status).phrase if status in HTTPStatus._value2member_map_ else "Error"
    detail = exc.detail if isinstance(exc.detail, str) else title
    if status == 404 and detail == title:
        detail = f"nothing at {request.url.path}; the API is under /v1 (see /docs)"
    headers = exc.headers
    if status == 405:
        # Starlette names the methods of the first route whose path matched; a path served
        # by several routes (GET and DELETE of a mesh) takes all of theirs.
        headers = {**(headers or {}), "Allow": ", ".join(_allowed_methods(request))}
    return problem_response(request, status=status, title=title, detail=detail, headers=headers)


def _allowed_methods(request: Request) -> list[str]:
    methods: set[str] = set()
    for route in request.app.routes:
        match, _ = route.matches({**request.scope, "method": "GET"})
        route_methods = getattr(route, "methods", None)
        if match != Match.NONE and route_methods:
            methods |= set(route_methods)
    if "GET" in methods and getattr(request.app.state, "head_as_get", False):
        methods.add("HEAD")  # answered as GET (head_requests.py)
    return sorted(methods)


async def _on_unavailable(request: Request, exc: StorageUnavailable) -> JSONResponse:
    log.warning("%s %s: %s", request.method, request.url.path, exc)
    return _kind_response(
        request, "not-ready", str(exc), headers={"Retry-After": str(RETRY_AFTER_S)},
        extensions={"part": exc.part},
    )  # fmt: skip


async def _on_unexpected(request: Request, exc: Exception) -> JSONResponse:
    log.error("unhandled error on %s %s", request.method, request.url.path, exc_info=exc)
    return _kind_response(
        request, "internal-error", "the server failed to handle this request; it was logged"
    )


def problem_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI ``responses`` entries documenting problem bodies for `statuses`."""
    return {
        status: {"model": ProblemDetails, "description": HTTPStatus(status).phrase}
        for status in statuses
    }


def install_problem_handlers(app: FastAPI) -> None:
    """Register the handlers and document error bodies as application/problem+json."""
    app.add_exception_handler(Problem, _on_problem)
    app.add_exception_handler(qem_core.QemError, _on_qem_error)
    app.add_exception_handler(RequestValidationError, _on_validation_error)
    app.add_exception_handler(StarletteHTTPException, _on_http_exception)
    app.add_exception_handler(StorageUnavailable, _on_unavailable)
    app.add_exception_handler(Exception, _on_unexpected)

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            schema = get_openapi(
                title=app.title,
                version=app.version,
                description=app.description,
                routes=app.routes,
            )
            _use_problem_media_type(schema)
            app.openapi_schema = schema
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def _use_problem_media_type(schema: dict[str, Any]) -> None:
    # FastAPI documents extra responses under the route's media type, and adds a 422 of its
    # own HTTPValidationError shape (``detail`` a list) to every route with parameters;
    # every error body is a ProblemDetails in application/problem+json (``detail`` a text).
    fastapi_422 = "#/components/schemas/HTTPValidationError"
    for path_item in schema.get("paths", {}).values():
        for operation in path_item.values():
            for status, response in operation.get("responses", {}).items():
                content = response.get("content", {})
                if str(status)[0] in "45" and "application/json" in content:
                    body = content.pop("application/json")
                    if body.get("schema", {}).get("$ref") == fastapi_422:
                        body["schema"] = {"$ref": "#/components/schemas/ProblemDetails"}
                    content[PROBLEM_MEDIA_TYPE] = body
    components = schema.setdefault("components", {}).setdefault("schemas", {})
    components.setdefault("ProblemDetails", ProblemDetails.model_json_schema())
    for unused in ("HTTPValidationError", "ValidationError"):
        components.pop(unused, None)

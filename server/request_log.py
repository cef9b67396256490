"""Request ids and JSON logs.

Every HTTP request gets an id: the client's ``X-Request-ID`` when it sends a sane one
(letters, digits, ``._-``, up to 64), else a new one; the response carries it back, and
every log line written while the request is handled carries it (``request_id``), the
access line included. ``QEM_LOG_FORMAT=json`` (``qem serve --log-format json``) writes
each line as one JSON object, for a log collector.
"""

from __future__ import annotations

import contextvars
import json
import logging
import re
import secrets
import time

__all__ = ["JsonFormatter", "RequestIds", "configure_logging", "current_request_id"]

_request_id: contextvars.ContextVar[str] = contextvars.ContextVar("request_id", default="-")
_GIVEN_ID = re.compile(rb"^[A-Za-z0-9._-]{1,64}$")
_TEXT_FORMAT = "%(levelname)s: %(name)s: %(message)s [%(request_id)s]"


def current_request_id() -> str:
    """The id of the request being handled ("-" outside a request)."""
    return _request_id.get()


class RequestIds:
    """ASGI middleware: sets the request's id for its log lines and answers it in
    ``X-Request-ID``."""

    def __init__(self, app) -> None:
        self.app = app

    async def __call__(self, scope, receive, send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        given = dict(scope["headers"]).get(b"x-request-id", b"")
        request_id = given.decode() if _GIVEN_ID.match(given) else secrets.token_hex(8)
        token = _request_id.set(request_id)

        async def sending(message) -> None:
            if message["type"] == "http.response.start":
                headers = [(k, v) for k, v in message.get("headers", []) if k != b"x-request-id"]
                message = {**message, "headers": [*headers, (b"x-request-id", request_id.encode())]}
            await send(message)

        try:
            await self.app(scope, receive, sending)
        finally:
            _request_id.reset(token)


class _WithRequestId(logging.Filter):
    def filter(self, record: logging.LogRecord) -> bool:
        record.request_id = _request_id.get()
        return True


class JsonFormatter(logging.Formatter):
    """One JSON object a line: time (UTC, ISO 8601), level, logger, message, request_id,
    and the traceback when there is one."""

    def format(self, record: logging.LogRecord) -> str:
        entry = {
            "time": time.strftime("%Y-%m-%dT%H:%M:%S", time.gmtime(record.created))
            + f".{int(record.msecs):03d}Z",
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
            "request_id": getattr(record, "request_id", "-"),
        }
        if record.exc_info:
            entry["exception"] = self.formatException(record.exc_info)
        return json.dumps(entry, ensure_ascii=False)


def configure_logging(level: str, format: str) -> None:
    """The process's log lines (qem's and uvicorn's alike) as ``format`` ("text" or
    "json"), each with its request id."""
    handler = logging.StreamHandler()
    handler.addFilter(_WithRequestId())
    handler.setFormatter(JsonFormatter() if format == "json" else logging.Formatter(_TEXT_FORMAT))
    root = logging.getLogger()
    root.handlers[:] = [handler]
    root.setLevel(level.upper())
    for name in ("uvicorn", "uvicorn.error", "uvicorn.access"):
        logger = logging.getLogger(name)
        logger.handlers[:] = []
        logger.propagate = True

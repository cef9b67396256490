"""HEAD requests, answered as GET without the body (RFC 9110, 9.3.2).

The API's routes take GET only, so a HEAD on them fell through to the viewer's static
mount at ``/`` and got its 404 ("nothing at ..."). Monitors and caches ask HEAD for the
status, the length and the ETag of what a GET would give; this middleware runs the GET
and sends its start (status and headers, Content-Length included) with an empty body.
A streamed answer (the splits) is dropped; the server stops producing it once the client,
which expects no body, is done.
"""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

__all__ = ["HeadAsGet"]


class HeadAsGet:
    """ASGI middleware: HEAD is run as GET, and only the response's start is sent."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "HEAD":
            await self.app(scope, receive, send)
            return
        body_sent = False

        async def send_without_body(message: Message) -> None:
            nonlocal body_sent
            if message["type"] != "http.response.body":
                await send(message)
            elif not body_sent:
                body_sent = True
                await send({"type": "http.response.body", "body": b"", "more_body": False})

        await self.app({**scope, "method": "GET"}, receive, send_without_body)

"""The yardstick of the serving benchmark: a bare ASGI app that answers every GET with
one file's bytes, held in memory, as a static file server or CDN would (no routing, no
lookup, no encoding). Run by uvicorn with the same options as ``qem serve``.

    python -m bench.bare_app FILE MEDIA_TYPE --port 0
"""

from __future__ import annotations

import argparse
from pathlib import Path

import uvicorn


def make_app(body: bytes, media_type: str):
    headers = [
        (b"content-type", media_type.encode()),
        (b"content-length", str(len(body)).encode()),
        (b"cache-control", b"public, max-age=31536000, immutable"),
        (b"etag", b'"bare"'),
    ]

    async def app(scope, receive, send):
        if scope["type"] != "http":
            return
        await send({"type": "http.response.start", "status": 200, "headers": headers})
        await send({"type": "http.response.body", "body": body})

    return app


def main() -> None:
    parser = argparse.ArgumentParser(prog="python -m bench.bare_app")
    parser.add_argument("file", type=Path)
    parser.add_argument("media_type")
    parser.add_argument("--port", type=int, default=0)
    parser.add_argument("--log-level", default="info")
    args = parser.parse_args()
    app = make_app(args.file.read_bytes(), args.media_type)
    uvicorn.run(app, host="127.0.0.1", port=args.port, log_level=args.log_level)


if __name__ == "__main__":
    main()

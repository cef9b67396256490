"""A Python client of the qem-lod HTTP API (httpx).

    from client.http import QemClient

    with QemClient("http://127.0.0.1:8000", token=None) as qem:
        mesh_id = qem.upload("bunny.ply")
        qem.wait_ready(mesh_id, timeout=600)
        ply = qem.lod(mesh_id, 5000, "ply")
        level = qem.refine(mesh_id, 20000, n_from=5000)  # exactly lod(20000), grid integers

Errors:

    QemClientError
    ├── QemConnectionError   the server cannot be reached (bad URL, down, timeout)
    ├── QemHTTPError         the server answered with an error (problem details attached)
    └── QemBuildFailed       the mesh's build failed (its reason attached)
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any
from urllib.parse import quote

import httpx

__all__ = [
    "DEFAULT_SERVER",
    "LodResponse",
    "QemBuildFailed",
    "QemClient",
    "QemClientError",
    "QemConnectionError",
    "QemHTTPError",
    "QemTimeoutError",
]

DEFAULT_SERVER = "http://127.0.0.1:8000"
# The members of a mesh's metadata that this client and the qem command read.
_INFO_KEYS = ("id", "name", "status", "progress", "vertices", "faces", "min_vertices")
_CHUNK = 1 << 20


class QemClientError(Exception):
    """Base class of the errors this client raises."""


class QemConnectionError(QemClientError):
    """The server could not be reached or did not answer in time."""


class QemTimeoutError(QemConnectionError):
    """The server did not answer in time."""


class QemHTTPError(QemClientError):
    """The server answered with an error status.

    status : HTTP status; problem : the RFC 9457 body as a dict (``type``, ``title``,
    ``detail``...), or a minimal one built from the status when the body is not JSON.
    """

    def __init__(self, status: int, problem: dict[str, Any]) -> None:
        self.status = status
        self.problem = problem
        self.type = str(problem.get("type", "about:blank"))
        self.title = str(problem.get("title", ""))
        self.detail = str(problem.get("detail", ""))
        super().__init__(
            f"{status} {self.title}: {self.detail}" if self.detail else f"{status} {self.title}"
        )


class QemBuildFailed(QemClientError):
    """The server could not build the mesh. info : its metadata; reason : why."""

    def __init__(self, info: dict[str, Any]) -> None:
        self.info = info
        self.reason = info.get("error") or "unknown reason"
        super().__init__(f"mesh {info.get('id')} ({info.get('name')}) failed: {self.reason}")


@dataclass(frozen=True)
class LodResponse:
    """A level as served: the encoded mesh and what the server says about it."""

    content: bytes
    media_type: str
    n_vertices: int
    n_faces: int
    error: float | None
    etag: str | None


class QemClient:
    """Client of one qem-lod server.

    base_url : e.g. ``http://127.0.0.1:8000``; token : bearer token for writes (upload,
    delete) when the server requires one; timeout : seconds per request (connect, read).
    Raises QemClientError when `base_url` is not an http(s) URL with a host.
    """

    def __init__(
        self,
        base_url: str = DEFAULT_SERVER,
        token: str | None = None,
        *,
        timeout: float = 60.0,
        transport: httpx.BaseTransport | None = None,
    ) -> None:
        if token and not (token.isascii() and token.isprintable()):
            # It goes in a header: httpx would raise UnicodeEncodeError or a protocol error.
            raise QemClientError("the token must be printable ASCII (it is sent as a header)")
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self.base_url = _check_base_url(base_url)
        self._http = httpx.Client(
            base_url=self.base_url, headers=headers, timeout=timeout, transport=transport
        )

    @classmethod
    def from_env(cls, base_url: str | None = None, **kwargs: Any) -> QemClient:
        """A client for ``base_url`` or $QEM_SERVER, with the token from $QEM_TOKEN."""
        return cls(
            base_url or os.environ.get("QEM_SERVER") or DEFAULT_SERVER,
            token=os.environ.get("QEM_TOKEN") or None,
            **kwargs,
        )

    def close(self) -> None:
        self._http.close()

    def __enter__(self) -> QemClient:
        return self

    def __exit__(self, *exc_info: object) -> None:
        self.close()

    # -- requests ---------------------------------------------------------------------

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        try:
            response = self._http.request(method, path, **kwargs)
        except httpx.TransportError as exc:
            raise self._transport_error(exc) from exc
        _raise_for_problem(response)
        return response

    def _transport_error(self, exc: httpx.TransportError) -> QemConnectionError:
        if isinstance(exc, httpx.TimeoutException):
            return QemTimeoutError(f"{self.base_url} did not answer in time ({type(exc).__name__})")
        if isinstance(exc, httpx.RemoteProtocolError):
            return QemConnectionError(
                f"the connection to {self.base_url} broke off ({exc or type(exc).__name__})"
            )
        return QemConnectionError(
            f"cannot reach the qem-lod server at {self.base_url} ({exc or type(exc).__name__})"
        )

    def _json(self, response: httpx.Response, *keys: str) -> Any:
        """The JSON body of a qem-lod answer, checked to be a map with ``keys``."""
        try:
            body = response.json()
        except ValueError:
            body = None
        if not isinstance(body, dict) or any(key not in body for key in keys):
            raise QemClientError(
                f"{response.request.method} {response.request.url.path} got an answer that is "
                f"not qem-lod's ({response.status_code}, "
                f"{response.headers.get('content-type', 'no content type')}); is "
                f"{self.base_url} a qem-lod server?"
            )
        return body

    def health(self) -> dict[str, Any]:
        return self._json(self._request("GET", "/healthz"))

    def upload(
        self,
        path: str | os.PathLike[str],
        *,
        name: str | None = None,
        options: dict[str, Any] | None = None,
        progress: Callable[[int, int], None] | None = None,
    ) -> str:
        """Upload a mesh file (streamed, never read whole); returns the new mesh id.

        name : file name to record (default: the file's); its extension gives the format.
        options : build options (``{"weighting": "volume"}``), see the server's API docs.
        progress : called as ``progress(bytes_sent, total_bytes)``.
        """
        path = Path(path)
        total = path.stat().st_size

        def body() -> Iterator[bytes]:
            sent = 0
            if progress is not None:
                progress(0, total)
            with open(path, "rb") as handle:
                while chunk := handle.read(_CHUNK):
                    sent += len(chunk)
                    yield chunk
                    if progress is not None:
                        progress(sent, total)

        # A name from a file system that is not UTF-8 holds lone surrogates, which no
        # query can carry: they go as "?".
        name = (name or path.name).encode("utf-8", "replace").decode("utf-8")
        params: dict[str, Any] = {"name": name}
        for key, value in (options or {}).items():
            params[key] = str(value).lower() if isinstance(value, bool) else value
        response = self._request(
            "POST",
            "/v1/meshes",
            params=params,
            content=body(),
            headers={"Content-Type": "application/octet-stream", "Content-Length": str(total)},
        )
        return self._json(response, "id")["id"]

    def list(self) -> list[dict[str, Any]]:
        """Metadata of every mesh on the server, oldest first."""
        meshes = self._json(self._request("GET", "/v1/meshes"), "meshes")["meshes"]
        if not isinstance(meshes, list) or not all(
            isinstance(mesh, dict) and all(key in mesh for key in _INFO_KEYS) for mesh in meshes
        ):
            raise QemClientError(f"{self.base_url} listed its meshes in an unknown form")
        return meshes

    def info(self, mesh_id: str) -> dict[str, Any]:
        """Metadata of one mesh (``status``, ``progress``, ``vertices``...)."""
        return self._json(self._request("GET", _mesh_path(mesh_id)), *_INFO_KEYS)

    def wait_ready(
        self,
        mesh_id: str,
        *,
        progress: Callable[[dict[str, Any]], None] | None = None,
        timeout: float | None = None,
        interval: float = 0.25,
    ) -> dict[str, Any]:
        """Poll until the mesh is ready; returns its metadata.

        progress : called with the metadata after each poll (``info["progress"]`` is 0..1).
        Raises QemBuildFailed if the build fails, TimeoutError after `timeout` seconds.
        """
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            info = self.info(mesh_id)
            if progress is not None:
                progress(info)
            if info["status"] == "ready":
                return info
            if info["status"] == "failed":
                raise QemBuildFailed(info)
            if deadline is not None and time.monotonic() >= deadline:
                raise TimeoutError(
                    f"mesh {mesh_id} is still {info['status']} "
                    f"({info['progress']:.0%}) after {timeout} s"
                )
            time.sleep(interval)

    def fetch_lod(
        self,
        mesh_id: str,
        n: int | None = None,
        format: str = "ply",
        *,
        etag: str | None = None,
    ) -> LodResponse | None:
        """The mesh at `n` vertices (clamped by the server; None: the full mesh).

        With `etag`, returns None if the level is unchanged (304)."""
        params: dict[str, Any] = {"format": format}
        if n is not None:
            params["vertices"] = n
        headers = {"If-None-Match": etag} if etag else {}
        response = self._request("GET", _mesh_path(mesh_id, "/lod"), params=params, headers=headers)
        if response.status_code == 304:
            return None
        try:
            n_vertices = int(response.headers["X-Lod-Vertices"])
            n_faces = int(response.headers["X-Lod-Faces"])
            error = response.headers.get("X-Lod-Error")
            error = float(error) if error is not None else None
        except (KeyError, ValueError):
            raise QemClientError(
                f"{self.base_url} sent a level without valid X-Lod-Vertices, X-Lod-Faces and "
                "X-Lod-Error headers; is it a qem-lod server?"
            ) from None
        return LodResponse(
            content=response.content,
            media_type=response.headers.get("Content-Type", ""),
            n_vertices=n_vertices,
            n_faces=n_faces,
            error=error,
            etag=response.headers.get("ETag"),
        )

    def lod(self, mesh_id: str, n: int | None = None, format: str = "ply") -> bytes:
        """The mesh at `n` vertices, encoded as `format` (ply, obj, glb, msgpack)."""
        lod = self.fetch_lod(mesh_id, n, format)
        assert lod is not None
        return lod.content

    def texture(self, mesh_id: str) -> tuple[str, bytes]:
        """The mesh's texture image as (media type, bytes); QemHTTPError (404,
        ``texture-not-found``) when the mesh was uploaded without one."""
        response = self._request("GET", _mesh_path(mesh_id, "/texture"))
        return response.headers["content-type"], response.content

    def splits(self, mesh_id: str, n1: int | None = None, n2: int | None = None) -> Iterator[bytes]:
        """The stored vertex-split frames covering level `n1` to `n2` (None: base and
        full), as they arrive: one frame payload (bytes) at a time, as
        `qem_core.stream.SplitStreamDecoder.feed` takes them. The run starts at the frame
        boundary at or below `n1` and ends at the one at or above `n2` (the server's
        X-Splits-From and X-Splits-To); `refine` handles that for you."""
        with self._split_frames(mesh_id, n1, n2) as (_, _, frames):
            yield from frames

    def refine(
        self,
        mesh_id: str,
        n_to: int | None = None,
        *,
        start=None,
        n_from: int | None = None,
    ):
        """Exactly lod(`n_to`) (None: the full mesh; clamped by the server) as a
        `qem_core.stream.SplitStreamDecoder` (grid integers, faces, wedges), refined by the
        stored split frames from `start` (a decoder holding a level, advanced in place and
        returned) or from `n_from`. When the frames start below the level held (it lies
        inside a frame) or nothing is held, the run's first level is fetched as msgpack."""
        from qem_core.stream import SplitStreamDecoder

        held = start.n_vertices if start is not None else n_from
        with self._split_frames(mesh_id, held, n_to) as (served_from, served_to, frames):
            decoder = start
            if decoder is None or decoder.n_vertices != served_from:
                level = self.lod(mesh_id, served_from, "msgpack")
                decoder = SplitStreamDecoder.from_msgpack(level)
            target = served_to if n_to is None else max(served_from, min(n_to, served_to))
            for payload in frames:
                decoder.feed(payload, stop=target)
        return decoder

    @contextmanager
    def _split_frames(self, mesh_id: str, n1: int | None, n2: int | None):
        """(X-Splits-From, X-Splits-To, iterator of frame payloads) of a /splits request,
        its errors turned into this client's."""
        from qem_core import CorruptFileError
        from qem_core.stream import iter_frames  # numpy-heavy: only when streaming

        params = {key: value for key, value in (("from", n1), ("to", n2)) if value is not None}
        try:
            with self._http.stream(
                "GET", _mesh_path(mesh_id, "/splits"), params=params
            ) as response:
                if response.is_error or response.status_code in _REDIRECTS:
                    response.read()
                    _raise_for_problem(response)
                try:
                    served = (
                        int(response.headers["X-Splits-From"]),
                        int(response.headers["X-Splits-To"]),
                    )
                except (KeyError, ValueError):
                    raise QemClientError(
                        f"{self.base_url} sent splits without valid X-Splits-From and "
                        "X-Splits-To headers; is it a qem-lod server?"
                    ) from None
                yield (*served, iter_frames(response.iter_bytes()))
        except httpx.TransportError as exc:
            raise self._transport_error(exc) from exc
        except CorruptFileError as exc:
            raise QemClientError(f"the split stream of mesh {mesh_id} is damaged: {exc}") from exc

    def delete(self, mesh_id: str) -> None:
        """Remove a mesh and its data from the server."""
        response = self._request("DELETE", _mesh_path(mesh_id))
        if response.status_code != 204:
            raise QemClientError(
                f"{self.base_url} answered a delete with {response.status_code}, not qem-lod's "
                "204; is it a qem-lod server?"
            )


def _mesh_path(mesh_id: str, rest: str = "") -> str:
    """The path of a mesh's resource, its id escaped: an id is one path segment, so
    "a/../b" or "a?x" cannot name another resource (nor can "", "." or "..", which a URL
    resolves away)."""
    if str(mesh_id) in ("", ".", ".."):
        raise QemClientError(f"{mesh_id!r} is not a mesh id")
    return f"/v1/meshes/{quote(str(mesh_id), safe='')}{rest}"


def _check_base_url(base_url: str) -> str:
    """`base_url` without its trailing slash; raises QemClientError unless it is an
    http(s) URL with a host (httpx would raise InvalidURL, or treat ``host:port`` as a
    scheme)."""
    try:
        url = httpx.URL(base_url)
    except (httpx.InvalidURL, TypeError) as exc:
        raise QemClientError(f"{base_url!r} is not a valid server URL ({exc})") from None
    if url.scheme not in ("http", "https") or not url.host:
        raise QemClientError(
            f"{base_url!r} is not a valid server URL; give one like {DEFAULT_SERVER}"
        )
    return str(base_url).rstrip("/")


# Redirects (304 Not Modified is an answer, not one).
_REDIRECTS = (301, 302, 303, 307, 308)


def _raise_for_problem(response: httpx.Response) -> None:
    if response.status_code in _REDIRECTS:
        # Not followed: a proxy's http -> https redirect would turn an upload into a GET.
        location = response.headers.get("location", "?")
        raise QemClientError(
            f"the server redirected {response.request.url.path} ({response.status_code}) to "
            f"{location}; give --server the URL it redirects to"
        )
    if not response.is_error:
        return
    try:
        problem = response.json()
        if not isinstance(problem, dict):
            raise ValueError
    except ValueError:
        problem = {
            "type": "about:blank",
            "title": response.reason_phrase,
            "status": response.status_code,
            "detail": response.text[:500],
        }
    raise QemHTTPError(response.status_code, problem)

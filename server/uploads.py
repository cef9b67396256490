"""Receiving uploads: the request body streamed into a blob, never whole in memory.

Two shapes of request are accepted:

- ``multipart/form-data`` with the file in the field ``file`` (its file name is kept);
- any other content type: the raw file as the body, its name in ``?name=``.

The body is written to a `BlobWriter` in chunks, counted against the size cap (413 as
soon as it is exceeded, before reading the rest), and committed only when complete; any
failure aborts the writer, so a partial upload leaves nothing behind. Parsing the mesh is
the build worker's job, not the request's.
"""

from __future__ import annotations

import logging
import re
import unicodedata
from pathlib import Path, PurePosixPath
from typing import Any
from urllib.parse import unquote

from python_multipart.exceptions import FormParserError
from python_multipart.multipart import MultipartParser, parse_options_header
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect, Request

from .jobs import JobQueue
from .problems import Problem
from .schemas import FILE_NAME_PATTERN, UPLOAD_EXTENSIONS
from .storage import BlobWriter, MeshRecord, Storage, new_mesh_id, upload_key

__all__ = [
    "check_file_name",
    "import_file",
    "receive_upload",
    "register_upload",
]

log = logging.getLogger("qem.server")

_FIELD = "file"
_BUFFER = 1 << 20  # write to storage in pieces of about this size
_MULTIPART_OVERHEAD = 64 * 1024  # envelope allowed on top of the file in Content-Length
_MAX_OTHER_FIELDS = 64 * 1024  # bytes of non-file multipart fields we are willing to skip
# RFC 5987 extended value: charset'language'percent-encoded bytes.
_EXTENDED_FILENAME = re.compile(
    rb"""filename\*\s*=\s*(utf-8|iso-8859-1)'[^']*'([^;\s]+)""", re.IGNORECASE
)


def _is_shown(character: str) -> bool:
    """False for control and format characters (C0, C1, the bidirectional overrides that
    make 'gpj.ply' read as 'ylp.jpg', zero-width joiners) and for unassigned ones."""
    return not unicodedata.category(character).startswith("C")


def check_file_name(name: str | None, *, strict: bool = True) -> str | None:
    """The base name of an uploaded file's name, cleaned for display and storage in the
    record (None when nothing is left of it).

    strict (``?name=``, which the OpenAPI document constrains): a 415 problem unless the
    name ends in a readable format's extension or has no dot after its last slash (the
    worker then guesses from the content): `schemas.FILE_NAME_PATTERN`. A multipart file
    name, which the document cannot constrain, is kept whatever it ends in, and the build
    goes by the content when its extension is not a mesh format's."""
    if name is None:
        return None
    if strict and not re.fullmatch(FILE_NAME_PATTERN, name):
        raise Problem(
            "unsupported-format",
            f"cannot read {name!r}: the name must end in "
            f"{', '.join('.' + e for e in UPLOAD_EXTENSIONS)} (any case), or have no "
            "extension for the format to be guessed from the content",
        )
    base = PurePosixPath(name.replace("\\", "/")).name
    base = "".join(filter(_is_shown, base)).strip()[:255]
    if base in ("", ".", ".."):
        return None
    return base


def _too_large(max_bytes: int) -> Problem:
    return Problem(
        "upload-too-large",
        f"the file is larger than this server's limit of {max_bytes} bytes "
        f"({max_bytes / 2**20:.3g} MiB); simplify it offline or raise QEM_MAX_UPLOAD_BYTES",
        max_bytes=max_bytes,
    )


class _Sink:
    """Buffers body bytes and counts them against the cap; flushed in a thread."""

    def __init__(self, writer: BlobWriter, max_bytes: int) -> None:
        self.writer = writer
        self.max_bytes = max_bytes
        self.size = 0
        self.pending: list[bytes] = []
        self.pending_size = 0

    def add(self, data: bytes) -> None:
        self.size += len(data)
        if self.size > self.max_bytes:
            raise _too_large(self.max_bytes)
        self.pending.append(data)
        self.pending_size += len(data)

    async def flush(self, force: bool = False) -> None:
        if self.pending and (force or self.pending_size >= _BUFFER):
            data = b"".join(self.pending)
            self.pending.clear()
            self.pending_size = 0
            await run_in_threadpool(self.writer.write, data)


async def receive_upload(request: Request, writer: BlobWriter, max_bytes: int) -> str | None:
    """Stream the body of `request` into `writer` (not committed here).

    Returns the file name a multipart upload gave, or None for a raw body. Raises
    `Problem` (400 bad-upload, 413 upload-too-large)."""
    content_type = request.headers.get("content-type", "")
    is_multipart = content_type.lower().startswith("multipart/form-data")
    declared = request.headers.get("content-length")
    # isascii: str.isdigit() also accepts digits int() refuses, such as '²' (a latin-1 byte).
    if declared is not None and declared.isascii() and declared.isdigit():
        allowance = _MULTIPART_OVERHEAD if is_multipart else 0
        if int(declared) > max_bytes + allowance:
            raise _too_large(max_bytes)
    sink = _Sink(writer, max_bytes)
    try:
        if is_multipart:
            filename = await _receive_multipart(request, content_type, sink)
        else:
            async for chunk in request.stream():
                sink.add(chunk)
                await sink.flush()
            filename = None
        await sink.flush(force=True)
    except ClientDisconnect:
        raise Problem(
            "bad-upload", "the client disconnected before the upload was complete"
        ) from None
    if sink.size == 0:
        raise Problem("bad-upload", "the uploaded file is empty")
    return filename


class _MultipartState:
    def __init__(self, sink: _Sink) -> None:
        self.sink = sink
        self.header_name = b""
        self.header_value = b""
        self.disposition = b""
        self.in_file = False
        self.found = False
        self.filename: str | None = None
        self.other_bytes = 0
        self.ended = False  # the closing boundary was read

    def callbacks(self) -> dict[str, Any]:
        return {
            "on_part_begin": self.on_part_begin,
            "on_part_data": self.on_part_data,
            "on_header_field": self.on_header_field,
            "on_header_value": self.on_header_value,
            "on_header_end": self.on_header_end,
            "on_headers_finished": self.on_headers_finished,
            "on_end": self.on_end,
        }

    def on_end(self) -> None:
        self.ended = True

    def on_part_begin(self) -> None:
        self.disposition = b""
        self.in_file = False

    def on_header_field(self, data: bytes, start: int, end: int) -> None:
        self.header_name += data[start:end]

    def on_header_value(self, data: bytes, start: int, end: int) -> None:
        self.header_value += data[start:end]

    def on_header_end(self) -> None:
        if self.header_name.lower() == b"content-disposition":
            self.disposition = self.header_value
        self.header_name = b""
        self.header_value = b""

    def on_headers_finished(self) -> None:
        _, options = parse_options_header(self.disposition)
        name = options.get(b"name", b"").decode("utf-8", "replace")
        if name == _FIELD and self.found:
            # Which of two files to keep would be a guess: the second was dropped unseen.
            raise Problem(
                "bad-upload", f"the multipart body has more than one field {_FIELD!r}; "
                "upload one mesh per request"
            )
        if name == _FIELD:
            self.found = True
            self.in_file = True
            raw = options.get(b"filename")
            self.filename = (
                raw.decode("utf-8", "replace")
                if raw is not None
                else _extended_filename(self.disposition)
            )

    def on_part_data(self, data: bytes, start: int, end: int) -> None:
        if self.in_file:
            self.sink.add(bytes(data[start:end]))
        else:
            self.other_bytes += end - start
            if self.other_bytes > _MAX_OTHER_FIELDS:
                raise Problem(
                    "bad-upload",
                    f"the multipart body carries more than {_MAX_OTHER_FIELDS} bytes "
                    f"besides the field {_FIELD!r}; send only the file",
                )


def _extended_filename(disposition: bytes) -> str | None:
    """The RFC 5987 ``filename*=UTF-8''...`` of a part, which some clients send instead
    of ``filename`` for a name outside ASCII (the multipart parser ignores it)."""
    found = _EXTENDED_FILENAME.search(disposition)
    if found is None:
        return None
    charset, encoded = found.group(1).decode("ascii"), found.group(2).decode("ascii", "replace")
    return unquote(encoded, encoding=charset, errors="replace")


async def _receive_multipart(request: Request, content_type: str, sink: _Sink) -> str | None:
    _, params = parse_options_header(content_type)
    boundary = params.get(b"boundary")
    if not boundary:
        raise Problem("bad-upload", "multipart/form-data without a boundary parameter")
    state = _MultipartState(sink)
    try:
        # Inside the try: the parser refuses a boundary longer than 256 bytes on creation.
        parser = MultipartParser(boundary, state.callbacks())
        async for chunk in request.stream():
            parser.write(chunk)
            await sink.flush()
        parser.finalize()
    except FormParserError as exc:
        raise Problem("bad-upload", f"the multipart body is malformed ({exc})") from None
    if not state.ended:
        # The parser's finalize does not check this: a cut-off body would be built as
        # if the part of the file that arrived were all of it.
        raise Problem(
            "bad-upload",
            "the multipart body ends before its closing boundary: the upload was cut short",
        )
    if not state.found:
        raise Problem(
            "bad-upload",
            f"the multipart body has no field named {_FIELD!r}; send the mesh as "
            f"-F {_FIELD}=@mesh.ply, or as the raw body with ?name=mesh.ply",
        )
    return state.filename


def register_upload(
    storage: Storage,
    jobs: JobQueue,
    *,
    mesh_id: str,
    name: str,
    size: int,
    options: dict[str, Any],
) -> MeshRecord:
    """Record a stored upload as a queued mesh and submit its build. If the record cannot
    be written, the upload blob is removed."""
    record = MeshRecord(
        id=mesh_id,
        name=name,
        upload_key=upload_key(mesh_id),
        upload_bytes=size,
        options=options,
    )
    try:
        storage.metadata.create(record)
    except BaseException:
        storage.blobs.delete(record.upload_key)
        raise
    try:
        jobs.submit(mesh_id)
    except Exception:
        # The record is queued and durable: the next start recovers it.
        log.exception("could not submit the build of mesh %s; it stays queued", mesh_id)
    return record


def import_file(
    storage: Storage, jobs: JobQueue, path: str | Path, options: dict[str, Any] | None = None
) -> MeshRecord:
    """Store a local mesh file as an upload and queue its build (the demo mesh)."""
    path = Path(path)
    name = check_file_name(path.name) or path.name
    mesh_id = new_mesh_id()
    with storage.blobs.writer(upload_key(mesh_id)) as writer, open(path, "rb") as source:
        while chunk := source.read(_BUFFER):
            writer.write(chunk)
    return register_upload(
        storage, jobs, mesh_id=mesh_id, name=name, size=writer.size, options=options or {}
    )

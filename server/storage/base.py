"""The storage interface: mesh records (metadata) and blobs (uploads, .qpm files).

Every path of the service that stores data goes through these two classes, so that the
embedded pair (SQLite + a local folder) can be swapped for PostgreSQL + an S3-compatible
object store by configuration.

The record is the truth about a build: status, progress, attempts, error. A build attempt
*claims* a queued record with a random token; its later writes are fenced by that token,
so a worker orphaned by a crash can never overwrite the state of the attempt that replaced
it.

    queued --claim--> building --finish--> ready
       ^                 |  \\
       +----requeue------+   +--fail--> failed
"""

from __future__ import annotations

import abc
import re
import secrets
import time
from collections.abc import Iterator
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, BinaryIO, Literal

__all__ = [
    "BlobStore",
    "BlobWriter",
    "MeshRecord",
    "MeshStatus",
    "MetadataStore",
    "StorageUnavailable",
    "UNFINISHED",
    "new_mesh_id",
    "new_token",
    "check_blob_key",
]

class StorageUnavailable(Exception):
    """The database or the blob store does not answer (down, locked, out of space): the
    request may succeed later (a 503 with Retry-After), and nothing was half-written.

    part : "database" or "blob store"."""

    def __init__(self, part: str, error: BaseException) -> None:
        # The first paragraph: some clients append pages of debugging detail.
        said = str(error).split("\n\n")[0]
        super().__init__(f"the {part} does not answer: {type(error).__name__}: {said}")
        self.part = part


MeshStatus = Literal["queued", "building", "ready", "failed"]
UNFINISHED: tuple[MeshStatus, ...] = ("queued", "building")

_BLOB_KEY = re.compile(r"^[A-Za-z0-9_-][A-Za-z0-9_.-]*(/[A-Za-z0-9_-][A-Za-z0-9_.-]*)*$")


def new_mesh_id() -> str:
    """A fresh mesh id: 16 lowercase hex characters."""
    return secrets.token_hex(8)


def new_token() -> str:
    """A fresh claim token for one build attempt."""
    return secrets.token_hex(8)


def check_blob_key(key: str) -> str:
    """Refuse keys that could escape the store (``..``, absolute paths, odd characters)."""
    if not _BLOB_KEY.match(key) or len(key) > 512:
        raise ValueError(f"invalid blob key {key!r}")
    return key


@dataclass(frozen=True)
class MeshRecord:
    """One uploaded mesh and the state of its build.

    upload_key : blob holding the file as uploaded (kept until the mesh is deleted).
    qpm_key : blob holding the built progressive mesh, once ready.
    options : build options as a plain dict (`qem_core.BuildOptions.from_mapping`).
    attempts : build attempts started so far (claims).
    claim : token of the build attempt that owns the record while building.
    n_vertices, n_faces : the full mesh; n_base : vertices of the base mesh.
    bbox : ((xmin, ymin, zmin), (xmax, ymax, zmax)).
    """

    id: str
    name: str
    upload_key: str
    upload_bytes: int
    status: MeshStatus = "queued"
    progress: float = 0.0
    options: dict[str, Any] = field(default_factory=dict)
    attempts: int = 0
    claim: str | None = None
    qpm_key: str | None = None
    n_vertices: int | None = None
    n_faces: int | None = None
    n_base: int | None = None
    bbox: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
    error: str | None = None
    created_at: float = field(default_factory=time.time)
    updated_at: float = field(default_factory=time.time)


class MetadataStore(abc.ABC):
    """Mesh records. Implementations are safe to use from several threads and processes."""

    @abc.abstractmethod
    def create(self, record: MeshRecord) -> None:
        """Insert a new record; its id must be new."""

    @abc.abstractmethod
    def get(self, mesh_id: str) -> MeshRecord | None:
        """The record, or None if there is none with this id."""

    @abc.abstractmethod
    def records(self) -> list[MeshRecord]:
        """All records, oldest first."""

    @abc.abstractmethod
    def ping(self) -> None:
        """Raise (OSError, the driver's error) unless the database answers a query."""

    @abc.abstractmethod
    def status_counts(self) -> dict[str, int]:
        """How many meshes are in each status (queued, building, ready, failed)."""

    @abc.abstractmethod
    def count(self) -> int:
        """Number of records."""

    @abc.abstractmethod
    def delete(self, mesh_id: str) -> MeshRecord | None:
        """Remove the record; returns it, or None if it did not exist."""

    @abc.abstractmethod
    def unfinished(self) -> list[MeshRecord]:
        """Records whose status is queued or building, oldest first."""

    @abc.abstractmethod
    def claim(self, mesh_id: str, token: str) -> MeshRecord | None:
        """Start a build attempt: queued -> building, attempts + 1, progress 0, owner
        `token`. Returns the updated record, or None if the record is not queued."""

    @abc.abstractmethod
    def set_progress(self, mesh_id: str, token: str, progress: float) -> bool:
        """Record build progress in [0, 1]; False if `token` no longer owns the record."""

    @abc.abstractmethod
    def finish(
        self,
        mesh_id: str,
        token: str,
        *,
        qpm_key: str,
        n_vertices: int,
        n_faces: int,
        n_base: int,
        bbox: tuple[tuple[float, float, float], tuple[float, float, float]],
    ) -> bool:
        """building -> ready; False if `token` no longer owns the record."""

    @abc.abstractmethod
    def fail(self, mesh_id: str, reason: str, *, token: str | None = None) -> bool:
        """-> failed with a readable reason. With `token`, only if it owns the record;
        without, only if the record is unfinished. False if nothing changed."""

    @abc.abstractmethod
    def lose(self, mesh_id: str, qpm_key: str, reason: str) -> bool:
        """ready -> failed with `reason`, if the record is still ready with this .qpm
        (its build's blob was lost from the store). False if nothing changed."""

    @abc.abstractmethod
    def requeue(self, mesh_id: str, *, token: str | None = None) -> bool:
        """An unfinished record -> queued with no owner (attempts kept); False if the
        record is missing or finished. With `token`, only if that attempt owns it."""

    @abc.abstractmethod
    def release(self, mesh_id: str) -> bool:
        """Hand a building record back to the queue without counting its attempt (the
        server stopped it on purpose: the build did nothing wrong). False if the record
        is not building."""

    def watch_deletes(self, on_delete) -> Any:
        """Call ``on_delete(mesh_id)`` whenever a record is deleted by another process
        (another replica on the same database), and ``on_delete(None)`` when deletes may
        have been missed (the watch reconnected); returns a function that stops the
        watch. Default: no other process serves this store (the embedded deployment),
        so there is nothing to hear."""
        return lambda: None

    def close(self) -> None:  # noqa: B027 - optional hook
        """Release connections."""


class BlobWriter(abc.ABC):
    """A blob being written. Nothing is visible under its key until `commit`."""

    size: int = 0

    @abc.abstractmethod
    def write(self, chunk: bytes) -> None: ...

    @abc.abstractmethod
    def commit(self) -> None:
        """Make the blob visible, atomically."""

    @abc.abstractmethod
    def abort(self) -> None:
        """Drop what was written; safe to call twice or after commit (no-op)."""

    def __enter__(self) -> BlobWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None:
            self.commit()
        else:
            self.abort()


class BlobStore(abc.ABC):
    """Opaque byte blobs under slash-separated keys (``uploads/<id>``)."""

    @abc.abstractmethod
    def ping(self) -> None:
        """Raise (OSError, the client's error) unless the store can be written."""

    @abc.abstractmethod
    def writer(self, key: str) -> BlobWriter:
        """A writer whose data appears under `key` only when committed."""

    @abc.abstractmethod
    def staged_path(self, key: str) -> AbstractContextManager[Path]:
        """A local path to write the blob to (for writers that want a file name, such as
        `ProgressiveMesh.save`); stored under `key` when the block exits cleanly, dropped
        otherwise."""

    @abc.abstractmethod
    def local_path(self, key: str) -> AbstractContextManager[Path]:
        """A local file holding the blob, for readers that want a path.

        Raises FileNotFoundError if there is no such blob."""

    @abc.abstractmethod
    def open(self, key: str) -> BinaryIO:
        """The blob opened for binary reading. Raises FileNotFoundError."""

    @abc.abstractmethod
    def exists(self, key: str) -> bool: ...

    @abc.abstractmethod
    def delete(self, key: str) -> bool:
        """Remove the blob; False if it did not exist."""

    @abc.abstractmethod
    def keys(self, prefix: str = "") -> Iterator[str]:
        """Keys of committed blobs starting with `prefix`."""

    @abc.abstractmethod
    def modified(self, key: str) -> float:
        """When the blob was last written (seconds since the epoch). Raises
        FileNotFoundError."""

    @abc.abstractmethod
    def sweep(self) -> int:
        """Remove leftovers of writes that never committed (after a crash); returns how
        many. Call only when no write is in flight, i.e. on start."""

"""Storage: mesh records plus blobs, behind the interfaces of `server.storage.base`.

`open_storage(settings)` builds the pair named by ``metadata_backend`` and
``blob_backend``. Blob keys:

    uploads/<id>              the file as uploaded
    meshes/<id>/<token>.qpm   the progressive mesh built by attempt <token>
    meshes/<id>/<token>.splits       its split stream, base to full, every frame a key
                                     frame (qem_core.stored_stream), written by the build
    meshes/<id>/<token>.splits.json  the index of that stream's frames; written after the
                                     stream, so a stream without an index is unfinished
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass

from ..settings import BLOB_BACKENDS, METADATA_BACKENDS, Settings, load_backend
from .base import (
    UNFINISHED,
    BlobStore,
    BlobWriter,
    MeshRecord,
    MeshStatus,
    MetadataStore,
    StorageUnavailable,
    new_mesh_id,
    new_token,
)

__all__ = [
    "UNFINISHED",
    "BlobStore",
    "BlobWriter",
    "MeshRecord",
    "MeshStatus",
    "MetadataStore",
    "Storage",
    "StorageUnavailable",
    "new_mesh_id",
    "new_token",
    "mesh_prefix",
    "open_storage",
    "qpm_key",
    "stream_index_key",
    "stream_key",
    "upload_key",
]

log = logging.getLogger("qem.storage")


def upload_key(mesh_id: str) -> str:
    return f"uploads/{mesh_id}"


def mesh_prefix(mesh_id: str) -> str:
    """Every blob of a mesh's builds starts so."""
    return f"meshes/{mesh_id}/"


def qpm_key(mesh_id: str, token: str) -> str:
    return f"{mesh_prefix(mesh_id)}{token}.qpm"


def stream_key(qpm: str) -> str:
    """The stored split stream of the build whose .qpm is ``qpm``."""
    return qpm.removesuffix(".qpm") + ".splits"


def stream_index_key(qpm: str) -> str:
    """The frame index of that stream."""
    return stream_key(qpm) + ".json"


@dataclass
class Storage:
    """The metadata store and the blob store of one deployment."""

    metadata: MetadataStore
    blobs: BlobStore

    def delete_mesh(self, mesh_id: str) -> MeshRecord | None:
        """Remove a mesh's record, then its blobs. Returns the record, or None."""
        record = self.metadata.delete(mesh_id)
        if record is not None:
            for key in list(self.blobs.keys(mesh_prefix(mesh_id))):
                self.blobs.delete(key)
            self.blobs.delete(record.upload_key)
        return record

    def delete_build(self, qpm: str) -> None:
        """Remove the blobs of one build: its .qpm, stream and stream index."""
        for key in (qpm, stream_key(qpm), stream_index_key(qpm)):
            self.blobs.delete(key)

    def collect_garbage(self, min_age_s: float = 0.0) -> int:
        """Remove temporary files of interrupted writes and blobs that no record refers
        to (a crash between writing a blob and its record, a deleted mesh whose orphaned
        build still wrote), if written at least `min_age_s` ago. Call on start, before
        serving; where other processes share the storage (replicas, workers), with an
        age past any write in flight: an upload's blob is written just before its
        record. Returns the number removed."""
        removed = self.blobs.sweep()
        records = {record.id: record for record in self.metadata.records()}
        before = time.time() - min_age_s
        for key in list(self.blobs.keys()):
            if _referenced(key, records):
                continue
            try:
                if min_age_s and self.blobs.modified(key) > before:
                    continue
            except FileNotFoundError:
                continue
            self.blobs.delete(key)
            removed += 1
        if removed:
            log.info("removed %d unreferenced or temporary blob(s)", removed)
        return removed

    def close(self) -> None:
        self.metadata.close()


def _referenced(key: str, records: dict[str, MeshRecord]) -> bool:
    parts = key.split("/")
    if len(parts) < 2 or parts[1] not in records:
        return False
    record = records[parts[1]]
    if parts[0] == "uploads":
        return key == record.upload_key
    if parts[0] == "meshes":
        # Keep the published build (its .qpm, stream and index); while building, the
        # attempt's own files may appear.
        if record.status in UNFINISHED:
            return True
        qpm = record.qpm_key
        return qpm is not None and key in (qpm, stream_key(qpm), stream_index_key(qpm))
    return False


def open_storage(settings: Settings) -> Storage:
    """The storage named by `settings`, ready to use."""
    metadata = load_backend(METADATA_BACKENDS, settings.metadata_backend).from_settings(settings)
    blobs = load_backend(BLOB_BACKENDS, settings.blob_backend).from_settings(settings)
    return Storage(metadata=metadata, blobs=blobs)

"""What the read endpoints keep in memory: records that can no longer change, loaded
progressive meshes and encoded levels (`LodCache`), stored split streams (`StreamCache`).

A ready record changes only by being deleted, so once read it is kept: a request for a
cached level or a stored stream then does no database round trip, no file read and no
encoding, and its handler runs on the event loop without a thread hop. Deleting a mesh
evicts everything of it at once: through this process directly, through another replica
sharing the database as its delete is announced (`MetadataStore.watch_deletes`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any, TypeVar

from .lod_cache import LodCache
from .lru import CacheStats, LruCache
from .problems import Problem
from .settings import Settings
from .storage import MeshRecord, Storage
from .stored_streams import StreamCache

__all__ = ["ReadPath"]

_READY_RECORDS = 4096
T = TypeVar("T")
log = logging.getLogger("qem.server")


class ReadPath:
    def __init__(self, storage: Storage, settings: Settings) -> None:
        self.storage = storage
        self.levels = LodCache(storage, settings.mesh_cache_size, settings.lod_cache_bytes)
        self.streams = StreamCache(storage, self.levels, settings.stream_cache_bytes)
        self._ready: LruCache[str, MeshRecord] = LruCache(_READY_RECORDS)
        # Ids deleted by this process: a read that fetched the record just before the
        # delete must not put it back after the delete evicted it.
        self._deleted: LruCache[str, bool] = LruCache(_READY_RECORDS)
        self._lock = threading.Lock()

    def cached_record(self, mesh_id: str) -> MeshRecord | None:
        """The record of a ready mesh if this process has read it (never blocks)."""
        return self._ready.peek(mesh_id)

    def record(self, mesh_id: str) -> MeshRecord | None:
        """The record from the database (blocking); kept when it is ready."""
        record = self.storage.metadata.get(mesh_id)
        if record is not None and record.status == "ready":
            with self._lock:
                if self._deleted.peek(mesh_id) is None:
                    self._ready.put(mesh_id, record)
        return record

    def load(self, read: Callable[..., T], record: MeshRecord, *args: Any) -> T:
        """``read(record, *args)``: a level, the stream or the progressive mesh of a ready
        mesh (blocking). If its .qpm is gone from the store, the mesh fails with the
        reason (the record says so from now on, other meshes are unaffected) and the
        request is answered with that problem."""
        try:
            return read(record, *args)
        except FileNotFoundError:
            reason = (
                "its progressive mesh is missing from the blob store (lost, or removed "
                "outside qem-lod); upload the mesh again"
            )
            if self.storage.metadata.lose(record.id, record.qpm_key or "", reason):
                log.error("mesh %s failed: %s", record.id, reason)
            self.evict(record.id)
            raise Problem(
                "mesh-failed", f"mesh {record.id}: {reason}", reason=reason
            ) from None

    def cache_stats(self) -> dict[str, CacheStats]:
        """Each in-memory cache of the read path by name (for /metrics)."""
        return {
            "records": self._ready.stats(),
            **self.levels.cache_stats(),
            **self.streams.cache_stats(),
        }

    def evict(self, mesh_id: str | None) -> None:
        """Forget everything of a deleted mesh (this process's delete, or another
        replica's heard through `MetadataStore.watch_deletes`); None: deletes may have been
        missed, so forget every record (each is read again from the database)."""
        with self._lock:
            if mesh_id is None:
                self._ready.drop(lambda key: True)
                return
            self._deleted.put(mesh_id, True)
            self._ready.drop(lambda key: key == mesh_id)
        self.levels.evict(mesh_id)
        self.streams.evict(mesh_id)

"""Split streams stored beside each .qpm and served as bytes.

The build writes a mesh's whole stream (every frame a key frame) and its frame index
(`qem_core.stored_stream`) next to the .qpm; a request for any ``from``/``to`` is
answered with the run of stored frames covering it, never by encoding. Each stream is
read from the blob store once per process, its length and CRC-32 checked against its
index, and kept in memory within a byte budget.

A mesh built before streams were stored (or whose stream blobs went missing, or were
stored in an older frame version) gets its stream made once, by the first request that
needs it (concurrent requests wait for that one), and stored: never per request.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass

from qem_core import CorruptFileError
from qem_core.stored_stream import OutdatedStreamError, StreamIndex, encode_stored_stream

from .lod_cache import LodCache
from .lru import CacheStats, LruCache
from .storage import BlobStore, MeshRecord, Storage, mesh_prefix, stream_index_key, stream_key

__all__ = ["StoredStream", "StreamCache", "write_stream"]

log = logging.getLogger("qem.streams")


@dataclass(frozen=True)
class StoredStream:
    """The stream of one build: its bytes and the index of its frames."""

    data: bytes
    index: StreamIndex


def write_stream(
    blobs: BlobStore, qpm: str, pm, progress: Callable[[float], None] | None = None
) -> StoredStream:
    """Encode the whole stream of ``pm`` and store it with its index beside the .qpm
    ``qpm`` (the index last: a stream without one is unfinished)."""
    data, index = encode_stored_stream(pm, progress=progress)
    with blobs.writer(stream_key(qpm)) as writer:
        writer.write(data)
    with blobs.writer(stream_index_key(qpm)) as writer:
        writer.write(index.to_json())
    return StoredStream(data, index)


class StreamCache:
    """Stored streams by .qpm key, read (or made) once, within ``byte_budget``."""

    def __init__(self, storage: Storage, meshes: LodCache, byte_budget: int) -> None:
        self._storage = storage
        self._meshes = meshes
        self._streams: LruCache[str, StoredStream] = LruCache(
            byte_budget, lambda stream: len(stream.data)
        )
        self.made = 0  # streams made by this process (meshes built before they were stored)

    def cached(self, record: MeshRecord) -> StoredStream | None:
        """The stream if it is in memory (never blocks)."""
        return self._streams.peek(record.qpm_key or "")

    def get(self, record: MeshRecord) -> StoredStream:
        """The stream of a ready record: from memory, else read from the store (its CRC
        checked), else made and stored. CorruptFileError, naming the mesh, when the stored
        stream does not match its index (the mesh's other data is left as it is)."""
        qpm = record.qpm_key
        if qpm is None:
            raise FileNotFoundError(f"mesh {record.id} has no progressive mesh yet")
        return self._streams.get(qpm, lambda: self._load(record, qpm))

    def cache_stats(self) -> dict[str, CacheStats]:
        return {"streams": self._streams.stats()}

    def evict(self, mesh_id: str) -> None:
        prefix = mesh_prefix(mesh_id)
        self._streams.drop(lambda key: key.startswith(prefix))

    def _load(self, record: MeshRecord, qpm: str) -> StoredStream:
        blobs = self._storage.blobs
        try:
            with blobs.open(stream_index_key(qpm)) as handle:
                index_bytes = handle.read()
            with blobs.open(stream_key(qpm)) as handle:
                data = handle.read()
        except FileNotFoundError:
            return self._make(record, qpm)
        try:
            index = StreamIndex.from_json(index_bytes)
            index.check(data)
        except OutdatedStreamError:
            return self._make(record, qpm)  # stored by an older version: made again once
        except CorruptFileError as error:
            raise CorruptFileError(
                f"the stored split stream of mesh {record.id} is damaged ({error}); its "
                "levels are served as before"
            ) from None
        return StoredStream(data, index)

    def _make(self, record: MeshRecord, qpm: str) -> StoredStream:
        started = time.monotonic()
        stream = write_stream(self._storage.blobs, qpm, self._meshes.progressive_mesh(record))
        self.made += 1
        log.info(
            "made the split stream of mesh %s once (%d bytes, %d frames, %.1f s): it was "
            "built before streams were stored, or its stream was missing or outdated",
            record.id,
            stream.index.size,
            stream.index.n_frames,
            time.monotonic() - started,
        )
        return stream

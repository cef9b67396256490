"""Loaded progressive meshes and encoded levels, kept in memory for repeated requests.

Two LRU maps: progressive meshes by their .qpm key (at most `mesh_capacity` entries) and
encoded levels by (.qpm key, vertex count, format) within a byte budget. A .qpm key names
one build of one mesh, so entries never go stale; `evict` only frees memory of deleted
meshes. Concurrent misses on the same progressive mesh load it once.
"""

from __future__ import annotations

import qem_core
from qem_core.levels import EncodedLevel, encode_level

from .lru import CacheStats, LruCache
from .storage import MeshRecord, Storage, mesh_prefix

__all__ = ["LodCache"]


class LodCache:
    def __init__(self, storage: Storage, mesh_capacity: int, byte_budget: int) -> None:
        self._storage = storage
        self._meshes: LruCache[str, object] = LruCache(mesh_capacity)
        # one huge level must not flush everything
        self._lods: LruCache[tuple[str, int, str], EncodedLevel] = LruCache(
            byte_budget, lambda lod: len(lod.content), max_entry=byte_budget // 4
        )

    def progressive_mesh(self, record: MeshRecord):
        """The `qem_core.ProgressiveMesh` of a ready record.

        Raises FileNotFoundError if its .qpm is missing, CorruptFileError if damaged."""
        key = record.qpm_key
        if key is None:
            raise FileNotFoundError(f"mesh {record.id} has no progressive mesh yet")

        def load():
            with self._storage.blobs.local_path(key) as path:
                return qem_core.load(path)

        return self._meshes.get(key, load)

    def cached_lod(self, record: MeshRecord, n_vertices: int, format: str) -> EncodedLevel | None:
        """Level `n_vertices` in `format` if it is in memory (never blocks)."""
        return self._lods.peek((record.qpm_key or "", int(n_vertices), format))

    def lod(self, record: MeshRecord, n_vertices: int, format: str) -> EncodedLevel:
        """Level `n_vertices` (already clamped into the mesh's range) in `format`."""
        key = (record.qpm_key or "", int(n_vertices), format)
        found = self._lods.peek(key)
        if found is not None:
            return found
        encoded = encode_level(self.progressive_mesh(record), n_vertices, format)
        self._lods.put(key, encoded)
        return encoded

    def cache_stats(self) -> dict[str, CacheStats]:
        return {"meshes": self._meshes.stats(), "levels": self._lods.stats()}

    def evict(self, mesh_id: str) -> None:
        """Forget everything cached of a mesh (after it was deleted)."""
        prefix = mesh_prefix(mesh_id)
        self._meshes.drop(lambda key: key.startswith(prefix))
        self._lods.drop(lambda key: key[0].startswith(prefix))

"""Loaded progressive meshes and encoded levels, kept in memory for repeated requests.

Two LRU maps: progressive meshes by their .qpm key (at most `mesh_capacity` entries) and
encoded levels by (.qpm key, vertex count, format) within a byte budget. A .qpm key names
one build of one mesh, so entries never go stale; `evict` only frees memory of deleted
meshes. Concurrent misses on the same progressive mesh load it once.
"""

from __future__ import annotations

from dataclasses import dataclass

import qem_core
from qem_core import codecs
from qem_core import stream as split_stream

from .lru import LruCache
from .storage import MeshRecord, Storage

__all__ = ["EncodedLod", "LodCache"]


@dataclass(frozen=True)
class EncodedLod:
    """One level of one mesh, encoded.

    content : the file, in `format`; n_vertices, n_faces : its counts;
    error : the quadric error of the level (`ProgressiveMesh.error`).
    """

    content: bytes
    format: str
    n_vertices: int
    n_faces: int
    error: float


class LodCache:
    def __init__(self, storage: Storage, mesh_capacity: int, byte_budget: int) -> None:
        self._storage = storage
        self._meshes: LruCache[str, object] = LruCache(mesh_capacity)
        # one huge level must not flush everything
        self._lods: LruCache[tuple[str, int, str], EncodedLod] = LruCache(
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

    def cached_lod(self, record: MeshRecord, n_vertices: int, format: str) -> EncodedLod | None:
        """Level `n_vertices` in `format` if it is in memory (never blocks)."""
        return self._lods.peek((record.qpm_key or "", int(n_vertices), format))

    def lod(self, record: MeshRecord, n_vertices: int, format: str) -> EncodedLod:
        """Level `n_vertices` (already clamped into the mesh's range) in `format`."""
        key = (record.qpm_key or "", int(n_vertices), format)
        found = self._lods.peek(key)
        if found is not None:
            return found
        pm = self.progressive_mesh(record)
        level = pm.lod_mesh(n_vertices)  # with the appearance attributes, if any
        vertices, faces = level.vertices, level.faces
        # uint16 msgpack positions on the split stream's grid: 6 bytes a vertex, and the
        # very integers the stream's deltas refer to, so a viewer refines it exactly; the
        # same for the wedges' values on the stream's attribute grid.
        grid = {}
        if format == "msgpack":
            wedges = split_stream.quantised_wedges(pm, n_vertices)
            grid = {"quantize_bits": 16, "grid_box": pm.position_bounds, "wedges": wedges}
        content = codecs.encode_mesh(vertices, faces, format, level.vertex_attributes,
                                     level.texture, level.corner_uvs, **grid)
        encoded = EncodedLod(
            content=content,
            format=format,
            n_vertices=int(len(vertices)),
            n_faces=int(len(faces)),
            error=float(pm.error(n_vertices)),
        )
        self._lods.put(key, encoded)
        return encoded

    def evict(self, record: MeshRecord) -> None:
        """Forget everything cached for `record` (after it was deleted)."""
        self._meshes.drop(lambda key: key == record.qpm_key)
        self._lods.drop(lambda key: key[0] == record.qpm_key)

"""Loaded progressive meshes and encoded levels, kept in memory for repeated requests.

Two LRU maps: progressive meshes by their .qpm key (at most `mesh_capacity` entries) and
encoded levels by (.qpm key, vertex count, format) within a byte budget. A .qpm key names
one build of one mesh, so entries never go stale; `evict` only frees memory of deleted
meshes. Concurrent misses on the same progressive mesh load it once.
"""

from __future__ import annotations

import threading
from collections import OrderedDict
from dataclasses import dataclass

import qem_core
from qem_core import codecs
from qem_core import stream as split_stream

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
        self._mesh_capacity = mesh_capacity
        self._byte_budget = byte_budget
        self._lock = threading.Lock()
        self._meshes: OrderedDict[str, object] = OrderedDict()
        self._loading: dict[str, threading.Lock] = {}
        self._lods: OrderedDict[tuple[str, int, str], EncodedLod] = OrderedDict()
        self._lod_bytes = 0

    def progressive_mesh(self, record: MeshRecord):
        """The `qem_core.ProgressiveMesh` of a ready record.

        Raises FileNotFoundError if its .qpm is missing, CorruptFileError if damaged."""
        key = record.qpm_key
        if key is None:
            raise FileNotFoundError(f"mesh {record.id} has no progressive mesh yet")
        with self._lock:
            if key in self._meshes:
                self._meshes.move_to_end(key)
                return self._meshes[key]
            loading = self._loading.setdefault(key, threading.Lock())
        with loading:
            with self._lock:
                if key in self._meshes:
                    return self._meshes[key]
            try:
                with self._storage.blobs.local_path(key) as path:
                    pm = qem_core.load(path)
            finally:
                with self._lock:
                    self._loading.pop(key, None)
            with self._lock:
                self._meshes[key] = pm
                while len(self._meshes) > self._mesh_capacity:
                    self._meshes.popitem(last=False)
            return pm

    def lod(self, record: MeshRecord, n_vertices: int, format: str) -> EncodedLod:
        """Level `n_vertices` (already clamped into the mesh's range) in `format`."""
        key = (record.qpm_key or "", int(n_vertices), format)
        with self._lock:
            found = self._lods.get(key)
            if found is not None:
                self._lods.move_to_end(key)
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
        size = len(encoded.content)
        if size <= self._byte_budget // 4:  # one huge level must not flush everything
            with self._lock:
                if key not in self._lods:
                    self._lods[key] = encoded
                    self._lod_bytes += size
                while self._lod_bytes > self._byte_budget:
                    _, dropped = self._lods.popitem(last=False)
                    self._lod_bytes -= len(dropped.content)
        return encoded

    def evict(self, record: MeshRecord) -> None:
        """Forget everything cached for `record` (after it was deleted)."""
        with self._lock:
            self._meshes.pop(record.qpm_key or "", None)
            for key in [key for key in self._lods if key[0] == record.qpm_key]:
                self._lod_bytes -= len(self._lods.pop(key).content)

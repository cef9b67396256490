"""The in-memory triangle mesh that every part of qem_core exchanges."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["Mesh"]


@dataclass
class Mesh:
    """A triangle mesh with optional per-vertex attributes.

    vertices : (n, 3) float64 positions.
    faces : (m, 3) int32 vertex indices, counter-clockwise seen from outside.
    vertex_attributes : name -> (n, k) float32 array; known names are ``normal`` (k=3),
        ``color`` (k=3 or 4, in [0, 1]) and ``uv`` (k=2).
    corner_uvs : optional (m, 3, 2) float32 texture coordinates per face corner, as OBJ
        stores them (one position may carry several UVs along a seam).
    texture : optional encoded image (PNG, JPEG or WebP bytes) the UVs refer to.
    name : the file name it came from, if any.
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_attributes: dict[str, np.ndarray] = field(default_factory=dict)
    corner_uvs: np.ndarray | None = None
    texture: bytes | None = None
    name: str | None = None

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

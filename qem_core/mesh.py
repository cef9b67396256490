"""The in-memory triangle mesh that every part of qem_core exchanges."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["MAX_MATERIALS", "Material", "Mesh", "materials_from_entries"]

# Materials a mesh may keep apart (a face's material is one of them); scenes with more
# are refused rather than merged. 256 keeps the material's wedge grid at 8 bits.
MAX_MATERIALS = 256


@dataclass
class Material:
    """One material of a mesh of several: a base-colour image, or a colour, or both.

    texture : encoded image (PNG, JPEG or WebP bytes) its faces' UVs refer to, or None.
    color : (r, g, b, a) in [0, 1], the glTF base-colour factor or the MTL's Kd, or None.
    """

    name: str
    texture: bytes | None = None
    color: tuple[float, float, float, float] | None = None


def materials_from_entries(entries, image_of, error: type[Exception], where: str) -> list:
    """Materials from the maps a file stores ({"name", "color", ...}), every field
    checked, as the msgpack form and the .qpm store them. ``image_of(i, entry)`` gives
    material i's image bytes or None (each format keeps them its own way) and raises
    ``error`` for a bad reference; anything else wrong raises ``error`` naming ``where``."""
    if not (isinstance(entries, list) and 2 <= len(entries) <= MAX_MATERIALS):
        raise error(f"{where} must list 2 to {MAX_MATERIALS} materials")
    materials = []
    for i, entry in enumerate(entries):
        if not (isinstance(entry, dict) and isinstance(entry.get("name"), str)):
            raise error(f"{where}: material {i} is not a map with a name")
        color = entry.get("color")
        if color is not None:
            # bool is an int, and msgpack's true would pass as 1.0.
            if not (isinstance(color, list) and len(color) == 4 and all(
                isinstance(c, (int, float)) and not isinstance(c, bool) and 0 <= c <= 1
                for c in color
            )):  # fmt: skip
                raise error(f"{where}: material {i}'s colour {color!r:.80} is not four "
                            "numbers in [0, 1]")  # fmt: skip
            color = tuple(float(c) for c in color)
        materials.append(Material(entry["name"], image_of(i, entry), color))
    return materials


@dataclass
class Mesh:
    """A triangle mesh with optional per-vertex attributes.

    vertices : (n, 3) float64 positions.
    faces : (m, 3) int32 vertex indices, counter-clockwise seen from outside.
    vertex_attributes : name -> (n, k) float32 array; known names are ``normal`` (k=3),
        ``color`` (k=3 or 4, in [0, 1]) and ``uv`` (k=2).
    corner_uvs : optional (m, 3, 2) float32 texture coordinates per face corner, as OBJ
        stores them (one position may carry several UVs along a seam).
    texture : optional encoded image (PNG, JPEG or WebP bytes) the UVs refer to, when
        the mesh has one material.
    materials : with several materials (2 to MAX_MATERIALS), each one's look, and
        ``face_materials`` (m,) int32, the material of each face; ``texture`` is then
        None. Faces of two materials never share a wedge: their border is a seam.
    name : the file name it came from, if any.
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_attributes: dict[str, np.ndarray] = field(default_factory=dict)
    corner_uvs: np.ndarray | None = None
    texture: bytes | None = None
    name: str | None = None
    materials: list[Material] | None = None
    face_materials: np.ndarray | None = None

    @property
    def n_vertices(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])

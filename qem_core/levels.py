"""One level of a progressive mesh encoded as it is served: the server's ``/lod``, the
static export's base mesh and ``qem lod`` write the same bytes for the same level.

The msgpack form holds positions as uint16 on the split stream's grid (6 bytes a vertex,
and the very integers the stream's deltas refer to, so a viewer refines it exactly) and
the wedges' values on the stream's attribute grid.
"""

from __future__ import annotations

from dataclasses import dataclass

from .codecs import encode_mesh
from .progressive import ProgressiveMesh
from .wedge_stream import quantised_wedges

__all__ = ["EncodedLevel", "encode_level"]

STREAM_GRID_BITS = 16


@dataclass(frozen=True)
class EncodedLevel:
    """One level, encoded: the file in `format`, its counts, its quantised error."""

    content: bytes
    format: str
    n_vertices: int
    n_faces: int
    error: float


def encode_level(pm: ProgressiveMesh, n: int, format: str) -> EncodedLevel:
    """Level ``n`` (clamped into the mesh's range) with its appearance attributes, as
    PLY, OBJ, GLB or msgpack (on the stream's grids)."""
    n = pm.clamp(n)
    level = pm.lod_mesh(n)
    grid = {}
    if format == "msgpack":
        grid = {
            "quantize_bits": STREAM_GRID_BITS,
            "grid_box": pm.position_bounds,
            "wedges": quantised_wedges(pm, n),
        }
    content = encode_mesh(
        level.vertices, level.faces, format, level.vertex_attributes, level.texture,
        level.corner_uvs, materials=level.materials, face_materials=level.face_materials,
        **grid,
    )  # fmt: skip
    return EncodedLevel(content, format, len(level.vertices), len(level.faces), float(pm.error(n)))

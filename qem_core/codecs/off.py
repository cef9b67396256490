"""OFF (Geomview Object File Format): reader for the ASCII variants.

Layout, one record per line, ``#`` starts a comment::

    [ST][C][N]OFF            header keyword (counts may follow on the same line)
    n_vertices n_faces n_edges
    x y z [nx ny nz] [r g b [a]] [s t]      n_vertices lines
    k i_1 ... i_k [r g b [a]]               n_faces lines, 0-based indices

``N`` gives "normal", ``C`` gives "color" (values above 1 are taken as 0..255), ``ST``
gives "uv"; vertex lines of unequal length keep positions only. Polygons are
triangulated (fans; strips past 16 corners); face colours are ignored. Binary OFF and
the 4D / nD variants are refused.
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import MeshFormatError
from ..mesh import Mesh
from ._polygons import triangulate_polygons
from ._text import parse_lines, parse_numbers

__all__ = ["read_off", "is_off"]

_KEYWORD = re.compile(rb"(ST)?(C)?(N)?(4)?(n)?OFF")
_COMMENT = re.compile(rb"#[^\n]*")


def is_off(data: bytes) -> bool:
    """True if the first word (after comments) is an OFF header keyword."""
    head = _COMMENT.sub(b"", data[:4096]).split(None, 1)
    return bool(head) and _KEYWORD.fullmatch(head[0]) is not None


def read_off(data: bytes) -> Mesh:
    """Decode an ASCII OFF file into a Mesh. Raises MeshFormatError."""
    lines = [line for line in _COMMENT.sub(b"", data).splitlines() if line.strip()]
    if not lines:
        raise MeshFormatError("OFF file is empty")
    header = lines[0].split()
    keyword = _KEYWORD.fullmatch(header[0])
    if keyword is None:
        raise MeshFormatError(f"not an OFF file: it starts with {header[0][:20]!r}, not 'OFF'")
    texture, color, normal, four_d, n_dimensional = (g is not None for g in keyword.groups())
    if four_d or n_dimensional or b"BINARY" in header[1:2]:
        raise MeshFormatError(
            # The header may hold any bytes: the message shows them, undecodable or not.
            f"{b' '.join(header[:2]).decode('utf-8', 'replace')}: only ASCII 3D OFF "
            "is read; convert the file to plain OFF, PLY or OBJ"
        )
    if len(header) > 1:
        count_line, first_vertex_line = header[1:], 1
    elif len(lines) > 1:
        count_line, first_vertex_line = lines[1].split(), 2
    else:
        raise MeshFormatError("OFF file ends after its header: no vertex and face counts")
    counts = parse_numbers(b" ".join(count_line[:3]), np.int64, "OFF counts line")
    if counts.size < 2 or counts.min() < 0:
        raise MeshFormatError("OFF counts line must hold 'n_vertices n_faces [n_edges]' >= 0")
    n_vertices, n_faces = int(counts[0]), int(counts[1])
    available = len(lines) - first_vertex_line
    if n_vertices + n_faces > available:
        raise MeshFormatError(
            f"OFF header declares {n_vertices} vertices and {n_faces} faces but only "
            f"{available} lines follow: the file is truncated or its counts are wrong"
        )
    vertex_lines = lines[first_vertex_line : first_vertex_line + n_vertices]
    face_lines = lines[first_vertex_line + n_vertices : first_vertex_line + n_vertices + n_faces]
    vertices, attributes = _vertices(vertex_lines, normal, color, texture)
    return Mesh(vertices=vertices, faces=_faces(face_lines), vertex_attributes=attributes)


def _vertices(
    lines: list[bytes], has_normal: bool, has_color: bool, has_uv: bool
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    numbers, counts = parse_lines(lines, "OFF vertex lines")
    if not lines:
        return np.zeros((0, 3)), {}
    if counts.min() < 3:
        bad = int(np.flatnonzero(counts < 3)[0])
        raise MeshFormatError(f"OFF vertex {bad} has {int(counts[bad])} numbers; it needs x y z")
    if counts.min() != counts.max():
        first = np.cumsum(counts) - counts
        return numbers[first[:, None] + np.arange(3)], {}
    table = numbers.reshape(len(lines), int(counts[0]))
    attributes = {}
    column = 3
    if has_normal:
        attributes["normal"] = table[:, column : column + 3]
        column += 3
    end = table.shape[1] - 2 if has_uv else table.shape[1]
    if has_color and end - column in (3, 4):
        colors = table[:, column:end]
        if colors.size and colors.max() > 1.0:
            colors = colors / 255.0
        attributes["color"] = np.clip(colors, 0.0, 1.0)
    if has_uv and end >= column:
        attributes["uv"] = table[:, end:]
    widths = {"normal": 3, "uv": 2}
    if any(a.shape[1] != widths.get(k, a.shape[1]) for k, a in attributes.items()):
        attributes = {}  # too few numbers per line for what the keyword promised
    return np.ascontiguousarray(table[:, :3]), {
        k: np.ascontiguousarray(v, dtype=np.float32) for k, v in attributes.items()
    }


def _faces(lines: list[bytes]) -> np.ndarray:
    numbers, counts = parse_lines(lines, "OFF face lines")
    if not lines:
        return np.zeros((0, 3), dtype=np.int64)
    first = np.cumsum(counts) - counts
    corner_counts = numbers[first]
    bad = (corner_counts != np.floor(corner_counts)) | ~(corner_counts >= 0)
    bad |= corner_counts > counts - 1
    if bad.any():
        face = int(np.flatnonzero(bad)[0])
        raise MeshFormatError(
            f"OFF face {face} says it has {float(corner_counts[face]):g} corners but its "
            f"line holds {int(counts[face]) - 1} more numbers"
        )
    corner_counts = corner_counts.astype(np.int64)
    face_of_corner = np.repeat(np.arange(len(lines)), corner_counts)
    corner_in_face = (
        np.arange(face_of_corner.size) - (np.cumsum(corner_counts) - corner_counts)[face_of_corner]
    )
    indices = numbers[first[face_of_corner] + 1 + corner_in_face]
    if not np.all((indices == np.floor(indices)) & (np.abs(indices) < 2.0**31)):
        raise MeshFormatError("OFF face lines hold a vertex index that is not an integer")
    return triangulate_polygons(corner_counts, indices.astype(np.int64), "OFF face")

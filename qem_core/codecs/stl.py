"""STL (stereolithography): reader for binary and ASCII files.

STL is a triangle soup: each facet stores its three corners, so a closed surface of V
vertices arrives as 3F unconnected vertices. They are returned as stored, three per
face, with no welding: welding is `qem_core.prepare.prepare_mesh`'s job (its
``merge_coincident``). Facet normals are not kept (they are per face, often zero, and
the simplifier recomputes what it needs); the binary attribute word is ignored.

Binary layout: 80-byte header, uint32 facet count, then per facet 12 little-endian
float32 (normal, three corners) and a uint16, 50 bytes. A file is binary when its size
is exactly 84 + 50 * count, whatever its header says (many binary files start with
"solid" too), ASCII when it starts with "solid".
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import MeshFormatError
from ..mesh import Mesh
from ._floats import widened
from ._text import parse_numbers

__all__ = ["read_stl", "is_binary_stl", "is_ascii_stl"]

_FACET = np.dtype([("normal", "<f4", (3,)), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
_VERTEX_LINE = re.compile(rb"^[ \t]*vertex[ \t]+([^\r\n]*)", re.MULTILINE | re.IGNORECASE)
# The closing line, looked for in the last bytes (after it only its name and blanks).
_END_SOLID = re.compile(rb"^[ \t]*endsolid\b[^\n]*\s*\Z", re.MULTILINE | re.IGNORECASE)
_TAIL_BYTES = 4096


def is_binary_stl(data: bytes) -> bool:
    """True if the size is exactly that of a binary STL with the count it declares."""
    return len(data) >= 84 and len(data) == 84 + 50 * _declared_facets(data)


def is_ascii_stl(data: bytes) -> bool:
    """True if the data starts like an ASCII STL ("solid" then a facet)."""
    head = data[:1024].lstrip()
    return head[:5].lower() == b"solid" and b"facet" in head.lower()


def read_stl(data: bytes) -> Mesh:
    """Decode a binary or ASCII STL into a triangle soup. Raises MeshFormatError."""
    if not is_binary_stl(data) and data.lstrip()[:5].lower() == b"solid":
        return _read_ascii(data)
    return _read_binary(data)


def _declared_facets(data: bytes) -> int:
    return int(np.frombuffer(data, dtype="<u4", count=1, offset=80)[0])


def _read_binary(data: bytes) -> Mesh:
    if len(data) < 84:
        raise MeshFormatError(
            f"binary STL is {len(data)} bytes, shorter than its 84-byte header: truncated"
        )
    n_facets = _declared_facets(data)
    needed = 84 + 50 * n_facets
    if len(data) < needed:
        raise MeshFormatError(
            f"binary STL declares {n_facets} facets ({needed} bytes) but has {len(data)} "
            "bytes: the file is truncated or not an STL"
        )
    facets = np.frombuffer(data, dtype=_FACET, count=n_facets, offset=84)
    return _soup(widened(facets["corners"].reshape(-1, 3)))


def _read_ascii(data: bytes) -> Mesh:
    lines = _VERTEX_LINE.findall(data)
    numbers = parse_numbers(b"\n".join(lines), np.float64, "ASCII STL 'vertex' lines")
    if numbers.size != 3 * len(lines):
        raise MeshFormatError("ASCII STL has a 'vertex' line without exactly 3 numbers")
    if len(lines) % 3:
        raise MeshFormatError(
            f"ASCII STL has {len(lines)} 'vertex' lines, not a multiple of 3: a facet is truncated"
        )
    if not _END_SOLID.search(data[-_TAIL_BYTES:]):
        raise MeshFormatError(
            "ASCII STL does not end with an 'endsolid' line: the file is truncated"
        )
    return _soup(numbers.reshape(-1, 3))


def _soup(corners: np.ndarray) -> Mesh:
    """Three vertices per face, as stored."""
    faces = np.arange(corners.shape[0], dtype=np.int64).reshape(-1, 3)
    return Mesh(vertices=corners, faces=faces)

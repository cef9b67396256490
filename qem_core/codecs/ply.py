"""PLY (Stanford polygon file format): reader and binary writer.

Reads ASCII, binary little-endian and binary big-endian PLY (Turk 1994; the layout as
in Paul Bourke's "PLY - Polygon File Format" page):

- ``vertex`` element: ``x y z`` of any numeric type (required); ``nx ny nz`` ->
  "normal"; ``red green blue [alpha]`` (also ``diffuse_red``... or ``r g b [a]``) ->
  "color" in [0, 1] (integer types are divided by their maximum, e.g. 255 for uchar;
  float colours above 1 are taken as 0..255); ``s t``, ``u v``, ``texture_u texture_v``
  or ``texture_s texture_t`` -> "uv".
- ``face`` element: list ``vertex_indices`` (or ``vertex_index``) of any integer count
  and index type; polygons are triangulated (`_polygons.py`). A list ``texcoord`` (MeshLab's
  per-corner UVs: u v for each corner, 2k values for a k-gon) -> `Mesh.corner_uvs`,
  and also "uv" when the vertex element has none and no vertex has two UVs.
- Every other element and property, lists included, is skipped.

Binary elements are mapped with one structured numpy dtype when their lists all have the
length of the first record's (the usual triangle mesh); otherwise a compiled walk finds
the records (`_ply_records`). The header's counts are checked against the file's size
before anything is allocated.

Writes binary little-endian PLY: float32 ``x y z``, float32 ``nx ny nz``, uchar
``red green blue [alpha]``, float32 ``s t``, and faces as ``list uchar int
vertex_indices`` followed, with `corner_uvs`, by ``list uchar float texcoord`` (6
values, u v per corner, as MeshLab writes them). docs/formats.md has the exact layout.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import partial

import numpy as np

from ..errors import MeshFormatError
from ..mesh import Mesh
from . import _ply_records
from ._corners import per_vertex
from ._polygons import polygon_corners, triangulate_polygons
from ._text import parse_numbers

__all__ = ["read_ply", "write_ply"]

_TYPES = {
    "char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1",
    "short": "i2", "int16": "i2", "ushort": "u2", "uint16": "u2",
    "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_BYTE_ORDERS = {"ascii": "<", "binary_little_endian": "<", "binary_big_endian": ">"}
# The header must end within this many bytes; real headers are a few hundred.
_MAX_HEADER_BYTES = 1 << 20

_FACE_LISTS = ("vertex_indices", "vertex_index")
_COLOR_NAMES = (
    ("red", "green", "blue", "alpha"),
    ("diffuse_red", "diffuse_green", "diffuse_blue", "diffuse_alpha"),
    ("r", "g", "b", "a"),
)
# MeshLab's per-corner UVs: a face list of u v per corner.
_TEXCOORD = "texcoord"
_UV_NAMES = (("s", "t"), ("u", "v"), ("texture_u", "texture_v"), ("texture_s", "texture_t"))


@dataclass(frozen=True)
class _Property:
    name: str
    dtype: np.dtype  # the value's type, or a list item's type
    count_dtype: np.dtype | None  # a list's count type; None for a scalar


@dataclass(frozen=True)
class _Element:
    name: str
    count: int
    properties: tuple[_Property, ...]

    @property
    def has_lists(self) -> bool:
        return any(p.count_dtype is not None for p in self.properties)

    def min_record_bytes(self) -> int:
        """Bytes of one binary record whose lists are all empty."""
        return sum((p.count_dtype or p.dtype).itemsize for p in self.properties)


@dataclass
class _Header:
    encoding: str
    elements: list[_Element]
    body_start: int


# Values read from one element: a scalar property -> (count,) array; a list property ->
# (item counts (count,) int64, its items). The items are all one after another
# (sum of counts,), or (count, k) when every list has k items: then they are a view into
# the file's bytes (binary) or tokens (ASCII), not a copy, and the counts a broadcast
# scalar.
_Values = dict[str, "np.ndarray | tuple[np.ndarray, np.ndarray]"]


def read_ply(data: bytes) -> Mesh:
    """Decode a PLY file (ASCII or binary) into a Mesh. Raises MeshFormatError."""
    header = _parse_header(data)
    _check_sizes(header, len(data))
    by_name = {e.name: e for e in header.elements}
    if "vertex" not in by_name:
        raise MeshFormatError(
            f"PLY has no 'vertex' element (elements: {[e.name for e in header.elements]})"
        )
    if "face" not in by_name:
        raise MeshFormatError(
            "PLY has no 'face' element: it is a point cloud or uses another layout "
            f"(elements: {[e.name for e in header.elements]}); qem-lod needs triangles"
        )
    face_list = next((n for n in _FACE_LISTS if _find(by_name["face"], n)), None)
    if face_list is None:
        raise MeshFormatError(
            "PLY 'face' element has no list property 'vertex_indices' or 'vertex_index' "
            f"(it has {[p.name for p in by_name['face'].properties]})"
        )
    if _find(by_name["face"], face_list).count_dtype is None:
        raise MeshFormatError(
            f"PLY face property {face_list!r} is a scalar; a face's corners are a list "
            f"('property list uchar int {face_list}')"
        )
    texcoord = _find(by_name["face"], _TEXCOORD)
    face_names = {face_list}
    if texcoord is not None and texcoord.count_dtype is not None:
        face_names.add(_TEXCOORD)
    wanted = {"vertex": _vertex_names(by_name["vertex"]), "face": face_names}
    values = _read_elements(data, header, wanted)
    return _build_mesh(
        by_name["vertex"],
        values["vertex"],
        values["face"][face_list],
        values["face"].get(_TEXCOORD),
    )


def write_ply(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_attributes: dict[str, np.ndarray],
    texture: bytes | None = None,
    corner_uvs: np.ndarray | None = None,
) -> bytes:
    """Encode as binary little-endian PLY; `corner_uvs` as the face list ``texcoord``.
    The texture, if any, is not stored (PLY has no place for image bytes)."""
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    normal = vertex_attributes.get("normal")
    color = vertex_attributes.get("color")
    uv = vertex_attributes.get("uv")
    if normal is not None:
        fields += [("nx", "<f4"), ("ny", "<f4"), ("nz", "<f4")]
    if color is not None:
        fields += [(name, "u1") for name in _COLOR_NAMES[0][: color.shape[1]]]
    if uv is not None:
        fields += [("s", "<f4"), ("t", "<f4")]
    records = np.zeros(vertices.shape[0], dtype=np.dtype(fields))
    for axis, name in enumerate("xyz"):
        records[name] = vertices[:, axis]
    if normal is not None:
        for axis, name in enumerate(("nx", "ny", "nz")):
            records[name] = normal[:, axis]
    if color is not None:
        quantised = np.round(np.clip(color, 0.0, 1.0) * 255.0).astype(np.uint8)
        for channel, name in enumerate(_COLOR_NAMES[0][: color.shape[1]]):
            records[name] = quantised[:, channel]
    if uv is not None:
        records["s"] = uv[:, 0]
        records["t"] = uv[:, 1]
    face_fields = [("n", "u1"), ("v", "<i4", (3,))]
    if corner_uvs is not None:
        face_fields += [("n_uv", "u1"), ("uv", "<f4", (6,))]
    face_records = np.zeros(faces.shape[0], dtype=face_fields)
    face_records["n"] = 3
    face_records["v"] = faces
    if corner_uvs is not None:
        face_records["n_uv"] = 6
        face_records["uv"] = corner_uvs.reshape(-1, 6)
    type_names = {"<f4": "float", "u1": "uchar"}
    lines = [
        "ply",
        "format binary_little_endian 1.0",
        "comment qem-lod",
        f"element vertex {vertices.shape[0]}",
        *(f"property {type_names[t]} {name}" for name, t in fields),
        f"element face {faces.shape[0]}",
        "property list uchar int vertex_indices",
        *([f"property list uchar float {_TEXCOORD}"] if corner_uvs is not None else []),
        "end_header",
    ]
    header = ("\n".join(lines) + "\n").encode("ascii")
    return header + records.tobytes() + face_records.tobytes()


def _parse_header(data: bytes) -> _Header:
    if not (data[:3] == b"ply" and data[3:4] in (b"\n", b"\r")):
        raise MeshFormatError("not a PLY file: it does not start with a 'ply' line")
    end = data.find(b"end_header", 0, _MAX_HEADER_BYTES)
    if end < 0:
        where = "the file" if len(data) <= _MAX_HEADER_BYTES else "its first 1 MiB"
        raise MeshFormatError(f"PLY header has no 'end_header' line in {where}")
    after = end + len(b"end_header")
    if data[after : after + 2] == b"\r\n":
        body_start = after + 2
    elif data[after : after + 1] in (b"\n", b"\r"):  # \r alone: classic Mac line ends
        body_start = after + 1
    else:  # trailing text on the line
        newline = data.find(b"\n", end)
        body_start = len(data) if newline < 0 else newline + 1
    encoding = None
    elements: list[_Element] = []
    properties: list[_Property] = []
    for line_number, line in enumerate(data[:end].decode("ascii", "replace").splitlines()):
        words = line.split()
        if not words or words[0] in ("comment", "obj_info") or line_number == 0:
            continue
        where = f"PLY header line {line_number + 1} ({line.strip()[:60]!r})"
        if words[0] == "format":
            if len(words) < 2 or words[1] not in _BYTE_ORDERS:
                raise MeshFormatError(f"{where}: format must be one of {list(_BYTE_ORDERS)}")
            encoding = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise MeshFormatError(f"{where}: expected 'element NAME COUNT', COUNT >= 0")
            if any(e.name == words[1] for e in elements):
                raise MeshFormatError(f"{where}: element {words[1]!r} is declared twice")
            properties = []
            elements.append(_Element(words[1], int(words[2]), ()))
        elif words[0] == "property":
            if not elements:
                raise MeshFormatError(f"{where}: a property before any element")
            properties.append(_parse_property(words, where))
            last = elements[-1]
            elements[-1] = _Element(last.name, last.count, tuple(properties))
        else:
            raise MeshFormatError(f"{where}: unknown header keyword {words[0]!r}")
    if encoding is None:
        raise MeshFormatError("PLY header has no 'format' line")
    byte_order = _BYTE_ORDERS[encoding]
    elements = [
        _Element(e.name, e.count, tuple(_with_byte_order(p, byte_order) for p in e.properties))
        for e in elements
    ]
    return _Header(encoding, elements, body_start)


def _parse_property(words: list[str], where: str) -> _Property:
    def type_of(name: str) -> np.dtype:
        if name not in _TYPES:
            raise MeshFormatError(f"{where}: unknown type {name!r}; PLY types are {list(_TYPES)}")
        return np.dtype(_TYPES[name])

    if len(words) == 3:
        return _Property(words[2], type_of(words[1]), None)
    if len(words) == 5 and words[1] == "list":
        count_dtype = type_of(words[2])
        if count_dtype.kind not in "iu":
            raise MeshFormatError(f"{where}: a list's count type must be an integer type")
        return _Property(words[4], type_of(words[3]), count_dtype)
    raise MeshFormatError(
        f"{where}: expected 'property TYPE NAME' or 'property list COUNT_TYPE TYPE NAME'"
    )


def _with_byte_order(prop: _Property, byte_order: str) -> _Property:
    count_dtype = None if prop.count_dtype is None else prop.count_dtype.newbyteorder(byte_order)
    return _Property(prop.name, prop.dtype.newbyteorder(byte_order), count_dtype)


def _check_sizes(header: _Header, n_bytes: int) -> None:
    """Refuse a header whose counts cannot fit in the file, before allocating anything.

    A binary record needs at least `min_record_bytes`; an ASCII value at least one
    character and one separator.
    """
    available = n_bytes - header.body_start
    needed = 0
    for element in header.elements:
        if header.encoding == "ascii":
            per_record = 2 * len(element.properties)
        else:
            per_record = element.min_record_bytes()
        needed += element.count * per_record
        if needed > available + 1:
            raise MeshFormatError(
                f"PLY header declares {element.count} '{element.name}' records of at least "
                f"{per_record} bytes each, but only {available} bytes follow the header: "
                "the file is truncated or its header is wrong"
            )


def _find(element: _Element, name: str) -> _Property | None:
    return next((p for p in element.properties if p.name == name), None)


def _vertex_names(vertex: _Element) -> set[str]:
    names = {p.name for p in vertex.properties}
    missing = [axis for axis in "xyz" if axis not in names]
    if missing:
        raise MeshFormatError(
            f"PLY 'vertex' element lacks {missing} (it has {sorted(names)}); "
            "positions must be properties x, y, z"
        )
    wanted = {"x", "y", "z"}
    if {"nx", "ny", "nz"} <= names:
        wanted |= {"nx", "ny", "nz"}
    for group in (*_COLOR_NAMES, *_UV_NAMES):
        if set(group[:2]) <= names:
            wanted |= names & set(group)
    return wanted


def _read_elements(data: bytes, header: _Header, wanted: dict[str, set[str]]) -> dict[str, _Values]:
    """Values of the wanted properties of the wanted elements; others are skipped."""
    if header.encoding == "ascii":
        source = parse_numbers(data[header.body_start :], np.float64, "PLY ASCII body")
        read = _read_ascii_element
    else:
        source = np.frombuffer(data, dtype=np.uint8)
        read = partial(_read_binary_element, big_endian=header.encoding == "binary_big_endian")
    position = header.body_start if header.encoding != "ascii" else 0
    values: dict[str, _Values] = {}
    for element in header.elements:
        if all(name in values for name in wanted):
            break
        element_values, position = read(source, position, element, wanted.get(element.name, set()))
        if element.name in wanted and element.name not in values:
            values[element.name] = element_values
    return values


def _read_binary_element(
    data: np.ndarray, start: int, element: _Element, wanted: set[str], big_endian: bool
) -> tuple[_Values, int]:
    """Values of `wanted` properties of a binary element starting at byte `start`, and
    the byte after it."""
    if element.count == 0 or not element.properties:
        return _empty_values(element, wanted), start
    dtype = _uniform_dtype(data, start, element)
    if dtype is not None and start + element.count * dtype.itemsize <= data.size:
        records = np.frombuffer(data, dtype=dtype, count=element.count, offset=start)
        values = _values_from_records(records, element, wanted)
        if values is not None:
            return values, start + element.count * dtype.itemsize
    # Lists of varying length: walk the records, then gather with numpy.
    props = element.properties
    starts = np.zeros((element.count, len(props)), dtype=np.int64)
    counts = np.zeros((element.count, len(props)), dtype=np.int64)
    end = _ply_records.walk_binary(
        data,
        start,
        element.count,
        np.array([p.count_dtype is not None for p in props]),
        np.array([p.dtype.itemsize for p in props], dtype=np.int64),
        np.array([(p.count_dtype or p.dtype).itemsize for p in props], dtype=np.int64),
        np.array([(p.count_dtype or p.dtype).kind == "i" for p in props]),
        big_endian,
        starts,
        counts,
    )

    def stored_count(at: int, prop: _Property) -> int:
        return int(data[at : at + prop.count_dtype.itemsize].view(prop.count_dtype)[0])

    _check_walk(end, element, starts, counts, stored_count)
    values: _Values = {}
    for column, prop in enumerate(props):
        if prop.name not in wanted:
            continue
        if prop.count_dtype is None:
            values[prop.name] = _gather_bytes(data, starts[:, column], 1, prop.dtype)
        else:
            items = _gather_bytes(data, starts[:, column], counts[:, column], prop.dtype)
            values[prop.name] = (counts[:, column], items)
    return values, int(end)


def _uniform_dtype(data: np.ndarray, start: int, element: _Element) -> np.dtype | None:
    """The record dtype if every list is as long as in the first record (None if the
    first record does not fit)."""
    fields = []
    position = start
    for column, prop in enumerate(element.properties):
        if prop.count_dtype is None:
            fields.append((f"p{column}", prop.dtype))
            position += prop.dtype.itemsize
            continue
        size = prop.count_dtype.itemsize
        if position + size > data.size:
            return None
        count = int(data[position : position + size].view(prop.count_dtype)[0])
        if count < 0:
            return None
        fields.append((f"n{column}", prop.count_dtype))
        fields.append((f"p{column}", prop.dtype, (count,)))
        position += size + count * prop.dtype.itemsize
        if position > data.size:
            return None
    return np.dtype(fields)


def _values_from_records(
    records: np.ndarray, element: _Element, wanted: set[str]
) -> _Values | None:
    """Values from a structured array, or None if a list's length differs from the
    first record's (the uniform guess was wrong)."""
    values: _Values = {}
    for column, prop in enumerate(element.properties):
        if prop.count_dtype is not None:
            counts = records[f"n{column}"]
            length = records.dtype[f"p{column}"].shape[0]
            if not np.all(counts == length):
                return None
            if prop.name in wanted:
                values[prop.name] = (_same_counts(len(records), length), records[f"p{column}"])
        elif prop.name in wanted:
            values[prop.name] = records[f"p{column}"]
    return values


def _same_counts(n_records: int, length: int) -> np.ndarray:
    """(n_records,) int64 list lengths, all `length`: a read-only broadcast scalar (no
    8 bytes a record)."""
    return np.broadcast_to(np.int64(length), (n_records,))


def _gather_bytes(
    data: np.ndarray, starts: np.ndarray, counts: np.ndarray | int, dtype: np.dtype
) -> np.ndarray:
    """Items of `dtype` stored at byte `starts` (counts items each, as the record walk
    found them within `data`), as one flat array. Copied in compiled code: no index
    array per item or per byte."""
    starts = np.ascontiguousarray(starts, dtype=np.int64)
    counts = np.ascontiguousarray(np.broadcast_to(counts, starts.shape), dtype=np.int64)
    out = np.empty(int(counts.sum()) * dtype.itemsize, dtype=np.uint8)
    _ply_records.gather_items(data, starts, counts, dtype.itemsize, out)
    return out.view(dtype)


def _read_ascii_element(
    tokens: np.ndarray, start: int, element: _Element, wanted: set[str]
) -> tuple[_Values, int]:
    """The ASCII twin of `_read_binary_element`; positions are indices into `tokens`."""
    if element.count == 0 or not element.properties:
        return _empty_values(element, wanted), start
    props = element.properties
    # Guess every list is as long as in the first record, and check the guess.
    widths = []
    position = start
    for prop in props:
        width = 1
        # Only a plausible first count sets the guess (inf, NaN or a huge one would not
        # convert): a wrong guess is found below and the records walked one by one.
        if prop.count_dtype is not None and position < tokens.size:
            first = tokens[position]
            width += int(first) if 0 <= first <= tokens.size - position else 0
        widths.append(width)
        position += width
    record_width = sum(widths)
    end = start + element.count * record_width
    if end <= tokens.size:
        table = tokens[start:end].reshape(element.count, record_width)
        columns = np.cumsum(widths) - widths
        uniform = all(
            np.all(table[:, column] == width - 1)
            for column, width, prop in zip(columns, widths, props, strict=True)
            if prop.count_dtype is not None
        )
        if uniform:
            values: _Values = {}
            for column, width, prop in zip(columns, widths, props, strict=True):
                if prop.name not in wanted:
                    continue
                if prop.count_dtype is None:
                    values[prop.name] = table[:, column]
                else:
                    items = table[:, column + 1 : column + width]
                    values[prop.name] = (_same_counts(element.count, width - 1), items)
            return values, end
    starts = np.zeros((element.count, len(props)), dtype=np.int64)
    counts = np.zeros((element.count, len(props)), dtype=np.int64)
    is_list = np.array([p.count_dtype is not None for p in props])
    end = _ply_records.walk_tokens(tokens, start, element.count, is_list, starts, counts)
    _check_walk(end, element, starts, counts, lambda at, prop: f"{float(tokens[at]):g}")
    values = {}
    for column, prop in enumerate(props):
        if prop.name not in wanted:
            continue
        if prop.count_dtype is None:
            values[prop.name] = tokens[starts[:, column]]
        else:
            record_counts = counts[:, column]
            first_item = np.cumsum(record_counts) - record_counts
            item_record = np.repeat(np.arange(element.count), record_counts)
            offsets = np.arange(item_record.size) - first_item[item_record]
            values[prop.name] = (record_counts, tokens[starts[item_record, column] + offsets])
    return values, int(end)


def _check_walk(
    end: int,
    element: _Element,
    starts: np.ndarray,
    counts: np.ndarray,
    count_at: Callable[[int, _Property], object],
) -> None:
    """Refuse a walk that ended early; ``count_at(position, property)`` is the list count
    stored at a position, as written in the file, for the message."""
    if end == _ply_records.TRUNCATED:
        raise MeshFormatError(
            f"PLY data ends inside the '{element.name}' element (header says "
            f"{element.count} records): the file is truncated"
        )
    if end == _ply_records.BAD_COUNT:
        record, column = (int(i) for i in np.argwhere(counts < 0)[0])
        prop = element.properties[column]
        count = count_at(int(starts[record, column]), prop)
        raise MeshFormatError(
            f"PLY '{element.name}' element has a list with a negative or non-integer "
            f"length: record {record}'s {prop.name!r} has length {count}, where a whole "
            "number no greater than the values that follow is needed: the file is damaged"
        )


def _empty_values(element: _Element, wanted: set[str]) -> _Values:
    values: _Values = {}
    for prop in element.properties:
        if prop.name in wanted:
            empty = np.zeros(element.count, dtype=prop.dtype)
            if prop.count_dtype is None:
                values[prop.name] = empty
            else:
                values[prop.name] = (np.zeros(element.count, dtype=np.int64), empty[:0])
    return values


def _build_mesh(
    vertex: _Element,
    vertex_values: _Values,
    face_list: tuple[np.ndarray, np.ndarray],
    texcoord: tuple[np.ndarray, np.ndarray] | None = None,
) -> Mesh:
    """Assemble a Mesh from the decoded vertex properties and the face list."""

    def column(name: str) -> np.ndarray:
        value = vertex_values[name]
        if isinstance(value, tuple):
            raise MeshFormatError(f"PLY vertex property {name!r} must be a scalar, not a list")
        return value

    # Filled column by column: no float64 copy of each column before the stack.
    vertices = np.empty((vertex.count, 3), dtype=np.float64)
    with np.errstate(invalid="ignore"):  # a signalling NaN: see _floats.widened
        for axis, name in enumerate("xyz"):
            vertices[:, axis] = column(name)
    attributes = {}
    if "nx" in vertex_values:
        attributes["normal"] = np.stack([column(n) for n in ("nx", "ny", "nz")], axis=1)
    for names in _COLOR_NAMES:
        present = [n for n in names if n in vertex_values]
        if len(present) >= 3:
            attributes["color"] = _colors(
                [column(n) for n in present], [_find(vertex, n).dtype for n in present]
            )
            break
    for names in _UV_NAMES:
        if all(n in vertex_values for n in names):
            attributes["uv"] = np.stack([column(n) for n in names], axis=1)
            break
    counts, items = face_list
    indices = _as_indices(items)
    faces = triangulate_polygons(counts, indices, "PLY face")
    corner_uvs = None
    if texcoord is not None:
        corner_uvs = _corner_uvs(counts, texcoord)
        in_range = faces.size and faces.min() >= 0 and faces.max() < vertices.shape[0]
        if "uv" not in attributes and in_range:
            uv = per_vertex(faces.reshape(-1), corner_uvs.reshape(-1, 2), vertices.shape[0])
            if uv is not None:
                attributes["uv"] = uv
    return Mesh(
        vertices=vertices,
        faces=faces,
        vertex_attributes={
            k: np.ascontiguousarray(v, dtype=np.float32) for k, v in attributes.items()
        },
        corner_uvs=corner_uvs,
    )


def _corner_uvs(corner_counts: np.ndarray, texcoord: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """(m, 3, 2) float32 UVs of the triangles' corners from the ``texcoord`` face
    list, which holds u v for each corner of its polygon (MeshLab's layout)."""
    uv_counts, uv_items = texcoord
    if not np.array_equal(uv_counts, 2 * np.asarray(corner_counts)):
        face = int(np.flatnonzero(uv_counts != 2 * np.asarray(corner_counts))[0])
        raise MeshFormatError(
            f"PLY face {face} has {int(corner_counts[face])} corners but "
            f"{int(uv_counts[face])} '{_TEXCOORD}' values; it needs u v per corner"
        )
    corner_uv = uv_items.astype(np.float32).reshape(-1, 2)
    return corner_uv[polygon_corners(corner_counts, "PLY face")]


def _colors(channels: list[np.ndarray], declared: list[np.dtype]) -> np.ndarray:
    """(n, 3 or 4) colours in [0, 1] from channels of their declared PLY types."""
    scaled = []
    for values, dtype in zip(channels, declared, strict=True):
        values = values.astype(np.float64)
        if dtype.kind in "iu":
            values = values / np.iinfo(dtype).max
        scaled.append(values)
    colors = np.stack(scaled, axis=1)
    if all(d.kind == "f" for d in declared) and colors.size and colors.max() > 1.0:
        # Float colours on a 0..255 scale (some exporters write them so).
        colors = colors / 255.0
    return np.clip(colors, 0.0, 1.0)


def _as_indices(items: np.ndarray) -> np.ndarray:
    """Face indices, flat and contiguous, in one copy from `items` of any layout (a
    strided (m, k) view of the file's records): int32, the type of `Mesh.faces`, when
    every value fits, which is what validation wants (no int64 copy of a scan's
    indices). Float values (ASCII, or a float list type) must be integers in int32's
    range. uint32 values of 2^31 or more are kept exactly, as int64, for validation to
    refuse naming them (no vertex count reaches them)."""
    if items.dtype.kind == "f":
        bad = ~(np.abs(items) < 2.0**31) | (items != np.floor(items))
        if bad.any():
            value = items.flat[np.flatnonzero(bad)[0]]
            raise MeshFormatError(
                f"PLY face index {float(value):g} is not an integer vertex index in int32 range"
            )
    elif items.dtype.kind == "u" and items.dtype.itemsize >= 4 and items.size:
        if items.max() > np.iinfo(np.int32).max:
            return items.astype(np.int64).reshape(-1)
    return np.ascontiguousarray(items, dtype=np.int32).reshape(-1)

"""The compact msgpack mesh form, "qem-mesh-msgpack" version 1.

One msgpack map (string keys; docs/formats.md is the reference a JavaScript viewer
decodes from):

    format          "qem-mesh-msgpack"
    version         1
    vertex_count    n
    face_count      m
    bbox            [min_x, min_y, min_z, max_x, max_y, max_z] (float64): the box of the
                    positions, or with "u16" the box of the grid (which holds them; a
                    served level uses the grid of its split stream)
    position_encoding  "f32" or "u16"
    position_bits   b, 1..16 (only with "u16")
    positions       bin: 3n little-endian values, x y z per vertex; "u16" values q are
                    on a grid over bbox: x = min_x + q * (max_x - min_x) / (2^b - 1)
    index_type      "u8" (n <= 256), "u16" (n <= 65536) or "u32"
    indices         bin: 3m little-endian values, 0-based, counter-clockwise triangles
    attributes      (optional) map name -> {"components": k, "type": "f32", "data": bin
                    of n*k little-endian float32}; names "normal", "color", "uv"
    corner_uvs      (optional) {"type": "f32", "data": bin of m*3*2 little-endian
                    float32}: u v of each face corner, face by face, in the order of
                    the indices (texture seams kept; origin bottom-left)
    texture         (optional) bin, the image bytes; texture_type its media type
    materials       (optional, a mesh of several materials, without "texture") a list of
                    2 to 256 maps {"name": str, "color": [r, g, b, a] in [0, 1] or nil,
                    "texture": bin or nil, "texture_type": its media type or nil}
    face_materials  (with "materials") bin of m uint8: the material of each face
    name            (optional) the mesh's name
    wedges          (optional) the appearance as wedges on the split stream's attribute
                    grid (a served level, so that a viewer refines it): {"grid": the
                    grid's map, "count": W, "corner_type": "u8"/"u16"/"u32", "corners":
                    bin of 3m values (the wedge of each face corner), "values": bin of
                    W*k little-endian uint16 (each wedge's k grid integers)}

Quantised positions are within half a grid step, (max - min) / (2^b - 1) / 2 per axis,
of the input; float32 positions are the input rounded to float32.
"""

from __future__ import annotations

import math

import msgpack
import numpy as np

from ..errors import InvalidOptionsError, MeshFormatError
from ..mesh import Material, Mesh, materials_from_entries
from ..quantise import AttributeGrid, Grid, QuantisedWedges
from ._floats import widened
from ._images import image_media_type

__all__ = [
    "read_msgpack",
    "read_msgpack_grid",
    "read_msgpack_wedges",
    "write_msgpack",
    "is_msgpack_mesh",
    "FORMAT_NAME",
    "VERSION",
]

FORMAT_NAME = "qem-mesh-msgpack"
VERSION = 1
_INDEX_TYPES = {"u8": np.dtype("u1"), "u16": np.dtype("<u2"), "u32": np.dtype("<u4")}
_ATTRIBUTE_WIDTHS = {"normal": (3,), "color": (3, 4), "uv": (2,)}


def is_msgpack_mesh(data: bytes) -> bool:
    """True if the data starts with a msgpack map that names this format early on."""
    is_map = data[:1] in (b"\xde", b"\xdf") or (bool(data) and 0x80 <= data[0] <= 0x8F)
    return is_map and FORMAT_NAME.encode() in data[:64]


def write_msgpack(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_attributes: dict[str, np.ndarray],
    texture: bytes | None = None,
    corner_uvs: np.ndarray | None = None,
    *,
    quantize_bits: int | None = None,
    grid_box: tuple[np.ndarray, np.ndarray] | None = None,
    name: str | None = None,
    wedges: QuantisedWedges | None = None,
    materials: list[Material] | None = None,
    face_materials: np.ndarray | None = None,
) -> bytes:
    """Encode in the msgpack form; `quantize_bits` None gives float32 positions, 1..16
    gives uint16 grid positions of that many bits, over `grid_box` (low, high) when
    given (it must hold every vertex), else over the vertices' bounding box. `wedges`:
    the level's wedges on the split stream's attribute grid."""
    n_vertices = vertices.shape[0]
    if grid_box is not None:
        low, high = (np.asarray(corner, np.float64).reshape(3) for corner in grid_box)
        if n_vertices and (np.any(vertices < low) or np.any(vertices > high)):
            raise InvalidOptionsError("grid_box must contain every vertex")
    else:
        low = vertices.min(axis=0) if n_vertices else np.zeros(3)
        high = vertices.max(axis=0) if n_vertices else np.zeros(3)
    message: dict = {
        "format": FORMAT_NAME,
        "version": VERSION,
        "vertex_count": n_vertices,
        "face_count": int(faces.shape[0]),
        "bbox": [float(x) for x in (*low, *high)],
    }
    if quantize_bits is None:
        message["position_encoding"] = "f32"
        message["positions"] = vertices.astype("<f4").tobytes()
    else:
        if not (_is_integer(quantize_bits) and quantize_bits in range(1, 17)):
            raise InvalidOptionsError(
                f"quantize_bits={quantize_bits!r}: use None (float32) or 1..16 (16 is usual)"
            )
        grid = Grid.over_box(low, high, quantize_bits)
        message["position_encoding"] = "u16"
        message["position_bits"] = quantize_bits
        message["positions"] = grid.quantise(vertices).astype("<u2").tobytes()
    index_type = _index_type(n_vertices)
    message["index_type"] = index_type
    message["indices"] = faces.astype(_INDEX_TYPES[index_type]).tobytes()
    if vertex_attributes:
        message["attributes"] = {
            key: {
                "components": int(values.shape[1]),
                "type": "f32",
                "data": values.astype("<f4").tobytes(),
            }
            for key, values in sorted(vertex_attributes.items())
        }
    if corner_uvs is not None:
        message["corner_uvs"] = {"type": "f32", "data": corner_uvs.astype("<f4").tobytes()}
    if texture is not None:
        message["texture"] = bytes(texture)
        message["texture_type"] = image_media_type(texture) or "application/octet-stream"
    if materials is not None and face_materials is not None:
        message["materials"] = [
            {"name": m.name, "color": None if m.color is None else [float(c) for c in m.color],
             "texture": m.texture, "texture_type": m.texture and image_media_type(m.texture)}
            for m in materials
        ]  # fmt: skip
        message["face_materials"] = face_materials.astype(np.uint8).tobytes()
    if name is not None:
        message["name"] = str(name)
    if wedges is not None:
        corner_type = _index_type(wedges.values.shape[0])
        message["wedges"] = {
            "grid": wedges.grid.to_dict(),
            "count": int(wedges.values.shape[0]),
            "corner_type": corner_type,
            "corners": wedges.face_wedges.astype(_INDEX_TYPES[corner_type]).tobytes(),
            "values": wedges.values.astype("<u2").tobytes(),
        }
    return msgpack.packb(message, use_bin_type=True)


def read_msgpack_grid(data: bytes) -> Grid | None:
    """The position grid of a msgpack mesh with "u16" positions (None for "f32"): the
    grid a split stream refining the level must use. Raises MeshFormatError as
    `read_msgpack` does."""
    return _position_grid(_message(data))


def _position_grid(message: dict) -> Grid | None:
    """The grid of "u16" positions, None for "f32", after checking ``bbox`` (a box whose
    min passes its max on an axis, or whose span float64 cannot step over, would put the
    positions elsewhere or at infinity)."""
    bbox = message.get("bbox")
    if (
        not isinstance(bbox, list)
        or len(bbox) != 6
        or not all((_is_integer(x) or isinstance(x, float)) and math.isfinite(x) for x in bbox)
    ):
        raise MeshFormatError("'bbox' must be 6 finite numbers: min x y z, max x y z")
    low, high = np.asarray(bbox[:3], np.float64), np.asarray(bbox[3:], np.float64)
    if (low > high).any():
        raise MeshFormatError(f"'bbox' {bbox}: a min is above its max (min x y z, max x y z)")
    encoding = message.get("position_encoding")
    if encoding == "f32":
        return None
    if encoding != "u16":
        raise MeshFormatError(f"'position_encoding' must be 'f32' or 'u16', got {encoding!r}")
    bits = message.get("position_bits")
    if not (_is_integer(bits) and bits in range(1, 17)):
        raise MeshFormatError(f"'position_bits' must be 1..16, got {bits!r}")
    try:
        return Grid.over_box(low, high, bits).check()
    except ValueError:
        raise MeshFormatError(f"'bbox' {bbox} spans more than float64 can hold") from None


def read_msgpack_wedges(data: bytes) -> QuantisedWedges | None:
    """The ``wedges`` entry of a msgpack mesh (None if it has none). Raises
    MeshFormatError naming the bad field; the mesh itself is read by `read_msgpack`."""
    message = _message(data)
    entry = message.get("wedges")
    if entry is None:
        return None
    if not isinstance(entry, dict):
        raise MeshFormatError("'wedges' must be a map")
    try:
        grid = AttributeGrid.from_dict(entry.get("grid"))
    except (TypeError, KeyError, ValueError, AttributeError) as error:
        raise MeshFormatError(f"'wedges' has no valid 'grid': {error}") from None
    count = _count(entry, "count")
    corner_dtype = _index_dtype(entry, "corner_type")
    n_faces = _count(message, "face_count")
    corners = _array(entry, "corners", corner_dtype, 3 * n_faces)
    if corners.size and int(corners.max()) >= count:
        raise MeshFormatError(f"'wedges' corners name a wedge beyond its count {count}")
    k = int(sum(grid.widths))
    values = _array(entry, "values", "<u2", count * k).astype(np.int64).reshape(count, k)
    if np.any(values > grid.q_max):
        raise MeshFormatError("'wedges' values lie outside their grid")
    return QuantisedWedges(grid, corners.astype(np.int32).reshape(-1, 3), values)


def read_msgpack(data: bytes) -> Mesh:
    """Decode the msgpack form. Raises MeshFormatError naming the bad field."""
    message = _message(data)
    n_vertices = _count(message, "vertex_count")
    n_faces = _count(message, "face_count")
    grid = _position_grid(message)
    if grid is None:
        vertices = widened(_array(message, "positions", "<f4", n_vertices * 3))
    else:
        quantised = _array(message, "positions", "<u2", n_vertices * 3).reshape(-1, 3)
        if quantised.size and int(quantised.max()) >= 1 << grid.bits:
            raise MeshFormatError(
                f"'positions' hold {int(quantised.max())}, past the {grid.bits}-bit grid"
            )
        vertices = grid.dequantise(quantised)
    index_dtype = _index_dtype(message, "index_type")
    faces = _array(message, "indices", index_dtype, n_faces * 3).astype(np.int64)
    if faces.size and int(faces.max()) >= n_vertices:
        raise MeshFormatError(
            f"'indices' name vertex {int(faces.max())}, but 'vertex_count' is {n_vertices}"
        )
    attribute_map = message.get("attributes") or {}
    if not isinstance(attribute_map, dict):
        raise MeshFormatError("'attributes' must be a map of name to attribute")
    attributes = {}
    for key, entry in attribute_map.items():
        if key not in _ATTRIBUTE_WIDTHS or not isinstance(entry, dict):
            raise MeshFormatError(f"unknown attribute {key!r}; known: {sorted(_ATTRIBUTE_WIDTHS)}")
        width = entry.get("components")
        if not (_is_integer(width) and width in _ATTRIBUTE_WIDTHS[key]) or (
            entry.get("type") != "f32"
        ):
            raise MeshFormatError(
                f"attribute {key!r} must be f32 with {_ATTRIBUTE_WIDTHS[key]} components"
            )
        attributes[key] = _array(entry, "data", "<f4", n_vertices * width).reshape(-1, width)
    corner_uvs = None
    entry = message.get("corner_uvs")
    if entry is not None:
        if not isinstance(entry, dict) or entry.get("type") != "f32":
            raise MeshFormatError("'corner_uvs' must be a map {'type': 'f32', 'data': bin}")
        corner_uvs = _array(entry, "data", "<f4", n_faces * 6).reshape(-1, 3, 2)
    texture = message.get("texture")
    if texture is not None and not isinstance(texture, bytes):
        raise MeshFormatError("'texture' must be bin (the image bytes)")
    name = message.get("name")
    materials, face_materials = _materials(message, n_faces)
    return Mesh(
        vertices=vertices.reshape(-1, 3),
        faces=faces.reshape(-1, 3),
        vertex_attributes={k: v.astype(np.float32) for k, v in attributes.items()},
        corner_uvs=None if corner_uvs is None else corner_uvs.astype(np.float32),
        texture=texture,
        name=name if isinstance(name, str) else None,
        materials=materials,
        face_materials=face_materials,
    )


def _materials(message: dict, n_faces: int) -> tuple[list[Material] | None, np.ndarray | None]:
    """The "materials" list and "face_materials" of a message, checked; (None, None)
    without them."""
    entries = message.get("materials")
    if entries is None:
        return None, None

    def image_of(i: int, entry: dict) -> bytes | None:
        texture = entry.get("texture")
        if texture is not None and not isinstance(texture, bytes):
            raise MeshFormatError(f"'materials': material {i}'s 'texture' must be bin or nil")
        return texture

    materials = materials_from_entries(entries, image_of, MeshFormatError, "'materials'")
    which = _array(message, "face_materials", "u1", n_faces)
    if which.size and int(which.max()) >= len(materials):
        raise MeshFormatError(f"'face_materials' name a material beyond the {len(materials)}")
    return materials, which.astype(np.int32)


def _message(data: bytes) -> dict:
    """The message's map, its format and version checked."""
    try:
        message = msgpack.unpackb(data, raw=False, strict_map_key=True)
    except (ValueError, TypeError, msgpack.UnpackException) as error:
        raise MeshFormatError(f"not a valid msgpack message: {error}") from None
    if not isinstance(message, dict) or message.get("format") != FORMAT_NAME:
        raise MeshFormatError(f"msgpack message is not a {FORMAT_NAME!r} map")
    version = message.get("version")
    if version != VERSION:
        raise MeshFormatError(
            f"{FORMAT_NAME} version {version!r} is not supported (this reader reads "
            f"version {VERSION}); upgrade qem-lod to read newer files"
        )
    return message


def _index_type(n_vertices: int) -> str:
    if n_vertices <= 1 << 8:
        return "u8"
    if n_vertices <= 1 << 16:
        return "u16"
    return "u32"


def _index_dtype(entry: dict, key: str) -> np.dtype:
    """The numpy type an index type field ("u8", "u16", "u32") names."""
    name = entry.get(key)
    if not isinstance(name, str) or name not in _INDEX_TYPES:  # a list or map: unhashable
        raise MeshFormatError(f"'{key}' must be one of {list(_INDEX_TYPES)}")
    return _INDEX_TYPES[name]


def _is_integer(value: object) -> bool:
    """An int that is not a bool. ``in range(...)`` alone would take 8.0 (8.0 == 8), which
    then breaks a bit shift or a reshape (TypeError); msgpack's true would pass as 1."""
    return isinstance(value, int) and not isinstance(value, bool)


def _count(message: dict, key: str) -> int:
    value = message.get(key)
    if not _is_integer(value) or value < 0:
        raise MeshFormatError(f"{key!r} must be a non-negative integer, got {value!r}")
    return value


def _array(message: dict, key: str, dtype: str | np.dtype, n_values: int) -> np.ndarray:
    """A bin field as n_values of dtype; its length must match exactly."""
    data = message.get(key)
    if not isinstance(data, bytes):
        raise MeshFormatError(f"{key!r} must be bin (raw bytes)")
    dtype = np.dtype(dtype)
    if len(data) != n_values * dtype.itemsize:
        raise MeshFormatError(
            f"{key!r} holds {len(data)} bytes, but the counts need {n_values} values of "
            f"{dtype.itemsize} bytes ({n_values * dtype.itemsize}): the message is damaged"
        )
    return np.frombuffer(data, dtype=dtype)

"""The .qpm file: one progressive mesh, versioned, loaded in O(size).

Layout (little-endian)::

    magic    8 bytes  b"QEMPM\\x00\\r\\n"  (the CR LF catches text-mode mangling)
    version  uint32   FORMAT_VERSION
    length   uint32   byte length of the header
    header   msgpack  {"arrays": [[name, dtype, shape, offset], ...], "metadata": {...}}
    arrays   raw C-order bytes, each at an 8-byte aligned offset from the data start
    crc32    uint32   of every byte before it

Version 2 adds optional arrays: the wedge arrays of a mesh built with appearance
attributes (`progressive.WEDGE_ARRAYS`, all or none) and the texture image bytes. A file
without them is written as version 1, so older readers keep reading it. Version 3 adds
the materials of a mesh of several: their images one after another in
``material_images``, and in the metadata ``materials``, one map each (name, colour, and
the [offset, length] of its image); only such a file is written as version 3.

A file from a newer version, a wrong checksum, or arrays that do not form a consistent
progressive mesh raise CorruptFileError. docs/formats.md documents the format.
"""

from __future__ import annotations

import math
import os
import struct
import tempfile
import zlib
from pathlib import Path
from typing import NoReturn

import msgpack
import numpy as np

from .errors import CorruptFileError
from .mesh import Material, materials_from_entries
from .progressive import WEDGE_ARRAYS, ProgressiveMesh, check_splits, check_wedge_arrays
from .split_checks import decreases

__all__ = ["FORMAT_VERSION", "MAGIC", "load", "save_qpm"]

MAGIC = b"QEMPM\x00\r\n"
FORMAT_VERSION = 3

# name -> (dtype, number of dimensions); the order is the order in the file.
_ARRAYS = {
    "base_vertices": ("<f8", 2),
    "split_vertex": ("<i4", 1),
    "split_positions": ("<f8", 3),
    "face_corners": ("<i4", 2),
    "level_faces": ("<i8", 1),
    "relabel_offsets": ("<i8", 1),
    "relabel_faces": ("<i4", 1),
    "split_cost": ("<f8", 1),
    "vertex_map": ("<i4", 1),
}
_WEDGE_DTYPES = {
    "base_wedge_values": ("<f4", 2), "face_wedge_corners": ("<i4", 2),
    "wedge_update_offsets": ("<i8", 1), "wedge_update_ids": ("<i4", 1),
    "wedge_update_values": ("<f4", 2), "wedge_new_offsets": ("<i8", 1),
    "wedge_new_values": ("<f4", 2), "wedge_relabel_offsets": ("<i8", 1),
    "wedge_relabel_corners": ("<i8", 1), "wedge_relabel_to": ("<i4", 1),
}  # fmt: skip
assert tuple(_WEDGE_DTYPES) == WEDGE_ARRAYS
_OPTIONAL_ARRAYS = {**_WEDGE_DTYPES, "texture": ("|u1", 1), "material_images": ("|u1", 1)}


def save_qpm(pm: ProgressiveMesh, path) -> None:
    """Write ``pm`` to ``path`` atomically (temporary file, then rename)."""
    entries, chunks, offset = [], [], 0
    optional = dict(pm.wedge_arrays)
    if pm.texture is not None:
        optional["texture"] = np.frombuffer(pm.texture, np.uint8)
    metadata = pm.metadata
    if pm.materials is not None:
        images, entries_of_materials, at = [], [], 0
        for material in pm.materials:
            image = None
            if material.texture is not None:
                image = [at, len(material.texture)]
                images.append(material.texture)
                at += len(material.texture)
            entries_of_materials.append({
                "name": material.name, "image": image,
                "color": None if material.color is None else [float(c) for c in material.color],
            })  # fmt: skip
        optional["material_images"] = np.frombuffer(b"".join(images), np.uint8)
        metadata = {**metadata, "materials": entries_of_materials}
    for name, (dtype, _ndim) in {**_ARRAYS, **_OPTIONAL_ARRAYS}.items():
        array = optional.get(name) if name in _OPTIONAL_ARRAYS else getattr(pm, name, None)
        if array is None:
            if name in _OPTIONAL_ARRAYS:
                continue
            array = np.zeros(0, dtype)
        # Written from the arrays themselves (a copy only where the dtype or layout
        # differs): building the file in memory first cost five copies of it, about
        # 0.15 s of CPU for dragon's 50 MB and peak memory for a big scan.
        data = memoryview(np.ascontiguousarray(array, dtype=dtype).reshape(-1).view(np.uint8))
        entries.append([name, dtype, list(np.shape(array)), offset])
        padding = -len(data) % 8
        chunks += [data, b"\0" * padding]
        offset += len(data) + padding
    header = msgpack.packb({"arrays": entries, "metadata": metadata})
    version = 3 if pm.materials is not None else 2 if optional else 1
    chunks.insert(0, MAGIC + struct.pack("<II", version, len(header)) + header)
    path = Path(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent or ".", prefix=path.name, suffix=".tmp")
    try:
        with os.fdopen(fd, "wb") as out:
            crc = 0
            for chunk in chunks:
                crc = zlib.crc32(chunk, crc)
                out.write(chunk)
            out.write(struct.pack("<I", crc))
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def load(source) -> ProgressiveMesh:
    """Read a .qpm file (a path or the file's bytes)."""
    blob = (
        source if isinstance(source, bytes | bytearray | memoryview) else Path(source).read_bytes()
    )
    blob = bytes(blob)
    fixed = len(MAGIC) + 8
    if len(blob) < fixed + 4 or blob[: len(MAGIC)] != MAGIC:
        raise CorruptFileError("not a .qpm file (bad magic bytes)")
    version, header_length = struct.unpack_from("<II", blob, len(MAGIC))
    if version > FORMAT_VERSION:
        raise CorruptFileError(
            f".qpm version {version} is newer than this qem-lod reads ({FORMAT_VERSION}); "
            "upgrade qem-lod"
        )
    if version < 1:
        raise CorruptFileError(f".qpm version {version} is not valid")
    (stored_crc,) = struct.unpack_from("<I", blob, len(blob) - 4)
    if zlib.crc32(blob[:-4]) != stored_crc:
        raise CorruptFileError(".qpm checksum mismatch: the file is damaged or truncated")
    if header_length > len(blob) - 4 - fixed:
        raise CorruptFileError(
            f".qpm header length {header_length} runs past the end of the file ({len(blob)} bytes)"
        )
    try:
        header = msgpack.unpackb(blob[fixed : fixed + header_length])
    except Exception as exc:  # msgpack raises several unrelated types (its docs say so)
        raise CorruptFileError(f".qpm header is unreadable: {exc}") from None
    entries, metadata = _header_fields(header)
    data_start = fixed + header_length
    data_length = len(blob) - 4 - data_start
    arrays = {}
    for name, (dtype, ndim) in {**_ARRAYS, **_OPTIONAL_ARRAYS}.items():
        if name not in entries:
            if name in _OPTIONAL_ARRAYS:
                continue
            raise CorruptFileError(f".qpm file lacks the array {name!r}")
        stored_dtype, shape, offset = _array_entry(name, entries[name])
        if stored_dtype != dtype or len(shape) != ndim:
            raise CorruptFileError(
                f".qpm array {name!r} has dtype {stored_dtype!r:.40} shape {shape!r:.80}, "
                f"expected {dtype!r} with {ndim} dimensions"
            )
        # Python integers: a huge declared shape must not wrap around in int64.
        nbytes = math.prod(shape) * np.dtype(dtype).itemsize
        if not 0 <= offset <= data_length - nbytes:
            raise CorruptFileError(f".qpm array {name!r} lies outside the file")
        arrays[name] = np.frombuffer(
            blob,
            dtype=dtype,
            count=nbytes // np.dtype(dtype).itemsize,
            offset=data_start + offset,
        ).reshape(shape)
    return _checked_progressive_mesh(arrays, metadata)


def _header_fields(header) -> tuple[dict, object]:
    """(name -> [dtype, shape, offset], metadata) of a decoded header: a map with an
    ``arrays`` list of entries led by distinct names, and a ``metadata`` (checked later)."""
    if not isinstance(header, dict) or "arrays" not in header or "metadata" not in header:
        raise CorruptFileError(".qpm header is unreadable: not a map of 'arrays' and 'metadata'")
    if not isinstance(header["arrays"], list):
        raise CorruptFileError(
            f".qpm header is unreadable: 'arrays' is {type(header['arrays']).__name__}, not a list"
        )
    entries = {}
    for entry in header["arrays"]:
        # The name is a key: a list there would be unhashable, and a repeated name would
        # leave which of its arrays is meant to the reader.
        if not isinstance(entry, list) or not entry or not isinstance(entry[0], str):
            raise CorruptFileError(f".qpm header has an array entry without a name: {entry!r:.80}")
        if entry[0] in entries:
            raise CorruptFileError(f".qpm header names the array {entry[0]!r:.80} twice")
        entries[entry[0]] = entry[1:]
    return entries, header["metadata"]


def _array_entry(name: str, entry) -> tuple[object, tuple[int, ...], int]:
    """(dtype, shape, offset) of a header entry; a malformed one (wrong length, a shape
    that is not non-negative integers or holds too many elements, an offset that is not
    an integer) would otherwise escape as ValueError or TypeError, so it is refused here,
    naming the field and its value."""

    def malformed(what: str) -> NoReturn:
        raise CorruptFileError(f".qpm array {name!r} has a malformed header entry: {what}")

    if len(entry) != 3:
        malformed(f"{len(entry)} fields after the name, not 3 (dtype, shape, offset)")
    shape, offset = entry[1], entry[2]
    if not isinstance(shape, list) or not all(_is_size(s) for s in shape):
        malformed(f"shape {shape!r:.80} is not a list of integers in [0, 2^48]")
    # numpy refuses a shape whose element count (its zero dimensions aside) passes int64,
    # even for 0 bytes ([2^48, 2^48, 0]); no real array comes near 2^48 elements.
    if math.prod(max(s, 1) for s in shape) > _SIZE_LIMIT:
        malformed(f"shape {shape!r:.80} has more than 2^48 elements")
    if not _is_size(offset):
        malformed(f"offset {offset!r:.80} is not an integer in [0, 2^48]")
    return entry[0], tuple(shape), offset


_SIZE_LIMIT = 1 << 48


def _is_size(value) -> bool:
    """A plain integer (not a bool, which is one to Python) in [0, 2^48]: no dimension or
    offset of a real file is larger."""
    return isinstance(value, int) and not isinstance(value, bool) and 0 <= value <= _SIZE_LIMIT


def _is_coordinate(value) -> bool:
    """A float or an integer, not a bool (msgpack's integers all fit float64)."""
    return isinstance(value, int | float) and not isinstance(value, bool)


def _checked_progressive_mesh(arrays: dict, metadata: dict) -> ProgressiveMesh:
    base, k = arrays["base_vertices"], arrays["split_vertex"].shape[0]
    level_faces = arrays["level_faces"]
    if base.shape[1:] != (3,) or arrays["split_positions"].shape != (k, 2, 3):
        raise CorruptFileError(".qpm vertex arrays have inconsistent shapes")
    # The positions' box (the stream's grid, quantised levels) needs one position; the
    # build refuses a mesh without faces.
    if base.shape[0] == 0:
        raise CorruptFileError(".qpm base mesh has no vertices")
    if level_faces.shape != (k + 1,) or arrays["split_cost"].shape != (k,):
        raise CorruptFileError(".qpm level arrays have inconsistent shapes")
    # Compared, not differenced: np.diff wraps around in int64 (see decreases).
    if level_faces[-1] != arrays["face_corners"].shape[0] or decreases(level_faces):
        raise CorruptFileError(".qpm face counts per level are inconsistent")
    if level_faces[0] < 0:
        raise CorruptFileError(".qpm base face count is negative")
    # Positions feed the stream's grid and the level files: a NaN or inf there would
    # reach the encoders as integers past any grid (and once kept one spinning).
    for name in ("base_vertices", "split_positions"):
        if not np.isfinite(arrays[name]).all():
            raise CorruptFileError(f".qpm {name} holds a non-finite coordinate")
    if np.isnan(arrays["split_cost"]).any():
        raise CorruptFileError(".qpm split costs hold a NaN")
    base_faces = arrays["face_corners"][: level_faces[0]]
    if base_faces.size and (base_faces.min() < 0 or base_faces.max() >= base.shape[0]):
        raise CorruptFileError(".qpm base faces use vertices outside the base mesh")
    check_splits(
        base.shape[0],
        int(level_faces[0]),
        arrays["split_vertex"],
        arrays["face_corners"][level_faces[0] :],
        np.diff(level_faces),
        arrays["relabel_offsets"],
        arrays["relabel_faces"],
    )
    # A metadata that is not a map, or a bbox that is not 2 x 3 numbers, would fail later
    # (in ProgressiveMesh or pm.bbox) with an unrelated error.
    if not isinstance(metadata, dict) or "bbox" not in metadata:
        raise CorruptFileError(".qpm metadata lacks the bounding box")
    box = metadata["bbox"]
    # Plain numbers only: numpy would read "1", b"1" or True as a number.
    if not (
        isinstance(box, list)
        and len(box) == 2
        and all(isinstance(corner, list) and len(corner) == 3 for corner in box)
        and all(_is_coordinate(x) for corner in box for x in corner)
    ):
        raise CorruptFileError(f".qpm bounding box {box!r:.120} is not 2 x 3 numbers")
    bbox = np.array(box, np.float64)
    if not np.isfinite(bbox).all():
        raise CorruptFileError(f".qpm bounding box {box!r:.120} holds a non-finite number")
    # The box goes out as is (the static export's manifest, a viewer's camera): the
    # build's box has its min corner at or below its max.
    if (bbox[0] > bbox[1]).any():
        raise CorruptFileError(f".qpm bounding box {box!r:.120} has min above max")
    # Each level carries the name (lod_mesh), and the build writes a string or nothing.
    mesh_name = metadata.get("name")
    if mesh_name is not None and not isinstance(mesh_name, str):
        raise CorruptFileError(f".qpm metadata name {mesh_name!r:.80} is not a string")
    vertex_map = arrays.pop("vertex_map")
    texture = arrays.pop("texture", None)
    materials = _materials(arrays.pop("material_images", None), metadata.pop("materials", None))
    if any(name in arrays for name in WEDGE_ARRAYS):
        if not all(name in arrays for name in WEDGE_ARRAYS):
            raise CorruptFileError(".qpm file has some of the wedge arrays but not all")
        check_wedge_arrays(arrays, level_faces, metadata.get("attributes"))
    pm = ProgressiveMesh(
        **arrays, metadata=metadata, texture=None if texture is None else texture.tobytes(),
        materials=materials,
    )
    _check_face_materials(pm)
    pm.vertex_map = vertex_map
    # The stream's grid spans every position (stream.grid_for): finite positions from
    # -1e308 to 1e308 would put its far corner, and the offsets it quantises, at infinity.
    low, high = pm.position_bounds
    with np.errstate(over="ignore"):
        span = high - low
    if not np.isfinite(span).all():
        raise CorruptFileError(
            f".qpm positions span {low.tolist()} to {high.tolist()}, wider than float64 holds"
        )
    # The index checks above cannot see a relabelled face without a corner at its split's
    # vertex, which would serve wrong levels and stop the stream's encoder: one replay of
    # every split (milliseconds; the server keeps loaded meshes) finds it.
    pm.lod(pm.n_full)
    return pm


def _materials(images: np.ndarray | None, entries: object) -> list[Material] | None:
    """The materials a version 3 file lists, checked; None for a file without them."""
    if images is None and entries is None:
        return None
    if (images is None) != (entries is None):
        raise CorruptFileError(".qpm has material images without their list, or the reverse")

    def image_of(i: int, entry: dict) -> bytes | None:
        image = entry.get("image")
        if image is None:
            return None
        if not (isinstance(image, list) and len(image) == 2 and all(map(_is_size, image))
                and image[0] + image[1] <= images.size):  # fmt: skip
            raise CorruptFileError(
                f".qpm material {i}'s image {image!r:.80} lies outside the material images"
            )
        return images[image[0] : image[0] + image[1]].tobytes()

    return materials_from_entries(entries, image_of, CorruptFileError, ".qpm materials")


def _check_face_materials(pm: ProgressiveMesh) -> None:
    """Materials and the wedges' material values come together, and every value names a
    listed material (a level's faces index the list with them)."""
    layout = pm.attribute_layout
    column = -1 if layout is None else layout.offset("material")
    if (column >= 0) != (pm.materials is not None):
        raise CorruptFileError(".qpm has materials without a material wedge value, or the reverse")
    if column < 0:
        return
    w = pm.wedge_arrays
    scale = np.float32(layout.scales[column])
    for name in ("base_wedge_values", "wedge_update_values", "wedge_new_values"):
        values = np.rint(w[name][:, column] / scale)
        if values.size and not (values.min() >= 0 and values.max() < len(pm.materials)):
            raise CorruptFileError(f".qpm {name} name a material beyond the "
                                   f"{len(pm.materials)} listed")

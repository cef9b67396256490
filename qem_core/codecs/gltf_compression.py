"""Compressed glTF, decoded into the plain document the glTF reader reads.

- EXT_meshopt_compression (gltfpack -cc): each compressed bufferView is decoded by
  meshoptimizer's own decoders (vertex and index codecs, and the octahedral, quaternion
  and exponential filters) into a new buffer, and the view points at it. Its fallback
  buffer, which holds nothing, reads as empty.
- KHR_draco_mesh_compression (gltf-transform draco): each compressed primitive is
  decoded by Draco (DracoPy) and its attributes and indices become new float32 and
  uint32 accessors, the primitive then an ordinary one.

A parser's word is not trusted: counts and sizes are checked against the compressed
bytes before anything is allocated, decoded attribute widths against their accessors,
decoded indices against the decoded vertex count (by the reader, as for any file). A
document is copied before it is changed; the caller's stays as it was.
"""

from __future__ import annotations

import copy

import numpy as np

from ..errors import MeshFormatError

__all__ = ["INDEX_SIZE", "decompressed", "extension"]

# Set on a view decoded from meshopt's index codec: the byte size of its indices.
INDEX_SIZE = "qem_decoded_index_size"

_MESHOPT = "EXT_meshopt_compression"
_DRACO = "KHR_draco_mesh_compression"
# The vertex codec stores at least one byte a vertex column block; this bounds what a
# view may decode to, so that a declared count cannot allocate without end.
_MAX_EXPANSION = 256
_SLACK = 1 << 20


def extension(item: object, name: str) -> dict | None:
    """``item["extensions"][name]`` (None when absent); MeshFormatError when the glTF
    object, its ``extensions`` or the extension is not a JSON object."""
    extensions = item.get("extensions") if isinstance(item, dict) else None
    if extensions is None:
        if not isinstance(item, dict):
            raise MeshFormatError(f"a glTF object holding {name} is not a JSON object")
        return None
    found = extensions.get(name) if isinstance(extensions, dict) else ()
    if found is not None and not isinstance(found, dict):
        raise MeshFormatError(f"glTF {name} (or the extensions holding it) is not an object")
    return found


def decompressed(gltf: dict, buffers: list[bytes]) -> tuple[dict, list[bytes]]:
    """``gltf`` and its buffers with every compressed view and primitive decoded (the
    same objects when nothing is compressed)."""
    used = {*(gltf.get("extensionsUsed") or []), *(gltf.get("extensionsRequired") or [])}
    if _MESHOPT not in used and _DRACO not in used:
        return gltf, buffers
    gltf = copy.deepcopy(gltf)
    buffers = list(buffers)
    if _MESHOPT in used:
        _decode_meshopt_views(gltf, buffers)
    if _DRACO in used:
        _decode_draco_primitives(gltf, buffers)
    return gltf, buffers


def _decode_meshopt_views(gltf: dict, buffers: list[bytes]) -> None:
    import meshoptimizer

    for index, view in enumerate(gltf.get("bufferViews", [])):
        ext = extension(view, _MESHOPT)
        if ext is None:
            continue
        what = f"{_MESHOPT} bufferView {index}"
        source = _slice(buffers, ext, what)
        count, stride = _size(ext, "count", what), _size(ext, "byteStride", what)
        mode, filter_ = ext.get("mode"), ext.get("filter", "NONE")
        if count * stride > _MAX_EXPANSION * len(source) + _SLACK:
            raise MeshFormatError(f"{what} declares {count} x {stride} bytes from "
                                  f"{len(source)}: more than any file decodes to")  # fmt: skip
        try:
            if mode == "ATTRIBUTES":
                if stride % 4 or not 0 < stride <= 256:
                    raise MeshFormatError(f"{what}: byteStride {stride}, not 4..256 by 4")
                raw = meshoptimizer.decode_vertex_buffer(
                    count, stride, source, np.dtype(f"V{stride}")
                )
                raw = np.frombuffer(raw.tobytes(), np.uint8)
                raw = _filtered(meshoptimizer, raw, filter_, count, stride, what)
            elif mode in ("TRIANGLES", "INDICES") and stride in (2, 4):
                decode = (meshoptimizer.decode_index_buffer if mode == "TRIANGLES"
                          else meshoptimizer.decode_index_sequence)  # fmt: skip
                indices = np.asarray(decode(count, stride, source))
                raw = indices.astype("<u2" if stride == 2 else "<u4")
            else:
                raise MeshFormatError(f"{what}: mode {mode!r} with byteStride {stride}")
        except (RuntimeError, ValueError) as error:
            if isinstance(error, MeshFormatError):
                raise
            raise MeshFormatError(f"{what} does not decode: {error}") from None
        buffers.append(np.ascontiguousarray(raw).tobytes())
        view.pop("extensions", None)
        view.update(buffer=len(buffers) - 1, byteOffset=0, byteLength=count * stride)
        if mode == "ATTRIBUTES":
            view["byteStride"] = stride
        else:  # an accessor must read these indices at the size they were decoded to
            view.pop("byteStride", None)
            view[INDEX_SIZE] = stride


def _filtered(meshoptimizer, raw: np.ndarray, filter_: str, count: int, stride: int, what):
    if filter_ == "NONE":
        return raw
    decode = {"OCTAHEDRAL": meshoptimizer.decode_filter_oct,
              "QUATERNION": meshoptimizer.decode_filter_quat,
              "EXPONENTIAL": meshoptimizer.decode_filter_exp}.get(filter_)  # fmt: skip
    if decode is None:
        raise MeshFormatError(f"{what}: unknown filter {filter_!r}")
    return np.frombuffer(np.asarray(decode(raw, count, stride)).tobytes(), np.uint8)


def _decode_draco_primitives(gltf: dict, buffers: list[bytes]) -> None:
    import DracoPy

    accessors = gltf.setdefault("accessors", [])
    views = gltf.setdefault("bufferViews", [])
    for mesh_number, mesh in enumerate(gltf.get("meshes", [])):
        for primitive in mesh.get("primitives", []):
            ext = extension(primitive, _DRACO)
            if ext is None:
                continue
            what = f"{_DRACO} of mesh {mesh_number}"
            view = _checked_view(gltf, ext.get("bufferView"), what)
            data = _slice(buffers, view, what)
            try:
                decoded = DracoPy.decode(data)
            except Exception as error:  # the Cython binding raises several kinds
                raise MeshFormatError(f"{what} does not decode: {error}") from None
            by_id = {a["unique_id"]: a for a in getattr(decoded, "attributes", [])}
            for semantic, unique_id in (ext.get("attributes") or {}).items():
                if semantic not in primitive.get("attributes", {}) or unique_id not in by_id:
                    continue  # an attribute the primitive does not name, or Draco lacks
                values = np.asarray(by_id[unique_id]["data"], np.float64)
                if values.ndim == 1:
                    values = values[:, None]
                accessor = dict(_checked_accessor(gltf, primitive["attributes"][semantic], what))
                if accessor.get("normalized") and accessor.get("componentType") in _NORMS:
                    values = values / _NORMS[accessor["componentType"]]
                primitive["attributes"][semantic] = _append(
                    accessors, views, buffers, values.astype("<f4"), 5126, accessor["type"]
                )
            faces = np.asarray(decoded.faces, np.int64).reshape(-1)
            if faces.size and faces.min() < 0:
                raise MeshFormatError(f"{what}: a decoded index is negative")
            primitive["indices"] = _append(
                accessors, views, buffers, faces.astype("<u4"), 5125, "SCALAR"
            )
            del primitive["extensions"][_DRACO]


_NORMS = {5121: 255.0, 5123: 65535.0, 5120: 127.0, 5122: 32767.0}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def _append(accessors, views, buffers, values: np.ndarray, component: int, kind: str) -> int:
    """A new accessor (and view and buffer) of ``values``; its index."""
    width = _WIDTHS.get(kind)
    if width is None or values.size % width:
        raise MeshFormatError(f"{_DRACO}: decoded values do not fit accessor type {kind!r}")
    if values.ndim == 2 and values.shape[1] != width:
        raise MeshFormatError(
            f"{_DRACO}: {values.shape[1]} decoded components for an accessor of type {kind!r}"
        )
    buffers.append(np.ascontiguousarray(values).tobytes())
    views.append({"buffer": len(buffers) - 1, "byteOffset": 0, "byteLength": len(buffers[-1])})
    accessors.append({"bufferView": len(views) - 1, "componentType": component,
                      "count": values.size // width, "type": kind})  # fmt: skip
    return len(accessors) - 1


def _checked_view(gltf: dict, index: object, what: str) -> dict:
    views = gltf.get("bufferViews", [])
    if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(views):
        raise MeshFormatError(f"{what} names bufferView {index!r}, which does not exist")
    return views[index]


def _checked_accessor(gltf: dict, index: object, what: str) -> dict:
    accessors = gltf.get("accessors", [])
    if not isinstance(index, int) or isinstance(index, bool) or not 0 <= index < len(accessors):
        raise MeshFormatError(f"{what} names accessor {index!r}, which does not exist")
    return accessors[index]


def _slice(buffers: list[bytes], item: dict, what: str) -> bytes:
    """The bytes ``item`` (a view, or a meshopt extension) names in ``buffers``."""
    number = item.get("buffer")
    if not isinstance(number, int) or isinstance(number, bool) or not 0 <= number < len(buffers):
        raise MeshFormatError(f"{what} names buffer {number!r}, which does not exist")
    start, length = _size(item, "byteOffset", what, 0), _size(item, "byteLength", what)
    if start + length > len(buffers[number]):
        raise MeshFormatError(f"{what} spans bytes {start}..{start + length} of a "
                              f"{len(buffers[number])}-byte buffer")  # fmt: skip
    return bytes(buffers[number][start : start + length])


def _size(item: dict, key: str, what: str, default: int | None = None) -> int:
    value = item.get(key, default)
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise MeshFormatError(f"{what} {key} is {value!r}, not a non-negative integer")
    return value

"""glTF 2.0 (Khronos): GLB reader and writer, and the .gltf reader.

Reader: every triangle primitive (mode 4) of every mesh the scene places is read and the
primitives are concatenated, indices offset. Node transforms and the scene graph are
applied: each mesh node of the default scene places its mesh by its world transform
(a mesh used by two nodes comes twice; a document without nodes gives its meshes as
they are). Attributes: POSITION (required), NORMAL -> "normal",
COLOR_0 -> "color", TEXCOORD_0 -> `Mesh.corner_uvs` (an attribute is kept only when
every primitive has it; normalised integer components are scaled to [0, 1]). glTF's
texture origin is the top-left corner, the Mesh's (like OBJ's) the bottom-left: v is
flipped on the way in and out. glTF vertices are per (position, attribute) tuple, so a
texture seam arrives as several vertices at one position: the reader welds vertices
whose position, normal and colour are bit for bit equal, keeping the first of each
group in file order, and their UVs stay per corner; the "uv" vertex attribute is given
too when no welded vertex has two UVs. The base-colour image of the first primitive's
material, when embedded (a bufferView or a data: URI) or a file beside the model
(`companions.Companions`: a path's folder, a zip's members), becomes `Mesh.texture`.
A .gltf (`read_gltf`) is the same document as JSON, its buffers data: URIs or files
beside it (a .bin); a GLB's buffers other than its own chunk may be files too. Sparse
accessors are refused; Draco and meshopt compression are decoded first
(`gltf_compression.py`).

Writer: one mesh, one primitive, one node; POSITION float32 with min/max, indices
uint16 when there are at most 65535 (glTF) vertices (65535 itself is the reserved
restart value) else uint32, NORMAL (normalised to unit length, as glTF requires),
COLOR_0 float32 in [0, 1], TEXCOORD_0 float32; a material that is not metallic, with
the texture (PNG, JPEG or WebP bytes, embedded) as base colour when one is given together
with UVs. With `corner_uvs`, each vertex is written once per distinct UV of its corners
(sorted by vertex, then UV bits; a vertex no face uses once, with UV (0, 0)), its
normal and colour copied; the "uv" attribute is used only without `corner_uvs`.
docs/formats.md has the exact layout.
"""

from __future__ import annotations

import base64
import json
import struct
import sys
from urllib.parse import unquote

import numpy as np

from ..errors import InvalidMeshError, MeshFormatError
from ..mesh import MAX_MATERIALS, Material, Mesh
from ._corners import split_at_seams, weld
from ._floats import widened
from ._images import image_media_type
from .companions import Companions, NoCompanions
from .gltf_compression import INDEX_SIZE, decompressed, extension

__all__ = ["is_glb", "read_glb", "read_gltf", "write_glb"]

_MAGIC = b"glTF"
_JSON_CHUNK = 0x4E4F534A
_BIN_CHUNK = 0x004E4942
_COMPONENT_TYPES = {
    5120: np.dtype("i1"),
    5121: np.dtype("u1"),
    5122: np.dtype("<i2"),
    5123: np.dtype("<u2"),
    5125: np.dtype("<u4"),
    5126: np.dtype("<f4"),
}
_WIDTHS = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}
_ATTRIBUTES = {"NORMAL": "normal", "COLOR_0": "color", "TEXCOORD_0": "uv"}
_TRIANGLES = 4
_ARRAY_BUFFER = 34962
_ELEMENT_ARRAY_BUFFER = 34963
_BYTE, _UNSIGNED_BYTE, _SHORT, _UNSIGNED_SHORT = 5120, 5121, 5122, 5123
_UNSIGNED_INT, _FLOAT = 5125, 5126
_COMPONENT_NAMES = {_BYTE: "BYTE", _UNSIGNED_BYTE: "UNSIGNED_BYTE", _SHORT: "SHORT",
                    _UNSIGNED_SHORT: "UNSIGNED_SHORT", _UNSIGNED_INT: "UNSIGNED_INT",
                    _FLOAT: "FLOAT"}  # fmt: skip
_LINEAR, _LINEAR_MIPMAP_LINEAR, _REPEAT = 9729, 9987, 10497
_QUANTIZATION = "KHR_mesh_quantization"
# What glTF 2.0 allows for each accessor the reader reads (its section 3.7.2.1,
# "Meshes"): the accessor types, and the component types, each with whether it must be
# normalized (True) or may be either (None); then what KHR_mesh_quantization adds when
# the file uses it. Checked before the values are read, so that a FLOAT index is
# refused rather than truncated, integer colours are never read as 0..255, and a SCALAR
# UV never reaches the code after.
_FLOAT_OR_NORMALIZED = ((_FLOAT, None), (_UNSIGNED_BYTE, True), (_UNSIGNED_SHORT, True))
_ALLOWED = {
    "POSITION": (("VEC3",), ((_FLOAT, None),)),
    "NORMAL": (("VEC3",), ((_FLOAT, None),)),
    "TEXCOORD_0": (("VEC2",), _FLOAT_OR_NORMALIZED),
    "COLOR_0": (("VEC3", "VEC4"), _FLOAT_OR_NORMALIZED),
    "indices": (
        ("SCALAR",),
        ((_UNSIGNED_BYTE, None), (_UNSIGNED_SHORT, None), (_UNSIGNED_INT, None)),
    ),
}
_ANY_SMALL_INTEGER = (
    (_BYTE, None),
    (_UNSIGNED_BYTE, None),
    (_SHORT, None),
    (_UNSIGNED_SHORT, None),
)
_QUANTIZED = {
    "POSITION": _ANY_SMALL_INTEGER,
    "NORMAL": ((_BYTE, True), (_SHORT, True)),
    "TEXCOORD_0": _ANY_SMALL_INTEGER,
}
_GENERATOR = "qem-lod"
_MESHOPT = "EXT_meshopt_compression"
_WEBP = "EXT_texture_webp"
# Primitive extras key: a bufferView of uint32 LE, the Mesh vertex of each glTF vertex.
_VERTEX_OF = "qem_lod_vertex_of"


def is_glb(data: bytes) -> bool:
    return data[:4] == _MAGIC


def read_glb(data: bytes, files: Companions | None = None) -> Mesh:
    """Decode a GLB file into a Mesh, reading the files it names through ``files``.
    Raises MeshFormatError."""
    gltf, binary = _chunks(data)
    return _read_document(gltf, binary, files)


def read_gltf(data: bytes, files: Companions | None = None) -> Mesh:
    """Decode a .gltf (JSON) file into a Mesh, its .bin and images read through
    ``files`` unless they are data: URIs. Raises MeshFormatError."""
    return _read_document(_json(data.removeprefix(b"\xef\xbb\xbf"), "glTF JSON"), None, files)


# Extensions a file may require: decoded (compression, quantised attributes), or about
# looks qem-lod does not keep (materials, lights; other image formats are left out as
# from any file). Any other required extension would change what the mesh is.
_READ_EXTENSIONS = {"KHR_draco_mesh_compression", _MESHOPT, "KHR_mesh_quantization",
                    "KHR_texture_transform", _WEBP}  # fmt: skip
_IGNORED_EXTENSION_PREFIXES = ("KHR_materials_", "KHR_lights_", "KHR_texture_basisu",
                               "EXT_lights_")  # fmt: skip


def _read_document(gltf: dict, binary: bytes | None, files: Companions | None) -> Mesh:
    files = files or NoCompanions()
    for key in ("extensionsUsed", "extensionsRequired"):
        names = gltf.get(key, [])
        if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
            raise MeshFormatError(f"glTF {key} must be a list of names")
    required = gltf.get("extensionsRequired", [])
    for name in required:
        if name not in _READ_EXTENSIONS and not name.startswith(_IGNORED_EXTENSION_PREFIXES):
            raise MeshFormatError(
                f"the glTF requires the extension {name[:60]!r}, which qem-lod does not "
                f"read (it reads {', '.join(sorted(_READ_EXTENSIONS))})"
            )
    try:
        gltf, buffers = decompressed(gltf, _buffers(gltf, binary, files))
        return _read_meshes(gltf, buffers, files)
    except MeshFormatError:
        raise
    except (KeyError, IndexError, TypeError, ValueError, AttributeError) as error:
        raise MeshFormatError(
            f"glTF JSON does not follow glTF 2.0 ({type(error).__name__}: {error})"
        ) from None


def write_glb(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_attributes: dict[str, np.ndarray],
    texture: bytes | None = None,
    corner_uvs: np.ndarray | None = None,
    materials: list[Material] | None = None,
    face_materials: np.ndarray | None = None,
) -> bytes:
    """Encode as a GLB: see the module docstring. With ``materials`` (and the material
    of each face), one primitive per material used, sharing the vertices."""
    uv = vertex_attributes.get("uv")
    source = None
    if corner_uvs is not None:
        # glTF attributes are per vertex: one glTF vertex per (position, corner UV).
        n_input = vertices.shape[0]
        source, uv, faces = split_at_seams(faces, corner_uvs, n_input)
        if source.size == n_input:
            source = None  # no seam: the vertices as given
        else:
            vertices = vertices[source]
            vertex_attributes = {k: v[source] for k, v in vertex_attributes.items()}
    blob = _BinaryBuilder()
    positions = vertices.astype(np.float32)
    attributes = {
        "POSITION": blob.accessor(
            positions,
            "VEC3",
            _ARRAY_BUFFER,
            bounds=(positions.min(axis=0).tolist(), positions.max(axis=0).tolist()),
        )
    }
    normal = vertex_attributes.get("normal")
    if normal is not None:
        attributes["NORMAL"] = blob.accessor(_unit(normal), "VEC3", _ARRAY_BUFFER)
    color = vertex_attributes.get("color")
    if color is not None:
        color = np.clip(color, 0.0, 1.0).astype(np.float32)
        attributes["COLOR_0"] = blob.accessor(color, f"VEC{color.shape[1]}", _ARRAY_BUFFER)
    if uv is not None:
        uv = uv.astype(np.float64)
        flipped = np.stack([uv[:, 0], 1.0 - uv[:, 1]], axis=1).astype(np.float32)
        attributes["TEXCOORD_0"] = blob.accessor(flipped, "VEC2", _ARRAY_BUFFER)
    index_type = "<u2" if vertices.shape[0] <= 0xFFFF else "<u4"
    if materials is None or face_materials is None:
        materials, face_materials = [Material("qem-lod", texture)], np.zeros(len(faces), np.int32)
    gltf: dict = {
        "asset": {"version": "2.0", "generator": _GENERATOR},
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": []}],
        "materials": [],
    }
    # Faces of one material together, in their order: a primitive each.
    order = np.argsort(face_materials, kind="stable")
    used, starts = np.unique(face_materials[order], return_index=True)
    if not used.size:  # no faces: one empty primitive all the same
        used, starts = np.zeros(1, np.int64), np.zeros(1, np.int64)
    for material_index, start, end in zip(used, starts, [*starts[1:], len(order)], strict=True):
        look = materials[int(material_index)]
        chosen = faces[order[start:end]].astype(index_type).reshape(-1)
        gltf["meshes"][0]["primitives"].append({
            "attributes": attributes,
            "indices": blob.accessor(chosen, "SCALAR", _ELEMENT_ARRAY_BUFFER),
            "mode": _TRIANGLES,
            "material": len(gltf["materials"]),
        })  # fmt: skip
        gltf["materials"].append(
            _material_entry(gltf, blob, look, look.texture if uv is not None else None)
        )
    if source is not None:
        # Which input vertex each glTF vertex copies, so that the reader undoes exactly
        # this split (and welds nothing else).
        vertex_of = blob.view(source.astype("<u4").tobytes(), target=None)
        for primitive in gltf["meshes"][0]["primitives"]:
            primitive["extras"] = {_VERTEX_OF: vertex_of}
    gltf["accessors"] = blob.accessors
    gltf["bufferViews"] = blob.views
    binary = blob.data()
    gltf["buffers"] = [{"byteLength": len(binary)}]
    json_bytes = _pad(json.dumps(gltf, separators=(",", ":")).encode("utf-8"), b" ")
    total = 12 + 8 + len(json_bytes) + 8 + len(binary)
    return b"".join(
        [
            struct.pack("<4sII", _MAGIC, 2, total),
            struct.pack("<II", len(json_bytes), _JSON_CHUNK),
            json_bytes,
            struct.pack("<II", len(binary), _BIN_CHUNK),
            binary,
        ]
    )


def _material_entry(gltf: dict, blob: _BinaryBuilder, look: Material,
                    texture: bytes | None) -> dict:
    """A glTF material of ``look``; its image, texture and sampler added to ``gltf``."""
    material: dict = {
        "name": look.name,
        "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 1.0},
        "doubleSided": False,
    }
    if look.color is not None:
        material["pbrMetallicRoughness"]["baseColorFactor"] = list(look.color)
    if texture is None:
        return material
    image_type = _image_type(texture)
    gltf.setdefault("images", []).append(
        {"bufferView": blob.view(texture, target=None), "mimeType": image_type}
    )
    if "samplers" not in gltf:
        gltf["samplers"] = [
            {"magFilter": _LINEAR, "minFilter": _LINEAR_MIPMAP_LINEAR, "wrapS": _REPEAT,
             "wrapT": _REPEAT}
        ]  # fmt: skip
    source = len(gltf["images"]) - 1
    textures = gltf.setdefault("textures", [])
    if image_type == "image/webp":
        # glTF's own sources are PNG and JPEG; a WebP one is the extension's.
        textures.append({"sampler": 0, "extensions": {_WEBP: {"source": source}}})
        gltf["extensionsUsed"] = gltf["extensionsRequired"] = [_WEBP]
    else:
        textures.append({"sampler": 0, "source": source})
    material["pbrMetallicRoughness"]["baseColorTexture"] = {"index": len(gltf["textures"]) - 1}
    return material


class _BinaryBuilder:
    """Collects bufferViews and accessors into one 4-byte-aligned binary buffer."""

    def __init__(self) -> None:
        self._parts: list[bytes] = []
        self._size = 0
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def view(self, payload: bytes, target: int | None) -> int:
        view = {"buffer": 0, "byteOffset": self._size, "byteLength": len(payload)}
        if target is not None:
            view["target"] = target
        padded = _pad(payload, b"\0")
        self._parts.append(padded)
        self._size += len(padded)
        self.views.append(view)
        return len(self.views) - 1

    def accessor(
        self,
        values: np.ndarray,
        kind: str,
        target: int,
        bounds: tuple[list[float], list[float]] | None = None,
    ) -> int:
        component = {"<f4": 5126, "<u2": 5123, "<u4": 5125}[values.dtype.newbyteorder("<").str]
        accessor = {
            "bufferView": self.view(np.ascontiguousarray(values).tobytes(), target),
            "componentType": component,
            "count": int(values.shape[0]),
            "type": kind,
        }
        if bounds is not None:
            accessor["min"], accessor["max"] = bounds
        self.accessors.append(accessor)
        return len(self.accessors) - 1

    def data(self) -> bytes:
        return b"".join(self._parts)


def _pad(payload: bytes, filler: bytes) -> bytes:
    return payload + filler * (-len(payload) % 4)


def _unit(normals: np.ndarray) -> np.ndarray:
    """Normals scaled to unit length; a zero normal becomes +z (glTF allows no other)."""
    normals = normals.astype(np.float64)
    length = np.linalg.norm(normals, axis=1)
    unit = np.zeros_like(normals)
    unit[:, 2] = 1.0
    nonzero = length > 0.0
    unit[nonzero] = normals[nonzero] / length[nonzero, None]
    return unit.astype(np.float32)


def _image_type(texture: bytes) -> str:
    media_type = image_media_type(texture)
    if media_type is None:
        raise InvalidMeshError(
            "texture must be PNG, JPEG or WebP bytes (glTF embeds no other format)"
        )
    return media_type


def _chunks(data: bytes) -> tuple[dict, bytes]:
    """The JSON document and the BIN chunk (b"" if none) of a GLB."""
    if len(data) < 12 or data[:4] != _MAGIC:
        raise MeshFormatError("not a GLB file: it does not start with the 'glTF' magic")
    _, version, length = struct.unpack_from("<4sII", data, 0)
    if version != 2:
        raise MeshFormatError(f"GLB version {version} is not supported; only glTF 2.0 is")
    if length > len(data):
        raise MeshFormatError(
            f"GLB header says {length} bytes but the file has {len(data)}: it is truncated"
        )
    gltf = None
    binary = b""
    position = 12
    while position + 8 <= length:
        chunk_length, chunk_type = struct.unpack_from("<II", data, position)
        start = position + 8
        if start + chunk_length > length:
            raise MeshFormatError("GLB chunk runs past the end of the file: it is truncated")
        if chunk_type == _JSON_CHUNK and gltf is None:
            gltf = _json(data[start : start + chunk_length], "GLB JSON chunk")
        elif chunk_type == _BIN_CHUNK and not binary:
            binary = data[start : start + chunk_length]
        position = start + chunk_length
    if gltf is None:
        raise MeshFormatError("GLB has no JSON chunk holding a glTF object")
    return gltf, binary


def _json(data: bytes, what: str) -> dict:
    """The glTF object of JSON bytes; MeshFormatError for anything else."""
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as error:
        raise MeshFormatError(
            f"{what} is not UTF-8 text (byte 0x{data[error.start]:02x} at offset "
            f"{error.start}); glTF JSON must be UTF-8"
        ) from None
    try:
        gltf = json.loads(text)
    except json.JSONDecodeError as error:
        raise MeshFormatError(f"{what} is not valid JSON: {error}") from None
    except ValueError:
        # json reads integers with int(), which refuses more digits than the interpreter's
        # limit (4300 by default); no glTF value comes near (counts fit in 2^53).
        raise MeshFormatError(
            f"{what} is not valid JSON for glTF: it holds an integer of more than "
            f"{sys.get_int_max_str_digits()} digits"
        ) from None
    except RecursionError:
        raise MeshFormatError(f"{what} nests too deeply to read") from None
    if not isinstance(gltf, dict):
        raise MeshFormatError(f"{what} does not hold a glTF object")
    return gltf


def _buffers(gltf: dict, binary: bytes | None, files: Companions) -> list[bytes]:
    buffers = []
    for number, buffer in enumerate(gltf.get("buffers", [])):
        uri = buffer.get("uri")
        if uri is None and (extension(buffer, _MESHOPT) or {}).get("fallback"):
            buffers.append(b"")  # read through its compressed views only
            continue
        if uri is None:
            if number != 0 or binary is None:
                raise MeshFormatError(
                    f"glTF buffer {number} has no URI, and only a GLB's first buffer may "
                    "(its binary chunk)"
                )
            content = binary
        else:
            content = _uri_bytes(uri, files, f"buffer {number}")
        if len(content) < buffer["byteLength"]:
            raise MeshFormatError(
                f"GLB buffer {number} should hold {buffer['byteLength']} bytes but has "
                f"{len(content)}: the file is truncated"
            )
        buffers.append(content)
    return buffers


# Vertices (and triangles) the primitives of a GLB may read beyond what its buffers hold.
_SHARED_ALLOWANCE = 1 << 20


def _read_meshes(gltf: dict, buffers: list[bytes], files: Companions) -> Mesh:
    positions, faces, attributes, offset = [], [], [], 0
    first_primitive = None
    looks: dict[tuple, int] = {}  # (image, colour) -> the material made of it
    material_of: dict[str, Material] = {}  # a primitive's "material" -> its look
    materials: list[Material] = []
    face_looks: list[np.ndarray] = []
    # Primitives may share accessors, and each is copied: a 300 KB file whose thousands
    # of primitives name one POSITION accessor expanded to gigabytes. A vertex takes at
    # least 3 bytes of buffer (12 unquantised) and an index 1, so these budgets let a
    # file share its data among 4 primitives or more, not without end.
    buffer_bytes = sum(len(buffer) for buffer in buffers)
    vertex_budget = buffer_bytes // 3 + _SHARED_ALLOWANCE
    index_budget = buffer_bytes + 3 * _SHARED_ALLOWANCE
    # Primitives of one placed mesh naming the same attribute accessors (a mesh of
    # several materials, as qem-lod writes it) share their vertices: read once.
    vertex_sets: dict[tuple, int] = {}
    for instance, (mesh_index, matrix) in enumerate(_mesh_instances(gltf)):
        for primitive in _item(gltf, "meshes", mesh_index)["primitives"]:
            if primitive.get("mode", _TRIANGLES) != _TRIANGLES:
                continue  # points and lines carry no surface
            if first_primitive is None:
                first_primitive = primitive
            names = primitive.get("attributes")
            if not isinstance(names, dict) or "POSITION" not in names:
                raise MeshFormatError(
                    f"GLB mesh {mesh_index} has a triangle primitive without a POSITION "
                    "attribute: glTF 2.0 requires one"
                )
            # Each material's image read once; repr keys a hostile non-index too, which
            # _material refuses by name.
            key = repr(primitive.get("material"))
            if key not in material_of:
                material_of[key] = _material(gltf, buffers, primitive, files)
            material = material_of[key]
            look = (material.texture, material.color)
            if look not in looks:
                looks[look] = len(materials)
                materials.append(material)
            shared = (instance, json.dumps(names, sort_keys=True), _uv_transform(gltf, primitive))
            if "extensions" not in primitive and shared in vertex_sets and "indices" in primitive:
                indices = _triangle_indices(gltf, buffers, primitive, None)
                index_budget -= indices.size
                if index_budget < 0:
                    raise MeshFormatError(
                        f"GLB primitives read more indices than {buffer_bytes} bytes of "
                        "buffer can hold: they share accessors too many times over"
                    )
                start, count = vertex_sets[shared]
                if indices.size and (indices.min() < 0 or indices.max() >= count):
                    raise MeshFormatError(
                        f"GLB triangle has vertex index {int(indices.max())}, but its "
                        f"primitive has {count} vertices: the file is damaged"
                    )
                faces.append(indices.reshape(-1, 3) + start)
                face_looks.append(np.full(indices.size // 3, looks[look], np.int32))
                continue
            # Normalised integer positions are KHR_mesh_quantization's (its node scales them).
            vertices = _accessor(gltf, buffers, names["POSITION"], "POSITION", normalized=True)
            indices = _triangle_indices(gltf, buffers, primitive, vertices.shape[0])
            vertex_budget -= vertices.shape[0]
            index_budget -= indices.size
            if vertex_budget < 0 or index_budget < 0:
                raise MeshFormatError(
                    f"GLB primitives read more vertices or indices than {buffer_bytes} bytes "
                    "of buffer can hold: they share accessors too many times over"
                )
            positions.append(_placed(widened(vertices), matrix))
            faces.append(indices.reshape(-1, 3) + offset)
            primitive_attributes = {}
            for key, name in _ATTRIBUTES.items():
                if key not in names:
                    continue
                values = _accessor(gltf, buffers, names[key], key, normalized=True)
                if values.shape[0] != vertices.shape[0]:
                    raise MeshFormatError(
                        f"GLB primitive has {values.shape[0]} {key} values for "
                        f"{vertices.shape[0]} positions; each vertex needs one"
                    )
                if name == "normal" and matrix is not None:
                    values = _turned_normals(values, matrix)
                if name == "uv":  # each primitive's own material may transform its UVs
                    values = _texture_transformed(widened(values[:, :2]), gltf,
                                                  primitive)
                primitive_attributes[name] = values
            attributes.append(primitive_attributes)
            face_looks.append(np.full(indices.size // 3, looks[look], np.int32))
            vertex_sets[shared] = (offset, vertices.shape[0])
            offset += vertices.shape[0]
    if first_primitive is None:
        raise MeshFormatError("GLB has no triangle primitive: nothing to simplify")
    vertex_attributes = {}
    for name in _ATTRIBUTES.values():
        if all(name in a for a in attributes):
            parts = [a[name] for a in attributes]
            if name == "color" and len({part.shape[1] for part in parts}) > 1:
                # RGB beside RGBA (valid glTF): the RGB parts opaque.
                parts = [np.pad(p, ((0, 0), (0, 4 - p.shape[1])), constant_values=1.0)
                         for p in parts]  # fmt: skip
            vertex_attributes[name] = np.concatenate(parts).astype(np.float32)
    vertices = np.concatenate(positions)
    all_faces = np.concatenate(faces)
    if all_faces.size and (all_faces.min() < 0 or all_faces.max() >= vertices.shape[0]):
        bad = int(all_faces.min() if all_faces.min() < 0 else all_faces.max())
        raise MeshFormatError(
            f"GLB triangle has vertex index {bad}, but the primitives have "
            f"{vertices.shape[0]} vertices: the file is damaged"
        )
    corner_uvs = None
    uv = vertex_attributes.pop("uv", None)
    if uv is not None:
        uv = uv.astype(np.float64)
        uv[:, 1] = 1.0 - uv[:, 1]
        uv = uv.astype(np.float32)
        corner_uvs = uv[all_faces]
    if len(vertex_sets) == 1 and _VERTEX_OF in (first_primitive.get("extras") or {}):
        kept, index = _unsplit(gltf, buffers, first_primitive["extras"][_VERTEX_OF], vertices)
    elif gltf.get("asset", {}).get("generator") == _GENERATOR:
        kept = index = np.arange(vertices.shape[0])  # qem-lod split nothing
    else:
        # Weld what an exporter split at texture seams (the same position, normal and
        # colour, another UV); vertices that differ in anything but UV stay apart.
        kept, index = weld([vertices, *vertex_attributes.values()])
    if kept.size < vertices.shape[0]:
        vertices = vertices[kept]
        vertex_attributes = {k: v[kept] for k, v in vertex_attributes.items()}
        all_faces = index[all_faces]
    if uv is not None and np.array_equal(uv[kept][index], uv):
        vertex_attributes["uv"] = np.ascontiguousarray(uv[kept])  # no seam: one UV each
    mesh = Mesh(vertices=vertices, faces=all_faces, vertex_attributes=vertex_attributes,
                corner_uvs=corner_uvs, texture=materials[0].texture)
    if len(materials) > 1:
        # Several looks: each kept, the faces told apart (an image without UVs to place
        # it is no look at all).
        if len(materials) > MAX_MATERIALS:
            raise MeshFormatError(f"GLB uses {len(materials)} materials; qem-lod keeps at "
                                  f"most {MAX_MATERIALS} apart")
        if uv is None:
            materials = [Material(m.name, None, m.color) for m in materials]
        mesh.texture = None
        mesh.materials = materials
        mesh.face_materials = np.concatenate(face_looks)
    return mesh


# Node nesting past this is a cycle or a hostile file; real scenes nest a few levels.
_MAX_NODE_DEPTH = 64


def _mesh_instances(gltf: dict) -> list[tuple[int, np.ndarray | None]]:
    """(mesh index, the 4x4 world matrix placing it, None for identity) for each node of
    the default scene (else the first, else every root node) that has a mesh, in scene
    order; a mesh used by two nodes comes twice. Without nodes, each mesh once, as is."""
    nodes = gltf.get("nodes", [])
    if not nodes:
        return [(index, None) for index in range(len(gltf.get("meshes", [])))]
    scenes = gltf.get("scenes", [])
    if scenes:
        scene = _item(gltf, "scenes", gltf.get("scene", 0))
        roots = scene.get("nodes", [])
    else:
        children = {c for node in nodes for c in node.get("children", [])}
        roots = [i for i in range(len(nodes)) if i not in children]
    instances: list[tuple[int, np.ndarray | None]] = []
    stack = [(root, np.eye(4), 0) for root in reversed(roots)]
    while stack:
        index, parent, depth = stack.pop()
        if depth > _MAX_NODE_DEPTH:
            raise MeshFormatError(f"glTF nodes nest deeper than {_MAX_NODE_DEPTH}: a cycle?")
        node = _item(gltf, "nodes", index)
        world = parent @ _node_matrix(node, index)
        if "mesh" in node:
            identity = np.array_equal(world, np.eye(4))
            instances.append((node["mesh"], None if identity else world))
        stack.extend((child, world, depth + 1) for child in reversed(node.get("children", [])))
    return instances


def _node_matrix(node: dict, index: int) -> np.ndarray:
    """A node's local 4x4 matrix: ``matrix`` (column-major) or T * R * S."""
    try:
        if "matrix" in node:
            matrix = np.asarray(node["matrix"], np.float64).reshape(4, 4).T
        else:
            x, y, z, w = np.asarray(node.get("rotation", [0, 0, 0, 1]), np.float64)
            rotation = np.array([
                [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
            ])  # fmt: skip
            matrix = np.eye(4)
            matrix[:3, :3] = rotation * np.asarray(node.get("scale", [1, 1, 1]), np.float64)
            matrix[:3, 3] = np.asarray(node.get("translation", [0, 0, 0]), np.float64)
    except (TypeError, ValueError):
        raise MeshFormatError(f"glTF node {index} has a malformed transform") from None
    if not np.isfinite(matrix).all():
        raise MeshFormatError(f"glTF node {index} has a transform that is not finite")
    return matrix


def _placed(positions: np.ndarray, matrix: np.ndarray | None) -> np.ndarray:
    if matrix is None:
        return positions
    return positions @ matrix[:3, :3].T + matrix[:3, 3]


def _turned_normals(normals: np.ndarray, matrix: np.ndarray) -> np.ndarray:
    """Normals under ``matrix``: by the inverse transpose of its 3x3 part, unit again."""
    try:
        turn = np.linalg.inv(matrix[:3, :3]).T
    except np.linalg.LinAlgError:
        return normals  # a degenerate transform flattens the mesh; leave its normals
    turned = normals @ turn.T
    length = np.linalg.norm(turned, axis=1, keepdims=True)
    return np.where(length > 0, turned / np.maximum(length, 1e-300), turned)


def _unsplit(
    gltf: dict, buffers: list[bytes], view: object, vertices: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(kept, index) as `weld` gives them, from the writer's record of which vertex
    each glTF vertex copies: output vertex j is the first glTF vertex that copies j."""
    buffer, start, length, _ = _view_bytes(gltf, buffers, view)
    if length != 4 * vertices.shape[0]:
        raise MeshFormatError(
            f"GLB extras {_VERTEX_OF!r} holds {length} bytes; it needs 4 per vertex "
            f"({4 * vertices.shape[0]}): the file is damaged"
        )
    source = np.frombuffer(buffer, "<u4", vertices.shape[0], start).astype(np.int64)
    n_kept = int(source.max()) + 1 if source.size else 0
    first = np.full(min(n_kept, source.size), -1, dtype=np.int64)
    if n_kept <= source.size:
        first[source[::-1]] = np.arange(source.size - 1, -1, -1)
    if n_kept > source.size or (first < 0).any():
        raise MeshFormatError(
            f"GLB extras {_VERTEX_OF!r} skips a vertex number: the file is damaged"
        )
    return first, source


def _item(gltf: dict, key: str, index: object) -> dict:
    """gltf[key][index], checking that the index exists (no negative indices)."""
    items = gltf.get(key, [])
    if isinstance(index, bool) or not isinstance(index, int) or not 0 <= index < len(items):
        raise MeshFormatError(f"GLB refers to {key}[{index!r}], which does not exist")
    return items[index]


def _view_bytes(gltf: dict, buffers: list[bytes], index: object) -> tuple[bytes, int, int, int]:
    """(buffer, start, length, stride or 0) of bufferView `index`, bounds checked."""
    view = _item(gltf, "bufferViews", index)
    buffer_index = view["buffer"]
    if not isinstance(buffer_index, int) or not 0 <= buffer_index < len(buffers):
        raise MeshFormatError(f"GLB bufferView {index} refers to a missing buffer")
    buffer = buffers[buffer_index]
    start = _whole_number(view, "byteOffset", f"bufferView {index}", 0)
    length = _whole_number(view, "byteLength", f"bufferView {index}")
    if start + length > len(buffer):
        raise MeshFormatError(
            f"GLB bufferView {index} spans bytes {start}..{start + length} of a "
            f"{len(buffer)}-byte buffer: the file is truncated or damaged"
        )
    return buffer, start, length, _whole_number(view, "byteStride", f"bufferView {index}", 0)


def _whole_number(item: dict, key: str, what: str, default: int | None = None) -> int:
    """item[key] as a non-negative int (glTF counts, offsets and lengths are JSON
    integers): a float, a string, Infinity or a negative number is refused by name."""
    value = item.get(key, default)
    if value is None:
        raise MeshFormatError(f"GLB {what} has no {key}")
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise MeshFormatError(f"GLB {what} {key} is {value!r}, not a non-negative integer")
    return value


def _accessor(
    gltf: dict, buffers: list[bytes], index: object, what: str, normalized: bool
) -> np.ndarray:
    """(count, width) copy of an accessor's values; normalised integers scaled to
    [0, 1] (or [-1, 1]) when `normalized` allows it."""
    accessor = _item(gltf, "accessors", index)
    if "sparse" in accessor:
        raise MeshFormatError(f"GLB {what} uses a sparse accessor, which is not supported")
    if "bufferView" not in accessor:
        raise MeshFormatError(f"GLB {what} accessor has no data (no bufferView)")
    dtype, width = _checked_format(gltf, accessor, what)
    count = _whole_number(accessor, "count", f"{what} accessor")
    decoded_size = _item(gltf, "bufferViews", accessor["bufferView"]).get(INDEX_SIZE)
    if decoded_size is not None and decoded_size != dtype.itemsize:
        raise MeshFormatError(
            f"GLB {what} accessor reads {dtype.itemsize}-byte values from a view decoded as "
            f"{decoded_size}-byte indices ({_MESHOPT}): the file is inconsistent"
        )
    buffer, start, length, stride = _view_bytes(gltf, buffers, accessor["bufferView"])
    element = dtype.itemsize * width
    stride = stride or element
    offset = _whole_number(accessor, "byteOffset", f"{what} accessor", 0)
    needed = offset + stride * (count - 1) + element if count > 0 else 0
    if stride < element or needed > length:
        raise MeshFormatError(
            f"GLB {what} accessor needs {needed} bytes ({count} values) but its bufferView "
            f"has {length}: the file is truncated or damaged"
        )
    values = np.ndarray(
        (count, width),
        dtype=dtype,
        buffer=buffer,
        offset=start + offset,
        strides=(stride, dtype.itemsize),
    )
    if normalized and dtype.kind in "iu" and accessor.get("normalized", False):
        return np.maximum(values / np.iinfo(dtype).max, -1.0)
    return np.array(values)


def _checked_format(gltf: dict, accessor: dict, what: str) -> tuple[np.dtype, int]:
    """(dtype, width) of an accessor read as ``what`` ("POSITION", "indices", ...), once
    its type, componentType and normalized are what glTF 2.0 allows there (`_ALLOWED`,
    and `_QUANTIZED` when the file uses KHR_mesh_quantization)."""
    kind = accessor.get("type")
    component = accessor.get("componentType")
    normalized = accessor.get("normalized", False)
    types, formats = _ALLOWED[what]
    used = (*gltf.get("extensionsUsed", []), *gltf.get("extensionsRequired", []))
    quantized = _QUANTIZATION in used
    if quantized:
        formats += _QUANTIZED.get(what, ())
    if not isinstance(kind, str) or kind not in types:
        raise MeshFormatError(
            f"GLB {what} accessor has type {kind!r}; glTF 2.0 allows {' or '.join(types)} there"
        )
    if not isinstance(normalized, bool):
        raise MeshFormatError(
            f"GLB {what} accessor has normalized {normalized!r}; it must be true or false"
        )
    known = isinstance(component, int) and component in _COMPONENT_NAMES
    if known and any(c == component and n in (None, normalized) for c, n in formats):
        return _COMPONENT_TYPES[component], _WIDTHS[kind]
    found = repr(component)
    if known:
        found = ("normalized " if normalized else "") + f"{_COMPONENT_NAMES[component]} ({found})"
    hint = ""
    if not quantized and known and any(c == component for c, _ in _QUANTIZED.get(what, ())):
        hint = f"; integer {what} values need the file to use {_QUANTIZATION}"
    raise MeshFormatError(
        f"GLB {what} accessor has componentType {found}; glTF 2.0 allows "
        f"{_formats_named(formats)} there{hint}"
    )


def _formats_named(formats: tuple[tuple[int, bool | None], ...]) -> str:
    """The (componentType, normalized) pairs named: "FLOAT, normalized UNSIGNED_BYTE"."""
    names = []
    for component in dict.fromkeys(c for c, _ in formats):
        modes = {n for c, n in formats if c == component}
        name = _COMPONENT_NAMES[component]
        names.append(f"normalized {name}" if modes == {True} else name)
    return ", ".join(names)


def _triangle_indices(gltf: dict, buffers: list[bytes], primitive: dict,
                      n_vertices: int | None) -> np.ndarray:
    """A triangle primitive's indices as int64, a multiple of 3 (without an accessor,
    its ``n_vertices`` vertices in order)."""
    if "indices" in primitive:
        indices = _accessor(gltf, buffers, primitive["indices"], "indices", False)
        indices = indices.reshape(-1).astype(np.int64)
    else:
        indices = np.arange(n_vertices, dtype=np.int64)
    if indices.size % 3:
        raise MeshFormatError(
            f"GLB triangle primitive has {indices.size} indices, not a multiple of 3"
        )
    return indices


def _uv_transform(gltf: dict, primitive: dict) -> str:
    """The KHR_texture_transform of a primitive's base-colour texture as JSON ("null"
    without one): primitives that share vertices but not this do not share UVs."""
    material = _item(gltf, "materials", primitive["material"]) if "material" in primitive else {}
    info = (material.get("pbrMetallicRoughness") or {}).get("baseColorTexture") or {}
    return json.dumps(extension(info, "KHR_texture_transform"), sort_keys=True)


def _texture_transformed(uv: np.ndarray, gltf: dict, primitive: dict) -> np.ndarray:
    """UVs (glTF's, origin top-left) under the KHR_texture_transform of the primitive's
    base-colour texture, if it has one: offset * rotation * scale, as the extension
    defines, so that the texture lands where the exporter put it."""
    material = _item(gltf, "materials", primitive["material"]) if "material" in primitive else {}
    info = (material.get("pbrMetallicRoughness") or {}).get("baseColorTexture") or {}
    transform = extension(info, "KHR_texture_transform")
    if transform is None:
        return uv
    try:
        ox, oy = (float(v) for v in transform.get("offset", [0.0, 0.0]))
        sx, sy = (float(v) for v in transform.get("scale", [1.0, 1.0]))
        rotation = float(transform.get("rotation", 0.0))
    except (TypeError, ValueError):
        raise MeshFormatError("KHR_texture_transform holds values that are not numbers") from None
    if not all(np.isfinite([ox, oy, sx, sy, rotation])):
        raise MeshFormatError("KHR_texture_transform holds a value that is not finite")
    cos, sin = np.cos(rotation), np.sin(rotation)
    u, v = uv[:, 0] * sx, uv[:, 1] * sy
    return np.stack([cos * u + sin * v + ox, -sin * u + cos * v + oy], axis=1)


def _material(gltf: dict, buffers: list[bytes], primitive: dict, files: Companions) -> Material:
    """A primitive's look: its material's base-colour image and factor (glTF's default
    material, white, for a primitive without one)."""
    if "material" not in primitive:
        return Material("default", None, None)
    index = primitive["material"]
    material = _item(gltf, "materials", index)
    factor = (material.get("pbrMetallicRoughness") or {}).get("baseColorFactor")
    color = None
    if factor is not None:
        if not (isinstance(factor, list) and len(factor) == 4 and all(
                isinstance(c, int | float) and not isinstance(c, bool) and np.isfinite(c)
                for c in factor)):
            raise MeshFormatError(f"GLB material {index} has baseColorFactor {factor!r:.80}; "
                                  "glTF requires four numbers in [0, 1]")
        # Exporters round past 1 now and then: clipped, as a renderer would.
        color = tuple(min(1.0, max(0.0, float(c))) for c in factor)
        color = None if color == (1.0, 1.0, 1.0, 1.0) else color
    name = material.get("name")
    name = name if isinstance(name, str) and name else f"material{index}"
    return Material(name, _base_color_image(gltf, buffers, material, files), color)


def _base_color_image(
    gltf: dict, buffers: list[bytes], material: dict, files: Companions
) -> bytes | None:
    """The embedded base-colour image bytes of a material, or None."""
    texture_info = (material.get("pbrMetallicRoughness") or {}).get("baseColorTexture")
    if texture_info is None:
        return None
    texture = _item(gltf, "textures", texture_info["index"])
    # A texture's own source is PNG or JPEG (what every reader decodes): taken when there
    # is one; else the WebP of EXT_texture_webp.
    source = texture.get("source")
    if source is None:
        source = (extension(texture, _WEBP) or {}).get("source")
    if source is None:
        return None
    image = _item(gltf, "images", source)
    if "bufferView" in image:
        buffer, start, length, _ = _view_bytes(gltf, buffers, image["bufferView"])
        return bytes(buffer[start : start + length])
    if "uri" not in image:
        return None
    try:
        return _uri_bytes(image["uri"], files, "the base-colour image")
    except MeshFormatError:
        return None  # the mesh is read without its image, as from OBJ with one missing


def _uri_bytes(uri: object, files: Companions, what: str) -> bytes:
    """The bytes a glTF URI names: a base64 data: URI, or a relative file read through
    ``files`` (percent-encoded, as URIs are)."""
    if not isinstance(uri, str):
        raise MeshFormatError(f"glTF {what} has a URI that is not a string")
    if uri.startswith("data:"):
        if ";base64," not in uri:
            raise MeshFormatError(f"glTF {what}: a data: URI must be base64")
        try:
            return base64.b64decode(uri.split(",", 1)[1], validate=True)
        except ValueError:
            raise MeshFormatError(f"glTF {what}: its data: URI is not valid base64") from None
    content = files.read(unquote(uri))
    if content is None:
        raise MeshFormatError(
            f"glTF {what} is the file {uri[:80]!r}, which is not there: send the .gltf with "
            "its .bin and images in a zip, or as one GLB"
        )
    return content

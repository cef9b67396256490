"""The format registry and the two entry points, `load_mesh` and `encode_mesh`.

Each format lives in its own module; this one only knows which function reads or writes
which format (the `_READERS` and `_WRITERS` dicts, like trimesh's `_ply_loaders`), how
to recognise a format from a file name or from the bytes themselves, and the checks
every loaded mesh goes through.
"""

from __future__ import annotations

import io
import os
import posixpath
from collections.abc import Callable
from typing import BinaryIO

import numpy as np

from ..errors import InvalidMeshError, InvalidOptionsError, MeshFormatError
from ..mesh import MAX_MATERIALS, Material, Mesh
from ..prepare import validate_mesh_arrays
from ..quantise import QuantisedWedges
from ._corners import checked_corner_uvs, finite_float32
from ._images import image_media_type
from .archive import is_zip, open_archive
from .companions import Companions, DirectoryFiles
from .glb import is_glb, read_glb, read_gltf, write_glb
from .msgpack_mesh import is_msgpack_mesh, read_msgpack, write_msgpack
from .obj import obj_companions, read_obj, write_obj, write_obj_zip
from .off import is_off, read_off
from .ply import read_ply, write_ply
from .stl import is_ascii_stl, is_binary_stl, read_stl

__all__ = [
    "MEDIA_TYPES",
    "check_float32_positions",
    "decode_msgpack_mesh",
    "encode_mesh",
    "load_mesh",
    "obj_companions",
    "write_mesh",
]

_READERS: dict[str, Callable[[bytes], Mesh]] = {
    "ply": read_ply,
    "obj": read_obj,
    "stl": read_stl,
    "off": read_off,
    "glb": read_glb,
    "gltf": read_gltf,
    "msgpack": read_msgpack,
}
# Readers that read the files a model names beside itself (an OBJ's .mtl and images, a
# glTF's .bin and images).
_READS_COMPANIONS = {"obj", "glb", "gltf"}
_WRITERS: dict[str, Callable[..., bytes]] = {
    "ply": write_ply,
    "obj": write_obj,
    "glb": write_glb,
    "msgpack": write_msgpack,
    "zip": write_obj_zip,
}
# Content types for HTTP. PLY and OFF have no registered type: the x- names are the
# customary ones.
MEDIA_TYPES: dict[str, str] = {
    "ply": "model/x-ply",
    "obj": "model/obj",
    "stl": "model/stl",
    "off": "model/x-off",
    "glb": "model/gltf-binary",
    "msgpack": "application/vnd.msgpack",
    "zip": "application/zip",
}
_EXTENSIONS = {f".{name}": name for name in _READERS} | {".mpk": "msgpack", ".zip": "zip"}
_ATTRIBUTE_WIDTHS = {"normal": (3,), "color": (3, 4), "uv": (2,)}

MeshSource = str | os.PathLike | bytes | bytearray | memoryview | BinaryIO


def load_mesh(
    source: MeshSource,
    format: str | None = None,
    name: str | None = None,
    files: Companions | None = None,
) -> Mesh:
    """Read and validate a triangle mesh.

    source : a file path, the file's bytes, or a binary file object.
    format : "ply", "obj", "stl", "off", "glb", "gltf", "msgpack" or "zip"; None infers it from
        the name's extension, else from the content (zip and PLY signatures, GLB "glTF"
        magic, OFF keyword, binary STL size, ASCII STL "solid", the msgpack form's
        header, else OBJ if it has 'v' and 'f' lines). A zip archive holds one model
        file and the files it names (`archive.py`: checked before anything is read).
    name : the file name, for format inference and messages; defaults to the path's or
        the file object's name.
    files : where the files the model names beside itself are read (an OBJ's .mtl and
        its images, `companions.py`); defaults to the path's directory for a path, and
        to none for bytes or a file object.

    Returns a Mesh with float64 (n, 3) vertices, int32 (m, 3) faces (polygons
    triangulated: fans, strips past 16 corners), the attributes the file has, and
    `name`. Texture coordinates
    stored per face corner (OBJ ``vt``, PLY ``texcoord``, GLB TEXCOORD_0, msgpack
    "corner_uvs") become `corner_uvs` (m, 3, 2) float32, and also the "uv" attribute
    where every vertex has one UV (OBJ, PLY, GLB); a GLB's vertices split at seams are
    welded back first (see the glb module).

    Raises MeshFormatError for an unknown format or a malformed, truncated file;
    InvalidMeshError for unusable content (no vertices or faces, NaN or infinite
    coordinates, face indices out of range). Messages name the bad value. Nothing is
    allocated in proportion to counts a header declares before they are checked
    against the file's size. OSError if a path cannot be read. A texture image that is
    not PNG, JPEG or WebP is left out (the UVs stay): see `_servable_texture`.
    """
    data, source_name = _read_source(source)
    if files is None and isinstance(source, str | os.PathLike):
        files = DirectoryFiles(os.path.dirname(os.path.abspath(source)))
    name = name if name is not None else source_name
    if name is not None:
        # A path from a file system that is not UTF-8 holds lone surrogates, which the
        # .qpm's msgpack metadata (and any JSON) cannot store: they become "?".
        name = str(name).encode("utf-8", "replace").decode("utf-8")
    label = name or "mesh data"
    fmt = _resolve_format(format, name, data)
    if fmt == "zip":  # the one model inside, with the files it names from the archive
        try:
            model, data, files = open_archive(data)
        except MeshFormatError as error:
            raise type(error)(f"{label}: {error}") from None
        label = f"{label}: {model}"
        name = posixpath.basename(model)
        fmt = _resolve_format(None, name, data)
    try:
        reader = _READERS[fmt]
        mesh = reader(data, files) if fmt in _READS_COMPANIONS else reader(data)
    except InvalidMeshError as error:
        raise type(error)(f"{label}: {error}") from None
    except (ValueError, IndexError, OverflowError, TypeError) as error:
        # A reader missed a check: still the caller's bad file, not a crash.
        raise MeshFormatError(f"{label}: could not read as {fmt} ({error})") from error
    vertices, faces = validate_mesh_arrays(mesh.vertices, mesh.faces, what=label)
    attributes = _checked_attributes(mesh.vertex_attributes, vertices.shape[0], label)
    corner_uvs = mesh.corner_uvs
    if corner_uvs is not None:
        corner_uvs = checked_corner_uvs(corner_uvs, faces.shape[0], label)
    materials, face_materials = _checked_materials(
        mesh.materials, mesh.face_materials, faces.shape[0], label
    )
    return Mesh(
        vertices=vertices,
        faces=faces,
        vertex_attributes=attributes,
        corner_uvs=corner_uvs,
        texture=_servable_texture(mesh.texture),
        name=name if name is not None else mesh.name,
        materials=materials,
        face_materials=face_materials,
    )


def _checked_materials(
    materials: list[Material] | None, face_materials: object, n_faces: int, label: str
) -> tuple[list[Material] | None, np.ndarray | None]:
    """Materials and face materials, checked (a reader's word is not trusted, nor a
    caller's): 2 to MAX_MATERIALS looks, a number for each face naming one of them."""
    if materials is None and face_materials is None:
        return None, None
    which = np.asarray(face_materials)
    if materials is None or not 2 <= len(materials) <= MAX_MATERIALS:
        raise MeshFormatError(f"{label}: materials must number 2 to {MAX_MATERIALS}")
    if which.shape != (n_faces,) or which.dtype.kind not in "iu":
        raise MeshFormatError(f"{label}: one material number a face, not shape {which.shape}")
    if n_faces and (which.min() < 0 or which.max() >= len(materials)):
        raise MeshFormatError(f"{label}: a face names a material beyond the {len(materials)}")
    looks = [Material(m.name, _servable_texture(m.texture), m.color) for m in materials]
    return looks, which.astype(np.int32)


def _servable_texture(texture: bytes | None) -> bytes | None:
    """The texture if it is PNG, JPEG or WebP, else None: those are what glTF embeds
    (WebP through EXT_texture_webp) and browsers decode. Another image (KTX2) is left out
    rather than refusing the mesh, whose UVs stay; keeping it would make every GLB level
    of the mesh fail to encode."""
    if texture is not None and image_media_type(texture) is None:
        return None
    return texture


def decode_msgpack_mesh(data: bytes) -> Mesh:
    """Decode and validate the compact msgpack form (docs/formats.md)."""
    return load_mesh(data, format="msgpack")


# As Python floats: compared with a float32 scalar, a float64 past its range is cast
# down to it (and warns).
_FLOAT32_MAX = float(np.finfo(np.float32).max)
_FLOAT32_TINY = float(np.finfo(np.float32).tiny)


def check_float32_positions(vertices: np.ndarray, what: str = "mesh") -> None:
    """Refuse positions that float32, the type of PLY, OBJ and GLB positions as written
    here, cannot hold: a coordinate past its largest value (written as inf), or a mesh
    smaller than its smallest normal number (written as zeros and subnormals, one point).
    Raises InvalidMeshError."""
    if vertices.size == 0:
        return
    largest = float(np.abs(vertices).max())
    if largest > _FLOAT32_MAX:
        raise InvalidMeshError(
            f"{what}: a coordinate is {largest:.3g}, past float32's range (±{_FLOAT32_MAX:.3g}) "
            "in which levels are written; scale the mesh down"
        )
    extent = float((vertices.max(axis=0) - vertices.min(axis=0)).max())
    if 0.0 < extent < _FLOAT32_TINY:
        raise InvalidMeshError(
            f"{what}: the mesh is {extent:.3g} across, below float32's smallest normal "
            f"number ({_FLOAT32_TINY:.3g}) in which levels are written; scale the mesh up"
        )


def encode_mesh(
    vertices: object,
    faces: object,
    format: str,
    vertex_attributes: dict[str, object] | None = None,
    texture: bytes | None = None,
    corner_uvs: object | None = None,
    *,
    quantize_bits: int | None = None,
    grid_box: tuple[object, object] | None = None,
    name: str | None = None,
    wedges: QuantisedWedges | None = None,
    material_library: str | None = None,
    materials: list[Material] | None = None,
    face_materials: object | None = None,
) -> bytes:
    """Encode a triangle mesh as "ply", "obj", "glb", "msgpack" or "zip" bytes ("zip":
    the OBJ with its .mtl and texture image, `obj.write_obj_zip`).

    vertices : (n, 3) float; faces : (m, 3) int in [0, n).
    vertex_attributes : optional "normal" (n, 3), "color" (n, 3 or 4) in [0, 1],
        "uv" (n, 2) with the origin at the bottom-left of the image.
    texture : optional PNG, JPEG or WebP bytes; stored by "glb" (with UVs; WebP through
        EXT_texture_webp) and "msgpack".
    corner_uvs : optional (m, 3, 2) UVs per face corner (origin bottom-left), seams
        included; every format keeps them per corner: OBJ ``vt`` per corner, PLY face
        list ``texcoord``, GLB one vertex per (position, UV) pair, msgpack
        "corner_uvs". Where both are given, corner_uvs win over the "uv" attribute in
        OBJ and GLB; PLY and msgpack store both.
    quantize_bits : "msgpack" only: None stores float32 positions, 16 (or 1..15) stores
        uint16 positions on a grid of that many bits over the bounding box, or over
        `grid_box` = (low, high) when given (e.g. the split stream's grid).
    name : "msgpack" only: stored in the message.
    wedges : "msgpack" only: the level's wedges quantised on the split stream's
        attribute grid (`qem_core.stream.quantised_wedges`), for a client that refines.
    material_library : "obj" only: with a texture and UVs, the OBJ names its material
        library ``<material_library>.mtl``, which `obj_companions` writes with the image.
    materials, face_materials : a mesh of several materials (`Mesh.materials`): GLB
        writes a primitive per material with its image or colour, OBJ a ``usemtl`` run
        per material (with ``material_library``), "zip" the OBJ with its .mtl and every
        image, msgpack the list and each face's number; PLY keeps no materials.

    Raises InvalidOptionsError for an unknown format or an option the format does not
    take, InvalidMeshError for bad arrays. docs/formats.md has each format's layout.
    """
    fmt = str(format).lower().lstrip(".")
    if fmt not in _WRITERS:
        raise InvalidOptionsError(
            f"cannot write format {format!r}; formats written are {sorted(_WRITERS)}"
        )
    vertices, faces = validate_mesh_arrays(vertices, faces, require_faces=False)
    attributes = _checked_attributes(vertex_attributes or {}, vertices.shape[0], "mesh")
    if texture is not None and not isinstance(texture, bytes | bytearray):
        raise InvalidMeshError("texture must be the bytes of a PNG, JPEG or WebP image")
    if corner_uvs is not None:
        corner_uvs = checked_corner_uvs(corner_uvs, faces.shape[0], "mesh")
    materials, face_materials = _checked_materials(materials, face_materials, faces.shape[0],
                                                   "mesh")  # fmt: skip
    looks = {"materials": materials, "face_materials": face_materials}
    if fmt != "msgpack" or quantize_bits is None:
        check_float32_positions(vertices)  # msgpack's grid takes any finite positions
    if fmt == "msgpack":
        return write_msgpack(
            vertices,
            faces,
            attributes,
            texture,
            corner_uvs,
            quantize_bits=quantize_bits,
            grid_box=grid_box,
            name=name,
            wedges=wedges,
            **looks,
        )
    if quantize_bits is not None or grid_box is not None or wedges is not None:
        raise InvalidOptionsError(
            f"quantize_bits, grid_box and wedges apply to 'msgpack' only, not {fmt!r}"
        )
    if fmt == "obj":
        return write_obj(vertices, faces, attributes, texture, corner_uvs, material_library,
                         **looks)  # fmt: skip
    if material_library is not None:
        raise InvalidOptionsError(f"material_library applies to 'obj' only, not {fmt!r}")
    if fmt == "ply":
        return write_ply(vertices, faces, attributes, texture, corner_uvs)  # no materials
    return _WRITERS[fmt](vertices, faces, attributes, texture, corner_uvs, **looks)


def write_mesh(
    mesh: Mesh,
    format: str,
    *,
    quantize_bits: int | None = None,
    grid_box: tuple[object, object] | None = None,
) -> bytes:
    """Encode a `Mesh` (positions, faces, vertex attributes, corner UVs, texture and,
    for "msgpack", its name) as `format`: `encode_mesh` with the mesh's fields."""
    if not isinstance(mesh, Mesh):
        raise InvalidMeshError(f"write_mesh takes a qem_core Mesh, not {type(mesh).__name__}")
    return encode_mesh(
        mesh.vertices,
        mesh.faces,
        format,
        mesh.vertex_attributes,
        mesh.texture,
        mesh.corner_uvs,
        quantize_bits=quantize_bits,
        grid_box=grid_box,
        name=mesh.name,
        materials=mesh.materials,
        face_materials=mesh.face_materials,
    )


def _read_source(source: MeshSource) -> tuple[bytes, str | None]:
    """The bytes of a path, bytes-like object or binary file object, and its name."""
    if isinstance(source, bytes | bytearray | memoryview):
        return bytes(source), None
    if isinstance(source, str | os.PathLike):
        with open(source, "rb") as file:
            return file.read(), os.path.basename(os.fspath(source))
    if isinstance(source, io.TextIOBase):
        # Checked before reading: a text-mode read of a binary file raises
        # UnicodeDecodeError, not the clear error below.
        raise MeshFormatError("the file object must be opened in binary mode ('rb')")
    if hasattr(source, "read"):
        data = source.read()
        if not isinstance(data, bytes | bytearray):
            raise MeshFormatError("the file object must be opened in binary mode ('rb')")
        file_name = getattr(source, "name", None)
        return bytes(data), os.path.basename(file_name) if isinstance(file_name, str) else None
    raise MeshFormatError(
        f"cannot read a mesh from {type(source).__name__}; give a path, bytes or a binary file"
    )


def _resolve_format(format: str | None, name: str | None, data: bytes) -> str:
    supported = ", ".join(sorted([*_READERS, "zip"]))
    if format is not None:
        fmt = str(format).lower().lstrip(".")
        if fmt not in _READERS and fmt != "zip":
            raise MeshFormatError(f"unknown mesh format {format!r}; supported: {supported}")
        return fmt
    extension = os.path.splitext(name or "")[1].lower()
    if extension in _EXTENSIONS:
        return _EXTENSIONS[extension]
    sniffed = _sniff(data)
    if sniffed is None:
        what = f"{name!r}" if name else "the data"
        raise MeshFormatError(
            f"cannot tell the mesh format of {what} from its name or content; "
            f"supported formats: {supported} (name the file with one of these extensions "
            "or pass format=)"
        )
    return sniffed


def _sniff(data: bytes) -> str | None:
    """The format the content looks like, or None."""
    if is_zip(data):
        return "zip"
    if data[:3] == b"ply" and data[3:4] in (b"\n", b"\r"):
        return "ply"
    if is_glb(data):
        return "glb"
    if is_msgpack_mesh(data):
        return "msgpack"
    if is_off(data):
        return "off"
    if is_binary_stl(data):
        return "stl"
    if is_ascii_stl(data):
        return "stl"
    head = data[:65536]
    if b"\0" not in head and _looks_like_obj(head):
        return "obj"
    return None


def _looks_like_obj(head: bytes) -> bool:
    words = {line.split(None, 1)[0] for line in head.splitlines() if line.strip()}
    return b"v" in words and (b"f" in words or len(head) == 65536)


def _checked_attributes(
    attributes: dict[str, object], n_vertices: int, label: str
) -> dict[str, np.ndarray]:
    """Known attributes as C-contiguous (n, k) float32, finite, of the right width."""
    checked = {}
    for key, values in attributes.items():
        if key not in _ATTRIBUTE_WIDTHS:
            raise InvalidMeshError(
                f"{label}: unknown vertex attribute {key!r}; known: {sorted(_ATTRIBUTE_WIDTHS)}"
            )
        values = np.asarray(values)
        widths = _ATTRIBUTE_WIDTHS[key]
        if values.ndim != 2 or values.shape[0] != n_vertices or values.shape[1] not in widths:
            raise InvalidMeshError(
                f"{label}: vertex attribute {key!r} must have shape ({n_vertices}, "
                f"{' or '.join(map(str, widths))}), got {values.shape}"
            )
        what = f"{label}: vertex attribute {key!r}"
        checked[key] = finite_float32(values, what, "vertex", "the attribute")
    return checked

"""Seed inputs: small files of every kind, written by the project's own writers (and by
hand for STL and OFF, which qem_core reads but does not write), plus the small shared
meshes and the earlier fuzz findings when ``../shared`` is there."""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path

import numpy as np

import qem_core
from qem_core import codecs
from qem_core.codecs.archive import write_archive
from qem_core.levels import encode_level
from qem_core.stream import encode_split_frames

__all__ = ["SHARED", "seeds", "stream_input"]

SHARED = Path(__file__).resolve().parents[2] / "shared"
# Shared meshes small enough that an execution stays in milliseconds.
_SMALL_SHARED = ("spot.obj", "spot.ply", "fandisk.ply")
_SUFFIXES = {"ply": ".ply", "obj": ".obj", "stl": ".stl", "off": ".off", "glb": ".glb",
             "gltf": ".gltf",
             "msgpack": ".msgpack", "qpm": ".qpm"}  # fmt: skip


def _bumpy_grid(n: int = 6):
    """An n x n grid, bumped, with per-vertex normals, colours and UVs."""
    xs, ys = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    z = 0.1 * np.sin(5 * xs) * np.cos(4 * ys)
    vertices = np.stack([xs.ravel(), ys.ravel(), z.ravel()], axis=1)
    faces = []
    for j in range(n - 1):
        for i in range(n - 1):
            v = j * n + i
            faces += [[v, v + 1, v + n + 1], [v, v + n + 1, v + n]]
    faces = np.array(faces, np.int32)
    normals = np.tile(np.array([0.0, 0.0, 1.0], np.float32), (n * n, 1))
    colours = np.clip(np.abs(vertices), 0, 1).astype(np.float32)
    uvs = vertices[:, :2].astype(np.float32)
    return vertices, faces, {"normal": normals, "color": colours, "uv": uvs}


def _stl(vertices, faces, binary: bool) -> bytes:
    triangles = vertices[faces]
    if binary:
        records = b"".join(
            struct.pack("<12fH", 0, 0, 0, *triangle.ravel().tolist(), 0) for triangle in triangles
        )
        return b"\0" * 80 + struct.pack("<I", len(faces)) + records
    lines = ["solid seed"]
    for triangle in triangles:
        lines += ["facet normal 0 0 0", " outer loop"]
        lines += [f"  vertex {x:.6g} {y:.6g} {z:.6g}" for x, y, z in triangle]
        lines += [" endloop", "endfacet"]
    return ("\n".join([*lines, "endsolid seed"]) + "\n").encode()


def _off(vertices, faces) -> bytes:
    lines = ["OFF", f"{len(vertices)} {len(faces)} 0"]
    lines += [f"{x:.6g} {y:.6g} {z:.6g}" for x, y, z in vertices]
    lines += [f"3 {a} {b} {c}" for a, b, c in faces]
    return ("\n".join(lines) + "\n").encode()


def _ascii_ply(vertices, faces) -> bytes:
    header = ["ply", "format ascii 1.0", f"element vertex {len(vertices)}",
              "property float x", "property float y", "property float z",
              f"element face {len(faces)}", "property list uchar int vertex_indices",
              "end_header"]  # fmt: skip
    body = [f"{x:.6g} {y:.6g} {z:.6g}" for x, y, z in vertices]
    body += [f"3 {a} {b} {c}" for a, b, c in faces]
    return ("\n".join(header + body) + "\n").encode()


def _as_gltf(glb: bytes) -> bytes:
    """A GLB's document as a .gltf, its binary chunk a data: URI (nothing beside it)."""
    json_length = struct.unpack_from("<I", glb, 12)[0]
    gltf = json.loads(glb[20 : 20 + json_length])
    binary = glb[28 + json_length :]
    gltf["buffers"][0]["uri"] = "data:;base64," + base64.b64encode(binary).decode()
    return json.dumps(gltf).encode()


def _compressed_gltf(vertices: np.ndarray, faces: np.ndarray, codec: str) -> bytes:
    """A .gltf of positions and indices compressed as gltf-transform (Draco) or gltfpack
    (meshopt) write them, the data a data: URI."""
    positions = np.ascontiguousarray(vertices, "<f4")
    indices = np.ascontiguousarray(faces, "<u4").reshape(-1)
    accessors = [
        {"componentType": 5126, "count": len(positions), "type": "VEC3"},
        {"componentType": 5125, "count": len(indices), "type": "SCALAR"},
    ]
    primitive: dict = {"attributes": {"POSITION": 0}, "indices": 1}
    if codec == "draco":
        import DracoPy

        data = DracoPy.encode(positions, faces, quantization_bits=14)
        position_id = DracoPy.decode(data).attributes[0]["unique_id"]
        views = [{"buffer": 0, "byteLength": len(data)}]
        primitive["extensions"] = {"KHR_draco_mesh_compression": {
            "bufferView": 0, "attributes": {"POSITION": position_id}}}  # fmt: skip
        extension, buffers = "KHR_draco_mesh_compression", [data]
    else:
        import meshoptimizer

        chunks = [
            meshoptimizer.encode_vertex_buffer(positions),
            meshoptimizer.encode_index_buffer(indices, len(indices), len(positions)),
        ]
        data, views = b"", []
        for chunk, (stride, mode, count) in zip(
            chunks, ((12, "ATTRIBUTES", len(positions)), (4, "TRIANGLES", len(indices))),
            strict=True,
        ):
            views.append({"buffer": 1, "byteLength": stride * count, "extensions": {
                "EXT_meshopt_compression": {"buffer": 0, "byteOffset": len(data),
                                            "byteLength": len(chunk), "byteStride": stride,
                                            "mode": mode, "count": count}}})  # fmt: skip
            data += chunk + b"\0" * (-len(chunk) % 4)
        views[0]["byteStride"] = 12
        for number, accessor in enumerate(accessors):
            accessor["bufferView"] = number
        extension, buffers = "EXT_meshopt_compression", [data]
    gltf = {
        "asset": {"version": "2.0"}, "extensionsUsed": [extension],
        "extensionsRequired": [extension], "accessors": accessors, "bufferViews": views,
        "buffers": [{"byteLength": len(buffers[0]),
                     "uri": "data:;base64," + base64.b64encode(buffers[0]).decode()}],
        "meshes": [{"primitives": [primitive]}],
    }  # fmt: skip
    if codec == "meshopt":
        fallback = sum(view["byteLength"] for view in views)
        gltf["buffers"].append({"byteLength": fallback,
                                "extensions": {extension: {"fallback": True}}})  # fmt: skip
        offset = 0
        for view in views:
            view["byteOffset"], offset = offset, offset + view["byteLength"]
    return json.dumps(gltf).encode()


def stream_input(pm) -> bytes:
    """The stream target's input for ``pm``: the msgpack base level (uint32 LE length
    first), then the split stream from it to the full mesh, a few splits a frame."""
    base = encode_level(pm, pm.n_base, "msgpack").content
    stream = b"".join(encode_split_frames(pm, pm.n_base, pm.n_full, splits_per_frame=7))
    return struct.pack("<I", len(base)) + base + stream


def seeds(target: str, shared: bool = True) -> list[bytes]:
    """The seed inputs of ``target`` (a name of targets.TARGETS)."""
    vertices, faces, attributes = _bumpy_grid()
    corner_uvs = attributes["uv"][faces]
    plain = qem_core.build(vertices, faces)
    mesh = qem_core.Mesh(vertices, faces, attributes, corner_uvs=corner_uvs)
    rich = qem_core.build_mesh(mesh)
    # Two materials (the grid's halves), one with an image, one with a colour only.
    looks = [qem_core.Material("image", _PNG), qem_core.Material("red", None, (1, 0, 0, 1))]
    halves = (np.arange(len(faces)) >= len(faces) // 2).astype(np.int32)
    several = qem_core.build_mesh(qem_core.Mesh(vertices, faces, attributes, corner_uvs=corner_uvs,
                                                materials=looks, face_materials=halves))

    def written_several(fmt: str) -> bytes:
        return codecs.write_mesh(several.lod_mesh(several.n_full), fmt)

    def written(fmt: str) -> list[bytes]:  # without and with the attributes
        return [
            codecs.encode_mesh(vertices, faces, fmt),
            codecs.encode_mesh(vertices, faces, fmt, attributes, corner_uvs=corner_uvs),
        ]

    out: list[bytes]
    if target == "ply":
        out = [_ascii_ply(vertices, faces), *written("ply")]
    elif target == "obj":
        out = written(target)
    elif target == "glb":
        out = [*written(target), written_several("glb")]
    elif target == "gltf":
        out = [_as_gltf(glb) for glb in [*written("glb"), written_several("glb")]]
        out += [_compressed_gltf(vertices, faces, codec) for codec in ("draco", "meshopt")]
    elif target == "stl":
        out = [_stl(vertices, faces, binary=True), _stl(vertices, faces, binary=False)]
    elif target == "off":
        out = [_off(vertices, faces)]
    elif target == "msgpack":
        out = [
            encode_level(rich, rich.n_base + 3, "msgpack").content,
            encode_level(plain, plain.n_base, "msgpack").content,
            codecs.encode_mesh(vertices, faces, "msgpack", attributes),
            encode_level(several, several.n_base + 3, "msgpack").content,
        ]
    elif target == "mtl":
        out = [_MTL, b"newmtl a\nKd 0.5 0.5 0.5\nmap_Kd -s 1 1 1 -clamp on tex.png\n"]
    elif target == "zip":
        obj = b"mtllib m.mtl\nusemtl look\n" + written("obj")[1]
        out = [write_archive({"a/model.obj": obj, "a/m.mtl": _MTL, "a/tex.png": _PNG}),
               write_archive({"grid.ply": written("ply")[0]}),
               written_several("zip")]  # fmt: skip
    elif target == "qpm":
        out = [_saved(plain), _saved(rich), _saved(several)]
    elif target == "stream":
        out = [stream_input(plain), stream_input(rich), stream_input(several)]
    else:
        raise ValueError(f"no seeds for target {target!r}")
    if shared:
        out += _shared_seeds(target)
    return out


# A 1 x 1 PNG, and a material using it.
_PNG = bytes.fromhex(
    "89504e470d0a1a0a0000000d4948445200000001000000010806000000"
    "1f15c4890000000d49444154789c6360f80f0000010100055a3d0a3b0000000049454e44ae426082"
)
_MTL = b"newmtl look\nKd 1 0.5 0.25\nmap_Kd tex.png\n"


def _saved(pm) -> bytes:
    import tempfile

    with tempfile.TemporaryDirectory() as work:
        path = Path(work) / "seed.qpm"
        pm.save(path)
        return path.read_bytes()


def _shared_seeds(target: str) -> list[bytes]:
    """The small shared meshes of the target's format, and the earlier findings' inputs."""
    suffix = _SUFFIXES.get(target)
    if suffix is None or not SHARED.is_dir():
        return []
    paths = [SHARED / "meshes" / name for name in _SMALL_SHARED if name.endswith(suffix)]
    paths += sorted((SHARED / "fuzz-findings" / "inputs").glob(f"*{suffix}"))
    return [path.read_bytes() for path in paths if path.is_file()]

"""A Draco-compressed GLB of a mesh's positions and faces: the static file a web viewer
would load instead of a progressive stream (three.js's GLTFLoader + DRACOLoader).

Positions and faces only, Draco at the bits and compression level given (DracoPy),
wrapped in glTF 2.0 with KHR_draco_mesh_compression: one buffer view holding the Draco
bytes, accessors without buffer views (as gltf-transform writes them).
"""

from __future__ import annotations

import json
import struct

import numpy as np

__all__ = ["draco_glb"]

_FLOAT = 5126
_UINT32 = 5125


def draco_glb(vertices: np.ndarray, faces: np.ndarray, bits: int = 16, level: int = 7) -> bytes:
    import DracoPy

    vertices = np.asarray(vertices, np.float32)
    encoded = DracoPy.encode(vertices, faces, quantization_bits=bits, compression_level=level)
    decoded = DracoPy.decode(encoded)
    position_id = next(a["unique_id"] for a in decoded.attributes if a["attribute_type"] == 0)
    gltf = {
        "asset": {"version": "2.0", "generator": "qem-lod bench"},
        "extensionsUsed": ["KHR_draco_mesh_compression"],
        "extensionsRequired": ["KHR_draco_mesh_compression"],
        "scene": 0,
        "scenes": [{"nodes": [0]}],
        "nodes": [{"mesh": 0}],
        "meshes": [{"primitives": [{
            "attributes": {"POSITION": 0}, "indices": 1, "mode": 4,
            "extensions": {"KHR_draco_mesh_compression": {
                "bufferView": 0, "attributes": {"POSITION": position_id}}},
        }]}],
        "accessors": [
            {"componentType": _FLOAT, "count": len(decoded.points), "type": "VEC3",
             "min": vertices.min(axis=0).tolist(), "max": vertices.max(axis=0).tolist()},
            {"componentType": _UINT32, "count": 3 * len(decoded.faces), "type": "SCALAR"},
        ],
        "bufferViews": [{"buffer": 0, "byteOffset": 0, "byteLength": len(encoded)}],
        "buffers": [{"byteLength": len(encoded)}],
    }  # fmt: skip
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    binary = encoded + b"\0" * (-len(encoded) % 4)
    chunks = [(0x4E4F534A, text), (0x004E4942, binary)]
    body = b"".join(struct.pack("<II", len(data), kind) + data for kind, data in chunks)
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body

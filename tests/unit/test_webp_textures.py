"""WebP textures (issue #33): read from a GLB's EXT_texture_webp, an OBJ's .mtl and the
msgpack form, written by GLB (EXT_texture_webp, required), OBJ companions and msgpack,
served by the API as image/webp."""

from __future__ import annotations

import io
import json
import struct

import pytest

import qem_core
from qem_core import codecs
from qem_core.codecs._images import image_media_type
from tests.unit.conftest import SPOT

PIL = pytest.importorskip("PIL", reason="Pillow is not installed (pip install -e '.[dev]')")


@pytest.fixture(scope="module")
def spot_webp():
    """Spot (the GLB beside the OBJ: UVs and texture) with its texture as WebP."""
    from PIL import Image

    mesh = qem_core.load_mesh(SPOT.with_suffix(".glb"))
    out = io.BytesIO()
    Image.open(io.BytesIO(mesh.texture)).save(out, "WEBP", quality=80)
    return mesh, out.getvalue()


def _gltf_json(glb: bytes) -> dict:
    length = struct.unpack_from("<I", glb, 12)[0]
    return json.loads(glb[20 : 20 + length])


def test_webp_is_known_by_its_bytes(spot_webp):
    _, webp = spot_webp
    assert image_media_type(webp) == "image/webp"
    assert image_media_type(b"RIFF\0\0\0\0WAVE") is None


def test_a_glb_carries_a_webp_texture_through_its_extension(spot_webp):
    mesh, webp = spot_webp
    glb = codecs.encode_mesh(mesh.vertices, mesh.faces, "glb", mesh.vertex_attributes, webp,
                             corner_uvs=mesh.corner_uvs)  # fmt: skip
    gltf = _gltf_json(glb)
    assert gltf["extensionsRequired"] == ["EXT_texture_webp"]
    assert gltf["textures"] == [{"sampler": 0, "extensions": {"EXT_texture_webp": {"source": 0}}}]
    assert gltf["images"][0]["mimeType"] == "image/webp"
    assert qem_core.load_mesh(glb, format="glb").texture == webp


def test_a_texture_with_its_own_source_and_a_webp_keeps_its_own(spot_webp):
    """A file written for every reader: PNG in `source`, WebP in the extension."""
    mesh, webp = spot_webp
    glb = codecs.encode_mesh(mesh.vertices, mesh.faces, "glb", mesh.vertex_attributes, mesh.texture,
                             corner_uvs=mesh.corner_uvs)  # fmt: skip
    gltf = _gltf_json(glb)
    gltf["textures"][0]["extensions"] = {"EXT_texture_webp": {"source": 0}}
    gltf["extensionsUsed"] = ["EXT_texture_webp"]
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    old_length = struct.unpack_from("<I", glb, 12)[0]
    rest = glb[20 + old_length :]
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    rebuilt = struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body
    assert qem_core.load_mesh(rebuilt, format="glb").texture == mesh.texture


def test_an_obj_with_a_webp_map_kd_and_its_companions(spot_webp, tmp_path):
    mesh, webp = spot_webp
    obj = codecs.encode_mesh(mesh.vertices, mesh.faces, "obj", mesh.vertex_attributes, webp,
                             corner_uvs=mesh.corner_uvs, material_library="spot")  # fmt: skip
    beside = codecs.obj_companions("spot", webp)
    assert sorted(beside) == ["spot.mtl", "spot_texture.webp"]
    for name, content in {"spot.obj": obj, **beside}.items():
        (tmp_path / name).write_bytes(content)
    assert qem_core.load_mesh(tmp_path / "spot.obj").texture == webp


def test_msgpack_names_a_webp_texture(spot_webp):
    mesh, webp = spot_webp
    data = codecs.encode_mesh(mesh.vertices, mesh.faces, "msgpack", mesh.vertex_attributes, webp,
                              corner_uvs=mesh.corner_uvs)  # fmt: skip
    import msgpack

    assert msgpack.unpackb(data)["texture_type"] == "image/webp"
    assert qem_core.load_mesh(data, format="msgpack").texture == webp

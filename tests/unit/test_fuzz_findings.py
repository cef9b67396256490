"""The fuzz findings of ../shared/fuzz-findings (r01-r09, found by atheris against
ea55663) as regression tests, their inputs built here so that a clone without ../shared
runs them; and every raw input of that folder read again when it is there.

Each reader and loader must check what it reads where it reads it: a refusal is a
QemError whose message says what is wrong (not a foreign exception reworded by a
catch-all), and no wrong value gets through.
"""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import msgpack
import numpy as np
import pytest

import qem_core
from qem_core.codecs.glb import read_glb
from qem_core.codecs.off import read_off
from qem_core.codecs.ply import read_ply
from qem_core.stream import SplitStreamDecoder
from tests.tiny_meshes import TETRAHEDRON

FINDINGS = Path(__file__).resolve().parents[3] / "shared" / "fuzz-findings"
TETRAHEDRON_V, TETRAHEDRON_F = TETRAHEDRON


@pytest.fixture(scope="module")
def uv_qpm(tmp_path_factory) -> bytes:
    uvs = np.random.default_rng(0).random((4, 3, 2)).astype(np.float32)
    pm = qem_core.build_mesh(qem_core.Mesh(TETRAHEDRON_V, TETRAHEDRON_F, corner_uvs=uvs))
    path = tmp_path_factory.mktemp("qpm") / "a.qpm"
    pm.save(path)
    return path.read_bytes()


def _patched(blob: bytes, change) -> bytes:
    """The .qpm with its msgpack header changed and its CRC-32 made right again, as any
    writer of a hostile file would."""
    length = struct.unpack_from("<I", blob, 12)[0]
    header = msgpack.unpackb(blob[16 : 16 + length], raw=False)
    change(header)
    packed = msgpack.packb(header)
    out = blob[:12] + struct.pack("<I", len(packed)) + packed + blob[16 + length : -4]
    return out + struct.pack("<I", zlib.crc32(out))


def _attributes(**values):
    return lambda header: header["metadata"]["attributes"].update(**values)


def _shape(name, shape):
    def change(header):
        for entry in header["arrays"]:
            if entry[0] == name:
                entry[2] = shape

    return change


@pytest.mark.parametrize(("change", "words"), [
    # r01: accepted, then lod_mesh raised, or negated the UVs, or made them inf
    (_attributes(scales=[]), "attribute scales"),
    (_attributes(names=[]), "attribute names"),
    (_attributes(names=[[]]), "attribute names"),
    (_attributes(names=["color"]), "attribute widths"),
    (_attributes(scales=[-1.0, -1.0]), "float32.s normal range"),
    (_attributes(scales=[0.0, 0.0]), "float32.s normal range"),
    (_attributes(corner_uvs=1), "corner_uvs"),
    (_attributes(scales=[1e300, 1e300]), "float32.s normal range"),  # found by fuzz/
    # r08: ValueError, TypeError, OverflowError out of load
    (_shape("base_wedge_values", [2**63 - 1, 0]), "malformed header entry"),
    (_shape("relabel_faces", [True]), "malformed header entry"),
    (_attributes(widths=[float("inf")]), "attribute widths"),
])  # fmt: skip
def test_a_crafted_qpm_is_refused_by_load(uv_qpm, change, words):
    with pytest.raises(qem_core.CorruptFileError, match=words):
        qem_core.load(_patched(uv_qpm, change))


def test_a_qpm_with_attributes_still_round_trips(uv_qpm):
    pm = qem_core.load(uv_qpm)
    level = pm.lod_mesh(pm.n_full)
    assert level.corner_uvs is not None and np.isfinite(level.corner_uvs).all()


def _ply(body: bytes, fmt: str = "ascii", face: str = "list uchar int vertex_indices") -> bytes:
    header = (f"ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
              f"property float z\nelement face 1\nproperty {face}\nend_header\n")  # fmt: skip
    return header.encode() + body


@pytest.mark.parametrize("data", [
    _ply(b"0 0 0\n1 0 0\n0 1 0\ninf 0 1 2\n"),  # r02: OverflowError
    _ply(b"0 0 0\n1 0 0\n0 1 0\nnan 0 1 2\n"),
    _ply(b"0 0 0\n1 0 0\n0 1 0\n1e300 0 1 2\n"),
])  # fmt: skip
def test_a_ply_list_count_that_is_no_count_is_refused(data):
    with pytest.raises(qem_core.MeshFormatError, match="negative or non-integer length"):
        read_ply(data)


@pytest.mark.parametrize("fmt, body", [
    ("ascii", b"0 0 0\n1 0 0\n0 1 0\n2\n"),
    ("binary_little_endian", b"\0" * 36 + b"\2\0\0\0"),
])  # fmt: skip
def test_scalar_vertex_indices_are_refused(fmt, body):  # r03: ValueError unpacking
    with pytest.raises(qem_core.MeshFormatError, match="is a scalar; a face's corners are a list"):
        read_ply(_ply(body, fmt, face="int vertex_indices"))


def _glb(gltf: dict, binary: bytes) -> bytes:
    text = json.dumps(gltf).encode() if isinstance(gltf, dict) else gltf
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    return (struct.pack("<4sII", b"glTF", 2, 28 + len(text) + len(binary))
            + struct.pack("<II", len(text), 0x4E4F534A) + text
            + struct.pack("<II", len(binary), 0x004E4942) + binary)  # fmt: skip


def test_a_glb_json_integer_past_pythons_digit_limit_is_refused():  # r04: ValueError
    text = b'{"asset":{"version":"2.0"},"x":' + b"9" * 5000 + b"}"
    with pytest.raises(qem_core.MeshFormatError, match="not valid JSON"):
        read_glb(_glb(text, b""))


POSITIONS = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], "<f4").tobytes()


def _one_primitive(index_type: int, index_kind: str, index_bytes: bytes, count: int) -> bytes:
    binary = POSITIONS + index_bytes
    return _glb({
        "asset": {"version": "2.0"}, "buffers": [{"byteLength": len(binary)}],
        "bufferViews": [{"buffer": 0, "byteLength": 36},
                        {"buffer": 0, "byteOffset": 36, "byteLength": len(index_bytes)}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
                      {"bufferView": 1, "componentType": index_type, "count": count,
                       "type": index_kind}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}, "indices": 1}]}],
    }, binary)  # fmt: skip


@pytest.mark.parametrize(("index_type", "kind", "data", "count"), [
    (5126, "SCALAR", np.array([0, 1.9, 2.5], "<f4").tobytes(), 3),  # r05: truncated
    (5122, "SCALAR", np.array([0, 1, 2], "<i2").tobytes(), 3),  # signed
    (5125, "VEC3", np.array([0, 1, 2], "<u4").tobytes(), 1),
])  # fmt: skip
def test_glb_indices_of_a_type_gltf_does_not_allow_are_refused(index_type, kind, data, count):
    with pytest.raises(qem_core.MeshFormatError, match="GLB indices accessor .* glTF 2.0 allows"):
        read_glb(_one_primitive(index_type, kind, data, count))
    assert read_glb(_one_primitive(5125, "SCALAR", np.array([0, 1, 2], "<u4").tobytes(), 3))


def _two_primitives(colour_types: tuple[str, str], uv_type: str | None = None) -> bytes:
    c3, c4 = np.full((3, 3), 0.5, "<f4").tobytes(), np.full((3, 4), 0.25, "<f4").tobytes()
    binary = POSITIONS + c3 + c4
    views = [{"buffer": 0, "byteOffset": 0, "byteLength": 36},
             {"buffer": 0, "byteOffset": 36, "byteLength": 36},
             {"buffer": 0, "byteOffset": 72, "byteLength": 48}]  # fmt: skip
    accessors = [
        {"bufferView": view, "componentType": 5126, "count": 3, "type": kind}
        for view, kind in ((0, "VEC3"), (1, "VEC3"), (2, "VEC4"), (1, "SCALAR"))
    ]
    kinds = {"VEC3": 1, "VEC4": 2}
    primitives = [{"attributes": {"POSITION": 0, "COLOR_0": kinds[t]}} for t in colour_types]
    if uv_type is not None:
        primitives = [{"attributes": {"POSITION": 0, "TEXCOORD_0": 3}}]
    gltf = {"asset": {"version": "2.0"}, "buffers": [{"byteLength": len(binary)}],
            "bufferViews": views, "accessors": accessors, "meshes": [{"primitives": primitives}]}
    return _glb(gltf, binary)


def test_a_scalar_texcoord_is_refused_by_its_check():  # r09 a: IndexError in the catch-all
    with pytest.raises(qem_core.MeshFormatError, match="TEXCOORD_0 accessor .* allows VEC2"):
        read_glb(_two_primitives(("VEC3",), uv_type="SCALAR"))


def test_rgb_and_rgba_colours_on_two_primitives_load():  # r09 b: a valid file refused
    mesh = qem_core.load_mesh(_two_primitives(("VEC3", "VEC4")), format="glb")
    colour = mesh.vertex_attributes["color"]
    assert mesh.n_vertices == 6 and colour.shape == (6, 4)  # other colours: not welded
    np.testing.assert_allclose(colour[:3], [[0.5, 0.5, 0.5, 1.0]] * 3)  # RGB made opaque
    np.testing.assert_allclose(colour[3:], [[0.25] * 4] * 3)


def test_a_served_level_whose_box_is_no_grid_is_refused():  # r06 (also in test_stream.py)
    level = msgpack.unpackb(qem_core.encode_mesh(TETRAHEDRON_V, TETRAHEDRON_F, "msgpack",
                                                 quantize_bits=16))  # fmt: skip
    for box in ([-1e308, 0, 0, 1e308, 1, 1], [1, 1, 1, 0, 0, 0]):
        with pytest.raises(qem_core.MeshFormatError, match="bbox"):
            SplitStreamDecoder.from_msgpack(msgpack.packb({**level, "bbox": box}))


@pytest.mark.parametrize("data", [b"STnOFF\t\xaf.", b"4OFF \xff\n", b"nOFF\n\xfe\xff"])
def test_a_refused_off_variant_with_bytes_that_are_not_utf8_is_refused(data):  # r07
    with pytest.raises(qem_core.MeshFormatError, match="only ASCII 3D OFF"):
        read_off(data)


def test_every_raw_input_of_the_findings_is_refused_or_read_right():
    folder = FINDINGS / "inputs"
    if not folder.is_dir():
        pytest.skip(f"{folder} is missing (the fuzz findings live beside the repository)")
    for path in sorted(folder.iterdir()):
        if path.suffix == ".txt":
            continue
        try:
            if path.suffix == ".qpm":
                pm = qem_core.load(path.read_bytes())
                for n in (pm.n_base, (pm.n_base + pm.n_full) // 2, pm.n_full):
                    level = pm.lod_mesh(n)
                    assert np.isfinite(level.vertices).all()
            else:
                qem_core.load_mesh(path)
        except qem_core.QemError as error:
            for foreign in ("IndexError", "ValueError:", "TypeError", "OverflowError",
                            "UnicodeDecodeError", "could not read as"):  # fmt: skip
                assert foreign not in str(error), (path.name, str(error))


def test_wedge_values_past_float32_at_their_scale_are_refused(uv_qpm):
    """Found by fuzz/ (qpm target): finite stored values that a level's division by
    their scale (in float32) took to infinity."""
    length = struct.unpack_from("<I", uv_qpm, 12)[0]
    header = msgpack.unpackb(uv_qpm[16 : 16 + length], raw=False)
    (entry,) = [e for e in header["arrays"] if e[0] == "base_wedge_values"]
    at = 16 + length + entry[3]
    body = bytearray(uv_qpm[:-4])
    body[at : at + 4] = struct.pack("<f", 3e38)
    with pytest.raises(qem_core.CorruptFileError, match="past float32's range"):
        qem_core.load(bytes(body) + struct.pack("<I", zlib.crc32(body)))


def test_a_signalling_nan_uv_is_refused_without_a_warning(recwarn):
    """Found by `python -m fuzz --target glb` (seeded with a two-material GLB): a UV
    read as float32 and widened for its primitive's texture transform raised numpy's
    RuntimeWarning, which the fuzzer counts as a finding; it is a NaN, refused."""
    from tests.unit.test_codec_attributes import _glb_json

    uvs = np.random.default_rng(1).random((4, 2)).astype(np.float32)
    blob = bytearray(qem_core.codecs.encode_mesh(TETRAHEDRON_V, TETRAHEDRON_F, "glb",
                                                 {"uv": uvs}))  # fmt: skip
    gltf = _glb_json(bytes(blob))
    accessor = gltf["accessors"][gltf["meshes"][0]["primitives"][0]["attributes"]["TEXCOORD_0"]]
    view = gltf["bufferViews"][accessor["bufferView"]]
    (json_length,) = struct.unpack_from("<I", blob, 12)
    at = 20 + json_length + 8 + view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
    blob[at : at + 4] = struct.pack("<I", 0x7FA00000)  # a signalling NaN
    with pytest.raises(qem_core.InvalidMeshError, match="(?i)nan|finite"):
        qem_core.load_mesh(bytes(blob), format="glb")
    assert [str(w.message) for w in recwarn] == []

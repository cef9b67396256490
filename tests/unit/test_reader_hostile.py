"""Hostile inputs against the mesh readers (fuzz findings r02, r03, r04, r05, r07 and
r09 of ../shared/fuzz-findings), each built here so that a clone without ../shared runs
them.

Every reader checks what it reads (types, shapes, ranges) where it reads it: a refusal
is a MeshFormatError whose message comes from that check and names the offending value,
never a foreign exception (ValueError, OverflowError, UnicodeDecodeError, IndexError, a
numpy error) reworded by a catch-all, either `load_mesh`'s ("could not read as ...") or
the glTF reader's ("does not follow glTF 2.0 (...)"); and no wrong value gets through.
"""

from __future__ import annotations

import json
import struct

import numpy as np
import pytest

import qem_core
from qem_core.codecs.glb import read_glb
from qem_core.codecs.off import read_off
from qem_core.codecs.ply import read_ply

# What a foreign exception reworded by a catch-all looks like in a message.
FOREIGN = (
    "could not read as",  # load_mesh's catch-all
    "does not follow glTF 2.0",  # read_glb's catch-all
    "Error",  # ValueError, IndexError, OverflowError, UnicodeDecodeError, KeyError, ...
    "codec can't decode",
    "not enough values to unpack",
    "cannot convert float",
    "set_int_max_str_digits",
    "input array dimensions",
    "index 1 is out of bounds",
)


def assert_own_message(error: BaseException) -> None:
    """The refusal came from a reader's own check, not from a catch-all."""
    message = str(error)
    for words in FOREIGN:
        assert words not in message, message
    assert error.__cause__ is None, repr(error.__cause__)


def refused(data: bytes, fmt: str, match: str) -> qem_core.MeshFormatError:
    """load_mesh(data) raises MeshFormatError matching ``match``, from its own check."""
    with pytest.raises(qem_core.MeshFormatError, match=match) as caught:
        qem_core.load_mesh(data, format=fmt)
    assert_own_message(caught.value)
    return caught.value


# r02, r03: PLY


def ply(body: bytes, fmt: str = "ascii", face: str = "list uchar int vertex_indices") -> bytes:
    header = (
        f"ply\nformat {fmt} 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
        f"property float z\nelement face 2\nproperty {face}\nend_header\n"
    )
    return header.encode() + body


VERTICES = b"0 0 0\n1 0 0\n0 1 0\n"


@pytest.mark.parametrize(
    ("faces", "record", "shown"),
    [
        (b"inf 0 1 2\n3 0 1 2\n", 0, "inf"),  # r02: OverflowError in read_ply
        (b"-inf 0 1 2\n3 0 1 2\n", 0, "-inf"),
        (b"nan 0 1 2\n3 0 1 2\n", 0, "nan"),
        (b"1e300 0 1 2\n3 0 1 2\n", 0, "1e\\+300"),
        (b"2.5 0 1 2\n3 0 1 2\n", 0, "2.5"),
        (b"-1 0 1 2\n3 0 1 2\n", 0, "-1"),
        (b"3 0 1 2\ninf 0 1 2\n", 1, "inf"),
        (b"3 0 1 2\n99 0 1 2\n", 1, "99"),  # more than the values left
    ],
)
def test_r02_a_ply_ascii_list_count_that_is_no_count_is_refused_with_its_value(
    faces, record, shown
):
    error = refused(
        ply(VERTICES + faces), "ply", f"record {record}'s 'vertex_indices' has length {shown},"
    )
    assert "a whole number no greater than the values that follow" in str(error)


def test_r02_a_negative_binary_list_count_is_refused_with_its_value():
    body = b"\0" * 36 + b"\x03" + struct.pack("<3i", 0, 1, 2) + b"\xff" + b"\0" * 12
    refused(
        ply(body, "binary_little_endian", "list char int vertex_indices"),
        "ply",
        "record 1's 'vertex_indices' has length -1,",
    )


@pytest.mark.parametrize(
    ("fmt", "body"),
    [("ascii", VERTICES + b"2\n2\n"), ("binary_little_endian", b"\0" * 36 + b"\2\0\0\0" * 2)],
)
def test_r03_scalar_vertex_indices_are_refused_as_not_a_list(fmt, body):
    # was ValueError "not enough values to unpack" in _build_mesh
    refused(
        ply(body, fmt, face="int vertex_indices"),
        "ply",
        "face property 'vertex_indices' is a scalar; a face's corners are a list "
        r"\('property list uchar int vertex_indices'\)",
    )


# r04, r05, r09: GLB


def glb_bytes(gltf: dict | bytes, binary: bytes = b"") -> bytes:
    text = json.dumps(gltf).encode() if isinstance(gltf, dict) else gltf
    text += b" " * (-len(text) % 4)
    binary += b"\0" * (-len(binary) % 4)
    return (
        struct.pack("<4sII", b"glTF", 2, 28 + len(text) + len(binary))
        + struct.pack("<II", len(text), 0x4E4F534A)
        + text
        + struct.pack("<II", len(binary), 0x004E4942)
        + binary
    )


class Document:
    """A glTF document under construction: each accessor gets its own bufferView."""

    def __init__(self) -> None:
        self.binary = b""
        self.views: list[dict] = []
        self.accessors: list[dict] = []
        self.primitives: list[dict] = []
        self.extensions: list[str] = []

    def accessor(self, values, dtype: str, kind: str, stride: int | None = None, **extra) -> int:
        """An accessor of ``values`` stored as ``dtype``; ``stride`` pads each element
        to that many bytes (glTF wants vertex elements 4-byte aligned)."""
        values = np.asarray(values)
        array = np.ascontiguousarray(values.astype(dtype))
        count = array.shape[0] if array.ndim > 1 else array.size
        data = array.tobytes()
        view = {"buffer": 0, "byteOffset": len(self.binary)}
        if stride is not None:
            element = array.itemsize * (array.shape[1] if array.ndim > 1 else 1)
            rows = array.reshape(count, -1).view(np.uint8).reshape(count, element)
            data = np.pad(rows, ((0, 0), (0, stride - element))).tobytes()
            view["byteStride"] = stride
        view["byteLength"] = len(data)
        self.binary += data + b"\0" * (-len(data) % 4)
        self.views.append(view)
        component = {"f4": 5126, "i1": 5120, "u1": 5121, "i2": 5122, "u2": 5123, "u4": 5125}
        self.accessors.append({
            "bufferView": len(self.views) - 1,
            "componentType": component[np.dtype(dtype).str[1:]],
            "count": count,
            "type": kind,
            **extra,
        })  # fmt: skip
        return len(self.accessors) - 1

    def primitive(self, indices: int | None = None, **attributes: int) -> None:
        primitive: dict = {"attributes": attributes}
        if indices is not None:
            primitive["indices"] = indices
        self.primitives.append(primitive)

    def glb(self) -> bytes:
        gltf: dict = {
            "asset": {"version": "2.0"},
            "buffers": [{"byteLength": len(self.binary)}],
            "bufferViews": self.views,
            "accessors": self.accessors,
            "meshes": [{"primitives": self.primitives}],
        }
        if self.extensions:
            gltf["extensionsUsed"] = gltf["extensionsRequired"] = self.extensions
        return glb_bytes(gltf, self.binary)


TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], np.float64)


def triangle(**attributes) -> Document:
    """A float triangle; ``attributes``: name -> (values, dtype, type, extra accessor keys)."""
    document = Document()
    names = {"POSITION": document.accessor(TRIANGLE, "<f4", "VEC3")}
    for name, (values, dtype, kind, extra) in attributes.items():
        names[name] = document.accessor(values, dtype, kind, **extra)
    document.primitive(**names)
    return document


def test_r04_a_glb_json_integer_of_more_digits_than_python_reads_is_refused():
    # was ValueError from json.loads escaping _chunks, outside read_glb's own handling
    text = b'{"asset":{"version":"2.0"},"x":' + b"9" * 5000 + b"}"
    error = refused(
        glb_bytes(text), "glb", "GLB JSON chunk is not valid JSON for glTF: it holds an"
    )
    assert "integer of more than" in str(error)
    with pytest.raises(qem_core.MeshFormatError, match="not valid JSON for glTF") as caught:
        read_glb(glb_bytes(text))  # the reader itself, not load_mesh, says so
    assert_own_message(caught.value)


def test_r04_the_same_integer_in_a_gltf_is_refused():
    text = b'{"asset":{"version":"2.0"},"x":-' + b"9" * 5000 + b"}"
    refused(text, "gltf", "glTF JSON is not valid JSON for glTF: it holds an integer")


def test_r04_a_glb_json_chunk_that_is_not_utf8_is_refused_with_the_byte():
    refused(glb_bytes(b'{"asset":"\xff"}'), "glb", "not UTF-8 text \\(byte 0xff at offset 10\\)")


def test_r04_malformed_glb_json_is_refused_as_such():
    refused(glb_bytes(b'{"asset": '), "glb", "GLB JSON chunk is not valid JSON: Expecting value")


def indexed(index_values, dtype: str, kind: str) -> bytes:
    document = Document()
    positions = document.accessor(TRIANGLE, "<f4", "VEC3")
    document.primitive(POSITION=positions, indices=document.accessor(index_values, dtype, kind))
    return document.glb()


@pytest.mark.parametrize(
    ("values", "dtype", "kind", "words"),
    [
        ([0, 1.9, 2.5], "<f4", "SCALAR", "componentType FLOAT \\(5126\\)"),  # r05: truncated
        ([0, 1, 2], "i1", "SCALAR", "componentType BYTE \\(5120\\)"),
        ([0, 1, 2], "<i2", "SCALAR", "componentType SHORT \\(5122\\)"),
        ([[0, 1, 2]], "<u4", "VEC3", "type 'VEC3'; glTF 2.0 allows SCALAR there"),
    ],
)
def test_r05_indices_of_a_type_gltf_does_not_allow_are_refused(values, dtype, kind, words):
    error = refused(indexed(values, dtype, kind), "glb", f"GLB indices accessor has {words}")
    if kind == "SCALAR":
        assert "allows UNSIGNED_BYTE, UNSIGNED_SHORT, UNSIGNED_INT there" in str(error)


@pytest.mark.parametrize("dtype", ["u1", "<u2", "<u4"])
def test_r05_unsigned_scalar_indices_still_load(dtype):
    mesh = qem_core.load_mesh(indexed([2, 1, 0], dtype, "SCALAR"), format="glb")
    assert mesh.faces.tolist() == [[2, 1, 0]]


UV = np.array([[0, 0], [1, 0], [0, 1]])
RGB = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255]])


@pytest.mark.parametrize(
    ("attributes", "words"),
    [
        # POSITION: float VEC3 (integers only with KHR_mesh_quantization)
        (
            {"POSITION": (TRIANGLE, "<u2", "VEC3", {})},
            "POSITION accessor has componentType UNSIGNED_SHORT \\(5123\\); glTF 2.0 allows "
            "FLOAT there; integer POSITION values need the file to use KHR_mesh_quantization",
        ),
        ({"POSITION": (TRIANGLE[:, :2], "<f4", "VEC2", {})}, "POSITION accessor has type 'VEC2'"),
        # NORMAL: float VEC3
        (
            {"NORMAL": (TRIANGLE, "i1", "VEC3", {"normalized": True})},
            "NORMAL accessor has componentType normalized BYTE \\(5120\\); glTF 2.0 allows FLOAT",
        ),
        ({"NORMAL": (TRIANGLE, "<f4", "VEC4", {})}, "NORMAL accessor has type 'VEC4'"),
        # TEXCOORD_0: float, or normalized unsigned byte/short, VEC2
        (
            {"TEXCOORD_0": (UV, "u1", "VEC2", {})},
            "TEXCOORD_0 accessor has componentType UNSIGNED_BYTE \\(5121\\); glTF 2.0 allows "
            "FLOAT, normalized UNSIGNED_BYTE, normalized UNSIGNED_SHORT there",
        ),
        (
            {"TEXCOORD_0": (UV, "<u4", "VEC2", {"normalized": True})},
            "TEXCOORD_0 accessor has componentType normalized UNSIGNED_INT",
        ),
        ({"TEXCOORD_0": (TRIANGLE, "<f4", "VEC3", {})}, "TEXCOORD_0 accessor has type 'VEC3'"),
        # COLOR_0: float, or normalized unsigned byte/short, VEC3 or VEC4
        (
            {"COLOR_0": (RGB, "u1", "VEC3", {})},  # would read as colours of 0..255
            "COLOR_0 accessor has componentType UNSIGNED_BYTE \\(5121\\); glTF 2.0 allows "
            "FLOAT, normalized UNSIGNED_BYTE, normalized UNSIGNED_SHORT there",
        ),
        (
            {"COLOR_0": (RGB, "<i2", "VEC3", {"normalized": True})},
            "COLOR_0 accessor has componentType normalized SHORT",
        ),
        (
            {"COLOR_0": (UV, "<f4", "VEC2", {})},
            "COLOR_0 accessor has type 'VEC2'; glTF 2.0 allows VEC3 or VEC4 there",
        ),
        (
            {"COLOR_0": (RGB, "u1", "VEC3", {"normalized": "yes"})},
            "COLOR_0 accessor has normalized 'yes'; it must be true or false",
        ),
    ],
)
def test_r05_attribute_accessors_are_checked_against_what_gltf_allows(attributes, words):
    if "POSITION" in attributes:
        values, dtype, kind, extra = attributes.pop("POSITION")
        document = Document()
        document.primitive(POSITION=document.accessor(values, dtype, kind, **extra))
    else:
        document = triangle(**attributes)
    refused(document.glb(), "glb", f"GLB {words}")


@pytest.mark.parametrize(
    ("change", "words"),
    [
        ({"componentType": None}, "componentType None"),
        ({"componentType": [5126]}, "componentType \\[5126\\]"),
        ({"componentType": True}, "componentType True"),
        ({"componentType": 5126.0}, "componentType 5126.0"),
        ({"type": ["VEC3"]}, "type \\['VEC3'\\]"),
        ({"type": None}, "type None"),
    ],
)
def test_r05_an_accessor_without_a_usable_format_is_refused_by_its_check(change, words):
    document = triangle()
    document.accessors[0].update(change)
    refused(document.glb(), "glb", f"GLB POSITION accessor has {words}")


def test_r05_a_primitive_without_position_is_refused_by_name():
    document = triangle()
    document.primitives[0]["attributes"] = {"NORMAL": 0}
    refused(document.glb(), "glb", "triangle primitive without a POSITION attribute")


def test_r05_normalized_integer_colours_and_uvs_load_scaled():
    rgba = np.array([[255, 0, 0, 255], [0, 255, 0, 0], [0, 0, 255, 51]])
    document = triangle(
        COLOR_0=(rgba, "u1", "VEC4", {"normalized": True}),
        TEXCOORD_0=(UV * 65535, "<u2", "VEC2", {"normalized": True}),
    )
    mesh = qem_core.load_mesh(document.glb(), format="glb")
    np.testing.assert_allclose(mesh.vertex_attributes["color"], rgba / 255.0, atol=1e-7)
    expected = np.stack([UV[:, 0], 1.0 - UV[:, 1]], axis=1)  # glTF's v flipped
    np.testing.assert_allclose(mesh.vertex_attributes["uv"], expected)


def test_r05_quantized_attributes_load_when_the_file_uses_khr_mesh_quantization():
    """KHR_mesh_quantization's integer positions (normalized or not), normals (normalized
    signed) and UVs (normalized or not), read as the accessors say."""
    document = Document()
    positions = document.accessor(TRIANGLE * 65535, "<u2", "VEC3", 8, normalized=True)
    raw = document.accessor(TRIANGLE * 7 - 1, "i1", "VEC3", 4)  # not normalized: as they are
    normals = document.accessor([[0, 0, 127]] * 3, "i1", "VEC3", 4, normalized=True)
    uvs = document.accessor(UV * 3, "<u2", "VEC2")  # not normalized: as they are
    document.primitive(POSITION=positions, NORMAL=normals, TEXCOORD_0=uvs)
    document.primitive(POSITION=raw, NORMAL=normals, TEXCOORD_0=uvs)
    document.extensions = ["KHR_mesh_quantization"]
    mesh = qem_core.load_mesh(document.glb(), format="glb")
    np.testing.assert_array_equal(mesh.vertices, np.concatenate([TRIANGLE, TRIANGLE * 7 - 1]))
    np.testing.assert_allclose(mesh.vertex_attributes["normal"], [[0, 0, 1]] * 6)
    np.testing.assert_allclose(mesh.corner_uvs[0], np.stack([UV[:, 0] * 3, 1 - UV[:, 1] * 3], 1))
    document.extensions = []
    refused(document.glb(), "glb", "POSITION values need the file to use KHR_mesh_quantization")


def two_colour_widths(uv_type: str | None = None) -> bytes:
    """Two primitives on one triangle, COLOR_0 of VEC3 then VEC4 (valid glTF 2.0); with
    ``uv_type``, one primitive whose TEXCOORD_0 is of that type instead."""
    document = Document()
    positions = document.accessor(TRIANGLE, "<f4", "VEC3")
    if uv_type is not None:
        uvs = document.accessor(np.full(3, 0.5), "<f4", uv_type)
        document.primitive(POSITION=positions, TEXCOORD_0=uvs)
        return document.glb()
    rgb = document.accessor(np.full((3, 3), 0.5), "<f4", "VEC3")
    rgba = document.accessor(np.full((3, 4), 0.25), "<f4", "VEC4")
    document.primitive(POSITION=positions, COLOR_0=rgb)
    document.primitive(POSITION=positions, COLOR_0=rgba)
    return document.glb()


def test_r09a_a_scalar_texcoord_is_refused_by_its_check():
    # was IndexError (uv[:, 1]) reworded by read_glb's catch-all
    refused(
        two_colour_widths(uv_type="SCALAR"),
        "glb",
        "GLB TEXCOORD_0 accessor has type 'SCALAR'; glTF 2.0 allows VEC2 there",
    )


def test_r09b_rgb_and_rgba_colours_on_two_primitives_load_with_rgb_opaque():
    # was refused through a numpy concatenate error in read_glb's catch-all
    mesh = qem_core.load_mesh(two_colour_widths(), format="glb")
    assert mesh.n_vertices == 6 and mesh.n_faces == 2  # other colours: not welded
    colour = mesh.vertex_attributes["color"]
    assert colour.shape == (6, 4) and colour.dtype == np.float32
    np.testing.assert_array_equal(colour[:3], [[0.5, 0.5, 0.5, 1.0]] * 3)  # alpha 1
    np.testing.assert_array_equal(colour[3:], [[0.25] * 4] * 3)
    np.testing.assert_array_equal(mesh.vertices, np.concatenate([TRIANGLE, TRIANGLE]))


# r07: OFF


@pytest.mark.parametrize(
    ("data", "shown"),
    [
        (b"STnOFF\t\xaf.", "STnOFF \ufffd."),  # the fuzzer's input
        (b"4OFF \xff\n3 1 0\n", "4OFF \ufffd"),
        (b"nOFF\n\xfe\xff", "nOFF"),
        (b"nOFF \xff\xfe 3\n", "nOFF \ufffd\ufffd"),
    ],
)
def test_r07_a_refused_off_variant_followed_by_bytes_that_are_not_utf8_is_refused(data, shown):
    # was UnicodeDecodeError while formatting the refusal
    error = refused(data, "off", "only ASCII 3D OFF is read; convert the file to plain OFF")
    assert str(error).startswith(f"mesh data: {shown}: ")
    with pytest.raises(qem_core.MeshFormatError, match="only ASCII 3D OFF"):
        read_off(data)


def test_r07_an_off_keyword_with_bytes_that_are_not_utf8_is_not_off():
    with pytest.raises(qem_core.MeshFormatError, match=r"starts with b'OFF\\xff', not 'OFF'"):
        read_off(b"OFF\xff BINARY\n")


def test_the_readers_themselves_raise_mesh_format_errors():
    """Called directly (no load_mesh in between), the readers refuse these by their own
    checks too."""
    for reader, data in (
        (read_ply, ply(VERTICES + b"inf 0 1 2\n3 0 1 2\n")),
        (read_ply, ply(VERTICES + b"2\n2\n", face="int vertex_indices")),
        (read_glb, indexed([0, 1.9, 2.5], "<f4", "SCALAR")),
        (read_glb, two_colour_widths(uv_type="SCALAR")),
        (read_off, b"STnOFF\t\xaf."),
    ):
        with pytest.raises(qem_core.MeshFormatError) as caught:
            reader(data)
        assert_own_message(caught.value)


def test_every_raw_glb_and_off_input_of_the_findings_loads_or_is_refused_by_a_check(
    fuzz_findings,
):
    inputs = fuzz_findings / "inputs"
    paths = sorted(p for p in inputs.glob("*") if p.suffix in (".glb", ".off"))
    if not paths:
        pytest.skip(f"no .glb or .off inputs in {inputs}")
    for path in paths:
        try:
            mesh = qem_core.load_mesh(path)
        except qem_core.QemError as error:
            for words in FOREIGN:
                assert words not in str(error), (path.name, str(error))
            assert error.__cause__ is None, (path.name, repr(error.__cause__))
        else:
            assert mesh.n_vertices > 0 and np.isfinite(mesh.vertices).all(), path.name

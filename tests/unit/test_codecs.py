"""Mesh codecs: every writer round-trips through load_mesh, and every reader refuses a
bad file with MeshFormatError or InvalidMeshError (never IndexError, ValueError,
MemoryError, a crash or a hang).

The precision each format promises, from qem_core/codecs: PLY, OBJ, GLB and msgpack
"f32" store float32 positions (so they read back as the float32 rounding of the input,
exactly); msgpack "u16" stores grid integers (within half a grid step); PLY stores colours
as uchar (within half of 1/255).
"""

import io
import struct

import msgpack
import numpy as np
import pytest

from qem_core import InvalidMeshError, InvalidOptionsError, MeshFormatError, encode_mesh, load_mesh
from qem_core.codecs._polygons import FAN_MAX_CORNERS
from tests.tiny_meshes import OCTAHEDRON, icosphere

WRITTEN = ["ply", "obj", "glb", "msgpack"]
READ = ["ply", "obj", "stl", "off", "glb", "msgpack"]
PNG = b"\x89PNG\r\n\x1a\n" + b"\0" * 32  # only the magic bytes matter to the codecs


def _sphere():
    vertices, faces = icosphere(1, jitter=0.1, seed=4)
    normals = vertices / np.linalg.norm(vertices, axis=1, keepdims=True)
    rng = np.random.default_rng(0)
    attributes = {
        "normal": normals.astype(np.float32),
        "color": rng.uniform(0, 1, (len(vertices), 4)).astype(np.float32),
        "uv": rng.uniform(0, 1, (len(vertices), 2)).astype(np.float32),
    }
    return vertices, faces, attributes


def _f32(values):
    return np.asarray(values, np.float32).astype(np.float64)


# -- writers round-trip ----------------------------------------------------------------


@pytest.mark.parametrize("fmt", WRITTEN)
def test_geometry_round_trips(fmt):
    vertices, faces, _ = _sphere()
    blob = encode_mesh(vertices, faces, fmt)
    mesh = load_mesh(blob, format=fmt)
    assert mesh.vertices.dtype == np.float64 and mesh.faces.dtype == np.int32
    if fmt == "obj":
        # 9 significant digits name each float32 uniquely, but the reader parses them as
        # float64: exact once rounded back to float32, within 1e-8 relative before.
        assert np.array_equal(mesh.vertices.astype(np.float32), vertices.astype(np.float32))
        np.testing.assert_allclose(mesh.vertices, _f32(vertices), rtol=1e-8)
    else:
        assert np.array_equal(mesh.vertices, _f32(vertices))
    assert np.array_equal(mesh.faces, faces)
    # The content alone tells the format (no name, no format=).
    sniffed = load_mesh(blob)
    assert np.array_equal(sniffed.vertices, mesh.vertices)
    assert np.array_equal(sniffed.faces, mesh.faces)


@pytest.mark.parametrize("fmt", WRITTEN)
def test_from_a_path_and_a_file_object(fmt, tmp_path):
    vertices, faces, _ = _sphere()
    blob = encode_mesh(vertices, faces, fmt)
    path = tmp_path / f"sphere.{'mpk' if fmt == 'msgpack' else fmt}"
    path.write_bytes(blob)
    for source in (path, str(path)):
        mesh = load_mesh(source)
        assert mesh.name == path.name and np.array_equal(mesh.faces, faces)
    with open(path, "rb") as file:
        assert np.array_equal(load_mesh(file).faces, faces)
    assert np.array_equal(load_mesh(io.BytesIO(blob), format=fmt).faces, faces)
    with open(path) as text_file, pytest.raises(MeshFormatError, match="binary mode"):
        load_mesh(text_file)


@pytest.mark.parametrize("fmt", WRITTEN)
def test_attributes_round_trip(fmt):
    vertices, faces, attributes = _sphere()
    mesh = load_mesh(encode_mesh(vertices, faces, fmt, attributes), format=fmt)
    got = mesh.vertex_attributes
    assert set(got) == {"normal", "color", "uv"}
    assert all(value.dtype == np.float32 for value in got.values())
    np.testing.assert_allclose(got["normal"], attributes["normal"], atol=1e-6)
    np.testing.assert_allclose(got["uv"], attributes["uv"], atol=1e-6)  # GLB flips v twice
    if fmt == "ply":
        np.testing.assert_allclose(got["color"], attributes["color"], atol=0.5 / 255 + 1e-7)
    elif fmt == "obj":
        # OBJ's "v x y z r g b" has no alpha.
        np.testing.assert_array_equal(got["color"], attributes["color"][:, :3])
    else:
        np.testing.assert_array_equal(got["color"], attributes["color"])


@pytest.mark.parametrize("fmt", ["glb", "msgpack"])
def test_texture_round_trips(fmt):
    vertices, faces, attributes = _sphere()
    mesh = load_mesh(encode_mesh(vertices, faces, fmt, attributes, PNG), format=fmt)
    assert mesh.texture == PNG


def test_glb_normals_are_written_unit_length():
    vertices, faces, attributes = _sphere()
    attributes["normal"] = 3 * attributes["normal"]
    attributes["normal"][0] = 0  # a zero normal becomes +z
    mesh = load_mesh(encode_mesh(vertices, faces, "glb", attributes))
    normal = mesh.vertex_attributes["normal"]
    np.testing.assert_allclose(np.linalg.norm(normal, axis=1), 1, atol=1e-6)
    assert normal[0].tolist() == [0, 0, 1]


def test_msgpack_float_and_name():
    vertices, faces, _ = _sphere()
    mesh = load_mesh(encode_mesh(vertices, faces, "msgpack", name="sphere.ply"))
    assert np.array_equal(mesh.vertices, _f32(vertices))
    assert mesh.name == "sphere.ply"


@pytest.mark.parametrize("bits", [1, 4, 10, 16])
def test_msgpack_quantised_is_within_half_a_grid_step(bits):
    vertices, faces, _ = _sphere()
    blob = encode_mesh(vertices, faces, "msgpack", quantize_bits=bits)
    message = msgpack.unpackb(blob)
    assert message["position_encoding"] == "u16" and message["position_bits"] == bits
    mesh = load_mesh(blob)
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    step = (high - low) / (2**bits - 1)
    assert np.all(np.abs(mesh.vertices - vertices) <= step / 2 * (1 + 1e-9))
    assert np.array_equal(mesh.faces, faces)


def test_msgpack_quantised_over_a_given_box():
    vertices, faces, _ = _sphere()
    box = (np.full(3, -2.0), np.full(3, 2.0))
    message = msgpack.unpackb(
        encode_mesh(vertices, faces, "msgpack", quantize_bits=16, grid_box=box)
    )
    assert message["bbox"] == [-2.0] * 3 + [2.0] * 3
    integers = np.frombuffer(message["positions"], "<u2").reshape(-1, 3)
    # By hand: q = round((x + 2) / 4 * 65535).
    assert np.array_equal(integers, np.rint((vertices + 2) / 4 * 65535))
    with pytest.raises(InvalidOptionsError, match="grid_box"):
        encode_mesh(vertices, faces, "msgpack", quantize_bits=16, grid_box=(box[0], box[0]))


def _strip(n_vertices):
    """A long strip of triangles with n_vertices vertices (n_vertices - 2 faces)."""
    i = np.arange(n_vertices)
    vertices = np.stack([i // 2, i % 2, np.zeros(n_vertices)], axis=1).astype(float)
    a = np.arange(n_vertices - 2)
    faces = np.where(
        (a % 2 == 0)[:, None], np.stack([a, a + 1, a + 2], 1), np.stack([a, a + 2, a + 1], 1)
    )
    return vertices, faces


@pytest.mark.parametrize("n_vertices, index_type", [
    (256, "u8"), (257, "u16"), (65536, "u16"), (65537, "u32"),
])  # fmt: skip
def test_msgpack_indices_use_the_smallest_type(n_vertices, index_type):
    """From the format: u8 for n <= 256, u16 for n <= 65536, else u32."""
    vertices, faces = _strip(n_vertices)
    blob = encode_mesh(vertices, faces, "msgpack")
    assert msgpack.unpackb(blob)["index_type"] == index_type
    assert np.array_equal(load_mesh(blob).faces, faces)


@pytest.mark.parametrize("n_vertices", [65535, 65536])
def test_glb_with_many_vertices_round_trips(n_vertices):
    """Indices are u16 up to 65535 vertices, u32 above (65535 is glTF's restart value)."""
    vertices, faces = _strip(n_vertices)
    mesh = load_mesh(encode_mesh(vertices, faces, "glb"))
    assert np.array_equal(mesh.faces, faces)


def test_encode_refuses_bad_requests():
    vertices, faces = OCTAHEDRON
    with pytest.raises(InvalidOptionsError, match="cannot write format"):
        encode_mesh(vertices, faces, "stl")
    with pytest.raises(InvalidOptionsError, match="msgpack"):
        encode_mesh(vertices, faces, "ply", quantize_bits=16)
    for bits in (0, 17, True, 8.0):
        with pytest.raises(InvalidOptionsError, match="quantize_bits"):
            encode_mesh(vertices, faces, "msgpack", quantize_bits=bits)
    with pytest.raises(InvalidMeshError, match="index"):
        encode_mesh(vertices, faces + 1, "ply")
    with pytest.raises(InvalidMeshError, match="attribute"):
        encode_mesh(vertices, faces, "ply", {"colour": np.zeros((6, 3))})
    with pytest.raises(InvalidMeshError, match="shape"):
        encode_mesh(vertices, faces, "ply", {"normal": np.zeros((5, 3))})
    with pytest.raises(InvalidMeshError, match="NaN"):
        encode_mesh(vertices, faces, "obj", {"uv": np.full((6, 2), np.nan)})


def test_glb_loads_in_trimesh():
    trimesh = pytest.importorskip("trimesh")
    vertices, faces, attributes = _sphere()
    blob = encode_mesh(vertices, faces, "glb", attributes, PNG)
    mesh = trimesh.load(io.BytesIO(blob), file_type="glb", force="mesh", process=False)
    assert np.array_equal(mesh.vertices, _f32(vertices))
    assert np.array_equal(mesh.faces, faces)
    # trimesh flips glTF's v back to a bottom-left origin, as qem_core's Mesh has it.
    np.testing.assert_allclose(mesh.visual.uv, attributes["uv"], atol=1e-6)
    plain = trimesh.load(
        io.BytesIO(encode_mesh(vertices, faces, "glb")),
        file_type="glb",
        force="mesh",
        process=False,
    )
    assert np.array_equal(plain.faces, faces)


# -- readers of formats qem_core does not write ------------------------------------------


def _stl_binary(vertices, faces, declared=None):
    facets = np.zeros(len(faces), [("n", "<f4", 3), ("c", "<f4", (3, 3)), ("a", "<u2")])
    facets["c"] = np.asarray(vertices)[np.asarray(faces)]
    count = len(faces) if declared is None else declared
    return b"\0" * 80 + struct.pack("<I", count) + facets.tobytes()


def _stl_ascii(vertices, faces):
    lines = ["solid test"]
    for tri in np.asarray(vertices)[np.asarray(faces)]:
        lines += ["facet normal 0 0 0", "outer loop"]
        lines += [f"vertex {x!r} {y!r} {z!r}" for x, y, z in tri.tolist()]
        lines += ["endloop", "endfacet"]
    return ("\n".join(lines + ["endsolid test"]) + "\n").encode()


def _off(vertices, faces, header="OFF"):
    lines = [header, f"{len(vertices)} {len(faces)} 0"]
    lines += [" ".join(map(repr, v)) for v in np.asarray(vertices).tolist()]
    lines += ["3 " + " ".join(map(str, f)) for f in np.asarray(faces).tolist()]
    return ("\n".join(lines) + "\n").encode()


def _ply_ascii(vertices, faces):
    lines = [
        "ply",
        "format ascii 1.0",
        f"element vertex {len(vertices)}",
        "property float x",
        "property float y",
        "property float z",
        f"element face {len(faces)}",
        "property list uchar int vertex_indices",
        "end_header",
    ]
    lines += [" ".join(map(repr, v)) for v in np.asarray(vertices).tolist()]
    lines += ["3 " + " ".join(map(str, f)) for f in np.asarray(faces).tolist()]
    return ("\n".join(lines) + "\n").encode()


@pytest.mark.parametrize("maker", [_stl_binary, _stl_ascii])
def test_stl_is_read_as_a_soup(maker):
    vertices, faces = OCTAHEDRON
    mesh = load_mesh(maker(vertices, faces), format="stl")
    # Three vertices per facet, as stored; welding is prepare_mesh's job.
    assert np.array_equal(mesh.vertices, vertices[faces.reshape(-1)])
    assert np.array_equal(mesh.faces, np.arange(24).reshape(8, 3))
    assert np.array_equal(load_mesh(maker(vertices, faces)).faces, mesh.faces)  # sniffed


def test_off_and_ascii_ply_are_read():
    vertices, faces = OCTAHEDRON
    for blob in (_off(vertices, faces), _ply_ascii(vertices, faces)):
        mesh = load_mesh(blob)
        assert np.array_equal(mesh.vertices, vertices)
        assert np.array_equal(mesh.faces, faces)


def test_ply_header_lines_may_end_in_crlf_or_cr_alone():
    """Regression: with CR alone the body was looked for after a LF that never came,
    and the file read as empty."""
    vertices, faces = OCTAHEDRON
    blob = _ply_ascii(vertices, faces)
    for newline in (b"\r\n", b"\r"):
        mesh = load_mesh(blob.replace(b"\n", newline), format="ply")
        assert np.array_equal(mesh.vertices, vertices)
        assert np.array_equal(mesh.faces, faces)


def test_polygons_are_fan_triangulated():
    """A quad (0 1 2 3) becomes (0 1 2) and (0 2 3), by hand."""
    square = b"v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nf 1 2 3 4\n"
    assert load_mesh(square, format="obj").faces.tolist() == [[0, 1, 2], [0, 2, 3]]
    off = b"OFF\n4 1 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n"
    assert load_mesh(off).faces.tolist() == [[0, 1, 2], [0, 2, 3]]


@pytest.mark.parametrize("k", [FAN_MAX_CORNERS + 1, FAN_MAX_CORNERS + 2, 1000, 1001])
def test_large_polygons_are_strips_of_low_degree(k):
    """Past FAN_MAX_CORNERS a polygon is a zigzag strip, by hand for 17 and 18 corners:
    the same area and orientation as a fan, every corner in at most four triangles
    (a 50 000-corner fan took the build 32 s)."""
    angles = np.linspace(0, 2 * np.pi, k, endpoint=False)
    vertices = np.stack([np.cos(angles), np.sin(angles), np.zeros(k)], axis=1)
    text = "".join(f"v {float(x)!r} {float(y)!r} 0\n" for x, y, _ in vertices)
    text += "f " + " ".join(str(i + 1) for i in range(k)) + "\n"
    faces = load_mesh(text.encode(), format="obj").faces
    assert faces.shape == (k - 2, 3)
    assert np.bincount(faces.reshape(-1), minlength=k).max() <= 4
    a, b, c = (vertices[faces[:, j]] for j in range(3))
    normals = np.cross(b - a, c - a)
    assert np.all(normals[:, 2] > 0)  # every triangle turns as the polygon does
    assert 0.5 * normals[:, 2].sum() == pytest.approx(0.5 * k * np.sin(2 * np.pi / k))
    if k <= FAN_MAX_CORNERS + 2:
        last = k - 1
        expected = [[0, 1, last], [1, last - 1, last], [1, 2, last - 1], [2, last - 2, last - 1]]
        assert faces[:4].tolist() == expected


# -- bad input -------------------------------------------------------------------------

_NAN_VERTICES = np.array([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]], float)
_TRIANGLE = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0]], float)

BAD_FILES = {
    # unknown or empty
    "empty": (b"", None),
    "empty_ply": (b"", "ply"),
    "empty_obj": (b"", "obj"),
    "empty_stl": (b"", "stl"),
    "empty_off": (b"", "off"),
    "empty_glb": (b"", "glb"),
    "empty_msgpack": (b"", "msgpack"),
    "binary_garbage": (bytes(range(256)) * 4, None),
    "unknown_format_name": (b"v 0 0 0\n", "xyz"),
    "whitespace": (b"   \n\n  ", None),
    # NaN coordinates
    "ply_nan": (_ply_ascii(_NAN_VERTICES, [[0, 1, 2]]), "ply"),
    "obj_nan": (b"v 0 0 0\nv 1 0 0\nv nan 1 0\nf 1 2 3\n", "obj"),
    "obj_inf": (b"v 0 0 0\nv 1 0 0\nv inf 1 0\nf 1 2 3\n", "obj"),
    "stl_nan": (_stl_ascii(_NAN_VERTICES, [[0, 1, 2]]), "stl"),
    "stl_binary_nan": (_stl_binary(_NAN_VERTICES, [[0, 1, 2]]), "stl"),
    "off_nan": (_off(_NAN_VERTICES, [[0, 1, 2]]), "off"),
    "msgpack_nan": (
        encode_mesh(_TRIANGLE, [[0, 1, 2]], "msgpack").replace(
            np.float32(1).tobytes(), np.float32(np.nan).tobytes(), 1
        ),
        "msgpack",
    ),
    # indices out of range
    "ply_index": (_ply_ascii(_TRIANGLE, [[0, 1, 3]]), "ply"),
    "ply_negative_index": (_ply_ascii(_TRIANGLE, [[0, 1, -1]]), "ply"),
    "ply_huge_index": (_ply_ascii(_TRIANGLE, [[0, 1, 2**40]]), "ply"),
    "ply_fractional_index": (_ply_ascii(_TRIANGLE, [[0, 1, 1.5]]), "ply"),
    "obj_index": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 4\n", "obj"),
    "obj_index_zero": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 0 1 2\n", "obj"),
    "obj_negative_too_far": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf -1 -2 -4\n", "obj"),
    "obj_huge_index": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 99999999999999999999\n", "obj"),
    "off_index": (_off(_TRIANGLE, [[0, 1, 3]]), "off"),
    "off_fractional_index": (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 1.5\n", "off"),
    "msgpack_index": (
        encode_mesh(_TRIANGLE, [[0, 1, 2]], "msgpack").replace(
            bytes([0, 1, 2]), bytes([0, 1, 9]), 1
        ),
        "msgpack",
    ),
    # counts that promise more than the file holds
    "ply_huge_count": (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\n"
        b"property float x\nproperty float y\nproperty float z\n"
        b"element face 1\nproperty list uchar int vertex_indices\n"
        b"end_header\n" + b"\0" * 64,
        "ply",
    ),
    "ply_ascii_huge_count": (
        _ply_ascii(_TRIANGLE, [[0, 1, 2]]).replace(b"element face 1", b"element face 999999999999"),
        "ply",
    ),
    "ply_huge_list": (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
        b"property float x\nproperty float y\nproperty float z\n"
        b"element face 1\nproperty list uint int vertex_indices\n"
        b"end_header\n" + b"\0" * 36 + struct.pack("<I", 2**32 - 1) + b"\0" * 12,
        "ply",
    ),
    "ply_negative_list": (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n"
        b"property float x\nproperty float y\nproperty float z\n"
        b"element face 2\nproperty list char int vertex_indices\n"
        b"end_header\n" + b"\0" * 36 + b"\x03" + b"\0" * 12 + b"\xff" + b"\0" * 12,
        "ply",
    ),
    "stl_huge_count": (_stl_binary(_TRIANGLE, [[0, 1, 2]], declared=2**32 - 1), "stl"),
    "off_huge_count": (b"OFF\n1000000000000 1000000000000 0\n0 0 0\n", "off"),
    "off_negative_count": (b"OFF\n-3 1 0\n0 0 0\n", "off"),
    "off_corner_count_lies": (b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n1000000 0 1 2\n", "off"),
    "msgpack_huge_count": (
        msgpack.packb(
            {
                **msgpack.unpackb(encode_mesh(_TRIANGLE, [[0, 1, 2]], "msgpack")),
                "vertex_count": 2**62,
            }
        ),
        "msgpack",
    ),
    # truncated
    "ply_truncated": (encode_mesh(*OCTAHEDRON, "ply")[:-7], "ply"),
    "ply_header_only": (b"ply\nformat ascii 1.0\nelement vertex 3\n", "ply"),
    "stl_truncated": (_stl_binary(*OCTAHEDRON)[:-30], "stl"),
    "stl_ascii_truncated": (_stl_ascii(*OCTAHEDRON)[:-80], "stl"),
    "off_truncated": (_off(*OCTAHEDRON)[:-12], "off"),
    "glb_truncated": (encode_mesh(*OCTAHEDRON, "glb")[:-20], "glb"),
    "msgpack_truncated": (encode_mesh(*OCTAHEDRON, "msgpack")[:-5], "msgpack"),
    # malformed
    "ply_bad_format": (b"ply\nformat xml 1.0\nend_header\n", "ply"),
    "ply_unknown_type": (_ply_ascii(_TRIANGLE, [[0, 1, 2]]).replace(b"float x", b"real x"), "ply"),
    "ply_no_faces": (
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\n"
        b"property float y\nproperty float z\nend_header\n0 0 0\n",
        "ply",
    ),
    "ply_not_numbers": (_ply_ascii(_TRIANGLE, [[0, 1, 2]]).replace(b"0.0 1.0", b"zero 1.0"), "ply"),
    "obj_bad_corner": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1/1/1/1 2 3\n", "obj"),
    "obj_two_corners": (b"v 0 0 0\nv 1 0 0\nf 1 2\n", "obj"),
    "obj_words": (b"v zero 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "obj"),
    "obj_no_faces": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\n", "obj"),
    "obj_short_vertex": (b"v 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "obj"),
    "stl_ascii_short_vertex": (
        _stl_ascii(_TRIANGLE, [[0, 1, 2]]).replace(b"vertex 0.0 1.0 0.0", b"vertex 0.0 1.0"),
        "stl",
    ),
    # Regression: cut after a facet, it loaded the facets before the cut.
    "stl_ascii_cut_after_a_facet": (
        _stl_ascii(*OCTAHEDRON).split(b"endfacet")[0] + b"endfacet", "stl"
    ),
    "off_binary": (b"OFF BINARY\n" + b"\0" * 40, "off"),
    "off_4d": (b"4OFF\n1 0 0\n0 0 0 0\n", "off"),
    "off_words": (b"OFF\nthree one zero\n", "off"),
    "glb_wrong_version": (b"glTF" + struct.pack("<II", 1, 12), "glb"),
    "glb_bad_json": (
        b"glTF" + struct.pack("<II", 2, 24) + struct.pack("<II", 4, 0x4E4F534A) + b"{{{{",
        "glb",
    ),
    "glb_no_json": (b"glTF" + struct.pack("<II", 2, 12), "glb"),
    # Regression: json.loads raised RecursionError past the codec.
    "glb_deep_json": (
        b"glTF" + struct.pack("<II", 2, 20 + 200_000) + struct.pack("<II", 200_000, 0x4E4F534A)
        + b"[" * 100_000 + b"]" * 100_000,
        "glb",
    ),
    # Regression: the layout came from the second 'vertex', the values from the first
    # (KeyError 'x').
    "ply_element_twice": (
        b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float a\nelement vertex 3\n"
        b"property float x\nproperty float y\nproperty float z\nelement face 1\n"
        b"property list uchar int vertex_indices\nend_header\n5\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
        "ply",
    ),
    "msgpack_not_a_map": (msgpack.packb([1, 2, 3]), "msgpack"),
    "msgpack_float_bits": (
        msgpack.packb(
            {
                **msgpack.unpackb(encode_mesh(_TRIANGLE, [[0, 1, 2]], "msgpack", quantize_bits=8)),
                "position_bits": 8.0,
            }
        ),
        "msgpack",
    ),
    # Regression: a float 3.0 passed the width check and broke reshape (TypeError), which
    # failed the server's build as an internal error.
    "msgpack_float_components": (
        msgpack.packb(
            {
                **msgpack.unpackb(encode_mesh(_TRIANGLE, [[0, 1, 2]], "msgpack")),
                "attributes": {
                    "color": {"components": 3.0, "type": "f32", "data": bytes(36)},
                },
            }
        ),
        "msgpack",
    ),
    "msgpack_boolean_bbox": (
        msgpack.packb(
            {
                **msgpack.unpackb(encode_mesh(_TRIANGLE, [[0, 1, 2]], "msgpack")),
                "bbox": [True, 0, 0, 1, 1, 1],
            }
        ),
        "msgpack",
    ),
    "msgpack_future_version": (
        msgpack.packb(
            {**msgpack.unpackb(encode_mesh(_TRIANGLE, [[0, 1, 2]], "msgpack")), "version": 2}
        ),
        "msgpack",
    ),
}


@pytest.mark.parametrize("name", list(BAD_FILES))
def test_bad_files_are_refused_clearly(name):
    blob, fmt = BAD_FILES[name]
    with pytest.raises(InvalidMeshError) as caught:
        load_mesh(blob, format=fmt)
    assert str(caught.value)  # a message, not a bare exception


@pytest.mark.parametrize("fmt", ["ply", "obj", "glb", "msgpack"])
@pytest.mark.parametrize("scale", [1e300, 1e-320])
def test_positions_float32_cannot_hold_are_refused_on_writing(fmt, scale):
    """Regression: written as inf, or as one point of zeros and subnormals."""
    with pytest.raises(InvalidMeshError, match="float32"):
        encode_mesh(np.asarray(_TRIANGLE) * scale, [[0, 1, 2]], fmt)


@pytest.mark.parametrize("scale", [1e300, 1e-320])
def test_msgpack_on_a_grid_writes_any_finite_positions(scale):
    """The grid over the box holds them (a box a few subnormals across quantises to its
    origin, where a step of 0 gave NaN)."""
    vertices = np.asarray(_TRIANGLE, np.float64) * scale
    blob = encode_mesh(vertices, [[0, 1, 2]], "msgpack", quantize_bits=16)
    decoded = load_mesh(blob, format="msgpack")
    assert np.isfinite(decoded.vertices).all()
    assert np.allclose(decoded.vertices, vertices, rtol=0, atol=1e-4 * scale + 1e-300)


def test_an_obj_with_a_byte_order_mark_reads_as_without():
    """Regression: the mark hid the first line, so the first vertex was lost and every
    index named the next vertex."""
    text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\nf 1 2 4\n"
    plain, marked = load_mesh(text, format="obj"), load_mesh(b"\xef\xbb\xbf" + text, format="obj")
    assert np.array_equal(marked.vertices, plain.vertices)
    assert np.array_equal(marked.faces, plain.faces)


def test_unknown_format_and_source_are_named():
    with pytest.raises(MeshFormatError, match="unknown mesh format 'xyz'"):
        load_mesh(b"v 0 0 0\n", format="xyz")
    with pytest.raises(MeshFormatError, match="cannot tell the mesh format"):
        load_mesh(bytes(range(256)))
    with pytest.raises(MeshFormatError, match="cannot read a mesh from int"):
        load_mesh(12)


def _glb_with(change, blob: bytes | None = None) -> bytes:
    """A GLB (the octahedron's by default) with its JSON changed by change(gltf), lengths
    redone."""
    import json

    blob = encode_mesh(*OCTAHEDRON, "glb") if blob is None else blob
    json_length = struct.unpack_from("<I", blob, 12)[0]
    gltf = json.loads(blob[20 : 20 + json_length])
    binary = blob[20 + json_length + 8 :]
    change(gltf)
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(binary)
    return (
        struct.pack("<4sII", b"glTF", 2, total)
        + struct.pack("<II", len(text), 0x4E4F534A)
        + text
        + struct.pack("<II", len(binary), 0x004E4942)
        + binary
    )


def _set_path(*path, value):
    def change(gltf):
        node = gltf
        for key in path[:-1]:
            node = node[key]
        node[path[-1]] = value

    return change


@pytest.mark.parametrize("change", [
    _set_path("accessors", 0, "count", value=10**12),
    _set_path("accessors", 0, "count", value=-5),
    _set_path("accessors", 1, "count", value=2**40),
    _set_path("accessors", 0, "byteOffset", value=10**9),
    _set_path("accessors", 0, "componentType", value=9999),
    _set_path("accessors", 0, "type", value="MAT9"),
    _set_path("accessors", 0, "sparse", value={}),
    _set_path("accessors", 0, "bufferView", value=99),
    _set_path("accessors", 0, "bufferView", value=-1),
    _set_path("accessors", 0, "type", value="VEC2"),
    _set_path("bufferViews", 0, "byteLength", value=10**9),
    _set_path("bufferViews", 0, "byteOffset", value=-4),
    _set_path("bufferViews", 0, "byteStride", value=2),
    _set_path("bufferViews", 0, "buffer", value=3),
    _set_path("buffers", 0, "byteLength", value=10**9),
    _set_path("buffers", 0, "uri", value="../../etc/passwd"),
    _set_path("buffers", 0, "uri", value="data:application/octet-stream;base64,!!!"),
    _set_path("meshes", 0, "primitives", 0, "indices", value=42),
    _set_path("meshes", 0, "primitives", 0, "attributes", value={}),
    _set_path("meshes", 0, "primitives", 0, "mode", value=0),
    _set_path("meshes", 0, "primitives", 0, "material", value=5),
    _set_path("meshes", 0, "primitives", 0, "attributes", value="POSITION"),
    _set_path("meshes", 0, "primitives", value=None),
    _set_path("meshes", value=[{"primitives": [{}]}]),
    _set_path("meshes", value="all"),
    _set_path("extensionsRequired", value=["EXT_not_an_extension_we_read"]),
    _set_path("extensionsRequired", value="KHR_draco_mesh_compression"),  # not a list
    _set_path("extensionsRequired", value=[["KHR_draco_mesh_compression"]]),  # found by fuzz/
    _set_path("extensionsUsed", value=[{"name": "EXT_meshopt_compression"}]),
])  # fmt: skip
def test_lying_glb_json_is_refused(change):
    with pytest.raises(MeshFormatError):
        load_mesh(_glb_with(change))


@pytest.mark.parametrize(("key", "value"), [
    ("count", 1e400),  # json.dumps writes Infinity, which Python's json reads back
    ("count", 3.5),
    ("count", "8"),
    ("count", True),
    ("byteOffset", -12),
])  # fmt: skip
def test_glb_counts_and_offsets_must_be_whole_numbers(key, value):
    with pytest.raises(MeshFormatError, match=f"{key} is .*not a non-negative integer"):
        load_mesh(_glb_with(_set_path("accessors", 0, key, value=value)))


def test_glb_attribute_of_another_count_than_the_positions_is_named():
    mesh = load_mesh(encode_mesh(*OCTAHEDRON, "glb"))
    attributes = {"normal": np.tile([[0.0, 0.0, 1.0]], (mesh.n_vertices, 1))}

    def shorter_normals(gltf):
        normals = gltf["meshes"][0]["primitives"][0]["attributes"]["NORMAL"]
        gltf["accessors"][normals]["count"] -= 1

    blob = _glb_with(shorter_normals, encode_mesh(mesh.vertices, mesh.faces, "glb", attributes))
    with pytest.raises(MeshFormatError, match="5 NORMAL values for 6 positions"):
        load_mesh(blob)


def test_polygon_messages_number_obj_lines_from_1_and_show_plain_numbers():
    with pytest.raises(MeshFormatError, match="OBJ 'f' line 2 has 2 corners"):
        load_mesh(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1 2\n", format="obj")
    with pytest.raises(MeshFormatError, match="OFF face 0 says it has 2.5 corners"):
        load_mesh(b"OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n2.5 0 1 2\n", format="off")
    ply = _ply_ascii(_TRIANGLE, [[0, 1, 2]]).replace(b"3 0 1 2", b"3 0 1 2.5")
    with pytest.raises(MeshFormatError, match="PLY face index 2.5 is not an integer"):
        load_mesh(ply, format="ply")


def test_glb_with_out_of_range_indices_is_refused():
    blob = bytearray(encode_mesh(*OCTAHEDRON, "glb"))
    # The index accessor comes after the positions (6 x 12 bytes) in the BIN chunk; the
    # first index (uint16) is set to 7 with 6 vertices.
    json_length = struct.unpack_from("<I", blob, 12)[0]
    first_index = 20 + json_length + 8 + 6 * 12
    blob[first_index : first_index + 2] = struct.pack("<H", 7)
    with pytest.raises(InvalidMeshError, match="index 7"):
        load_mesh(bytes(blob))


# -- every truncation and many flipped bytes: a mesh or a clear error, nothing else -------


def _small_files():
    vertices, faces = OCTAHEDRON
    attributes = {"normal": vertices, "color": np.abs(vertices), "uv": vertices[:, :2] / 2 + 0.5}
    return {
        "ply": encode_mesh(vertices, faces, "ply", attributes),
        "ply_ascii": _ply_ascii(vertices, faces),
        "obj": encode_mesh(vertices, faces, "obj", attributes),
        "stl": _stl_binary(vertices, faces),
        "stl_ascii": _stl_ascii(vertices, faces),
        "off": _off(vertices, faces),
        "glb": encode_mesh(vertices, faces, "glb", attributes, PNG),
        "msgpack": encode_mesh(vertices, faces, "msgpack", attributes, PNG),
        "msgpack_u16": encode_mesh(vertices, faces, "msgpack", quantize_bits=16),
        # Corner UVs with seams: OBJ vt per corner, PLY texcoord lists, GLB split
        # vertices and their record, msgpack corner_uvs.
        **{
            f"{fmt}_seams": encode_mesh(vertices, faces, fmt, corner_uvs=_SEAMS)
            for fmt in ("obj", "ply", "glb", "msgpack")
        },
    }


_SEAMS = (np.arange(8 * 3 * 2).reshape(8, 3, 2) % 7 / 7).astype(np.float32)


def _load_or_refuse(blob, fmt):
    try:
        mesh = load_mesh(blob, format=fmt)
    except InvalidMeshError as error:
        assert str(error)
        return
    # What loads is a valid mesh.
    assert np.isfinite(mesh.vertices).all()
    assert mesh.faces.size and 0 <= mesh.faces.min() and mesh.faces.max() < len(mesh.vertices)


@pytest.mark.parametrize("name", list(_small_files()))
def test_every_truncation_loads_or_is_refused(name):
    blob = _small_files()[name]
    fmt = name.split("_")[0]
    for length in range(len(blob)):
        _load_or_refuse(blob[:length], fmt)
        _load_or_refuse(blob[:length], None)


@pytest.mark.parametrize("name", list(_small_files()))
def test_flipped_bytes_load_or_are_refused(name):
    blob = _small_files()[name]
    fmt = name.split("_")[0]
    rng = np.random.default_rng(len(blob))
    for position in range(len(blob)):
        for bit in rng.choice(8, size=2, replace=False):
            damaged = bytearray(blob)
            damaged[position] ^= 1 << int(bit)
            _load_or_refuse(bytes(damaged), fmt)


def test_glb_primitives_sharing_one_accessor_without_end_are_refused(monkeypatch):
    """Regression: thousands of primitives naming one POSITION accessor copied it each
    time (a 300 KB file asked for gigabytes). Sharing is allowed up to the data the
    buffers could hold (times four, plus an allowance, set to 0 here to test it small).
    Primitives of one mesh naming the same attribute accessors share their vertices (a
    mesh of several materials); their indices still count against the budget."""
    from qem_core.codecs import glb

    monkeypatch.setattr(glb, "_SHARED_ALLOWANCE", 0)

    def primitives(times):
        return lambda gltf: gltf["meshes"][0].update(
            primitives=gltf["meshes"][0]["primitives"] * times
        )

    shared = load_mesh(_glb_with(primitives(4)))
    assert shared.n_vertices == OCTAHEDRON[0].shape[0]
    assert shared.n_faces == 4 * OCTAHEDRON[1].shape[0]
    with pytest.raises(MeshFormatError, match="share accessors"):
        load_mesh(_glb_with(primitives(40)))

"""Appearance attributes through every writer: corner UVs (texture seams included),
colours, normals and the texture survive write -> read in each format that has a place
for them, and bad attribute input is refused clearly.

What each format promises (qem_core/codecs): OBJ, PLY and msgpack store corner UVs as
float32 per corner (exact); GLB splits a vertex per (position, UV) and stores v flipped
(1 - v), so its UVs come back within two float32 roundings; its reader welds the split
back, so positions and faces come back as written.
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from qem_core import InvalidMeshError, MeshFormatError
from qem_core.codecs import _corners, encode_mesh, load_mesh, write_mesh
from qem_core.mesh import Mesh
from tests.conftest import REPO
from tests.tiny_meshes import OCTAHEDRON

FORMATS = ["obj", "glb", "ply", "msgpack"]
SPOT = REPO / "server" / "demo" / "spot.obj"  # ships with the repo: UVs with seams
PNG = b"\x89PNG\r\n\x1a\n" + b"\0" * 32  # only the magic bytes matter to the codecs
# GLB flips v on the way out and back: 1 - (1 - v), two float32 roundings of values
# below 4 in magnitude.
GLB_UV_TOLERANCE = 3e-7


def _f32(values):
    return np.asarray(values, np.float32).astype(np.float64)


def _assert_same_uvs(got, expected, fmt):
    assert got is not None, f"{fmt} lost the corner UVs"
    assert got.dtype == np.float32 and got.shape == expected.shape
    if fmt == "glb":
        np.testing.assert_allclose(got, expected, rtol=0, atol=GLB_UV_TOLERANCE)
    else:
        np.testing.assert_array_equal(got, expected)


@pytest.fixture(scope="module")
def spot():
    if not SPOT.is_file():
        pytest.skip(f"the demo mesh {SPOT} is missing")
    return load_mesh(SPOT)


def test_spot_has_seams(spot):
    """The demo cow is a fair test: some positions carry several UVs."""
    corner_vertices = spot.faces.reshape(-1)
    pairs = np.unique(
        np.column_stack([corner_vertices, spot.corner_uvs.reshape(-1, 2).view(np.uint32)]),
        axis=0,
    )
    assert len(pairs) > spot.n_vertices  # 3225 (position, UV) pairs on 2930 positions
    assert "uv" not in spot.vertex_attributes  # ambiguous at seams


@pytest.mark.parametrize("fmt", FORMATS)
def test_spot_round_trips_with_its_seams(spot, fmt):
    mesh = load_mesh(write_mesh(spot, fmt), format=fmt)
    assert np.array_equal(mesh.vertices.astype(np.float32), spot.vertices.astype(np.float32))
    assert np.array_equal(mesh.faces, spot.faces)
    _assert_same_uvs(mesh.corner_uvs, spot.corner_uvs, fmt)
    assert "uv" not in mesh.vertex_attributes


@pytest.mark.parametrize("fmt", FORMATS)
def test_write_mesh_is_encode_mesh_with_the_mesh_fields(spot, fmt):
    by_fields = encode_mesh(
        spot.vertices,
        spot.faces,
        fmt,
        spot.vertex_attributes,
        None,
        spot.corner_uvs,
        name=spot.name,
    )
    assert write_mesh(spot, fmt) == by_fields
    with pytest.raises(InvalidMeshError, match="Mesh"):
        write_mesh((spot.vertices, spot.faces), fmt)


def test_spot_texture_is_embedded_in_glb_and_msgpack(spot, shared_meshes):
    texture = (shared_meshes / "spot_texture.png").read_bytes()
    textured = Mesh(spot.vertices, spot.faces, corner_uvs=spot.corner_uvs, texture=texture)
    for fmt in ("glb", "msgpack"):
        mesh = load_mesh(write_mesh(textured, fmt), format=fmt)
        assert mesh.texture == texture
        _assert_same_uvs(mesh.corner_uvs, spot.corner_uvs, fmt)


# -- GLB: one glTF vertex per (position, UV), valid for other readers ----------------


def _glb_json(blob: bytes) -> dict:
    length = struct.unpack_from("<I", blob, 12)[0]
    return json.loads(blob[20 : 20 + length])


def _with_glb_json(blob: bytes, gltf: dict) -> bytes:
    """The GLB with its JSON chunk replaced (the BIN chunk kept)."""
    old_length = struct.unpack_from("<I", blob, 12)[0]
    rest = blob[20 + old_length :]
    text = json.dumps(gltf).encode()
    text += b" " * (-len(text) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + rest
    return struct.pack("<4sII", b"glTF", 2, 12 + len(body)) + body


def test_glb_splits_seams_into_valid_glTF(spot):
    blob = write_mesh(spot, "glb")
    gltf = _glb_json(blob)
    primitive = gltf["meshes"][0]["primitives"][0]
    accessors = gltf["accessors"]
    n_gltf = accessors[primitive["attributes"]["POSITION"]]["count"]
    assert n_gltf == 3225  # the (position, UV) pairs
    for name in ("POSITION", "TEXCOORD_0"):
        assert accessors[primitive["attributes"][name]]["count"] == n_gltf
    indices = accessors[primitive["indices"]]
    assert indices["count"] == 3 * spot.n_faces and indices["componentType"] == 5123
    position = accessors[primitive["attributes"]["POSITION"]]
    vertices = spot.vertices.astype(np.float32)
    assert position["min"] == vertices.min(axis=0).tolist()
    assert position["max"] == vertices.max(axis=0).tolist()
    for accessor in accessors:  # every accessor fits its buffer view
        view = gltf["bufferViews"][accessor["bufferView"]]
        width = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}[accessor["type"]]
        size = {5123: 2, 5125: 4, 5126: 4}[accessor["componentType"]]
        assert accessor["count"] * width * size == view["byteLength"]
        assert view["byteOffset"] % 4 == 0
    assert (
        sum(-v["byteLength"] % 4 + v["byteLength"] for v in gltf["bufferViews"])
        == (gltf["buffers"][0]["byteLength"])
    )


def test_a_texture_that_is_not_png_jpeg_or_webp_is_left_out(spot):
    # Another exporter's GLB may embed a KTX2 image: the mesh and its UVs load, the image
    # is dropped (a level could not re-embed it), for GLB and msgpack alike.
    mesh = Mesh(spot.vertices, spot.faces, corner_uvs=spot.corner_uvs, texture=PNG)
    webp = b"\xabKTX 20\xbb\r\n"  # KTX2's signature
    for fmt in ("glb", "msgpack"):
        blob = write_mesh(mesh, fmt)
        assert blob.count(PNG) == 1
        loaded = load_mesh(blob.replace(PNG, webp + PNG[len(webp):]), format=fmt)
        assert loaded.texture is None
        np.testing.assert_allclose(loaded.corner_uvs, spot.corner_uvs, atol=GLB_UV_TOLERANCE)
        assert write_mesh(loaded, "glb")  # and its levels still encode


def test_glb_with_seams_loads_in_trimesh(spot):
    trimesh = pytest.importorskip("trimesh")
    mesh = Mesh(spot.vertices, spot.faces, corner_uvs=spot.corner_uvs, texture=PNG)
    loaded = trimesh.load(
        io.BytesIO(write_mesh(mesh, "glb")), file_type="glb", force="mesh", process=False
    )
    assert len(loaded.vertices) == 3225 and len(loaded.faces) == spot.n_faces
    # Corner by corner, trimesh sees the same positions and (v flipped back) UVs.
    assert np.array_equal(loaded.vertices[loaded.faces], _f32(spot.vertices)[spot.faces])
    np.testing.assert_allclose(
        loaded.visual.uv[loaded.faces], spot.corner_uvs, rtol=0, atol=GLB_UV_TOLERANCE
    )


def test_a_foreign_glb_split_at_seams_is_welded_by_position(spot):
    """A GLB from another exporter (no qem-lod record of the split): vertices equal in
    position, normal and colour are welded, their UVs kept per corner."""
    blob = write_mesh(spot, "glb")
    gltf = _glb_json(blob)
    del gltf["meshes"][0]["primitives"][0]["extras"]
    gltf["asset"]["generator"] = "another exporter"
    mesh = load_mesh(_with_glb_json(blob, gltf), format="glb")
    assert mesh.n_vertices == spot.n_vertices
    # Welding keeps the first copy of each position: map back through the positions.
    order = {tuple(v): i for i, v in enumerate(spot.vertices.astype(np.float32).tolist())}
    renumber = np.array([order[tuple(v)] for v in mesh.vertices.astype(np.float32).tolist()])
    assert np.array_equal(renumber[mesh.faces], spot.faces)
    _assert_same_uvs(mesh.corner_uvs, spot.corner_uvs, "glb")


def test_a_foreign_glb_keeps_vertices_split_by_normal():
    """Copies of a position with different normals (a hard edge) stay apart: welding
    them would lose a normal."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0]], float)
    faces = np.array([[0, 1, 2], [3, 2, 1]])
    normals = np.array([[0, 0, 1], [0, 0, 1], [0, 0, 1], [0, 1, 0]], np.float32)
    blob = encode_mesh(vertices, faces, "glb", {"normal": normals})
    gltf = _glb_json(blob)
    gltf["asset"]["generator"] = "another exporter"
    mesh = load_mesh(_with_glb_json(blob, gltf), format="glb")
    assert mesh.n_vertices == 4 and np.array_equal(mesh.faces, faces)
    # The same file with equal normals welds vertex 3 onto vertex 0.
    blob = encode_mesh(vertices, faces, "glb", {"normal": normals[[0, 1, 2, 0]]})
    mesh = load_mesh(_with_glb_json(blob, gltf), format="glb")
    assert mesh.n_vertices == 3 and np.array_equal(mesh.faces, [[0, 1, 2], [0, 2, 1]])


@pytest.mark.parametrize("with_uvs", [False, True])
def test_qem_glb_keeps_coincident_vertices_apart(with_uvs):
    """Two vertices at one position that the mesh keeps apart (e.g. a cut) stay apart in
    a qem-lod GLB: its reader undoes exactly the writer's split."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [-1, 0, 0]], float)
    faces = np.array([[0, 1, 2], [3, 2, 4]])
    corner_uvs = np.array([[[0, 0], [1, 0], [0, 1]], [[0.5, 0.5], [0, 1], [1, 1]]], np.float32)
    blob = encode_mesh(vertices, faces, "glb", corner_uvs=corner_uvs if with_uvs else None)
    mesh = load_mesh(blob)
    assert np.array_equal(mesh.vertices, vertices) and np.array_equal(mesh.faces, faces)
    if with_uvs:
        _assert_same_uvs(mesh.corner_uvs, corner_uvs, "glb")


def test_glb_vertex_record_that_lies_is_refused(spot):
    blob = write_mesh(spot, "glb")
    gltf = _glb_json(blob)
    primitive = gltf["meshes"][0]["primitives"][0]
    primitive["extras"]["qem_lod_vertex_of"] = primitive["indices"]  # wrong length
    with pytest.raises(MeshFormatError, match="qem_lod_vertex_of"):
        load_mesh(_with_glb_json(blob, gltf), format="glb")


# -- OBJ and PLY layouts ---------------------------------------------------------------


def _two_triangles_with_a_seam():
    """A square of two triangles whose diagonal is a seam: vertices 0 and 2 carry other
    UVs in each triangle."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    faces = np.array([[0, 1, 2], [0, 2, 3]])
    corner_uvs = np.array(
        [[[0, 0], [0.5, 0], [0.5, 0.5]], [[0.6, 0], [1, 0.5], [0.6, 0.5]]], np.float32
    )
    return vertices, faces, corner_uvs


def test_obj_writes_each_distinct_uv_once_and_corners_as_given():
    vertices, faces, corner_uvs = _two_triangles_with_a_seam()
    corner_uvs[1, 2] = corner_uvs[0, 0]  # a UV used at two positions: one vt line
    text = encode_mesh(vertices, faces, "obj", corner_uvs=corner_uvs).decode()
    lines = text.splitlines()
    assert sum(line.startswith("vt ") for line in lines) == 5
    assert "mtllib" not in text
    faces_lines = [line for line in lines if line.startswith("f ")]
    assert all(len(corner.split("/")) == 2 for line in faces_lines for corner in line.split()[1:])
    mesh = load_mesh(text.encode(), format="obj")
    assert np.array_equal(mesh.faces, faces)
    _assert_same_uvs(mesh.corner_uvs, corner_uvs, "obj")
    assert "uv" not in mesh.vertex_attributes  # vertices 0 and 2 have two UVs


def test_obj_with_uvs_normals_and_colours():
    vertices, faces, corner_uvs = _two_triangles_with_a_seam()
    attributes = {
        "normal": np.tile([0, 0, 1], (4, 1)).astype(np.float32),
        "color": np.linspace(0, 1, 16).reshape(4, 4).astype(np.float32),
        "uv": np.zeros((4, 2), np.float32),  # corner_uvs win over it
    }
    blob = encode_mesh(vertices, faces, "obj", attributes, PNG, corner_uvs)
    first_face = next(line for line in blob.decode().splitlines() if line.startswith("f "))
    corners = [corner.split("/") for corner in first_face.split()[1:]]
    assert [(v, n) for v, _, n in corners] == [("1", "1"), ("2", "2"), ("3", "3")]
    mesh = load_mesh(blob, format="obj")
    _assert_same_uvs(mesh.corner_uvs, corner_uvs, "obj")
    np.testing.assert_array_equal(mesh.vertex_attributes["normal"], attributes["normal"])
    np.testing.assert_array_equal(mesh.vertex_attributes["color"], attributes["color"][:, :3])


def test_ply_stores_corner_uvs_as_the_meshlab_texcoord_list():
    vertices, faces, corner_uvs = _two_triangles_with_a_seam()
    blob = encode_mesh(vertices, faces, "ply", corner_uvs=corner_uvs)
    header, body = blob.split(b"end_header\n")
    assert header.endswith(
        b"property list uchar int vertex_indices\nproperty list uchar float texcoord\n"
    )
    records = np.frombuffer(
        body[4 * 12 :], [("n", "u1"), ("v", "<i4", 3), ("n_uv", "u1"), ("uv", "<f4", 6)]
    )
    assert records["n_uv"].tolist() == [6, 6]
    assert np.array_equal(records["uv"].reshape(-1, 3, 2), corner_uvs)
    mesh = load_mesh(blob)
    _assert_same_uvs(mesh.corner_uvs, corner_uvs, "ply")


def test_ascii_ply_polygons_with_texcoord_are_fan_triangulated():
    text = b"""ply
format ascii 1.0
comment as MeshLab writes it
element vertex 4
property float x
property float y
property float z
element face 1
property list uchar int vertex_indices
property list uchar float texcoord
property int texnumber
end_header
0 0 0
1 0 0
1 1 0
0 1 0
4 0 1 2 3 8 0 0 1 0 1 1 0 1 0
"""
    mesh = load_mesh(text, format="ply")
    assert np.array_equal(mesh.faces, [[0, 1, 2], [0, 2, 3]])
    expected = np.array([[[0, 0], [1, 0], [1, 1]], [[0, 0], [1, 1], [0, 1]]], np.float32)
    _assert_same_uvs(mesh.corner_uvs, expected, "ply")
    # One UV per vertex: the "uv" attribute too, as OBJ's reader gives it.
    np.testing.assert_array_equal(mesh.vertex_attributes["uv"], [[0, 0], [1, 0], [1, 1], [0, 1]])
    with pytest.raises(MeshFormatError, match="texcoord"):
        load_mesh(text.replace(b"8 0 0 1 0 1 1 0 1", b"6 0 0 1 0 1 1 0 1"), format="ply")


# -- colours ---------------------------------------------------------------------------


@pytest.mark.parametrize("fmt", FORMATS)
def test_airplane_colours_survive(shared_meshes, fmt):
    airplane = load_mesh(shared_meshes / "airplane_colored.ply")
    colors = airplane.vertex_attributes["color"]
    assert colors.shape[1] == 4
    mesh = load_mesh(write_mesh(airplane, fmt), format=fmt)
    assert np.array_equal(mesh.faces, airplane.faces)
    got = mesh.vertex_attributes["color"]
    if fmt == "obj":  # the common "v x y z r g b" extension has no alpha
        np.testing.assert_array_equal(got, colors[:, :3])
    else:  # uchar in the file: k / 255 read back exactly as float32 in every format
        np.testing.assert_array_equal(got, colors)


# -- random meshes ---------------------------------------------------------------------


@st.composite
def textured_meshes(draw):
    n_vertices = draw(st.integers(3, 12))
    n_faces = draw(st.integers(1, 10))
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    vertices = rng.uniform(-10, 10, (n_vertices, 3))
    if draw(st.booleans()):  # coincident vertices, kept apart by the mesh
        vertices[-1] = vertices[0]
    faces = np.stack([rng.choice(n_vertices, 3, replace=False) for _ in range(n_faces)])
    # UVs from a small pool (shared by corners: seams and non-seams) or anything.
    pool = rng.uniform(-2, 3, (draw(st.integers(1, 6)), 2)).astype(np.float32)
    if draw(st.booleans()):
        corner_uvs = pool[rng.integers(0, len(pool), (n_faces, 3))]
    else:
        corner_uvs = rng.uniform(-2, 3, (n_faces, 3, 2)).astype(np.float32)
    attributes = {}
    if draw(st.booleans()):
        attributes["normal"] = rng.normal(size=(n_vertices, 3)).astype(np.float32)
    if draw(st.booleans()):
        attributes["color"] = (rng.integers(0, 256, (n_vertices, 4)) / 255).astype(np.float32)
    return Mesh(vertices, faces, attributes, corner_uvs=corner_uvs)


@settings(max_examples=60, derandomize=True)
@given(mesh=textured_meshes())
def test_random_corner_uvs_round_trip(mesh):
    for fmt in FORMATS:
        got = load_mesh(write_mesh(mesh, fmt), format=fmt)
        assert np.array_equal(got.vertices.astype(np.float32), mesh.vertices.astype(np.float32))
        assert np.array_equal(got.faces, mesh.faces), fmt
        _assert_same_uvs(got.corner_uvs, mesh.corner_uvs, fmt)
        assert sorted(got.vertex_attributes.keys() - {"uv"}) == sorted(mesh.vertex_attributes)
        if "color" in mesh.vertex_attributes:
            width = 3 if fmt == "obj" else 4
            np.testing.assert_array_equal(
                got.vertex_attributes["color"], mesh.vertex_attributes["color"][:, :width]
            )
        if "normal" in mesh.vertex_attributes and fmt != "glb":  # GLB makes them unit
            np.testing.assert_array_equal(
                got.vertex_attributes["normal"], mesh.vertex_attributes["normal"]
            )


# -- bad input -------------------------------------------------------------------------


@pytest.mark.parametrize("fmt", FORMATS)
def test_bad_corner_uvs_are_refused(fmt):
    vertices, faces = OCTAHEDRON
    good = np.zeros((len(faces), 3, 2), np.float32)
    with pytest.raises(InvalidMeshError, match=r"corner_uvs must have shape \(8, 3, 2\)"):
        encode_mesh(vertices, faces, fmt, corner_uvs=good[:-1])
    with pytest.raises(InvalidMeshError, match="shape"):
        encode_mesh(vertices, faces, fmt, corner_uvs=good.reshape(8, 6))
    with pytest.raises(InvalidMeshError, match="numbers"):
        encode_mesh(vertices, faces, fmt, corner_uvs=good.astype(str))
    bad = good.copy()
    bad[5, 1, 0] = np.nan
    with pytest.raises(InvalidMeshError, match="face 5 .*NaN"):
        encode_mesh(vertices, faces, fmt, corner_uvs=bad)
    bad[5, 1, 0] = np.inf
    with pytest.raises(InvalidMeshError, match="face 5"):
        write_mesh(Mesh(vertices, faces, corner_uvs=bad), fmt)


def test_bad_msgpack_corner_uvs_are_refused():
    vertices, faces = OCTAHEDRON
    blob = encode_mesh(vertices, faces, "msgpack", corner_uvs=np.zeros((8, 3, 2)))
    message = msgpack.unpackb(blob)
    assert message["corner_uvs"]["type"] == "f32" and len(message["corner_uvs"]["data"]) == 192
    short = {**message, "corner_uvs": {"type": "f32", "data": b"\0" * 190}}
    with pytest.raises(MeshFormatError, match="190 bytes"):
        load_mesh(msgpack.packb(short), format="msgpack")
    for wrong in ([0.0] * 48, {"type": "u16", "data": b"\0" * 96}):
        with pytest.raises(MeshFormatError, match="corner_uvs"):
            load_mesh(msgpack.packb({**message, "corner_uvs": wrong}), format="msgpack")
    nan = {**message, "corner_uvs": {"type": "f32", "data": np.full(48, np.nan, "<f4").tobytes()}}
    with pytest.raises(InvalidMeshError, match="NaN"):
        load_mesh(msgpack.packb(nan), format="msgpack")


def test_obj_with_nan_texture_coordinates_is_refused():
    text = b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 nan\nvt 1 0\nvt 0 1\nf 1/1 2/2 3/3\n"
    with pytest.raises(InvalidMeshError, match="NaN"):
        load_mesh(text, format="obj")


def test_files_are_named_in_messages(tmp_path: Path):
    path = tmp_path / "broken.obj"
    path.write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 inf\nf 1/1 2/1 3/1\n")
    with pytest.raises(InvalidMeshError, match="broken.obj"):
        load_mesh(path)


@pytest.mark.parametrize("multiplier", [None, 0])
def test_weld_is_exact_even_when_hashes_collide(monkeypatch, multiplier):
    """The GLB reader's weld: rows equal in every column merge, in first-seen order;
    with a multiplier of 0 every hash is the last word alone, so different rows share
    hashes and the exact fallback must answer the same."""
    if multiplier is not None:
        monkeypatch.setattr(_corners, "_HASH_MULTIPLIER", np.uint64(multiplier))
    rng = np.random.default_rng(3)
    positions = rng.integers(0, 4, (500, 3)).astype(float)
    normals = np.zeros((500, 3), np.float32)
    normals[:, 0] = positions[:, 2]  # the last word (normal z, padding) is 0 in every row
    kept, index = _corners.weld([positions, normals])
    unique, first = np.unique(positions, axis=0, return_index=True)
    assert kept.tolist() == sorted(first.tolist())
    assert np.array_equal(positions[kept][index], positions)
    empty = _corners.weld([np.zeros((0, 3)), np.zeros((0, 3), np.float32)])
    assert [a.size for a in empty] == [0, 0]


@pytest.mark.parametrize("fmt", FORMATS)
def test_a_level_without_faces_takes_empty_corner_uvs(fmt):
    """A coarse level of a build without topology preservation may have no faces."""
    blob = encode_mesh(np.eye(3), np.zeros((0, 3), int), fmt, corner_uvs=np.zeros((0, 3, 2)))
    assert blob

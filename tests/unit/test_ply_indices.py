"""PLY face indices of every type the format has, read straight to int32 (the type of
`Mesh.faces`) without an int64 copy of the whole list: values right for every integer
and float type, both byte orders, triangle-only faces (the records mapped with one
dtype) and mixed polygons (the records walked); uint32 values of 2^31 or more read
exactly and refused by validation naming them; out-of-range values refused."""

from __future__ import annotations

import numpy as np
import pytest

import qem_core
from qem_core.codecs.ply import read_ply

_TYPES = {
    "char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4",
    "uint": "u4", "float": "f4", "double": "f8",
}  # fmt: skip
_ORDERS = {"binary_little_endian": "<", "binary_big_endian": ">"}

# A fan of triangles around vertex 0 over a rim of 100 vertices: indices up to 100 fit
# every type, char included.
_N = 101
_VERTICES = np.concatenate(
    [
        [[0.0, 0.0, 1.0]],
        np.stack(
            [np.cos(np.arange(100) * 0.06), np.sin(np.arange(100) * 0.06), np.zeros(100)],
            axis=1,
        ),
    ]
)
_TRIANGLES = np.stack([np.zeros(99), np.arange(1, 100), np.arange(2, 101)], axis=1).astype(int)


def _header(fmt: str, n_vertices: int, n_faces: int, count_type: str, index_type: str) -> bytes:
    lines = [
        "ply", f"format {fmt} 1.0", f"element vertex {n_vertices}",
        "property float x", "property float y", "property float z",
        f"element face {n_faces}", f"property list {count_type} {index_type} vertex_indices",
        "end_header",
    ]  # fmt: skip
    return ("\n".join(lines) + "\n").encode()


def _binary_ply(polygons, index_type: str, fmt: str, vertices=_VERTICES) -> bytes:
    order = _ORDERS[fmt]
    body = np.asarray(vertices, f"{order}f4").tobytes()
    for polygon in polygons:
        body += np.array([len(polygon)], "u1").tobytes()
        body += np.array(polygon, f"{order}{_TYPES[index_type]}").tobytes()
    return _header(fmt, len(vertices), len(polygons), "uchar", index_type) + body


def _ascii_ply(polygons, vertices=_VERTICES) -> bytes:
    lines = [" ".join(f"{x:.9g}" for x in vertex) for vertex in vertices]
    lines += [" ".join(str(i) for i in [len(p), *p]) for p in polygons]
    return (
        _header("ascii", len(vertices), len(polygons), "uchar", "int")
        + ("\n".join(lines) + "\n").encode()
    )


def _quads_and_triangles():
    """The fan's triangles, every third pair of them merged into a quad, as polygons,
    and the triangles the reader makes of them (a quad a b c d -> a b c, a c d)."""
    polygons, triangles = [], []
    i = 0
    while i < len(_TRIANGLES):
        a, b, c = _TRIANGLES[i]
        if i % 3 == 0 and i + 1 < len(_TRIANGLES):
            d = _TRIANGLES[i + 1][2]
            polygons.append([a, b, c, d])
            triangles += [[a, b, c], [a, c, d]]
            i += 2
        else:
            polygons.append([a, b, c])
            triangles.append([a, b, c])
            i += 1
    return polygons, np.array(triangles)


@pytest.mark.parametrize("fmt", sorted(_ORDERS))
@pytest.mark.parametrize("index_type", sorted(_TYPES))
def test_triangles_of_every_index_type_are_read_as_int32(index_type, fmt):
    mesh = read_ply(_binary_ply(_TRIANGLES.tolist(), index_type, fmt))
    assert mesh.faces.dtype == np.int32
    assert mesh.faces.flags.c_contiguous
    np.testing.assert_array_equal(mesh.faces, _TRIANGLES)
    np.testing.assert_array_equal(mesh.vertices, _VERTICES.astype(np.float32))
    assert mesh.vertices.dtype == np.float64


@pytest.mark.parametrize("fmt", sorted(_ORDERS))
@pytest.mark.parametrize("index_type", sorted(_TYPES))
def test_mixed_polygons_of_every_index_type_are_read_as_int32(index_type, fmt):
    polygons, triangles = _quads_and_triangles()
    mesh = read_ply(_binary_ply(polygons, index_type, fmt))
    assert mesh.faces.dtype == np.int32
    np.testing.assert_array_equal(mesh.faces, triangles)


def test_ascii_indices_are_read_as_int32():
    polygons, triangles = _quads_and_triangles()
    for faces, expected in ((_TRIANGLES.tolist(), _TRIANGLES), (polygons, triangles)):
        mesh = read_ply(_ascii_ply(faces))
        assert mesh.faces.dtype == np.int32
        np.testing.assert_array_equal(mesh.faces, expected)


@pytest.mark.parametrize("fmt", sorted(_ORDERS))
def test_indices_up_to_the_largest_int32_are_read_right(fmt):
    """Values near 2^31 - 1 in uint and int survive the narrowing unchanged (validation
    then refuses them against the small vertex count, naming the value)."""
    big = 2**31 - 1
    for index_type in ("int", "uint"):
        faces = [[0, 1, 2], [big, 1, 2]]
        mesh = read_ply(_binary_ply(faces, index_type, fmt))
        assert mesh.faces.dtype == np.int32
        np.testing.assert_array_equal(mesh.faces, faces)
        with pytest.raises(qem_core.InvalidMeshError, match=f"vertex index {big},"):
            qem_core.load_mesh(_binary_ply(faces, index_type, fmt), format="ply")


@pytest.mark.parametrize("fmt", sorted(_ORDERS))
@pytest.mark.parametrize("value", [2**31, 3_000_000_000, 2**32 - 1])
@pytest.mark.parametrize("mixed", [False, True])
def test_uint32_indices_past_int32_are_read_exactly_then_refused(fmt, value, mixed):
    """A uint index of 2^31 or more is never wrapped to a negative int32: it is read as
    it is (int64) and refused by validation, which names it (no vertex count reaches it)."""
    faces = [[0, 1, 2], [1, value, 2]] + ([[0, 1, 2, 3]] if mixed else [])
    data = _binary_ply(faces, "uint", fmt)
    mesh = read_ply(data)
    assert mesh.faces[1, 1] == value
    assert mesh.faces.min() >= 0
    with pytest.raises(qem_core.InvalidMeshError, match=f"vertex index {value},.*not below"):
        qem_core.load_mesh(data, format="ply")


@pytest.mark.parametrize("index_type", ["char", "short", "int"])
def test_negative_indices_are_refused_by_validation(index_type):
    data = _binary_ply([[0, 1, 2], [0, -1, 2]], index_type, "binary_little_endian")
    np.testing.assert_array_equal(read_ply(data).faces[1], [0, -1, 2])
    with pytest.raises(qem_core.InvalidMeshError, match="vertex index -1,.*negative"):
        qem_core.load_mesh(data, format="ply")


@pytest.mark.parametrize("value", [2.0**31, -(2.0**31) - 1, 1.5, float("nan"), float("inf")])
@pytest.mark.parametrize("index_type", ["float", "double"])
def test_float_indices_must_be_integers_in_int32_range(index_type, value):
    if index_type == "float" and value == -(2.0**31) - 1:
        value = -(2.0**32)  # -2^31 - 1 is not a float32
    data = _binary_ply([[0, 1, 2], [0, value, 2]], index_type, "binary_little_endian")
    with pytest.raises(qem_core.MeshFormatError, match="not an integer vertex index"):
        read_ply(data)


def test_an_empty_face_list_is_refused_without_a_crash():
    data = _binary_ply([[0, 1, 2], []], "int", "binary_little_endian")
    with pytest.raises(qem_core.MeshFormatError, match="face 1 has 0 corners"):
        read_ply(data)


def test_a_big_triangle_file_is_read_without_an_int64_copy_of_its_indices():
    """The int32 faces are the only array of the face list's size that the reader makes:
    the file's records are read in place (no flat copy, no int64 widening, no per-face
    counts)."""
    import tracemalloc

    rng = np.random.default_rng(0)
    n_faces, n_vertices = 200_000, 1000
    vertices = rng.random((n_vertices, 3)).astype(np.float32)
    faces = rng.integers(0, n_vertices, (n_faces, 3)).astype("<i4")
    records = np.zeros(n_faces, [("n", "u1"), ("v", "<i4", (3,))])
    records["n"], records["v"] = 3, faces
    data = _header("binary_little_endian", n_vertices, n_faces, "uchar", "int")
    data += vertices.tobytes() + records.tobytes()
    tracemalloc.start()
    try:
        mesh = read_ply(data)
        _, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    np.testing.assert_array_equal(mesh.faces, faces)
    # int32 faces (12 B a face), the float64 vertices and small change; before: 12 B of
    # flat items, 8 of counts and 24 of int64 indices a face on top.
    assert peak < 14 * n_faces + 24 * n_vertices + 65536

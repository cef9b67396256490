"""Input preparation: welding, dropped faces and vertices, the report, and non-manifold
input that the build must survive. Expected counts are worked out by hand in comments.
"""

from collections import Counter

import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st

import qem_core
from qem_core._kernels.topology import MAX_FACES_COMPARED, find_edges
from qem_core.prepare import prepare_mesh, unique_edges
from tests import reference
from tests.tiny_meshes import BOWTIE, CUBE, FIN, OCTAHEDRON, SQUARE, TETRAHEDRON, soup


def test_the_docstring_example():
    """prepare.py's sketch: 3 coincides with 0, 4 is unreferenced; faces 1 and 2 become
    duplicates of face 0 after welding."""
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 0], [5, 5, 5]], float)
    faces = np.array([[0, 1, 2], [3, 2, 1], [1, 2, 3]])
    prepared = prepare_mesh(vertices, faces)
    assert prepared.vertex_map.tolist() == [0, 1, 2, 0, -1]
    assert prepared.face_map.tolist() == [0, -1, -1]
    assert prepared.faces.tolist() == [[0, 1, 2]]
    assert prepared.vertices.tolist() == vertices[:3].tolist()
    assert prepared.report == {
        "unreferenced_vertices": 1,
        "merged_vertices": 1,
        "degenerate_faces": 0,
        "duplicate_faces": 2,
        "non_manifold_edges": 0,
        "boundary_edges": 3,
        "components": 1,
    }


def test_an_stl_soup_is_welded_back_into_the_closed_cube():
    vertices, faces = soup(*CUBE)  # 12 faces x 3 corners = 36 vertices
    prepared = prepare_mesh(vertices, faces)
    assert prepared.vertices.shape == (8, 3) and prepared.faces.shape == (12, 3)
    assert prepared.report["merged_vertices"] == 36 - 8
    assert prepared.report["unreferenced_vertices"] == 0
    assert prepared.report["boundary_edges"] == 0 and prepared.report["components"] == 1
    # Each soup vertex maps to the kept vertex at its own position.
    assert np.array_equal(prepared.vertices[prepared.vertex_map], vertices)
    assert reference.is_closed_manifold(prepared.faces)
    assert reference.euler_characteristic(prepared.faces) == 2
    # Kept vertices keep their input order: first appearances in the soup, in order.
    _, first = np.unique(vertices, axis=0, return_index=True)
    assert np.array_equal(prepared.vertices, vertices[np.sort(first)])


def test_without_welding_a_soup_stays_a_soup():
    vertices, faces = soup(*CUBE)
    prepared = prepare_mesh(vertices, faces, merge_coincident=False)
    assert prepared.vertices.shape == (36, 3)
    assert prepared.report["merged_vertices"] == 0
    assert prepared.report["components"] == 12 and prepared.report["boundary_edges"] == 36


def test_negative_zero_is_welded_onto_zero():
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [-0.0, -0.0, 0], [0, 0, 1]])
    faces = np.array([[0, 1, 2], [3, 2, 4]])
    prepared = prepare_mesh(vertices, faces)
    assert prepared.vertex_map.tolist() == [0, 1, 2, 0, 3]
    assert prepared.report["merged_vertices"] == 1


def test_nearly_coincident_vertices_are_not_welded():
    vertices = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [np.nextafter(0, 1), 0, 0], [0, 0, 1]])
    prepared = prepare_mesh(vertices, np.array([[0, 1, 2], [3, 2, 4]]))
    assert prepared.report["merged_vertices"] == 0 and len(prepared.vertices) == 5


def test_degenerate_faces_are_dropped_zero_area_ones_kept():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [0, 0, 0]], float)
    faces = np.array([
        [0, 1, 2],  # kept
        [0, 0, 1],  # two corners on one vertex: dropped
        [1, 2, 2],  # dropped
        [0, 1, 3],  # three distinct collinear vertices: zero area, kept
        [4, 1, 0],  # 4 welds onto 0: dropped as degenerate
    ])  # fmt: skip
    prepared = prepare_mesh(vertices, faces)
    assert prepared.face_map.tolist() == [0, -1, -1, 1, -1]
    assert prepared.report["degenerate_faces"] == 3
    assert prepared.report["duplicate_faces"] == 0
    # Vertex 4 is welded onto 0, which is kept: merged, not unreferenced.
    assert prepared.report["merged_vertices"] == 1
    assert prepared.report["unreferenced_vertices"] == 0


def test_duplicate_faces_in_any_order_or_orientation_are_dropped():
    vertices, faces = TETRAHEDRON
    extra = np.array([faces[0], faces[0][[1, 2, 0]], faces[1][::-1], faces[2]])
    prepared = prepare_mesh(vertices, np.concatenate([faces, extra]))
    assert prepared.report["duplicate_faces"] == 4
    assert prepared.face_map.tolist() == [0, 1, 2, 3, -1, -1, -1, -1]
    assert np.array_equal(prepared.faces, faces)  # the first of each is kept


def test_unreferenced_vertices_are_dropped_and_the_rest_renumbered():
    vertices, faces = SQUARE
    # Put an unused vertex first and one in the middle: indices shift by hand.
    padded = np.concatenate([[[7, 7, 7]], vertices[:2], [[8, 8, 8]], vertices[2:]])
    prepared = prepare_mesh(padded, np.array([[1, 2, 4], [1, 4, 5]]))
    assert prepared.vertex_map.tolist() == [-1, 0, 1, -1, 2, 3]
    assert prepared.report["unreferenced_vertices"] == 2
    assert np.array_equal(prepared.vertices, vertices)
    assert np.array_equal(prepared.faces, faces)


def test_a_vertex_only_used_by_a_dropped_face_is_unreferenced():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [5, 5, 5]], float)
    prepared = prepare_mesh(vertices, np.array([[0, 1, 2], [3, 3, 0]]))
    assert prepared.vertex_map.tolist() == [0, 1, 2, -1]
    assert prepared.report["unreferenced_vertices"] == 1


def test_report_counts_boundary_and_non_manifold_edges_and_components():
    # FIN: edge 0-1 has three faces; the other 6 edges one each.
    fin = prepare_mesh(*FIN).report
    assert fin["non_manifold_edges"] == 1 and fin["boundary_edges"] == 6
    assert fin["components"] == 1
    # BOWTIE: two triangles sharing vertex 0 are one component (joined by a vertex).
    bowtie = prepare_mesh(*BOWTIE).report
    assert bowtie["boundary_edges"] == 6 and bowtie["components"] == 1
    # Two separate octahedra.
    v, f = OCTAHEDRON
    two = prepare_mesh(np.concatenate([v, v + 3]), np.concatenate([f, f + 6])).report
    assert two["components"] == 2 and two["boundary_edges"] == 0


def test_all_faces_degenerate_is_refused():
    with pytest.raises(qem_core.InvalidMeshError, match="degenerate"):
        prepare_mesh(np.zeros((3, 3)), np.array([[0, 1, 2]]))  # all three weld together


@pytest.mark.parametrize("vertices, faces, message", [
    (np.zeros((3, 2)), [[0, 1, 2]], "shape"),
    (np.array([["a", "b", "c"]] * 3), [[0, 1, 2]], "real numbers"),
    (np.eye(3), [[0, 1]], "triangulate"),
    (np.eye(3), [[0.0, 1.0, 2.0]], "integer"),
    (np.eye(3), [[0, 1, -1]], "negative"),
    (np.array([[0, 0, np.inf], [1, 0, 0], [0, 1, 0]]), [[0, 1, 2]], "non-finite"),
    ([[0, 0, 0], [1, 0]], [[0, 1, 2]], "must be arrays"),  # ragged: numpy's ValueError
])  # fmt: skip
def test_bad_arrays_are_refused_naming_the_problem(vertices, faces, message):
    with pytest.raises(qem_core.InvalidMeshError, match=message):
        prepare_mesh(vertices, faces)


def test_preparation_is_deterministic_and_keeps_input_order():
    rng = np.random.default_rng(3)
    vertices = rng.integers(0, 4, (200, 3)).astype(float)  # many coincident points
    faces = rng.integers(0, 200, (300, 3))
    first, second = prepare_mesh(vertices, faces), prepare_mesh(vertices.copy(), faces.copy())
    for a, b in zip(first, second, strict=True):
        if isinstance(a, dict):
            assert a == b
        else:
            assert np.array_equal(a, b)
    # Against a slow reference: weld onto the first equal point, drop faces by rule.
    weld = {}
    welded = [weld.setdefault(tuple(p), i) for i, p in enumerate(vertices.tolist())]
    seen, kept = set(), []
    for face in faces.tolist():
        w = [welded[i] for i in face]
        if len(set(w)) == 3 and frozenset(w) not in seen:
            seen.add(frozenset(w))
            kept.append(w)
    used = sorted({i for face in kept for i in face})
    renumber = {old: new for new, old in enumerate(used)}
    assert first.faces.tolist() == [[renumber[i] for i in face] for face in kept]
    assert first.vertices.tolist() == vertices[used].tolist()


@pytest.mark.parametrize(
    "mesh, non_manifold_edges",
    [
        (FIN, 1),
        (BOWTIE, 0),
        # Two cubes sharing an edge (cube 1's 3-7 is cube 2's 0-4): four faces on it.
        (
            (
                np.concatenate([CUBE[0], CUBE[0] + [1, 1, 0]]),
                np.concatenate([CUBE[1], CUBE[1] + 8]),
            ),
            1,
        ),
        # Two octahedra touching at (1, 0, 0): pinched at one vertex, no shared edge.
        (
            (
                np.concatenate([OCTAHEDRON[0], OCTAHEDRON[0] + [2, 0, 0]]),
                np.concatenate([OCTAHEDRON[1], OCTAHEDRON[1] + 6]),
            ),
            0,
        ),
        # A closed cube with a fin on its edge 0-1 (which then has three faces).
        ((np.concatenate([CUBE[0], [[0.5, -1, 0.5]]]), np.concatenate([CUBE[1], [[0, 1, 8]]])), 1),
    ],
    ids=["fin", "bowtie", "cubes_on_an_edge", "octahedra_on_a_vertex", "cube_with_fin"],
)
def test_non_manifold_input_builds_and_serves_every_level(mesh, non_manifold_edges):
    vertices, faces = mesh
    pm = qem_core.build(vertices, faces)
    assert pm.metadata["prepare_report"]["non_manifold_edges"] == non_manifold_edges
    base = pm.lod(pm.n_base)
    for n in range(pm.n_base, pm.n_full + 1):
        level_vertices, level_faces = pm.lod(n)
        assert level_vertices.shape == (n, 3)
        assert np.array_equal(np.unique(level_faces), np.arange(n))
        out_vertices, out_faces = qem_core.apply_splits(*base, pm.splits(pm.n_base, n))
        assert np.array_equal(out_faces, level_faces)
        assert np.array_equal(out_vertices, level_vertices)


@given(st.integers(3, 10).flatmap(lambda n: st.tuples(
    st.just(n),
    st.lists(st.lists(st.integers(0, n - 1), min_size=3, max_size=3, unique=True),
             max_size=30))),
    st.integers(1, 5))
def test_edges_are_numbered_in_end_order_whatever_the_chunks(drawn, n_chunks):
    """find_edges against a dictionary of the sides: (low, high) order, each side's edge,
    the faces on each edge and its last side, the same for any number of chunks."""
    n, face_list = drawn
    faces = np.array(face_list, np.int32).reshape(-1, 3)
    sides = {}
    for f, face in enumerate(face_list):
        for k in range(3):
            u, v = face[k], face[(k + 1) % 3]
            sides.setdefault((min(u, v), max(u, v)), []).append(3 * f + k)
    expected = sorted(sides)
    m = faces.shape[0]
    face_edge, edges = np.full((m, 3), -1, np.int32), np.full((3 * m, 2), -1, np.int32)
    # Garbage where the kernel must write first: it takes its counts uninitialised.
    counts, last_side = np.full(3 * m, -7, np.int32), np.full(3 * m, -1, np.int64)
    n_edges, _ = find_edges(faces, n, face_edge, edges, counts, last_side, n_chunks,
                            np.zeros(0, np.uint8))
    assert n_edges == len(expected)
    assert [tuple(edge) for edge in edges[:n_edges].tolist()] == expected
    for e, edge in enumerate(expected):
        assert counts[e] == len(sides[edge])
        assert last_side[e] == max(sides[edge])
        for side in sides[edge]:
            assert face_edge[side // 3, side % 3] == e
    assert unique_edges(faces, n).edges.tolist() == edges[:n_edges].tolist()


@given(st.integers(3, 6).flatmap(lambda n: st.tuples(
    st.just(n),
    st.lists(st.permutations(range(n)).map(lambda p: p[:3]), min_size=1, max_size=40))),
    st.integers(1, 5), st.booleans())
@example(drawn=(3, [[0, 1, 2]] * 40), n_chunks=1, fall_back=False)  # a failure CI found
def test_duplicate_faces_are_found_on_their_edges(drawn, n_chunks, fall_back):
    """find_edges' search against sets of corners: a face is a duplicate when an earlier
    face has its three corners (on few vertices the faces repeat, and edges have many
    faces; an edge of more than MAX_FACES_COMPARED of them is counted as unsearched, and
    preparation compares sorted corners for it). ``fall_back``: prepare_mesh is told no
    edge was searched and compares sorted corners for all; the same faces are dropped
    either way."""
    from qem_core import prepare

    n, face_list = drawn
    faces = np.array(face_list, np.int32).reshape(-1, 3)
    seen, expected = set(), []
    for face in face_list:
        expected.append(int(frozenset(face) in seen))
        seen.add(frozenset(face))
    m = faces.shape[0]
    duplicate = np.zeros(m, np.uint8)
    _, unsearched = find_edges(faces, n, np.empty((m, 3), np.int32),
                               np.empty((3 * m, 2), np.int32), np.zeros(3 * m, np.int32),
                               np.empty(3 * m, np.int64), n_chunks, duplicate)
    faces_on_edge = Counter(frozenset((face[i], face[i - 1])) for face in face_list
                            for i in range(3))
    assert unsearched == sum(count > MAX_FACES_COMPARED for count in faces_on_edge.values())
    if not unsearched:  # else preparation compares sorted corners, checked below
        assert duplicate.tolist() == expected

    real = prepare._find_edges

    def nothing_searched(faces, n_vertices, search_duplicates):
        mesh_edges, found, _ = real(faces, n_vertices, search_duplicates)
        return mesh_edges, np.zeros_like(found), 1 if search_duplicates else 0

    with pytest.MonkeyPatch.context() as patch:
        if fall_back:
            patch.setattr(prepare, "_find_edges", nothing_searched)
        prepared = prepare_mesh(np.random.default_rng(n).random((n, 3)), faces)
    kept = [not d for d in expected]
    assert prepared.report["duplicate_faces"] == sum(expected)
    assert (prepared.face_map >= 0).tolist() == kept
    assert np.array_equal(prepared.faces, prepared.vertex_map[faces[kept]])
    assert prepared.faces.shape[0] == len(seen)


def test_duplicates_on_an_edge_of_very_many_faces_are_found_by_sorted_corners():
    """A book of 40 pages on edge 0-1 (more faces than the edge search compares), page 7
    repeated at the end, reversed: the edge is counted as unsearched, and preparation
    finds the repeat by comparing sorted corners."""
    n_pages = 40
    assert n_pages > MAX_FACES_COMPARED
    angles = np.linspace(0.0, np.pi, n_pages)
    vertices = np.concatenate([[[0, 0, 0], [0, 0, 1]],
                               np.stack([np.cos(angles), np.sin(angles), 0.5 + 0 * angles], 1)])
    pages = [[0, 1, 2 + i] for i in range(n_pages)]
    faces = np.array(pages + [pages[7][::-1]], np.int32)
    m = faces.shape[0]
    _, unsearched = find_edges(faces, vertices.shape[0], np.empty((m, 3), np.int32),
                               np.empty((3 * m, 2), np.int32), np.zeros(3 * m, np.int32),
                               np.empty(3 * m, np.int64), 2, np.zeros(m, np.uint8))
    assert unsearched == 1
    prepared = prepare_mesh(vertices, faces)
    assert prepared.report["duplicate_faces"] == 1
    assert prepared.face_map.tolist() == list(range(n_pages)) + [-1]
    assert prepared.report["non_manifold_edges"] == 1

"""The progressive mesh: lod(n) at every level, clamping, the error curve, splits.

Each mesh is built once per module; every level of it is checked (the meshes are small).
"""

import numpy as np
import pytest

import qem_core
from qem_core.prepare import prepare_mesh
from qem_core.simplify import contract_greedily
from tests import reference
from tests.tiny_meshes import (
    BOWTIE,
    FIN,
    OCTAHEDRON,
    OPEN_BOX,
    SQUARE,
    TETRAHEDRON,
    bumpy_grid,
    icosphere,
    perforated_icosphere,
    soup,
)

MESHES = {
    "octahedron": OCTAHEDRON,
    "square": SQUARE,
    "open_box": OPEN_BOX,
    "sphere": icosphere(2, jitter=0.05, seed=1),
    "perforated_sphere": perforated_icosphere(2, holes=4, seed=2),
    "bumpy_grid": bumpy_grid(7, seed=3),
    # Two components: a tetrahedron (stays) beside an octahedron (shrinks to one).
    "tetra_and_octahedron": (
        np.concatenate([TETRAHEDRON[0], OCTAHEDRON[0] + 3]),
        np.concatenate([TETRAHEDRON[1], OCTAHEDRON[1] + 4]),
    ),
    "fin": FIN,
    "bowtie": BOWTIE,
}
OPTIONS = {
    "default": {},
    "exact": {"error_mode": "exact"},
    "volume_no_border": {"weighting": "volume", "boundary_weight": 0.0},
}
CASES = [(m, o) for m in MESHES for o in OPTIONS]


@pytest.fixture(scope="module")
def built():
    cache = {}

    def get(mesh_name: str, options_name: str = "default") -> qem_core.ProgressiveMesh:
        key = (mesh_name, options_name)
        if key not in cache:
            cache[key] = qem_core.build(*MESHES[mesh_name], OPTIONS[options_name])
        return cache[key]

    return get


def levels(pm):
    return range(pm.n_base, pm.n_full + 1)


@pytest.mark.parametrize("mesh_name, options_name", CASES)
def test_every_level_has_exactly_n_vertices_all_referenced(built, mesh_name, options_name):
    pm = built(mesh_name, options_name)
    for n in levels(pm):
        vertices, faces = pm.lod(n)
        assert vertices.shape == (n, 3) and vertices.dtype == np.float64
        assert faces.dtype == np.int32 and faces.shape == (pm.n_faces(n), 3)
        # No unreferenced vertex: the faces use exactly 0..n-1.
        assert np.array_equal(np.unique(faces), np.arange(n))
        # No degenerate face at any level.
        assert np.all(
            (faces[:, 0] != faces[:, 1])
            & (faces[:, 1] != faces[:, 2])
            & (faces[:, 2] != faces[:, 0])
        )


@pytest.mark.parametrize("mesh_name", MESHES)
def test_each_level_is_a_prefix_of_every_finer_level(built, mesh_name):
    """Faces are numbered in order of appearance and vertices in order of introduction:
    the first F(n1) faces of lod(n2), each corner replaced by the vertex of lod(n1) it was
    split from (reference.ancestors, from split_vertex alone), are lod(n1)'s faces."""
    pm = built(mesh_name)
    counts = [pm.n_faces(n) for n in levels(pm)]
    assert counts == sorted(counts) and counts[-1] == pm.n_faces_full
    for n1 in levels(pm):
        faces = pm.lod(n1)[1]
        for n2 in (n1 + 1, (n1 + pm.n_full + 1) // 2, pm.n_full):
            if n2 <= pm.n_full:
                finer = pm.lod(n2)[1]
                parent = reference.ancestors(pm, n1)
                assert np.array_equal(parent[finer[: len(faces)]], faces), (n1, n2)


@pytest.mark.parametrize("mesh_name", MESHES)
def test_requests_outside_the_range_are_clamped(built, mesh_name):
    pm = built(mesh_name)
    for low in (-(10**9), 0, 1, pm.n_base - 1):
        assert pm.clamp(low) == pm.n_base
        assert len(pm.lod(low)[0]) == pm.n_base
        assert pm.error(low) == pm.error(pm.n_base)
    for high in (pm.n_full + 1, 10**12, np.int64(pm.n_full + 7)):
        assert pm.clamp(high) == pm.n_full
        assert len(pm.lod(high)[0]) == pm.n_full
        assert pm.error(high) == 0.0
    clamped = pm.splits(-5, 10**9)
    assert (clamped.n_from, clamped.n_to) == (pm.n_base, pm.n_full)
    assert pm.n_faces(10**9) == pm.n_faces_full


@pytest.mark.parametrize("bad", [2.5, "10", None, True, 1e3])
def test_a_vertex_count_that_is_not_an_integer_is_refused(built, bad):
    pm = built("sphere")
    for call in (pm.lod, pm.error, pm.n_faces, pm.clamp):
        with pytest.raises(qem_core.InvalidOptionsError, match="integer"):
            call(bad)


def test_splits_must_go_from_coarse_to_fine(built):
    pm = built("sphere")
    with pytest.raises(qem_core.InvalidOptionsError, match="from=.*to="):
        pm.splits(pm.n_base + 10, pm.n_base + 2)


@pytest.mark.parametrize("mesh_name, options_name", CASES)
def test_error_is_the_worst_contraction_cost_of_the_greedy_run_stopped_there(
    built, mesh_name, options_name
):
    """error(n) = the largest cost the greedy run paid to get down to n vertices, taken
    from the run's own record (not from the progressive mesh); so it never increases as
    n grows, and it is 0 at the full count."""
    pm = built(mesh_name, options_name)
    prepared = prepare_mesh(*MESHES[mesh_name])
    options = qem_core.BuildOptions(**OPTIONS[options_name])
    run = contract_greedily(prepared.vertices, prepared.faces, options)
    assert run.n_contractions == pm.n_full - pm.n_base
    costs = run.record.cost[: run.n_contractions]
    for n in reference.greedy_levels(pm):  # the sweep order's levels inside its windows differ
        k = pm.n_full - n
        assert pm.error(n) == (costs[:k].max() if k else 0.0)
    errors = np.array([pm.error(n) for n in levels(pm)])
    assert np.all(np.diff(errors) <= 0)
    assert np.array_equal(pm.errors(), errors)


@pytest.mark.parametrize("mesh_name, options_name", CASES)
def test_lod_equals_the_greedy_run_stopped_at_n(built, mesh_name, options_name):
    """Bit for bit: the same positions and the same oriented triangles as the complex
    the greedy loop leaves after n_full - n contractions, at the levels the sweep order
    keeps (`reference.greedy_levels`), its own positions: no tangent lattice."""
    pm = qem_core.build(*MESHES[mesh_name], {**OPTIONS[options_name], "tangent_lattice": False})
    prepared = prepare_mesh(*MESHES[mesh_name])
    options = qem_core.BuildOptions(**OPTIONS[options_name])
    ends = {pm.n_base, pm.n_base + 1, (pm.n_base + pm.n_full) // 2, pm.n_full - 1, pm.n_full}
    sample = sorted({reference.greedy_level(pm, n) for n in ends})
    for n in sample:
        run = contract_greedily(
            prepared.vertices, prepared.faces, options, max_contractions=pm.n_full - n
        )
        cx = run.complex
        alive = cx.vertex_alive.astype(bool)
        assert np.count_nonzero(alive) == n
        vertices, faces = pm.lod(n)
        expected_positions = np.sort(cx.vertices[alive].view("V24").ravel())
        assert np.array_equal(np.sort(vertices.view("V24").ravel()), expected_positions)
        run_faces = cx.faces[cx.face_alive.astype(bool)]
        assert reference.exact_triangle_set(vertices, faces) == reference.exact_triangle_set(
            cx.vertices, run_faces
        )


def _apply_and_compare(pm, n1, n2):
    vertices, faces = pm.lod(n1)
    refined_vertices, refined_faces = qem_core.apply_splits(vertices, faces, pm.splits(n1, n2))
    expected_vertices, expected_faces = pm.lod(n2)
    assert np.array_equal(refined_faces, expected_faces)
    assert refined_faces.dtype == expected_faces.dtype
    # Bit for bit, not merely close: the splits carry the same float64 positions.
    assert refined_vertices.tobytes() == expected_vertices.tobytes()


@pytest.mark.parametrize("mesh_name, options_name", CASES)
def test_splits_from_every_level_to_every_later_level_give_that_level(
    built, mesh_name, options_name
):
    pm = built(mesh_name, options_name)
    all_levels = list(levels(pm))
    # Every pair on the small meshes; a spread of pairs (ends included) on larger ones.
    if len(all_levels) > 40:
        picks = np.unique(np.linspace(pm.n_base, pm.n_full, 12).astype(int)).tolist()
        pairs = [(a, b) for a in picks for b in picks if a <= b]
    else:
        pairs = [(a, b) for a in all_levels for b in all_levels if a <= b]
    for n1, n2 in pairs:
        _apply_and_compare(pm, n1, n2)


def test_splits_in_steps_give_the_same_as_one_jump(built):
    pm = built("perforated_sphere")
    vertices, faces = pm.lod(pm.n_base)
    steps = np.unique(np.linspace(pm.n_base, pm.n_full, 9).astype(int))
    for n1, n2 in zip(steps[:-1], steps[1:], strict=True):
        vertices, faces = qem_core.apply_splits(vertices, faces, pm.splits(int(n1), int(n2)))
    full_vertices, full_faces = pm.lod(pm.n_full)
    assert np.array_equal(faces, full_faces)
    assert np.array_equal(vertices, full_vertices)


def test_apply_splits_leaves_its_inputs_alone_and_refuses_the_wrong_level(built):
    pm = built("sphere")
    n1, n2 = pm.n_base + 3, pm.n_base + 40
    vertices, faces = pm.lod(n1)
    before = vertices.copy(), faces.copy()
    qem_core.apply_splits(vertices, faces, pm.splits(n1, n2))
    assert np.array_equal(vertices, before[0]) and np.array_equal(faces, before[1])
    other_vertices, other_faces = pm.lod(n1 + 1)
    with pytest.raises(qem_core.InvalidOptionsError, match="start from"):
        qem_core.apply_splits(other_vertices, other_faces, pm.splits(n1, n2))


@pytest.mark.parametrize(
    "change, match",
    [
        # apply_splits sizes its output by n_to and the kernel writes a row per split:
        # a wrong n_to or too few positions wrote or read past the arrays' ends.
        (lambda s: s._replace(n_to=s.n_from), "cannot refine"),
        (lambda s: s._replace(n_to=10**12), "cannot refine"),
        (lambda s: s._replace(n_to=-1), "must be counts"),
        (lambda s: s._replace(split_positions=s.split_positions[:1]), "positions have shape"),
        (lambda s: s._replace(split_vertex=s.split_vertex.astype(float)), "integer arrays"),
        # Checked before the kernel's int32: these wrapped back into range.
        (lambda s: s._replace(relabel_faces=s.relabel_faces.astype(np.int64) + 2**32),
         "relabels a face that does not exist"),
        (lambda s: s._replace(split_vertex=s.split_vertex.astype(np.int64) - 2**32),
         "does not exist yet"),
    ],
)
def test_apply_splits_refuses_splits_that_are_not_a_run(built, change, match):
    pm = built("sphere")
    n1, n2 = pm.n_base + 3, pm.n_base + 40
    with pytest.raises(qem_core.CorruptFileError, match=match):
        qem_core.apply_splits(*pm.lod(n1), change(pm.splits(n1, n2)))


@pytest.mark.parametrize(
    "change, match",
    [
        (lambda v, f: (v[:, :2], f), "start from"),
        (lambda v, f: (v, f.astype(np.int64) + 2**32), "outside"),
        (lambda v, f: (v, f - 1), "outside"),
        (lambda v, f: (v, f.astype(float)), "faces integers"),
    ],
)
def test_apply_splits_refuses_a_mesh_that_is_not_a_level(built, change, match):
    pm = built("sphere")
    n1, n2 = pm.n_base + 3, pm.n_base + 40
    with pytest.raises(qem_core.InvalidOptionsError, match=match):
        qem_core.apply_splits(*change(*pm.lod(n1)), pm.splits(n1, n2))


def test_empty_splits_change_nothing(built):
    pm = built("sphere")
    n = pm.n_base + 10
    splits = pm.splits(n, n)
    assert splits.split_vertex.size == 0 and splits.new_faces.shape == (0, 3)
    vertices, faces = pm.lod(n)
    out_vertices, out_faces = qem_core.apply_splits(vertices, faces, splits)
    assert np.array_equal(out_vertices, vertices) and np.array_equal(out_faces, faces)


def _input_faces_through_vertex_map(pm, faces) -> np.ndarray:
    """The input's faces in level numbering, with the faces preparation drops (two
    corners on one vertex after welding, or the same three vertices as an earlier face)
    dropped here too, independently of prepare.py."""
    mapped = pm.vertex_map[np.asarray(faces)]
    kept = (
        (mapped[:, 0] != mapped[:, 1])
        & (mapped[:, 1] != mapped[:, 2])
        & (mapped[:, 2] != mapped[:, 0])
    )
    mapped = mapped[kept]
    _, first = np.unique(np.sort(mapped, axis=1), axis=0, return_index=True)
    return mapped[np.sort(first)]


@pytest.mark.parametrize("mesh_name", MESHES)
def test_full_level_reproduces_the_prepared_input(built, mesh_name):
    """lod(n_full) is the input surface: each kept input vertex at its own position
    (to the bit), and the input's faces, oriented as given, renumbered by vertex_map."""
    vertices, faces = MESHES[mesh_name]
    pm = built(mesh_name)
    full_vertices, full_faces = pm.lod(pm.n_full)
    used = pm.vertex_map >= 0
    assert np.array_equal(full_vertices[pm.vertex_map[used]], np.asarray(vertices, float)[used])
    # Every level number is the image of some input vertex.
    assert np.array_equal(np.unique(pm.vertex_map[used]), np.arange(pm.n_full))
    expected = _input_faces_through_vertex_map(pm, faces)
    assert np.array_equal(
        reference.canonical_faces(full_faces), reference.canonical_faces(expected)
    )


# The bowtie's two faces meet at a vertex only: no split brings a face with both s and t.
@pytest.mark.parametrize("mesh_name", [name for name in MESHES if name != "bowtie"])
def test_a_born_face_begins_at_its_third_corner_forward_ones_first(built, mesh_name):
    """Each face a split brings with both its s and t begins at the other corner, and
    those going from s to t come before those going back (the split stream then codes
    next to nothing of them; that the faces keep the input's orientation,
    test_full_level_reproduces_the_prepared_input)."""
    pm = built(mesh_name)
    born_at = np.repeat(np.arange(pm.n_splits), np.diff(pm.level_faces))
    born = pm.face_corners[pm.level_faces[0] :]
    s = pm.split_vertex[born_at][:, None]
    t = (pm.n_base + born_at)[:, None]
    with_both = np.any(born == s, axis=1) & np.any(born == t, axis=1)
    assert with_both.any()
    first = born[with_both, 0]
    assert np.all((first != s[with_both, 0]) & (first != t[with_both, 0]))
    kind = np.where(born[:, 1] == s[:, 0], 0, np.where(born[:, 1] == t[:, 0], 1, 2))
    kind[~with_both] = 2
    # Sorted by split then kind: the kinds never step down within a split.
    assert np.all((np.diff(born_at) > 0) | (np.diff(kind) >= 0))


def test_full_level_of_a_dirty_input_is_the_cleaned_input():
    """A soup with an unreferenced vertex, a degenerate and a duplicate face: the full
    level is the welded closed cube (8 vertices, 12 faces), as counted by hand."""
    from tests.tiny_meshes import CUBE

    vertices, faces = soup(*CUBE)
    vertices = np.concatenate([vertices, [[9.0, 9.0, 9.0]]])  # unreferenced
    faces = np.concatenate([faces, [[0, 0, 1], faces[3][::-1], faces[5]]])
    pm = qem_core.build(vertices, faces)
    assert pm.n_full == 8 and pm.n_faces_full == 12
    assert pm.vertex_map[-1] == -1
    full_vertices, full_faces = pm.lod(pm.n_full)
    assert np.array_equal(full_vertices[pm.vertex_map[:-1]], vertices[:-1])
    expected = _input_faces_through_vertex_map(pm, faces)
    assert expected.shape == (12, 3)
    assert np.array_equal(
        reference.canonical_faces(full_faces), reference.canonical_faces(expected)
    )
    assert reference.is_closed_manifold(full_faces)
    report = pm.metadata["prepare_report"]
    # 36 corners + 1 extra vertex: 8 kept, 28 welded onto them, 1 unreferenced.
    assert report["merged_vertices"] == 28 and report["unreferenced_vertices"] == 1
    # (0, 0, 1) is degenerate; face 3 reversed and face 5 repeat earlier faces.
    assert report["degenerate_faces"] == 1 and report["duplicate_faces"] == 2


def test_metadata_describes_the_input(built):
    vertices, faces = MESHES["perforated_sphere"]
    pm = built("perforated_sphere")
    assert pm.metadata["input_vertices"] == len(vertices)
    assert pm.metadata["input_faces"] == len(faces)
    np.testing.assert_array_equal(pm.bbox, [vertices.min(axis=0), vertices.max(axis=0)])
    low, high = pm.position_bounds
    for n in levels(pm):
        level_vertices = pm.lod(n)[0]
        assert np.all(level_vertices >= low) and np.all(level_vertices <= high)


@pytest.mark.parametrize("mesh_name", ["octahedron", "sphere", "bowtie"])
def test_without_topology_preservation_every_level_still_uses_every_vertex(mesh_name):
    pm = qem_core.build(*MESHES[mesh_name], {"preserve_topology": False})
    for n in levels(pm):
        vertices, faces = pm.lod(n)
        assert len(faces) > 0, f"lod({n}) has no face"
        assert np.array_equal(np.unique(faces), np.arange(n)), f"lod({n}) has unused vertices"

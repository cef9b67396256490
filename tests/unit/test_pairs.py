"""Garland's pair contraction (BuildOptions.pair_threshold): vertex pairs closer than t
that share no edge are candidates too, so separate parts can join.

    two tetrahedra, 0.2 apart along x (t = pair_threshold x the box diagonal)

        2                 6
        |\\                |\\
        | \\               | \\
        0--1   0.2   4--5           vertices 1 = (1, 0, 0) and 4 = (1.2, 0, 0):
       /                 /             the only pair closer than t = 0.25; joined,
      3                 7              their vertex has the 3 + 3 faces of both
"""

import numpy as np
import pytest

import qem_core
from qem_core._kernels.pairs import MAX_PAIRS_PER_VERTEX, candidate_pairs
from qem_core.prepare import prepare_mesh, unique_edges
from qem_core.simplify import contract_greedily
from tests import reference
from tests.tiny_meshes import OCTAHEDRON, TETRAHEDRON, icosphere

V_TET, F_TET = TETRAHEDRON
TWO_TETRAHEDRA = (
    np.concatenate([V_TET, V_TET + [1.2, 0, 0]]),
    np.concatenate([F_TET, F_TET + 4]),
)
DIAGONAL = float(np.linalg.norm([2.2, 1, 1]))


def _part_of_split(pm, n_first_part):
    """For each split: (part of the vertex split, part of the new vertex)."""
    part = np.zeros(pm.n_full, int)
    part[pm.vertex_map[n_first_part:]] = 1
    return part[pm.split_vertex], part[pm.n_base + np.arange(pm.n_splits)]


def test_two_tetrahedra_closer_than_t_merge_at_their_nearest_vertices():
    pm = qem_core.build(*TWO_TETRAHEDRA, {"pair_threshold": 0.25 / DIAGONAL})
    # One contraction, the pair (1, 4); then each tetrahedron is as small as it can be.
    assert (pm.n_full, pm.n_base) == (8, 7)
    kept, new = _part_of_split(pm, 4)
    assert kept[0] != new[0]
    base_vertices, base_faces = pm.lod(7)
    assert base_faces.shape == (8, 3)  # no face dies joining two parts at a vertex
    assert reference.components(base_faces) == 1
    # The joint, in the faces of both, lies in the gap between the corners it joined.
    joint = base_vertices[np.bincount(base_faces.ravel(), minlength=7) == 6]
    assert joint.shape == (1, 3) and 1.0 < joint[0, 0] < 1.2


def test_parts_farther_apart_than_t_stay_apart():
    pm = qem_core.build(*TWO_TETRAHEDRA, {"pair_threshold": 0.19 / DIAGONAL})
    assert pm.n_base == pm.n_full == 8
    assert reference.components(pm.lod(8)[1]) == 2


def test_threshold_zero_changes_nothing():
    mesh = icosphere(2, jitter=0.05, seed=4)
    options = qem_core.BuildOptions(pair_threshold=0.0)
    default, zero = qem_core.build(*mesh), qem_core.build(*mesh, options)
    # A threshold below every distance between vertices finds no pair: the same run.
    tiny = qem_core.build(*mesh, {"pair_threshold": 1e-9})
    for pm in (zero, tiny):
        assert pm.n_base == default.n_base and pm.n_full == default.n_full
        assert np.array_equal(pm.split_vertex, default.split_vertex)
        assert np.array_equal(pm.split_positions, default.split_positions)
        assert np.array_equal(pm.face_corners, default.face_corners)
        assert np.array_equal(pm.relabel_faces, default.relabel_faces)


def _two_spheres():
    """Two jittered icospheres 0.05 apart: every vertex near the gap has pairs across."""
    v1, f1 = icosphere(2, jitter=0.02, seed=1)
    v2, f2 = icosphere(2, jitter=0.02, seed=2)
    return np.concatenate([v1, v2 + [2.1, 0, 0]]), np.concatenate([f1, f2 + len(v1)]), len(v1)


@pytest.mark.parametrize(
    "options",
    [
        {"pair_threshold": 0.03},
        {"pair_threshold": 0.03, "error_mode": "exact"},
        {"pair_threshold": 0.03, "preserve_topology": False},
    ],
)
def test_levels_and_splits_stay_consistent_with_pairs(options):
    vertices, faces, n_first = _two_spheres()
    pm = qem_core.build(vertices, faces, options)
    kept, new = _part_of_split(pm, n_first)
    assert np.any(kept != new), "no pair across the gap was contracted"
    levels = sorted({pm.n_base, pm.n_base + 1, pm.n_full // 3, pm.n_full // 2, pm.n_full})
    for n in levels:
        level_vertices, level_faces = pm.lod(n)
        assert level_vertices.shape == (n, 3)
        assert np.array_equal(np.unique(level_faces), np.arange(n)), f"lod({n}) leaves a vertex"
    for n1, n2 in zip(levels[:-1], levels[1:], strict=True):
        refined = qem_core.apply_splits(*pm.lod(n1), pm.splits(n1, n2))
        expected = pm.lod(n2)
        assert np.array_equal(refined[1], expected[1])
        assert np.array_equal(refined[0], expected[0])


def test_lod_equals_the_greedy_run_with_pairs_stopped_there():
    vertices, faces, _ = _two_spheres()
    options = qem_core.BuildOptions(pair_threshold=0.03, tangent_lattice=False)
    pm = qem_core.build(vertices, faces, options)
    prepared = prepare_mesh(vertices, faces)
    for n in sorted({reference.greedy_level(pm, n)
                     for n in (pm.n_base, pm.n_full // 2, pm.n_full - 40)}):
        run = contract_greedily(
            prepared.vertices, prepared.faces, options, max_contractions=pm.n_full - n
        )
        alive = run.complex.face_alive.astype(bool)
        expected = reference.triangle_set(run.complex.vertices, run.complex.faces[alive])
        assert reference.triangle_set(*pm.lod(n)) == expected


def test_candidate_pairs_are_the_near_non_edges():
    #   3 ---- 2       a square of two triangles, and a vertex 4 at height 0.1 above 0.
    #   | \    |       Non-edges: 0-2 (1.41), 0-4 (0.1), 1-4 and 3-4 (1.005), 2-4 (1.42).
    #   |   \  |
    #   0 ---- 1
    vertices = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 0.1]], float)
    edges = unique_edges(np.array([[0, 1, 3], [1, 2, 3]], np.int32), 5).edges
    assert candidate_pairs(vertices, edges, 1.05).tolist() == [[0, 4], [1, 4], [3, 4]]
    assert candidate_pairs(vertices, edges, 0.1).tolist() == []  # strictly closer than t
    assert candidate_pairs(vertices, edges, 1.5).tolist() == [
        [0, 2],
        [0, 4],
        [1, 4],
        [2, 4],
        [3, 4],
    ]


def test_each_vertex_keeps_its_nearest_few_pairs():
    cloud = np.random.default_rng(0).uniform(0, 1, (300, 3))
    pairs = candidate_pairs(cloud, np.zeros((0, 2), np.int32), 10.0)
    assert np.all(pairs[:, 0] < pairs[:, 1])
    distance = np.linalg.norm(cloud[:, None] - cloud[None], axis=2)
    np.fill_diagonal(distance, np.inf)
    order = np.argsort(distance, axis=1, kind="stable")[:, :MAX_PAIRS_PER_VERTEX]
    expected = {(min(u, v), max(u, v)) for u in range(300) for v in order[u].tolist()}
    assert set(map(tuple, pairs.tolist())) == expected


def test_octahedra_joined_by_pairs_build_in_both_error_modes():
    v, f = OCTAHEDRON
    vertices, faces = np.concatenate([v, v + [2.1, 0, 0]]), np.concatenate([f, f + 6])
    for mode in ("additive", "exact"):
        pm = qem_core.build(vertices, faces, {"pair_threshold": 0.1, "error_mode": mode})
        kept, new = _part_of_split(pm, 6)
        assert np.any(kept != new)
        for n in range(pm.n_base, pm.n_full + 1):
            assert np.array_equal(np.unique(pm.lod(n)[1]), np.arange(n))

"""Placement: the minimiser closest to the midpoint, by a truncated pseudo-inverse."""

import numpy as np
import pytest

from qem_core._kernels.placement import clearly_well_conditioned, eigenvalues3, minimise_near
from tests import reference

RANK_TOLERANCE = 1e-3


def quadric_from_planes(normals, offsets):
    q = np.zeros(10)
    for n, d in zip(normals, offsets, strict=True):
        n = np.asarray(n, float) / np.linalg.norm(n)
        q += reference._plane(n, d, 1.0)
    return q


def truncated_reference(q, m):
    a = np.array([[q[0], q[1], q[2]], [q[1], q[3], q[4]], [q[2], q[4], q[5]]])
    w, u = np.linalg.eigh(a)
    g = a @ m + q[6:9]
    keep = w > RANK_TOLERANCE * w.max()
    return m - u[:, keep] @ ((u[:, keep].T @ g) / w[keep])


@pytest.mark.parametrize("normals, offsets", [
    ([[1, 0, 0], [0, 1, 0], [0, 0, 1]], [-1, -2, -3]),  # a corner: one point
    ([[1, 0, 0], [0, 1, 0]], [-1, -2]),  # a crease: a line of minimisers
    ([[0, 0, 1]], [-0.5]),  # a plane of minimisers
    ([[1, 1, 0], [1, -1, 0.001]], [0.3, -0.2]),  # nearly a line
])
def test_minimiser_matches_a_dense_pseudo_inverse(normals, offsets):
    q = quadric_from_planes(normals, offsets)
    m = np.array([0.2, -0.4, 0.7])
    out = np.zeros(3)
    minimise_near(q, *m, RANK_TOLERANCE, out)
    np.testing.assert_allclose(out, truncated_reference(q, m), atol=1e-9)


def test_plane_case_projects_the_midpoint_onto_the_plane():
    q = quadric_from_planes([[0, 0, 1]], [-0.5])
    out = np.zeros(3)
    minimise_near(q, 1.0, 2.0, 3.0, RANK_TOLERANCE, out)
    np.testing.assert_allclose(out, [1.0, 2.0, 0.5])


def test_closed_form_eigenvalues():
    rng = np.random.default_rng(0)
    for _ in range(200):
        b = rng.normal(size=(3, 3))
        a = b @ b.T
        got = eigenvalues3(a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2])
        np.testing.assert_allclose(sorted(got), np.linalg.eigvalsh(a), rtol=1e-7, atol=1e-9)


def _psd_near_the_tolerance(rng, n, degenerate):
    """Random symmetric matrices with smallest / largest eigenvalue near RANK_TOLERANCE,
    at scales from 1e-80 to 1e80; ``degenerate`` makes the two smallest (or the two
    largest) nearly equal, where arccos is worst conditioned."""
    smallest = RANK_TOLERANCE * rng.uniform(0.5, 2.0, n)
    middle = rng.uniform(smallest, 1.0)
    if degenerate == "low":
        middle = smallest * (1 + 10.0 ** rng.uniform(-16, -4, n))
    elif degenerate == "high":
        middle = 1 - 10.0 ** rng.uniform(-16, -4, n)
    rotations, _ = np.linalg.qr(rng.normal(size=(n, 3, 3)))
    eigenvalues = np.stack([np.ones(n), middle, smallest], axis=1)
    scale = 10.0 ** rng.uniform(-80, 80, n)
    return np.einsum("nij,nj,nkj->nik", rotations, eigenvalues, rotations) * scale[:, None, None]


@pytest.mark.parametrize("degenerate", [None, "low", "high"])
def test_the_well_conditioned_shortcut_never_disagrees_with_the_eigenvalues(degenerate):
    """The shortcut may only say yes where eigenvalues3 passes the tolerance test (else
    the branch, and the levels, would change); and it does say yes when clear."""
    rng = np.random.default_rng(7)
    said_yes = 0
    for a in _psd_near_the_tolerance(rng, 3000, degenerate):
        entries = (a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2])
        largest, _, smallest = eigenvalues3(*entries)
        if clearly_well_conditioned(*entries, RANK_TOLERANCE):
            said_yes += 1
            assert largest > 0.0 and smallest > RANK_TOLERANCE * largest
    assert said_yes > 0 or degenerate is not None
    rotations, _ = np.linalg.qr(rng.normal(size=(100, 3, 3)))
    for rotation, low, scale in zip(rotations, rng.uniform(0.05, 1, 100),
                                    10.0 ** rng.uniform(-80, 80, 100), strict=True):
        a = rotation @ np.diag([1.0, 1.0, low]) @ rotation.T * scale
        assert clearly_well_conditioned(a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2],
                                        RANK_TOLERANCE)


def _midpoint_offsets(pm):
    """Per split, how far the contracted vertex lay from its edge's midpoint, over the
    edge's length: replayed from the base mesh (the vertex's position just before its
    split)."""
    splits = pm.splits(pm.n_base, pm.n_full)
    held = np.zeros((pm.n_full, 3))
    held[: pm.n_base] = pm.base_vertices
    contracted = np.empty((pm.n_splits, 3))
    for i, s in enumerate(splits.split_vertex):
        contracted[i] = held[s]
        held[s], held[pm.n_base + i] = splits.split_positions[i]
    ends = splits.split_positions
    lengths = np.linalg.norm(ends[:, 1] - ends[:, 0], axis=1)
    offsets = np.linalg.norm(contracted - ends.mean(axis=1), axis=1)
    return offsets[lengths > 0] / lengths[lengths > 0]


@pytest.mark.parametrize("with_uvs", [False, True], ids=["geometry", "appearance"])
def test_a_larger_rank_tolerance_keeps_vertices_nearer_midpoints_and_streams_smaller(with_uvs):
    """The option reaches both cost paths (plain quadrics; Hoppe's appearance quadric),
    and does what it says: vertices nearer their edges' midpoints, which the stream's
    midpoint prediction codes in fewer bytes, every level still exact."""
    import qem_core
    from qem_core.stream import encode_split_frames
    from tests.unit.conftest import SPOT

    mesh = qem_core.load_mesh(SPOT)
    if not with_uvs:
        mesh = qem_core.Mesh(mesh.vertices, mesh.faces)
    # Without the tangent lattice, which moves the same vertices (test_lattice.py).
    built = {rt: qem_core.build_mesh(mesh, {"rank_tolerance": rt, "tangent_lattice": False})
             for rt in (1e-3, 0.05)}
    offsets = {rt: np.median(_midpoint_offsets(pm)) for rt, pm in built.items()}
    size = {rt: sum(map(len, encode_split_frames(pm, pm.n_base, pm.n_full)))
            for rt, pm in built.items()}
    assert offsets[0.05] < 0.8 * offsets[1e-3], offsets
    assert size[0.05] < 0.97 * size[1e-3], size
    for pm in built.values():
        n = (pm.n_base + pm.n_full) // 2
        assert pm.lod(n)[0].shape[0] == n

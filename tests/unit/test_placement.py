"""Placement: the minimiser closest to the midpoint, by a truncated pseudo-inverse."""

import numpy as np
import pytest

from qem_core._kernels.placement import eigenvalues3, minimise_near
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

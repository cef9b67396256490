"""bench.texture_metrics on tiny hand-made meshes: the figures known in closed form."""

from __future__ import annotations

import numpy as np
import pytest

from bench import texture_metrics as tm

# A unit square in the z = 0 plane, two triangles, UVs = (x, y).
SQUARE_VERTICES = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], dtype=np.float64)
SQUARE_FACES = np.array([[0, 1, 2], [0, 2, 3]])
SQUARE_UVS = SQUARE_VERTICES[:, :2][SQUARE_FACES]

# A regular tetrahedron-ish closed mesh, outward (counter-clockwise seen from outside).
TETRA_VERTICES = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=np.float64)
TETRA_FACES = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def _gradient_texture(size: int = 64) -> np.ndarray:
    """(size, size, 3): red = u, green = v at texel centres, blue = 0 (row 0 at the top)."""
    centres = (np.arange(size) + 0.5) / size
    u = np.broadcast_to(centres[None, :], (size, size))
    v = np.broadcast_to(centres[::-1, None], (size, size))
    return np.stack([u, v, np.zeros((size, size))], axis=2)


def test_bilinear_lookup_reproduces_a_linear_texture_and_clamps_outside():
    texture = _gradient_texture()
    uv = np.array([[0.25, 0.75], [0.5, 0.5], [0.9, 0.1]])
    assert np.allclose(tm.bilinear_lookup(texture, uv), np.column_stack([uv, np.zeros(3)]))
    # Outside [0, 1]: the edge texel centre's colour.
    edge = tm.bilinear_lookup(texture, np.array([[-0.3, 1.4]]))
    assert np.allclose(edge, [[0.5 / 64, 1 - 0.5 / 64, 0.0]])


def test_bilinear_lookup_of_a_2x2_texture_at_the_centre_is_the_mean():
    texture = np.arange(12, dtype=np.float64).reshape(2, 2, 3)
    assert np.allclose(tm.bilinear_lookup(texture, np.array([[0.5, 0.5]])), texture.mean((0, 1)))


def test_samples_are_on_the_surface_and_area_uniform():
    # Two triangles of areas 1/2 and 3/2 (the second stretched along x by 3).
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [2, 0, 0], [5, 0, 0], [2, 1, 0.0]])
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    samples = tm.sample_surface(vertices, faces, 40_000, seed=3)
    assert np.allclose(samples.barycentric.sum(axis=1), 1.0)
    assert (samples.barycentric >= 0).all()
    assert abs(np.mean(samples.face_ids == 1) - 0.75) < 0.01
    again = tm.sample_surface(vertices, faces, 40_000, seed=3)
    assert np.array_equal(samples.points, again.points)


def test_closest_point_regions_of_one_triangle():
    a, b, c = np.array([0.0, 0, 0]), np.array([1.0, 0, 0]), np.array([0.0, 1, 0])
    points = np.array(
        [
            [-1, -1, 0],  # vertex a
            [2, -0.5, 0],  # vertex b
            [-0.2, 3, 0],  # vertex c
            [0.5, -1, 0],  # edge ab, midpoint
            [-1, 0.25, 0],  # edge ac
            [1, 1, 0],  # edge bc, midpoint
            [0.25, 0.25, 5],  # above the inside
        ],
        dtype=np.float64,
    )
    expected = np.array(
        [
            [1, 0, 0],
            [0, 1, 0],
            [0, 0, 1],
            [0.5, 0.5, 0],
            [0.75, 0, 0.25],
            [0, 0.5, 0.5],
            [0.5, 0.25, 0.25],
        ]
    )
    k = len(points)
    found = tm.closest_point_on_triangles(
        points, np.tile(a, (k, 1)), np.tile(b, (k, 1)), np.tile(c, (k, 1))
    )
    assert np.allclose(found, expected)


@pytest.mark.parametrize("brute_force", [True, False])
def test_closest_points_on_a_tetrahedron(brute_force):
    if not brute_force:
        # open3d-cpu installs without libusb-1.0, and then fails to import (ImportError).
        pytest.importorskip("open3d", exc_type=ImportError)
    rng = np.random.default_rng(0)
    points = rng.normal(size=(200, 3))
    hits = tm.closest_points(TETRA_VERTICES, TETRA_FACES, points, brute_force=brute_force)
    # Against a dense reference: no surface point is closer than the one found.
    dense = tm.sample_surface(TETRA_VERTICES, TETRA_FACES, 20_000, seed=1).points
    nearest_dense = np.min(np.linalg.norm(points[:, None] - dense[None], axis=2), axis=1)
    assert (hits.distances <= nearest_dense + 1e-6).all()
    assert np.allclose(np.linalg.norm(hits.points - points, axis=1), hits.distances)
    if not brute_force:
        exact = tm.closest_points(TETRA_VERTICES, TETRA_FACES, points, brute_force=True)
        assert np.allclose(hits.distances, exact.distances, atol=1e-6)


def test_texture_error_is_zero_for_the_same_mesh_and_the_uv_shift_otherwise():
    texture = _gradient_texture()
    square = (SQUARE_VERTICES, SQUARE_FACES, SQUARE_UVS)
    same = tm.texture_error(square, square, texture, samples=2000, seed=0)
    assert same.symmetric_rms < 1e-6 and same.geometric_rms < 1e-6
    # UVs in [0.1, 0.9], then the same moved by +0.05 in u (still between the texel
    # centres, no clamping): red is off by 0.05 everywhere, one channel of three.
    shifted_uvs = SQUARE_UVS * 0.8 + [0.1, 0.1]
    moved = (SQUARE_VERTICES, SQUARE_FACES, shifted_uvs + [0.05, 0.0])
    base = (SQUARE_VERTICES, SQUARE_FACES, shifted_uvs)
    error = tm.texture_error(base, moved, texture, samples=2000, seed=0)
    assert error.forward_rms == pytest.approx(0.05 / np.sqrt(3), rel=1e-6)
    assert error.symmetric_rms == pytest.approx(0.05 / np.sqrt(3), rel=1e-6)


def test_color_error_of_a_coarser_square_is_its_interpolation_error():
    # Original: the square split at its centre (5 vertices) with a bright centre;
    # simplified: the two-triangle square, where the centre colour is the corners' mean.
    vertices = np.vstack([SQUARE_VERTICES, [[0.5, 0.5, 0.0]]])
    faces = np.array([[0, 1, 4], [1, 2, 4], [2, 3, 4], [3, 0, 4]])
    colors = np.zeros((5, 3))
    colors[4] = 1.0
    coarse_colors = np.zeros((4, 3))
    error = tm.color_error(
        (vertices, faces, colors),
        (SQUARE_VERTICES, SQUARE_FACES, coarse_colors),
        samples=50_000,
        seed=0,
    )
    # The original's colour is the barycentric weight of the centre, a "pyramid" with
    # mean square 1/6 over the square; the coarse mesh is black.
    assert error.forward_rms == pytest.approx(np.sqrt(1 / 6), rel=0.01)
    assert error.backward_rms == pytest.approx(np.sqrt(1 / 6), rel=0.01)
    same = tm.color_error((vertices, faces, colors), (vertices, faces, colors), 1000, 0)
    assert same.symmetric_rms < 1e-6  # Open3D answers in float32


def test_uv_counts_outside_flipped_and_degenerate():
    uvs = SQUARE_UVS.copy()
    assert tm.uv_outside_count(uvs) == 0
    uvs[0, 1] = [1.2, 0.0]
    assert tm.uv_outside_count(uvs) == 1
    original = (SQUARE_VERTICES, SQUARE_FACES, SQUARE_UVS)
    assert tm.uv_flipped_count(original, original) == (0, 0)
    flipped = SQUARE_UVS.copy()
    flipped[1] = flipped[1][[0, 2, 1]]  # corners swapped in UV only: turns clockwise
    assert tm.uv_flipped_count(original, (SQUARE_VERTICES, SQUARE_FACES, flipped)) == (1, 0)
    collapsed = SQUARE_UVS.copy()
    collapsed[0] = [[0.5, 0.5]] * 3
    assert tm.uv_flipped_count(original, (SQUARE_VERTICES, SQUARE_FACES, collapsed)) == (0, 1)
    assert np.allclose(tm.uv_signed_areas(SQUARE_UVS), [0.5, 0.5])


def test_seam_cracks_count_records_positions_and_open_edges():
    # The tetrahedron with vertex 3 split into two records at the same position: welded,
    # still closed.
    vertices = np.vstack([TETRA_VERTICES, TETRA_VERTICES[3]])
    faces = TETRA_FACES.copy()
    faces[3] = [1, 2, 4]
    assert tm.seam_cracks(vertices, faces) == {"records": 5, "positions": 4, "open_edges": 0}
    # Moving the second record away opens the crack: the two edges at vertex 3 and the
    # two at its moved copy lose their partner face.
    vertices[4] += [0.0, 0.0, 0.1]
    cracked = tm.seam_cracks(vertices, faces)
    assert cracked["positions"] == 5 and cracked["open_edges"] == 4


def test_signed_volume_of_a_tetrahedron_and_its_translate():
    assert tm.signed_volume(TETRA_VERTICES, TETRA_FACES) == pytest.approx(1 / 6)
    moved = TETRA_VERTICES + [10.0, -3.0, 7.0]
    assert tm.signed_volume(moved, TETRA_FACES) == pytest.approx(1 / 6)
    assert tm.signed_volume(TETRA_VERTICES, TETRA_FACES[:, ::-1]) == pytest.approx(-1 / 6)

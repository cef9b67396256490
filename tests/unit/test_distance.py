"""The one-step distance term (qem_core/_kernels/distance.py) and what it is for: cuts
that plane quadrics price at almost nothing."""

import numpy as np
import pytest

import qem_core
from qem_core._kernels.adjacency import make_face_lists
from qem_core._kernels.distance import (
    FREE_RATIO,
    point_triangle_distance2,
    star_distance2,
    with_distance,
)
from qem_core._kernels.heap import cost_key, key_cost
from tests import reference
from tests.tiny_meshes import grid, icosphere


def reference_distance(p, a, b, c):
    """Distance from p to triangle abc: to its plane if p projects inside, else to the
    nearest of its three sides."""
    n = np.cross(b - a, c - a)
    n = n / np.linalg.norm(n)
    q = p - np.dot(p - a, n) * n
    inside = all(np.dot(np.cross(v - u, q - u), n) >= 0 for u, v in ((a, b), (b, c), (c, a)))
    if inside:
        return abs(np.dot(p - a, n))

    def to_segment(u, v):
        t = np.clip(np.dot(p - u, v - u) / np.dot(v - u, v - u), 0.0, 1.0)
        return np.linalg.norm(p - (u + t * (v - u)))

    return min(to_segment(a, b), to_segment(b, c), to_segment(c, a))


def test_point_triangle_distance_matches_a_reference():
    rng = np.random.default_rng(0)
    for _ in range(500):
        a, b, c, p = rng.normal(size=(4, 3))
        got = np.sqrt(point_triangle_distance2(*p, *a, *b, *c))
        assert got == pytest.approx(reference_distance(p, a, b, c), rel=1e-9, abs=1e-12)


def test_point_triangle_distance_of_a_degenerate_triangle_is_to_its_segment():
    a, b = np.zeros(3), np.array([2.0, 0.0, 0.0])
    assert point_triangle_distance2(1.0, 1.0, 0.0, *a, *b, *b) == pytest.approx(1.0)


@pytest.mark.parametrize("corners", [(0, 0, 1), (0, 1, 1), (0, 1, 0), (0, 0, 0)])
def test_point_triangle_distance_with_coincident_corners_is_to_the_rest(corners):
    """Regression: a zero-length edge divided 0 by 0 (ZeroDivisionError in the build of
    a mesh with coincident vertices kept, merge_coincident=False)."""
    points = np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0]])
    a, b, c = points[list(corners)]
    ends = points[sorted(set(corners))]  # the triangle is this segment (or point)
    rng = np.random.default_rng(1)
    for p in rng.normal(size=(200, 3)):
        t = np.clip(p[0] / 2.0, 0.0, 1.0) if len(ends) == 2 else 0.0
        expected = np.linalg.norm(p - (ends[0] + t * (ends[-1] - ends[0])))
        got = np.sqrt(point_triangle_distance2(*p, *a, *b, *c))
        assert got == pytest.approx(expected, rel=1e-9, abs=1e-12)


def test_a_mesh_with_coincident_vertices_kept_builds():
    vertices = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 1, 0]], float)  # 3 on 2
    pm = qem_core.build(vertices, [[0, 1, 2], [3, 2, 1]], {"merge_coincident": False})
    for n in range(pm.n_base, pm.n_full + 1):
        assert pm.lod(n)[0].shape[0] == n


def star_of(vertices, faces):
    faces = np.asarray(faces, np.int32)
    lists = make_face_lists(faces, vertices.shape[0], capacity=faces.size)
    return faces, lists.start, lists.count, lists.pool


def spike_fan(height):
    """A unit hexagon in z = 0, its centre 0 raised into a spike of the given height."""
    angles = np.arange(6) * np.pi / 3
    ring = np.stack([np.cos(angles), np.sin(angles), np.zeros(6)], axis=1)
    vertices = np.vstack([[0.0, 0.0, height], ring])
    faces = [[0, 1 + i, 1 + (i + 1) % 6] for i in range(6)]
    return vertices, faces


def test_flat_contraction_moves_nothing():
    vertices, faces = grid(4)
    faces, start, count, pool = star_of(vertices, faces)
    a, b = 5, 6  # an inner edge of the grid, contracted to its midpoint
    p = 0.5 * (vertices[a] + vertices[b])
    assert star_distance2(vertices, faces, start, count, pool, a, b, *p, 0.0) < 1e-24


def test_cutting_a_spike_off_costs_its_height():
    vertices, faces = spike_fan(height=3.0)
    faces, start, count, pool = star_of(vertices, faces)
    # The tip 0 into the corner 1, which stays where it is: the fan from 1 covers the
    # hexagon, 3 under the old tip.
    d2 = star_distance2(vertices, faces, start, count, pool, 0, 1, *vertices[1], 0.0)
    assert np.sqrt(d2) == pytest.approx(3.0)


def reference_star_distance(vertices, faces, a, b, p):
    """The same points, brute force: the old a and b against every new face, p and the
    midpoint of every new edge against every old face."""
    old = [f for f in faces if a in f or b in f]
    new = []
    for f in old:
        if a in f and b in f:
            continue
        corners = [p if v in (a, b) else vertices[v] for v in f]
        new.append(corners)
    new_edges = {v for f in old if not (a in f and b in f) for v in f} - {a, b}

    def to_old(q):
        return min(reference_distance(q, *vertices[f]) for f in old)

    def to_new(q):
        return min(reference_distance(q, *corners) for corners in new)

    return max([to_new(vertices[a]), to_new(vertices[b]), to_old(p)]
               + [to_old(0.5 * (p + vertices[x])) for x in new_edges])


def random_contraction(seed, mesh_seed):
    """A jittered icosphere, a random edge (a, b) of it and a new position p near it."""
    rng = np.random.default_rng(seed)
    vertices, faces = icosphere(2, jitter=0.3, seed=mesh_seed)
    faces = np.asarray(faces, np.int32)
    a = int(rng.integers(len(vertices)))
    ring = sorted({int(v) for f in faces if a in f for v in f} - {a})
    b = ring[int(rng.integers(len(ring)))]
    p = vertices[a] + rng.uniform(-0.2, 1.2) * (vertices[b] - vertices[a])
    p = p + rng.normal(scale=0.1, size=3)
    faces, start, count, pool = star_of(vertices, faces)
    return vertices, faces, start, count, pool, a, b, p


@pytest.mark.parametrize("seed", range(20))
def test_star_distance_matches_a_brute_force_over_its_points(seed):
    vertices, faces, start, count, pool, a, b, p = random_contraction(seed, seed)
    d2 = star_distance2(vertices, faces, start, count, pool, a, b, *p, 0.0)
    expected = reference_star_distance(vertices, faces.tolist(), a, b, p)
    assert np.sqrt(d2) == pytest.approx(expected, rel=1e-9, abs=1e-12)


def quadric_cost(vertices, faces, a, b, p):
    """(quadric, cost) of contracting (a, b) to p, unweighted planes of their faces."""
    q = reference.star_quadric(vertices, faces, a, b)
    return q, reference.evaluate_quadric(q, p)


def test_with_distance_charges_a_cut_and_leaves_a_flat_move_alone():
    vertices, faces = spike_fan(height=3.0)
    faces_array, start, count, pool = star_of(vertices, faces)
    args = (vertices, faces_array, start, count, pool)
    q, cost = quadric_cost(vertices, faces_array, 0, 1, vertices[1])
    # The next candidate costs as much as this one: any charge puts this one behind it.
    charged = with_distance(*args, 0, 1, *vertices[1], q, cost, cost_key(cost),
                            cost_key(cost), 1.0)
    weight = q[0] + q[3] + q[5]
    assert 9.0 > FREE_RATIO * cost / weight
    assert charged == pytest.approx(cost + weight * (9.0 - FREE_RATIO * cost / weight))
    # A key above the quadric cost is a full cost priced before: taken as it is.
    assert with_distance(*args, 0, 1, *vertices[1], q, cost, cost_key(2 * charged),
                         cost_key(cost), 1.0) == 2 * charged
    # Nothing waits behind it (or nothing below its full cost): contracted now either
    # way, at its quadric cost.
    for next_cost in (np.inf, 2 * charged):
        assert with_distance(*args, 0, 1, *vertices[1], q, cost, cost_key(cost),
                             cost_key(next_cost), 1.0) == cost
    flat, flat_faces = grid(4)
    flat_faces, start, count, pool = star_of(flat, flat_faces)
    p = 0.5 * (flat[5] + flat[6])
    q, cost = quadric_cost(flat, flat_faces, 5, 6, p)
    assert with_distance(flat, flat_faces, start, count, pool, 5, 6, *p, q, cost,
                         cost_key(cost), cost_key(cost), 1.0) == cost


def test_key_cost_inverts_cost_key():
    for cost in (0.0, 1e-300, 0.5, 3.0, 1e300, np.inf):
        assert key_cost(cost_key(cost)) == cost


def spiked_sphere(height):
    """An icosphere (642 vertices) with vertex 0 pulled out into a spike."""
    vertices, faces = icosphere(3)
    vertices = vertices / np.linalg.norm(vertices, axis=1)[:, None]
    vertices[0] *= 1.0 + height
    return vertices, faces


def distance_to_level(point, vertices, faces):
    return np.sqrt(min(point_triangle_distance2(*point, *vertices[f[0]], *vertices[f[1]],
                                                *vertices[f[2]]) for f in faces))


@pytest.mark.parametrize("n", [30, 10])
def test_a_spike_outlives_the_smooth_parts(n):
    # The spike's faces are nearly parallel to it, so the plane quadrics price cutting it
    # back at little more than flattening the sphere (the dragon's scan-seam fins go the
    # same way); with the distance term each step costs its length and the spike stays
    # while the sphere around it coarsens.
    vertices, faces = spiked_sphere(height=0.5)
    pm = qem_core.build(vertices, faces, {"distance_weight": 2.0})
    assert distance_to_level(vertices[0], *pm.lod(n)) < 0.1


def test_without_the_distance_term_the_spike_is_cut():
    vertices, faces = spiked_sphere(height=0.5)
    pm = qem_core.build(vertices, faces, {"distance_weight": 0.0})
    assert distance_to_level(vertices[0], *pm.lod(30)) > 0.3


def test_distance_weight_is_validated():
    for bad in (-1.0, float("nan"), "2", True):
        with pytest.raises(qem_core.InvalidOptionsError, match="distance_weight"):
            qem_core.BuildOptions(distance_weight=bad)


def test_a_vertex_of_high_degree_is_priced_by_the_quadric():
    """Regression: the star search costs the square of the star's size and the centre of
    a fan is contracted into once per rim vertex; a fan of 3000 triangles took minutes.
    Stars past MAX_DISTANCE_STAR faces skip the term."""
    n = 2000
    angles = np.arange(n) * 2 * np.pi / n
    rim = np.stack([np.cos(angles), np.sin(angles), 0 * angles], axis=1)
    vertices = np.vstack([[0.0, 0.0, 0.0], rim])
    faces = [[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]
    pm = qem_core.build(vertices, faces)
    assert pm.n_base == 3
    for level in (3, 100, n + 1):
        assert pm.lod(level)[0].shape[0] == level


@pytest.mark.parametrize("seed", range(20))
def test_star_distance_is_exact_beyond_enough_and_within_it_below(seed):
    """With a bound ``enough`` the search may stop early (a point within it of some face
    counts for nothing), so the value is the brute force's where that is beyond the
    bound, and within the bound where the brute force is."""
    vertices, faces, start, count, pool, a, b, p = random_contraction(100 + seed, seed)
    expected2 = reference_star_distance(vertices, faces.tolist(), a, b, p) ** 2
    for enough in (0.25 * expected2, 0.9 * expected2, 1.1 * expected2, 1.5 * expected2):
        d2 = star_distance2(vertices, faces, start, count, pool, a, b, *p, enough)
        if expected2 > enough:
            assert d2 == pytest.approx(expected2, rel=1e-9, abs=1e-24)
        else:
            assert d2 <= enough

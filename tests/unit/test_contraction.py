"""The greedy contraction on hand-drawn meshes with known outcomes."""

import numpy as np
import pytest

import qem_core
from qem_core import simplify
from qem_core._kernels.adjacency import make_face_lists
from qem_core._kernels.contract import RETRY_MAX_FACES, update_vertex_edges
from qem_core._kernels.heap import cost_key, make_heap
from qem_core._kernels.link import make_neighbourhood
from qem_core._kernels.quadrics import QUADRIC_SIZE
from qem_core.prepare import unique_edges
from qem_core.simplify import contract_greedily
from tests import reference
from tests.tiny_meshes import (
    OCTAHEDRON,
    OPEN_BOX,
    SQUARE,
    TETRAHEDRON,
    bumpy_grid,
    grid,
    icosphere,
)


def every_level(pm):
    for n in range(pm.n_base, pm.n_full + 1):
        yield n, *pm.lod(n)


def test_tetrahedron_cannot_shrink():
    pm = qem_core.build(*TETRAHEDRON)
    assert (pm.n_base, pm.n_full) == (4, 4)
    assert pm.lod(1)[1].shape == (4, 3)


def test_octahedron_shrinks_to_a_tetrahedron_and_stays_closed():
    pm = qem_core.build(*OCTAHEDRON)
    assert (pm.n_base, pm.n_full) == (4, 6)
    for n, vertices, faces in every_level(pm):
        assert vertices.shape == (n, 3)
        assert reference.is_closed_manifold(faces)
        assert reference.euler_characteristic(faces) == 2


def test_square_becomes_one_triangle():
    pm = qem_core.build(*SQUARE)
    assert (pm.n_base, pm.n_full) == (3, 4)
    vertices, faces = pm.lod(3)
    assert faces.shape == (1, 3)
    assert reference.boundary_loops(faces) == 1


def test_open_box_keeps_its_single_border_loop():
    pm = qem_core.build(*OPEN_BOX)
    assert pm.n_full == 8
    for _n, _vertices, faces in every_level(pm):
        assert reference.boundary_loops(faces) == 1
        assert reference.euler_characteristic(faces) == 1


def test_two_tetrahedra_stay_two_components():
    v, f = TETRAHEDRON
    pm = qem_core.build(np.concatenate([v, v + 5]), np.concatenate([f, f + 4]))
    assert pm.n_base == 8 and reference.components(pm.lod(8)[1]) == 2


def test_flat_grid_stays_in_its_plane():
    pm = qem_core.build(*grid(6))
    for _n, vertices, _faces in every_level(pm):
        assert np.all(vertices[:, 2] == 0.0)


def test_flat_grid_costs_nothing_without_border_planes():
    # The plane quadrics alone: the distance term would charge the border's shrinking
    # (which no plane sees without border planes, and which it is there to see).
    pm = qem_core.build(*grid(6), {"boundary_weight": 0.0, "distance_weight": 0.0})
    assert pm.error(pm.n_base) == pytest.approx(0.0, abs=1e-12)


def test_border_of_a_flat_grid_does_not_erode():
    """Border vertices slide along the border, never off the square; at 4 vertices the
    square is exactly its four corners (every other border vertex goes first, free)."""
    pm = qem_core.build(*grid(6))
    for _n, vertices, _faces in every_level(pm):
        assert vertices[:, :2].min() >= 0 and vertices[:, :2].max() <= 5
    vertices, _faces = pm.lod(4)
    corners = {(0.0, 0.0), (5.0, 0.0), (0.0, 5.0), (5.0, 5.0)}
    assert corners <= {tuple(p) for p in vertices[:, :2].tolist()}


def test_error_never_decreases_as_levels_coarsen():
    pm = qem_core.build(*icosphere(2, jitter=0.05))
    errors = pm.errors()
    assert errors[-1] == 0.0
    assert np.all(np.diff(errors) <= 0)


@pytest.mark.parametrize("options", [
    {}, {"error_mode": "exact"}, {"weighting": "none"}, {"weighting": "sqrt_area"},
    {"weighting": "volume"},
    {"boundary_weight": 0.0}, {"max_face_turn_deg": 180.0}, {"distance_weight": 0.0},
    {"distance_weight": 3.0, "error_mode": "exact"}, {"volume_weight": 0.0},
    {"volume_weight": 10.0, "distance_weight": 0.0},
])
def test_build_is_deterministic(options, tmp_path):
    mesh = icosphere(2, jitter=0.05, seed=3)
    first, second = qem_core.build(*mesh, options), qem_core.build(*mesh, options)
    first.save(tmp_path / "a.qpm")
    second.save(tmp_path / "b.qpm")
    assert (tmp_path / "a.qpm").read_bytes() == (tmp_path / "b.qpm").read_bytes()


def test_progress_is_reported_from_zero_to_one():
    seen = []
    qem_core.build(*icosphere(2), progress=seen.append)
    assert seen[0] == 0.0 and seen[-1] == 1.0
    assert seen == sorted(seen)


def test_a_small_mesh_reports_progress_while_it_contracts():
    """Regression: progress (and a server's check for a delete) came once per 16384
    contractions, so a mesh of fewer vertices reported none until it was done."""
    seen = []
    qem_core.build(*grid(60), progress=seen.append)  # 3600 vertices
    assert len({f for f in seen if 0.02 < f < 0.95}) >= 8


@pytest.mark.parametrize("distance_weight, volume_weight", [(0.0, 0.0), (1.0, 0.0), (0.0, 3.0),
                                                           (2.0, 3.0)])
def test_lod_equals_the_greedy_run_stopped_there(distance_weight, volume_weight):
    vertices, faces = icosphere(2, jitter=0.05, seed=1)
    # The greedy run's own positions: no tangent lattice (test_lattice.py tests that).
    options = qem_core.BuildOptions(distance_weight=distance_weight,
                                    volume_weight=volume_weight, tangent_lattice=False)
    pm = qem_core.build(vertices, faces, options)
    for n in sorted({reference.greedy_level(pm, n) for n in (pm.n_base, 20, 60, 120, pm.n_full)}):
        run = contract_greedily(vertices.astype(float), faces.astype(np.int32), options,
                                max_contractions=pm.n_full - n)
        alive = run.complex.face_alive.astype(bool)
        expected = reference.triangle_set(run.complex.vertices, run.complex.faces[alive])
        assert reference.triangle_set(*pm.lod(n)) == expected


@pytest.mark.parametrize("bad, message", [
    ((np.zeros((0, 3)), np.zeros((0, 3), int)), "vert"),
    ((np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), [[0, 1, 2]]), "finite"),
    ((np.eye(3), [[0, 1, 3]]), "index 3"),
    ((np.eye(3), np.zeros((0, 3), int)), "face"),
])
def test_bad_meshes_are_refused_clearly(bad, message):
    with pytest.raises(qem_core.InvalidMeshError, match=f"(?i){message}"):
        qem_core.build(*bad)


def test_bad_options_are_refused_clearly():
    with pytest.raises(qem_core.InvalidOptionsError, match="weighting"):
        qem_core.build(*SQUARE, {"weighting": "mass"})
    with pytest.raises(qem_core.InvalidOptionsError, match="unknown build option"):
        qem_core.build(*SQUARE, {"colour": 1})


def _same_levels_scaled(pm, scaled, exponent, cost_degree):
    assert (scaled.n_base, scaled.n_full) == (pm.n_base, pm.n_full)
    for n in range(pm.n_base, pm.n_full + 1):
        vertices, faces = pm.lod(n)
        scaled_vertices, scaled_faces = scaled.lod(n)
        assert np.array_equal(scaled_faces, faces)
        assert np.array_equal(scaled_vertices, np.ldexp(vertices, exponent))
        assert scaled.error(n) == np.ldexp(pm.error(n), cost_degree * exponent)


@pytest.mark.parametrize("weighting, cost_degree", [("none", 2), ("sqrt_area", 3), ("volume", 6)])
@pytest.mark.parametrize("exponent", [-150, -3, 5, 150])  # costs stay in the float range
def test_levels_are_the_same_at_any_power_of_two_scale(weighting, cost_degree, exponent):
    """build contracts every mesh at one scale (simplify.to_unit_scale): a mesh 2^e
    times as large has the same levels, 2^e times as large, and costs that scale as a
    squared distance times its plane weight. Regression: at 1e+-80 nothing contracted
    (the quadrics overflowed or underflowed) and the build returned the input alone."""
    vertices, faces = bumpy_grid(8)
    vertices = vertices * [1.0, 1.5, 0.7] + [3.0, -2.0, 0.5]
    options = {"weighting": weighting}
    pm = qem_core.build(vertices, faces, options)
    scaled = qem_core.build(np.ldexp(vertices, exponent), faces, options)
    _same_levels_scaled(pm, scaled, exponent, cost_degree)


@pytest.mark.parametrize("scale", [1e-300, 1e-100, 1e100, 1e300])
def test_meshes_of_extreme_size_simplify_as_far(scale):
    vertices, faces = icosphere(2, jitter=0.1)
    assert qem_core.build(vertices * scale, faces).n_base == qem_core.build(vertices, faces).n_base


@pytest.mark.parametrize("exponent", [-300, 7, 300])
def test_levels_with_colours_are_the_same_at_any_power_of_two_scale(exponent):
    """The colours, weighted by the bounding-box diagonal, scale with it: the levels
    and their colours do not change, nor does what the file stores."""
    vertices, faces = bumpy_grid(8)
    colours = np.random.default_rng(3).uniform(0, 1, (vertices.shape[0], 3)).astype(np.float32)
    options = {"distance_weight": 0.0}  # costs past the float range at 2^300 are clamped
    pm = qem_core.build_mesh(qem_core.Mesh(vertices, faces, {"color": colours}), options)
    scaled = qem_core.build_mesh(
        qem_core.Mesh(np.ldexp(vertices, exponent), faces, {"color": colours}), options
    )
    assert pm.metadata["attributes"] == scaled.metadata["attributes"]
    for name, array in pm.wedge_arrays.items():
        assert np.array_equal(scaled.wedge_arrays[name], array), name
    for n in range(pm.n_base, pm.n_full + 1):
        level, scaled_level = pm.lod_mesh(n), scaled.lod_mesh(n)
        assert np.array_equal(scaled_level.faces, level.faces)
        assert np.array_equal(scaled_level.vertices, np.ldexp(level.vertices, exponent))
        assert np.array_equal(scaled_level.vertex_attributes["color"],
                              level.vertex_attributes["color"])


def flat_fan(n_faces, closed):
    """Vertex 0 at the centre of a flat fan of n_faces triangles around it (a full disk
    when closed, else a half disk with vertex 0 on its border), rim vertices 1, 2, ..."""
    angles = np.linspace(0.0, 2.0 * np.pi if closed else np.pi, n_faces + 1)
    if closed:
        angles = angles[:-1]
    rim = np.stack([np.cos(angles), np.sin(angles), np.zeros_like(angles)], axis=1)
    vertices = np.vstack([np.zeros((1, 3)), rim])
    first = np.arange(n_faces) + 1
    second = (np.arange(n_faces) + 1) % rim.shape[0] + 1
    faces = np.stack([np.zeros(n_faces, np.int64), first, second], axis=1)
    return vertices, faces


@pytest.mark.parametrize("hub_faces", [RETRY_MAX_FACES, RETRY_MAX_FACES + 1])
def test_a_refused_hub_is_retried_only_up_to_its_face_limit(hub_faces):
    """When v is contracted into, its neighbours that had an edge refused are listed for
    a retry, except a hub of more than RETRY_MAX_FACES faces, which stays marked (its
    retries made a flat fan's build quadratic in the hub's degree, contract.py)."""
    vertices, faces = flat_fan(hub_faces, closed=True)
    n = vertices.shape[0]
    options = qem_core.BuildOptions()
    cx, _ = simplify._initial_complex(vertices, faces, options, unique_edges(faces, n), None,
                                      owned=False)
    assert np.count_nonzero(cx.faces == 0) == hub_faces
    lists = make_face_lists(cx.faces, n, 6 * cx.faces.shape[0] + 1024, alive=cx.face_alive)
    hood = make_neighbourhood(n)
    heap = make_heap(int(cx.face_edge.max()) + 1)
    cx.vertex_refused[[0, 2]] = 1  # the hub and a rim neighbour of vertex 1
    look = simplify._look(cx, simplify._make_scratch(cx, options, None))
    _, n_retry = update_vertex_edges(
        cx.vertices, cx.vertex_quadrics, cx.vertex_refused, cx.edge_quadrics, cx.faces,
        cx.face_alive, cx.face_edge, lists.start, lists.count, lists.pool, hood.near,
        hood.generation, hood.retry, hood.part, heap.entries, heap.position, heap.size,
        cost_key(np.inf), np.int64(1), np.bool_(False), False, options.rank_tolerance,
        np.zeros(QUADRIC_SIZE), np.zeros(3), look)
    retried = sorted(hood.retry[:n_retry].tolist())
    hub_retried = hub_faces <= RETRY_MAX_FACES
    assert retried == ([0, 2] if hub_retried else [2])
    assert cx.vertex_refused[0] == (0 if hub_retried else 1)
    assert cx.vertex_refused[2] == 0
    assert heap.size[0] == 3  # vertex 1's edges to the hub and both rim neighbours


@pytest.mark.parametrize("closed", [False, True])
def test_a_flat_fan_around_a_hub_simplifies_to_its_base(closed):
    vertices, faces = flat_fan(2 * RETRY_MAX_FACES, closed)
    pm = qem_core.build(vertices, faces)
    assert pm.n_base == 3
    base_vertices, base_faces = pm.lod(pm.n_base)
    assert np.allclose(base_vertices[:, 2], 0.0)
    assert reference.boundary_loops(base_faces) == 1


def double_cone(n_rim):
    """Two hubs (vertex 0 above, vertex n_rim + 1 below) joined by a flat rim of n_rim
    vertices: a closed sphere whose hubs have n_rim faces each, far past the prefetch and
    retry limits of contract.py."""
    vertices, top = flat_fan(n_rim, closed=True)
    vertices[0] = (0.0, 0.0, 1.0)  # the fan's centre lifted: the upper hub
    vertices = np.vstack([vertices, [[0.0, 0.0, -1.0]]])
    bottom = np.stack([np.full(n_rim, n_rim + 1), top[:, 2], top[:, 1]], axis=1)
    return vertices, np.vstack([top, bottom])


def test_a_double_cone_keeps_its_sphere_down_to_a_tetrahedron():
    """Every contraction next to a hub reads the hub's faces (flip guard, bare-vertex
    check, prefetch), which take the hub's smaller partner or a capped prefix first: the
    answers must stay those of the full scans."""
    vertices, faces = double_cone(2 * RETRY_MAX_FACES)
    assert reference.is_closed_manifold(faces)
    pm = qem_core.build(vertices, faces)
    assert pm.n_base == 4
    for n, _, level_faces in every_level(pm):
        assert reference.fast_is_closed_manifold(level_faces), n
        assert reference.fast_euler_characteristic(level_faces) == 2, n

"""Appearance attributes (Hoppe's quadric over wedges) and volume preservation."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import qem_core
from qem_core._kernels.appearance import (
    ALPHA,
    B_START,
    add_schur,
    best_attributes,
    wedge_row_size,
)
from qem_core._kernels.placement import solve3
from qem_core.attributes import make_wedges
from qem_core.options import BuildOptions
from qem_core.prepare import prepare_mesh
from qem_core.simplify import contract_greedily, to_unit_scale
from tests import reference

REPO = Path(__file__).resolve().parents[2]
SPOT = REPO / "server" / "demo" / "spot.obj"
SHARED = REPO.parent / "shared" / "meshes"


@pytest.fixture(scope="module")
def spot():
    return qem_core.load_mesh(SPOT)


@pytest.fixture(scope="module")
def spot_pm(spot):
    return qem_core.build_mesh(spot)


def _uv_areas(faces_uv: np.ndarray) -> np.ndarray:
    d1 = faces_uv[:, 1] - faces_uv[:, 0]
    d2 = faces_uv[:, 2] - faces_uv[:, 0]
    return d1[:, 0] * d2[:, 1] - d1[:, 1] * d2[:, 0]


# -- the O(m) solve -------------------------------------------------------------------
@pytest.mark.parametrize("m", [1, 2, 3, 5, 8])
@pytest.mark.parametrize("seed", range(5))
def test_schur_solve_equals_dense_solve(m, seed):
    """Minimising through the 3x3 Schur complement gives the minimiser of the whole
    (3 + m)-dimensional quadric, for random well-conditioned quadrics."""
    rng = np.random.default_rng(seed)
    alpha = rng.uniform(0.5, 2.0)
    g = rng.normal(size=(3, m))  # B = -g
    extra = rng.normal(size=(3, 3))
    a_matrix = g @ g.T / alpha + extra @ extra.T + np.eye(3)  # A - B B^T / alpha is PD
    b1, b2, c = rng.normal(size=3), rng.normal(size=m), rng.uniform(5, 10)
    b_matrix = -g
    dense = np.block([[a_matrix, b_matrix], [b_matrix.T, alpha * np.eye(m)]])
    assert np.all(np.linalg.eigvalsh(dense) > 0)
    expected = np.linalg.solve(dense, -np.concatenate([b1, b2]))

    row = np.zeros(wedge_row_size(m))
    row[[0, 1, 2, 3, 4, 5]] = a_matrix[[0, 0, 0, 1, 1, 2], [0, 1, 2, 1, 2, 2]]
    row[6:9], row[9], row[ALPHA] = b1, c, alpha
    row[B_START : B_START + 3 * m] = b_matrix.T.reshape(-1)
    row[B_START + 3 * m :] = b2
    reduced = np.zeros(10)
    add_schur(row, m, reduced)
    p = -np.array(solve3(*reduced[:6], *reduced[6:9]))
    s = np.zeros(m)
    bounds = np.array([[-1e9] * m, [1e9] * m])
    best_attributes(row, m, p[0], p[1], p[2], np.zeros(m), bounds, s)
    np.testing.assert_allclose(np.concatenate([p, s]), expected, rtol=1e-9, atol=1e-9)
    # and the reduced quadric's value is the minimum of the whole one over s
    x = np.concatenate([p, s])
    full_value = x @ dense @ x + 2 * np.concatenate([b1, b2]) @ x + c
    reduced_value = (p @ np.array([[reduced[0], reduced[1], reduced[2]],
                                   [reduced[1], reduced[3], reduced[4]],
                                   [reduced[2], reduced[4], reduced[5]]]) @ p
                     + 2 * reduced[6:9] @ p + reduced[9])
    assert reduced_value == pytest.approx(full_value, rel=1e-9, abs=1e-9)


# -- spot: texture coordinates with seams -------------------------------------------
def test_spot_full_level_gives_back_every_corner_uv(spot, spot_pm):
    full = spot_pm.lod_mesh(spot_pm.n_full)
    level_to_input = np.empty(spot_pm.n_full, np.int64)
    level_to_input[spot_pm.vertex_map] = np.arange(spot_pm.vertex_map.size)
    by_face = {frozenset(f.tolist()): (f.tolist(), uv) for f, uv in
               zip(spot.faces, spot.corner_uvs, strict=True)}
    for face, uvs in zip(level_to_input[full.faces], full.corner_uvs, strict=True):
        input_face, input_uvs = by_face[frozenset(face.tolist())]
        order = [input_face.index(v) for v in face.tolist()]
        np.testing.assert_allclose(uvs, input_uvs[order], atol=1e-6)


@pytest.mark.parametrize("fraction", [0.5, 0.1, 0.02])
def test_spot_levels_keep_uvs_inside_unflipped_and_seams_closed(spot, spot_pm, fraction):
    n = int(fraction * spot.vertices.shape[0])
    level = spot_pm.lod_mesh(n)
    assert level.vertices.shape[0] == n
    uv = level.corner_uvs
    assert uv.shape == (level.faces.shape[0], 3, 2)
    low, high = spot.corner_uvs.min(axis=(0, 1)), spot.corner_uvs.max(axis=(0, 1))
    assert np.all(uv >= low - 1e-6) and np.all(uv <= high + 1e-6)
    # Seams are closed in space: the level is still a closed surface (every edge has
    # two faces), however many UVs a vertex carries.
    edges = np.sort(level.faces[:, [0, 1, 1, 2, 2, 0]].reshape(-1, 2), axis=1)
    _, counts = np.unique(edges, axis=0, return_counts=True)
    assert np.all(counts == 2)


@pytest.fixture(scope="module")
def spot_wedges(spot):
    prepared = prepare_mesh(spot.vertices, spot.faces)
    diagonal = float(np.linalg.norm(np.ptp(prepared.vertices, axis=0)))
    wedges = make_wedges(spot, prepared.face_map, prepared.faces, BuildOptions(), diagonal)
    return prepared, wedges


@pytest.mark.parametrize("fraction", [0.5, 0.1, 0.02])
def test_no_uv_triangle_flips(spot_wedges, fraction):
    """Every face that survives keeps the orientation its UV triangle had in the input
    (spot has a few clockwise UV triangles: they stay clockwise) and never collapses."""
    prepared, wedges = spot_wedges
    n = prepared.vertices.shape[0]
    run = contract_greedily(prepared.vertices, prepared.faces, BuildOptions(), wedges=wedges,
                            max_contractions=n - int(fraction * n))
    alive = run.complex.face_alive.astype(bool)
    before = _uv_areas(wedges.values[wedges.face_wedges[alive]])
    after = _uv_areas(run.complex.wedge_values[run.complex.face_wedges[alive]])
    assert np.count_nonzero(before < 0) > 0
    assert np.all(np.sign(after) == np.sign(before))


def test_lod_mesh_equals_the_greedy_run_stopped_there(spot):
    """Positions and the UV of every face corner at level n are those the greedy run
    had when it stopped at n vertices (built without the tangent lattice, which moves
    the positions of the coarser levels: test_lattice.py)."""
    spot_pm = qem_core.build_mesh(spot, {"tangent_lattice": False})
    options = BuildOptions()
    prepared = prepare_mesh(spot.vertices, spot.faces)
    unit_vertices, scale, diagonal = to_unit_scale(prepared.vertices)  # as build does
    wedges = make_wedges(spot, prepared.face_map, prepared.faces, options, diagonal)
    for n in sorted({reference.greedy_level(spot_pm, n) for n in (2000, 500, 60)}):
        run = contract_greedily(unit_vertices, prepared.faces, options, wedges=wedges,
                                max_contractions=prepared.vertices.shape[0] - n)
        cx = run.complex
        alive = cx.face_alive.astype(bool)
        corners = cx.faces[alive]
        expected = np.concatenate(
            [np.ldexp(cx.vertices[corners], scale).reshape(-1, 3),
             cx.wedge_values[cx.face_wedges[alive]].reshape(-1, 2).astype(np.float32)], axis=1)
        level_faces, level_values = spot_pm.wedge_level(n)
        vertices, faces = spot_pm.lod(n)
        got = np.concatenate([vertices[faces].reshape(-1, 3),
                              level_values[level_faces].reshape(-1, 2)], axis=1)
        assert np.array_equal(np.unique(expected, axis=0), np.unique(got, axis=0))


def test_attributes_survive_qpm(tmp_path, spot_pm):
    spot_pm.save(tmp_path / "spot.qpm")
    loaded = qem_core.load(tmp_path / "spot.qpm")
    for n in (spot_pm.n_base, 300, spot_pm.n_full):
        a, b = spot_pm.lod_mesh(n), loaded.lod_mesh(n)
        assert np.array_equal(a.faces, b.faces)
        assert np.array_equal(a.corner_uvs, b.corner_uvs)


def test_damaged_wedge_arrays_are_refused(tmp_path, spot_pm):
    from qem_core.qpm import _checked_progressive_mesh  # noqa: F401 (the checker in use)

    path = tmp_path / "spot.qpm"
    spot_pm.save(path)
    arrays = dict(spot_pm.wedge_arrays)
    arrays["wedge_relabel_to"] = arrays["wedge_relabel_to"].copy()
    arrays["wedge_relabel_to"][-1] = 10**8
    with pytest.raises(qem_core.CorruptFileError):
        qem_core.progressive.check_wedge_arrays(arrays, spot_pm.level_faces,
                                                spot_pm.metadata["attributes"])


def test_geometry_only_build_is_unchanged_by_the_attribute_code(spot):
    plain = qem_core.build(spot.vertices, spot.faces)
    no_weights = qem_core.build_mesh(spot, {"uv_weight": 0.0})
    for n in (100, 1000):
        a, b = plain.lod(n), no_weights.lod(n)
        assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert no_weights.attribute_layout is None


# -- colours -------------------------------------------------------------------------
def test_vertex_colours_are_kept_in_range():
    rng = np.random.default_rng(3)
    grid = 12
    x, y = np.meshgrid(np.linspace(0, 1, grid), np.linspace(0, 1, grid))
    vertices = np.stack([x.ravel(), y.ravel(), 0.05 * np.sin(6 * x.ravel())], axis=1)
    quads = np.array([[i * grid + j, i * grid + j + 1, (i + 1) * grid + j + 1,
                       (i + 1) * grid + j] for i in range(grid - 1) for j in range(grid - 1)])
    faces = np.concatenate([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]])
    colours = np.where(vertices[:, :1] < 0.5, [1.0, 0.0, 0.0], [0.0, 0.0, 1.0])
    colours = np.clip(colours + rng.uniform(0, 0.01, colours.shape), 0, 1)
    mesh = qem_core.Mesh(vertices=vertices, faces=faces,
                         vertex_attributes={"color": colours.astype(np.float32)})
    pm = qem_core.build_mesh(mesh)
    level = pm.lod_mesh(40)
    assert level.vertex_attributes["color"].shape == (40, 3)
    assert level.vertex_attributes["color"].min() >= 0.0
    assert level.vertex_attributes["color"].max() <= 1.0 + 1e-6
    # The colour border survives: a red and a blue side remain.
    red = level.vertex_attributes["color"][:, 0] > 0.9
    blue = level.vertex_attributes["color"][:, 2] > 0.9
    assert red.sum() >= 5 and blue.sum() >= 5


# -- volume --------------------------------------------------------------------------
@pytest.mark.skipif(not (SHARED / "fandisk.ply").exists(),
                    reason="needs ../shared/meshes (fandisk.ply)")
def test_volume_is_kept_on_fandisk():
    mesh = qem_core.load_mesh(SHARED / "fandisk.ply")
    before = reference.enclosed_volume(mesh.vertices, mesh.faces)
    pm = qem_core.build(mesh.vertices, mesh.faces, {"preserve_volume": True})
    for fraction in (0.5, 0.1, 0.02):
        vertices, faces = pm.lod(int(fraction * mesh.vertices.shape[0]))
        assert abs(reference.enclosed_volume(vertices, faces) - before) <= 1e-4 * abs(before)


def test_volume_is_kept_on_spot(spot):
    before = reference.enclosed_volume(spot.vertices, spot.faces)
    pm = qem_core.build_mesh(spot, {"preserve_volume": True})
    vertices, faces = pm.lod(60)
    assert abs(reference.enclosed_volume(vertices, faces) - before) <= 1e-6 * abs(before)


# -- bad input -------------------------------------------------------------------------
def test_exact_mode_with_attributes_is_refused(spot):
    with pytest.raises(qem_core.InvalidOptionsError, match="additive"):
        qem_core.build_mesh(spot, {"error_mode": "exact"})


def test_nan_uvs_are_refused(spot):
    uvs = spot.corner_uvs.copy()
    uvs[5, 1, 0] = np.nan
    bad = qem_core.Mesh(vertices=spot.vertices, faces=spot.faces, corner_uvs=uvs)
    with pytest.raises(qem_core.InvalidMeshError, match="NaN"):
        qem_core.build_mesh(bad)


def test_uvs_past_float32_once_weighted_are_refused(spot):
    """Regression: finite float32 UVs near its largest value, weighted, were stored as
    inf, and the .qpm written could not be read back."""
    uvs = (spot.corner_uvs * np.float32(3e38)).astype(np.float32)
    bad = qem_core.Mesh(vertices=spot.vertices, faces=spot.faces, corner_uvs=uvs)
    with pytest.raises(qem_core.InvalidMeshError, match="float32"):
        qem_core.build_mesh(bad)


@pytest.mark.parametrize("value", [-1.0, float("nan"), "heavy"])
def test_bad_attribute_weights_are_refused(value):
    with pytest.raises(qem_core.InvalidOptionsError):
        BuildOptions(uv_weight=value)


# -- property: random small meshes with random corner UVs ------------------------------
@settings(max_examples=25)
@given(seed=st.integers(0, 10_000), n_seams=st.integers(0, 6))
def test_random_uv_meshes_refine_consistently(seed, n_seams):
    rng = np.random.default_rng(seed)
    # An octahedron subdivided once, with UVs from a projection and some corners
    # given their own UV (a seam).
    sphere_vertices = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1],
                                [0, 0, -1]], float)
    sphere_faces = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5],
                             [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    vertices = sphere_vertices + rng.normal(scale=0.05, size=sphere_vertices.shape)
    uv = (vertices[:, :2] + 1.5) / 3.0
    corner_uvs = uv[sphere_faces].astype(np.float32)
    for _ in range(n_seams):
        f, k = rng.integers(0, sphere_faces.shape[0]), rng.integers(0, 3)
        corner_uvs[f, k] += rng.uniform(-0.05, 0.05, 2).astype(np.float32)
    mesh = qem_core.Mesh(vertices=vertices, faces=sphere_faces, corner_uvs=corner_uvs)
    pm = qem_core.build_mesh(mesh, {"preserve_volume": bool(seed % 2)})
    for n in range(pm.n_base, pm.n_full + 1):
        level = pm.lod_mesh(n)
        assert level.vertices.shape[0] == n
        assert level.corner_uvs.shape == (level.faces.shape[0], 3, 2)
        assert np.isfinite(level.corner_uvs).all()
    full = pm.lod_mesh(pm.n_full)
    got = np.sort(np.concatenate([full.vertices[full.faces].reshape(-1, 3),
                                  full.corner_uvs.reshape(-1, 2)], axis=1), axis=0)
    want = np.sort(np.concatenate([vertices[sphere_faces].reshape(-1, 3),
                                   corner_uvs.reshape(-1, 2)], axis=1), axis=0)
    np.testing.assert_allclose(got, want, atol=1e-6)

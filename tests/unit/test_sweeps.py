"""The sweep order (qem_core/_kernels/sweeps.py): the refinement reordered within windows
so that the split vertices ascend, the levels at the windows' ends those of the greedy
run, and the stream's split vertices a few bits each."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import qem_core
from qem_core import simplify
from qem_core._kernels import sweeps
from qem_core._kernels.stream_coding import FIELD_SPLIT_BACK
from qem_core.stream import new_contexts, range_code_fields, split_frame_symbols
from tests.tiny_meshes import icosphere
from tests.unit.conftest import SPOT


def _greedy(monkeypatch, build):
    """``build()`` with the contractions left in the greedy run's order."""
    with monkeypatch.context() as patch:
        patch.setattr(simplify, "_in_sweep_order", lambda run: run)
        return build()


def _faces_by_position(pm, n) -> np.ndarray:
    """The faces of lod(n) as rows of their corners' positions, each face rotated to
    start at its smallest corner and the rows sorted: level ids set aside."""
    vertices, faces = pm.lod(n)
    corners = vertices[faces]  # (F, 3, 3)
    keys = [tuple(map(tuple, face)) for face in corners]
    rows = []
    for face in keys:
        first = face.index(min(face))
        rows.append(sum(face[first:] + face[:first], ()))
    return np.array(sorted(rows))


def test_levels_at_the_window_ends_are_the_greedy_runs(monkeypatch):
    mesh = qem_core.load_mesh(SPOT)
    # The tangent lattice places each vertex by the order it splits in: left out here.
    swept = qem_core.build_mesh(mesh, {"tangent_lattice": False})
    greedy = _greedy(monkeypatch, lambda: qem_core.build_mesh(mesh, {"tangent_lattice": False}))
    assert swept.n_base == greedy.n_base and swept.n_full == greedy.n_full
    ends = sweeps.window_ends(swept.n_base, swept.n_full - swept.n_base)
    assert ends[-1] == swept.n_full and len(ends) > 10
    for n in ends[:: max(1, len(ends) // 12)] + [ends[-1]]:
        assert np.array_equal(_faces_by_position(swept, n), _faces_by_position(greedy, n)), n
    # Inside a window the level is another (a different subset of the window's splits).
    middle = (ends[-3] + ends[-2]) // 2
    assert not np.array_equal(_faces_by_position(swept, middle), _faces_by_position(greedy, middle))


def test_split_vertices_ascend_and_cost_a_few_bits(monkeypatch, spot_pm):
    ascending = np.mean(np.diff(spot_pm.split_vertex.astype(np.int64)) > 0)
    assert ascending > 0.9

    def split_vertex_bytes(pm) -> int:
        probs = new_contexts()
        return sum(
            len(range_code_fields(symbols, FIELD_SPLIT_BACK, probs))
            for symbols in split_frame_symbols(pm, pm.n_base, pm.n_full)
        )

    greedy = _greedy(monkeypatch, lambda: qem_core.build_mesh(qem_core.load_mesh(SPOT)))
    assert np.mean(np.diff(greedy.split_vertex.astype(np.int64)) > 0) < 0.7
    # The same coder on the greedy order (an index's worth a split) and on the sweeps.
    assert split_vertex_bytes(spot_pm) < 0.7 * split_vertex_bytes(greedy)


@settings(max_examples=15, derandomize=True, deadline=None)
@given(
    seed=st.integers(0, 2**31 - 1),
    jitter=st.floats(0.0, 0.2),
    error_mode=st.sampled_from(["additive", "exact"]),
)
def test_every_window_end_matches_on_random_spheres(seed, jitter, error_mode):
    vertices, faces = icosphere(2, jitter=jitter, seed=seed)
    options = {"error_mode": error_mode, "tangent_lattice": False}
    swept = qem_core.build(vertices, faces, options)
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(simplify, "_in_sweep_order", lambda run: run)
        greedy = qem_core.build(vertices, faces, options)
    for n in sweeps.window_ends(swept.n_base, swept.n_full - swept.n_base):
        assert np.array_equal(_faces_by_position(swept, n), _faces_by_position(greedy, n))
    # Every level in between is a mesh of exactly n vertices, each of them used.
    for n in range(swept.n_base, swept.n_full + 1):
        level_vertices, level_faces = swept.lod(n)
        assert np.array_equal(np.unique(level_faces), np.arange(n))


def test_window_ends_follow_the_kernels_rule():
    assert sweeps.window_ends(10, 0) == []
    ends = sweeps.window_ends(100, 1000)
    assert ends[0] == 100 + sweeps.MIN_WINDOW  # 100 // 16 < 16
    assert ends[-1] == 1100
    steps = np.diff([100, *ends])
    levels = np.array([100, *ends[:-1]])
    assert np.all(steps[:-1] == np.maximum(sweeps.MIN_WINDOW, levels[:-1] // sweeps.WINDOW_SHARE))

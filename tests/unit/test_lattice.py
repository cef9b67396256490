"""The tangent lattice (qem_core/lattice.py): inner vertices moved along the surface so
that the split stream codes their place in a few bits; the full level never moves."""

from pathlib import Path

import msgpack
import numpy as np
import pytest

import qem_core
from qem_core._kernels.stream_coding import lattice_step
from qem_core.stream import (
    SplitStreamDecoder,
    encode_split_frames,
    grid_for,
    iter_frames,
    range_code_fields,
    split_frame_symbols,
)
from tests.tiny_meshes import icosphere, perforated_icosphere
from tests.unit.test_stream import _first_frame, _sealed

SHARED = Path(__file__).resolve().parents[3] / "shared" / "meshes"
ON_LATTICE = 7  # stream_coding._ON_LATTICE: the decision's column of the position symbols


def _both(vertices, faces, **options):
    return (
        qem_core.build(vertices, faces, options={**options, "tangent_lattice": True}),
        qem_core.build(vertices, faces, options={**options, "tangent_lattice": False}),
    )


def _stream_bytes(pm):
    return sum(map(len, encode_split_frames(pm, pm.n_base, pm.n_full)))


def _lattice_decisions(pm):
    frames = split_frame_symbols(pm, pm.n_base, pm.n_full)
    return np.concatenate([symbols.positions[:, ON_LATTICE] for symbols in frames])


@pytest.fixture(scope="module")
def sphere_pair():
    return _both(*icosphere(4, jitter=0.01, seed=3))


def test_the_full_level_and_the_connectivity_do_not_move(sphere_pair):
    on, off = sphere_pair
    for n in (on.n_full, (on.n_base + on.n_full) // 2, on.n_base):
        assert np.array_equal(on.lod(n)[1], off.lod(n)[1])
    assert np.array_equal(on.lod(on.n_full)[0], off.lod(off.n_full)[0])
    assert np.array_equal(on.split_vertex, off.split_vertex)
    moved = (on.split_positions != off.split_positions).any(axis=2)
    assert moved.any(), "no inner vertex moved"


def test_the_grid_stays_and_the_moved_vertices_lie_on_it(sphere_pair):
    on, off = sphere_pair
    grid = grid_for(on)
    assert np.array_equal(grid.origin, grid_for(off).origin)
    assert np.array_equal(grid.step, grid_for(off).step)
    moved = (on.split_positions != off.split_positions).any(axis=2)
    points = on.split_positions[moved]
    assert np.array_equal(grid.dequantise(grid.quantise(points)), points)


def test_most_splits_are_coded_on_the_lattice_and_the_stream_is_smaller(sphere_pair):
    on, off = sphere_pair
    decisions = _lattice_decisions(on)
    coded = decisions[decisions >= 0]
    assert coded.size > 0.5 * on.n_splits
    assert (coded == 1).mean() > 0.8
    # Without the lattice the build's optima are rarely on it: the decision says so.
    assert (_lattice_decisions(off) == 1).mean() < 0.1
    assert _stream_bytes(on) < 0.95 * _stream_bytes(off)


def test_the_levels_stay_near_the_surface(sphere_pair):
    """A sphere's levels: vertices moved along the surface stay about as near it."""
    on, off = sphere_pair
    for n in ((on.n_base + on.n_full) // 2, on.n_base + (on.n_full - on.n_base) // 8):
        off_surface = [np.abs(np.linalg.norm(pm.lod(n)[0], axis=1) - 1).mean() for pm in (on, off)]
        assert off_surface[0] <= 1.2 * off_surface[1] + 1e-4


def test_a_stream_of_another_grid_codes_the_same_mesh_exactly(sphere_pair):
    """The lattice is laid on the 16-bit grid; a 12-bit stream's mids are coded exactly
    where they are not on its lattice, and still decode to the levels."""
    on, _ = sphere_pair
    grid = grid_for(on, 12)
    vertices, faces = on.lod(on.n_base)
    decoder = SplitStreamDecoder(grid.quantise(vertices), faces, None, grid)
    for payload in iter_frames(encode_split_frames(on, on.n_base, on.n_full, 12)):
        decoder.feed(payload)
    assert np.array_equal(decoder.quantised, grid.quantise(on.lod(on.n_full)[0]))


def test_a_border_vertex_stays():
    """A vertex on a hole's border (its fan is open) is not moved: the leaves' planes do
    not hold the border, so a move along it could erode it."""
    on, off = _both(*perforated_icosphere(3, holes=4, seed=5))
    moved_inside = 0
    for i in range(min(on.n_splits, 300)):
        n = on.n_base + i
        s = int(on.split_vertex[i])
        _, faces = off.lod(n)
        position_on, position_off = on.lod(n)[0][s], off.lod(n)[0][s]
        if _on_border(faces, s):
            assert np.array_equal(position_on, position_off), f"split {i}"
        else:
            moved_inside += not np.array_equal(position_on, position_off)
    assert moved_inside > 0


def _on_border(faces, v):
    """Whether some edge at v has only one face."""
    edges = {}
    for face in faces[(faces == v).any(axis=1)]:
        for a, b in ((face[0], face[1]), (face[1], face[2]), (face[2], face[0])):
            if v in (a, b):
                key = (min(a, b), max(a, b))
                edges[key] = edges.get(key, 0) + 1
    return any(count == 1 for count in edges.values())


def test_the_step_is_a_sixteenth_of_the_edge_or_none():
    assert lattice_step(np.array([15, -3, 0])) == 1  # a short edge: no lattice
    assert lattice_step(np.array([16, 0, 0])) == 2
    assert lattice_step(np.array([0, -1000, 40])) == 64
    assert lattice_step(np.array([1 << 20, 0, 0])) == 1 << 17


@pytest.mark.skipif(not (SHARED / "bunny.ply").exists(), reason="needs ../shared/meshes/bunny.ply")
def test_bunny_stream_is_a_tenth_smaller():
    mesh = qem_core.load_mesh(SHARED / "bunny.ply")
    on = qem_core.build_mesh(mesh)
    off = qem_core.build_mesh(mesh, {"tangent_lattice": False})
    assert _stream_bytes(on) < 0.9 * _stream_bytes(off)


def _lattice_frame(pm, n2, column, value):
    """The first frame of pm's stream to n2 with one split on the lattice given
    ``value`` as its mid value in ``column`` (4: the first, 6: the third), well coded
    and sealed."""
    (symbols,) = split_frame_symbols(pm, pm.n_base, n2)
    on = np.flatnonzero(symbols.positions[:, ON_LATTICE] == 1)
    assert on.size, "no split on the lattice to craft"
    symbols.positions[on[-1], column] = value
    body = msgpack.unpackb(_first_frame(pm, n2)[:-4])
    return _sealed(msgpack.packb({**body, "splits": range_code_fields(symbols)}))


@pytest.mark.parametrize("column", [4, 6])
@pytest.mark.parametrize("value", [8 * 65536 + 1, -(1 << 33) + 2])
def test_a_lattice_value_past_the_grid_is_refused(sphere_pair, column, value):
    """A value in lattice steps larger than 8 grid lengths is refused before it is
    multiplied (its product could pass 2^53, where the JavaScript decoder's floats
    would round)."""
    on, _ = sphere_pair
    n2 = on.n_base + 400
    vertices, faces = on.lod(on.n_base)
    grid = grid_for(on)
    decoder = SplitStreamDecoder(grid.quantise(vertices), faces, None, grid)
    with pytest.raises(qem_core.CorruptFileError, match="a position leaves the grid"):
        decoder.feed(_lattice_frame(on, n2, column, value))
    # Refused, the frame changed nothing: the true one still applies.
    decoder.feed(next(iter_frames(encode_split_frames(on, on.n_base, n2))))
    assert np.array_equal(decoder.faces, on.lod(n2)[1])
    assert np.array_equal(decoder.quantised, grid.quantise(on.lod(n2)[0]))

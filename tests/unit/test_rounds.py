"""Parallel rounds (qem_core/rounds.py): the merged record, and builds that run in rounds.

Rounds start above `rounds.PARALLEL_MIN_VERTICES` live vertices (65536); these tests lower
it so small meshes run several rounds (the shared igea and face_rangemap meshes run them
at the real threshold in test_shared_meshes.py).
"""

import os
import threading
import time
from types import SimpleNamespace

import numba
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

import qem_core
from qem_core import rounds, simplify
from qem_core._kernels.adjacency import make_face_lists
from qem_core._kernels.contract import update_vertex_edges
from qem_core._kernels.heap import PARKED, cost_key, make_heap
from qem_core._kernels.link import PART_FROZEN, make_neighbourhood
from qem_core._kernels.partition import (
    faces_by_lowest_corner,
    order_by_code,
    part_edges,
    renumber_ids,
)
from qem_core._kernels.quadrics import QUADRIC_SIZE
from qem_core._kernels.runs import merge_by_running_max
from qem_core.prepare import unique_edges
from qem_core.progressive import ProgressiveMesh
from qem_core.record import append_merged, make_record
from tests import reference
from tests.tiny_meshes import icosphere, perforated_icosphere

ARRAY_FIELDS = ("base_vertices", "split_vertex", "split_positions", "face_corners",
                "level_faces", "relabel_offsets", "relabel_faces", "split_cost")


@pytest.fixture
def small_rounds(monkeypatch):
    """Rounds down to 200 live vertices, in parts of about 256 (so the first rounds of
    these meshes, some thousand vertices, have many parts, more than the cores); returns
    a list of (round contractions) calls."""
    monkeypatch.setattr(rounds, "PARALLEL_MIN_VERTICES", 200)
    monkeypatch.setattr(rounds, "PART_VERTICES", 256)
    calls = []
    contract = rounds.contract_in_rounds

    def counting(*args, **kwargs):
        record, done = contract(*args, **kwargs)
        calls.append(done)
        return record, done

    monkeypatch.setattr("qem_core.simplify.contract_in_rounds", counting)
    return calls


def same_levels(first: ProgressiveMesh, second: ProgressiveMesh) -> bool:
    return all(np.array_equal(getattr(first, name), getattr(second, name))
               for name in ARRAY_FIELDS)


def part_record(costs, faces_killed, relabelled):
    """A record of len(costs) contractions, (j, 100 + j) -> j at cost costs[j], with the
    given runs of killed and relabelled faces; room for 16."""
    record = make_record(16, 64)
    for j, cost in enumerate(costs):
        record.a[j], record.b[j] = j, 100 + j
        record.position_a[j] = j
        record.cost[j] = cost
    killed = [f for run in faces_killed for f in run]
    relabel = [f for run in relabelled for f in run]
    record.killed[: len(killed)] = killed
    record.killed_end[: len(costs)] = np.cumsum([len(run) for run in faces_killed])
    record.relabel[: len(relabel)] = relabel
    record.relabel_end[: len(costs)] = np.cumsum([len(run) for run in relabelled])
    record.counts[:3] = len(costs), len(killed), len(relabel)
    return record


def runs(values, ends, count):
    starts = np.concatenate([[0], ends[: count - 1]])
    return [values[s:e].tolist() for s, e in zip(starts, ends[:count], strict=True)]


def test_merge_keeps_each_parts_order_and_takes_the_cheaper_first():
    first = part_record([1.0, 3.0, 2.0], [[1, 2], [3], [4, 5]], [[10], [], [11, 12]])
    second = part_record([2.0, 2.5], [[6], [7, 8]], [[13, 14], [15]])
    second.a[:2] = [50, 51]
    merged = append_merged(part_record([0.5], [[0]], [[9]]), [first, second])
    # Running maxima: first 1, 3, 3 and second 2, 2.5; ties go to the lower part.
    assert merged.counts.tolist()[:3] == [6, 9, 7]
    assert merged.a[:6].tolist() == [0, 0, 50, 51, 1, 2]
    assert merged.cost[:6].tolist() == [0.5, 1.0, 2.0, 2.5, 3.0, 2.0]
    assert runs(merged.killed, merged.killed_end, 6) == [[0], [1, 2], [6], [7, 8], [3], [4, 5]]
    assert runs(merged.relabel, merged.relabel_end, 6) == [
        [9], [10], [13, 14], [15], [], [11, 12]]


def test_merge_grows_the_relabel_array():
    record = part_record([], [], [])
    record = record._replace(relabel=np.full(2, -1, np.int32))
    part = part_record([1.0], [[1]], [[2, 3, 4, 5]])
    merged = append_merged(record, [part, part_record([], [], [])])
    assert runs(merged.relabel, merged.relabel_end, 1) == [[2, 3, 4, 5]]


COSTS = st.one_of(st.sampled_from([0.0, -0.0, 1.0, 2.0, np.inf, np.nan]),
                  st.floats(0.0, 4.0, allow_nan=False))


@given(st.lists(st.lists(COSTS, max_size=12), min_size=1, max_size=12))
def test_merge_order_is_a_stable_sort_of_the_running_maxima(parts):
    """The one-pass merge against the sort it replaces: the running maxima (NaN stays),
    sorted by (value, part, row), NaN last."""
    counts = [len(costs) for costs in parts]
    costs = np.array([c for costs in parts for c in costs], float)
    running = np.concatenate([np.maximum.accumulate(np.array(c, float)) for c in parts if c]
                             or [np.zeros(0)])
    part_of = np.repeat(np.arange(len(parts)), counts)
    expected = np.lexsort((np.arange(costs.size), part_of, running))
    order = np.empty(costs.size, np.int64)
    merge_by_running_max(costs, np.cumsum(counts), order)
    np.testing.assert_array_equal(order, expected)


@given(st.lists(st.booleans(), min_size=3, max_size=80), st.integers(2, 9),
       st.sampled_from([0.0, 0.5]))
def test_cut_labels_runs_of_the_live_vertices_and_freezes_the_band(alive, n_parts, shift):
    """Parts are n_parts runs of equal size of the live vertices in index order, moved on
    by ``shift`` of a run (the last wraps round); the corners of a live face across two
    parts are frozen, and so are the dead vertices; the counts are of what is left."""
    n = len(alive)
    alive = np.array(alive, np.uint8)
    live = np.flatnonzero(alive)
    faces = np.array([[i, (i + 1) % n, (i + 2) % n] for i in range(n)], np.int32)
    face_alive = alive[faces].all(axis=1).astype(np.uint8)
    cx = SimpleNamespace(vertex_alive=alive, faces=faces, face_alive=face_alive)
    part = np.zeros(n, np.uint8)
    vertices_in_part, faces_in_part = rounds._cut(cx, part, n_parts, shift)

    labels = np.full(n, PART_FROZEN, np.int64)
    offset = int(shift * live.size) // n_parts
    labels[live] = (np.arange(live.size) + offset) * n_parts // live.size % n_parts
    if live.size >= n_parts:
        sizes = np.bincount(labels[live], minlength=n_parts)
        assert sizes.max() - sizes.min() <= 1  # runs of equal size
    expected = labels.copy()
    within = np.zeros(n_parts, np.int64)
    for f in np.flatnonzero(face_alive):
        corner_labels = set(labels[faces[f]].tolist())
        if len(corner_labels) > 1:
            expected[faces[f]] = PART_FROZEN
        else:
            within[corner_labels.pop()] += 1
    np.testing.assert_array_equal(part, expected)
    np.testing.assert_array_equal(vertices_in_part[:n_parts],
                                  np.bincount(expected, minlength=256)[:n_parts])
    np.testing.assert_array_equal(faces_in_part[:n_parts], within)


@given(st.permutations(range(12)), st.lists(st.integers(-1, 11), max_size=40))
def test_renumber_ids_maps_each_id_and_keeps_none(order, ids):
    order = np.array(order, np.int64)
    ids = np.array(ids, np.int32)
    expected = np.where(ids >= 0, order[np.maximum(ids, 0)], -1)
    renumber_ids(order, ids)
    np.testing.assert_array_equal(ids, expected)


@given(st.lists(st.integers(0, (1 << 30) - 1) | st.integers(0, 7), max_size=300))
def test_order_by_code_is_a_stable_argsort(codes):
    """The z-order's radix sort against numpy's stable argsort: codes of up to 30 bits,
    with many ties (small codes drawn often)."""
    codes = np.array(codes, np.uint64)
    assert order_by_code(codes, 30).tolist() == np.argsort(codes, kind="stable").tolist()


@given(st.integers(3, 12).flatmap(lambda n: st.tuples(
    st.permutations(range(n)),
    st.lists(st.permutations(range(n)).map(lambda p: p[:3]), max_size=40))),
    st.integers(1, 5))
def test_faces_by_lowest_corner_is_a_stable_sort_whatever_the_chunks(drawn, n_chunks):
    """The z-order's face sort against numpy's stable argsort of the lowest new corner."""
    rank, face_list = drawn
    rank = np.array(rank, np.int32)
    faces = np.array(face_list, np.int32).reshape(-1, 3)
    face_order = np.empty(faces.shape[0], np.int64)
    renumbered = np.empty(faces.shape, np.int32)
    faces_by_lowest_corner(faces, rank, face_order, renumbered, n_chunks)
    expected = np.argsort(rank[faces].min(axis=1) if faces.size else faces[:, 0], kind="stable")
    assert face_order.tolist() == expected.tolist()
    assert renumbered.tolist() == rank[faces[expected]].tolist()


def test_a_closed_mesh_keeps_its_topology_through_the_rounds(small_rounds):
    vertices, faces = icosphere(4, jitter=0.05, seed=3)
    pm = qem_core.build(vertices, faces)
    assert small_rounds and small_rounds[0] > 0.8 * (len(vertices) - 200)
    assert pm.n_base == 4
    chi = reference.fast_euler_characteristic(faces)
    for n in np.unique(np.geomspace(4, pm.n_full, 12).astype(int)):
        level_vertices, level_faces = pm.lod(int(n))
        assert level_vertices.shape[0] == n
        assert np.unique(level_faces).size == n
        assert reference.fast_is_closed_manifold(level_faces), n
        assert reference.fast_euler_characteristic(level_faces) == chi, n


def test_an_open_mesh_keeps_its_borders_through_the_rounds(small_rounds):
    vertices, faces = perforated_icosphere(4, holes=12, seed=5)
    pm = qem_core.build(vertices, faces)
    assert small_rounds and small_rounds[0] > 0
    loops = reference.fast_boundary_loops(faces)
    for n in np.unique(np.geomspace(pm.n_base, pm.n_full, 10).astype(int)):
        _, level_faces = pm.lod(int(n))
        assert reference.fast_boundary_loops(level_faces) == loops, n


def test_a_round_of_as_many_parts_as_labels_allows(small_rounds, monkeypatch):
    """Parts of one vertex: the first round has MAX_PARTS parts, most of them all band
    (no edge, an empty heap); the build still contracts to a closed tetrahedron."""
    monkeypatch.setattr(rounds, "PART_VERTICES", 1)
    parts_per_round = []
    start_round = rounds._start_round

    def counting(*args, **kwargs):
        loops = start_round(*args, **kwargs)
        parts_per_round.append(None if loops is None else len(loops))
        return loops

    monkeypatch.setattr(rounds, "_start_round", counting)
    vertices, faces = icosphere(4, jitter=0.05, seed=6)
    pm = qem_core.build(vertices, faces)
    assert parts_per_round[0] == rounds.MAX_PARTS
    assert small_rounds and small_rounds[0] > 0
    assert pm.n_base == 4
    for n in np.unique(np.geomspace(4, pm.n_full, 8).astype(int)):
        _, level_faces = pm.lod(int(n))
        assert reference.fast_is_closed_manifold(level_faces), n


def test_the_levels_do_not_depend_on_the_number_of_cores(small_rounds, monkeypatch):
    vertices, faces = icosphere(4, jitter=0.1, seed=1)
    on_two = qem_core.build(vertices, faces, {"error_mode": "exact"})
    monkeypatch.setattr(rounds.os, "cpu_count", lambda: 1)
    threads = numba.get_num_threads()
    numba.set_num_threads(1)  # the parallel kernels too (their chunks: adjacency.sort_chunks)
    try:
        on_one = qem_core.build(vertices, faces, {"error_mode": "exact"})
    finally:
        numba.set_num_threads(threads)
    assert same_levels(on_two, on_one)
    assert len(small_rounds) == 2


@pytest.mark.parametrize("mesh, error_mode", [
    (icosphere(4, jitter=0.1, seed=3), "additive"),
    (perforated_icosphere(4, jitter=0.1, seed=3), "exact"),
])
def test_the_serial_loop_on_the_compacted_live_part_contracts_as_on_the_whole(
        small_rounds, monkeypatch, mesh, error_mode):
    """After the rounds the serial loop runs on the live part alone (rounds.compacted),
    renumbered in order: every tie-break keeps its order, so the levels are those of the
    loop on the whole complex, told back in its numbers (rounds.write_back)."""
    vertices, faces = mesh
    compacted_seen = []

    def checked(cx):
        live, rows = rounds.compacted(cx)
        assert live.vertex_alive.all() and live.face_alive.all()
        assert rows.vertices.size == np.count_nonzero(cx.vertex_alive) < cx.vertices.shape[0]
        np.testing.assert_array_equal(rows.vertices[live.faces], cx.faces[rows.faces])
        np.testing.assert_array_equal(rows.edges[live.face_edge], cx.face_edge[rows.faces])
        compacted_seen.append(rows.vertices.size)
        return live, rows

    def whole(cx):
        # The identity: the loop runs on cx itself, and telling back moves each row onto
        # itself (move_rows with out = source is safe for the identity order).
        return cx, rounds.LiveRows(*(np.arange(size, dtype=np.int32) for size in (
            cx.vertices.shape[0], cx.faces.shape[0], int(cx.face_edge.max()) + 1)))

    monkeypatch.setattr("qem_core.simplify.compacted", checked)
    on_live_part = qem_core.build(vertices, faces, {"error_mode": error_mode})
    monkeypatch.setattr("qem_core.simplify.compacted", whole)
    on_whole = qem_core.build(vertices, faces, {"error_mode": error_mode})
    assert small_rounds and compacted_seen
    assert same_levels(on_live_part, on_whole)


@pytest.mark.parametrize("mesh, error_mode", [
    (icosphere(4, jitter=0.1, seed=5), "additive"),
    (perforated_icosphere(4, jitter=0.1, seed=5), "exact"),
])
def test_rounds_on_the_compacted_live_part_contract_as_on_the_whole(
        small_rounds, monkeypatch, mesh, error_mode):
    """Below PARALLEL_MIN_VERTICES the rounds go on on the compacted live part: the same
    cuts (the live vertices in the same order), the same tie-breaks, the same parity of
    the cut's shift (rounds.RoundsState), so the same levels as rounds on the whole
    arrays all the way."""
    vertices, faces = mesh
    live_at_compaction = []
    compact = rounds.compacted

    def recorded(cx):
        live_at_compaction.append(int(np.count_nonzero(cx.vertex_alive)))
        return compact(cx)

    monkeypatch.setattr("qem_core.simplify.compacted", recorded)
    monkeypatch.setattr(rounds, "PARALLEL_MIN_VERTICES", 2000)
    monkeypatch.setattr("qem_core.simplify.COMPACTED_ROUNDS_MIN_VERTICES", 200)
    progress = []
    compacted_first = qem_core.build(vertices, faces, {"error_mode": error_mode},
                                     progress=progress.append)
    assert np.all(np.diff(progress) >= 0) and progress[-1] == 1.0  # on across the two
    # Two calls of the rounds, each of which contracted: on the whole arrays down to
    # 2000 live vertices (one round: the next one is the first with its cut shifted), then
    # on the compacted part down to 200.
    assert len(small_rounds) == 2 and min(small_rounds) > 0
    assert 200 < live_at_compaction[0] <= 2000
    monkeypatch.setattr(rounds, "PARALLEL_MIN_VERTICES", 200)
    on_whole = qem_core.build(vertices, faces, {"error_mode": error_mode})
    assert len(small_rounds) == 3 and live_at_compaction[1] < live_at_compaction[0]
    assert same_levels(compacted_first, on_whole)


@pytest.mark.parametrize("error_mode", ["additive", "exact"])
def test_compacting_keeps_the_live_rows_in_order_and_may_find_none(error_mode):
    """`rounds.compacted` of a complex with some rows dead takes the live ones in order
    (their faces and edge ids renumbered); with every row dead, empty arrays of the
    same widths."""
    from qem_core.options import BuildOptions
    from qem_core.simplify import _initial_complex

    vertices, faces = icosphere(1)
    options = BuildOptions(error_mode=error_mode)
    cx, _ = _initial_complex(np.asarray(vertices, np.float64), np.asarray(faces, np.int32),
                             options, unique_edges(faces, len(vertices)), None, owned=False)
    dead_vertex = 5
    cx.face_alive[np.any(cx.faces == dead_vertex, axis=1)] = 0
    cx.vertex_alive[dead_vertex] = 0
    live, rows = rounds.compacted(cx)
    assert rows.vertices.tolist() == [v for v in range(len(vertices)) if v != dead_vertex]
    assert rows.faces.tolist() == np.flatnonzero(cx.face_alive).tolist()
    np.testing.assert_array_equal(rows.vertices[live.faces], cx.faces[rows.faces])
    np.testing.assert_array_equal(live.vertex_quadrics, cx.vertex_quadrics[rows.vertices])
    if error_mode == "exact":
        np.testing.assert_array_equal(live.face_quadrics, cx.face_quadrics[rows.faces])
        np.testing.assert_array_equal(live.edge_quadrics, cx.edge_quadrics[rows.edges])
    else:  # the additive mode keeps neither
        assert live.face_quadrics.shape[0] == live.edge_quadrics.shape[0] == 0
    assert sorted(set(live.face_edge.ravel().tolist())) == list(range(rows.edges.size))

    cx.face_alive[:] = 0
    cx.vertex_alive[:] = 0
    empty, none = rounds.compacted(cx)
    assert none.vertices.size == none.faces.size == none.edges.size == 0
    for name in ("vertices", "vertex_quadrics", "faces", "face_normals", "face_edge",
                 "face_quadrics", "edge_quadrics"):
        assert getattr(empty, name).shape == (0,) + getattr(cx, name).shape[1:], name


def test_vertex_map_names_the_input_vertices_in_rounds(small_rounds):
    """Rounds contract the mesh in z-order; the levels still name the input's vertices."""
    vertices, faces = icosphere(4, jitter=0.05, seed=7)
    pm = qem_core.build(vertices, faces)
    assert small_rounds
    full_vertices, full_faces = pm.lod(pm.n_full)
    np.testing.assert_array_equal(full_vertices[pm.vertex_map], vertices)
    assert reference.canonical_faces(pm.vertex_map[faces]).tolist() == \
        reference.canonical_faces(full_faces).tolist()


def test_parallel_rounds_off_is_the_strict_greedy_run(small_rounds, monkeypatch):
    vertices, faces = icosphere(4, jitter=0.05, seed=2)
    strict = qem_core.build(vertices, faces, {"parallel_rounds": False})
    assert not small_rounds
    monkeypatch.setattr(rounds, "PARALLEL_MIN_VERTICES", 1 << 40)
    assert same_levels(strict, qem_core.build(vertices, faces))


def test_parallel_rounds_must_be_a_bool():
    with pytest.raises(qem_core.InvalidOptionsError, match="parallel_rounds"):
        qem_core.BuildOptions(parallel_rounds=1)


def test_progress_rises_through_the_rounds(small_rounds):
    vertices, faces = icosphere(4, jitter=0.05, seed=4)
    seen = []
    qem_core.build(vertices, faces, progress=seen.append)
    assert small_rounds
    assert len(seen) > 3
    assert seen == sorted(seen)
    assert seen[0] == 0.0 and seen[-1] == 1.0


def test_a_progress_callback_that_raises_stops_the_rounds(small_rounds, monkeypatch):
    """A cancelled build (the callback raises, as a deleted job's does) stops the loops of
    the round it is in after the chunk they are in, and the error reaches the caller; the
    next build is whole."""
    vertices, faces = icosphere(4, jitter=0.05, seed=4)
    expected = qem_core.build(vertices, faces)
    rounds_before = len(small_rounds)

    class Cancelled(Exception):
        pass

    cancelled = threading.Event()
    chunks = []

    def cancel_in_a_round(fraction):
        # Once a loop is in its first chunk: whether the other has started by then is
        # up to the threads.
        if 0.0 < fraction < 0.95 and chunks:
            cancelled.set()
            raise Cancelled

    run = rounds._PartLoop.run

    def run_after_the_cancel(self, max_steps):
        # Each loop's first chunk goes on once the cancel is raised (and has had time to
        # reach the driver's stop), so a loop that ignored the stop would run more.
        chunks.append(max_steps)
        cancelled.wait(timeout=10)  # a bound, not a hang, if no cancel ever comes
        time.sleep(0.05)
        return run(self, max_steps)

    monkeypatch.setattr(rounds, "REPORT_INTERVAL_S", 0.0)
    monkeypatch.setattr(rounds._PartLoop, "run", run_after_the_cancel)
    with pytest.raises(Cancelled):
        qem_core.build(vertices, faces, progress=cancel_in_a_round)
    assert len(small_rounds) == rounds_before  # raised inside the rounds: none returned
    assert 1 <= len(chunks) <= (os.cpu_count() or 1)  # loops not yet started never run
    monkeypatch.setattr(rounds._PartLoop, "run", run)
    assert same_levels(expected, qem_core.build(vertices, faces))


def test_a_loop_that_fails_in_a_round_raises(small_rounds, monkeypatch):
    vertices, faces = icosphere(4, jitter=0.05, seed=4)

    def failing(self, max_steps):
        raise RuntimeError("a part's loop failed")

    monkeypatch.setattr(rounds._PartLoop, "run", failing)
    with pytest.raises(RuntimeError, match="part's loop failed"):
        qem_core.build(vertices, faces)


def test_part_edges_writes_within_each_region_and_counts_all():
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6]], np.int32)
    face_edge = unique_edges(faces, 7).face_edge
    part = np.array([0, 0, 0, 0, 1, 1, 1], np.uint8)
    alive = np.ones(3, np.uint8)

    def run(room):
        start = np.array([0, room[0]], np.int64)
        ids = np.full(sum(room), -7, np.int64)
        ends = np.full((sum(room), 2), -7, np.int32)
        found = np.zeros(2, np.int64)
        part_edges(faces, alive, face_edge, part, int(face_edge.max()) + 1, start,
                   start + np.array(room), ids, ends, found)
        return ids, ends, found

    ids, ends, found = run([6, 3])  # three rows per face of each part
    assert found.tolist() == [5, 3]
    assert ends[:5].tolist() == [[0, 1], [1, 2], [2, 0], [2, 3], [3, 0]]
    assert ends[6:9].tolist() == [[4, 5], [5, 6], [6, 4]]
    ids, ends, found = run([2, 3])  # too little room for part 0: counted, not written
    assert found.tolist() == [5, 3]
    assert ends[:2].tolist() == [[0, 1], [1, 2]]
    assert ends[2:].tolist() == [[4, 5], [5, 6], [6, 4]]


def test_a_parked_edge_is_not_priced_again_in_its_round():
    """After a contraction into v, v's edges get fresh costs in the heap, but an edge
    parked above the round's stop cost stays parked, unpriced, even where its cost is
    now below that cost: it waits for the next round (contract.py)."""
    vertices, faces = icosphere(1)
    n = vertices.shape[0]
    options = qem_core.BuildOptions()
    cx, _ = simplify._initial_complex(vertices, faces, options, unique_edges(faces, n), None,
                                      owned=False)
    lists = make_face_lists(cx.faces, n, 6 * cx.faces.shape[0] + 1024, alive=cx.face_alive)
    hood = make_neighbourhood(n)
    v = 0
    v_edges = np.array(sorted(edge for key, edge in cx.edge_slot.items()
                              if v in divmod(key, n)))
    heap = make_heap(int(cx.face_edge.max()) + 1)
    parked = int(v_edges[0])
    heap.position[parked] = PARKED
    stop_key = cost_key(np.inf)  # every fresh cost is below it
    look = simplify._look(cx, simplify._make_scratch(cx, options, None))
    update_vertex_edges(cx.vertices, cx.vertex_quadrics, cx.vertex_refused, cx.edge_quadrics,
                        cx.faces, cx.face_alive, cx.face_edge, lists.start, lists.count,
                        lists.pool, hood.near, hood.generation, hood.retry, hood.part,
                        heap.entries, heap.position, heap.size, stop_key, np.int64(v),
                        np.bool_(False), False, options.rank_tolerance, np.zeros(QUADRIC_SIZE),
                        np.zeros(3), look)
    assert heap.position[parked] == PARKED
    priced = v_edges[1:]
    assert heap.size[0] == priced.size and np.all(heap.position[priced] >= 0)
    assert sorted(heap.entries[: heap.size[0], 2].tolist()) == priced.tolist()

"""Parallel rounds: most of a big build, contracted by one loop per part at once.

The greedy loop is sequential: each contraction changes the costs around it. But two
contractions far apart change nothing of each other, and a big mesh is mostly far apart.
A round cuts the live complex into parts, freezes the band of vertices that have a
neighbour in another part, and runs one loop per part (`contract.run_contractions`,
which releases the GIL) in threads, on the same complex: a loop only contracts edges
whose two ends are in its part and not frozen, so every vertex, face, edge and list it
reads or writes belongs to its part, and the loops share nothing that changes. Each loop
has its own heap, face-list pool region, generation counter and record.

The parts are runs of about ``PART_VERTICES`` live vertices in index order, which is
z-order (the build runs on the mesh renumbered by `spatial_order`), so a part is a
compact piece of the surface and lies in a few runs of every array. That is what the
size is for: a contraction reads a dozen random rows of its neighbourhood and walks its
heap, and a part's rows and heap mostly stay in the core's cache while its loop runs,
where a half of the mesh (two parts for two cores) did not; a core's parts run one after
another. Smaller parts would freeze more of the mesh in their bands.

Each loop stops before a candidate that costs more than the round's stop cost, the
``STOP_QUANTILE`` quantile of the costs of all the round's candidates when it starts, so
its heap keeps out the edges priced above that cost (they are parked, see heap.py): half
the rows, and no sinking of the edges re-priced above it. A parked edge is not priced
again in the round (contract.py): a contraction at one of its ends almost never brings
it back below the stop cost. A candidate whose full cost (the distance and volume terms,
priced at the top) passes the stop cost waits too. The parts' records are then merged
by cost (`record.append_merged`), so the sequence is the greedy one except for the
band's candidates below the stop cost, and the rare parked edge whose cost fell below
it, which wait for the next round. That round shifts the runs by half a part, so the
band is inside a part again. Rounds go on on the build's whole arrays while more than
``PARALLEL_MIN_VERTICES`` vertices are live, then on the live part copied out together
(`compacted`), whose rounds' set-ups scan only its rows, while more than
``COMPACTED_ROUNDS_MIN_VERTICES`` are; the serial loop does the rest, on that part too
(`RoundsState` carries the rounds from the one to the other, so the cuts are those of
rounds on the whole arrays). The build tells its record in the input's numbers
afterwards (`in_input_order`).

Deterministic: the cut, the loops and the merge depend on the mesh alone, not on the
number of threads or their timing. With one core the parts run one after the other and
give the same levels.
"""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, wait
from typing import NamedTuple

import numpy as np

from ._kernels.adjacency import FaceLists, make_face_lists, sort_chunks
from ._kernels.bounds import bounding_box
from ._kernels.contract import (
    PARAM_EXACT,
    PARAM_RANK_TOLERANCE,
    PARAM_SHARED_COMPLEX,
    PARAM_STOP_COST,
    STATUS_NEED_RELABEL_SPACE,
    STATUS_STEPS_DONE,
    Complex,
    Record,
    Scratch,
    run_contractions,
)
from ._kernels.heap import Heap, key_cost, kth_smallest_key, park_above
from ._kernels.link import PART_FROZEN, Neighbourhood, restart_generations
from ._kernels.pairs import Pairs
from ._kernels.partition import (
    faces_by_lowest_corner,
    freeze_band,
    label_runs,
    morton_codes,
    move_rows,
    order_by_code,
    part_edges,
    renumber_edges,
    renumber_ids,
    take_rows,
)
from ._kernels.setup import fill_heap
from .prepare import MeshEdges
from .record import append_merged, make_record, with_room_for

__all__ = [
    "COMPACTED_ROUNDS_MIN_VERTICES",
    "PARALLEL_MIN_VERTICES",
    "PART_VERTICES",
    "LiveRows",
    "RoundArrays",
    "RoundsState",
    "compacted",
    "contract_in_rounds",
    "in_input_order",
    "edges_by_part",
    "mesh_only",
    "spatial_order",
    "write_back",
]

# Live vertices per part of a round, about (module docstring). On dragon the rounds'
# loops took 0.72-0.86x the time with parts of this size as with two halves of the mesh;
# parts of 8192 were no faster, and their bands cost some levels up to 23 % in RMS.
PART_VERTICES = 16384
# Part labels are uint8 and PART_FROZEN is the last: at most this many parts a round.
MAX_PARTS = PART_FROZEN
# Rounds run while more vertices than this are live (and only for meshes this big), on the
# build's whole arrays. The coarse levels are the ones the bands' deferrals would cost:
# with two halves, rounds down to 16384 live vertices took 0.93-0.98x dragon's build time
# but raised the Hausdorff distance of its 2 % levels up to 1.07x the best peer's
# (docs/performance.md).
PARALLEL_MIN_VERTICES = 65536
# Then they go on, on the live part compacted (`compacted`), down to this many live
# vertices; the serial loop does the rest. A round's set-up scans every row of its
# arrays: on dragon's whole arrays the rounds from 65536 down to 32768 live vertices
# cost what they spared the serial loop (0.96x the first build, 1.04x the second); on
# the compacted part, 0.95x and 0.90x (docs/performance.md). The levels below 65536
# then wait for the bands too, within the quality aims (bench/results/quality*.md);
# down to 16384, igea's 13436-vertex level missed the Hausdorff aim (1.18x), down to
# 24576 its 674-vertex level (1.26x).
COMPACTED_ROUNDS_MIN_VERTICES = 32768
# A bound on the rounds of one build (each halves the live vertices or so; 6 on dragon).
MAX_ROUNDS = 64
# A round's stop cost: this quantile of the costs of its candidates at its start.
STOP_QUANTILE = 0.5
# Rounds end once one contracts fewer than this share of the live vertices.
MIN_ROUND_SHARE = 0.02
# How often the driver reports a round's progress while its loops run.
REPORT_INTERVAL_S = 0.1
# Room in a part's face-list pool for the runs its contractions write, per vertex of
# the part (a loop of a round may not compact its pool: see contract.PARAM_SHARED_COMPLEX).
POOL_ROOM_PER_VERTEX = 16


# Bits per axis of the Morton code of `spatial_order`.
MORTON_BITS = 10


class RoundArrays:
    """The working arrays of a build's rounds, each kept for the next round: a round's
    are no larger than the first's (the live vertices, faces and edges only shrink), and
    a fresh array's pages are faulted in on first touch, several microseconds a page on
    these machines, where a kept array's are in memory already. `empty` hands out an
    uninitialised view of the array kept under a name, made (or made larger) when it
    is too small. Without reuse (a `RoundArrays` made for one call) it is np.empty."""

    def __init__(self) -> None:
        self._kept: dict[str, np.ndarray] = {}

    def empty(self, name: str, shape: tuple[int, ...], dtype: type) -> np.ndarray:
        size = int(np.prod(shape))
        kept = self._kept.get(name)
        if kept is None or kept.size < size or kept.dtype != dtype:
            kept = self._kept[name] = np.empty(size, dtype)
        return kept[:size].reshape(shape)


def spatial_order(vertices: np.ndarray, faces: np.ndarray, mesh_edges: MeshEdges
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, MeshEdges]:
    """The mesh renumbered in z-order: (vertex_order, face_order (int32), ordered_faces,
    ordered_edges). The vertices go by the Morton code of their position (on a
    2^MORTON_BITS grid over the bounding box, ties by index), the faces by their lowest
    corner in that order; ``ordered_faces`` is ``faces[face_order]`` in the new vertex
    numbers and ``ordered_edges`` its edges, numbered in order of first appearance (not by
    their ends, as preparation numbers them: nothing after it needs that order).

    The loops of a round write rows of the same arrays at once; in input order, the
    rows of two parts share cache lines everywhere and each write evicts the line from
    the other core (false sharing: two loops ran 1.2x as fast as one). In z-order a
    part is a few long runs of rows. It also puts neighbours near each other in memory.
    """
    n = vertices.shape[0]
    low, high = bounding_box(vertices)
    extent = float((high - low).max())
    # Uninitialised where a kernel writes every element (zeros cost a memset of reused
    # memory): the codes, the faces and their order, the renumbered edges.
    codes = np.empty(n, np.uint64)
    morton_codes(vertices, low, ((1 << MORTON_BITS) - 1) / extent if extent > 0 else 0.0,
                 MORTON_BITS, codes)
    # Both orders are kept to the build's end (`in_input_order`): int32, like every index.
    vertex_order = order_by_code(codes, 3 * MORTON_BITS).astype(np.int32)
    rank = np.empty(n, np.int32)
    rank[vertex_order] = np.arange(n, dtype=np.int32)
    face_order = np.empty(faces.shape[0], np.int32)
    ordered_faces = np.empty(faces.shape, np.int32)
    faces_by_lowest_corner(faces, rank, face_order, ordered_faces, sort_chunks())
    n_edges = mesh_edges.edges.shape[0]
    ordered_edges = MeshEdges(np.empty((n_edges, 2), np.int32), np.empty(faces.shape, np.int32),
                              np.empty(n_edges, np.int32), np.empty(n_edges, np.int64))
    renumber_edges(mesh_edges.face_edge, face_order, mesh_edges.edges,
                   mesh_edges.edge_face_count, rank, ordered_edges.face_edge,
                   ordered_edges.edges, ordered_edges.edge_face_count, ordered_edges.edge_side)
    return vertex_order, face_order, ordered_faces, ordered_edges


def in_input_order(run_record: Record, cx: Complex, vertex_order: np.ndarray,
                   face_order: np.ndarray) -> tuple[Record, Complex]:
    """A record and complex of the mesh ``vertices[vertex_order]``, faces renumbered and
    taken in ``face_order``, told in the input's vertex and face numbers. Their arrays
    are rewritten in place, one at a time, so the build's peak memory grows by one array,
    not by a second complex.

    Only the mesh is told back (vertices, faces, what is alive): the loop's working state
    (vertex and face quadrics, face normals, edge ids, refusal marks) is left out, as
    empty arrays, since nothing after the loop reads it; moving it took 0.1 s of the
    dragon's build."""

    def in_place(values: np.ndarray) -> np.ndarray:
        if not values.flags.c_contiguous:  # reshape would copy, and the writes be lost
            raise ValueError("in_input_order rewrites contiguous arrays only")
        return values

    def renumber(order: np.ndarray, values: np.ndarray) -> None:
        renumber_ids(order, in_place(values).reshape(-1))

    def move(order: np.ndarray, values: np.ndarray) -> None:
        rows = in_place(values).reshape(values.shape[0], -1)
        move_rows(order, rows.copy(), rows)

    _renumber_record(run_record, vertex_order, face_order, since=np.zeros(3, np.int64))
    renumber(vertex_order, cx.faces)
    for values in (cx.vertices, cx.vertex_alive):
        move(vertex_order, values)
    for values in (cx.faces, cx.face_alive):
        move(face_order, values)
    return run_record, mesh_only(cx)


def mesh_only(cx: Complex) -> Complex:
    """``cx`` with only its mesh (vertices, faces, what is alive, wedge values): the
    loop's working state left out, as empty arrays of the same trailing shapes."""

    def left_out(values: np.ndarray) -> np.ndarray:
        return np.zeros((0,) + values.shape[1:], values.dtype)

    working = ("vertex_quadrics", "vertex_refused", "face_normals", "face_quadrics",
               "face_edge", "edge_quadrics", "face_wedges")
    return cx._replace(**{name: left_out(getattr(cx, name)) for name in working})


def _renumber_record(record: Record, vertex_ids: np.ndarray, face_ids: np.ndarray,
                     since: np.ndarray) -> None:
    """Tell the record's rows after its counts ``since`` (contractions, killed faces,
    relabelled faces) in other numbers: vertex v becomes vertex_ids[v], face f
    face_ids[f]."""
    (j0, k0, r0), (j1, k1, r1) = since[:3], record.counts[:3]
    renumber_ids(vertex_ids, record.a[j0:j1])
    renumber_ids(vertex_ids, record.b[j0:j1])
    renumber_ids(face_ids, record.killed[k0:k1])
    renumber_ids(face_ids, record.relabel[r0:r1])


def edges_by_part(cx: Complex, part: np.ndarray, faces_in_part: np.ndarray, n_edge_ids: int,
                  arrays: RoundArrays | None = None, heap_rows: np.ndarray | None = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The edges of the live faces with both ends in one part p < faces_in_part.size
    (``part`` as `Neighbourhood.part`): (ids (R,) int64, ends (R, 2) int32, run_start,
    run_end (P,) int64), part p's in rows [run_start[p], run_end[p]) (run_start[0] = 0),
    the rows between the runs unwritten.
    faces_in_part : the live faces with all corners in each part (or more): their three
    sides each are the room for its edges, so they are found in one pass, not counted
    first; R is that room. n_edge_ids: more than any edge id of ``cx``.
    ``arrays``: where ids and ends are taken from (fresh ones if None).
    ``heap_rows``: (R, 3) int64 heap entries, or None: ids and ends are then views of
    their rows instead, the ids in column 2 and the ends in column 1's two halves, where
    `fill_heap` reads each before it writes that row."""
    arrays = arrays or RoundArrays()
    room = 3 * faces_in_part.astype(np.int64)
    run_start = np.concatenate([[0], np.cumsum(room)[:-1]]).astype(np.int64)
    if heap_rows is None:
        ids = arrays.empty("edge ids", (int(room.sum()),), np.int64)
        ends = arrays.empty("edge ends", (ids.size, 2), np.int32)
    else:
        # No arrays of their own: 24 bytes an edge less at a round's peak memory.
        ids = heap_rows[:, 2]
        ends = heap_rows.view(np.int32)[:, 2:4]
        if ids.size != int(room.sum()):
            raise ValueError(f"edges_by_part: {ids.size} heap rows for room {int(room.sum())}")
    found = np.zeros(room.size, np.int64)
    part_edges(cx.faces, cx.face_alive, cx.face_edge, part, n_edge_ids, run_start,
               run_start + room, ids, ends, found)
    if np.any(found > room):
        raise RuntimeError(f"edges_by_part: {found.tolist()} edges for room {room.tolist()}")
    return ids, ends, run_start, run_start + found


class _PartLoop:
    """One part's loop in a round, and what it owns."""

    def __init__(self, cx: Complex, lists: FaceLists, pairs: Pairs, hood: Neighbourhood,
                 heap: Heap, record: Record, params: np.ndarray, scratch: Scratch):
        self.cx, self.lists, self.pairs, self.hood = cx, lists, pairs, hood
        self.heap, self.record, self.params, self.scratch = heap, record, params, scratch
        self.running = heap.size[0] > 0
        self.done = 0  # contractions so far, read by the driver's thread for progress

    def run(self, max_steps: int) -> int:
        """Up to max_steps contractions; returns how many were done."""
        status, steps = run_contractions(self.cx, self.lists, self.pairs, self.hood, self.heap,
                                         self.record, self.params, max_steps, self.scratch)
        if status == STATUS_NEED_RELABEL_SPACE:
            self.record = with_room_for(self.record, status)
        elif status != STATUS_STEPS_DONE:
            # Exhausted, past the stop cost, or out of pool (it may not compact): the
            # rest waits for the next round.
            self.running = False
        self.done += steps
        return steps

    def run_to_end(self, chunk: int, stop: threading.Event) -> None:
        """Chunks of contractions until the loop is done or ``stop`` is set; sets it
        when this loop fails, so the others stop too."""
        try:
            while self.running and not stop.is_set():
                self.run(chunk)
        except BaseException:
            stop.set()
            raise


def _run_loops(executor: ThreadPoolExecutor, loops: list[_PartLoop], chunk: int,
               report: Callable[[int], None]) -> int:
    """Run a round's loops to their ends, each in a thread of its own, reporting the
    round's contractions so far from this thread every REPORT_INTERVAL_S. Returns them.

    No loop waits for another between chunks: the parts' chunks take different times,
    and a barrier after each left a core idle for the difference. If ``report`` raises
    (a cancelled build), the loops stop after their chunk and the error goes on (a
    loop's own error, if one also failed, is then not raised)."""
    stop = threading.Event()
    futures = [executor.submit(loop.run_to_end, chunk, stop) for loop in loops if loop.running]
    try:
        running = futures
        while running:
            _, running = wait(running, timeout=REPORT_INTERVAL_S)
            report(sum(loop.done for loop in loops))
    finally:
        stop.set()
    for future in futures:
        future.result()  # a loop's error, if one failed
    return sum(loop.done for loop in loops)


def _cut(cx: Complex, part: np.ndarray, n_parts: int, shift: float
         ) -> tuple[np.ndarray, np.ndarray]:
    """Label the live vertices, in index order, into n_parts runs of equal size, the runs
    moved on by ``shift`` of a run (the last one wraps round to the first vertices), then
    freeze the band. Returns the number of vertices left in each part and of faces with
    all corners in it (by part number)."""
    label_runs(cx.vertex_alive, n_parts, shift, part)
    vertices_in_part = np.zeros(PART_FROZEN + 1, np.int64)
    faces_in_part = np.zeros(PART_FROZEN + 1, np.int64)
    freeze_band(cx.faces, cx.face_alive, part, vertices_in_part, faces_in_part)
    return vertices_in_part, faces_in_part


class RoundsState:
    """What a build's calls of `contract_in_rounds` carry from one to the next (the
    rounds on its whole arrays, then those on the compacted live part): the rounds run so
    far, whose parity shifts the cut, whether the rounds are over (one found nothing or
    too little to do), and the kept arrays."""

    def __init__(self) -> None:
        self.rounds = 0
        self.over = False
        self.arrays = RoundArrays()


def contract_in_rounds(cx: Complex, hood: Neighbourhood, pairs: Pairs, record: Record,
                       params: np.ndarray, make_scratch: Callable[[], Scratch], chunk: int,
                       report: Callable[[int], None], min_live: int,
                       state: RoundsState) -> tuple[Record, int]:
    """Contract in parallel rounds (module docstring) while more than ``min_live``
    vertices are live. Appends to ``record``; returns it (grown if it had to be) and the
    number of contractions. ``report(contractions so far)`` is called from this thread
    while the loops run (`_run_loops`). ``state``: the build's, carried from its call on
    its whole arrays to the one on the compacted live part, so the rounds go on as if in
    one call. Leaves ``hood.part`` all 0."""
    done = 0
    # A contraction never makes an edge id: the first round's bound holds for them all.
    n_edge_ids = int(cx.face_edge.max()) + 1 if cx.face_edge.size else 0
    with ThreadPoolExecutor(os.cpu_count() or 1) as executor:
        while not state.over and state.rounds < MAX_ROUNDS:
            n_live = int(np.count_nonzero(cx.vertex_alive))
            if n_live <= min_live:
                break
            restart_generations(hood)
            n_parts = min(MAX_PARTS, max(2, round(n_live / PART_VERTICES)))
            loops = _start_round(executor, cx, hood, pairs, params, make_scratch, n_parts,
                                 0.5 * (state.rounds % 2), n_edge_ids, state.arrays)
            state.rounds += 1
            if loops is None:
                state.over = True
                break
            round_done = _run_loops(executor, loops, chunk,
                                    lambda round_done, before=done: report(before + round_done))
            record = append_merged(record, [loop.record for loop in loops])
            hood.generation[0] = max(int(loop.hood.generation[0]) for loop in loops)
            del loops  # the parts' records, freed before the next round's are made
            done += round_done
            if round_done < MIN_ROUND_SHARE * n_live:
                state.over = True
    hood.part[:] = 0
    return record, done


def _start_round(executor: ThreadPoolExecutor, cx: Complex, hood: Neighbourhood, pairs: Pairs,
                 params: np.ndarray, make_scratch: Callable[[], Scratch], n_parts: int,
                 shift: float, n_edge_ids: int, arrays: RoundArrays
                 ) -> list[_PartLoop] | None:
    """Cut the complex (`_cut`) and set up one loop per part; None if no part has a
    candidate. n_edge_ids: more than any edge id of ``cx``. The pool, the edges and the
    heaps are taken from ``arrays``, the previous round's kept."""
    n = cx.vertices.shape[0]
    vertices_in_part, faces_in_part = _cut(cx, hood.part, n_parts, shift)
    # One pool: the runs of the live faces, then a region per part for the runs its
    # contractions write. Each loop is handed the pool up to the end of its region and
    # appends from the region's start; of the shared runs below, each changes only its
    # own vertices'.
    room = [POOL_ROOM_PER_VERTEX * int(vertices_in_part[p]) + 1024 for p in range(n_parts)]
    used = 3 * int(np.count_nonzero(cx.face_alive))
    capacity = used + sum(room)
    lists = make_face_lists(cx.faces, n, capacity, alive=cx.face_alive,
                            pool=arrays.empty("pool", (capacity,), np.int32))
    # The parts' heaps are runs of one array, each the room of its part's edges (a heap
    # never holds more: an edge is in it at most once, and a loop adds only edges of its
    # part), filled at once (in parallel). ``position`` is shared: the ids are disjoint.
    entries = arrays.empty("heap entries", (3 * int(faces_in_part[:n_parts].sum()), 3),
                           np.int64)  # the runs' rows written
    ids, ends, run_start, run_end = edges_by_part(cx, hood.part, faces_in_part[:n_parts],
                                                  n_edge_ids, arrays, heap_rows=entries)
    runs = [slice(start, end)
            for start, end in zip(run_start.tolist(), run_end.tolist(), strict=True)]
    n_edges = int((run_end - run_start).sum())
    if n_edges == 0:
        return None
    position = arrays.empty("heap positions", (n_edge_ids,), np.int32)
    position.fill(-1)
    fill_heap(cx.vertices, cx.vertex_quadrics, cx.edge_quadrics, ends, ids, run_start, run_end,
              params[PARAM_EXACT] != 0.0, params[PARAM_RANK_TOLERANCE], entries)
    stop_key = kth_smallest_key(entries, run_start, run_end, int(STOP_QUANTILE * (n_edges - 1)))
    heaps = [Heap(entries[run], position, np.array([run.stop - run.start], np.int64))
             for run in runs]
    # The loops stop before the candidates above the round's cost: those stay out. The
    # heaps are ordered in threads (the kernel releases the GIL; the ids are disjoint).
    list(executor.map(lambda heap: park_above(heap.entries, heap.position, heap.size, stop_key),
                      heaps))
    round_params = params.copy()
    round_params[PARAM_STOP_COST] = key_cost(stop_key)
    round_params[PARAM_SHARED_COMPLEX] = 1.0
    loops = []
    region_end = used
    for p, heap in enumerate(heaps):
        n_part = int(vertices_in_part[p])
        region_start, region_end = region_end, region_end + room[p]
        part_lists = FaceLists(lists.start, lists.count, lists.pool[:region_end],
                               np.array([region_start], np.int64))
        # retry: scratch for the neighbours of one vertex, all in the part.
        part_hood = Neighbourhood(hood.near, hood.generation.copy(),
                                  np.empty(n_part + 1, np.int32), hood.part)
        # A contraction kills faces of its part only, at most all of them.
        loops.append(_PartLoop(cx, part_lists, pairs, part_hood, heap,
                               make_record(max(n_part, 1), int(faces_in_part[p])),
                               round_params, make_scratch()))
    return loops


class LiveRows(NamedTuple):
    """Where the rows of a compacted complex (`compacted`) came from: for each, its
    vertex, face and edge id in the complex it was taken from."""

    vertices: np.ndarray  # (n_live,) int32
    faces: np.ndarray  # (m_live,) int32
    edges: np.ndarray  # (E_live,) int32


def compacted(cx: Complex) -> tuple[Complex, LiveRows]:
    """The live part of ``cx`` as a complex of its own: its live vertices, faces and
    edges, renumbered in the order they had. The last rounds and the serial loop run on
    it: its few live rows, scattered over arrays sized for the input, now lie together.
    An order-keeping renumbering changes no cut or tie-break (parts are runs of live
    vertices in order, equal costs are ordered by their ends' numbers, lists by face
    number), so the rounds and the loop make the same contractions.
    Geometric costs only (no appearance attributes: the rounds run without them)."""
    assert cx.face_wedges.shape[0] == 0, "the rounds run without appearance attributes"
    live_vertices, vertex_row = _live_rows(cx.vertex_alive)
    live_faces = np.flatnonzero(cx.face_alive).astype(np.int32)

    def take(rows: np.ndarray, values: np.ndarray) -> np.ndarray:
        if values.shape[0] == 0:  # a field the mode does not use
            return values
        out = np.empty((rows.size,) + values.shape[1:], values.dtype)
        width = int(np.prod(values.shape[1:]))
        take_rows(rows, values.reshape(values.shape[0], width), out.reshape(rows.size, width))
        return out

    faces = take(live_faces, cx.faces)
    renumber_ids(vertex_row, faces.reshape(-1))
    face_edge = take(live_faces, cx.face_edge)
    edge_used = np.zeros(int(cx.face_edge.max()) + 1 if cx.face_edge.size else 0, np.uint8)
    edge_used[face_edge] = 1
    live_edges, edge_row = _live_rows(edge_used)
    renumber_ids(edge_row, face_edge.reshape(-1))
    small = cx._replace(
        vertices=take(live_vertices, cx.vertices),
        vertex_quadrics=take(live_vertices, cx.vertex_quadrics),
        vertex_alive=cx.vertex_alive[live_vertices],
        vertex_refused=cx.vertex_refused[live_vertices],
        faces=faces,
        face_alive=cx.face_alive[live_faces],
        face_normals=take(live_faces, cx.face_normals),
        face_quadrics=take(live_faces, cx.face_quadrics),
        face_edge=face_edge,
        edge_quadrics=take(live_edges, cx.edge_quadrics),
    )
    return small, LiveRows(live_vertices, live_faces, live_edges)


def _live_rows(flags: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The rows set in ``flags`` (0/1), and each row's number among them (a row not set
    gets the previous set row's, or -1: never read, since no live face names it)."""
    return (np.flatnonzero(flags).astype(np.int32),
            np.cumsum(flags, dtype=np.int32) - 1)


def write_back(small: Complex, rows: LiveRows, cx: Complex, record: Record,
               counts_before: np.ndarray) -> None:
    """Tell what the rounds and the loop did on ``small`` (`compacted` from ``cx``) in
    cx's numbers: the mesh (positions, faces, what is alive) and the record's rows after
    ``counts_before`` (its counts at the compaction). Their working state (quadrics,
    refusal marks, edge ids) is not told back: nothing after the loop reads it
    (`in_input_order`)."""
    move_rows(rows.vertices, small.vertices, cx.vertices)
    cx.vertex_alive[rows.vertices] = small.vertex_alive
    move_rows(rows.faces, rows.vertices[small.faces], cx.faces)
    cx.face_alive[rows.faces] = small.face_alive
    _renumber_record(record, rows.vertices, rows.faces, since=counts_before)

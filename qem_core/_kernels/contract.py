"""The greedy contraction loop: pop the cheapest edge, check it, contract it, record it.

Contracting (a, b) -> c keeps the slot of a for c and retires b::

        x                 x
       / \\               / \\
      /   \\             /   \\
     a --- b    ->         c          faces abx and aby die; faces of b now use c;
      \\   /             \\   /          edges bx, by merge into ax, ay; other edges
       \\ /               \\ /           bz keep their id as cz
        y                 y

Edges have ids (the sides of the input faces, numbered once, see setup.py) and each face
side knows its edge (``face_edge``), so the heap, the exact mode's edge quadrics and the
merging of edges all work on ids, with no hashing of vertex pairs.

Error modes (Edelsbrunner, Geometry and Topology for Mesh Generation, III.12):
additive uses Q_c = Q_a + Q_b; exact keeps quadrics on edges too and uses
Q_c = Q_a + Q_b - Q_ab and Q_xc = Q_xa + Q_xb - Q_xab, so every original plane is counted
once in every vertex and edge quadric. Triangle quadrics are the face quadrics themselves.

Candidates: every live edge is in the heap with its current cost, except edges refused by
the link condition or the flip guard. Those stay out until the neighbourhood of one of
their ends changes: a refused edge marks both ends, and when a neighbour of a marked
vertex is contracted into, the vertex's missing edges go back in with fresh costs; a
vertex of more than ``RETRY_MAX_FACES`` faces is not retried so, and its refused edges come
back only when it or the edge's other end is contracted into. With
pair contraction on, the pairs (pairs.py) are candidates too, numbered after the edges;
they skip the link condition. No contraction may leave a vertex without a face. In a
parallel round (rounds.py) each loop holds only the edges within its part of the
complex and stops at the round's cost (PARAM_STOP_COST); an edge priced above that cost
is parked out of the heap (heap.update_or_park) rather than sunk to its place, and stays
parked, unpriced, until the round ends: a contraction at one of its ends almost never
brings it back below that cost (quadrics only grow; on dragon 0.07 % of 1.74 million
such prices did, through the truncated placement of nearly flat quadrics), and pricing
them took about 8 % of a build's CPU time (docs/performance.md). The next round prices
every edge afresh.

The loop runs in chunks of ``max_steps`` contractions so Python can report progress, and
stops early with a status code when an array is full (Python grows it and resumes).
Helpers take plain arrays, not the NamedTuples: a tuple argument costs reference counting
on each of its members at every call; and the loop hands them borrowed views, which cost
none (memory.py). A contraction touches a dozen random vertices of arrays far larger than
the cache, so the loop prefetches: the rows of the current neighbourhood as soon as it is
gathered, and the lists and faces of the likely next candidate while it works.
"""

from typing import NamedTuple

import numba
import numpy as np

from .adjacency import compact, corner_of, opposite
from .appearance import (
    SETTING_UV_OFFSET,
    candidate_cost,
    merge_wedges,
    new_wedge_values,
    uv_keeps_orientation,
)
from .distance import with_distance
from .guards import faces_keep_orientation, leaves_a_vertex_bare
from .heap import PARKED, cost_key, pair, remove, top, update, update_or_park
from .link import (
    NEAR_EDGE_A,
    NEAR_EDGE_B,
    NEAR_SCRATCH,
    NEAR_TAG_A,
    REFUSE_NONE,
    check_link,
    gather,
)
from .memory import borrow, borrowing_kernel, prefetch
from .pairs import merge_pairs, update_vertex_pairs
from .quadrics import QUADRIC_SIZE
from .volume import with_volume

# A refused vertex with more faces than this is not retried when a neighbour changes (see
# above): retrying a hub re-priced every one of its missing edges after each change of its
# rim, and each came to the top and was refused again at O(its faces) a pop. A flat fan of
# 50 000 triangles with its apex on the border took 129 s to build, now 0.9 s. Real meshes
# have no such vertex: the levels of all the shared meshes are byte-identical.
RETRY_MAX_FACES = 256
# Only the first this many faces of a vertex have their rows prefetched: a hub's rows
# would not stay in the cache anyway, and asking for them all made every pop of one of
# its edges cost O(its faces) in prefetches alone (a cone of 100 000 rim vertices).
PREFETCH_MAX_FACES = 64

STATUS_EXHAUSTED = 0  # nothing valid left to contract
STATUS_STEPS_DONE = 1  # max_steps contractions done, more may follow
STATUS_NEED_RELABEL_SPACE = 2
STATUS_NEED_POOL_SPACE = 3
STATUS_NEED_PAIR_POOL_SPACE = 4
STATUS_NEED_WEDGE_SPACE = 5
STATUS_STOP_COST = 6  # the cheapest candidate costs more than PARAM_STOP_COST

# Indices into the float parameter vector.
PARAM_RANK_TOLERANCE = 0
PARAM_COS_STEP_TURN = 1  # cos of the largest allowed per-contraction turn of a face normal
PARAM_EXACT = 2  # 1.0 for the exact (inclusion-exclusion) error mode
PARAM_PRESERVE_TOPOLOGY = 3
PARAM_DISTANCE_WEIGHT = 4  # weight of the one-step distance in the cost (distance.py)
# Parallel rounds (rounds.py): the loop returns STATUS_STOP_COST before a candidate that
# costs more than this (inf: never), and with PARAM_SHARED_COMPLEX != 0 another loop
# works on the same complex at the same time, so the pool is never compacted (that
# would move the other loop's lists): STATUS_NEED_POOL_SPACE instead.
PARAM_STOP_COST = 5
PARAM_SHARED_COMPLEX = 6
PARAM_VOLUME_WEIGHT = 7
N_PARAMS = 8


class Complex(NamedTuple):
    """The current simplicial complex and its quadrics."""

    vertices: np.ndarray  # (n, 3) float64, moved in place
    vertex_quadrics: np.ndarray  # (n, 10) float64
    vertex_alive: np.ndarray  # (n,) uint8
    vertex_refused: np.ndarray  # (n,) uint8: an edge of it was refused, retry on change
    faces: np.ndarray  # (m, 3) int32, corners rewritten in place
    face_alive: np.ndarray  # (m,) uint8
    face_normals: np.ndarray  # (m, 3) float64, unit normals of the original faces
    face_quadrics: np.ndarray  # (m, 10) float64 (triangle quadrics, exact mode)
    face_edge: np.ndarray  # (m, 3) int32: edge id of side k (corner k to k + 1)
    edge_quadrics: np.ndarray  # (E, 10) float64 by edge id (exact mode only; else (0, 10))
    face_wedges: np.ndarray  # (m, 3) int32 wedge of each corner (appearance.py); or (0, 3)
    wedge_quadrics: np.ndarray  # (W, 11 + 4k) float64 appearance quadrics; or (0, 11)
    wedge_values: np.ndarray  # (W, k) float64 attribute values, weighted; or (0, 0)

    @property
    def edge_slot(self) -> dict[int, int]:
        """For inspection (the kernels use ``face_edge``): the id, and so the row of
        ``edge_quadrics``, of every current edge, keyed ``low * n + high``."""
        alive = self.face_alive.astype(bool)
        corners = self.faces[alive].astype(np.int64)
        ends = np.stack([corners, np.roll(corners, -1, axis=1)], axis=2).reshape(-1, 2)
        keys = ends.min(axis=1) * self.vertices.shape[0] + ends.max(axis=1)
        return dict(zip(keys.tolist(), self.face_edge[alive].reshape(-1).tolist(), strict=True))


class Record(NamedTuple):
    """Every contraction, in order: (a, b) -> c at position, with its cost."""

    a: np.ndarray  # (n,) int32 survivor slot
    b: np.ndarray  # (n,) int32 retired slot
    position_a: np.ndarray  # (n, 3) float64, a before the contraction
    position_b: np.ndarray  # (n, 3) float64
    cost: np.ndarray  # (n,) float64
    killed_end: np.ndarray  # (n,) int64, end of this contraction's run in killed
    killed: np.ndarray  # (m,) int32 faces that died, in order
    relabel_end: np.ndarray  # (n,) int64
    relabel: np.ndarray  # (capacity,) int32 faces whose corner b became a
    wedge_log_end: np.ndarray  # (n,) int64
    wedge_log: np.ndarray  # (capacity, 2) int32 (wedge, its group's survivor)
    wedge_log_values: np.ndarray  # (capacity, k) float64, the wedge's values before
    wedge_relabel_end: np.ndarray  # (n,) int64
    wedge_relabel: np.ndarray  # (capacity, 3) int32 (face, corner, retired wedge it named)
    counts: np.ndarray  # (5,) int64: contractions, killed, relabel, wedge log, wedge relabel


class Scratch(NamedTuple):
    """Work space of the appearance and volume costs (appearance.py)."""

    wedge_tag: np.ndarray  # (W,) int64
    wedge_slot: np.ndarray  # (W,) int32
    members: np.ndarray  # (C, 2) int32
    group_rows: np.ndarray  # (C, 11 + 4k) float64
    counter: np.ndarray  # (2,) int64
    settings: np.ndarray  # (4,) float64
    value_bounds: np.ndarray  # (2, k) float64
    total: np.ndarray  # (10,) float64
    group_values: np.ndarray  # (C, k) float64


def _prefetch_neighbourhood(vertices, vertex_quadrics, edge_quadrics, face_normals, faces,
                            face_edge, start, count, pool, heap_position, near, v, exact):
    """Ask for the rows a contraction at v will read (see memory.py): the neighbourhood
    rows of v's neighbours (`link.gather`, next), their positions and quadrics, normals
    of its faces, heap positions (and in exact mode quadrics) of its edges. A quadric row
    is 80 bytes: two cache lines."""
    s = start[v]
    for i in range(min(count[v], PREFETCH_MAX_FACES)):
        f = pool[s + i]
        prefetch(face_normals, f, 0)
        for k in range(3):
            x = faces[f, k]
            prefetch(near, x, 0)
            prefetch(vertices, x, 0)
            prefetch(vertex_quadrics, x, 0)
            prefetch(vertex_quadrics, x, 8 * QUADRIC_SIZE - 8)
            edge = face_edge[f, k]
            prefetch(heap_position, edge, 0)
            if exact:
                prefetch(edge_quadrics, edge, 0)
                prefetch(edge_quadrics, edge, 8 * QUADRIC_SIZE - 8)


prefetch_neighbourhood = borrowing_kernel(_prefetch_neighbourhood)


def _prefetch_opposites(faces, start, count, pool, near, heap_entries, heap_position, a, b,
                        stage):
    """Ask for what the contraction of (a, b) will read of the opposite vertex x of each
    face abx once its checks pass, in two stages, each reading what the stage before
    asked for: 0 where x's face list is, and the heap row of edge b-x (merge_edges takes
    it out of the heap); 1 the list itself (rewrite_faces takes the face abx out of it).
    Call after `link.gather` (near[x, NEAR_EDGE_B] is edge b-x)."""
    s = start[b]
    for i in range(count[b]):
        x = opposite(faces, pool[s + i], b, a)
        if x < 0:
            continue
        if stage == 0:
            prefetch(start, x, 0)
            prefetch(count, x, 0)
            row = heap_position[near[x, NEAR_EDGE_B]]
            if row >= 0:
                prefetch(heap_entries, row, 0)
        else:
            prefetch(pool, start[x], 0)


prefetch_opposites = numba.njit(cache=True, inline="always")(_prefetch_opposites)


def _prefetch_next(heap_entries, heap_size, start, count, pool, faces, face_edge, stage):
    """Start fetching the face lists and faces of the likely next candidate, the top of
    the heap, in stages spread over the current contraction, each reading what the stage
    before asked for: 0 where its lists are, 1 the lists, 2 the faces."""
    if heap_size[0] == 0:
        return
    a, b, _ = top(heap_entries)
    for v in (a, b):
        if stage == 0:
            prefetch(start, v, 0)
            prefetch(count, v, 0)
        elif stage == 1:
            prefetch(pool, start[v], 0)
            prefetch(pool, start[v] + count[v] - 1, 0)
        else:
            s = start[v]
            for i in range(min(count[v], 16)):
                prefetch(faces, pool[s + i], 0)
                prefetch(face_edge, pool[s + i], 0)


prefetch_next = numba.njit(cache=True, inline="always")(_prefetch_next)


def _update_vertex_edges(vertices, vertex_quadrics, vertex_refused, edge_quadrics, faces,
                         face_alive, face_edge, start, count, pool, near, generation, retry,
                         part, heap_entries, heap_position, heap_size, stop_key, v,
                         only_missing, exact, rank_tolerance, quadric, position, look):
    """Give every edge of v its current cost in the heap (inserting it if it was out).

    With ``only_missing``, edges already in the heap are left alone (their cost is
    current: it changes only when an end changes, and then this runs for that end).
    Edges parked above the round's stop key (`heap.update_or_park`) are always left
    alone: they wait for the next round (module docstring).
    Without it (v was just contracted into), the neighbours that had a candidate refused
    are listed in ``retry`` (and their mark cleared): v's change may have lifted the
    reason; not those of more than RETRY_MAX_FACES faces (module docstring), whose edge
    to v is priced here anyway. Edges to a vertex of another part than v's (``part``,
    rounds.py) are left out, and so are such neighbours from ``retry``: another loop may
    be changing them.
    Tags the neighbours of v (column NEAR_SCRATCH) with a new generation.
    Returns (that generation, how many neighbours were listed). quadric (10,),
    position (3,): float64 work space.
    """
    s = start[v]
    for i in range(count[v]):
        f = pool[s + i]
        # The rows these edges hold and their parents: read after the costs below.
        for k in range(3):
            row = heap_position[face_edge[f, k]]
            if row >= 0:
                prefetch(heap_entries, row, 0)
                prefetch(heap_entries, (row - 1) // 4, 0)
    generation[0] += 1
    g = generation[0]
    near[v, NEAR_SCRATCH] = g
    n_retry = 0
    for i in range(count[v]):
        f = pool[s + i]
        corner = corner_of(faces, f, v)
        # The two sides at v: v -> next corner is side ``corner``, previous -> v the other.
        for step in range(1, 3):
            x = faces[f, (corner + step) % 3]
            if near[x, NEAR_SCRATCH] == g:
                continue
            near[x, NEAR_SCRATCH] = g
            if part[x] != part[v]:
                continue
            edge = face_edge[f, corner if step == 1 else (corner + 2) % 3]
            if only_missing:
                if heap_position[edge] != -1:
                    continue  # in the heap (its cost is current), or parked
            else:
                if vertex_refused[x] and count[x] <= RETRY_MAX_FACES:
                    vertex_refused[x] = 0
                    retry[n_retry] = x
                    n_retry += 1
                if heap_position[edge] == PARKED:
                    continue  # waits for the next round (module docstring)
            cost = candidate_cost(vertices, vertex_quadrics, edge_quadrics, v, x, edge, exact,
                                  rank_tolerance, quadric, position, faces, face_alive, start,
                                  count, pool, look)
            update_or_park(heap_entries, heap_position, heap_size, cost_key(cost), pair(v, x),
                           edge, stop_key)
    return g, n_retry


update_vertex_edges = borrowing_kernel(_update_vertex_edges)


def _merge_edges(faces, face_edge, face_quadrics, edge_quadrics, start, count, pool, near,
                 generation, heap_entries, heap_position, heap_size, a, b, g, exact):
    """Edge bx merges into ax for every common neighbour x of a and b (gathered in
    generation g): the sides of b's faces take ax's id and bx leaves the heap. Other
    edges bz keep their id: after the relabelling they are az.

    Exact mode: Q_xa <- Q_xa + Q_xb - Q_xab, each sum in a fixed order (the levels must
    be bit-identical from run to run). Runs before the faces are rewritten, while faces
    abx are still alive.
    """
    generation[0] += 1
    g_seen = generation[0]
    s = start[b]
    for i in range(count[b]):
        f = pool[s + i]
        corner = corner_of(faces, f, b)
        for step in range(1, 3):
            x = faces[f, (corner + step) % 3]
            if x == a or near[x, NEAR_TAG_A] != g:
                continue
            row_ax, row_bx = near[x, NEAR_EDGE_A], near[x, NEAR_EDGE_B]
            face_edge[f, corner if step == 1 else (corner + 2) % 3] = row_ax
            if near[x, NEAR_SCRATCH] == g_seen:
                continue  # x seen through an earlier face of b
            near[x, NEAR_SCRATCH] = g_seen
            remove(heap_entries, heap_position, heap_size, row_bx)
            if exact:
                for d in range(QUADRIC_SIZE):
                    edge_quadrics[row_ax, d] += edge_quadrics[row_bx, d]
    if not exact:
        return
    # The dying faces abx were counted in both Q_xa and Q_xb: subtract them once.
    s = start[a]
    for i in range(count[a]):
        f = pool[s + i]
        x = opposite(faces, f, a, b)
        if x < 0:
            continue
        row_ax = near[x, NEAR_EDGE_A]
        for d in range(QUADRIC_SIZE):
            edge_quadrics[row_ax, d] -= face_quadrics[f, d]


merge_edges = borrowing_kernel(_merge_edges)


def _remove_from_run(start, count, pool, v, f):
    s = start[v]
    c = count[v]
    for i in range(c):
        if pool[s + i] == f:
            pool[s + i] = pool[s + c - 1]
            count[v] = c - 1
            return


remove_from_run = numba.njit(cache=True, inline="always")(_remove_from_run)


def _rewrite_faces(faces, face_alive, start, count, pool, used, a, b, killed, n_killed,
                   relabel, n_relabel):
    """Kill faces abx, move b's faces to a, write a's new run at the end of the pool.

    Returns the new (n_killed, n_relabel) fill levels of the record arrays.
    """
    out = used[0]
    s = start[a]
    for i in range(count[a]):
        f = pool[s + i]
        x = opposite(faces, f, a, b)
        if x >= 0:
            face_alive[f] = 0
            killed[n_killed] = f
            n_killed += 1
            remove_from_run(start, count, pool, x, f)
            continue
        pool[out] = f
        out += 1
    s = start[b]
    for i in range(count[b]):
        f = pool[s + i]
        if not face_alive[f]:
            continue  # a face abx, killed above
        for k in range(3):
            if faces[f, k] == b:
                faces[f, k] = a
        relabel[n_relabel] = f
        n_relabel += 1
        pool[out] = f
        out += 1
    start[a] = used[0]
    count[a] = out - used[0]
    used[0] = out
    count[b] = 0
    return n_killed, n_relabel


rewrite_faces = borrowing_kernel(_rewrite_faces)


def _update_after_contraction(vertices, vertex_quadrics, vertex_refused, edge_quadrics,
                              faces, face_alive, face_edge, start, count, pool, near,
                              generation, retry, part, heap_entries, heap_position, heap_size,
                              stop_key, pair_ends, pair_alive, first_pair, pair_start, pair_count,
                              pair_pool, a, b, killed, killed_from, killed_to, exact,
                              rank_tolerance, quadric, position, look):
    """New costs for the edges (and pairs) of the new vertex a; edges left without a
    face leave the heap; neighbours that had a candidate refused get their missing ones
    back, since a's change may have lifted the reason. ``retry`` is (n,) int32 scratch.
    """
    has_pairs = pair_ends.shape[0] > 0
    # One type for the vertex and the flag at every call, so that each helper compiles
    # once: a literal True and False, or an int32 and an int64 id, are two compilations.
    all_edges, only_missing = np.bool_(False), np.bool_(True)
    a = np.int64(a)
    g, n_retry = update_vertex_edges(vertices, vertex_quadrics, vertex_refused,
                                     edge_quadrics, faces, face_alive, face_edge, start,
                                     count, pool, near, generation, retry, part, heap_entries,
                                     heap_position, heap_size, stop_key, a, all_edges, exact,
                                     rank_tolerance, quadric, position, look)
    if has_pairs:
        update_vertex_pairs(vertices, vertex_quadrics, edge_quadrics, near, generation,
                            heap_entries, heap_position, heap_size, pair_ends, pair_alive,
                            first_pair, pair_start, pair_count, pair_pool, a, g, all_edges, exact,
                            rank_tolerance, quadric, position, faces, face_alive, start, count,
                            pool, look)
    # Edge ax of a dying face abx lives on only if another face has it (always, unless
    # the input is non-manifold or topology is not preserved).
    for i in range(killed_from, killed_to):
        f = killed[i]
        x = faces[f, 0] + faces[f, 1] + faces[f, 2] - a - b
        if near[x, NEAR_SCRATCH] != g:
            remove(heap_entries, heap_position, heap_size, near[x, NEAR_EDGE_A])
    for i in range(n_retry):
        v = np.int64(retry[i])
        g, _ = update_vertex_edges(vertices, vertex_quadrics, vertex_refused, edge_quadrics,
                                   faces, face_alive, face_edge, start, count, pool, near,
                                   generation, retry, part, heap_entries, heap_position,
                                   heap_size, stop_key, v, only_missing, exact, rank_tolerance,
                                   quadric, position, look)
        if has_pairs:
            update_vertex_pairs(vertices, vertex_quadrics, edge_quadrics, near, generation,
                                heap_entries, heap_position, heap_size, pair_ends, pair_alive,
                                first_pair, pair_start, pair_count, pair_pool, v, g,
                                only_missing, exact, rank_tolerance, quadric, position, faces,
                                face_alive, start, count, pool, look)


update_after_contraction = borrowing_kernel(_update_after_contraction)


def _run_contractions(cx, lists, pairs, hood, heap, record, params, max_steps, scratch):
    """Contract greedily until max_steps are done or nothing valid is left.

    Returns (status, steps done). Never raises; Python reads the status.
    """
    exact = params[PARAM_EXACT] != 0.0
    preserve_topology = params[PARAM_PRESERVE_TOPOLOGY] != 0.0
    cos_step = params[PARAM_COS_STEP_TURN]
    rank_tolerance = params[PARAM_RANK_TOLERANCE]
    distance_weight = params[PARAM_DISTANCE_WEIGHT]
    volume_weight = params[PARAM_VOLUME_WEIGHT]
    # Borrowed views: this call's caller holds every array until it returns.
    vertices, vertex_quadrics = borrow(cx.vertices), borrow(cx.vertex_quadrics)
    vertex_alive, vertex_refused = borrow(cx.vertex_alive), borrow(cx.vertex_refused)
    faces, face_alive = borrow(cx.faces), borrow(cx.face_alive)
    face_normals, face_edge = borrow(cx.face_normals), borrow(cx.face_edge)
    face_quadrics, edge_quadrics = borrow(cx.face_quadrics), borrow(cx.edge_quadrics)
    start, count = borrow(lists.start), borrow(lists.count)
    pool, used = borrow(lists.pool), borrow(lists.used)
    pair_ends, pair_alive = borrow(pairs.ends), borrow(pairs.alive)
    pair_start, pair_count = borrow(pairs.start), borrow(pairs.count)
    pair_pool, pair_used = borrow(pairs.pool), borrow(pairs.used)
    first_pair = pairs.first[0]
    has_pairs = pair_ends.shape[0] > 0
    near, generation, retry = borrow(hood.near), borrow(hood.generation), borrow(hood.retry)
    part = borrow(hood.part)
    stop_key = cost_key(params[PARAM_STOP_COST])
    shared_complex = params[PARAM_SHARED_COMPLEX] != 0.0
    heap_entries, heap_position = borrow(heap.entries), borrow(heap.position)
    heap_size = borrow(heap.size)
    record_a, record_b = borrow(record.a), borrow(record.b)
    position_a, position_b = borrow(record.position_a), borrow(record.position_b)
    record_cost, record_counts = borrow(record.cost), borrow(record.counts)
    killed, killed_end = borrow(record.killed), borrow(record.killed_end)
    relabel, relabel_end = borrow(record.relabel), borrow(record.relabel_end)
    wedge_log, wedge_log_values = borrow(record.wedge_log), borrow(record.wedge_log_values)
    wedge_log_end = borrow(record.wedge_log_end)
    wedge_relabel = borrow(record.wedge_relabel)
    wedge_relabel_end = borrow(record.wedge_relabel_end)
    look = (
        borrow(cx.face_wedges), borrow(cx.wedge_quadrics), borrow(cx.wedge_values),
        borrow(scratch.wedge_tag), borrow(scratch.wedge_slot), borrow(scratch.members),
        borrow(scratch.group_rows), borrow(scratch.counter), borrow(scratch.settings),
        borrow(scratch.value_bounds), borrow(scratch.total), borrow(scratch.group_values),
    )
    has_wedges = cx.wedge_quadrics.shape[0] > 0
    has_uvs = has_wedges and scratch.settings[SETTING_UV_OFFSET] >= 0.0
    quadric = np.zeros(QUADRIC_SIZE)
    penalised = np.zeros(QUADRIC_SIZE)
    position = np.zeros(3)
    steps = 0
    while steps < max_steps:
        if heap_size[0] == 0:
            return STATUS_EXHAUSTED, steps
        key = heap_entries[0, 0]
        if key > stop_key:
            return STATUS_STOP_COST, steps
        a, b, edge = top(heap_entries)
        # The survivor is the vertex with more faces: fewer corners to relabel, and the
        # guards and prefetches that read b's list read the shorter one.
        if count[b] > count[a]:
            a, b = b, a
        if used[0] + count[a] + count[b] > pool.shape[0]:
            if shared_complex:
                return STATUS_NEED_POOL_SPACE, steps
            compact(start, count, pool, used, vertex_alive)
            if used[0] + count[a] + count[b] > pool.shape[0]:
                return STATUS_NEED_POOL_SPACE, steps
        if has_pairs and pair_used[0] + pair_count[a] + pair_count[b] > pair_pool.shape[0]:
            compact(pair_start, pair_count, pair_pool, pair_used, vertex_alive)
            if pair_used[0] + pair_count[a] + pair_count[b] > pair_pool.shape[0]:
                return STATUS_NEED_PAIR_POOL_SPACE, steps
        if record_counts[2] + count[b] > relabel.shape[0]:
            return STATUS_NEED_RELABEL_SPACE, steps
        if has_wedges and (
            record_counts[3] + count[a] + count[b] > wedge_log.shape[0]
            or record_counts[4] + count[a] + count[b] > wedge_relabel.shape[0]
        ):
            return STATUS_NEED_WEDGE_SPACE, steps
        for v in (a, b):
            prefetch_neighbourhood(vertices, vertex_quadrics, edge_quadrics, face_normals,
                                   faces, face_edge, start, count, pool, heap_position, near,
                                   v, exact)
        generation[0] += 1
        g = generation[0]
        facts = gather(faces, face_edge, start, count, pool, a, b, near, g)
        prefetch_opposites(faces, start, count, pool, near, heap_entries, heap_position, a, b,
                           0)
        remove(heap_entries, heap_position, heap_size, edge)
        prefetch_next(heap_entries, heap_size, start, count, pool, faces, face_edge, 0)
        if edge >= first_pair:
            # A pair: no face joins a and b, and none of the link condition applies.
            if near[b, NEAR_TAG_A] == g:
                pair_alive[edge - first_pair] = 0  # an edge now (cannot happen: such die)
                continue
        elif near[b, NEAR_TAG_A] != g:
            continue  # no face left on the edge (cannot happen: such edges leave the heap)
        elif preserve_topology and check_link(
            faces, start, count, pool, a, b, near, g, facts
        ) != REFUSE_NONE:
            vertex_refused[a] = 1
            vertex_refused[b] = 1
            continue
        if leaves_a_vertex_bare(faces, start, count, pool, near, a, b):
            vertex_refused[a] = 1
            vertex_refused[b] = 1
            continue
        cost = candidate_cost(vertices, vertex_quadrics, edge_quadrics, a, b, edge, exact,
                              rank_tolerance, quadric, position, faces, face_alive, start,
                              count, pool, look)
        if volume_weight > 0.0:
            # May move the position. With wedges the cost is the total quadric's, the
            # appearance's Schur complements included (look[10], appearance.py).
            cost = with_volume(vertices, faces, start, count, pool, a, b,
                               look[10] if has_wedges else quadric,
                               quadric[0] + quadric[3] + quadric[5], cost, volume_weight,
                               rank_tolerance, penalised, position)
        px, py, pz = position[0], position[1], position[2]
        if has_wedges:
            if look[7][1] < 0:
                vertex_refused[a] = 1  # more wedges than the scratch space holds
                vertex_refused[b] = 1
                continue
            new_wedge_values(position, look)
            if has_uvs and not uv_keeps_orientation(faces, face_alive, start, count, pool,
                                                    a, b, look):
                vertex_refused[a] = 1
                vertex_refused[b] = 1
                continue
        prefetch_next(heap_entries, heap_size, start, count, pool, faces, face_edge, 1)
        prefetch_opposites(faces, start, count, pool, near, heap_entries, heap_position, a, b,
                           1)
        if not faces_keep_orientation(vertices, faces, face_normals, start, count, pool, a, b,
                                      px, py, pz, cos_step):
            vertex_refused[a] = 1
            vertex_refused[b] = 1
            continue
        if volume_weight > 0.0 or distance_weight > 0.0:
            # The volume and distance terms are priced only here, at the top of the
            # queue: the heap holds the quadric cost, a lower bound, and a candidate that
            # costs more than the next key goes back with its full cost as its key (reset
            # to the quadric cost when an end changes). Below the next key the distance
            # changes nothing, so it is not priced. In a parallel round the next key is
            # at most the round's stop key: the edges above it are parked, not in the
            # heap, and a candidate whose full cost passes it waits for the next round.
            next_key = heap_entries[0, 0] if heap_size[0] > 0 else cost_key(np.inf)
            next_key = min(next_key, stop_key)
            if distance_weight > 0.0:
                cost = with_distance(vertices, faces, start, count, pool, a, b, px, py, pz,
                                     quadric, cost, key, next_key, distance_weight)
            if cost_key(cost) > next_key:
                update(heap_entries, heap_position, heap_size, cost_key(cost), pair(a, b),
                       edge)
                continue
        merge_edges(faces, face_edge, face_quadrics, edge_quadrics, start, count, pool, near,
                    generation, heap_entries, heap_position, heap_size, a, b, g, exact)
        if has_pairs:
            merge_pairs(pair_ends, pair_alive, pair_start, pair_count, pair_pool, pair_used,
                        first_pair, heap_entries, heap_position, heap_size, a, b)
        j = record_counts[0]
        record_a[j] = a
        record_b[j] = b
        for d in range(3):
            position_a[j, d] = vertices[a, d]
            position_b[j, d] = vertices[b, d]
        record_cost[j] = cost
        killed_from = record_counts[1]
        if has_wedges:
            n_log, n_wedge_relabel = merge_wedges(
                faces, face_alive, start, count, pool, a, b, look, wedge_log,
                wedge_log_values, record_counts[3], wedge_relabel, record_counts[4],
            )
            wedge_log_end[j] = n_log
            wedge_relabel_end[j] = n_wedge_relabel
            record_counts[3] = n_log
            record_counts[4] = n_wedge_relabel
        n_killed, n_relabel = rewrite_faces(
            faces, face_alive, start, count, pool, used, a, b, killed,
            killed_from, relabel, record_counts[2],
        )
        killed_end[j] = n_killed
        relabel_end[j] = n_relabel
        record_counts[0] = j + 1
        record_counts[1] = n_killed
        record_counts[2] = n_relabel
        vertices[a, 0], vertices[a, 1], vertices[a, 2] = px, py, pz
        for k in range(QUADRIC_SIZE):
            vertex_quadrics[a, k] = quadric[k]
        vertex_alive[b] = 0
        steps += 1
        prefetch_next(heap_entries, heap_size, start, count, pool, faces, face_edge, 2)
        update_after_contraction(vertices, vertex_quadrics, vertex_refused, edge_quadrics,
                                 faces, face_alive, face_edge, start, count, pool, near,
                                 generation, retry, part, heap_entries, heap_position,
                                 heap_size, stop_key, pair_ends, pair_alive, first_pair, pair_start,
                                 pair_count, pair_pool, a, b, killed, killed_from, n_killed, exact,
                                 rank_tolerance, quadric, position, look)
    return STATUS_STEPS_DONE, steps


# nogil: the loops of a parallel round run in threads of their own (rounds.py).
run_contractions = numba.njit(cache=True, nogil=True)(_run_contractions)

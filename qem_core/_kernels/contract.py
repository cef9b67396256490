"""The greedy contraction loop: pop the cheapest edge, check it, contract it, record it.

Contracting (a, b) -> c keeps the slot of a for c and retires b::

        x                 x
       / \\               / \\
      /   \\             /   \\
     a --- b    ->         c          faces abx and aby die; faces of b now use c
      \\   /             \\   /
       \\ /               \\ /
        y                 y

Error modes (Edelsbrunner, Geometry and Topology for Mesh Generation, III.12):
additive uses Q_c = Q_a + Q_b; exact keeps quadrics on edges too and uses
Q_c = Q_a + Q_b - Q_ab and Q_xc = Q_xa + Q_xb - Q_xab, so every original plane is counted
once in every vertex and edge quadric. Triangle quadrics are the face quadrics themselves.

The loop runs in chunks of ``max_steps`` contractions so Python can report progress, and
stops early with a status code when an array is full (Python grows it and resumes).
Helpers take plain arrays, not the NamedTuples: a tuple argument costs reference counting
on each of its members at every call.
"""

from typing import NamedTuple

import numba
import numpy as np

from .adjacency import compact
from .heap import cost_key, drop_stale, pop_top, push, top_pair
from .link import REFUSE_NONE, check_link, gather
from .placement import place
from .quadrics import QUADRIC_SIZE

STATUS_EXHAUSTED = 0  # nothing valid left to contract
STATUS_STEPS_DONE = 1  # max_steps contractions done, more may follow
STATUS_NEED_RELABEL_SPACE = 2
STATUS_NEED_POOL_SPACE = 3
STATUS_NEED_HEAP_SPACE = 4

# Indices into the float parameter vector.
PARAM_RANK_TOLERANCE = 0
PARAM_COS_STEP_TURN = 1  # cos of the largest allowed per-contraction turn of a face normal
PARAM_EXACT = 2  # 1.0 for the exact (inclusion-exclusion) error mode
PARAM_PRESERVE_TOPOLOGY = 3
N_PARAMS = 4


class Complex(NamedTuple):
    """The current simplicial complex and its quadrics."""

    vertices: np.ndarray  # (n, 3) float64, moved in place
    vertex_quadrics: np.ndarray  # (n, 10) float64
    vertex_stamp: np.ndarray  # (n,) int32, bumped on every change
    vertex_alive: np.ndarray  # (n,) uint8
    vertex_refused: np.ndarray  # (n,) uint8: an edge of it was refused, retry on change
    faces: np.ndarray  # (m, 3) int32, corners rewritten in place
    face_alive: np.ndarray  # (m,) uint8
    face_normals: np.ndarray  # (m, 3) float64, unit normals of the original faces
    face_quadrics: np.ndarray  # (m, 10) float64 (triangle quadrics, exact mode)
    edge_slot: object  # numba typed Dict int64 -> int64, edge key -> edge_quadrics row
    edge_quadrics: np.ndarray  # (E, 10) float64 (exact mode only; else (0, 10))


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
    counts: np.ndarray  # (3,) int64: contractions, killed used, relabel used


def _edge_key(a, b, n):
    if a < b:
        return np.int64(a) * n + b
    return np.int64(b) * n + a


edge_key = numba.njit(cache=True)(_edge_key)


def _edge_cost(vertices, vertex_quadrics, edge_slot, edge_quadrics, a, b, exact,
               rank_tolerance, quadric, position):
    """Cost and best position of contracting (a, b); quadric (10,) receives Q_c."""
    for k in range(QUADRIC_SIZE):
        quadric[k] = vertex_quadrics[a, k] + vertex_quadrics[b, k]
    if exact:
        key = edge_key(a, b, vertices.shape[0])
        if key in edge_slot:
            row = edge_slot[key]
            for k in range(QUADRIC_SIZE):
                quadric[k] -= edge_quadrics[row, k]
    return place(quadric, vertices, a, b, rank_tolerance, position)


edge_cost = numba.njit(cache=True)(_edge_cost)


def _push_vertex_edges(vertices, vertex_quadrics, vertex_stamp, edge_slot, edge_quadrics,
                       faces, face_alive, start, count, pool, tag, generation,
                       heap_entries, heap_size, v, exact, rank_tolerance):
    """Push every edge of v with its current cost. False if the heap filled up."""
    quadric = np.zeros(QUADRIC_SIZE)
    position = np.zeros(3)
    scratch = np.zeros(1)
    generation[0] += 1
    g = generation[0]
    tag[v] = g
    s = start[v]
    for i in range(count[v]):
        f = pool[s + i]
        if not face_alive[f]:
            continue
        for k in range(3):
            x = faces[f, k]
            if tag[x] == g:
                continue
            tag[x] = g
            cost = edge_cost(vertices, vertex_quadrics, edge_slot, edge_quadrics, v, x,
                             exact, rank_tolerance, quadric, position)
            lo, hi = (v, x) if v < x else (x, v)
            if not push(heap_entries, heap_size, cost_key(cost, scratch), lo, hi,
                        vertex_stamp[lo], vertex_stamp[hi]):
                return False
    return True


push_vertex_edges = numba.njit(cache=True)(_push_vertex_edges)


def _turn_ok(vertices, faces, face_normals, f, moved, px, py, pz, cos_step):
    """Would moving corner ``moved`` of face f to p keep the face from flipping?

    Refused when the new normal turns more than the step limit from the current one, or
    more than 90 degrees from the original face's normal, or the face becomes degenerate.
    A per-step limit below 90 degrees (meshoptimizer uses 75) also stops faces from
    folding over in small steps that each look harmless.
    """
    i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
    p0x, p0y, p0z = vertices[i0, 0], vertices[i0, 1], vertices[i0, 2]
    p1x, p1y, p1z = vertices[i1, 0], vertices[i1, 1], vertices[i1, 2]
    p2x, p2y, p2z = vertices[i2, 0], vertices[i2, 1], vertices[i2, 2]
    ux, uy, uz = p1x - p0x, p1y - p0y, p1z - p0z
    vx, vy, vz = p2x - p0x, p2y - p0y, p2z - p0z
    ox, oy, oz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    if i0 == moved:
        p0x, p0y, p0z = px, py, pz
    elif i1 == moved:
        p1x, p1y, p1z = px, py, pz
    else:
        p2x, p2y, p2z = px, py, pz
    ux, uy, uz = p1x - p0x, p1y - p0y, p1z - p0z
    vx, vy, vz = p2x - p0x, p2y - p0y, p2z - p0z
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    new_length = np.sqrt(nx * nx + ny * ny + nz * nz)
    if new_length == 0.0:
        return False
    old_length = np.sqrt(ox * ox + oy * oy + oz * oz)
    if old_length > 0.0 and ox * nx + oy * ny + oz * nz < cos_step * old_length * new_length:
        return False
    return face_normals[f, 0] * nx + face_normals[f, 1] * ny + face_normals[f, 2] * nz > 0.0


turn_ok = numba.njit(cache=True)(_turn_ok)


def _faces_keep_orientation(vertices, faces, face_alive, face_normals, start, count, pool,
                            a, b, px, py, pz, cos_step):
    for v, other in ((a, b), (b, a)):
        s = start[v]
        for i in range(count[v]):
            f = pool[s + i]
            if not face_alive[f]:
                continue
            if faces[f, 0] == other or faces[f, 1] == other or faces[f, 2] == other:
                continue  # dies with the contraction
            if not turn_ok(vertices, faces, face_normals, f, v, px, py, pz, cos_step):
                return False
    return True


faces_keep_orientation = numba.njit(cache=True)(_faces_keep_orientation)


def _merge_edge_quadrics(edge_slot, edge_quadrics, face_quadrics, faces, face_alive, start,
                         count, pool, n, a, b):
    """Exact mode: Q_xa <- Q_xa + Q_xb - Q_xab for every neighbour x of b; drop Q_ab.

    Runs before the faces are rewritten, while faces abx are still alive.
    """
    s = start[b]
    for i in range(count[b]):
        f = pool[s + i]
        if not face_alive[f]:
            continue
        for k in range(3):
            x = faces[f, k]
            if x == a or x == b:
                continue
            key_bx = edge_key(b, x, n)
            if key_bx not in edge_slot:
                continue  # already moved (x seen through an earlier face of b)
            row_bx = edge_slot[key_bx]
            del edge_slot[key_bx]
            key_ax = edge_key(a, x, n)
            if key_ax in edge_slot:
                row_ax = edge_slot[key_ax]
                for d in range(QUADRIC_SIZE):
                    edge_quadrics[row_ax, d] += edge_quadrics[row_bx, d]
            else:
                edge_slot[key_ax] = row_bx
    # The dying faces abx were counted in both Q_xa and Q_xb: subtract them once.
    s = start[a]
    for i in range(count[a]):
        f = pool[s + i]
        if not face_alive[f]:
            continue
        c0, c1, c2 = faces[f, 0], faces[f, 1], faces[f, 2]
        if c0 != b and c1 != b and c2 != b:
            continue
        row_ax = edge_slot[edge_key(a, c0 + c1 + c2 - a - b, n)]
        for d in range(QUADRIC_SIZE):
            edge_quadrics[row_ax, d] -= face_quadrics[f, d]
    key_ab = edge_key(a, b, n)
    if key_ab in edge_slot:
        del edge_slot[key_ab]


merge_edge_quadrics = numba.njit(cache=True)(_merge_edge_quadrics)


def _remove_from_run(start, count, pool, v, f):
    s = start[v]
    c = count[v]
    for i in range(c):
        if pool[s + i] == f:
            pool[s + i] = pool[s + c - 1]
            count[v] = c - 1
            return


remove_from_run = numba.njit(cache=True)(_remove_from_run)


def _rewrite_faces(faces, face_alive, start, count, pool, used, a, b, killed, n_killed,
                   relabel, n_relabel):
    """Kill faces abx, move b's faces to a, write a's new run at the end of the pool.

    Returns the new (n_killed, n_relabel) fill levels of the record arrays.
    """
    out = used[0]
    s = start[a]
    for i in range(count[a]):
        f = pool[s + i]
        if not face_alive[f]:
            continue
        c0, c1, c2 = faces[f, 0], faces[f, 1], faces[f, 2]
        if c0 == b or c1 == b or c2 == b:
            face_alive[f] = 0
            killed[n_killed] = f
            n_killed += 1
            remove_from_run(start, count, pool, c0 + c1 + c2 - a - b, f)
            continue
        pool[out] = f
        out += 1
    s = start[b]
    for i in range(count[b]):
        f = pool[s + i]
        if not face_alive[f]:
            continue
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


rewrite_faces = numba.njit(cache=True)(_rewrite_faces)


def _push_after_contraction(vertices, vertex_quadrics, vertex_stamp, vertex_refused,
                            edge_slot, edge_quadrics, faces, face_alive, start, count, pool,
                            tag, generation, retry, heap_entries, heap_size, a, exact,
                            rank_tolerance):
    """Push the edges of the new vertex a, and again those of neighbours that had an edge
    refused: a's change may have lifted the reason. ``retry`` is (n,) int32 scratch.

    False if the heap filled up; calling it again after growing the heap is harmless
    (a duplicate entry is skipped as stale once the first copy is used).
    """
    generation[0] += 1
    g = generation[0]
    n_retry = 0
    s = start[a]
    for i in range(count[a]):
        f = pool[s + i]
        for k in range(3):
            x = faces[f, k]
            if x != a and vertex_refused[x] and tag[x] != g:
                tag[x] = g
                vertex_refused[x] = 0
                retry[n_retry] = x
                n_retry += 1
    retry[n_retry] = a
    n_retry += 1
    for i in range(n_retry):
        if not push_vertex_edges(vertices, vertex_quadrics, vertex_stamp, edge_slot,
                                 edge_quadrics, faces, face_alive, start, count, pool, tag,
                                 generation, heap_entries, heap_size, retry[i], exact,
                                 rank_tolerance):
            for j in range(i, n_retry - 1):
                vertex_refused[retry[j]] = 1  # not pushed yet: try again on next change
            return False
    return True


push_after_contraction = numba.njit(cache=True)(_push_after_contraction)


def _resume_pushes(cx, lists, hood, heap, a, params):
    """``push_after_contraction`` for Python, after it grew the heap."""
    return push_after_contraction(
        cx.vertices, cx.vertex_quadrics, cx.vertex_stamp, cx.vertex_refused, cx.edge_slot,
        cx.edge_quadrics, cx.faces, cx.face_alive, lists.start, lists.count, lists.pool,
        hood.tag_scratch, hood.generation, hood.retry, heap.entries, heap.size, a,
        params[PARAM_EXACT] != 0.0, params[PARAM_RANK_TOLERANCE],
    )


resume_pushes = numba.njit(cache=True)(_resume_pushes)


def _run_contractions(cx, lists, hood, heap, record, params, max_steps):
    """Contract greedily until max_steps are done or nothing valid is left.

    Returns (status, steps done, vertex whose edges still need pushing or -1).
    Never raises; Python reads the status.
    """
    exact = params[PARAM_EXACT] != 0.0
    preserve_topology = params[PARAM_PRESERVE_TOPOLOGY] != 0.0
    cos_step = params[PARAM_COS_STEP_TURN]
    rank_tolerance = params[PARAM_RANK_TOLERANCE]
    vertices, vertex_quadrics, vertex_stamp = cx.vertices, cx.vertex_quadrics, cx.vertex_stamp
    vertex_alive, vertex_refused = cx.vertex_alive, cx.vertex_refused
    faces, face_alive, face_normals = cx.faces, cx.face_alive, cx.face_normals
    edge_slot, edge_quadrics = cx.edge_slot, cx.edge_quadrics
    start, count, pool, used = lists.start, lists.count, lists.pool, lists.used
    tag_a, count_a, tag_b, count_b = hood.tag_a, hood.count_a, hood.tag_b, hood.count_b
    tag_opposite, tag_scratch, generation = hood.tag_opposite, hood.tag_scratch, hood.generation
    retry = hood.retry
    heap_entries, heap_size = heap.entries, heap.size
    n = vertices.shape[0]
    quadric = np.zeros(QUADRIC_SIZE)
    position = np.zeros(3)
    steps = 0
    while steps < max_steps:
        if heap_size[0] == 0:
            return STATUS_EXHAUSTED, steps, -1
        a, b, stamp_a, stamp_b = top_pair(heap_entries)
        if (
            vertex_stamp[a] != stamp_a
            or vertex_stamp[b] != stamp_b
            or not vertex_alive[a]
            or not vertex_alive[b]
        ):
            pop_top(heap_entries, heap_size)
            continue
        # The survivor is the vertex with more faces: fewer corners to relabel.
        if count[b] > count[a]:
            a, b = b, a
        if used[0] + count[a] + count[b] > pool.shape[0]:
            compact(lists, vertex_alive)
            if used[0] + count[a] + count[b] > pool.shape[0]:
                return STATUS_NEED_POOL_SPACE, steps, -1
        if record.counts[2] + count[b] > record.relabel.shape[0]:
            return STATUS_NEED_RELABEL_SPACE, steps, -1
        generation[0] += 1
        g = generation[0]
        gather(faces, face_alive, start, count, pool, a, b, tag_a, count_a, tag_b, count_b,
               tag_opposite, g)
        if tag_a[b] != g:
            pop_top(heap_entries, heap_size)  # no longer an edge
            continue
        if preserve_topology and check_link(
            faces, face_alive, start, count, pool, a, b, tag_a, count_a, tag_b, count_b,
            tag_opposite, g,
        ) != REFUSE_NONE:
            pop_top(heap_entries, heap_size)
            vertex_refused[a] = 1
            vertex_refused[b] = 1
            continue
        cost = edge_cost(vertices, vertex_quadrics, edge_slot, edge_quadrics, a, b, exact,
                         rank_tolerance, quadric, position)
        px, py, pz = position[0], position[1], position[2]
        if not faces_keep_orientation(vertices, faces, face_alive, face_normals, start, count,
                                      pool, a, b, px, py, pz, cos_step):
            pop_top(heap_entries, heap_size)
            vertex_refused[a] = 1
            vertex_refused[b] = 1
            continue
        pop_top(heap_entries, heap_size)
        if exact:
            merge_edge_quadrics(edge_slot, edge_quadrics, cx.face_quadrics, faces, face_alive,
                                start, count, pool, n, a, b)
        j = record.counts[0]
        record.a[j] = a
        record.b[j] = b
        for d in range(3):
            record.position_a[j, d] = vertices[a, d]
            record.position_b[j, d] = vertices[b, d]
        record.cost[j] = cost
        n_killed, n_relabel = rewrite_faces(
            faces, face_alive, start, count, pool, used, a, b, record.killed,
            record.counts[1], record.relabel, record.counts[2],
        )
        record.killed_end[j] = n_killed
        record.relabel_end[j] = n_relabel
        record.counts[0] = j + 1
        record.counts[1] = n_killed
        record.counts[2] = n_relabel
        vertices[a, 0], vertices[a, 1], vertices[a, 2] = px, py, pz
        for k in range(QUADRIC_SIZE):
            vertex_quadrics[a, k] = quadric[k]
        vertex_alive[b] = 0
        vertex_stamp[a] += 1
        vertex_stamp[b] += 1
        steps += 1
        if heap_size[0] + 8 * (count[a] + 2) >= heap_entries.shape[0]:
            drop_stale(heap_entries, heap_size, vertex_stamp)
            if 2 * heap_size[0] >= heap_entries.shape[0]:
                return STATUS_NEED_HEAP_SPACE, steps, a
        if not push_after_contraction(vertices, vertex_quadrics, vertex_stamp, vertex_refused,
                                      edge_slot, edge_quadrics, faces, face_alive, start,
                                      count, pool, tag_scratch, generation, retry,
                                      heap_entries, heap_size, a, exact, rank_tolerance):
            return STATUS_NEED_HEAP_SPACE, steps, a
    return STATUS_STEPS_DONE, steps, -1


run_contractions = numba.njit(cache=True)(_run_contractions)

"""Initial state of the contraction loop: edges, vertex, edge and border quadrics, first
costs. Everything here is O(faces) and runs once per build."""

import numba
import numpy as np

from . import heap as heap_ops
from .memory import prefetch
from .placement import edge_cost
from .quadrics import QUADRIC_SIZE, boundary_quadric

# How many candidates ahead `fill_heap` asks for the rows of their ends.
FILL_AHEAD = 8


def _sum_quadrics(faces, face_quadrics, face_edge, border, border_edges, border_quadrics,
                  vertex_quadrics, edge_quadrics, exact):
    """The border planes summed into vertex quadrics (after the faces, which
    ``fill_face_quadrics`` summed), and in exact mode the edge quadrics.

    vertex_quadrics : (n, 10), in and out: every border plane at its first end, then at
    its second end. edge_quadrics : (E, 10) zeros, out (exact only): every face at each
    side, then every border plane. The order of the sums is fixed here: levels must come
    out bit-identical on every run.
    """
    for end in range(2):
        for i in range(border_edges.shape[0]):
            v = border_edges[i, end]
            for d in range(QUADRIC_SIZE):
                vertex_quadrics[v, d] += border_quadrics[i, d]
    if not exact:
        return
    for f in range(faces.shape[0]):
        for k in range(3):
            e = face_edge[f, k]
            for d in range(QUADRIC_SIZE):
                edge_quadrics[e, d] += face_quadrics[f, d]
    for i in range(border.shape[0]):
        e = border[i]
        for d in range(QUADRIC_SIZE):
            edge_quadrics[e, d] += border_quadrics[i, d]


sum_quadrics = numba.njit(cache=True)(_sum_quadrics)


def _fill_border_quadrics(vertices, border_edges, border_faces, face_normals, weighting,
                          boundary_weight, out):
    """out[i] = constraint plane of border edge i (its endpoints, its one face)."""
    for i in range(border_edges.shape[0]):
        boundary_quadric(
            vertices, border_edges[i, 0], border_edges[i, 1],
            face_normals[border_faces[i]], weighting, boundary_weight, out[i],
        )


fill_border_quadrics = numba.njit(cache=True)(_fill_border_quadrics)


def _fill_heap(vertices, vertex_quadrics, edge_quadrics, edges, ids, run_start, run_end,
               exact, rank_tolerance, heap_entries):
    """Write the heap row of every candidate in the runs [run_start[r], run_end[r]) of
    ``edges`` and ``ids``, at the same row of ``heap_entries``, unordered (the caller
    orders each heap: `heap.heapify`, or `heap.park_above` in a round).

    edges : (E, 2) int32 candidates, ids : (E,) int64 their ids (the build's first heap:
    one run of 0..E-1, the edges and then the pairs of pairs.py; a round: a run per
    part, each the room of its heap, rounds.py). Rows outside the runs are not read.

    The costs are independent, so they are computed in parallel, each edge by the same
    arithmetic as in the loop: the result does not depend on the number of threads. Each
    chunk takes its share of every run.

    An edge's ends are near it in z-order but not in the cache: each pricing waited for
    their rows, one edge after another. The rows of the ends (in exact mode, the edge's
    too) FILL_AHEAD edges on are asked for first: the rounds' fills took 0.6-0.7x the
    time on the dragon.
    """
    n_chunks = 256
    for chunk in numba.prange(n_chunks):
        quadric = np.zeros(QUADRIC_SIZE)
        position = np.zeros(3)
        for r in range(run_start.shape[0]):
            length = run_end[r] - run_start[r]
            first = run_start[r] + chunk * length // n_chunks
            last = run_start[r] + (chunk + 1) * length // n_chunks
            for e in range(first, last):
                if e + FILL_AHEAD < last:
                    for end in range(2):
                        v = edges[e + FILL_AHEAD, end]
                        prefetch(vertices, v, 0)
                        prefetch(vertex_quadrics, v, 0)
                        prefetch(vertex_quadrics, v, 8 * QUADRIC_SIZE - 8)
                    if exact:
                        prefetch(edge_quadrics, ids[e + FILL_AHEAD], 0)
                        prefetch(edge_quadrics, ids[e + FILL_AHEAD], 8 * QUADRIC_SIZE - 8)
                a, b, edge = edges[e, 0], edges[e, 1], ids[e]
                cost = edge_cost(vertices, vertex_quadrics, edge_quadrics, a, b, edge, exact,
                                 rank_tolerance, quadric, position)
                heap_entries[e, 0] = heap_ops.cost_key(cost)
                heap_entries[e, 1] = heap_ops.pair(a, b)
                heap_entries[e, 2] = edge


fill_heap = numba.njit(cache=True, parallel=True)(_fill_heap)

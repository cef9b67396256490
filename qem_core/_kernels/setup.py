"""Initial state of the contraction loop: edges, vertex, edge and border quadrics, first
costs. Everything here is O(faces) and runs once per build."""

import numba
import numpy as np

from . import heap as heap_ops
from .contract import edge_cost
from .quadrics import QUADRIC_SIZE, boundary_quadric


def _find_edges(faces, n_vertices, face_edge, edges, edge_face_count, edge_side):
    """Number the undirected edges of ``faces`` in (low, high) order; returns their count E.

    faces : (m, 3) int32. Side k of face f runs from corner k to corner k + 1.
    face_edge : (m, 3) int32 out, the edge of each side.
    edges : (>= E, 2) int32 out, (low, high) of each edge, low < high.
    edge_face_count : (>= E,) int32 zeros, out: the faces on each edge.
    edge_side : (>= E,) int64 out: the last side (3 f + k) on each edge.

    A counting sort by low end, then an insertion sort of each low end's few sides by
    high end: O(m) and no (3m,) int64 key array to sort, where np.unique with its inverse
    spent most of the set-up.
    """
    n_sides = 3 * faces.shape[0]
    bucket = np.zeros(n_vertices + 1, np.int64)
    for s in range(n_sides):
        f, k = s // 3, s % 3
        u, v = faces[f, k], faces[f, (k + 1) % 3]
        bucket[min(u, v) + 1] += 1
    for v in range(n_vertices):
        bucket[v + 1] += bucket[v]
    fill = bucket[:-1].copy()
    side_high = np.zeros(n_sides, np.int32)
    side_of = np.zeros(n_sides, np.int64)
    for s in range(n_sides):
        f, k = s // 3, s % 3
        u, v = faces[f, k], faces[f, (k + 1) % 3]
        low = min(u, v)
        i = fill[low]
        fill[low] = i + 1
        # Insertion by high end, behind equal ones: sides of an edge stay in side order.
        high = max(u, v)
        while i > bucket[low] and side_high[i - 1] > high:
            side_high[i] = side_high[i - 1]
            side_of[i] = side_of[i - 1]
            i -= 1
        side_high[i] = high
        side_of[i] = s
    n_edges = 0
    for low in range(n_vertices):
        previous = -1
        for i in range(bucket[low], bucket[low + 1]):
            if side_high[i] != previous:
                previous = side_high[i]
                edges[n_edges, 0] = low
                edges[n_edges, 1] = previous
                n_edges += 1
            e = n_edges - 1
            s = side_of[i]
            face_edge[s // 3, s % 3] = e
            edge_face_count[e] += 1
            edge_side[e] = s
    return n_edges


find_edges = numba.njit(cache=True)(_find_edges)


def _sum_quadrics(faces, face_quadrics, face_edge, border, border_edges, border_quadrics,
                  vertex_quadrics, edge_quadrics, exact):
    """Vertex quadrics (and, in exact mode, edge quadrics) as sums of face and border
    planes.

    vertex_quadrics : (n, 10) zeros, out: every face at each corner, then every border
    plane at its first end, then at its second end. edge_quadrics : (E, 10) zeros, out
    (exact only): every face at each side, then every border plane. The order of the sums
    is fixed here: levels must come out bit-identical on every run.
    """
    for f in range(faces.shape[0]):
        for k in range(3):
            v = faces[f, k]
            for d in range(QUADRIC_SIZE):
                vertex_quadrics[v, d] += face_quadrics[f, d]
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


def _fill_heap(vertices, vertex_quadrics, edge_quadrics, edges, exact, rank_tolerance,
               heap_entries, heap_position, heap_size):
    """Put every edge in the heap with its cost, then order it once (O(E))."""
    quadric = np.zeros(QUADRIC_SIZE)
    position = np.zeros(3)
    for e in range(edges.shape[0]):
        a, b = edges[e, 0], edges[e, 1]
        cost = edge_cost(vertices, vertex_quadrics, edge_quadrics, a, b, e, exact,
                         rank_tolerance, quadric, position)
        heap_entries[e, 0] = heap_ops.cost_key(cost)
        heap_entries[e, 1] = heap_ops.pair(a, b)
        heap_entries[e, 2] = e
    heap_size[0] = edges.shape[0]
    heap_ops.heapify(heap_entries, heap_position, heap_size)


fill_heap = numba.njit(cache=True)(_fill_heap)

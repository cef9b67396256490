"""Whole-mesh passes of the preparation: equal rows, edges and their faces, components.

Each is O(size) with no sort: on a 871k-face scan the numpy versions (sorting packed keys,
np.unique with its inverse, union-find rounds of np.minimum.at) took most of the time
before the contraction loop starts.
"""

import numba
import numpy as np


def _first_equal_rows(rows, first):
    """first[i] = the smallest j with rows[j] == rows[i] (row by row, exactly).

    rows : (r, c) uint64; first : (r,) int64, out. An open-addressing hash table of row
    indices, probed linearly: a hash collision costs a comparison, never a wrong answer.
    """
    n_rows, n_columns = rows.shape
    size = 1
    while size < 2 * n_rows:
        size *= 2
    mask = np.uint64(size - 1)
    table = np.full(size, -1, np.int64)
    for i in range(n_rows):
        key = np.uint64(0)
        for c in range(n_columns):  # splitmix64-style mixing of the columns
            key = (key ^ rows[i, c]) * np.uint64(0x9E3779B97F4A7C15)
            key ^= key >> np.uint64(29)
        slot = key & mask
        while True:
            j = table[slot]
            if j < 0:
                table[slot] = i
                first[i] = i
                break
            same = True
            for c in range(n_columns):
                if rows[j, c] != rows[i, c]:
                    same = False
                    break
            if same:
                first[i] = j
                break
            slot = (slot + np.uint64(1)) & mask


first_equal_rows = numba.njit(cache=True)(_first_equal_rows)


def _find_edges(faces, n_vertices, face_edge, edges, edge_face_count, edge_side):
    """Number the undirected edges of ``faces`` in (low, high) order; returns their count E.

    faces : (m, 3) int32. Side k of face f runs from corner k to corner k + 1.
    face_edge : (m, 3) int32 out, the edge of each side.
    edges : (>= E, 2) int32 out, (low, high) of each edge, low < high.
    edge_face_count : (>= E,) int32 zeros, out: the faces on each edge.
    edge_side : (>= E,) int64 out: the last side (3 f + k) on each edge.

    A counting sort by low end, then an insertion sort of each low end's few sides by
    high end: O(m), and no (3m,) int64 key array to sort.
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


def _root(parent, v):
    while parent[v] != v:
        parent[v] = parent[parent[v]]  # path halving
        v = parent[v]
    return v


root = numba.njit(cache=True)(_root)


def _count_components(faces, n_vertices):
    """Connected components of the vertices 0..n_vertices-1 joined by face sides (a vertex
    no face uses is a component of its own). Union-find, one pass over the faces."""
    parent = np.arange(n_vertices)
    n_components = n_vertices
    for f in range(faces.shape[0]):
        for k in range(2):
            u = root(parent, faces[f, k])
            v = root(parent, faces[f, k + 1])
            if u != v:
                parent[max(u, v)] = min(u, v)
                n_components -= 1
    return n_components


count_components = numba.njit(cache=True)(_count_components)

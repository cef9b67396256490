"""Whole-mesh passes of the preparation: equal rows, degenerate faces and the renumbering,
edges and their faces (and so duplicate faces), components.

Each is O(size) with no sort: on a 871k-face scan the numpy versions (sorting packed keys,
np.unique with its inverse, union-find rounds of np.minimum.at) took most of the time
before the contraction loop starts.
"""

import numba
import numpy as np

from .adjacency import chunk_starts
from .memory import prefetch

LOW_32_BITS = (1 << 32) - 1


def _row_hash(rows, i):
    """splitmix64-style mixing of the columns of row i."""
    key = np.uint64(0)
    for c in range(rows.shape[1]):
        key = (key ^ rows[i, c]) * np.uint64(0x9E3779B97F4A7C15)
        key ^= key >> np.uint64(29)
    return key


row_hash = numba.njit(cache=True, inline="always")(_row_hash)

# Rows ahead of the one placed whose table slot `first_equal_rows` asks the cache for:
# the table is far larger than the cache and each probe would wait for memory otherwise.
PROBE_AHEAD = 16


def _first_equal_rows(rows, first):
    """first[i] = the smallest j with rows[j] == rows[i] (row by row, exactly).

    rows : (r, c) uint64; first : (r,) int64, out. An open-addressing hash table of row
    indices, probed linearly: a hash collision costs a comparison, never a wrong answer.
    """
    n_rows = rows.shape[0]
    size = 1
    while size < 2 * n_rows:
        size *= 2
    mask = np.uint64(size - 1)
    table = np.full(size, -1, np.int64)
    for i in range(n_rows):
        if i + PROBE_AHEAD < n_rows:
            prefetch(table, np.int64(row_hash(rows, i + PROBE_AHEAD) & mask), 0)
        slot = row_hash(rows, i) & mask
        while True:
            j = table[slot]
            if j < 0:
                table[slot] = i
                first[i] = i
                break
            same = True
            for c in range(rows.shape[1]):
                if rows[j, c] != rows[i, c]:
                    same = False
                    break
            if same:
                first[i] = j
                break
            slot = (slot + np.uint64(1)) & mask


first_equal_rows = numba.njit(cache=True)(_first_equal_rows)


def _sorted_corner_keys(faces, keys):
    """keys[f] = the corners of face f as a set: (low << 32 | middle, high).

    faces : (m, 3) int32; keys : (m, 2) uint64, out."""
    for i in range(faces.shape[0]):
        a, b, c = faces[i, 0], faces[i, 1], faces[i, 2]
        low = min(a, b, c)
        high = max(a, b, c)
        middle = a ^ b ^ c ^ low ^ high
        keys[i, 0] = (np.uint64(low) << np.uint64(32)) | np.uint64(middle)
        keys[i, 1] = np.uint64(high)


sorted_corner_keys = numba.njit(cache=True)(_sorted_corner_keys)


# An edge of more faces than this is not searched for duplicate faces (`find_edges`):
# the search compares every two of its faces.
MAX_FACES_COMPARED = 32


def _mark_degenerate_faces(faces, weld_map, degenerate, vertex_used):
    """degenerate (m,) uint8 out: 1 for each face with two corners on one vertex once
    welded (``weld_map``: each vertex's representative); vertex_used (n,) uint8 zeros,
    out: 1 for each representative a face that is not degenerate uses. Returns the
    number of degenerate faces."""
    n_degenerate = 0
    for f in range(faces.shape[0]):
        a, b, c = weld_map[faces[f, 0]], weld_map[faces[f, 1]], weld_map[faces[f, 2]]
        if a == b or b == c or c == a:
            degenerate[f] = 1
            n_degenerate += 1
        else:
            degenerate[f] = 0
            vertex_used[a] = 1
            vertex_used[b] = 1
            vertex_used[c] = 1
    return n_degenerate


mark_degenerate_faces = numba.njit(cache=True)(_mark_degenerate_faces)


def _renumber_kept_faces(faces, degenerate, vertex_map, out):
    """out (faces left, 3) int32: the faces not degenerate, in order, each corner v
    written vertex_map[v] (its welded representative's new number)."""
    row = 0
    for f in range(faces.shape[0]):
        if degenerate[f]:
            continue
        for k in range(3):
            out[row, k] = vertex_map[faces[f, k]]
        row += 1


renumber_kept_faces = numba.njit(cache=True)(_renumber_kept_faces)


def _find_edges(faces, n_vertices, face_edge, edges, edge_face_count, edge_side, n_chunks,
                duplicate):
    """Number the undirected edges of ``faces`` in (low, high) order; returns their count
    E and the number of edges not searched for duplicate faces (below).

    faces : (m, 3) int32. Side k of face f runs from corner k to corner k + 1.
    face_edge : (m, 3) int32 out, the edge of each side.
    edges : (>= E, 2) int32 out, (low, high) of each edge, low < high.
    edge_face_count : (>= E,) int32 out: the faces on each edge.
    edge_side : (>= E,) int64 out: the last side (3 f + k) on each edge.
    duplicate : (m,) uint8 zeros, out, or (0,) for no search: 1 for each face with the
    same three corners as an earlier face. Two such faces share all three edges, so
    they are found on any of them, comparing the corners opposite each edge of its
    faces; no edge but those of more than MAX_FACES_COMPARED faces goes unsearched
    (the second count: 0 means ``duplicate`` is complete). The edges come out the same
    with or without the search (prepare.py: it replaced a hash table of sorted corners).

    A counting sort of the sides by low end, then an insertion sort of each low end's few
    sides by high end: O(m), and no (3m,) int64 key array to sort. Each side is one int64,
    high << 32 | side, so the sort moves one array and keeps an edge's sides in side
    order. In parallel: the faces in ``n_chunks`` chunks for the counting sort (each
    chunk's sides after the earlier chunks'), then the low ends, each its own sides and
    edges (an edge is numbered and written from its low end alone); the same numbers for
    any number of chunks.
    """
    n_faces = faces.shape[0]
    offset = np.zeros((n_chunks, n_vertices), np.int64)
    for chunk in numba.prange(n_chunks):
        for f in range(chunk * n_faces // n_chunks, (chunk + 1) * n_faces // n_chunks):
            for k in range(3):
                offset[chunk, min(faces[f, k], faces[f, (k + 1) % 3])] += 1
    bucket = np.zeros(n_vertices + 1, np.int64)
    bucket[n_vertices] = chunk_starts(offset, bucket)
    high_and_side = np.empty(3 * n_faces, np.int64)  # every element written
    for chunk in numba.prange(n_chunks):
        for f in range(chunk * n_faces // n_chunks, (chunk + 1) * n_faces // n_chunks):
            for k in range(3):
                u, v = faces[f, k], faces[f, (k + 1) % 3]
                low = min(u, v)
                i = offset[chunk, low]
                offset[chunk, low] = i + 1
                high_and_side[i] = (np.int64(max(u, v)) << 32) | (3 * f + k)
    # Each low end's sides in increasing (high, side) order, and its number of edges.
    first_edge = np.zeros(n_vertices + 1, np.int64)
    for low in numba.prange(n_vertices):
        begin, end = bucket[low], bucket[low + 1]
        for i in range(begin + 1, end):
            key = high_and_side[i]
            j = i
            while j > begin and high_and_side[j - 1] > key:
                high_and_side[j] = high_and_side[j - 1]
                j -= 1
            high_and_side[j] = key
        n_edges = 0
        previous = -1
        for i in range(begin, end):
            high = high_and_side[i] >> 32
            if high != previous:
                previous = high
                n_edges += 1
        first_edge[low + 1] = n_edges
    for low in range(n_vertices):
        first_edge[low + 1] += first_edge[low]
    search = duplicate.shape[0] > 0
    unsearched = np.zeros(n_vertices, np.int32)
    for low in numba.prange(n_vertices):
        e = first_edge[low] - 1
        previous = -1
        edge_start = 0
        for i in range(bucket[low], bucket[low + 1]):
            high = high_and_side[i] >> 32
            if high != previous:
                previous = high
                e += 1
                edges[e, 0] = low
                edges[e, 1] = high
                edge_face_count[e] = 0  # written before it is read: no zeroed pages
                edge_start = i
            s = high_and_side[i] & LOW_32_BITS
            face_edge[s // 3, s % 3] = e
            edge_face_count[e] += 1
            edge_side[e] = s
            if search and i > edge_start:
                if edge_face_count[e] > MAX_FACES_COMPARED:
                    if edge_face_count[e] == MAX_FACES_COMPARED + 1:
                        unsearched[low] += 1
                    continue
                # The corner opposite side s; the earlier sides of this edge are of
                # earlier faces (a side sorts by 3 f + k).
                x = faces[s // 3, (s % 3 + 2) % 3]
                for j in range(edge_start, i):
                    t = high_and_side[j] & LOW_32_BITS
                    if faces[t // 3, (t % 3 + 2) % 3] == x:
                        duplicate[s // 3] = 1  # the same 1 from each shared edge
                        break
    return first_edge[n_vertices], unsearched.sum()


find_edges = numba.njit(cache=True, parallel=True)(_find_edges)


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

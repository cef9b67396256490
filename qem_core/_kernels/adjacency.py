"""Vertex -> faces lists that change as vertices merge, in one flat pool.

Each vertex owns a run ``pool[start[v] : start[v] + count[v]]`` of face ids. Merging a and
b writes the merged list at the end of the pool (``used`` grows); when the pool is full,
``compact`` rewrites the live runs to the front (meshoptimizer keeps similar flat
adjacency arrays, rebuilt rather than linked). The same lists hold the candidate pairs of
each vertex (pairs.py): items of two corners instead of three.

A vertex's run holds its live faces only: a contraction takes each face it kills out of
the runs of its three corners (``contract.rewrite_faces``), so the kernels that walk a
run read no ``face_alive``.
"""

from typing import NamedTuple

import numba
import numpy as np


def _corner_of(faces, f, v):
    """Which corner (0, 1, 2) of face f is vertex v (v must be one)."""
    return 0 if faces[f, 0] == v else (1 if faces[f, 1] == v else 2)


corner_of = numba.njit(cache=True, inline="always")(_corner_of)


def _has_corner(faces, f, v):
    """Is v a corner of face f?"""
    return faces[f, 0] == v or faces[f, 1] == v or faces[f, 2] == v


has_corner = numba.njit(cache=True, inline="always")(_has_corner)


def _opposite(faces, f, a, b):
    """The third corner x of face f if f is a face abx (f has corner a), else -1."""
    c0, c1, c2 = faces[f, 0], faces[f, 1], faces[f, 2]
    if c0 != b and c1 != b and c2 != b:
        return -1
    return c0 + c1 + c2 - a - b


opposite = numba.njit(cache=True, inline="always")(_opposite)


def _face_across(faces, start, count, pool, v, f, x):
    """The first live face of v other than f with the corner x: on a manifold, the face
    across the edge v-x from f; -1 if there is none (v-x a border edge)."""
    s = start[v]
    for i in range(count[v]):
        g = pool[s + i]
        if g != f and has_corner(faces, g, x):
            return g
    return -1


face_across = numba.njit(cache=True, inline="always")(_face_across)


class FaceLists(NamedTuple):
    start: np.ndarray  # (n,) int64
    count: np.ndarray  # (n,) int32
    pool: np.ndarray  # (capacity,) int32
    used: np.ndarray  # (1,) int64


# At most this many chunks in a parallel counting sort (`sort_chunks`): each chunk holds a
# row of offsets, one per key, so memory, not speed, bounds them.
MAX_SORT_CHUNKS = 8


def sort_chunks() -> int:
    """How many chunks a parallel counting sort (`fill_face_lists`, topology.find_edges,
    partition.faces_by_lowest_corner) splits its items into: one per numba thread, at
    most MAX_SORT_CHUNKS. Their results do not depend on it."""
    return max(1, min(numba.get_num_threads(), MAX_SORT_CHUNKS))


def _chunk_starts(offset, start):
    """The middle step of a counting sort in chunks: ``offset`` (chunks, keys) holds how
    many items each chunk has of each key, and becomes where those items start (after
    the items of every lower key, then after the earlier chunks' items of the same key);
    start[key] (at least ``keys`` long) receives where the key's items start. Returns
    the number of items."""
    used = 0
    for key in range(offset.shape[1]):
        start[key] = used
        for chunk in range(offset.shape[0]):
            items = offset[chunk, key]
            offset[chunk, key] = used
            used += items
    return used


chunk_starts = numba.njit(cache=True)(_chunk_starts)


def make_face_lists(faces: np.ndarray, n_vertices: int, capacity: int,
                    alive: np.ndarray | None = None, pool: np.ndarray | None = None
                    ) -> FaceLists:
    """CSR vertex -> incident faces (each run in increasing face order), in a pool of
    ``capacity`` (>= faces.size) slots. faces : (m, c) int32, c corners per item;
    ``alive`` (m,) uint8: list only those items (all if None). ``pool``: (capacity,)
    int32 to fill, its contents ignored (a fresh one if None)."""
    count = np.zeros(n_vertices, np.int32)
    start = np.zeros(n_vertices, np.int64)
    # Uninitialised: only the runs are ever read, and the pool's room past them (most of
    # it in a parallel round's regions) then costs no page until a run is written there.
    if pool is None:
        pool = np.empty(capacity, np.int32)
    elif pool.shape != (capacity,) or pool.dtype != np.int32:
        raise ValueError(f"make_face_lists: pool must be ({capacity},) int32")
    if alive is None:
        alive = np.ones(faces.shape[0], np.uint8)
    used = fill_face_lists(faces, alive, start, count, pool, sort_chunks())
    return FaceLists(start, count, pool, np.array([used], np.int64))


def _fill_face_lists(faces, alive, start, count, pool, n_chunks):
    """Counting sort of the corners of the live items by vertex (O(m); a stable argsort
    cost 0.15 s on 871k faces). start, count : zeros, out; pool : (>= 3 m,), out.
    Returns the number of pool slots used.

    The items are counted and placed in ``n_chunks`` chunks, one per thread: each
    chunk's items of a vertex go after the earlier chunks' (``offset``, one row per
    chunk), so every run is in increasing item order whatever the number of chunks."""
    n_items, n_corners = faces.shape
    n_vertices = start.shape[0]
    offset = np.zeros((n_chunks, n_vertices), np.int64)
    for chunk in numba.prange(n_chunks):
        for f in range(chunk * n_items // n_chunks, (chunk + 1) * n_items // n_chunks):
            if alive[f]:
                for k in range(n_corners):
                    offset[chunk, faces[f, k]] += 1
    used = chunk_starts(offset, start)
    for v in range(n_vertices):
        count[v] = (start[v + 1] if v + 1 < n_vertices else used) - start[v]
    for chunk in numba.prange(n_chunks):
        for f in range(chunk * n_items // n_chunks, (chunk + 1) * n_items // n_chunks):
            if alive[f]:
                for k in range(n_corners):
                    v = faces[f, k]
                    pool[offset[chunk, v]] = f
                    offset[chunk, v] += 1
    return used


fill_face_lists = numba.njit(cache=True, parallel=True)(_fill_face_lists)


def _compact(start, count, pool, used, alive):
    """Move the lists of live vertices to the front of the pool, in vertex order."""
    total = 0
    for v in range(start.shape[0]):
        if alive[v]:
            total += count[v]
    packed = np.zeros(total, np.int32)
    cursor = 0
    for v in range(start.shape[0]):
        if alive[v]:
            s = start[v]
            for i in range(count[v]):
                packed[cursor + i] = pool[s + i]
            start[v] = cursor
            cursor += count[v]
        else:
            count[v] = 0
            start[v] = 0
    pool[:total] = packed
    used[0] = total


compact = numba.njit(cache=True)(_compact)

"""A binary min-heap of candidate contractions over flat arrays, with lazy invalidation.

An entry is ``cost[i]`` and ``ids[i] = (a, b, stamp_a, stamp_b)``. Every change to a
vertex bumps its stamp, so an entry whose stamps no longer match is stale and is skipped
when popped; the fresh cost was pushed when the vertex changed. Ties are broken by
(a, b), which makes the order, and so every level of detail, deterministic.
The size lives in ``size[0]`` so kernels update it in place.
"""

from typing import NamedTuple

import numba
import numpy as np


class Heap(NamedTuple):
    cost: np.ndarray  # (capacity,) float64
    ids: np.ndarray  # (capacity, 4) int32: a, b, stamp_a, stamp_b
    size: np.ndarray  # (1,) int64


def make_heap(capacity: int) -> Heap:
    return Heap(np.full(capacity, np.inf), np.full((capacity, 4), -1, np.int32),
                np.zeros(1, np.int64))


def grow_heap(heap: Heap) -> Heap:
    capacity = heap.cost.shape[0]
    bigger = make_heap(2 * capacity)
    bigger.cost[:capacity] = heap.cost
    bigger.ids[:capacity] = heap.ids
    bigger.size[0] = heap.size[0]
    return bigger


def _less(cost, ids, i, j):
    if cost[i] != cost[j]:
        return cost[i] < cost[j]
    if ids[i, 0] != ids[j, 0]:
        return ids[i, 0] < ids[j, 0]
    return ids[i, 1] < ids[j, 1]


less = numba.njit(cache=True)(_less)


def _swap(cost, ids, i, j):
    cost[i], cost[j] = cost[j], cost[i]
    for k in range(4):
        ids[i, k], ids[j, k] = ids[j, k], ids[i, k]


swap = numba.njit(cache=True)(_swap)


def _sift_down(cost, ids, i, size):
    while True:
        left = 2 * i + 1
        if left >= size:
            return
        smallest = left
        right = left + 1
        if right < size and less(cost, ids, right, left):
            smallest = right
        if not less(cost, ids, smallest, i):
            return
        swap(cost, ids, i, smallest)
        i = smallest


sift_down = numba.njit(cache=True)(_sift_down)


def _heapify(cost, ids, size):
    for i in range(size[0] // 2 - 1, -1, -1):
        sift_down(cost, ids, i, size[0])


heapify = numba.njit(cache=True)(_heapify)


def _push(cost, ids, size, value, a, b, stamp_a, stamp_b):
    """Push an entry; False when the heap is full (the caller grows or compacts it)."""
    i = size[0]
    if i >= cost.shape[0]:
        return False
    cost[i] = value
    ids[i, 0] = a
    ids[i, 1] = b
    ids[i, 2] = stamp_a
    ids[i, 3] = stamp_b
    size[0] = i + 1
    while i > 0:
        parent = (i - 1) // 2
        if not less(cost, ids, i, parent):
            break
        swap(cost, ids, i, parent)
        i = parent
    return True


push = numba.njit(cache=True)(_push)


def _pop_top(cost, ids, size):
    """Remove the top entry (the caller has read it at index 0)."""
    last = size[0] - 1
    swap(cost, ids, 0, last)
    size[0] = last
    sift_down(cost, ids, 0, last)


pop_top = numba.njit(cache=True)(_pop_top)


def _drop_stale(cost, ids, size, vertex_stamp):
    """Remove every entry whose stamps are out of date, then restore the heap order."""
    kept = 0
    for i in range(size[0]):
        if vertex_stamp[ids[i, 0]] == ids[i, 2] and vertex_stamp[ids[i, 1]] == ids[i, 3]:
            cost[kept] = cost[i]
            for k in range(4):
                ids[kept, k] = ids[i, k]
            kept += 1
    size[0] = kept
    heapify(cost, ids, size)


drop_stale = numba.njit(cache=True)(_drop_stale)

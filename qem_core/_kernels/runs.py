"""Runs of the contraction record, gathered in another order.

The record keeps, per contraction j, a run ``values[end[j-1] : end[j]]`` (faces killed,
faces relabelled). The progressive mesh wants the same runs for split k = J-1-j: the runs
in reverse order, each run's own order kept; a parallel round's records are merged in
order of cost (record.py). A slice per run in Python cost ~0.3 s per half a million
contractions; this is one pass.
"""

import numba
import numpy as np


def _gather_runs(values, ends, order, out):
    """out[...] = the runs of ``values`` ending at ``ends``, taken in ``order``, each run's
    own order kept.

    values : (>= ends[-1],); ends : increasing run ends; order : run numbers; out :
    (total length of those runs,) of values' dtype, filled.
    """
    cursor = 0
    for j in order:
        start = ends[j - 1] if j > 0 else 0
        for i in range(start, ends[j]):
            out[cursor] = values[i]
            cursor += 1


gather_runs = numba.njit(cache=True)(_gather_runs)


def _taken_before(key, p, q):
    """Whether part p's head is taken before part q's: by key, NaN after every number,
    ties to the lower part."""
    kp, kq = key[p], key[q]
    if kp != kp:
        return kq != kq and p < q
    if kq != kq:
        return True
    return kp < kq or (kp == kq and p < q)


taken_before = numba.njit(cache=True, inline="always")(_taken_before)


def _sift_part_down(heap, size, key, i):
    """Move heap[i] down to its place in the binary heap heap[:size] of parts."""
    while True:
        child = 2 * i + 1
        if child >= size:
            return
        if child + 1 < size and taken_before(key, heap[child + 1], heap[child]):
            child += 1
        if not taken_before(key, heap[child], heap[i]):
            return
        heap[i], heap[child] = heap[child], heap[i]
        i = child


sift_part_down = numba.njit(cache=True, inline="always")(_sift_part_down)


def _head_key(costs, h, running):
    """The running maximum of a part once its row h is taken: NaN stays NaN."""
    value = costs[h]
    if running != running:
        return running
    if value <= running:
        return running
    return value  # larger, or NaN


head_key = numba.njit(cache=True, inline="always")(_head_key)


def _merge_by_running_max(costs, part_ends, order):
    """order (N,) out: the rows of ``costs`` merged part by part on running maxima.

    costs : (N,) float64, the parts' costs one part after another, part p ending at row
    part_ends[p]. Each part's rows keep their order; the next row taken is the head of
    the part whose running maximum (its costs so far, the head's included) is smallest,
    ties to the lower part. The same order as a stable sort of the running maxima by
    (value, part), NaN after every number as numpy sorts it, in one pass: a round's
    parts are each in cost order already (np.lexsort and its keys took ~10 ms of a
    dragon build's 42 ms of merging). The parts' heads are kept in a binary heap: a
    round has dozens of parts (rounds.py), and a scan of them all for every row took
    longer than the rest of the merge.
    """
    n_parts = part_ends.shape[0]
    head = np.empty(n_parts, np.int64)
    key = np.empty(n_parts)  # each part's running maximum once its head is taken
    heap = np.empty(n_parts, np.int64)  # the parts with rows left
    size = 0
    for p in range(n_parts):
        head[p] = part_ends[p - 1] if p > 0 else 0
        if head[p] < part_ends[p]:
            key[p] = head_key(costs, head[p], -np.inf)
            heap[size] = p
            size += 1
    for i in range(size // 2 - 1, -1, -1):
        sift_part_down(heap, size, key, i)
    for i in range(order.shape[0]):
        p = heap[0]
        order[i] = head[p]
        head[p] += 1
        if head[p] < part_ends[p]:
            key[p] = head_key(costs, head[p], key[p])
        else:
            size -= 1
            heap[0] = heap[size]
        sift_part_down(heap, size, key, 0)


merge_by_running_max = numba.njit(cache=True)(_merge_by_running_max)

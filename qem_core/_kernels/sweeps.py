"""The refinement order the stream codes cheaply: sweeps of ascending split vertices.

The greedy run contracts the cheapest edge first wherever it lies, so its splits name
their vertex s all over the level: an index of about log2(n) bits a split, a quarter
of the split stream. Two splits whose neighbourhoods share no vertex commute: either
order gives the same faces and positions once both are done. Within a window of the
refinement (the splits that grow a level of n vertices by about n/16), the splits are
put in an order that keeps every dependency and takes them in sweeps of ascending s
(Kahn's topological order, a ready split joining the sweep while its s lies ahead of
the last one taken). The stream then codes s as the gap from the previous split's s:
a few bits. Levels at the windows' ends are those of the greedy run; a level inside a
window holds other splits of the same window than the greedy order would.

A split's neighbourhood (``touched``): its s and t, and the corners of the faces it
relabels and brings back. If two splits touch no common vertex, no face of one holds a
vertex of the other, so neither changes what the other reads (the link condition is
combinatorial, the positions are each split's own). The dependencies are found in one
replay of the contractions backwards (splits forwards) over the faces the run left.
"""

import math

import numba
import numpy as np

from .memory import prefetch

# The splits of a window grow the level by at most this share of its vertices.
WINDOW_SHARE = 16
MIN_WINDOW = 16


# How many splits ahead split_dependencies asks for the faces a split will read, and
# half as many for the ``last`` entries of their corners: the splits' faces lie all over
# the mesh, and each read would otherwise wait on memory.
_AHEAD = 16


@numba.njit(cache=True, inline="always")
def _prefetch_ahead(faces, last, killed, killed_end, relabel, relabel_end, j_count, k):
    for step in range(2):
        ahead = k + (_AHEAD if step == 0 else _AHEAD // 2)
        if ahead >= j_count:
            continue
        j = j_count - 1 - ahead
        for run in range(2):
            items = relabel if run == 0 else killed
            ends = relabel_end if run == 0 else killed_end
            for i in range(ends[j - 1] if j > 0 else 0, ends[j]):
                f = items[i]
                if step == 0:
                    prefetch(faces, f, 0)
                else:
                    for r in range(3):
                        prefetch(last, faces[f, r], 0)


@numba.njit(cache=True, inline="always")
def _touch(v, k, last, taken_by, preds, n):
    """Split k touches vertex v: the last earlier split that touched v becomes one of k's
    predecessors (once). Returns (preds, n), preds grown if need be."""
    p = last[v]
    last[v] = k
    if p < 0 or p == k or taken_by[p] == k:
        return preds, n
    taken_by[p] = k
    if n == preds.shape[0]:
        bigger = np.empty(2 * n, np.int32)
        bigger[:n] = preds
        preds = bigger
    preds[n] = p
    return preds, n + 1


@numba.njit(cache=True)
def split_dependencies(faces, a, b, killed, killed_end, relabel, relabel_end, j_count, n_slots):
    """For split k (undoing contraction j = j_count-1-k), the earlier splits it must
    follow: the last split before it that touched each vertex it touches. Returns
    (pred_offsets (j_count + 1,) int64, preds int32). ``faces`` (m, 3) int32, the faces
    as the run left them (killed ones as they were when killed), is replayed back to
    the input's faces (overwritten)."""
    last = np.full(n_slots, -1, np.int32)
    taken_by = np.full(j_count, -1, np.int32)  # the last split each one preceded
    pred_offsets = np.zeros(j_count + 1, np.int64)
    preds = np.empty(max(64, 6 * j_count), np.int32)
    n = 0
    for k in range(j_count):
        _prefetch_ahead(faces, last, killed, killed_end, relabel, relabel_end, j_count, k)
        j = j_count - 1 - k
        s = a[j]
        t = b[j]
        preds, n = _touch(s, k, last, taken_by, preds, n)
        preds, n = _touch(t, k, last, taken_by, preds, n)
        for i in range(relabel_end[j - 1] if j > 0 else 0, relabel_end[j]):
            f = relabel[i]
            for r in range(3):
                if faces[f, r] == s:
                    faces[f, r] = t
            for r in range(3):
                preds, n = _touch(faces[f, r], k, last, taken_by, preds, n)
        for i in range(killed_end[j - 1] if j > 0 else 0, killed_end[j]):
            for r in range(3):
                preds, n = _touch(faces[killed[i], r], k, last, taken_by, preds, n)
        pred_offsets[k + 1] = n
    return pred_offsets, preds[:n]


def window_ends(n_base: int, j_count: int) -> list[int]:
    """The levels (vertex counts) where the sweep order's windows end, from n_base + the
    first window to n_base + j_count: the levels the greedy run's order gives. A window
    grows the level by 1/WINDOW_SHARE of its vertices, at least MIN_WINDOW."""
    ends = []
    k0 = 0
    while k0 < j_count:
        k0 = min(j_count, k0 + max(MIN_WINDOW, (n_base + k0) // WINDOW_SHARE))
        ends.append(n_base + k0)
    return ends


@numba.njit(cache=True, inline="always")
def _lowest_bit(word):
    """The index of the lowest set bit of a nonzero int64 word."""
    if word == np.int64(-0x8000000000000000):
        return 63
    return np.int64(math.log2(word & -word))  # a power of two below 2^63: exact


@numba.njit(cache=True)
def sweep_order(pred_offsets, preds, survivor, retired, level_of_slot, n_base, ends):
    """The new split order (position -> old split k), window by window (see the module
    docstring). survivor, retired : the slots a and b of each contraction j (split
    k = J-1-j); level_of_slot : (slots,) int32, the survivors' level numbers (the
    others -1), overwritten with every slot's number in the new order; ends : the
    windows' last levels (``window_ends``).

    The ready splits of a window are bits of a bitmap over their s's level numbers (two
    ready splits never share an s: the second would follow the first); a sweep takes the
    next set bit after the last one taken, and starts again from 0 at the end."""
    j_count = survivor.shape[0]
    n_succ = np.zeros(j_count + 1, np.int64)
    for k in range(j_count):
        for z in range(pred_offsets[k], pred_offsets[k + 1]):
            n_succ[preds[z] + 1] += 1
    succ_offsets = np.cumsum(n_succ)
    succ = np.empty(preds.shape[0], np.int32)
    fill = succ_offsets[:-1].copy()
    for k in range(j_count):
        for z in range(pred_offsets[k], pred_offsets[k + 1]):
            p = preds[z]
            succ[fill[p]] = k
            fill[p] += 1
    split_s = np.empty(j_count, np.int32)  # the slot of each split's s, in split order
    split_t = np.empty(j_count, np.int32)
    for k in range(j_count):
        split_s[k] = survivor[j_count - 1 - k]
        split_t[k] = retired[j_count - 1 - k]
    waiting = np.zeros(j_count, np.int32)  # predecessors in the window not yet taken
    order = np.empty(j_count, np.int64)
    ready = np.zeros((n_base + j_count) // 64 + 1, np.int64)
    split_of_key = np.empty(n_base + j_count, np.int32)
    taken = 0
    k0 = 0
    for end in ends:
        k1 = end - n_base
        for k in range(k0, k1):
            count = 0
            for z in range(pred_offsets[k], pred_offsets[k + 1]):
                count += preds[z] >= k0
            waiting[k] = count
            if count == 0:
                key = level_of_slot[split_s[k]]
                ready[key >> 6] |= np.int64(1) << (key & 63)
                split_of_key[key] = k
        cursor = 0
        while taken < k1:
            w = cursor >> 6
            word = ready[w] & (np.int64(-1) << (cursor & 63))  # cursor <= n_base + j_count
            while word == 0:  # a ready split's s is below n_base + taken
                w += 1
                if w > (n_base + taken) >> 6:
                    w = 0  # a new sweep
                word = ready[w]
            key = (w << 6) + _lowest_bit(word)
            ready[w] &= ~(np.int64(1) << (key & 63))
            cursor = key + 1
            k = split_of_key[key]
            level_of_slot[split_t[k]] = n_base + taken
            order[taken] = k
            taken += 1
            for z in range(succ_offsets[k], succ_offsets[k + 1]):
                q = succ[z]
                if q >= k1:
                    continue
                waiting[q] -= 1
                if waiting[q] == 0:
                    key = level_of_slot[split_s[q]]
                    ready[key >> 6] |= np.int64(1) << (key & 63)
                    split_of_key[key] = q
        k0 = k1
    return order

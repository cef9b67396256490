"""An indexed 4-ary min-heap of the candidate edges, one row per edge in the heap.

A row of ``entries`` (capacity, 3) int64 is::

    [cost key, a << 32 | b, edge id]        (a < b, the edge's ends)

and ``position[edge]`` is the row holding that edge, -1 when it is not in the heap (-2,
`PARKED`, when a parallel round keeps it out above its stop cost: `update_or_park`). The
cost key is the bit pattern of the (non-negative) float64 cost, which orders exactly as
the cost does; ties are broken by (a, b), which makes the order, and so every level of
detail, deterministic.

Why indexed: a lazily invalidated heap pushes a new entry whenever an edge's cost changes
and skips the old one when it surfaces; on a big mesh nine pops in ten were such stale
entries, each walking the height of a heap several times the number of edges. Here an
edge is in the heap at most once: a changed cost moves its row in place (costs mostly
grow after a contraction, and most rows sit near the leaves, so the walk is short), a
dead edge is removed, and every pop is a real candidate. The capacity is the number of
edges of the input: contraction never creates an edge id.

Why this layout: each step of a walk reads the four children of one node; one 24-byte
row per entry (instead of parallel cost and id arrays) and four children per node (a
quarter of the height of a binary heap for the same fan-out in cache lines) keep that to
about two cache lines. ``size[0]`` holds the size so kernels update it in place.
"""

from typing import NamedTuple

import numba
import numpy as np
from llvmlite import ir
from numba.core import types
from numba.extending import intrinsic

from .memory import borrowing_kernel

ARITY = 4
_LOW32 = (1 << 32) - 1
# ``position`` of an edge kept out of the heap because its cost is above the loop's stop
# cost (`update_or_park`): not missing, not a candidate this round, and not priced again
# in it (contract.py).
PARKED = -2


class Heap(NamedTuple):
    entries: np.ndarray  # (capacity, 3) int64: cost key, a << 32 | b, edge id
    position: np.ndarray  # (capacity,) int32: row of each edge id, -1 if not in the heap
    # (PARKED: kept out above a round's stop cost)
    size: np.ndarray  # (1,) int64


def make_heap(capacity: int) -> Heap:
    """An empty heap for edge ids 0..capacity-1."""
    return Heap(
        np.zeros((max(capacity, 1), 3), np.int64),
        np.full(max(capacity, 1), -1, np.int32),
        np.zeros(1, np.int64),
    )


@intrinsic
def _float_bits(typingctx, value):
    """The bits of a float64 as an int64 (a register move; no array view, no allocation)."""

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.IntType(64))

    return types.int64(types.float64), codegen


def _cost_key(cost):
    """The int64 whose order is the order of ``cost``.

    Negative round-off (a quadric is never below zero) becomes 0, NaN becomes +inf."""
    if not cost >= 0.0:
        cost = np.inf if cost != cost else 0.0
    return _float_bits(cost + 0.0)  # + 0.0 turns -0.0 into 0.0


cost_key = numba.njit(cache=True, inline="always")(_cost_key)


@intrinsic
def _bits_float(typingctx, value):
    """The float64 whose bits an int64 holds (the inverse of ``_float_bits``)."""

    def codegen(context, builder, signature, args):
        return builder.bitcast(args[0], ir.DoubleType())

    return types.float64(types.int64), codegen


def _key_cost(key):
    """The cost a key of ``cost_key`` was made from."""
    return _bits_float(key)


key_cost = numba.njit(cache=True, inline="always")(_key_cost)


def _pair(a, b):
    """The packed (low, high) pair of an edge's ends, the tie-break of equal costs."""
    if a < b:
        return (np.int64(a) << 32) | np.int64(b)
    return (np.int64(b) << 32) | np.int64(a)


pair = numba.njit(cache=True, inline="always")(_pair)


def _top(entries):
    """(a, b, edge id) of the top row, a < b."""
    ab = entries[0, 1]
    return ab >> 32, ab & _LOW32, entries[0, 2]


top = numba.njit(cache=True, inline="always")(_top)


def _sift_down(entries, position, i, size):
    """Move the row at i down to its place, shifting smaller children up (no swaps)."""
    key, ab, edge = entries[i, 0], entries[i, 1], entries[i, 2]
    while True:
        first = ARITY * i + 1
        if first >= size:
            break
        best = first
        last = min(first + ARITY, size)
        for j in range(first + 1, last):
            if entries[j, 0] < entries[best, 0] or (
                entries[j, 0] == entries[best, 0] and entries[j, 1] < entries[best, 1]
            ):
                best = j
        if entries[best, 0] > key or (entries[best, 0] == key and entries[best, 1] >= ab):
            break
        moved = entries[best, 2]
        entries[i, 0], entries[i, 1], entries[i, 2] = entries[best, 0], entries[best, 1], moved
        position[moved] = i
        i = best
    entries[i, 0], entries[i, 1], entries[i, 2] = key, ab, edge
    position[edge] = i


sift_down = numba.njit(cache=True, inline="always")(_sift_down)


def _sift_up(entries, position, i, key, ab, edge):
    """Put (key, ab, edge) at row i or above, shifting larger parents down."""
    while i > 0:
        parent = (i - 1) // ARITY
        if entries[parent, 0] < key or (entries[parent, 0] == key and entries[parent, 1] <= ab):
            break
        moved = entries[parent, 2]
        entries[i, 0], entries[i, 1], entries[i, 2] = entries[parent, 0], entries[parent, 1], moved
        position[moved] = i
        i = parent
    entries[i, 0], entries[i, 1], entries[i, 2] = key, ab, edge
    position[edge] = i


sift_up = numba.njit(cache=True, inline="always")(_sift_up)


def _heapify(entries, position, size):
    """Order rows 0..size-1 (written unordered, e.g. by ``fill_heap``) in O(size)."""
    n = size[0]
    for i in range((n - 2) // ARITY, -1, -1):
        sift_down(entries, position, i, n)
    for i in range(n):
        position[entries[i, 2]] = i


heapify = borrowing_kernel(_heapify)


def _update(entries, position, size, key, ab, edge):
    """Give ``edge`` the key (key, ab): insert it, or move its row up or down."""
    i = position[edge]
    if i < 0:
        i = size[0]
        size[0] = i + 1
        sift_up(entries, position, i, key, ab, edge)
    elif key < entries[i, 0] or (key == entries[i, 0] and ab < entries[i, 1]):
        sift_up(entries, position, i, key, ab, edge)
    else:
        entries[i, 0], entries[i, 1] = key, ab
        sift_down(entries, position, i, size[0])


update = borrowing_kernel(_update)


def _remove(entries, position, size, edge):
    """Take ``edge`` out of the heap if it is in; the last row fills its place."""
    i = position[edge]
    if i < 0:
        return
    position[edge] = -1
    last = size[0] - 1
    size[0] = last
    if i == last:
        return
    key, ab, moved = entries[last, 0], entries[last, 1], entries[last, 2]
    parent = (i - 1) // ARITY
    if i > 0 and (
        key < entries[parent, 0] or (key == entries[parent, 0] and ab < entries[parent, 1])
    ):
        sift_up(entries, position, i, key, ab, moved)
    else:
        entries[i, 0], entries[i, 1], entries[i, 2] = key, ab, moved
        sift_down(entries, position, i, last)


remove = borrowing_kernel(_remove)


def _update_or_park(entries, position, size, key, ab, edge, stop_key):
    """`update`, but an edge whose key is above ``stop_key`` leaves the heap instead and is
    `PARKED`: the loop stops before it would reach it, so it need not sink to its place
    (a parallel round's heap keeps out the edges priced above the round's cost)."""
    if key > stop_key:
        remove(entries, position, size, edge)
        position[edge] = PARKED
    else:
        update(entries, position, size, key, ab, edge)


update_or_park = borrowing_kernel(_update_or_park)


# kth_smallest_key selects by 16 bits of the key at a time, from the top: a key is the
# bits of a float64 >= 0, so below 2^63.
KEY_DIGIT_BITS = 16
KEY_DIGIT_MASK = (1 << KEY_DIGIT_BITS) - 1


def _digit_of_rank(count, k):
    """The digit whose keys hold rank k (from 0) among keys counted by digit, and k's
    rank among that digit's keys."""
    digit = 0
    while k >= count[digit]:
        k -= count[digit]
        digit += 1
    return digit, k


digit_of_rank = numba.njit(cache=True, inline="always")(_digit_of_rank)


def _kth_smallest_key(entries, run_start, run_end, k):
    """The k-th smallest (from 0) of the keys entries[i, 0] of the rows of the runs
    [run_start[r], run_end[r]): the value np.partition would put at k, by a radix select.
    The rows are counted by their keys' top 16 bits (a sixteenth of an octave of cost)
    and those of the digit holding rank k gathered; the next 16 bits select among them,
    and so on down, each pass over fewer keys; after the last, the keys left are equal.
    O(n), whatever the keys: zero-cost edges of a flat mesh share every digit (numpy's
    copy of the keys and its partition took 25-30 ms over a dragon build's rounds; this,
    7 ms)."""
    count = np.zeros(1 << KEY_DIGIT_BITS, np.int64)
    shift = 63 - KEY_DIGIT_BITS
    for r in range(run_start.shape[0]):
        for i in range(run_start[r], run_end[r]):
            count[entries[i, 0] >> shift] += 1
    digit, k = digit_of_rank(count, k)
    inside = np.empty(count[digit], np.int64)
    n = 0
    for r in range(run_start.shape[0]):
        for i in range(run_start[r], run_end[r]):
            if entries[i, 0] >> shift == digit:
                inside[n] = entries[i, 0]
                n += 1
    while shift > 0:
        shift = max(shift - KEY_DIGIT_BITS, 0)
        count[:] = 0
        for j in range(n):
            count[(inside[j] >> shift) & KEY_DIGIT_MASK] += 1
        digit, k = digit_of_rank(count, k)
        kept = 0
        for j in range(n):
            if (inside[j] >> shift) & KEY_DIGIT_MASK == digit:
                inside[kept] = inside[j]
                kept += 1
        n = kept
    return inside[0]


kth_smallest_key = numba.njit(cache=True)(_kth_smallest_key)


def _park_above(entries, position, size, stop_key):
    """Keep the rows 0..size-1 (written unordered) with a key at or below ``stop_key``, park
    the others (`PARKED`), and order what is kept (`heapify`)."""
    kept = 0
    for i in range(size[0]):
        if entries[i, 0] > stop_key:
            position[entries[i, 2]] = PARKED
            continue
        for column in range(3):
            entries[kept, column] = entries[i, column]
        kept += 1
    size[0] = kept
    heapify(entries, position, size)


# nogil: a round parks its parts' heaps in threads at once (rounds.py).
park_above = borrowing_kernel(_park_above, nogil=True)

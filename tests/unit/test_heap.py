"""The indexed heap of candidates (qem_core/_kernels/heap.py) against a plain dict."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from qem_core._kernels.heap import (
    PARKED,
    heapify,
    kth_smallest_key,
    make_heap,
    park_above,
    remove,
    top,
    update,
    update_or_park,
)

N_EDGES = 24
KEYS = st.integers(0, 6)  # few values: ties, broken by (a, b), are the point
LOW_ENDS = st.integers(0, 5)  # an edge's high end is 100 + its id: no two edges share ends
OPERATIONS = st.lists(st.one_of(
    st.tuples(st.just("update"), st.integers(0, N_EDGES - 1), KEYS, LOW_ENDS),
    st.tuples(st.just("park"), st.integers(0, N_EDGES - 1), KEYS, LOW_ENDS),
    st.tuples(st.just("remove"), st.integers(0, N_EDGES - 1)),
    st.tuples(st.just("pop"),),
), max_size=60)


def pack(a, edge):
    """The heap's (a, b) of an edge with ends a and 100 + edge."""
    return (a << 32) | (100 + edge)


def check_heap(heap, expected, parked):
    """Rows form a 4-ary min-heap on (key, ab), ``position`` names each edge's row, and
    the edges held, with their keys, and the parked ones are the expected ones."""
    entries, position, size = heap.entries, heap.position, int(heap.size[0])
    for i in range(1, size):
        parent = (i - 1) // 4
        assert tuple(entries[parent, :2]) <= tuple(entries[i, :2])
    held = {int(entries[i, 2]): (int(entries[i, 0]), int(entries[i, 1])) for i in range(size)}
    assert held == expected
    for edge in range(N_EDGES):
        if edge in expected:
            assert entries[position[edge], 2] == edge
        else:
            assert position[edge] == (PARKED if edge in parked else -1)


@settings(max_examples=200)
@given(OPERATIONS, KEYS)
def test_operations_keep_the_heap_and_its_index(operations, stop):
    heap = make_heap(N_EDGES)
    expected, parked = {}, set()
    for operation in operations:
        if operation[0] == "pop":
            if expected:
                best = min(expected, key=lambda edge: expected[edge])
                a, b, edge = top(heap.entries)
                assert (edge, (a << 32) | b) == (best, expected[best][1])
                remove(heap.entries, heap.position, heap.size, edge)
                del expected[edge]
        elif operation[0] == "remove":
            edge = operation[1]
            remove(heap.entries, heap.position, heap.size, edge)
            expected.pop(edge, None)
            if edge in parked:  # a parked edge is left parked: it is not in the heap
                continue
        else:
            kind, edge, key, a = operation
            if kind == "update":
                update(heap.entries, heap.position, heap.size, key, pack(a, edge), edge)
                expected[edge] = (key, pack(a, edge))
                parked.discard(edge)
            else:
                update_or_park(heap.entries, heap.position, heap.size, key, pack(a, edge),
                               edge, stop)
                if key > stop:
                    expected.pop(edge, None)
                    parked.add(edge)
                else:
                    expected[edge] = (key, pack(a, edge))
                    parked.discard(edge)
        check_heap(heap, expected, parked)


@settings(max_examples=200)
@given(st.lists(st.tuples(KEYS, LOW_ENDS), min_size=0, max_size=N_EDGES), KEYS)
def test_park_above_keeps_the_rows_at_or_below_the_stop_in_order(rows, stop):
    heap = make_heap(N_EDGES)
    for i, (key, a) in enumerate(rows):
        heap.entries[i] = (key, pack(a, i), i)
    heap.size[0] = len(rows)
    park_above(heap.entries, heap.position, heap.size, stop)
    expected = {i: (key, pack(a, i)) for i, (key, a) in enumerate(rows) if key <= stop}
    parked = {i for i, (key, _) in enumerate(rows) if key > stop}
    check_heap(heap, expected, parked)


def test_heapify_orders_rows_written_unordered():
    rng = np.random.default_rng(7)
    heap = make_heap(N_EDGES)
    keys = rng.integers(0, 5, N_EDGES)
    for i, key in enumerate(keys):
        heap.entries[i] = (key, pack(i % 3, i), i)
    heap.size[0] = N_EDGES
    heapify(heap.entries, heap.position, heap.size)
    check_heap(heap, {i: (int(keys[i]), pack(i % 3, i)) for i in range(N_EDGES)}, set())


@given(st.lists(st.one_of(st.floats(0.0, 1e30), st.sampled_from([0.0, 1e-300, np.inf, 2.5])),
                min_size=1, max_size=300),
       st.lists(st.integers(0, 300), min_size=0, max_size=4), st.floats(0.0, 1.0))
def test_kth_smallest_key_is_what_partition_gives(costs, cuts, quantile):
    """Over the keys of some runs of rows (gaps between them unread), the k-th smallest
    is np.partition's, for costs across many octaves, repeated ones, zero and infinity."""
    keys = (np.array(costs, np.float64) + 0.0).view(np.int64)  # -0.0 as cost_key makes it
    n = keys.size
    edges = sorted({0, n, *(min(c, n) for c in cuts)})
    # Each run is followed by a gap of garbage rows.
    run_start, run_end, rows = [], [], []
    for low, high in zip(edges[:-1], edges[1:], strict=True):
        run_start.append(len(rows))
        rows.extend(keys[low:high])
        run_end.append(len(rows))
        rows.extend([-1, 2**62])
    entries = np.zeros((len(rows), 3), np.int64)
    entries[:, 0] = rows
    k = int(quantile * (n - 1))
    expected = np.partition(keys.copy(), k)[k]
    assert kth_smallest_key(entries, np.array(run_start, np.int64),
                            np.array(run_end, np.int64), k) == expected

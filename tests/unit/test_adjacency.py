"""Vertex -> face lists (qem_core/_kernels/adjacency.py): the parallel counting sort."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from qem_core._kernels.adjacency import fill_face_lists, make_face_lists


@st.composite
def items(draw):
    """(items (m, c) int32, alive (m,) uint8, n): faces (c = 3) or pairs (c = 2)."""
    n = draw(st.integers(1, 12))
    corners = draw(st.sampled_from([2, 3]))
    m = draw(st.integers(0, 40))
    flat = draw(st.lists(st.integers(0, n - 1), min_size=m * corners, max_size=m * corners))
    alive = draw(st.lists(st.integers(0, 1), min_size=m, max_size=m))
    return (np.array(flat, np.int32).reshape(m, corners), np.array(alive, np.uint8), n)


def runs(start, count, pool):
    return [pool[start[v]:start[v] + count[v]].tolist() for v in range(start.size)]


@given(items(), st.integers(1, 6))
def test_runs_list_each_vertexs_live_items_in_order_whatever_the_chunks(drawn, n_chunks):
    faces, alive, n = drawn
    expected = [[] for _ in range(n)]
    for f in range(faces.shape[0]):
        if alive[f]:
            for v in faces[f]:
                expected[v].append(f)
    start, count = np.zeros(n, np.int64), np.zeros(n, np.int32)
    pool = np.full(faces.size + 1, -7, np.int32)
    used = fill_face_lists(faces, alive, start, count, pool, n_chunks)
    assert runs(start, count, pool) == expected
    assert used == sum(len(run) for run in expected)
    assert np.all(start == np.concatenate([[0], np.cumsum(count)[:-1]]))
    lists = make_face_lists(faces, n, capacity=faces.size + 1, alive=alive)
    assert runs(lists.start, lists.count, lists.pool) == expected
    assert int(lists.used[0]) == used

"""May (a, b) be contracted without changing the topological type?

Edelsbrunner's link condition Lk a ∩ Lk b = Lk ab, checked on the complex extended by a
dummy vertex ω joined to every border vertex, which yields the border rules:

    vertices: every common neighbour x of a and b spans a face abx      (no pinched neck)
    edges:    no edge xy lies in both links: faces axy and bxy together  (no collapse of a
              tetrahedron to a double triangle)
    ω:        a and b both on the border only if ab is a border edge     (no pinching two
              border loops together)
    ωx:       no x joined to both a and b by border edges                (no closing a
              3-edge hole, no single triangle shrinking to an edge)

The scratch arrays of ``Neighbourhood`` are filled by ``gather``: how many live faces each
neighbour shares with a and with b (2 interior edge, 1 border edge, 3+ non-manifold).
They are stamped with a generation, so nothing is cleared between calls. Kernels take the
arrays one by one: passing a tuple of arrays to a small jitted function costs reference
counting on every member, which dominated the loop.
"""

from typing import NamedTuple

import numba
import numpy as np

REFUSE_NONE = 0
REFUSE_LINK = 1
REFUSE_BORDER = 2
REFUSE_NOT_EDGE = 3


class Neighbourhood(NamedTuple):
    tag_a: np.ndarray  # (n,) int64: generation when count_a[x] was set
    count_a: np.ndarray  # (n,) int64: live faces containing edge a-x
    tag_b: np.ndarray
    count_b: np.ndarray
    tag_opposite: np.ndarray  # (n,) int64: x spans a face abx in this generation
    tag_scratch: np.ndarray  # (n,) int64: free for callers (dedupe of neighbours)
    generation: np.ndarray  # (1,) int64
    retry: np.ndarray  # (n + 1,) int32: scratch list of vertices


def make_neighbourhood(n_vertices: int) -> Neighbourhood:
    return Neighbourhood(
        *(np.full(n_vertices, -1, np.int64) for _ in range(6)),
        np.zeros(1, np.int64),
        np.full(n_vertices + 1, -1, np.int32),
    )


def _count_edges(faces, face_alive, start, count, pool, v, tag, edge_count, g):
    """edge_count[x] = live faces containing edge v-x, for each neighbour x of v."""
    s = start[v]
    for i in range(count[v]):
        f = pool[s + i]
        if not face_alive[f]:
            continue
        for k in range(3):
            x = faces[f, k]
            if x == v:
                continue
            if tag[x] != g:
                tag[x] = g
                edge_count[x] = 0
            edge_count[x] += 1


count_edges = numba.njit(cache=True)(_count_edges)


def _gather(faces, face_alive, start, count, pool, a, b, tag_a, count_a, tag_b, count_b,
            tag_opposite, g):
    """Fill the neighbourhood of a and b for generation g."""
    count_edges(faces, face_alive, start, count, pool, a, tag_a, count_a, g)
    count_edges(faces, face_alive, start, count, pool, b, tag_b, count_b, g)
    s = start[a]
    for i in range(count[a]):
        f = pool[s + i]
        if not face_alive[f]:
            continue
        f0, f1, f2 = faces[f, 0], faces[f, 1], faces[f, 2]
        if f0 == b or f1 == b or f2 == b:
            tag_opposite[f0 + f1 + f2 - a - b] = g


gather = numba.njit(cache=True)(_gather)


def _is_border(faces, face_alive, start, count, pool, v, tag, edge_count, g):
    s = start[v]
    for i in range(count[v]):
        f = pool[s + i]
        if not face_alive[f]:
            continue
        for k in range(3):
            x = faces[f, k]
            if x != v and tag[x] == g and edge_count[x] == 1:
                return True
    return False


is_border = numba.njit(cache=True)(_is_border)


def _has_face_on_opposites(faces, face_alive, start, count, pool, v, other, tag_opposite, g):
    """Does v have a live face vxy (not containing ``other``) with x, y both opposite?"""
    s = start[v]
    for i in range(count[v]):
        f = pool[s + i]
        if not face_alive[f]:
            continue
        n_opposite = 0
        has_other = False
        for k in range(3):
            x = faces[f, k]
            if x == other:
                has_other = True
            elif x != v and tag_opposite[x] == g:
                n_opposite += 1
        if not has_other and n_opposite == 2:
            return True
    return False


has_face_on_opposites = numba.njit(cache=True)(_has_face_on_opposites)


def _check_link(faces, face_alive, start, count, pool, a, b, tag_a, count_a, tag_b, count_b,
                tag_opposite, g):
    """One of the REFUSE_* codes for contracting a and b (gathered in generation g)."""
    if tag_a[b] != g:
        return REFUSE_NOT_EDGE
    # Vertices of Lk a ∩ Lk b must be opposite vertices of faces abx.
    s = start[b]
    for i in range(count[b]):
        f = pool[s + i]
        if not face_alive[f]:
            continue
        for k in range(3):
            x = faces[f, k]
            if x != a and x != b and tag_a[x] == g and tag_opposite[x] != g:
                return REFUSE_LINK
    # Edges of Lk a ∩ Lk b: faces axy and bxy over two opposite vertices x, y.
    if has_face_on_opposites(faces, face_alive, start, count, pool, a, b, tag_opposite, g) and (
        has_face_on_opposites(faces, face_alive, start, count, pool, b, a, tag_opposite, g)
    ):
        return REFUSE_LINK
    ab_border = count_a[b] == 1
    a_border = is_border(faces, face_alive, start, count, pool, a, tag_a, count_a, g)
    b_border = is_border(faces, face_alive, start, count, pool, b, tag_b, count_b, g)
    if a_border and b_border and not ab_border:
        return REFUSE_BORDER
    if a_border and b_border:
        # ωx in both links: x joined to a and to b by border edges.
        s = start[b]
        for i in range(count[b]):
            f = pool[s + i]
            if not face_alive[f]:
                continue
            for k in range(3):
                x = faces[f, k]
                if x == a or x == b:
                    continue
                if count_b[x] == 1 and tag_a[x] == g and count_a[x] == 1:
                    return REFUSE_BORDER
    return REFUSE_NONE


check_link = numba.njit(cache=True)(_check_link)

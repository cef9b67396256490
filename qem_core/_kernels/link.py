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

The scratch rows of ``Neighbourhood.near`` are filled by ``gather``: how many live faces
each neighbour x shares with a and with b (2 interior edge, 1 border edge, 3+
non-manifold), and the ids of edges a-x and b-x (the contraction merges and renames edges
by these ids). Values are stamped with a generation, so nothing is cleared between calls.
All of a vertex's scratch values sit in one 32-byte row: a contraction visits a dozen
random vertices, and one row is one cache miss where eight separate arrays were eight.
``gather`` also decides, on its one pass over each end's faces, the parts of the rules
that need no second look (see the FACT_* bits); ``check_link`` revisits faces only for
the rare rest.
"""

from typing import NamedTuple

import numba
import numpy as np

from .memory import borrowing_kernel

REFUSE_NONE = 0
REFUSE_LINK = 1
REFUSE_BORDER = 2
REFUSE_NOT_EDGE = 3

# Columns of ``near``. A count or edge id is valid only while its tag holds the current
# generation; ``A`` columns describe edge a-x, ``B`` columns edge b-x.
NEAR_TAG_A = 0
NEAR_COUNT_A = 1
NEAR_EDGE_A = 2
NEAR_TAG_B = 3
NEAR_COUNT_B = 4
NEAR_EDGE_B = 5
NEAR_OPPOSITE = 6  # tag: x spans a face abx
NEAR_SCRATCH = 7  # tag free for callers (dedupe of neighbours)
NEAR_COLUMNS = 8
# Generations are int32 in ``near``; the driver restarts them well before they overflow.
MAX_GENERATION = 1 << 30
# ``Neighbourhood.part`` of a vertex no loop of a parallel round may contract (rounds.py).
PART_FROZEN = 255


class Neighbourhood(NamedTuple):
    near: np.ndarray  # (n, 8) int32, columns NEAR_*
    generation: np.ndarray  # (1,) int64, the last generation handed out
    retry: np.ndarray  # (n + 1,) int32: scratch list of vertices
    # (n,) uint8: the part of a parallel round each vertex is in (rounds.py), PART_FROZEN
    # for the band between parts; a loop only puts edges within its vertex's part in its
    # heap. All 0 outside rounds.
    part: np.ndarray


def make_neighbourhood(n_vertices: int) -> Neighbourhood:
    return Neighbourhood(np.full((n_vertices, NEAR_COLUMNS), -1, np.int32),
                         np.zeros(1, np.int64), np.full(n_vertices + 1, -1, np.int32),
                         np.zeros(n_vertices, np.uint8))


def restart_generations(hood: Neighbourhood) -> None:
    """Clear the tags and start generations again from 0 (before they overflow int32)."""
    if hood.generation[0] > MAX_GENERATION:
        hood.near[:] = -1
        hood.generation[0] = 0


# Facts ``gather`` finds on its way, as bits of the value it returns.
FACT_A_BORDER = 1  # a has a border edge (a neighbour sharing one face with it)
FACT_B_BORDER = 2
FACT_COMMON_NOT_OPPOSITE = 4  # a common neighbour of a and b spans no face abx
FACT_B_FACE_ON_OPPOSITES = 8  # a face bxy without a over two opposite vertices x, y


def _count_edges(faces, face_edge, start, count, pool, v, other, near, column, g):
    """For each neighbour x of v: near[x, column + 1] = live faces containing edge v-x,
    near[x, column + 2] = that edge's id; near[x, column] = g marks them valid.

    Side a (column NEAR_TAG_A, other = b) also tags the opposite vertex of each face abx
    (NEAR_OPPOSITE). Side b, counted second, meets every common neighbour and so checks
    the vertex part of the link condition on the way. Returns the FACT_* bits found.
    """
    side_b = column == NEAR_TAG_B
    n_single = 0  # neighbours sharing exactly one face with v so far
    facts = 0
    s = start[v]
    for i in range(count[v]):
        f = pool[s + i]
        has_other = False
        n_opposite = 0
        for k in range(3):
            x = faces[f, k]
            if x == v:
                continue
            if near[x, column] != g:
                near[x, column] = g
                near[x, column + 1] = 1
                n_single += 1
            else:
                near[x, column + 1] += 1
                if near[x, column + 1] == 2:
                    n_single -= 1
            # Side k runs from corner k to k + 1: it is x-v if v follows x, else v-x is
            # the side that ends at x.
            if faces[f, (k + 1) % 3] == v:
                near[x, column + 2] = face_edge[f, k]
            else:
                near[x, column + 2] = face_edge[f, (k + 2) % 3]
            if x == other:
                has_other = True
            elif side_b and near[x, NEAR_TAG_A] == g:
                if near[x, NEAR_OPPOSITE] == g:
                    n_opposite += 1
                else:
                    facts |= FACT_COMMON_NOT_OPPOSITE
        if side_b:
            if not has_other and n_opposite == 2:
                facts |= FACT_B_FACE_ON_OPPOSITES
        elif has_other:
            near[faces[f, 0] + faces[f, 1] + faces[f, 2] - v - other, NEAR_OPPOSITE] = g
    if n_single > 0:
        facts |= FACT_B_BORDER if side_b else FACT_A_BORDER
    return facts


count_edges = numba.njit(cache=True, inline="always")(_count_edges)


def _gather(faces, face_edge, start, count, pool, a, b, near, g):
    """Fill the neighbourhood of a and b for generation g; returns the FACT_* bits that
    ``check_link`` needs (one pass over the faces of each end, instead of one per rule)."""
    facts = count_edges(faces, face_edge, start, count, pool, a, b, near, NEAR_TAG_A, g)
    return facts | count_edges(faces, face_edge, start, count, pool, b, a, near, NEAR_TAG_B, g)


gather = borrowing_kernel(_gather)


def _has_face_on_opposites(faces, start, count, pool, v, other, near, g):
    """Does v have a live face vxy (not containing ``other``) with x, y both opposite?"""
    s = start[v]
    for i in range(count[v]):
        f = pool[s + i]
        n_opposite = 0
        has_other = False
        for k in range(3):
            x = faces[f, k]
            if x == other:
                has_other = True
            elif x != v and near[x, NEAR_OPPOSITE] == g:
                n_opposite += 1
        if not has_other and n_opposite == 2:
            return True
    return False


has_face_on_opposites = numba.njit(cache=True, inline="always")(_has_face_on_opposites)


def _check_link(faces, start, count, pool, a, b, near, g, facts):
    """One of the REFUSE_* codes for contracting a and b (gathered in generation g, with
    the FACT_* bits ``gather`` returned)."""
    if near[b, NEAR_TAG_A] != g:
        return REFUSE_NOT_EDGE
    # Vertices of Lk a ∩ Lk b must be opposite vertices of faces abx.
    if facts & FACT_COMMON_NOT_OPPOSITE:
        return REFUSE_LINK
    # Edges of Lk a ∩ Lk b: faces axy and bxy over two opposite vertices x, y.
    if facts & FACT_B_FACE_ON_OPPOSITES and has_face_on_opposites(
        faces, start, count, pool, a, b, near, g
    ):
        return REFUSE_LINK
    if facts & FACT_A_BORDER and facts & FACT_B_BORDER:
        # Both on the border: only along a border edge ab (ω is in both links)...
        if near[b, NEAR_COUNT_A] != 1:
            return REFUSE_BORDER
        # ...and no ωx in both links: x joined to a and to b by border edges.
        s = start[b]
        for i in range(count[b]):
            f = pool[s + i]
            for k in range(3):
                x = faces[f, k]
                if x == a or x == b:
                    continue
                if (near[x, NEAR_COUNT_B] == 1 and near[x, NEAR_TAG_A] == g
                        and near[x, NEAR_COUNT_A] == 1):
                    return REFUSE_BORDER
    return REFUSE_NONE


check_link = borrowing_kernel(_check_link)

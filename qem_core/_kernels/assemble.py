"""The contraction record reversed into levels: the arrays of the progressive mesh.

Contraction j of J retires slot b_j; split k = J-1-j brings it back. Each kernel is one
pass over the record (numpy's chain of fancy-indexed gathers, reversals and cumulative
sums took 0.3 s on a 435k-contraction record):

    level_of_slot   survivors in slot order 0..n_base-1, then b_{J-1}, b_{J-2}, ..., b_0
    face_order      alive faces in id order, then the faces killed by contraction J-1
                    (born at split 0), then by J-2, ...; each run in its recorded order
    level_of_face   the inverse of face_order

A born face's corners are then turned to begin at its third corner (the one not s or t
of the split that brings it), and each split's faces put in one order (those going from s
to t first): choices the input's accidents made, which the split stream would code.
"""

import numba


def _number_slots(vertex_alive, retired, n_contractions, level_of_slot):
    """level_of_slot (n,) int32 (-1 filled), out; returns the number of survivors."""
    n_base = 0
    for v in range(vertex_alive.shape[0]):
        if vertex_alive[v]:
            level_of_slot[v] = n_base
            n_base += 1
    for j in range(n_contractions):
        level_of_slot[retired[j]] = n_base + n_contractions - 1 - j
    return n_base


number_slots = numba.njit(cache=True)(_number_slots)


def _order_faces(face_alive, killed, killed_end, n_contractions, face_order, level_of_face):
    """face_order (alive + killed,) int64 and level_of_face (m,) int64, out (see the
    module docstring); returns the number of alive (base) faces."""
    n = 0
    for f in range(face_alive.shape[0]):
        if face_alive[f]:
            face_order[n] = f
            n += 1
    n_base = n
    for j in range(n_contractions - 1, -1, -1):
        for i in range(killed_end[j - 1] if j > 0 else 0, killed_end[j]):
            face_order[n] = killed[i]
            n += 1
    for i in range(n):
        level_of_face[face_order[i]] = i
    return n_base


order_faces = numba.njit(cache=True)(_order_faces)


def _level_corners(faces, level_of_face, level_of_slot, out):
    """out[level_of_face[f]] = level numbers of the corners of face f (as the run left
    it), in parallel. Faces are read in id order, whose corners lie close together in
    level_of_slot: gathering them in level order was twice as slow."""
    for f in numba.prange(faces.shape[0]):
        row = level_of_face[f]
        if row >= 0:
            for k in range(3):
                out[row, k] = level_of_slot[faces[f, k]]


level_corners = numba.njit(cache=True, parallel=True)(_level_corners)


def _gather_reversed_runs(values, ends, n_runs, lookup, out, offsets):
    """out = lookup[values] with the runs ending at ends[:n_runs] in reverse order (each
    run's own order kept); offsets (n_runs + 1,) out: where each reversed run starts.

    The offsets first, then the runs in parallel, each written at its own offset (each
    look-up waits for memory: one thread took 56 ms for the dragon's relabelled faces)."""
    offsets[0] = 0
    for k in range(n_runs):
        j = n_runs - 1 - k
        offsets[k + 1] = offsets[k] + ends[j] - (ends[j - 1] if j > 0 else 0)
    n_chunks = 64
    for chunk in numba.prange(n_chunks):
        for k in range(chunk * n_runs // n_chunks, (chunk + 1) * n_runs // n_chunks):
            j = n_runs - 1 - k
            cursor = offsets[k]
            for i in range(ends[j - 1] if j > 0 else 0, ends[j]):
                out[cursor] = lookup[values[i]]
                cursor += 1


gather_reversed_runs = numba.njit(cache=True, parallel=True)(_gather_reversed_runs)


def _fill_splits(survivor, position_a, position_b, cost, killed_end, n_contractions,
                 level_of_slot, n_base_faces, split_vertex, split_positions, split_cost,
                 level_faces):
    """Split k from contraction J-1-k: its vertex s (the survivor's level number), the
    positions of s and t before the contraction, its cost, and level_faces (J + 1,), the
    face count of each level (split k appends the faces contraction J-1-k killed). The
    splits are each their own (in parallel); the face counts add up (one pass)."""
    for k in numba.prange(n_contractions):
        j = n_contractions - 1 - k
        split_vertex[k] = level_of_slot[survivor[j]]
        for d in range(3):
            split_positions[k, 0, d] = position_a[j, d]
            split_positions[k, 1, d] = position_b[j, d]
        split_cost[k] = cost[j]
    level_faces[0] = n_base_faces
    for k in range(n_contractions):
        j = n_contractions - 1 - k
        born = killed_end[j] - (killed_end[j - 1] if j > 0 else 0)
        level_faces[k + 1] = level_faces[k] + born


fill_splits = numba.njit(cache=True, parallel=True)(_fill_splits)


@numba.njit(cache=True, inline="always")
def _orientation(u, w, s, t):
    """0 when a face's corners u, w (in its order) are s then t, 1 for t then s, else 2."""
    return 0 if (u == s and w == t) else (1 if (u == t and w == s) else 2)


def _turn_born_faces(face_corners, level_faces, split_vertex, n_base, turns, source):
    """Turn each face born at a split (rows level_faces[0]: on) in place so that its
    corner other than the split's s and t comes first; turns (F,) int8 receives by how
    many places each row turned (0 for base faces, and for a face without both s and
    t). Then source (F,) int64 receives the row each row takes so that each split's faces
    come as (x, s, t) first, then (x, t, s), then any other, each kind in the order it
    had (base rows stay).

    Why: which corner of a face is its first, and in which order a split lists its
    faces, are the input file's and the run's accidents, and the split stream codes them
    (a face's code names its rotation and orientation, against the face before it: 0.53 B
    of dragon's 6.36 B a split); with every face turned and listed alike those codes cost
    next to nothing. A turn keeps the face's orientation and its corners."""
    for f in range(level_faces[0]):
        source[f] = f
    for k in numba.prange(split_vertex.shape[0]):
        s = split_vertex[k]
        t = n_base + k
        for f in range(level_faces[k], level_faces[k + 1]):
            a = face_corners[f, 0]
            b = face_corners[f, 1]
            c = face_corners[f, 2]
            turn = 0  # also when (b, c) are s and t: a comes first already
            if _orientation(b, c, s, t) < 2:
                pass
            elif _orientation(c, a, s, t) < 2:
                turn = 1
                face_corners[f, 0], face_corners[f, 1], face_corners[f, 2] = b, c, a
            elif _orientation(a, b, s, t) < 2:
                turn = 2
                face_corners[f, 0], face_corners[f, 1], face_corners[f, 2] = c, a, b
            turns[f] = turn
        at = level_faces[k]
        for kind in range(3):
            for f in range(level_faces[k], level_faces[k + 1]):
                if _orientation(face_corners[f, 1], face_corners[f, 2], s, t) == kind:
                    source[at] = f
                    at += 1


turn_born_faces = numba.njit(cache=True, parallel=True)(_turn_born_faces)

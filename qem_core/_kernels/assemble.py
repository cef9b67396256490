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


def _third_corner_first(face_corners, level_faces, split_vertex, n_base, turns):
    """Turn each face born at a split (rows level_faces[0]: on) so that its corner other
    than the split's s and t comes first, in place; turns (F,) int8 receives by how many
    places each row turned (0 for base faces, and for a face without both s and t).

    Why: which corner of a face is its first is the input file's accident, and the split
    stream codes it (log2 3 bits a face: 0.40 B of dragon's 6.36 B a split); with every
    face turned alike the stream's adaptive codes of it cost next to nothing. A turn
    keeps the face's orientation and its corners."""
    for k in numba.prange(split_vertex.shape[0]):
        s = split_vertex[k]
        t = n_base + k
        for f in range(level_faces[k], level_faces[k + 1]):
            a = face_corners[f, 0]
            b = face_corners[f, 1]
            c = face_corners[f, 2]
            turn = 0
            if (b == s and c == t) or (b == t and c == s):
                turn = 0
            elif (c == s and a == t) or (c == t and a == s):
                turn = 1
            elif (a == s and b == t) or (a == t and b == s):
                turn = 2
            turns[f] = turn
            if turn == 1:
                face_corners[f, 0], face_corners[f, 1], face_corners[f, 2] = b, c, a
            elif turn == 2:
                face_corners[f, 0], face_corners[f, 1], face_corners[f, 2] = c, a, b


third_corner_first = numba.njit(cache=True, parallel=True)(_third_corner_first)


def _forward_faces_first(face_corners, level_faces, split_vertex, n_base, source):
    """source (F,) int64, out: the row each row takes so that each split's faces
    (turned by `third_corner_first`) come as (x, s, t) first, then (x, t, s), then any
    other, each kind in the order it had (base rows stay).

    Why: the split stream codes each face's orientation against the one before it, and
    in the order the run killed them the two kinds alternate at random (0.12 B a split
    of bunny's 7.74; ordered, 0.01)."""
    for f in range(level_faces[0]):
        source[f] = f
    for k in numba.prange(split_vertex.shape[0]):
        s = split_vertex[k]
        t = n_base + k
        at = level_faces[k]
        for kind in range(3):
            for f in range(level_faces[k], level_faces[k + 1]):
                b = face_corners[f, 1]
                c = face_corners[f, 2]
                if kind == (0 if (b == s and c == t) else (1 if (b == t and c == s) else 2)):
                    source[at] = f
                    at += 1


forward_faces_first = numba.njit(cache=True, parallel=True)(_forward_faces_first)

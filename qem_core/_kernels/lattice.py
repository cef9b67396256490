"""Kernels that put the progressive mesh's inner vertices on the split stream's tangent
lattice (``stream_coding.lattice_step``; the Python side is ``qem_core/lattice.py``).

A vertex that splits again (an *inner* vertex: a node of the contraction forest above
its leaves) sits at its contraction's quadric optimum, which the stream codes as the
mid of its two children against it: one value off the surface, two along it. Those two
along the surface cost about log2 of the edge's length in bits each, and moving the
vertex along the surface costs its level little error. So each inner vertex is moved to
the point nearest its optimum, by the quadric's own measure, whose two tangent values
are multiples of the lattice step.

The pass runs over the splits from the last to the first (the forest from its leaves
up): when split i is placed, every vertex of level i but s has its final position (it
is a leaf, or it splits after i and was placed before), so the frame the stream codes
split i in is known, and the children of split i are final.

Positions are kept by *slot*, one per vertex version: base vertex v is slot v, the two
ends of split i (s after it, and t) are slots n_base + 2 i and n_base + 2 i + 1 (the
rows of base_vertices, then of split_positions). ``split_fans`` replays the levels once
and records what the others need: for each split, the slot s had before it and its fan
(the faces at s, their other corners as slots), and each face's corners as slots when
it is born. Every change of a face's corners is one of those: a face changes only when
a corner splits (it is then in that corner's fan) or when it is born.
"""

import numba
import numpy as np

from . import range_coder as rc
from .quadrics import QUADRIC_SIZE, evaluate
from .stream_coding import (
    _DIFF_BITS,
    _NORMAL,
    _NORMAL_BITS,
    SPLIT_CONTEXT,
    _append_face,
    _mid_frame,
    _relabel,
    _shift_to,
    lattice_step,
    link_corners,
    mid_third,
)

# Helpers that allocate nothing: no reference counting, so a call costs no atomics per
# array argument (as stream_coding's kernels); the scan of every face's states calls one
# four million times on dragon.
_helper = numba.njit(cache=True, nogil=True, _nrt=False)


@numba.njit(cache=True, nogil=True)
def split_fans(faces, n_faces, n_vertices, split_vertex, n_from, new_faces, new_face_counts,
               relabel_offsets, relabel_faces):
    """Replay the levels from the base (faces: room for every face of the last level,
    its first n_faces those of the first) and record, as slots:

    - parent (k,): the slot of s before each split;
    - fan_offsets (k + 1,), fans (m, 4) int32: for each corner of s in the level it
      splits, the face (s, u, w): u's slot, w's slot, the face, and 1 if the split
      relabels it to t (0: it keeps s, at s's new slot);
    - born (new faces, 4) int32: each new face's three corners' slots and the face.

    Returns a parent of length 0 if a relabelled face has no corner s (an inconsistent
    run)."""
    k = split_vertex.shape[0]
    head = np.empty(n_vertices, np.int32)
    nxt = np.empty(3 * faces.shape[0], np.int32)
    link_corners(faces, n_faces, head, nxt)
    slot_of = np.empty(n_vertices, np.int64)
    for v in range(n_from):
        slot_of[v] = v
    parent = np.empty(k, np.int64)
    offsets = np.zeros(k + 1, np.int64)
    fans = np.empty((max(16, 8 * k), 4), np.int32)
    born = np.empty((new_faces.shape[0], 4), np.int32)
    used = 0
    face = n_faces
    new = 0
    for i in range(k):
        s = split_vertex[i]
        t = n_from + i
        parent[i] = slot_of[s]
        first = used
        c = head[s]
        while c != -1:
            if used == fans.shape[0]:
                grown = np.empty((2 * used, 4), np.int32)
                grown[:used] = fans[:used]
                fans = grown
            f = c // 3
            j = c % 3
            fans[used, 0] = slot_of[faces[f, (j + 1) % 3]]
            fans[used, 1] = slot_of[faces[f, (j + 2) % 3]]
            fans[used, 2] = f
            fans[used, 3] = 0
            used += 1
            c = nxt[c]
        offsets[i + 1] = used
        for r in range(relabel_offsets[i], relabel_offsets[i + 1]):
            if not _relabel(faces, head, nxt, relabel_faces[r], s, t):
                return np.zeros(0, np.int64), offsets, fans[:0], born[:0]
        for r in range(first, used):
            f = fans[r, 2]
            fans[r, 3] = faces[f, 0] == t or faces[f, 1] == t or faces[f, 2] == t
        slot_of[s] = n_from + 2 * i
        slot_of[t] = n_from + 2 * i + 1
        for r in range(new, new + new_face_counts[i]):
            _append_face(faces, head, nxt, face, new_faces[r, 0], new_faces[r, 1], new_faces[r, 2])
            for j in range(3):
                born[r, j] = slot_of[new_faces[r, j]]
            born[r, 3] = face
            face += 1
        new += new_face_counts[i]
    return parent, offsets, fans[:used], born


@_helper
def _fan_normal(fans, lo, hi, q, centre, context):
    """The ring's normal as the stream encoder computes it (``_ring_shape``) for s at
    ``centre``, into context[_NORMAL:_NORMAL + 3]: the sum over the fan of the cross
    products of the two corners' offsets from s, each shifted to _DIFF_BITS bits, the
    sum shifted to _NORMAL_BITS. q: the positions by slot. Returns the largest offset."""
    big = 0
    for r in range(lo, hi):
        for side in range(2):
            for d in range(3):
                big = max(big, abs(q[fans[r, side], d] - centre[d]))
    shift = max(0, rc.bit_length(big) - _DIFF_BITS)
    nx = 0
    ny = 0
    nz = 0
    for r in range(lo, hi):
        u = fans[r, 0]
        w = fans[r, 1]
        ux = (q[u, 0] - centre[0]) >> shift
        uy = (q[u, 1] - centre[1]) >> shift
        uz = (q[u, 2] - centre[2]) >> shift
        wx = (q[w, 0] - centre[0]) >> shift
        wy = (q[w, 1] - centre[1]) >> shift
        wz = (q[w, 2] - centre[2]) >> shift
        nx += uy * wz - uz * wy
        ny += uz * wx - ux * wz
        nz += ux * wy - uy * wx
    context[_NORMAL] = nx
    context[_NORMAL + 1] = ny
    context[_NORMAL + 2] = nz
    _shift_to(context[_NORMAL : _NORMAL + 3], _NORMAL_BITS)
    return big


@_helper
def _cross_into(a, q, b, c, ratio, out):
    """(q[b] - a) x (q[c] - a), each axis scaled by ratio, into out."""
    ux = (q[b, 0] - a[0]) * ratio[0]
    uy = (q[b, 1] - a[1]) * ratio[1]
    uz = (q[b, 2] - a[2]) * ratio[2]
    wx = (q[c, 0] - a[0]) * ratio[0]
    wy = (q[c, 1] - a[1]) * ratio[1]
    wz = (q[c, 2] - a[2]) * ratio[2]
    out[0] = uy * wz - uz * wy
    out[1] = uz * wx - ux * wz
    out[2] = ux * wy - uy * wx


@_helper
def _turns_a_face(fans, lo, hi, q, old, candidate, ratio, normals, min_cos, turned, before):
    """Whether s moved from old to candidate turns a face of its fan by more than
    acos(min_cos), or to face away from the full level's face it comes from (turned,
    before: (3,) scratch)."""
    for r in range(lo, hi):
        u, w, face = fans[r, 0], fans[r, 1], fans[r, 2]
        _cross_into(candidate, q, u, w, ratio, turned)
        _cross_into(old, q, u, w, ratio, before)
        along = (turned[0] * normals[face, 0] + turned[1] * normals[face, 1]
                 + turned[2] * normals[face, 2])
        if along <= 0.0:
            return True
        dot = turned[0] * before[0] + turned[1] * before[1] + turned[2] * before[2]
        sizes = np.sqrt((turned[0] ** 2 + turned[1] ** 2 + turned[2] ** 2)
                        * (before[0] ** 2 + before[1] ** 2 + before[2] ** 2))
        if dot < min_cos * sizes:
            return True
    return False


@_helper
def _closed(fans, lo, hi):
    """Whether the fan fans[lo:hi] closes: each face's first other corner is some face's
    second (the faces around s go all the way round)."""
    for r in range(lo, hi):
        found = False
        for other in range(lo, hi):
            found |= fans[other, 1] == fans[r, 0]
        if not found:
            return False
    return True


@_helper
def _in_grid_units(quadric, ratio, out):
    """The quadric (quadrics.py's row) over grid coordinates q of one over q * ratio."""
    at = 0
    for i in range(3):
        for j in range(i, 3):
            out[at] = quadric[at] * ratio[i] * ratio[j]
            at += 1
    for i in range(3):
        out[6 + i] = quadric[6 + i] * ratio[i]
    out[9] = quadric[9]


@_helper
def _entry(quadric, i, j):
    """A[i, j] of the symmetric A stored as xx, xy, xz, yy, yz, zz."""
    if i > j:
        i, j = j, i
    return quadric[3 * i + j - (i * (i + 1)) // 2]


@numba.njit(cache=True, nogil=True)
def place_inner_vertices(q, exact, split_vertex, parent, fan_offsets, fans, quadrics, normals,
                         ratio, q_max, tolerance, min_cos):
    """Move the inner vertices of a progressive mesh onto the tangent lattice, in place.

    q (slots, 3) int64: the grid positions by slot, as the stream codes them; exact
    (slots, 3): the same before rounding, in grid units (the build's optima);
    split_vertex (k,); parent, fan_offsets, fans: ``split_fans``; quadrics (n_full,
    QUADRIC_SIZE) and normals (faces, 3): the full level's vertex quadrics and unit face
    normals (``quadrics.fill_face_quadrics``) in coordinates q * ratio (ratio (3,): the
    grid's step per axis over its mean). A vertex's quadric is the sum of its leaves';
    it moves to the lattice point of least quadric error near it, if that error is at
    most (1 + tolerance) times the optimum's (at ``exact``: the grid's own rounding
    counts, so a level finer than the grid keeps its optima) and no face of its fan
    turns by more than acos(min_cos) or away from the full level's face it comes from.
    A vertex stays if it is on the grid's border on some axis (the grid is the box of
    every position: moving it could shrink the box), on the mesh's border (its fan is
    open: the leaves' planes do not hold the border), or if a move would change the
    frame its split is coded in."""
    k = split_vertex.shape[0]
    n_base = q.shape[0] - 2 * k
    totals = quadrics.copy()
    quadric = np.zeros(QUADRIC_SIZE)
    context = np.zeros(SPLIT_CONTEXT, np.int64)
    moved_context = np.zeros(SPLIT_CONTEXT, np.int64)
    edge = np.zeros(3, np.int64)
    mid = np.zeros(3, np.int64)
    trial = np.zeros(3, np.int64)
    axes = np.zeros(3, np.int64)
    moved_axes = np.zeros(3, np.int64)
    binormal = np.zeros(3, np.int64)
    moved_binormal = np.zeros(3, np.int64)
    old = np.zeros(3, np.int64)
    c = np.zeros(3, np.int64)  # the candidate being checked
    candidates = np.zeros((8, 3), np.int64)
    costs = np.zeros(8)
    turned = np.zeros(3)
    before = np.zeros(3)
    for i in range(k - 1, -1, -1):
        s = split_vertex[i]
        t = n_base + i
        for j in range(QUADRIC_SIZE):
            totals[s, j] += totals[t, j]  # the parent's: its leaves' planes
        slot = parent[i]
        at_border = False
        an_end_stayed = False
        for d in range(3):
            old[d] = q[slot, d]
            a = q[n_base + 2 * i, d]
            b = q[n_base + 2 * i + 1, d]
            edge[d] = b - a
            mid[d] = ((a + b) >> 1) - old[d]
            at_border |= old[d] == 0 or old[d] == q_max
        for side in range(2):
            same = True
            for d in range(3):
                same &= q[n_base + 2 * i + side, d] == old[d]
            an_end_stayed |= same
        step = lattice_step(edge)
        if at_border or an_end_stayed or step == 1:
            continue
        lo, hi = fan_offsets[i], fan_offsets[i + 1]
        if not _closed(fans, lo, hi):
            continue
        big = _fan_normal(fans, lo, hi, q, old, context)
        if not _mid_frame(context, edge, axes, binormal):
            continue
        _in_grid_units(totals[s], ratio, quadric)
        a_axis, b_axis, k_axis = axes[0], axes[1], axes[2]
        # A little of the identity, so that a flat quadric still picks the nearest point.
        eps = 1e-9 * (quadric[0] + quadric[3] + quadric[5]) + 1e-300
        optimum = evaluate(quadric, exact[slot, 0], exact[slot, 1], exact[slot, 2])
        bound = (1.0 + tolerance) * optimum
        abb = _entry(quadric, b_axis, b_axis) + eps
        abk = _entry(quadric, b_axis, k_axis)
        akk = _entry(quadric, k_axis, k_axis) + eps
        aab = _entry(quadric, a_axis, b_axis)
        aak = _entry(quadric, a_axis, k_axis)
        det = abb * akk - abk * abk
        # delta = P' - P = mid - mid'. With the first value on the lattice, the other
        # two minimise the quadric (a 2 x 2 solve); the integers and lattice values
        # around that optimum are the candidates, tried from the least error up.
        n_candidates = 0
        first = mid[a_axis] // step
        for ua in range(first, first + 2):
            trial[a_axis] = ua * step
            da = float(mid[a_axis] - trial[a_axis])
            db = -da * (aab * akk - aak * abk) / det if det > 0 else 0.0
            near_b = int(np.floor(mid[b_axis] - db))
            for mb in range(near_b, near_b + 2):
                trial[b_axis] = mb
                db = float(mid[b_axis] - mb)
                dk = -(aak * da + abk * db) / akk
                against = mid_third(axes, binormal, trial)
                near_k = int(np.floor((mid[k_axis] - dk - against) / step))
                for uk in range(near_k, near_k + 2):
                    trial[k_axis] = against + uk * step
                    inside = True
                    for d in range(3):
                        candidates[n_candidates, d] = old[d] + mid[d] - trial[d]
                        inside &= 0 < candidates[n_candidates, d] < q_max
                    x0 = candidates[n_candidates, 0]
                    x1 = candidates[n_candidates, 1]
                    x2 = candidates[n_candidates, 2]
                    error = evaluate(quadric, float(x0), float(x1), float(x2))
                    if inside and error <= bound:
                        costs[n_candidates] = error + eps * (
                            (x0 - old[0]) ** 2 + (x1 - old[1]) ** 2 + (x2 - old[2]) ** 2
                        )
                        n_candidates += 1
        for _ in range(n_candidates):
            cheapest = 0
            for r in range(1, n_candidates):
                if costs[r] < costs[cheapest]:
                    cheapest = r
            costs[cheapest] = np.inf
            for d in range(3):
                c[d] = candidates[cheapest, d]
            if _turns_a_face(fans, lo, hi, q, old, c, ratio, normals, min_cos, turned, before):
                continue
            # The encoder computes the frame with s at its new place. Around a closed
            # fan the sum of the cross products does not depend on s's place while no
            # offset is shifted (under 2^_DIFF_BITS): then it is the same frame.
            same_frame = True
            reach = max(abs(c[0] - old[0]), abs(c[1] - old[1]), abs(c[2] - old[2]))
            if rc.bit_length(big + reach) > _DIFF_BITS:
                _fan_normal(fans, lo, hi, q, c, moved_context)
                same_frame = _mid_frame(moved_context, edge, moved_axes, moved_binormal)
                for d in range(3):
                    same_frame &= moved_axes[d] == axes[d]
                    same_frame &= moved_binormal[d] == binormal[d]
            if same_frame:
                for d in range(3):
                    q[slot, d] = c[d]
                break


@_helper
def _flipped(points, a, b, c, normals, f):
    """Whether the face of corners a, b, c (rows of points) faces away from normals[f]
    (its full-level face's), or has lost its area."""
    ux = points[b, 0] - points[a, 0]
    uy = points[b, 1] - points[a, 1]
    uz = points[b, 2] - points[a, 2]
    wx = points[c, 0] - points[a, 0]
    wy = points[c, 1] - points[a, 1]
    wz = points[c, 2] - points[a, 2]
    nx = uy * wz - uz * wy
    ny = uz * wx - ux * wz
    nz = ux * wy - uy * wx
    along = nx * normals[f, 0] + ny * normals[f, 1] + nz * normals[f, 2]
    # A margin over the exact sign, so that no rounding of another evaluation flips it.
    return along <= 1e-9 * np.sqrt(nx * nx + ny * ny + nz * nz)


@_helper
def _check(points, a, b, c, normals, f, moved, suspect, revert):
    """Check one state of a face (corner slots a, b, c) if one of them is suspect (a
    bitmap: it fits in a core's cache where a byte a slot would not); mark its moved
    corners for putting back if it is flipped."""
    a, b, c = np.int64(a), np.int64(b), np.int64(c)
    either = (suspect[a >> 6] >> (a & 63)) | (suspect[b >> 6] >> (b & 63))
    if not ((either | (suspect[c >> 6] >> (c & 63))) & 1):
        return
    if _flipped(points, a, b, c, normals, f):
        revert[a] |= moved[a]
        revert[b] |= moved[b]
        revert[c] |= moved[c]


@numba.njit(cache=True, nogil=True)
def flipped_moves(points, base_faces, parent, fan_offsets, fans, born, moved, suspect, normals):
    """Every state of every face over the levels (the base's faces, each fan as its split
    leaves it, each face as born), its corners at ``points`` (slots, 3: the scaled
    lattice coordinates), against its full-level face's normal. Only states
    with a corner in a ``suspect`` slot are checked (a bool per slot; after a first
    round, the slots put back: a state of none of them is as it was). Returns the moved
    slots to put back: the moved corners of a flipped state."""
    k = parent.shape[0]
    n_base = points.shape[0] - 2 * k
    revert = np.zeros(points.shape[0], np.bool_)
    bits = np.zeros((points.shape[0] + 63) // 64, np.int64)
    for slot in range(points.shape[0]):
        if suspect[slot]:
            bits[slot >> 6] |= np.int64(1) << (slot & 63)
    suspect = bits
    for f in range(base_faces.shape[0]):
        _check(points, base_faces[f, 0], base_faces[f, 1], base_faces[f, 2], normals, f,
               moved, suspect, revert)
    for i in range(k):
        for r in range(fan_offsets[i], fan_offsets[i + 1]):
            corner = n_base + 2 * i + fans[r, 3]  # s's new slot, or t's
            _check(points, corner, fans[r, 0], fans[r, 1], normals, fans[r, 2], moved,
                   suspect, revert)
    for r in range(born.shape[0]):
        _check(points, born[r, 0], born[r, 1], born[r, 2], normals, born[r, 3], moved,
               suspect, revert)
    return revert

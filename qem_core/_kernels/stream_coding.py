"""Split-stream (version 6) coding kernels: connectivity relative to the split vertex's
neighbourhood, positions relative to the split vertex's old position in a frame fitted
to its ring, the symbols range-coded (``code_splits`` / ``decode_connectivity``,
contexts below the constants). docs/formats.md, section 2, gives every step.

Encoder and decoder keep the same state, the mesh at the level being refined:

- ``faces`` (capacity, 3) int32, the faces as they are at that level;
- per-vertex lists of the corners (corner c = 3 * face + j) that name the vertex,
  ``head[v]`` the first corner of v (-1: none), ``nxt[c]`` the next corner of the same
  vertex (-1: last). The order in a list does not matter: every use sorts or sums.
- ``quantised``, the level's grid positions.

For split i (s = split_vertex[i], t = n_from + i), with the corners of s sorted by corner
index (``cs``) and the distinct other vertices of s's faces sorted (``nb``):

- s is coded against the s of the frame's previous split (-1 for its first): whether it
  lies ahead of it, then the gap to it (the build takes the splits in sweeps of
  ascending s, ``sweeps.py``), else as a bucket of [0, previous s] (``S_BUCKETS`` of
  them) and its place in the bucket;
- each new face gets a code 0..6 (0-2: (s, t, x) rotated by the code; 3-5: (t, s, x)
  rotated; 6 explicit). The third corner x of the first face of code 0-5 (the first
  *wing*) is its index in ``nb`` (``ESCAPE`` = 255 when x is not there or the index is
  >= 255: x is then given as ``t - x`` in ``backs``). The first later face of the other
  orientation (the second wing) gives x as its step on the walk around s from the first
  wing (``_walk``), or the walk's length (not on it) followed by an index as above. An
  explicit face gives its three corners as ``t - corner`` in ``backs``.
- the corners of s whose faces the split relabels s -> t: one bit per corner of ``cs``,
  coded against the bit that ``_predict`` derives from the new faces (the fan of faces
  swept from the wing x of the (s, t, x) face to the wing of the (t, s, x) face, exactly
  the relabelled set for a manifold edge split). Relabelling a marked corner's face turns
  its first corner equal to s into t (the rule of apply_split_run), in ``cs`` order.
- positions (``_ring_shape``, ``_span_axes``, ``_mid_axes``): the edge e = t - s_new
  against the two rings' centroids, its axis nearest the ring's normal against the plane
  of the ring; whether s or t stayed at s's old position; else the midpoint against the
  old position in the frame (e, normal, e x normal), its two tangent values in units of
  the lattice step when the build put it on the tangent lattice.
"""

import numba
import numpy as np

from . import range_coder as rc
from .memory import prefetch

# Kernels that allocate nothing and return no array: no reference counting (as in
# range_coder.py), a call costs no atomics per array argument.
_kernel = numba.njit(cache=True, nogil=True, _nrt=False)

ESCAPE = 255
EXPLICIT = 6
# Rings larger than this get no span prediction (keeps every product below 2^53, so a
# JavaScript decoder computes the same floors in float64).
SPAN_RING_LIMIT = 64
# An s not ahead of the previous one, in [0, n) for n = previous s + 1, is coded as its
# bucket floor(S_BUCKETS * s / n) (a tree of contexts: the splits favour older vertices)
# then its offset in the bucket.
S_BUCKETS = 32
_S_BUCKET_BITS = 5
# Coordinate differences and normals are shifted right to these many bits before they
# are multiplied, so that every product and sum stays exact in float64 (JavaScript).
_DIFF_BITS = 13
_NORMAL_BITS = 12
_LAPLACE_BITS = 20

# Decoder status codes (0: fine); stream.py turns them into messages.
BAD_VERTEX = 1
BAD_CODE = 2
BAD_THIRD = 3
BAD_BACK = 4
SHORT_DATA = 5
LONG_DATA = 6
BAD_POSITION = 7
NO_CORNER = 8
BAD_COUNT = 9
TOO_MUCH_WORK = 13  # after the wedge statuses (wedge_coding.py: 10-12, then its 14)

# Splitting s walks and sorts the corners of s, so a frame costs the sum of its split
# vertices' corner counts: a frame that splits one vertex over and over (a fan) costs the
# square of its length, and a crafted 24 KB frame held a decoder for 11 s. Frames of the
# encoder stay within this many corners (``plan_frame``; a frame of one split always
# fits); a decoder refuses a frame that goes past it. Real meshes, ~10 corners a split,
# reach a twentieth of it in the largest frames (8192 splits).
FRAME_WORK_LIMIT = 1 << 21
# The wedge side's work (wedge_coding.py): the corners it reads, for each corner of a new
# face, of that corner's vertex (twice for a vertex other than s and t: its list of
# wedges, and the prediction). The encoder keeps a frame of more than one split within
# WEDGE_WORK_LIMIT; the decoders refuse one past twice that (a margin over the planner's
# count), or past eight times within its first split, which no planner can shorten: a
# split of more than ~3 000 new faces (only builds without topology preservation of
# non-manifold input make one) cannot be streamed with its wedges, and a crafted split
# of one vertex's faces cannot stall a decoder.
WEDGE_WORK_LIMIT = 1 << 22

# Version 3 and on code the fields with the adaptive range coder (range_coder.py), split by
# split in the order the decoder needs them. The contexts of each field, as slots of one
# probability array (a block per field, ``_ROWS`` blocks where a context picks a row):
_ROWS = 21  # magnitude classes 0..20: bit lengths of a ring spread or an edge
_STEP_ROWS = 9  # walk lengths 0..8 (8: 8 or more)
_IS = rc.INTEGER_SLOTS
_S_BUCKET_SLOTS = 0  # bucket of s: 5-bit tree
_S_SLOTS = _S_BUCKET_SLOTS + S_BUCKETS  # s in its bucket: uniform, bit-position contexts
_S_AHEAD_SLOTS = _S_SLOTS + rc.UNIFORM_SLOTS  # s ahead of the previous one? by the last
_S_GAP_SLOTS = _S_AHEAD_SLOTS + 2  # s - previous s - 1: integer
_COUNT_SLOTS = _S_GAP_SLOTS + _IS  # new faces of the split: integer
_CODE_SLOTS = _COUNT_SLOTS + _IS  # face code: 3-bit tree per previous code
_ESCAPE_SLOT = _CODE_SLOTS + 8 * 8  # third corner escaped?
_THIRD_SLOTS = _ESCAPE_SLOT + 1  # its index in nb: uniform, a row per min(nn, 16)
_STEP_SLOTS = _THIRD_SLOTS + 17 * 8  # second wing's walk step: integer, row by walk length
_BACK_SLOTS = _STEP_SLOTS + _STEP_ROWS * _IS  # corners_back values: integer
_MASK_SLOTS = _BACK_SLOTS + _IS  # relabel mask: "as predicted?", then bits by prediction
_SPAN_SLOTS = _MASK_SLOTS + 3  # position_span, tangent axes: row by the ring spread
_SPAN_SIGN_SLOTS = _SPAN_SLOTS + _ROWS * _IS  # their signs, by the prediction's sign
_NORMAL_SLOTS = _SPAN_SIGN_SLOTS + 3  # position_span, normal axis: row by the ring spread
_PLACE_SLOTS = _NORMAL_SLOTS + _ROWS * _IS  # placement: "an end stayed?", "which?"
_MID_SLOTS = _PLACE_SLOTS + 2  # position_mid without a frame: row by the edge's axis
_MID1_SLOTS = _MID_SLOTS + _ROWS * _IS  # position_mid along e: row by the edge's axis
_MID2_SLOTS = _MID1_SLOTS + _ROWS * _IS  # second and third: row by the edge's length
_MID3_SLOTS = _MID2_SLOTS + _ROWS * _IS
_MID_SIGN_SLOTS = _MID3_SLOTS + _ROWS * _IS  # signs of the first two, by the curvature
_LATTICE_SLOT = _MID_SIGN_SLOTS + 6  # "the mid's tangent values on the lattice?"
_LATTICE1_SLOTS = _LATTICE_SLOT + 1  # position_mid on the lattice, first value
_LATTICE3_SLOTS = _LATTICE1_SLOTS + _IS  # and third (sign in its slot 132)
CONTEXT_SLOTS = _LATTICE3_SLOTS + _IS

# The tangent lattice (stream version 6). A split's mid, coded in the frame of the edge
# and the ring's normal, has two values that move the new position along the surface
# (along the edge, and across it in the ring's plane) and one that moves it off the
# surface. The build places each vertex that splits again (qem_core.lattice) so that its
# two tangent values are multiples of a step of about a sixteenth of the edge it splits
# into: they then cost a few bits where the exact optimum's cost about log2 of the
# edge's length each, and the vertex stays as near its quadric optimum as a move along
# the surface allows. A decision says which splits do (any other split is coded exactly).
LATTICE_BITS = 4

# Field flags of ``code_splits`` (which fields to code: all for a frame, one at a time
# to measure a field; each field has contexts of its own, so its bytes do not depend on
# the others).
FIELD_SPLIT_BACK = 1
FIELD_FACE_COUNTS = 2
FIELD_FACE_CODES = 4
FIELD_THIRD_CORNERS = 8
FIELD_CORNERS_BACK = 16
FIELD_RELABEL_MASKS = 32
FIELD_POSITION_SPAN = 64
FIELD_POSITION_MID = 128
ALL_FIELDS = 255
# The split's values that a context needs and the decoder knows from its state before
# the split (``_ring_shape``): nn, nc, the ring spread per axis (mean |Q[w] - Q[s]|),
# the ring's normal (3), the sign of the curvature along it.
SPLIT_CONTEXT = 9
_NN, _NC, _SPREAD, _NORMAL, _BULGE = 0, 1, 2, 5, 8
# Per split, the position symbols in coding order: three of position_span, the
# placement, three of position_mid (coded only when the placement is 0), and whether
# the mid is on the tangent lattice (-1 when that decision is not coded), coded before
# the mid's values.
POSITION_SYMBOLS = 8
_PLACEMENT = 3
_ON_LATTICE = 7


@_kernel
def position_box(base, splits, low, high):
    """The box of the rows of ``base`` (n, 3) and ``splits`` (m, 3) into low and high
    (3,), in one pass (numpy's min and max along the first axis of (m, 3) arrays take
    ~30 ms each on dragon's 870 000 split positions, ahead of the encoder's threads).
    Returns False, the box unknown, where numpy's answer might differ from a pass of
    comparisons: no rows, a NaN, or a corner coordinate of 0 (0.0 or -0.0: which one
    min returns is numpy's choice, and the grid's bytes keep the sign)."""
    if base.shape[0] + splits.shape[0] == 0:
        return False
    first = base if base.shape[0] else splits
    for d in range(3):
        low[d] = first[0, d]
        high[d] = first[0, d]
    for rows in (base, splits):
        for i in range(rows.shape[0]):
            for d in range(3):
                x = rows[i, d]
                if x != x:
                    return False
                low[d] = min(low[d], x)
                high[d] = max(high[d], x)
    for d in range(3):
        if low[d] == 0.0 or high[d] == 0.0:
            return False
    return True


@_kernel
def link_corners(faces, n_faces, head, nxt):
    """Fill the corner lists of faces[:n_faces]; returns False if a corner is not a
    vertex of ``head``."""
    head[:] = -1
    n_vertices = head.shape[0]
    for f in range(n_faces):
        for j in range(3):
            v = faces[f, j]
            if v < 0 or v >= n_vertices:
                return False
            c = 3 * f + j
            nxt[c] = head[v]
            head[v] = c
    return True


@_kernel
def _unlink(head, nxt, v, c):
    prev = -1
    at = head[v]
    while at != -1 and at != c:
        prev = at
        at = nxt[at]
    if at == -1:
        return
    if prev == -1:
        head[v] = nxt[c]
    else:
        nxt[prev] = nxt[c]


@_kernel
def _sort_prefix(values, n):
    """Sort values[:n] in place: by insertion for the few entries of a vertex's ring,
    else a heapsort (no allocation either way)."""
    if n <= 32:
        for i in range(1, n):
            value = values[i]
            j = i - 1
            while j >= 0 and values[j] > value:
                values[j + 1] = values[j]
                j -= 1
            values[j + 1] = value
        return
    for start in range(n // 2 - 1, -1, -1):
        _sift_down(values, start, n)
    for end in range(n - 1, 0, -1):
        values[0], values[end] = values[end], values[0]
        _sift_down(values, 0, end)


@_kernel
def _sift_down(values, root, n):
    while True:
        child = 2 * root + 1
        if child >= n:
            return
        if child + 1 < n and values[child + 1] > values[child]:
            child += 1
        if values[root] >= values[child]:
            return
        values[root], values[child] = values[child], values[root]
        root = child


@_kernel
def _gather(faces, head, nxt, s, cs, nb):
    """Sorted corners of s into cs, sorted distinct other vertices of its faces into nb;
    returns (nc, nn)."""
    nc = 0
    c = head[s]
    while c != -1:
        cs[nc] = c
        nc += 1
        c = nxt[c]
    _sort_prefix(cs, nc)
    m = 0
    for q in range(nc):
        f = cs[q] // 3
        for j in range(3):
            v = faces[f, j]
            nb[m] = v  # kept unless s, without a branch (m stays below 2 nc)
            m += v != s
    return nc, _distinct_sorted(nb, m)


@_kernel
def _distinct_sorted(values, n):
    """Sort values[:n] in place and drop repeats; returns the new length.

    The repeats go first (each value compared with those kept, without a branch on the
    outcome, as in ``_ring_sum``), so that the sort has half the values of a ring."""
    m = 0
    for q in range(n):
        value = values[q]
        seen = False
        for r in range(m):
            seen |= values[r] == value
        values[m] = value  # m <= q: values[q] is read before
        m += not seen
    _sort_prefix(values, m)
    return m


@_kernel
def _find(values, n, x):
    """Index of x in sorted values[:n], or -1."""
    lo, hi = 0, n
    while lo < hi:
        mid = (lo + hi) >> 1
        if values[mid] < x:
            lo = mid + 1
        else:
            hi = mid
    if lo < n and values[lo] == x:
        return lo
    return -1


@_kernel
def _fan_keys(faces, s, cs, nc, forward, keys):
    """keys[:nc] = side * nc + q sorted, side the corner before s (after s when not
    ``forward``) in the face of cs[q]: the corners of each side in cs order, found by
    bisection (``_fan_next``). keys[nc] remembers the direction: a split's walk and
    prediction, which usually go the same way, key its corners once (the caller sets
    keys[nc] = -1 for each new split)."""
    if keys[nc] == forward:
        return
    keys[nc] = forward
    for q in range(nc):
        c = cs[q]
        f = c // 3
        j = c % 3
        side = faces[f, (j + 2) % 3] if forward else faces[f, (j + 1) % 3]
        keys[q] = side * nc + q
    _sort_prefix(keys, nc)


@_kernel
def _fan_next(keys, nc, used, y):
    """The first corner q (in cs order) not ``used`` whose side (``_fan_keys``) is y, or
    -1."""
    # The first key of side y: counted, not bisected (a few keys; a bisection's
    # branches are guesses the processor gets wrong half the time).
    lo = 0
    for q in range(nc):
        lo += keys[q] < y * nc
    while lo < nc and keys[lo] < (y + 1) * nc:
        q = keys[lo] - y * nc
        if not used[q]:
            return q
        lo += 1
    return -1


@_kernel
def _fan_step(faces, cs, q, forward):
    """The corner after s (before s when not ``forward``) in the face of cs[q]."""
    c = cs[q]
    f = c // 3
    j = c % 3
    return faces[f, (j + 1) % 3] if forward else faces[f, (j + 2) % 3]


@_kernel
def _walk(faces, s, cs, nc, start, forward, stop, used, ys, keys):
    """Walk around s from ``start``: each step takes the first corner of cs not yet
    ``used`` whose face has y before s (after s when not ``forward``), marks it used and
    moves y to its face's corner after s (before s); it stops when none is found, when y
    is ``stop``, or after nc steps. The vertices met before stopping go into ys; returns
    how many."""
    used[:nc] = 0
    _fan_keys(faces, s, cs, nc, forward, keys)
    y = start
    m = 0
    for _ in range(nc):
        q = _fan_next(keys, nc, used, y)
        if q < 0:
            break
        used[q] = 1
        y = _fan_step(faces, cs, q, forward)
        if y == stop:
            break
        ys[m] = y
        m += 1
    return m


@_kernel
def _predict(faces, s, cs, nc, xl, xr, mark, ys, keys):
    """The predicted relabel mask over cs[:nc] into mark[:nc] (0/1): the corners the walk
    forward from xl to xr takes (the fan of s's faces between the two wings), or without
    xl the walk backwards from xr. xl, xr = -1 when absent."""
    if xl < 0 and xr < 0:
        mark[:nc] = 0
        return
    forward = xl >= 0
    # one call (not one per direction): each distinct call compiles its own copy
    _walk(faces, s, cs, nc, xl if forward else xr, forward, xr if forward else xl, mark, ys, keys)


@_kernel
def _relabel(faces, head, nxt, f, s, t):
    """Turn the first corner of face f equal to s into t; False if there is none."""
    for j in range(3):
        if faces[f, j] == s:
            faces[f, j] = t
            c = 3 * f + j
            _unlink(head, nxt, s, c)
            nxt[c] = head[t]
            head[t] = c
            return True
    return False


@_kernel
def _append_face(faces, head, nxt, f, a, b, c):
    faces[f, 0] = a
    faces[f, 1] = b
    faces[f, 2] = c
    for j in range(3):
        v = faces[f, j]
        corner = 3 * f + j
        nxt[corner] = head[v]
        head[v] = corner


@numba.njit(cache=True, nogil=True)
def _scratch_start():
    """The buffers of a coder or decoder: cs, nb, mark, ys, keys of _gather, _predict and
    _walk (``_room`` grows them), sums of _span_prediction, six 3-vectors (prediction,
    work, binormal, edge, mid, axes) and the slots of a value."""
    return (
        np.empty(16, np.int64),
        np.empty(32, np.int64),
        np.empty(16, np.uint8),
        np.empty(16, np.int64),
        np.empty(16, np.int64),
        np.zeros((2, 3), np.int64),
        np.zeros((6, 3), np.int64),
        np.zeros(2, np.int64),
    )


@_kernel
def _degree(head, nxt, v):
    """How many corners v has (the length of its list)."""
    degree = 0
    c = head[v]
    while c != -1:
        degree += 1
        c = nxt[c]
    return degree


@numba.njit(cache=True, nogil=True, inline="always")
def _room(need, cs, nb, mark, ys, keys):
    """The buffers of _gather and _set_gather, _predict and _walk, grown for ``need`` corners."""
    if need < cs.shape[0]:
        return cs, nb, mark, ys, keys
    return (
        np.empty(2 * need, np.int64),
        np.empty(4 * need, np.int64),
        np.empty(2 * need, np.uint8),
        np.empty(2 * need, np.int64),
        np.empty(2 * need, np.int64),
    )


@_kernel
def _ring_sum(faces, head, nxt, v, other, quantised, total, nb):
    """Sum of the positions of v's distinct neighbours other than ``other`` into total;
    returns their number (``nb`` is scratch with room for twice v's corners).

    The neighbours are made distinct by comparing each with those kept so far, without
    a branch on the outcome (a ring has a dozen entries, each but the first repeated
    once on a manifold: a sort's or a test's branches would be guessed wrong half the
    time); the sum of integers does not depend on the order."""
    m = 0
    c = head[v]
    while c != -1:
        m = _ring_corner(faces, c, v, other, nb, m)
        c = nxt[c]
    _sum_rows(quantised, nb, m, total)
    return m


@_kernel
def _ring_corner(faces, c, v, other, nb, m):
    """Add the two other vertices of corner c's face (v's neighbours) to nb[:m] unless
    there already or ``other``; returns the new length."""
    f = c // 3
    j = c - 3 * f  # v's place in the face: the other two are its neighbours
    for step in range(1, 3):
        w = faces[f, j + step - 3 if j + step >= 3 else j + step]
        seen = (w == v) | (w == other)  # v twice: a degenerate face
        for q in range(m):
            seen |= nb[q] == w
        nb[m] = w  # two a corner: nb has room
        m += not seen
    return m


@_kernel
def _sum_rows(quantised, nb, m, total):
    total[:] = 0
    for q in range(m):
        for d in range(3):
            total[d] += quantised[nb[q], d]


@_kernel
def _span_prediction(faces, head, nxt, s, t, quantised, nb, sums, prediction):
    """The predicted t - s_new once the split's connectivity is applied: each of s and t
    at the centroid of its ring (which holds the other), solved for both. With A the
    other neighbours of t (a of them) and B those of s (b): t (a + 1) = sum A + s and
    s (b + 1) = sum B + t, so t = (sum A (b + 1) + sum B) / d and s = (sum B (a + 1) +
    sum A) / d, d = (a + 1)(b + 1) - 1, each floored. Zero when a or b is 0 or over
    SPAN_RING_LIMIT. ``sums`` is (2, 3) scratch."""
    a = _ring_sum(faces, head, nxt, t, s, quantised, sums[0], nb)
    b = _ring_sum(faces, head, nxt, s, t, quantised, sums[1], nb)
    _centroid_span(a, b, sums, prediction)


@_kernel
def _centroid_span(a, b, sums, prediction):
    """The span prediction from the ring sums (sums[0] of t's a neighbours, sums[1] of
    s's b): zero when a or b is 0 or over SPAN_RING_LIMIT."""
    prediction[:] = 0
    if a == 0 or b == 0 or a > SPAN_RING_LIMIT or b > SPAN_RING_LIMIT:
        return
    den = (a + 1) * (b + 1) - 1
    for d in range(3):
        pt = (sums[0, d] * (b + 1) + sums[1, d]) // den
        ps = (sums[1, d] * (a + 1) + sums[0, d]) // den
        prediction[d] = pt - ps


@numba.njit(cache=True, nogil=True, inline="always")
def _grow(array, need):
    if need <= array.shape[0]:
        return array
    size = max(2 * array.shape[0], need)
    grown = np.zeros(size, array.dtype)
    grown[: array.shape[0]] = array
    return grown


@_kernel
def _sign(value):
    """Context of a sign: 0 for 0, 1 for positive, 2 for negative."""
    return 1 if value > 0 else (2 if value < 0 else 0)


@_kernel
def _shift_to(values, bits):
    """Shift the three values right (floor) until the largest magnitude has at most
    ``bits`` bits."""
    big = max(abs(values[0]), abs(values[1]), abs(values[2]))
    shift = max(0, rc.bit_length(big) - bits)
    for d in range(3):
        values[d] >>= shift


@_kernel
def _round_div(num, den):
    """num / den rounded to nearest (halves up), den != 0."""
    if den < 0:
        num = -num
        den = -den
    return (2 * num + den) // (2 * den)


@_kernel
def _dominant(values):
    """Index of the largest magnitude of the three (the first on ties)."""
    k = 0
    for d in range(1, 3):
        if abs(values[d]) > abs(values[k]):
            k = d
    return k


@_kernel
def _ring_shape(faces, quantised, s, cs, nc, nb, nn, context, work):
    """What the positions' contexts need of s's ring before the split, into context:
    nn, nc, the spread per axis (mean |Q[w, d] - Q[s, d]| over the neighbours w, 0
    without any), the ring's normal (sum over s's corners of the cross product of the two
    other corners' offsets from s, offsets shifted to _DIFF_BITS bits, the sum to
    _NORMAL_BITS) and the sign of the curvature along it (sum of the offsets, shifted to
    _LAPLACE_BITS bits, dotted with the normal). ``work`` is (3,) scratch."""
    context[_NN] = nn
    context[_NC] = nc
    big = 0
    for d in range(3):
        context[_SPREAD + d] = 0
        work[d] = 0
    for q in range(nn):
        for d in range(3):
            offset = quantised[nb[q], d] - quantised[s, d]
            work[d] += offset
            context[_SPREAD + d] += abs(offset)
            big = max(big, abs(offset))
    for d in range(3):
        context[_SPREAD + d] = context[_SPREAD + d] // nn if nn else 0
    _shift_to(work, _LAPLACE_BITS)
    shift = max(0, rc.bit_length(big) - _DIFF_BITS)
    nx = 0
    ny = 0
    nz = 0
    sx = quantised[s, 0]
    sy = quantised[s, 1]
    sz = quantised[s, 2]
    for q in range(nc):
        f = cs[q] // 3
        j = cs[q] % 3
        u = faces[f, (j + 1) % 3]
        w = faces[f, (j + 2) % 3]
        ux = (quantised[u, 0] - sx) >> shift
        uy = (quantised[u, 1] - sy) >> shift
        uz = (quantised[u, 2] - sz) >> shift
        wx = (quantised[w, 0] - sx) >> shift
        wy = (quantised[w, 1] - sy) >> shift
        wz = (quantised[w, 2] - sz) >> shift
        nx += uy * wz - uz * wy
        ny += uz * wx - ux * wz
        nz += ux * wy - uy * wx
    bulge = 0
    context[_NORMAL] = nx
    context[_NORMAL + 1] = ny
    context[_NORMAL + 2] = nz
    _shift_to(context[_NORMAL : _NORMAL + 3], _NORMAL_BITS)
    for d in range(3):
        bulge += work[d] * context[_NORMAL + d]
    context[_BULGE] = _sign(bulge)


@_kernel
def _span_axes(context, axes):
    """The order in which position_span codes the axes into axes: the two others, then
    the normal's dominant one (whose value is predicted from the plane of the ring);
    returns whether there is such a plane (a nonzero normal), else 0, 1, 2."""
    normal = context[_NORMAL : _NORMAL + 3]
    k = _dominant(normal)
    if normal[k] == 0:
        axes[0], axes[1], axes[2] = 0, 1, 2
        return False
    axes[0] = 1 if k == 0 else 0
    axes[1] = 1 if k == 2 else 2
    axes[2] = k
    return True


@_kernel
def _span_slots(context, plane, axes, n_known, edge, prediction, slots):
    """Context slots (magnitude block, sign slot) of the n_known-th span value into
    slots, and the value it is coded against (edge holds the axes already known)."""
    d = axes[n_known]
    row = min(rc.bit_length(context[_SPREAD + d]), _ROWS - 1)
    if plane and n_known == 2:
        i, j = axes[0], axes[1]
        normal = context[_NORMAL : _NORMAL + 3]
        slots[0] = _NORMAL_SLOTS + row * _IS
        slots[1] = slots[0] + _IS - 1
        return _round_div(-(normal[i] * edge[i] + normal[j] * edge[j]), normal[d])
    slots[0] = _SPAN_SLOTS + row * _IS
    slots[1] = _SPAN_SIGN_SLOTS + _sign(prediction[d])
    return prediction[d]


@_kernel
def _mid_frame(context, edge, axes, work):
    """The frame position_mid codes in: axes[0] the axis of the edge's largest component
    other than axes[2], axes[2] the dominant axis of b = e x normal, axes[1] the last;
    work holds b shifted to _NORMAL_BITS bits. Returns False when there is no frame
    (a zero normal, or e along it): then the axes are 0, 1, 2."""
    normal = context[_NORMAL : _NORMAL + 3]
    work[0] = edge[1] * normal[2] - edge[2] * normal[1]
    work[1] = edge[2] * normal[0] - edge[0] * normal[2]
    work[2] = edge[0] * normal[1] - edge[1] * normal[0]
    k = _dominant(work)
    if work[k] == 0:
        axes[0], axes[1], axes[2] = 0, 1, 2
        return False
    _shift_to(work, _NORMAL_BITS)
    a = 1 if k == 0 else 0
    b = 1 if k == 2 else 2
    if abs(edge[b]) > abs(edge[a]):
        a, b = b, a
    axes[0], axes[1], axes[2] = a, b, k
    return True


@_kernel
def lattice_step(edge):
    """The tangent lattice's step for a split of edge e: 2^(bitlen(max |e_d|) -
    LATTICE_BITS), at least 1 (then there is no lattice)."""
    big = max(abs(edge[0]), abs(edge[1]), abs(edge[2]))
    return 1 << max(0, rc.bit_length(big) - LATTICE_BITS)


@_kernel
def _mid_slots(context, framed, axes, n_known, edge, binormal, reduced, mid, slots, lattice):
    """Context slots of the n_known-th mid value into slots, and the value it is coded
    against: in the frame, the second axis against the first scaled along e (``reduced``
    is e shifted to _NORMAL_BITS bits), the third against the plane of e and the normal
    (mid holds the values already known). With ``lattice`` the first and third values
    are coded in units of the lattice step, in blocks of their own."""
    d = axes[n_known]
    if not framed:
        slots[0] = _MID_SLOTS + min(rc.bit_length(edge[d]), _ROWS - 1) * _IS
        slots[1] = slots[0] + _IS - 1
        return 0
    a, b = axes[0], axes[1]
    normal = context[_NORMAL : _NORMAL + 3]
    bulge = 1 if context[_BULGE] == 1 else (-1 if context[_BULGE] == 2 else 0)
    length = min(rc.bit_length(abs(edge[0]) + abs(edge[1]) + abs(edge[2])), _ROWS - 1)
    if n_known == 0:
        slots[0] = _MID1_SLOTS + min(rc.bit_length(edge[a]), _ROWS - 1) * _IS
        if lattice:
            slots[0] = _LATTICE1_SLOTS
        slots[1] = _MID_SIGN_SLOTS + _sign(bulge * normal[a])
        return 0
    if n_known == 1:
        slots[0] = _MID2_SLOTS + length * _IS
        cross = normal[b] * reduced[a] - normal[a] * reduced[b]
        slots[1] = _MID_SIGN_SLOTS + 3 + _sign(bulge * _sign_of(cross) * _sign_of(reduced[a]))
        if reduced[a] == 0:
            return 0
        return _round_div(mid[a] * reduced[b], reduced[a])
    slots[0] = _LATTICE3_SLOTS if lattice else _MID3_SLOTS + length * _IS
    slots[1] = slots[0] + _IS - 1
    return mid_third(axes, binormal, mid)


@_kernel
def mid_third(axes, binormal, mid):
    """What the mid's third value is coded against: the plane of e and the normal
    (binormal is e x normal shifted to _NORMAL_BITS bits), given the first two."""
    a, b, d = axes[0], axes[1], axes[2]
    return _round_div(-(binormal[a] * mid[a] + binormal[b] * mid[b]), binormal[d])


@_kernel
def _sign_of(value):
    return 1 if value > 0 else (-1 if value < 0 else 0)


@_kernel
def _third_row(nn):
    return _THIRD_SLOTS + min(nn, 16) * 8


@_kernel
def _step_row(walk_length):
    return _STEP_SLOTS + min(walk_length, _STEP_ROWS - 1) * _IS


@_kernel
def plan_frame(corner_counts, n_from, split_vertex, new_faces, new_face_counts,
               relabel_offsets, limit, wedge_limit):
    """How many of these splits (n_from.., at least one) a frame holds within ``limit``
    (FRAME_WORK_LIMIT): the sum over its splits of the split vertex's corner count, as
    ``decode_connectivity`` counts it; and, with ``wedge_limit`` >= 0 (a stream with
    wedges: WEDGE_WORK_LIMIT), within that many corners read by the wedge side, as
    ``wedge_coding.code_wedges`` counts them. ``corner_counts`` (>= n_to,) int64 holds
    every vertex's corner count in the level n_from and is advanced past the splits
    taken: a split moves its relabelled corners from s to t and adds its new faces'
    corners."""
    walked = 0
    wedge_walked = 0
    face = 0
    for i in range(split_vertex.shape[0]):
        s = split_vertex[i]
        t = n_from + i
        walked += corner_counts[s]
        if i > 0 and walked > limit:
            return i
        moved = relabel_offsets[i + 1] - relabel_offsets[i]
        corner_counts[s] -= moved
        corner_counts[t] += moved
        first = face
        for _ in range(new_face_counts[i]):
            for j in range(3):
                corner_counts[new_faces[face, j]] += 1
            face += 1
        if wedge_limit < 0:
            continue
        # The wedge side reads, for each new corner, its vertex's corners in the level
        # after the split.
        for f in range(first, face):
            for j in range(3):
                v = new_faces[f, j]
                wedge_walked += corner_counts[v] * (1 if v == s or v == t else 2)
        if i > 0 and wedge_walked > wedge_limit:
            for f in range(first, face):  # not taken: back to the level before it
                for j in range(3):
                    corner_counts[new_faces[f, j]] -= 1
            corner_counts[t] -= moved
            corner_counts[s] += moved
            return i
    return split_vertex.shape[0]


# How many splits ahead the encoder fetches the split vertex's corner list, faces and
# ring positions (``_prefetch_ahead``): a walk takes a step a split, and a list has ~6
# corners on a real mesh, more in coarse levels.
_AHEAD = 16


@_kernel
def _prefetch_ahead(faces, head, nxt, quantised, split_vertex, i, cursors):
    """Ask for what the splits after split i will read of the state, one link a split.

    Each split reads the corner list of its split vertex s (a chain of dependent loads
    through ``nxt``, each a cache miss: the vertices split one after another lie all over
    the level), the faces of those corners and the positions of their vertices; without
    this the misses come one after another, about half of the encoder's time (dragon).
    The encoder knows the split vertices ahead (the decoder does not), so it walks the
    lists of the next _AHEAD splits a link at a time, one step per split: cursors[j %
    _AHEAD] is the corner of split j's list whose ``nxt`` entry and face were asked for
    one split ago (-2: its head not read yet, -1: done). A step reads what the step
    before asked for, so it never waits long, and asks for the next link, the face of
    that corner, and the positions of the face's vertices. The splits in between change
    the lists (a relabelled corner moves to t's list): a cursor then follows the wrong
    list, which costs a useless fetch, never a wrong result; a cursor only ever holds
    -2, -1 or a corner of the state."""
    k = split_vertex.shape[0]
    n_corners = nxt.shape[0]
    j = i + _AHEAD
    if j < k:
        s = split_vertex[j]
        prefetch(head, s, 0)
        cursors[j % _AHEAD] = -2
    for j in range(i + 1, min(i + _AHEAD, k)):
        slot = j % _AHEAD
        c = cursors[slot]
        if c == -2:
            s = split_vertex[j]
            c = head[s]
            prefetch(quantised, s, 0)
            prefetch(quantised, s, 16)
        elif c >= 0:
            f = c // 3
            for r in range(3):
                v = faces[f, r]
                prefetch(quantised, v, 0)
                prefetch(quantised, v, 16)
                prefetch(head, v, 0)  # a new face on v links its corner there
            c = nxt[c]
        else:
            continue
        if c >= 0 and c < n_corners:
            prefetch(nxt, c, 0)
            prefetch(faces, c // 3, 0)
        else:
            c = -1
        cursors[slot] = c


@numba.njit(cache=True, nogil=True)
def encode_connectivity(
    faces,
    faces_from,
    head,
    nxt,
    n_from,
    split_vertex,
    new_faces,
    new_face_counts,
    relabel_offsets,
    relabel_faces,
    quantised,
    split_quantised,
    positions,
    position_slots,
    split_context,
):
    """Code splits n_from.. against the state (faces[:faces_from], head, nxt), which is
    advanced to the level after the last split (faces must have room for the new faces).
    split_context (K, SPLIT_CONTEXT) receives what ``code_splits`` needs of the state.

    Positions: ``quantised`` (>= n_to, 3) int64 holds the level's grid positions and is
    advanced too; split_quantised (K, 2, 3) are the new s and t. Per split, positions[i]
    (POSITION_SYMBOLS values) receives the position symbols in coding order and
    position_slots[i] (POSITION_SYMBOLS, 2) their contexts (``_span_slots``,
    ``_mid_slots``; a mid value not coded has slot -1).

    Returns (codes uint8, thirds int64, steps int64, walks int64, backs int64, masks
    uint8, status). Per face of code 0-5: thirds its index in nb or ESCAPE (-1 when the
    walk gives it), steps its walk step (-1 when it is not the second wing or there is
    no walk), walks the walk's length. masks: per corner of cs, bit 0 relabelled, bit 1
    predicted. status is NO_CORNER if a relabelled face has no corner s (inconsistent
    splits), else 0.
    """
    k = split_vertex.shape[0]
    n_new = new_faces.shape[0]
    codes = np.empty(n_new, np.uint8)
    thirds = np.empty(n_new, np.int64)
    steps = np.empty(n_new, np.int64)
    walks = np.empty(n_new, np.int64)
    backs = np.empty(3 * n_new, np.int64)
    masks = np.zeros(max(16, 6 * k), np.uint8)
    cs, nb, mark, ys, keys, sums, vectors, slots = _scratch_start()
    cursors = np.full(_AHEAD, -2, np.int64)
    counters = np.zeros(_COUNTERS, np.int64)
    counters[_FACE] = faces_from
    while True:
        status, need = _encode_splits(
            faces, head, nxt, n_from, split_vertex, new_faces, new_face_counts,
            relabel_offsets, relabel_faces, quantised, split_quantised, positions,
            position_slots, split_context, codes, thirds, steps, walks, backs, masks,
            counters, cursors, cs, nb, mark, ys, keys, sums, vectors, slots,
        )  # fmt: skip
        if status != _NEED_ROOM:
            break
        cs, nb, mark, ys, keys = _room(need, cs, nb, mark, ys, keys)
        masks = _grow(masks, counters[_MASK] + need)
    return (
        codes,
        thirds[: counters[_THIRD]],
        steps[: counters[_THIRD]],
        walks[: counters[_THIRD]],
        backs[: counters[_BACK]],
        masks[: counters[_MASK]],
        status,
    )


# Where _encode_splits stands, kept between its calls in counters: the next split, and
# how many thirds, backs, mask entries, faces (of the state) and new faces so far.
_SPLIT = 0
_THIRD = 1
_BACK = 2
_MASK = 3
_FACE = 4
_NEW = 5  # rows of new_faces taken
_COUNTERS = 6
_NEED_ROOM = -1


@_kernel
def _encode_splits(
    faces, head, nxt, n_from, split_vertex, new_faces, new_face_counts, relabel_offsets,
    relabel_faces, quantised, split_quantised, positions, position_slots, split_context,
    codes, thirds, steps, walks, backs, masks, counters, cursors, cs, nb, mark, ys, keys,
    sums, vectors, slots,
):  # fmt: skip
    """The loop of ``encode_connectivity`` from split counters[_SPLIT] on, in a kernel
    without reference counting: its arrays are never rebound here, and numba counted
    references (an atomic increment and decrement) at each rebinding and each view, about
    6 % of the encoder's time. Returns (status, 0), or (_NEED_ROOM, need) before touching
    a split whose corners do not fit the scratch (or masks): the caller grows them for
    ``need`` corners and calls again."""
    prediction, work, binormal, edge, mid, axes = vectors
    k = split_vertex.shape[0]
    n_third = counters[_THIRD]
    n_back = counters[_BACK]
    n_mask = counters[_MASK]
    face = counters[_FACE]
    new = counters[_NEW]
    for i in range(counters[_SPLIT], k):
        _prefetch_ahead(faces, head, nxt, quantised, split_vertex, i, cursors)
        s = np.int64(split_vertex[i])  # int64 as in the decoder: the helpers compile once
        t = n_from + i
        # Room for the corners of s, and for those of s and t after the split (the ring
        # sums): each of its new faces brings at most three.
        nc = _degree(head, nxt, s)
        need = nc + 3 * new_face_counts[i]
        if need >= cs.shape[0] or n_mask + nc > masks.shape[0]:
            _keep(counters, i, n_third, n_back, n_mask, face, new)
            return _NEED_ROOM, need
        nc, nn = _gather(faces, head, nxt, s, cs, nb)
        keys[nc] = -1  # not keyed for this split yet
        context = split_context[i]
        _ring_shape(faces, quantised, s, cs, nc, nb, nn, context, work)
        xl = -1
        xr = -1
        first_forward = False
        walk_length = -1  # not walked yet
        for q in range(new, new + new_face_counts[i]):
            code = EXPLICIT
            third = 0
            for r in range(3):
                a = new_faces[q, r]
                b = new_faces[q, (r + 1) % 3]
                if a == s and b == t:
                    code = r
                elif a == t and b == s:
                    code = 3 + r
                else:
                    continue
                third = new_faces[q, (r + 2) % 3]
                break
            codes[q] = code
            if code == EXPLICIT:
                for r in range(3):
                    backs[n_back] = t - new_faces[q, r]
                    n_back += 1
                continue
            forward = code < 3
            second = xl >= 0 or xr >= 0
            second = second and walk_length < 0 and forward != first_forward
            if not (xl >= 0 or xr >= 0):
                first_forward = forward
            steps[n_third] = -1
            walks[n_third] = 0
            if second:
                start = xl if xl >= 0 else xr
                walk_length = _walk(faces, s, cs, nc, start, first_forward, start, mark, ys, keys)
                walks[n_third] = walk_length
                if walk_length > 0:
                    step = walk_length
                    for q2 in range(walk_length):
                        if ys[q2] == third:
                            step = q2
                            break
                    steps[n_third] = step
            if forward and xl < 0:
                xl = third
            if not forward and xr < 0:
                xr = third
            if steps[n_third] >= 0 and steps[n_third] < walks[n_third]:
                thirds[n_third] = -1
            else:
                index = _find(nb, nn, third)
                if 0 <= index < ESCAPE:
                    thirds[n_third] = index
                else:
                    thirds[n_third] = ESCAPE
                    backs[n_back] = t - third
                    n_back += 1
            n_third += 1
        _predict(faces, s, cs, nc, xl, xr, mark, ys, keys)
        for q in range(nc):
            masks[n_mask + q] = 2 * mark[q]
        moved = False
        for r in range(relabel_offsets[i], relabel_offsets[i + 1]):
            f = relabel_faces[r]
            hit = -1
            for j in range(3):
                if faces[f, j] == s:
                    hit = 3 * f + j
                    faces[f, j] = t  # as _relabel, its corner moved to t's list below
                    break
            q = 0  # hit's place in cs, counted (cs holds every corner of s)
            for q2 in range(nc):
                q += cs[q2] < hit
            if hit < 0 or q >= nc or cs[q] != hit:
                return NO_CORNER, 0
            masks[n_mask + q] |= 1
            moved = True
        if moved:
            # The lists of s and t rebuilt from cs at once, rather than each relabelled
            # corner unlinked by a walk of s's list (the order of a list does not matter).
            head[s] = -1
            for q in range(nc):
                c = cs[q]
                v = t if masks[n_mask + q] & 1 else s
                nxt[c] = head[v]
                head[v] = c
        n_mask += nc
        for q in range(new, new + new_face_counts[i]):
            _append_face(faces, head, nxt, face, new_faces[q, 0], new_faces[q, 1], new_faces[q, 2])
            face += 1
        new += new_face_counts[i]
        _span_prediction(faces, head, nxt, s, t, quantised, nb, sums, prediction)
        for d in range(3):
            edge[d] = split_quantised[i, 1, d] - split_quantised[i, 0, d]
        plane = _span_axes(context, axes)
        for n_known in range(3):
            against = _span_slots(context, plane, axes, n_known, edge, prediction, slots)
            positions[i, n_known] = edge[axes[n_known]] - against
            position_slots[i, n_known, 0] = slots[0]
            position_slots[i, n_known, 1] = slots[1]
        stays_s = True
        stays_t = True
        for d in range(3):
            stays_s &= split_quantised[i, 0, d] == quantised[s, d]
            stays_t &= split_quantised[i, 1, d] == quantised[s, d]
        placement = 1 if stays_s else (2 if stays_t else 0)
        positions[i, _PLACEMENT] = placement
        for d in range(3):
            a = split_quantised[i, 0, d]
            b = split_quantised[i, 1, d]
            mid[d] = ((a + b) >> 1) - quantised[s, d]
        framed = _mid_frame(context, edge, axes, binormal)
        for d in range(3):
            work[d] = edge[d]
        _shift_to(work, _NORMAL_BITS)
        step = lattice_step(edge)
        lattice = placement == 0 and framed and step > 1
        positions[i, _ON_LATTICE] = -1
        if lattice:
            # On the lattice when both tangent values are multiples of the step.
            third = mid[axes[2]] - mid_third(axes, binormal, mid)
            lattice = mid[axes[0]] % step == 0 and third % step == 0
            positions[i, _ON_LATTICE] = 1 if lattice else 0
        for n_known in range(3):
            at = _PLACEMENT + 1 + n_known
            if placement:
                positions[i, at] = 0
                position_slots[i, at, 0] = -1
                continue
            against = _mid_slots(
                context, framed, axes, n_known, edge, binormal, work, mid, slots, lattice
            )
            value = mid[axes[n_known]] - against
            positions[i, at] = value // step if lattice and n_known != 1 else value
            position_slots[i, at, 0] = slots[0]
            position_slots[i, at, 1] = slots[1]
        for d in range(3):
            quantised[s, d] = split_quantised[i, 0, d]
            quantised[t, d] = split_quantised[i, 1, d]
    _keep(counters, k, n_third, n_back, n_mask, face, new)
    return 0, 0


@_kernel
def _keep(counters, split, n_third, n_back, n_mask, face, new):
    """Where _encode_splits stopped, for its next call and its caller."""
    counters[_SPLIT] = split
    counters[_THIRD] = n_third
    counters[_BACK] = n_back
    counters[_MASK] = n_mask
    counters[_FACE] = face
    counters[_NEW] = new


@_kernel
def _code_s(enc, out, probs, s, previous, was_ahead):
    """s against the previous split's (-1: none); returns whether it was ahead of it."""
    ahead = 1 if s > previous else 0
    rc.encode_bit(enc, out, probs, _S_AHEAD_SLOTS + was_ahead, ahead)
    if ahead:
        rc.encode_integer(enc, out, probs, _S_GAP_SLOTS, s - previous - 1, False)
        return 1
    n = previous + 1
    bucket = (S_BUCKETS * s) // n
    rc.encode_tree(enc, out, probs, _S_BUCKET_SLOTS, _S_BUCKET_BITS, bucket)
    lo = (bucket * n + S_BUCKETS - 1) // S_BUCKETS
    hi = ((bucket + 1) * n + S_BUCKETS - 1) // S_BUCKETS
    rc.encode_uniform(enc, out, probs, _S_SLOTS, s - lo, hi - lo)
    return 0


@_kernel
def code_splits(
    enc,
    out,
    probs,
    fields,
    n_from,
    split_back,
    new_face_counts,
    codes,
    thirds,
    steps,
    walks,
    backs,
    masks,
    positions,
    position_slots,
    split_context,
):
    """Range-code what ``encode_connectivity`` produced in the order
    ``decode_connectivity`` reads it: every split's s, then split by split the face
    count, each face's code and third corner (or corners_back), the relabel mask,
    position_span, the placement, position_mid. Only
    the fields in the ``fields`` flags are coded (all of them for a frame). Returns 0, or
    1 when an integer was out of the coder's range (``range_coder.encode_integer``: the
    output is then wrong)."""
    bad = 0
    at_face = 0
    at_third = 0
    at_back = 0
    at_mask = 0
    if fields & FIELD_SPLIT_BACK:
        # Every split's s first: a decoder then knows the frame's split vertices before
        # it touches the state, and fetches what the next splits will read early.
        previous_s = -1
        was_ahead = 0
        for i in range(split_back.shape[0]):
            s = n_from + i - split_back[i]
            was_ahead = _code_s(enc, out, probs, s, previous_s, was_ahead)
            previous_s = s
    for i in range(split_back.shape[0]):
        context = split_context[i]
        count = new_face_counts[i]
        if fields & FIELD_FACE_COUNTS:
            bad |= rc.encode_integer(enc, out, probs, _COUNT_SLOTS, count, False)
        previous = 7
        for _ in range(count):
            code = codes[at_face]
            at_face += 1
            if fields & FIELD_FACE_CODES:
                rc.encode_tree(enc, out, probs, _CODE_SLOTS + 8 * previous, 3, code)
            previous = code
            n_backs = 3 if code == EXPLICIT else 0
            if code < EXPLICIT:
                index = thirds[at_third]
                step = steps[at_third]
                walk_length = walks[at_third]
                at_third += 1
                n_backs = 1 if index == ESCAPE else 0
                if fields & FIELD_THIRD_CORNERS:
                    if step >= 0:
                        bad |= rc.encode_integer(
                            enc, out, probs, _step_row(walk_length), step, False
                        )
                    if index >= 0:
                        rc.encode_bit(enc, out, probs, _ESCAPE_SLOT, index == ESCAPE)
                        if index != ESCAPE:
                            nn = min(context[_NN], ESCAPE)
                            rc.encode_uniform(enc, out, probs, _third_row(nn), index, nn)
            for _ in range(n_backs):
                if fields & FIELD_CORNERS_BACK:
                    bad |= rc.encode_integer(enc, out, probs, _BACK_SLOTS, backs[at_back], False)
                at_back += 1
        nc = context[_NC]
        if fields & FIELD_RELABEL_MASKS and nc:
            as_predicted = True
            for q in range(nc):
                as_predicted &= masks[at_mask + q] == 0 or masks[at_mask + q] == 3
            rc.encode_bit(enc, out, probs, _MASK_SLOTS, not as_predicted)
            if not as_predicted:
                for q in range(nc):
                    bit = masks[at_mask + q] & 1
                    rc.encode_bit(enc, out, probs, _MASK_SLOTS + 1 + (masks[at_mask + q] >> 1), bit)
        at_mask += nc
        if fields & FIELD_POSITION_SPAN:
            for n_known in range(3):
                bad |= _code_value(
                    enc, out, probs, positions[i, n_known], position_slots[i, n_known]
                )
        if fields & FIELD_POSITION_MID:
            placement = positions[i, _PLACEMENT]
            rc.encode_bit(enc, out, probs, _PLACE_SLOTS, placement != 0)
            if placement:
                rc.encode_bit(enc, out, probs, _PLACE_SLOTS + 1, placement == 2)
            else:
                if positions[i, _ON_LATTICE] >= 0:
                    rc.encode_bit(enc, out, probs, _LATTICE_SLOT, positions[i, _ON_LATTICE])
                for at in range(_PLACEMENT + 1, _PLACEMENT + 4):
                    bad |= _code_value(enc, out, probs, positions[i, at], position_slots[i, at])
    return bad


@_kernel
def _code_value(enc, out, probs, value, slots):
    """Returns encode_integer's status."""
    bad = rc.encode_integer(enc, out, probs, slots[0], abs(value), False)
    if value != 0:
        rc.encode_bit(enc, out, probs, slots[1], value < 0)
    return bad


@_kernel
def _read_value(reader, data, probs, slots):
    """(value, reader): the inverse of _code_value."""
    magnitude, reader = rc.read_integer(reader, data, probs, slots[0], False)
    if magnitude != 0:
        negative, reader = rc.read_bit(reader, data, probs, slots[1])
        if negative:
            return -magnitude, reader
    return magnitude, reader


# The decoder's corner sets. The encoder's per-vertex linked lists (head, nxt) cost the
# decoder a chain of dependent cache misses a split (head[s], then each nxt[c]: the
# corners of s lie all over a large level) and a sort of cs; the decoder knows no split
# vertex ahead, so it cannot fetch them early as the encoder does. It keeps each
# vertex's corners instead in a block of one pool, sorted by corner number: ``starts[v]``
# the block's place in ``pool``, ``counts[v]`` the corners in it, ``caps[v]`` its room.
# Sorted for free: a split moves a sorted subset of the corners of s to t (a new vertex)
# and appends new faces, whose corners come after every corner held; a block that is
# full moves to the end of the pool with twice the room (the pool grows by doubling).
# The set of corners of a vertex is the same as the list's, so every decoded symbol is.


@numba.njit(cache=True, nogil=True)
def build_corner_sets(faces, n_faces, n_vertices, starts, counts, caps):
    """The corner sets (pool, used) of faces[:n_faces] over vertices [0, n_vertices)
    into starts, counts and caps (>= n_vertices; entries past n_vertices emptied); ok is
    False (and the sets unusable) if a face names a vertex outside [0, n_vertices)."""
    counts[:] = 0
    caps[:] = 0
    starts[:] = 0
    for f in range(n_faces):
        for j in range(3):
            v = faces[f, j]
            if v < 0 or v >= n_vertices:
                return False, np.empty(0, np.int64), 0
            counts[v] += 1
    used = 0
    for v in range(n_vertices):
        starts[v] = used
        caps[v] = max(8, counts[v] + 4)  # room for the new faces' corners to come
        used += caps[v]
    pool = np.empty(max(16, used + (used >> 2)), np.int64)
    counts[:] = 0
    for f in range(n_faces):
        for j in range(3):
            v = faces[f, j]
            pool[starts[v] + counts[v]] = 3 * f + j
            counts[v] += 1
    return True, pool, used


@_kernel
def _move_set(pool, starts, caps, counts, v, at, cap):
    """Move v's full set to pool[at : at + cap] (its room doubled)."""
    old = starts[v]
    for q in range(counts[v]):
        pool[at + q] = pool[old + q]
    starts[v] = at
    caps[v] = cap


@_kernel
def _set_ring_sum(faces, starts, counts, pool, v, other, quantised, total, nb):
    """``_ring_sum`` over v's corner set."""
    m = 0
    at = starts[v]
    for r in range(counts[v]):
        m = _ring_corner(faces, pool[at + r], v, other, nb, m)
    _sum_rows(quantised, nb, m, total)
    return m


@_kernel
def _set_span_prediction(faces, starts, counts, pool, s, t, quantised, nb, sums, prediction):
    """``_span_prediction`` over the corner sets."""
    a = _set_ring_sum(faces, starts, counts, pool, t, s, quantised, sums[0], nb)
    b = _set_ring_sum(faces, starts, counts, pool, s, t, quantised, sums[1], nb)
    _centroid_span(a, b, sums, prediction)


@_kernel
def _set_gather(faces, starts, counts, pool, s, cs, nb):
    """``_gather`` from s's corner set (sorted already); returns (nc, nn)."""
    nc = counts[s]
    at = starts[s]
    for q in range(nc):
        cs[q] = pool[at + q]
    m = 0
    for q in range(nc):
        f = cs[q] // 3
        for j in range(3):
            v = faces[f, j]
            nb[m] = v
            m += v != s
    return nc, _distinct_sorted(nb, m)


@_kernel
def undo_splits(faces, quantised, split_vertex, old_positions, n_started, undo, n_undo):
    """Take back what ``decode_connectivity`` changed of the level held (faces[:faces_from]
    and quantised[:n_from]): the relabelled corners (undo[:n_undo], pairs of corner and
    vertex before) and the positions of the split vertices (old_positions[:n_started]),
    latest first. The corner sets are rebuilt afterwards (``build_corner_sets``)."""
    for r in range(n_undo - 2, -1, -2):
        c = undo[r]
        faces[c // 3, c % 3] = undo[r + 1]
    for i in range(n_started - 1, -1, -1):
        s = split_vertex[i]
        for d in range(3):
            quantised[s, d] = old_positions[i, d]


@_kernel
def _read_split_vertices(reader, data, probs, n_from, split_vertex):
    """Every split's s of the frame into split_vertex (the inverse of code_splits's
    first loop); returns (status, reader), status 0, SHORT_DATA, or BAD_VERTEX for an s
    that is no vertex yet."""
    previous_s = -1
    was_ahead = 0
    for i in range(split_vertex.shape[0]):
        if reader[rc.R_BROKEN]:
            return SHORT_DATA, reader
        t = n_from + i
        if t < 1:
            return BAD_VERTEX, reader
        ahead, reader = rc.read_bit(reader, data, probs, _S_AHEAD_SLOTS + was_ahead)
        if ahead:
            was_ahead = 1
            gap, reader = rc.read_integer(reader, data, probs, _S_GAP_SLOTS, False)
            s = previous_s + 1 + gap
            if s >= t:
                return BAD_VERTEX, reader
        else:
            was_ahead = 0
            n = previous_s + 1
            bucket, reader = rc.read_tree(reader, data, probs, _S_BUCKET_SLOTS, _S_BUCKET_BITS)
            lo = (bucket * n + S_BUCKETS - 1) // S_BUCKETS
            hi = ((bucket + 1) * n + S_BUCKETS - 1) // S_BUCKETS
            if hi <= lo:
                return BAD_VERTEX, reader
            within, reader = rc.read_uniform(reader, data, probs, _S_SLOTS, hi - lo)
            s = lo + within
        previous_s = s
        split_vertex[i] = s
    return 0, reader


# How far ahead the decoder asks for each stage of a split's reads (_set_prefetch_ahead).
_SET_AHEAD = (16, 8, 4, 2)
_PREFETCH_CORNERS = 16  # at most this many corners of a split vertex are fetched early


@_kernel
def _set_prefetch_ahead(faces, starts, counts, pool, quantised, split_vertex, i):
    """Ask for what the decoder's next splits will read of the corner sets, in stages a
    split apart: the frame's split vertices are decoded first (``code_splits``), so the
    decoder knows them ahead, as the encoder does (``_prefetch_ahead``). For split
    i + 16 its set's place and its position; for i + 8 its block of corners; for i + 4
    the faces of those corners; for i + 2 the positions of their vertices (the ring).
    Each stage reads what the one before asked for. The splits in between change the
    sets: a stage may then fetch something useless, never read out of the state."""
    k = split_vertex.shape[0]
    j = i + _SET_AHEAD[0]
    if j < k:
        v = split_vertex[j]
        prefetch(starts, v, 0)
        prefetch(counts, v, 0)
        prefetch(quantised, v, 0)
        prefetch(quantised, v, 16)
    j = i + _SET_AHEAD[1]
    if j < k:
        at = starts[split_vertex[j]]
        prefetch(pool, at, 0)
        prefetch(pool, at, 64)
    j = i + _SET_AHEAD[2]
    if j < k:
        v = split_vertex[j]
        at = starts[v]
        for q in range(min(counts[v], _PREFETCH_CORNERS)):
            prefetch(faces, pool[at + q] // 3, 0)
    j = i + _SET_AHEAD[3]
    if j < k:
        v = split_vertex[j]
        at = starts[v]
        for q in range(min(counts[v], _PREFETCH_CORNERS)):
            f = pool[at + q] // 3
            for r in range(3):
                w = faces[f, r]
                prefetch(quantised, w, 0)
                prefetch(quantised, w, 16)


@numba.njit(cache=True, nogil=True)
def decode_connectivity(
    faces,
    faces_from,
    starts,
    counts,
    caps,
    pool,
    used,
    n_from,
    n_splits,
    n_frame_splits,
    n_new_faces,
    data,
    quantised,
    q_max,
    probs,
    born_faces,
    face_counts,
    partial,
    old_positions,
):
    """Inverse of ``encode_connectivity`` + ``code_splits``: decodes n_splits splits from
    the range-coded ``data`` (uint8) with the contexts ``probs`` (fresh, or as the
    previous frame of the stream left them: they are updated) and advances the state:
    the faces, the corner sets (starts, counts, caps, pool[:used]: ``build_corner_sets``)
    and the positions (faces must have room for n_new_faces more faces, starts, counts,
    caps and quantised for the new vertices, with the new vertices' sets empty). Every
    decoded position must lie on the grid, in [0, q_max] = [0, 2^bits - 1] per axis
    (BAD_POSITION otherwise: a decoder holding 32-bit integers, as the viewer's, must
    not wrap a value that this one refuses). What the wedge side needs of the splits
    goes to born_faces (>= n_new_faces, 3): the new faces as born, before later splits
    relabel them, and face_counts (>= n_splits,): each split's new faces.
    old_positions (>= n_splits, 3) receives the position of each split vertex before its
    split, for ``undo_splits``.

    Returns (status, split_vertex, relabel_counts, relabel_faces, pool, used, n_started,
    undo): status 0 when the splits used every byte of data, exactly n_new_faces faces
    and only indices in range, else a status code (the state is then partly advanced:
    ``undo_splits`` with n_started splits and the pairs in undo takes faces and
    positions back, and the corner sets must be rebuilt). With ``partial`` the n_splits
    splits are the first of a frame that holds more (a client that stops inside a
    frame): bytes and faces may remain, n_new_faces is a bound. n_frame_splits
    (>= n_splits) is how many splits the frame holds: the s of every one of them comes
    first in data.
    """
    k = n_splits
    reader = rc.reader_at(data, 0)  # the coder's state, in locals (range_coder.py)
    context = np.zeros(SPLIT_CONTEXT, np.int64)
    split_vertex = np.zeros(n_frame_splits, np.int32)
    status, reader = _read_split_vertices(reader, data, probs, n_from, split_vertex)
    relabel_counts = np.zeros(k, np.int64)
    relabel_faces = np.empty(max(16, 2 * k), np.int32)
    undo = np.empty(max(16, 4 * k), np.int64)
    cs, nb, mark, ys, keys, sums, vectors, slots = _scratch_start()
    prediction, work, binormal, edge, mid, axes = vectors
    corner = np.zeros(3, np.int64)
    n_relabel = 0
    n_undo = 0
    n_started = 0
    corners_walked = 0  # against FRAME_WORK_LIMIT
    face = faces_from
    face_end = faces_from + n_new_faces
    for i in range(0 if status else k):  # no split runs when its s was refused
        if reader[rc.R_BROKEN]:
            status = SHORT_DATA
            break
        t = n_from + i
        _set_prefetch_ahead(faces, starts, counts, pool, quantised, split_vertex, i)
        s = np.int64(split_vertex[i])
        for d in range(3):
            old_positions[i, d] = quantised[s, d]
        n_started = i + 1
        cs, nb, mark, ys, keys = _room(counts[s], cs, nb, mark, ys, keys)
        nc, nn = _set_gather(faces, starts, counts, pool, s, cs, nb)
        corners_walked += nc
        if i > 0 and corners_walked > FRAME_WORK_LIMIT:
            status = TOO_MUCH_WORK
            break
        keys[nc] = -1  # not keyed for this split yet
        _ring_shape(faces, quantised, s, cs, nc, nb, nn, context, work)
        count, reader = rc.read_integer(reader, data, probs, _COUNT_SLOTS, False)
        if count > face_end - face:
            status = BAD_COUNT
            break
        face_counts[i] = count
        xl = -1
        xr = -1
        first_forward = False
        walk_length = -1
        first_new = face
        previous = 7
        for _ in range(count):
            code, reader = rc.read_tree(reader, data, probs, _CODE_SLOTS + 8 * previous, 3)
            previous = code
            if code == EXPLICIT:
                for r in range(3):
                    b, reader = rc.read_integer(reader, data, probs, _BACK_SLOTS, False)
                    if b > t:
                        status = BAD_BACK
                        break
                    corner[r] = t - b
                if status:
                    break
            elif code < EXPLICIT:
                forward = code < 3
                x = -1
                if (xl >= 0 or xr >= 0) and walk_length < 0 and forward != first_forward:
                    start = xl if xl >= 0 else xr
                    walk_length = _walk(
                        faces, s, cs, nc, start, first_forward, start, mark, ys, keys
                    )
                    if walk_length > 0:
                        step, reader = rc.read_integer(
                            reader, data, probs, _step_row(walk_length), False
                        )
                        if step > walk_length:
                            status = BAD_THIRD
                            break
                        if step < walk_length:
                            x = ys[step]
                if not (xl >= 0 or xr >= 0):
                    first_forward = forward
                if x < 0:  # not the walk's step: escaped to a back index, or a neighbour
                    escaped, reader = rc.read_bit(reader, data, probs, _ESCAPE_SLOT)
                    if escaped:
                        b, reader = rc.read_integer(reader, data, probs, _BACK_SLOTS, False)
                        if b > t:
                            status = BAD_BACK
                            break
                        x = t - b
                    elif nn > 0:
                        n_index = min(nn, ESCAPE)
                        third, reader = rc.read_uniform(
                            reader, data, probs, _third_row(n_index), n_index
                        )
                        x = nb[third]
                    else:
                        status = BAD_THIRD
                        break
                r = code % 3
                corner[r] = s if forward else t
                corner[(r + 1) % 3] = t if forward else s
                corner[(r + 2) % 3] = x
                if forward and xl < 0:
                    xl = x
                if not forward and xr < 0:
                    xr = x
            else:
                status = BAD_CODE
                break
            # Written now (the corner sets get them after the relabels).
            for j in range(3):
                faces[face, j] = corner[j]
                born_faces[face - faces_from, j] = corner[j]
            face += 1
        if status:
            break
        _predict(faces, s, cs, nc, xl, xr, mark, ys, keys)
        mispredicted = 0
        if nc:
            mispredicted, reader = rc.read_bit(reader, data, probs, _MASK_SLOTS)
        if mispredicted:
            for q in range(nc):
                mark[q], reader = rc.read_bit(reader, data, probs, _MASK_SLOTS + 1 + mark[q])
        relabel_faces = _grow(relabel_faces, n_relabel + nc)
        undo = _grow(undo, n_undo + 2 * nc)
        moved = 0
        for q in range(nc):
            if mark[q]:
                f = cs[q] // 3
                hit = -1
                for j in range(3):
                    if faces[f, j] == s:
                        hit = 3 * f + j
                        faces[f, j] = t
                        break
                if hit < 0:
                    status = NO_CORNER
                    break
                undo[n_undo] = hit
                undo[n_undo + 1] = s
                n_undo += 2
                relabel_faces[n_relabel] = f
                n_relabel += 1
                moved += 1
                # hit is a corner of s not moved yet, at or before cs[q] in its face:
                # at or before q in cs (sorted); flagged as moved
                h = q
                while h > 0 and cs[h] != hit:
                    h -= 1
                if cs[h] != hit:
                    status = NO_CORNER
                    break
                cs[h] = -1 - hit
        if status:
            break
        relabel_counts[i] = moved
        if moved:
            # s keeps its other corners in order; t (empty) takes the moved ones, sorted
            # as cs is.
            at = starts[s]
            kept = 0
            for q in range(nc):
                c = cs[q]
                if c >= 0:
                    pool[at + kept] = c
                    kept += 1
            counts[s] = kept
            # t's set: empty, given room for the moved corners and those to come
            cap = max(8, 2 * moved)
            if used + cap > pool.shape[0]:
                pool = _grow(pool, used + cap)
            starts[t] = used
            caps[t] = cap
            used += cap
            at = used - cap
            for q in range(nc):
                c = cs[q]
                if c < 0:
                    pool[at] = -1 - c
                    at += 1
            counts[t] = moved
        for f in range(first_new, face):
            for j in range(3):
                # corner 3 f + j comes after every corner of v: appended
                v = faces[f, j]
                n = counts[v]
                if n == caps[v]:
                    cap = max(8, 2 * n)
                    if used + cap > pool.shape[0]:
                        pool = _grow(pool, used + cap)
                    _move_set(pool, starts, caps, counts, v, used, cap)
                    used += cap
                pool[starts[v] + n] = 3 * f + j
                counts[v] = n + 1
        need = 4 * (counts[s] + counts[t])  # room for twice the corners of s and t
        if need > nb.shape[0]:
            nb = np.empty(need, np.int64)
        _set_span_prediction(faces, starts, counts, pool, s, t, quantised, nb, sums, prediction)
        plane = _span_axes(context, axes)
        for n_known in range(3):
            against = _span_slots(context, plane, axes, n_known, edge, prediction, slots)
            value, reader = _read_value(reader, data, probs, slots)
            edge[axes[n_known]] = value + against
        placement = 0
        placed, reader = rc.read_bit(reader, data, probs, _PLACE_SLOTS)
        if placed:
            which, reader = rc.read_bit(reader, data, probs, _PLACE_SLOTS + 1)
            placement = 1 + which
        if placement == 0:
            framed = _mid_frame(context, edge, axes, binormal)
            for d in range(3):
                work[d] = edge[d]
            _shift_to(work, _NORMAL_BITS)
            step = lattice_step(edge)
            lattice = False
            if framed and step > 1:
                on_lattice, reader = rc.read_bit(reader, data, probs, _LATTICE_SLOT)
                lattice = on_lattice == 1
            for n_known in range(3):
                against = _mid_slots(
                    context, framed, axes, n_known, edge, binormal, work, mid, slots, lattice
                )
                value, reader = _read_value(reader, data, probs, slots)
                if lattice and n_known != 1:
                    # A mid on the grid is under 2^bits an axis; a value past 8 grid
                    # lengths is refused, which keeps value * step below 2^47.
                    if abs(value) > 8 * (q_max + 1):
                        status = BAD_POSITION
                    value *= step
                mid[axes[n_known]] = value + against
            if status:
                break
        for d in range(3):
            old = quantised[s, d]
            e = edge[d]
            if placement == 1:
                a = old
            elif placement == 2:
                a = old - e
            else:
                # a + b = 2 (old + mid) + (e & 1) and b - a = e
                a = (2 * (old + mid[d]) + (e & 1) - e) >> 1
            if a < 0 or a > q_max or a + e < 0 or a + e > q_max:
                status = BAD_POSITION
                break
            quantised[s, d] = a
            quantised[t, d] = a + e
        if status:
            break
    if status == 0:
        if reader[rc.R_BROKEN]:
            status = SHORT_DATA
        elif not partial and reader[rc.R_POSITION] != data.shape[0]:
            status = LONG_DATA
        elif not partial and face != face_end:
            status = BAD_COUNT
    return (
        status,
        split_vertex[:k],
        relabel_counts,
        relabel_faces[:n_relabel],
        pool,
        used,
        n_started,
        undo[:n_undo],
    )

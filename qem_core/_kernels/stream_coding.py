"""Split-stream (version 3) coding kernels: connectivity relative to the split vertex's
neighbourhood, positions relative to the split vertex's old position, the symbols
range-coded (``code_splits`` / ``decode_connectivity``, contexts below the constants).

Encoder and decoder keep the same state, the mesh at the level being refined:

- ``faces`` (capacity, 3) int32, the faces as they are at that level;
- per-vertex lists of the corners (corner c = 3 * face + j) that name the vertex,
  ``head[v]`` the first corner of v (-1: none), ``nxt[c]`` the next corner of the same
  vertex (-1: last). The order in a list does not matter: every use sorts.

For split i (s = split_vertex[i], t = n_from + i), with the corners of s sorted by corner
index (``cs``) and the distinct other vertices of s's faces sorted (``nb``):

- each new face gets a code 0..6 (0-2: (s, t, x) rotated by the code; 3-5: (t, s, x)
  rotated; 6 explicit) and, for codes 0-5, the index of x in ``nb`` as one byte
  (``ESCAPE`` = 255 when x is not there or the index is >= 255: x is then given as
  ``t - x`` in ``backs``); an explicit face gives its three corners as ``t - corner``
  in ``backs``. ``backs`` is in face order.
- the corners of s whose faces the split relabels s -> t form a mask over ``cs``,
  ``(nc + 7) // 8`` bytes (bit q of byte b is corner 8b + q), stored XOR the mask that
  ``_predict`` derives from the new faces: the fan of faces swept from the wing x of the
  (s, t, x) face to the wing of the (t, s, x) face, which is exactly the relabelled set
  for a manifold edge split. Relabelling a marked corner's face turns its first corner
  equal to s into t (the rule of apply_split_run), marks taken in ``cs`` order.
"""

import numba
import numpy as np

from . import range_coder as rc

ESCAPE = 255
EXPLICIT = 6
# The fan walk is quadratic in the number of corners of s; beyond this many the
# prediction is the empty mask (the mask is then stored as it is).
PREDICT_LIMIT = 64
# Rings larger than this get no span prediction (keeps every product below 2^53, so a
# JavaScript decoder computes the same floors in float64).
SPAN_RING_LIMIT = 64

# Decoder status codes (0: fine); stream.py turns them into messages.
BAD_VERTEX = 1
BAD_CODE = 2
BAD_THIRD = 3
BAD_BACK = 4
SHORT_DATA = 5
LONG_DATA = 6
BAD_MASK = 7
NO_CORNER = 8
BAD_COUNT = 9

# Version 3 codes the fields with the adaptive range coder (range_coder.py), split by
# split in the order the decoder needs them. The contexts of each field, as slots of one
# probability array (a block per field, ``rows`` blocks where a context picks a row):
_ROWS = 21  # magnitude classes 0..20: bit lengths of a ring spread or an edge
_S_SLOTS = 0  # s in [0, t): uniform, bit-position contexts
_COUNT_SLOTS = _S_SLOTS + rc.UNIFORM_SLOTS  # new faces of the split: integer
_CODE_SLOTS = _COUNT_SLOTS + rc.INTEGER_SLOTS  # face code: 3-bit tree per previous code
_ESCAPE_SLOT = _CODE_SLOTS + 8 * 8  # third corner escaped?
_THIRD_SLOTS = _ESCAPE_SLOT + 1  # its index in nb: uniform, a row per min(nn, 16)
_BACK_SLOTS = _THIRD_SLOTS + 17 * 8  # corners_back values: integer
_MASK_SLOTS = _BACK_SLOTS + rc.INTEGER_SLOTS  # relabel mask: "any bit set?", then its bits
_SPAN_SLOTS = _MASK_SLOTS + 2  # position_span: signed integer, row by the ring spread
_MID_SLOTS = _SPAN_SLOTS + _ROWS * rc.INTEGER_SLOTS  # position_mid: row by the edge
CONTEXT_SLOTS = _MID_SLOTS + _ROWS * rc.INTEGER_SLOTS

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
# The split's values that a context needs and the decoder knows from its state: nn, nc,
# the ring spread per axis (mean |Q[w] - Q[s]| over s's neighbours w before the split),
# and the edge t - s_new per axis.
SPLIT_CONTEXT = 8


@numba.njit(cache=True)
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


@numba.njit(cache=True)
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


@numba.njit(cache=True)
def _gather(faces, head, nxt, s, cs, nb):
    """Sorted corners of s into cs, sorted distinct other vertices of its faces into nb;
    returns (nc, nn)."""
    nc = 0
    c = head[s]
    while c != -1:
        cs[nc] = c
        nc += 1
        c = nxt[c]
    cs[:nc].sort()
    m = 0
    for q in range(nc):
        f = cs[q] // 3
        for j in range(3):
            v = faces[f, j]
            if v != s:
                nb[m] = v
                m += 1
    return nc, _distinct_sorted(nb, m)


@numba.njit(cache=True)
def _distinct_sorted(values, n):
    """Sort values[:n] in place and drop repeats; returns the new length."""
    values[:n].sort()
    m = 0
    for q in range(n):
        if m == 0 or values[q] != values[m - 1]:
            values[m] = values[q]
            m += 1
    return m


@numba.njit(cache=True)
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


@numba.njit(cache=True)
def _predict(faces, s, cs, nc, xl, xr, mark):
    """The predicted relabel mask over cs[:nc] into mark[:nc] (0/1): the fan of s's faces
    from the one whose corner before s is xl, each next one sharing the edge to the
    previous one's corner after s, until the corner after s is xr (walked backwards from
    xr when there is no xl). xl, xr = -1 when absent."""
    mark[:nc] = 0
    if nc > PREDICT_LIMIT or (xl < 0 and xr < 0):
        return
    forward = xl >= 0
    y = xl if forward else xr
    for _ in range(nc):
        found = -1
        for q in range(nc):
            if mark[q]:
                continue
            c = cs[q]
            f = c // 3
            j = c % 3
            side = faces[f, (j + 2) % 3] if forward else faces[f, (j + 1) % 3]
            if side == y:
                found = q
                break
        if found < 0:
            return
        mark[found] = 1
        c = cs[found]
        f = c // 3
        j = c % 3
        y = faces[f, (j + 1) % 3] if forward else faces[f, (j + 2) % 3]
        if forward and y == xr:
            return


@numba.njit(cache=True)
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


@numba.njit(cache=True)
def _append_face(faces, head, nxt, f, a, b, c):
    faces[f, 0] = a
    faces[f, 1] = b
    faces[f, 2] = c
    for j in range(3):
        v = faces[f, j]
        corner = 3 * f + j
        nxt[corner] = head[v]
        head[v] = corner


@numba.njit(cache=True)
def _scratch(head, nxt, s, cs, nb, mark):
    """The buffers of _gather and _predict, grown for the corners of s if need be."""
    degree = 0
    c = head[s]
    while c != -1:
        degree += 1
        c = nxt[c]
    if degree <= cs.shape[0]:
        return cs, nb, mark
    return (
        np.empty(2 * degree, np.int64),
        np.empty(4 * degree, np.int64),
        np.empty(2 * degree, np.uint8),
    )


@numba.njit(cache=True)
def _ring_sum(faces, head, nxt, v, other, quantised, total, nb):
    """Sum of the positions of v's distinct neighbours other than ``other`` into total;
    returns their number (``nb`` is scratch with room for twice v's corners)."""
    m = 0
    c = head[v]
    while c != -1:
        f = c // 3
        for j in range(3):
            w = faces[f, j]
            if w != v and w != other:
                nb[m] = w
                m += 1
        c = nxt[c]
    nb[:m].sort()
    total[:] = 0
    count = 0
    for q in range(m):
        if q == 0 or nb[q] != nb[q - 1]:
            count += 1
            for d in range(3):
                total[d] += quantised[nb[q], d]
    return count


@numba.njit(cache=True)
def _span_prediction(faces, head, nxt, s, t, quantised, nb, prediction):
    """The predicted t - s_new once the split's connectivity is applied: each of s and t
    at the centroid of its ring (which holds the other), solved for both. With A the
    other neighbours of t (a of them) and B those of s (b): t (a + 1) = sum A + s and
    s (b + 1) = sum B + t, so t = (sum A (b + 1) + sum B) / d and s = (sum B (a + 1) +
    sum A) / d, d = (a + 1)(b + 1) - 1, each floored. Zero when a or b is 0 or over
    SPAN_RING_LIMIT."""
    sum_a = np.zeros(3, np.int64)
    sum_b = np.zeros(3, np.int64)
    a = _ring_sum(faces, head, nxt, t, s, quantised, sum_a, nb)
    b = _ring_sum(faces, head, nxt, s, t, quantised, sum_b, nb)
    prediction[:] = 0
    if a == 0 or b == 0 or a > SPAN_RING_LIMIT or b > SPAN_RING_LIMIT:
        return
    den = (a + 1) * (b + 1) - 1
    for d in range(3):
        pt = (sum_a[d] * (b + 1) + sum_b[d]) // den
        ps = (sum_b[d] * (a + 1) + sum_a[d]) // den
        prediction[d] = pt - ps


@numba.njit(cache=True)
def _ring_room(head, nxt, s, t, nb):
    """nb, grown to hold twice the corners of s and of t if need be."""
    need = 0
    c = head[s]
    while c != -1:
        need += 2
        c = nxt[c]
    c = head[t]
    while c != -1:
        need += 2
        c = nxt[c]
    return nb if need <= nb.shape[0] else np.empty(2 * need, np.int64)


@numba.njit(cache=True)
def _grow(array, need):
    if need <= array.shape[0]:
        return array
    size = max(2 * array.shape[0], need)
    grown = np.zeros(size, array.dtype)
    grown[: array.shape[0]] = array
    return grown


@numba.njit(cache=True)
def _bit_length(value):
    value = abs(value)
    n = 0
    while value:
        n += 1
        value >>= 1
    return n


@numba.njit(cache=True)
def _ring_spread(quantised, s, nb, nn, context):
    """context[2 + d] = mean |Q[w, d] - Q[s, d]| over s's neighbours w (0 without any):
    the scale of the split's edges along each axis."""
    for d in range(3):
        total = 0
        for q in range(nn):
            total += abs(quantised[nb[q], d] - quantised[s, d])
        context[2 + d] = total // nn if nn else 0


@numba.njit(cache=True)
def _span_row(context, d):
    return _SPAN_SLOTS + min(_bit_length(context[2 + d]), _ROWS - 1) * rc.INTEGER_SLOTS


@numba.njit(cache=True)
def _mid_row(context, d):
    """The midpoint's offset from the collapsed vertex grows with the edge."""
    return _MID_SLOTS + min(_bit_length(context[5 + d]), _ROWS - 1) * rc.INTEGER_SLOTS


@numba.njit(cache=True)
def _third_row(nn):
    return _THIRD_SLOTS + min(nn, 16) * 8


@numba.njit(cache=True)
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
    mid,
    span,
    split_context,
):
    """Code splits n_from.. against the state (faces[:faces_from], head, nxt), which is
    advanced to the level after the last split (faces must have room for the new faces).
    split_context (K, SPLIT_CONTEXT) receives what ``code_splits`` needs of the state.

    Positions: ``quantised`` (>= n_to, 3) int64 holds the level's grid positions and is
    advanced too; split_quantised (K, 2, 3) are the new s and t; written out per split:
    mid[i] = floor((s_new + t) / 2) - old s (the quadric optimum lies near the middle of
    the edge it collapsed) and span[i] = t - s_new - ``_span_prediction``.

    Returns (codes uint8, thirds uint8, backs int64, masks uint8, status): status is
    NO_CORNER if a relabelled face has no corner s (inconsistent splits), else 0.
    """
    prediction = np.zeros(3, np.int64)
    k = split_vertex.shape[0]
    n_new = new_faces.shape[0]
    codes = np.empty(n_new, np.uint8)
    thirds = np.empty(n_new, np.uint8)
    backs = np.empty(3 * n_new, np.int64)
    masks = np.zeros(max(16, k), np.uint8)
    cs = np.empty(16, np.int64)
    nb = np.empty(32, np.int64)
    mark = np.empty(16, np.uint8)
    n_third = 0
    n_back = 0
    n_mask = 0
    face = faces_from
    new = 0
    for i in range(k):
        s = split_vertex[i]
        t = n_from + i
        cs, nb, mark = _scratch(head, nxt, s, cs, nb, mark)
        nc, nn = _gather(faces, head, nxt, s, cs, nb)
        split_context[i, 0] = nn
        split_context[i, 1] = nc
        _ring_spread(quantised, s, nb, nn, split_context[i])
        xl = -1
        xr = -1
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
            if code < 3 and xl < 0:
                xl = third
            if code >= 3 and xr < 0:
                xr = third
            index = _find(nb, nn, third)
            if 0 <= index < ESCAPE:
                thirds[n_third] = index
            else:
                thirds[n_third] = ESCAPE
                backs[n_back] = t - third
                n_back += 1
            n_third += 1
        _predict(faces, s, cs, nc, xl, xr, mark)
        n_bytes = (nc + 7) // 8
        masks = _grow(masks, n_mask + n_bytes)
        for q in range(nc):
            if mark[q]:
                masks[n_mask + q // 8] ^= np.uint8(1 << (q % 8))
        for r in range(relabel_offsets[i], relabel_offsets[i + 1]):
            f = relabel_faces[r]
            hit = -1
            for j in range(3):
                if faces[f, j] == s:
                    hit = 3 * f + j
                    break
            if hit < 0:
                return codes, thirds[:n_third], backs[:n_back], masks[:n_mask], NO_CORNER
            q = _find(cs, nc, hit)
            masks[n_mask + q // 8] ^= np.uint8(1 << (q % 8))
            _relabel(faces, head, nxt, f, s, t)
        n_mask += n_bytes
        for q in range(new, new + new_face_counts[i]):
            _append_face(faces, head, nxt, face, new_faces[q, 0], new_faces[q, 1], new_faces[q, 2])
            face += 1
        new += new_face_counts[i]
        nb = _ring_room(head, nxt, s, t, nb)
        _span_prediction(faces, head, nxt, s, t, quantised, nb, prediction)
        for d in range(3):
            old = quantised[s, d]
            a = split_quantised[i, 0, d]
            b = split_quantised[i, 1, d]
            mid[i, d] = ((a + b) >> 1) - old
            span[i, d] = b - a - prediction[d]
            split_context[i, 5 + d] = b - a
            quantised[s, d] = a
            quantised[t, d] = b
    return codes, thirds[:n_third], backs[:n_back], masks[:n_mask], 0


@numba.njit(cache=True)
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
    backs,
    masks,
    mid,
    span,
    split_context,
):
    """Range-code what ``encode_connectivity`` produced, split by split, in the order
    ``decode_connectivity`` reads it: s, the face count, each face's code and third corner
    (or corners_back), the relabel mask, position_span, position_mid. Only the fields in
    the ``fields`` flags are coded (all of them for a frame)."""
    at_face = 0
    at_third = 0
    at_back = 0
    at_mask = 0
    for i in range(split_back.shape[0]):
        t = n_from + i
        context = split_context[i]
        if fields & FIELD_SPLIT_BACK:
            rc.encode_uniform(enc, out, probs, _S_SLOTS, t - split_back[i], t)
        count = new_face_counts[i]
        if fields & FIELD_FACE_COUNTS:
            rc.encode_integer(enc, out, probs, _COUNT_SLOTS, count, False)
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
                at_third += 1
                if fields & FIELD_THIRD_CORNERS:
                    rc.encode_bit(enc, out, probs, _ESCAPE_SLOT, index == ESCAPE)
                    if index != ESCAPE:
                        nn = min(context[0], ESCAPE)
                        rc.encode_uniform(enc, out, probs, _third_row(nn), index, nn)
                n_backs = 1 if index == ESCAPE else 0
            for _ in range(n_backs):
                if fields & FIELD_CORNERS_BACK:
                    rc.encode_integer(enc, out, probs, _BACK_SLOTS, backs[at_back], False)
                at_back += 1
        nc = context[1]
        if fields & FIELD_RELABEL_MASKS and nc:
            any_set = False
            for q in range(nc):
                any_set |= (masks[at_mask + q // 8] >> (q % 8)) & 1 == 1
            rc.encode_bit(enc, out, probs, _MASK_SLOTS, any_set)
            if any_set:
                for q in range(nc):
                    bit = (masks[at_mask + q // 8] >> (q % 8)) & 1
                    rc.encode_bit(enc, out, probs, _MASK_SLOTS + 1, bit)
        at_mask += (nc + 7) // 8
        for d in range(3):
            if fields & FIELD_POSITION_SPAN:
                rc.encode_integer(enc, out, probs, _span_row(context, d), span[i, d], True)
        for d in range(3):
            if fields & FIELD_POSITION_MID:
                rc.encode_integer(enc, out, probs, _mid_row(context, d), mid[i, d], True)


@numba.njit(cache=True)
def decode_connectivity(
    faces,
    faces_from,
    head,
    nxt,
    n_from,
    n_splits,
    n_new_faces,
    data,
    quantised,
    born_faces,
    face_counts,
):
    """Inverse of ``encode_connectivity`` + ``code_splits``: decodes n_splits splits from
    the range-coded ``data`` (uint8) and advances the state (faces must have room for
    n_new_faces more faces, head and quantised for the new vertices). What the wedge
    side needs of the splits goes to born_faces (>= n_new_faces, 3): the new faces as
    born, before later splits relabel them, and face_counts (>= n_splits,): each split's
    new faces.

    Returns (status, split_vertex, relabel_counts, relabel_faces): status 0 when the
    splits used every byte of data, exactly n_new_faces faces and only indices in range,
    else a status code (the state is then partly advanced and must be dropped).
    """
    k = n_splits
    probs = np.full(CONTEXT_SLOTS, rc.HALF, np.uint16)
    dec = rc.start_decoder(data, 0)
    prediction = np.zeros(3, np.int64)
    context = np.zeros(SPLIT_CONTEXT, np.int64)
    split_vertex = np.zeros(k, np.int32)
    relabel_counts = np.zeros(k, np.int64)
    relabel_faces = np.empty(max(16, 2 * k), np.int32)
    cs = np.empty(16, np.int64)
    nb = np.empty(32, np.int64)
    mark = np.empty(16, np.uint8)
    n_relabel = 0
    face = faces_from
    face_end = faces_from + n_new_faces
    for i in range(k):
        if dec[rc.BROKEN]:
            return SHORT_DATA, split_vertex, relabel_counts, relabel_faces[:n_relabel]
        t = n_from + i
        if t < 1:
            return BAD_VERTEX, split_vertex, relabel_counts, relabel_faces[:n_relabel]
        s = rc.decode_uniform(dec, data, probs, _S_SLOTS, t)
        split_vertex[i] = s
        cs, nb, mark = _scratch(head, nxt, s, cs, nb, mark)
        nc, nn = _gather(faces, head, nxt, s, cs, nb)
        context[0] = nn
        context[1] = nc
        _ring_spread(quantised, s, nb, nn, context)
        count = rc.decode_integer(dec, data, probs, _COUNT_SLOTS, False)
        if count > face_end - face:
            return BAD_COUNT, split_vertex, relabel_counts, relabel_faces[:n_relabel]
        face_counts[i] = count
        xl = -1
        xr = -1
        first_new = face
        previous = 7
        corner = np.zeros(3, np.int64)
        for _ in range(count):
            code = rc.decode_tree(dec, data, probs, _CODE_SLOTS + 8 * previous, 3)
            previous = code
            if code == EXPLICIT:
                for r in range(3):
                    b = rc.decode_integer(dec, data, probs, _BACK_SLOTS, False)
                    if b > t:
                        return BAD_BACK, split_vertex, relabel_counts, relabel_faces[:n_relabel]
                    corner[r] = t - b
            elif code < EXPLICIT:
                if rc.decode_bit(dec, data, probs, _ESCAPE_SLOT):
                    b = rc.decode_integer(dec, data, probs, _BACK_SLOTS, False)
                    if b > t:
                        return BAD_BACK, split_vertex, relabel_counts, relabel_faces[:n_relabel]
                    x = t - b
                elif nn > 0:
                    n_index = min(nn, ESCAPE)
                    x = nb[rc.decode_uniform(dec, data, probs, _third_row(n_index), n_index)]
                else:
                    return BAD_THIRD, split_vertex, relabel_counts, relabel_faces[:n_relabel]
                r = code % 3
                swapped = code >= 3
                corner[r] = t if swapped else s
                corner[(r + 1) % 3] = s if swapped else t
                corner[(r + 2) % 3] = x
                if not swapped and xl < 0:
                    xl = x
                if swapped and xr < 0:
                    xr = x
            else:
                return BAD_CODE, split_vertex, relabel_counts, relabel_faces[:n_relabel]
            # Written now (the state's lists get them after the relabels).
            for j in range(3):
                faces[face, j] = corner[j]
                born_faces[face - faces_from, j] = corner[j]
            face += 1
        _predict(faces, s, cs, nc, xl, xr, mark)
        if nc and rc.decode_bit(dec, data, probs, _MASK_SLOTS):
            for q in range(nc):
                mark[q] ^= rc.decode_bit(dec, data, probs, _MASK_SLOTS + 1)
        relabel_faces = _grow(relabel_faces, n_relabel + nc)
        for q in range(nc):
            if mark[q]:
                f = cs[q] // 3
                if not _relabel(faces, head, nxt, f, s, t):
                    return NO_CORNER, split_vertex, relabel_counts, relabel_faces[:n_relabel]
                relabel_faces[n_relabel] = f
                n_relabel += 1
                relabel_counts[i] += 1
        for f in range(first_new, face):
            for j in range(3):
                v = faces[f, j]
                corner_id = 3 * f + j
                nxt[corner_id] = head[v]
                head[v] = corner_id
        nb = _ring_room(head, nxt, s, t, nb)
        _span_prediction(faces, head, nxt, s, t, quantised, nb, prediction)
        for d in range(3):
            e = rc.decode_integer(dec, data, probs, _span_row(context, d), True)
            context[5 + d] = e + prediction[d]
        for d in range(3):
            old = quantised[s, d]
            m = rc.decode_integer(dec, data, probs, _mid_row(context, d), True) + old
            e = context[5 + d]
            # a + b = 2m + (e & 1) and b - a = e
            a = (2 * m + (e & 1) - e) >> 1
            quantised[s, d] = a
            quantised[t, d] = a + e
    if dec[rc.BROKEN]:
        return SHORT_DATA, split_vertex, relabel_counts, relabel_faces[:n_relabel]
    if dec[rc.POSITION] != data.shape[0]:
        return LONG_DATA, split_vertex, relabel_counts, relabel_faces[:n_relabel]
    if face != face_end:
        return BAD_COUNT, split_vertex, relabel_counts, relabel_faces[:n_relabel]
    return 0, split_vertex, relabel_counts, relabel_faces[:n_relabel]

"""Split-stream (version 2) coding kernels: connectivity relative to the split vertex's
neighbourhood, positions relative to the split vertex's old position.

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
):
    """Code splits n_from.. against the state (faces[:faces_from], head, nxt), which is
    advanced to the level after the last split (faces must have room for the new faces).

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
            quantised[s, d] = a
            quantised[t, d] = b
    return codes, thirds[:n_third], backs[:n_back], masks[:n_mask], 0


@numba.njit(cache=True)
def decode_connectivity(
    faces,
    faces_from,
    head,
    nxt,
    n_from,
    split_back,
    new_face_counts,
    codes,
    thirds,
    backs,
    masks,
    quantised,
    mid,
    span,
    born_faces,
):
    """Inverse of ``encode_connectivity``: advances the state (faces must have room for
    sum(new_face_counts) more faces, head and quantised for the new vertices). The new
    faces as born (before later splits relabel them) go to born_faces (>= new faces, 3).

    Returns (status, split_vertex, relabel_counts, relabel_faces): status 0 when every
    field was consumed exactly and every index was in range, else a status code (the
    state is then partly advanced and must be dropped).
    """
    k = split_back.shape[0]
    prediction = np.zeros(3, np.int64)
    split_vertex = np.zeros(k, np.int32)
    relabel_counts = np.zeros(k, np.int64)
    relabel_faces = np.empty(max(16, 2 * k), np.int32)
    cs = np.empty(16, np.int64)
    nb = np.empty(32, np.int64)
    mark = np.empty(16, np.uint8)
    n_relabel = 0
    at_code = 0
    at_third = 0
    at_back = 0
    at_mask = 0
    face = faces_from
    for i in range(k):
        t = n_from + i
        back = np.int64(split_back[i])
        if back < 1 or back > t:
            return BAD_VERTEX, split_vertex, relabel_counts, relabel_faces[:n_relabel]
        s = t - back
        split_vertex[i] = s
        cs, nb, mark = _scratch(head, nxt, s, cs, nb, mark)
        nc, nn = _gather(faces, head, nxt, s, cs, nb)
        count = np.int64(new_face_counts[i])
        if at_code + count > codes.shape[0]:
            return SHORT_DATA, split_vertex, relabel_counts, relabel_faces[:n_relabel]
        xl = -1
        xr = -1
        first_new = face
        for _ in range(count):
            code = codes[at_code]
            at_code += 1
            corner = np.zeros(3, np.int64)
            if code == EXPLICIT:
                if at_back + 3 > backs.shape[0]:
                    return SHORT_DATA, split_vertex, relabel_counts, relabel_faces[:n_relabel]
                for r in range(3):
                    b = backs[at_back]
                    at_back += 1
                    if b < 0 or b > t:
                        return BAD_BACK, split_vertex, relabel_counts, relabel_faces[:n_relabel]
                    corner[r] = t - b
            elif code < EXPLICIT:
                if at_third >= thirds.shape[0]:
                    return SHORT_DATA, split_vertex, relabel_counts, relabel_faces[:n_relabel]
                index = thirds[at_third]
                at_third += 1
                if index == ESCAPE:
                    if at_back >= backs.shape[0]:
                        return SHORT_DATA, split_vertex, relabel_counts, relabel_faces[:n_relabel]
                    b = backs[at_back]
                    at_back += 1
                    if b < 0 or b > t:
                        return BAD_BACK, split_vertex, relabel_counts, relabel_faces[:n_relabel]
                    x = t - b
                elif index < nn:
                    x = nb[index]
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
        n_bytes = (nc + 7) // 8
        if at_mask + n_bytes > masks.shape[0]:
            return SHORT_DATA, split_vertex, relabel_counts, relabel_faces[:n_relabel]
        for q in range(nc):
            bit = (masks[at_mask + q // 8] >> (q % 8)) & 1
            mark[q] ^= bit
        if nc % 8 and masks[at_mask + n_bytes - 1] >> (nc % 8):
            return BAD_MASK, split_vertex, relabel_counts, relabel_faces[:n_relabel]
        at_mask += n_bytes
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
            old = quantised[s, d]
            m = mid[i, d] + old
            e = span[i, d] + prediction[d]
            # a + b = 2m + (e & 1) and b - a = e
            a = (2 * m + (e & 1) - e) >> 1
            quantised[s, d] = a
            quantised[t, d] = a + e
    if at_code != codes.shape[0] or at_third != thirds.shape[0]:
        return LONG_DATA, split_vertex, relabel_counts, relabel_faces[:n_relabel]
    if at_back != backs.shape[0] or at_mask != masks.shape[0]:
        return LONG_DATA, split_vertex, relabel_counts, relabel_faces[:n_relabel]
    return 0, split_vertex, relabel_counts, relabel_faces[:n_relabel]

"""Split-stream (version 3) wedge coding: the appearance side of each vertex split, coded
against the wedges the split vertex already has.

One kernel, ``code_wedges``, serves both ends: it replays the splits' connectivity on its
own copy of the level (`WedgeLevel`: faces and per-vertex corner lists as in
``stream_coding.py``, the wedge of every corner, the wedges' quantised values) and,
corner by corner, either writes the symbol naming the wedge the split gives it
(encoding, targets from the progressive mesh's wedge records) or reads it (decoding).
Predictions and candidate lists are computed by the same lines in both directions.

Split i (s, t = n_from + i, W wedges before it, ``n_new`` new wedges W.. after):

- ``ws`` = the distinct wedges of s's corners before the split, sorted; ``L`` = ws, then
  the new wedges (sorted as a whole, since every new wedge is >= W);
- s's old corners ``cs`` (sorted) in order, then the corners of the split's new faces in
  face order, each get a symbol: 0 = the predicted wedge, 1..254 = candidate
  ``symbol - 1`` of the corner's list (``L`` at s and t, else the sorted distinct wedges
  of the vertex's earlier corners), ``ESCAPE`` = a back-distance ``W_after - wedge``;
- predictions: a corner that stays at s keeps its wedge; a corner moved to t takes what
  an earlier moved corner of the same old wedge took, else the lowest new wedge not yet
  taken when that old wedge also stays at s (a seam opens), else keeps it (the wedge
  moves with t); a new face's corner takes the wedge of the first of its vertex's
  earlier corners whose face holds the new face's vertex other than s and t (for that
  vertex itself: t), else one holding another vertex of the new face, else the first
  (at s, the moved corners are looked at first, with their old wedges: a new face lies
  between s's and t's fans and takes the wedge the moved side had);
- corners outside those whose wedge changes (none in practice) are *extra relabels*:
  back-distances ``3 F_after - corner`` and ``W_after - wedge``;
- value rows: one per wedge of ws (new value minus old: 0 when the split leaves it
  alone), one per *extra update* of a wedge outside ws (back-distance ``W - wedge``, then
  new minus old), one per new wedge (its value minus the old value of the wedge of ws
  whose moved corners took it, else of ws[0], else 0).

The fields are range-coded (``range_coder.py``, contexts of their own, carried from
frame to frame as the splits' are) by ``code_wedge_fields`` / ``decode_wedge_fields``,
one field after the other:

- counts, row by row (new wedges of every split, then extra updates, then extra
  relabels): unsigned Exp-Golomb, a context block per row;
- symbols: "is it 0?" with a context per class of the previous symbol (0, 1..254,
  ESCAPE), then symbol - 1 as an 8-bit tree;
- backs: unsigned Exp-Golomb;
- value rows, row by row, column by column: signed Exp-Golomb, a context block per
  (column, min(bit length of the same column of the previous row, 7), min(bit length
  of the previous column of this row, 3)) (the first row and column count 0).
"""

from typing import NamedTuple

import numba
import numpy as np

from . import range_coder as rc
from .stream_coding import (
    LONG_DATA,
    NO_CORNER,
    SHORT_DATA,
    WEDGE_WORK_LIMIT,
    _append_face,
    _distinct_sorted,
    _find,
    _grow,
    _relabel,
)

ESCAPE = 255
# Symbols 1..254 name candidates 0..253 of a corner's list; later ones are escaped.
LISTED = 254

# Decoder status codes, after stream_coding's 1..9 and before its 13 (0: fine); stream.py
# words them.
BAD_WEDGE = 10
BAD_WEDGE_CORNER = 11
BAD_VALUE = 12
TOO_MUCH_WEDGE_WORK = 14  # after stream_coding's TOO_MUCH_WORK

# No residual larger than this keeps a value on a grid of at most 16 bits (the decoder
# refuses one as it reads it, as wedges.js does: the viewer holds 32-bit values).
RESIDUAL_LIMIT = (1 << 16) - 1

# Cursors into the fields, an int64 array advanced as they are read or written.
AT_SYMBOL, AT_BACK, AT_ROW = 0, 1, 2


# Context slots of the coded fields (one probability array, ``wedge_context_slots``).
_COUNT_SLOTS = 0  # 3 integer blocks, a block per counts row
_ZERO_SLOTS = _COUNT_SLOTS + 3 * rc.INTEGER_SLOTS  # symbol is 0? per previous class
_SYMBOL_SLOTS = _ZERO_SLOTS + 3  # symbol - 1: 8-bit tree
_BACK_SLOTS = _SYMBOL_SLOTS + 255  # backs: integer
_ROW_SLOTS = _BACK_SLOTS + rc.INTEGER_SLOTS  # values: a block per (column, classes)
_ROW_CLASSES = 8  # bit length of the previous row's value in the column, capped
_COLUMN_CLASSES = 4  # bit length of the previous column's value in the row, capped


@numba.njit(cache=True, nogil=True)
def wedge_context_slots(width):
    """The probability slots the wedge fields of ``width`` columns use."""
    return _ROW_SLOTS + width * _ROW_CLASSES * _COLUMN_CLASSES * rc.INTEGER_SLOTS


@numba.njit(cache=True, nogil=True)
def _symbol_class(symbol):
    return 0 if symbol == 0 else (2 if symbol == ESCAPE else 1)


@numba.njit(cache=True, nogil=True)
def _row_context(rows, r, d):
    """The context block of value rows[r, d] (module docstring)."""
    above = rc.bit_length(rows[r - 1, d]) if r > 0 else 0
    left = rc.bit_length(rows[r, d - 1]) if d > 0 else 0
    block = (d * _ROW_CLASSES + min(above, _ROW_CLASSES - 1)) * _COLUMN_CLASSES
    return _ROW_SLOTS + (block + min(left, _COLUMN_CLASSES - 1)) * rc.INTEGER_SLOTS


@numba.njit(cache=True, nogil=True)
def code_wedge_fields(enc, out, probs, counts, symbols, backs, rows):
    """Range-code a frame's wedge fields (counts (3, K), symbols, backs, rows (R, k))
    in the order ``decode_wedge_fields`` reads them. Returns 0, or 1 when an integer was
    out of the coder's range (``range_coder.encode_integer``: the output is then
    wrong)."""
    bad = 0
    for row in range(3):
        for i in range(counts.shape[1]):
            bad |= rc.encode_integer(
                enc, out, probs, _COUNT_SLOTS + row * rc.INTEGER_SLOTS, counts[row, i], False
            )
    previous = 0
    for q in range(symbols.shape[0]):
        symbol = np.int64(symbols[q])
        rc.encode_bit(enc, out, probs, _ZERO_SLOTS + _symbol_class(previous), symbol != 0)
        if symbol != 0:
            rc.encode_tree(enc, out, probs, _SYMBOL_SLOTS, 8, symbol - 1)
        previous = symbol
    for q in range(backs.shape[0]):
        bad |= rc.encode_integer(enc, out, probs, _BACK_SLOTS, backs[q], False)
    for r in range(rows.shape[0]):
        for d in range(rows.shape[1]):
            bad |= rc.encode_integer(enc, out, probs, _row_context(rows, r, d), rows[r, d], True)
    return bad


@numba.njit(cache=True, nogil=True)
def decode_wedge_fields(data, k, n_symbols, n_backs, n_rows, width, probs):
    """Inverse of ``code_wedge_fields`` over all of ``data`` (the caller bounds the
    counts first) with the contexts ``probs`` (``wedge_context_slots(width)`` of them,
    fresh or as the stream's previous frame left them: they are updated). Returns
    (status, counts, symbols, backs, rows): status BAD_VALUE as soon as a residual is
    over RESIDUAL_LIMIT in magnitude, SHORT_DATA if the fields need more bytes than data
    has (or data is no coder output), LONG_DATA if they leave bytes unread, else 0."""
    reader = rc.reader_at(data, 0)  # the coder's state, in locals (range_coder.py)
    counts = np.zeros((3, k), np.int64)
    symbols = np.zeros(n_symbols, np.uint8)
    backs = np.zeros(n_backs, np.int64)
    rows = np.zeros((n_rows, width), np.int64)
    for row in range(3):
        for i in range(k):
            counts[row, i], reader = rc.read_integer(
                reader, data, probs, _COUNT_SLOTS + row * rc.INTEGER_SLOTS, False
            )
        if reader[rc.R_BROKEN]:
            return SHORT_DATA, counts, symbols, backs, rows
    previous = 0
    for q in range(n_symbols):
        symbol = 0
        nonzero, reader = rc.read_bit(reader, data, probs, _ZERO_SLOTS + _symbol_class(previous))
        if nonzero:
            symbol, reader = rc.read_tree(reader, data, probs, _SYMBOL_SLOTS, 8)
            symbol += 1
        symbols[q] = symbol
        previous = symbol
        if reader[rc.R_BROKEN]:
            return SHORT_DATA, counts, symbols, backs, rows
    for q in range(n_backs):
        backs[q], reader = rc.read_integer(reader, data, probs, _BACK_SLOTS, False)
        if reader[rc.R_BROKEN]:
            return SHORT_DATA, counts, symbols, backs, rows
    for r in range(n_rows):
        for d in range(width):
            rows[r, d], reader = rc.read_integer(
                reader, data, probs, _row_context(rows, r, d), True
            )
            if abs(rows[r, d]) > RESIDUAL_LIMIT:
                return BAD_VALUE, counts, symbols, backs, rows
        if reader[rc.R_BROKEN]:
            return SHORT_DATA, counts, symbols, backs, rows
    if reader[rc.R_BROKEN]:
        return SHORT_DATA, counts, symbols, backs, rows
    if reader[rc.R_POSITION] != data.shape[0]:
        return LONG_DATA, counts, symbols, backs, rows
    return 0, counts, symbols, backs, rows


class WedgeLevel(NamedTuple):
    """The level both ends hold, with room for the splits to come.

    faces (capacity, 3) int32, head (vertex capacity,) and nxt (3 capacity,) int64 its
    corner lists (``stream_coding.link_corners``); corner_wedge (3 capacity,) int64 the
    wedge of each corner; values (wedge capacity, k) int64 the wedges' grid integers;
    q_max (k,) int64 the largest integer of each column.
    """

    faces: np.ndarray
    head: np.ndarray
    nxt: np.ndarray
    corner_wedge: np.ndarray
    values: np.ndarray
    q_max: np.ndarray


class SplitRun(NamedTuple):
    """The connectivity of the splits (as decoded, or from the progressive mesh):
    split_vertex (K,) int32, new_faces (F_new, 3) int32 as born, new_face_counts (K,)
    int64, relabel_offsets (K + 1,) int64 and relabel_faces (R,) int32."""

    split_vertex: np.ndarray
    new_faces: np.ndarray
    new_face_counts: np.ndarray
    relabel_offsets: np.ndarray
    relabel_faces: np.ndarray


@numba.njit(cache=True, nogil=True)
def code_wedges(
    decoding, level, n_faces, n_wedges, n_from, run, records, counts, symbols, backs, rows
):
    """Code (decoding=False) or decode (True) the wedge side of splits n_from.. against
    ``level`` (a `WedgeLevel` of n_faces faces and n_wedges wedges), which advances to
    the level after the last split.

    Fields: counts (3, K) int64 (new wedges, extra updates, extra relabels per split),
    symbols uint8, backs int64, rows (R, k) int64 value residuals, in split order; read
    when decoding; when encoding, written (counts filled in place; the others grown as
    needed, so use the returned ones). ``records``: encoding, the wedge records of the
    splits (a ``progressive.WedgeSplits`` with its values quantised: int64 grid
    integers; runs relative to the first split); decoding, empty runs.

    Returns (status, symbols, backs, rows, at, n_wedges): status 0 or a decoder status
    code (the level is then partly advanced and must be dropped), ``at`` the number of
    symbols, backs and rows used.
    """
    width = level.values.shape[1]
    at = np.zeros(3, np.int64)
    cs = np.empty(16, np.int64)
    old = np.empty(16, np.int64)
    ws = np.empty(16, np.int64)
    listed = np.empty(16, np.int64)
    map_to = np.empty(16, np.int64)
    targets = np.empty(16, np.int64)
    before = np.zeros((16, width), np.int64)
    extras = np.empty(16, np.int64)
    status = 0
    face = n_faces
    new = 0
    work = np.zeros(1, np.int64)  # corners read (stream_coding.WEDGE_WORK_LIMIT)
    for i in range(run.split_vertex.shape[0]):
        s = run.split_vertex[i]
        t = n_from + i
        # The encoder's frames stay within the limit; a decoder refuses past a margin.
        work_cap = (2 if i > 0 else 8) * WEDGE_WORK_LIMIT if decoding else -1
        cs, nc, _ = _sorted_corners(level.head, level.nxt, s, 3 * face, cs)
        old = _grow(old, nc)
        ws = _grow(ws, nc)
        for q in range(nc):
            old[q] = level.corner_wedge[cs[q]]
            ws[q] = old[q]
        nws = _distinct_sorted(ws, nc)
        for r in range(run.relabel_offsets[i], run.relabel_offsets[i + 1]):
            if not _relabel(level.faces, level.head, level.nxt, run.relabel_faces[r], s, t):
                status = NO_CORNER
        if status:
            break
        first_face = face
        for q in range(new, new + run.new_face_counts[i]):
            f = run.new_faces[q]
            _append_face(level.faces, level.head, level.nxt, face, f[0], f[1], f[2])
            level.corner_wedge[3 * face : 3 * face + 3] = -1
            face += 1
        n_coded = nc + 3 * (face - first_face)
        targets = _grow(targets, n_coded)
        if not decoding:
            # Room for every relabel (corner, wedge) pair and update of split i.
            relabels = records.relabel_offsets[i + 1] - records.relabel_offsets[i]
            extras = _grow(
                extras, 2 * relabels + records.update_offsets[i + 1] - records.update_offsets[i]
            )
            _targets(
                level, records, i, cs, nc, old, ws, nws, first_face, face, new, counts,
                targets, extras,
            )  # fmt: skip
            symbols = _grow(symbols, at[AT_SYMBOL] + n_coded)
            backs = _grow(backs, at[AT_BACK] + n_coded + 2 * counts[2, i] + counts[1, i])
            rows = _grow_rows(rows, at[AT_ROW] + nws + counts[1, i] + counts[0, i])
        n_new = counts[0, i]
        if at[AT_SYMBOL] + n_coded > symbols.shape[0]:
            status = SHORT_DATA
        elif at[AT_ROW] + nws + counts[1, i] + n_new > rows.shape[0]:
            status = SHORT_DATA
        if status:
            break
        listed = _grow(listed, nws + n_new)
        listed[:nws] = ws[:nws]
        for j in range(n_new):
            listed[nws + j] = n_wedges + j
        map_to = _grow(map_to, nws)
        status = _code_corners(
            decoding, level, s, t, cs, nc, old, ws, nws, listed, n_new, n_wedges,
            first_face, face, targets, map_to, symbols, backs, at, work, work_cap,
        )  # fmt: skip
        if status:
            break
        status = _code_extra_relabels(
            decoding, level, counts[2, i], 3 * face, n_wedges + n_new, extras, backs, at,
        )  # fmt: skip
        if status:
            break
        before = _grow_rows(before, nws)
        status = _code_values(
            decoding, level, records, i, ws, nws, map_to, n_wedges, n_new, counts[1, i],
            extras[2 * counts[2, i] :], before, backs, rows, at,
        )  # fmt: skip
        if status:
            break
        n_wedges += n_new
        new += run.new_face_counts[i]
    if (
        status == 0
        and decoding
        and (
            at[AT_SYMBOL] != symbols.shape[0]
            or at[AT_BACK] != backs.shape[0]
            or at[AT_ROW] != rows.shape[0]
        )
    ):
        status = LONG_DATA
    return status, symbols, backs, rows, at, n_wedges


@numba.njit(cache=True, nogil=True)
def _targets(
    level, records, i, cs, nc, old, ws, nws, first_face, face, new, counts, targets, extras
):
    """Encoding: the wedge of each coded corner once split i is applied (its records'
    relabels over cs's old wedges and the new faces' wedges as born) into targets; the
    extra relabels (corner, wedge pairs), then the extra updates' record rows, into
    extras; split i's counts."""
    n_new_corners = 3 * (face - first_face)
    for q in range(nc):
        targets[q] = old[q]
    for q in range(n_new_corners):
        targets[nc + q] = records.new_face_wedges[new + q // 3, q % 3]
    n_extra = 0
    for r in range(records.relabel_offsets[i], records.relabel_offsets[i + 1]):
        c = records.relabel_corners[r]
        q = _find(cs, nc, c)
        if 3 * first_face <= c < 3 * face:
            targets[nc + c - 3 * first_face] = records.relabel_to[r]
        elif q >= 0:
            targets[q] = records.relabel_to[r]
        else:
            extras[2 * n_extra] = c
            extras[2 * n_extra + 1] = records.relabel_to[r]
            n_extra += 1
    n_updates = 0
    for u in range(records.update_offsets[i], records.update_offsets[i + 1]):
        if _find(ws, nws, records.update_ids[u]) < 0:
            extras[2 * n_extra + n_updates] = u
            n_updates += 1
    counts[0, i] = records.new_offsets[i + 1] - records.new_offsets[i]
    counts[1, i] = n_updates
    counts[2, i] = n_extra


@numba.njit(cache=True, nogil=True)
def _code_corners(
    decoding,
    level,
    s,
    t,
    cs,
    nc,
    old,
    ws,
    nws,
    listed,
    n_new,
    n_wedges,
    first_face,
    face,
    targets,
    map_to,
    symbols,
    backs,
    at,
    work,
    work_cap,
):
    """The symbols of split i's old corners of s and its new faces' corners (module
    docstring); sets their wedges and map_to (the wedge each old wedge's moved corners
    took, -1 if none). Adds the corners it reads to work[0], and stops with
    TOO_MUCH_WEDGE_WORK past ``work_cap`` (-1: no cap). Returns a status."""
    faces = level.faces
    after = n_wedges + n_new
    n_listed = nws + n_new
    map_to[:nws] = -1
    stays = np.zeros(nws, np.uint8)
    taken = np.zeros(n_new, np.uint8)
    for q in range(nc):
        if faces[cs[q] // 3, cs[q] % 3] == s:
            stays[_find(ws, nws, old[q])] = 1
    fresh = 0  # the lowest new wedge not taken yet
    mine = np.empty(16, np.int64)
    theirs = np.empty(16, np.int64)
    for z in range(nc + 3 * (face - first_face)):
        c = cs[z] if z < nc else 3 * first_face + z - nc
        v = faces[c // 3, c % 3]
        choices = listed
        n_choices = n_listed
        read = 0  # corners of v read for this corner (each read is one chain: bounded)
        if v != s and v != t:
            mine, n_mine, read = _sorted_corners(level.head, level.nxt, v, c, mine)
            theirs = _grow(theirs, n_mine)
            for q in range(n_mine):
                theirs[q] = level.corner_wedge[mine[q]]
            choices = theirs
            n_choices = _distinct_sorted(theirs, n_mine)
        slot = -1
        if z < nc:
            slot = _find(ws, nws, old[z])
            if v == s:
                predicted = old[z]
            elif map_to[slot] >= 0:
                predicted = map_to[slot]
            elif stays[slot] and fresh < n_new:
                predicted = n_wedges + fresh
            else:
                predicted = old[z]
        else:
            predicted, predict_read = _predict_new_corner(level, c, s, t, cs, nc, old, mine)
            read += predict_read
            if predicted < 0 and (v == s or v == t) and n_listed > 0:
                predicted = n_wedges + fresh if fresh < n_new else listed[0]
        work[0] += read
        if 0 <= work_cap < work[0]:
            return TOO_MUCH_WEDGE_WORK
        if decoding:
            symbol = symbols[at[AT_SYMBOL]]
            wedge = -1
            if symbol == 0:
                wedge = predicted
            elif symbol == ESCAPE:
                if at[AT_BACK] >= backs.shape[0]:
                    return SHORT_DATA
                wedge = after - backs[at[AT_BACK]]
                at[AT_BACK] += 1
            elif symbol - 1 < n_choices:
                wedge = choices[symbol - 1]
            if wedge < 0 or wedge >= after:
                return BAD_WEDGE
        else:
            wedge = targets[z]
            index = _find(choices, n_choices, wedge)
            if wedge == predicted:
                symbols[at[AT_SYMBOL]] = 0
            elif 0 <= index < LISTED:
                symbols[at[AT_SYMBOL]] = 1 + index
            else:
                symbols[at[AT_SYMBOL]] = ESCAPE
                backs[at[AT_BACK]] = after - wedge
                at[AT_BACK] += 1
        at[AT_SYMBOL] += 1
        level.corner_wedge[c] = wedge
        if z < nc and v == t and map_to[slot] < 0:
            map_to[slot] = wedge
            if n_wedges <= wedge < after:
                taken[wedge - n_wedges] = 1
                while fresh < n_new and taken[fresh]:
                    fresh += 1
    return 0


@numba.njit(cache=True, nogil=True)
def _code_extra_relabels(decoding, level, n_extra, n_corners, after, extras, backs, at):
    """Extra relabels: corners outside s's fan and the new faces (encoding: the pairs
    in extras). Returns a status."""
    for e in range(n_extra):
        if decoding:
            if at[AT_BACK] + 2 > backs.shape[0]:
                return SHORT_DATA
            c = n_corners - backs[at[AT_BACK]]
            wedge = after - backs[at[AT_BACK] + 1]
            if c < 0 or c >= n_corners:
                return BAD_WEDGE_CORNER
            if wedge < 0 or wedge >= after:
                return BAD_WEDGE
        else:
            c = extras[2 * e]
            wedge = extras[2 * e + 1]
            backs[at[AT_BACK]] = n_corners - c
            backs[at[AT_BACK] + 1] = after - wedge
        at[AT_BACK] += 2
        level.corner_wedge[c] = wedge
    return 0


@numba.njit(cache=True, nogil=True)
def _code_values(
    decoding,
    level,
    records,
    i,
    ws,
    nws,
    map_to,
    n_wedges,
    n_new,
    n_updates,
    update_rows,
    before,
    backs,
    rows,
    at,
):
    """The value rows of split i: ws, extra updates (encoding: their record rows in
    update_rows), new wedges. Returns a status: decoding, BAD_VALUE as soon as a value
    written leaves its grid (each is checked as it is written, as wedges.js does)."""
    values = level.values
    width = values.shape[1]
    row = at[AT_ROW]
    for q in range(nws):
        before[q] = values[ws[q]]
    if decoding:
        if at[AT_BACK] + n_updates > backs.shape[0]:
            return SHORT_DATA
        for q in range(nws):
            values[ws[q]] = before[q] + rows[row + q]
            if not _in_grid(values, ws[q], level.q_max):
                return BAD_VALUE
        for e in range(n_updates):
            wedge = n_wedges - backs[at[AT_BACK] + e]
            if wedge < 0 or wedge >= n_wedges:
                return BAD_WEDGE
            values[wedge] += rows[row + nws + e]
            if not _in_grid(values, wedge, level.q_max):
                return BAD_VALUE
    else:
        for e in range(n_updates):
            u = update_rows[e]
            wedge = records.update_ids[u]
            backs[at[AT_BACK] + e] = n_wedges - wedge
            rows[row + nws + e] = records.update_values[u] - values[wedge]
            values[wedge] = records.update_values[u]
        for u in range(records.update_offsets[i], records.update_offsets[i + 1]):
            values[records.update_ids[u]] = records.update_values[u]
        for q in range(nws):
            rows[row + q] = values[ws[q]] - before[q]
            if not _in_grid(values, ws[q], level.q_max):
                return BAD_VALUE
    at[AT_BACK] += n_updates
    for j in range(n_new):
        parent = 0 if nws > 0 else -1
        for q in range(nws):
            if map_to[q] == n_wedges + j:
                parent = q
                break
        wedge = n_wedges + j
        r = row + nws + n_updates + j
        for d in range(width):
            predicted = before[parent, d] if parent >= 0 else 0
            if decoding:
                values[wedge, d] = predicted + rows[r, d]
            else:
                values[wedge, d] = records.new_values[records.new_offsets[i] + j, d]
                rows[r, d] = values[wedge, d] - predicted
        if not _in_grid(values, wedge, level.q_max):
            return BAD_VALUE
    at[AT_ROW] = row + nws + n_updates + n_new
    return 0


@numba.njit(cache=True, nogil=True)
def _in_grid(values, wedge, q_max):
    for d in range(values.shape[1]):
        if values[wedge, d] < 0 or values[wedge, d] > q_max[d]:
            return False
    return True


@numba.njit(cache=True, nogil=True)
def _predict_new_corner(level, c, s, t, cs, nc, old, mine):
    """(The predicted wedge of corner c of a new face (module docstring), -1 when its
    vertex has no earlier corner to copy; the corners read of that vertex). ``mine`` is
    scratch."""
    faces = level.faces
    f = c // 3
    j = c % 3
    v = faces[f, j]
    u = faces[f, (j + 1) % 3]
    w = faces[f, (j + 2) % 3]
    if v == s or v == t:
        preferred_a = u if u != s and u != t else -1
        preferred_b = w if w != s and w != t else -1
    else:
        preferred_a = t
        preferred_b = -1
    best = 0
    predicted = -1
    first = -1
    if v == s:
        for q in range(nc):
            corner = cs[q]
            if faces[corner // 3, corner % 3] != t:
                continue
            if first < 0:
                first = old[q]
            score = _face_score(faces, corner // 3, u, w, preferred_a, preferred_b)
            if score > best:
                best = score
                predicted = old[q]
    mine, n_mine, read = _sorted_corners(level.head, level.nxt, v, c, mine)
    for q in range(n_mine):
        corner = mine[q]
        if first < 0:
            first = level.corner_wedge[corner]
        score = _face_score(faces, corner // 3, u, w, preferred_a, preferred_b)
        if score > best:
            best = score
            predicted = level.corner_wedge[corner]
    return (predicted if predicted >= 0 else first), read


@numba.njit(cache=True, nogil=True)
def _sorted_corners(head, nxt, v, below, out):
    """v's corners numbered below ``below``, ascending, into out (grown if need be);
    returns (out, their count, the count of all v's corners: those read)."""
    count = 0
    c = head[v]
    while c != -1:
        count += 1
        c = nxt[c]
    out = _grow(out, count)
    n = 0
    c = head[v]
    while c != -1:
        if c < below:
            out[n] = c
            n += 1
        c = nxt[c]
    out[:n].sort()
    return out, n, count


@numba.njit(cache=True, nogil=True)
def _face_score(faces, face, u, w, preferred_a, preferred_b):
    """2 if the face holds a preferred vertex, 1 if it holds u or w, else 0 (-1 for a
    preferred vertex means none)."""
    score = 0
    for j in range(3):
        x = faces[face, j]
        if x == preferred_a or x == preferred_b:
            return 2
        if x == u or x == w:
            score = 1
    return score


@numba.njit(cache=True, nogil=True)
def _grow_rows(rows, need):
    if need <= rows.shape[0]:
        return rows
    grown = np.zeros((max(2 * rows.shape[0], need), rows.shape[1]), rows.dtype)
    grown[: rows.shape[0]] = rows
    return grown

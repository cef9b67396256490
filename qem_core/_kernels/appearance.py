"""Appearance attributes and volume in the contraction cost (Hoppe 1999 and 2000).

**Wedges.** An attribute value (a UV, a colour, a normal: m floats in all) belongs to a
*wedge*: one vertex's corners that share it. A vertex inside a texture chart has one
wedge; a vertex on a UV seam has one per side. Each face corner names its wedge
(``face_wedges``), and positions stay shared, so a seam never opens in space.

**The quadric.** Over a face, each attribute j is the linear function s_j(p) = g_j.p + d_j
that interpolates its corners (g_j in the face's plane). The face's appearance quadric
measures sum_j (g_j.p + d_j - s_j)^2, weighted like the face's plane: in (p, s) it is

    Q(p, s) = p^T A p + 2 p^T B s + alpha s^T s + 2 b1^T p + 2 b2^T s + c

with A = sum g g^T, B = -[g_1 .. g_m], alpha = 1, b1 = sum d_j g_j, b2 = -d, c = |d|^2,
all times the weight. Every corner's wedge sums the quadrics of its faces. A wedge row is
``[A (6), b1 (3), c, alpha, B (3m, column by column), b2 (m)]``: its first ten entries
have the layout of a position quadric (quadrics.py).

**Minimising in O(m)** (Hoppe 2000): for fixed p the best s is -(B^T p + b2) / alpha,
and putting it back leaves the position quadric (A - B B^T / alpha, b1 - B b2 / alpha,
c - |b2|^2 / alpha): a 3x3 Schur complement. Contracting (a, b) merges the wedges of a
with the wedges of b they meet across the faces that die (union-find over those faces),
each merged group has its own s, so the cost of the contraction is the position quadric
plus one Schur complement per group, minimised as usual (placement.py).

**Volume** (optional, volume.py): the contraction keeps the volume enclosed by the faces
around a and b, a linear constraint g.p = h on the new position, met with a Lagrange
multiplier.

Everything is passed as ``look``, a tuple of borrowed arrays (see memory.py: a tuple of
them costs no reference counting)::

    look = (face_wedges (m, 3) int32, wedge_quadrics (W, 11 + 4m), wedge_values (W, m),
            wedge_tag (W,) int64, wedge_slot (W,) int32, members (C, 2) int32,
            group_rows (C, 11 + 4m), counter (2,) int64 [generation, members gathered],
            settings (4,) float64, value_bounds (2, m) float64, total (10,) float64,
            group_values (C, m) float64)

``settings`` = [preserve volume (0/1), offset of the UV pair in a value row (-1: none),
0, 0]. With no wedges (W = 0) and no volume, costs are the plain ones.
"""

import numba
import numpy as np

from .adjacency import corner_of, has_corner
from .heap import cost_key, pair
from .memory import borrowing_kernel
from .placement import contraction_quadric, edge_cost, place
from .quadrics import QUADRIC_SIZE, area_weight
from .volume import place_keeping_volume

SETTING_VOLUME = 0
SETTING_UV_OFFSET = 1
N_SETTINGS = 4

ALPHA = QUADRIC_SIZE  # column of alpha in a wedge row
B_START = QUADRIC_SIZE + 1


def wedge_row_size(m):
    return 11 + 4 * m


def _fill_wedge_quadrics(vertices, faces, face_wedges, wedge_values, weighting, out):
    """Sum each face's appearance quadric into the wedges of its three corners.

    out : (W, 11 + 4m) zeros. A face of zero area adds nothing (it has no plane).
    """
    m = wedge_values.shape[1]
    row = np.zeros(out.shape[1])
    for f in range(faces.shape[0]):
        i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
        e1 = vertices[i1] - vertices[i0]
        e2 = vertices[i2] - vertices[i0]
        n = np.cross(e1, e2)
        length = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        if length == 0.0:
            continue
        n = n / length
        # The gradient g with g.e1 = ds1, g.e2 = ds2, g.n = 0: the inverse of the matrix
        # with rows e1, e2, n has columns (e2 x n, n x e1, e1 x e2) / det.
        c1 = np.cross(e2, n)
        c2 = np.cross(n, e1)
        det = e1[0] * c1[0] + e1[1] * c1[1] + e1[2] * c1[2]
        if det == 0.0:
            continue
        weight = area_weight(0.5 * length, weighting)
        row[:] = 0.0
        row[ALPHA] = weight
        w0, w1, w2 = face_wedges[f, 0], face_wedges[f, 1], face_wedges[f, 2]
        for j in range(m):
            s0 = wedge_values[w0, j]
            ds1 = wedge_values[w1, j] - s0
            ds2 = wedge_values[w2, j] - s0
            gx = (ds1 * c1[0] + ds2 * c2[0]) / det
            gy = (ds1 * c1[1] + ds2 * c2[1]) / det
            gz = (ds1 * c1[2] + ds2 * c2[2]) / det
            d = s0 - (gx * vertices[i0, 0] + gy * vertices[i0, 1] + gz * vertices[i0, 2])
            row[0] += weight * gx * gx
            row[1] += weight * gx * gy
            row[2] += weight * gx * gz
            row[3] += weight * gy * gy
            row[4] += weight * gy * gz
            row[5] += weight * gz * gz
            row[6] += weight * d * gx
            row[7] += weight * d * gy
            row[8] += weight * d * gz
            row[9] += weight * d * d
            row[B_START + 3 * j] = -weight * gx
            row[B_START + 3 * j + 1] = -weight * gy
            row[B_START + 3 * j + 2] = -weight * gz
            row[B_START + 3 * m + j] = -weight * d
        for k in range(3):
            w = face_wedges[f, k]
            for d in range(out.shape[1]):
                out[w, d] += row[d]


fill_wedge_quadrics = numba.njit(cache=True)(_fill_wedge_quadrics)


def _add_schur(row, m, quadric):
    """Add the position quadric left by minimising ``row`` over its attributes."""
    alpha = row[ALPHA]
    for k in range(QUADRIC_SIZE):
        quadric[k] += row[k]
    if alpha <= 0.0:
        return
    b2 = B_START + 3 * m
    for j in range(m):
        gx, gy, gz = row[B_START + 3 * j], row[B_START + 3 * j + 1], row[B_START + 3 * j + 2]
        e = row[b2 + j]
        quadric[0] -= gx * gx / alpha
        quadric[1] -= gx * gy / alpha
        quadric[2] -= gx * gz / alpha
        quadric[3] -= gy * gy / alpha
        quadric[4] -= gy * gz / alpha
        quadric[5] -= gz * gz / alpha
        quadric[6] -= gx * e / alpha
        quadric[7] -= gy * e / alpha
        quadric[8] -= gz * e / alpha
        quadric[9] -= e * e / alpha


add_schur = numba.njit(cache=True, inline="always")(_add_schur)


def _best_attributes(row, m, px, py, pz, fallback, bounds, out):
    """s = -(B^T p + b2) / alpha, clamped into the input's range; ``fallback`` (m,) when
    the row has no weight."""
    alpha = row[ALPHA]
    for j in range(m):
        if alpha <= 0.0:
            out[j] = fallback[j]
            continue
        base = B_START + 3 * j
        value = -(row[base] * px + row[base + 1] * py + row[base + 2] * pz
                  + row[B_START + 3 * m + j]) / alpha
        out[j] = min(max(value, bounds[0, j]), bounds[1, j])


best_attributes = numba.njit(cache=True, inline="always")(_best_attributes)


def _find_root(members, i):
    while members[i, 1] != i:
        members[i, 1] = members[members[i, 1], 1]
        i = members[i, 1]
    return i


find_root = numba.njit(cache=True, inline="always")(_find_root)


def _gather_groups(faces, face_alive, start, count, pool, a, b, look):
    """The wedges of a and b (``members`` rows: wedge, root), joined across the faces
    that contain both; each root's row of ``group_rows`` gets its group's summed
    quadric. Returns the number of members, or -1 if there are more than fit."""
    face_wedges, wedge_quadrics = look[0], look[1]
    wedge_tag, wedge_slot, members = look[3], look[4], look[5]
    group_rows, counter = look[6], look[7]
    counter[0] += 1
    g = counter[0]
    n = 0
    for side in range(2):
        v = a if side == 0 else b
        s = start[v]
        for i in range(count[v]):
            f = pool[s + i]
            if not face_alive[f]:
                continue
            w = face_wedges[f, corner_of(faces, f, v)]
            if wedge_tag[w] == g:
                continue
            if n == members.shape[0]:
                return -1
            wedge_tag[w] = g
            wedge_slot[w] = n
            members[n, 0] = w
            members[n, 1] = n
            n += 1
    s = start[a]
    for i in range(count[a]):
        f = pool[s + i]
        if not face_alive[f]:
            continue
        if not has_corner(faces, f, b):
            continue
        ra = find_root(members, wedge_slot[face_wedges[f, corner_of(faces, f, a)]])
        rb = find_root(members, wedge_slot[face_wedges[f, corner_of(faces, f, b)]])
        if ra != rb:
            # The earlier member stays root: the survivor is the first wedge met.
            members[max(ra, rb), 1] = min(ra, rb)
    for i in range(n):
        find_root(members, i)
    for i in range(n):
        if members[i, 1] == i:
            group_rows[i, :] = 0.0
    for i in range(n):
        r = members[i, 1]
        w = members[i, 0]
        for d in range(group_rows.shape[1]):
            group_rows[r, d] += wedge_quadrics[w, d]
    return n


gather_groups = borrowing_kernel(_gather_groups)


def _appearance_cost(vertices, vertex_quadrics, edge_quadrics, a, b, edge, exact,
                     rank_tolerance, quadric, position, faces, face_alive, start, count, pool,
                     look):
    """`candidate_cost` with wedges or volume: a kernel of its own, called, not inlined.
    Inlined at each of candidate_cost's call sites it was most of the package's compile
    time, for meshes that have neither."""
    wedge_quadrics, settings = look[1], look[8]
    contraction_quadric(vertex_quadrics, edge_quadrics, a, b, edge, exact, quadric)
    total = look[10]
    for k in range(QUADRIC_SIZE):  # a loop: an array copy would allocate (no NRT here)
        total[k] = quadric[k]
    if wedge_quadrics.shape[0] > 0:
        n = gather_groups(faces, face_alive, start, count, pool, a, b, look)
        look[7][1] = n
        if n < 0:
            return np.inf
        m = look[2].shape[1]
        members, group_rows = look[5], look[6]
        for i in range(n):
            if members[i, 1] == i:
                add_schur(group_rows[i], m, total)
    if settings[SETTING_VOLUME] != 0.0:
        return place_keeping_volume(total, vertices, faces, start, count, pool, a, b,
                                    rank_tolerance, position)
    return place(total, vertices, a, b, rank_tolerance, position)


appearance_cost = borrowing_kernel(_appearance_cost)


def _candidate_cost(vertices, vertex_quadrics, edge_quadrics, a, b, edge, exact,
                    rank_tolerance, quadric, position, faces, face_alive, start, count, pool,
                    look):
    """Cost and position of contracting (a, b), appearance and volume included;
    ``quadric`` receives the position quadric of the new vertex (without the wedges,
    which stay in ``group_rows`` for `merge_wedges`). Infinite when the wedges of a and
    b do not fit the scratch space."""
    if look[1].shape[0] == 0 and look[8][SETTING_VOLUME] == 0.0:
        return edge_cost(vertices, vertex_quadrics, edge_quadrics, a, b, edge, exact,
                         rank_tolerance, quadric, position)
    # int64 ids at every call site (some pass int32 ones): one compilation, not five.
    return appearance_cost(vertices, vertex_quadrics, edge_quadrics, np.int64(a), np.int64(b),
                           np.int64(edge), exact, rank_tolerance, quadric, position, faces,
                           face_alive, start, count, pool, look)


candidate_cost = numba.njit(cache=True, inline="always")(_candidate_cost)


def _uv_keeps_orientation(faces, face_alive, start, count, pool, a, b, look):
    """Would the new wedge values (`new_wedge_values`) keep every surviving face's UV
    triangle from flipping or collapsing?"""
    face_wedges, wedge_values, wedge_slot, members = look[0], look[2], look[4], look[5]
    values = look[11]
    uv = int(look[8][SETTING_UV_OFFSET])
    for side in range(2):
        v, other = (a, b) if side == 0 else (b, a)
        s = start[v]
        for i in range(count[v]):
            f = pool[s + i]
            if not face_alive[f]:
                continue
            if has_corner(faces, f, other):
                continue  # dies with the contraction
            k = corner_of(faces, f, v)
            w0, w1, w2 = face_wedges[f, k], face_wedges[f, (k + 1) % 3], face_wedges[f, (k + 2) % 3]
            u1, v1 = wedge_values[w1, uv], wedge_values[w1, uv + 1]
            u2, v2 = wedge_values[w2, uv], wedge_values[w2, uv + 1]
            before = ((u1 - wedge_values[w0, uv]) * (v2 - wedge_values[w0, uv + 1])
                      - (v1 - wedge_values[w0, uv + 1]) * (u2 - wedge_values[w0, uv]))
            r = members[wedge_slot[w0], 1]
            nu, nv = values[r, uv], values[r, uv + 1]
            after = (u1 - nu) * (v2 - nv) - (v1 - nv) * (u2 - nu)
            if before > 0.0 and not after > 0.0:
                return False
            if before < 0.0 and not after < 0.0:
                return False
    return True


uv_keeps_orientation = borrowing_kernel(_uv_keeps_orientation)


def _new_wedge_values(position, look):
    """Each group gathered by the last cost: its best values at ``position``, written at
    its root's row of ``group_values``."""
    wedge_values, members, group_rows, bounds = look[2], look[5], look[6], look[9]
    values = look[11]
    m = wedge_values.shape[1]
    for i in range(look[7][1]):
        if members[i, 1] == i:
            best_attributes(group_rows[i], m, position[0], position[1], position[2],
                            wedge_values[members[i, 0]], bounds, values[i])


new_wedge_values = borrowing_kernel(_new_wedge_values)


def _merge_wedges(faces, face_alive, start, count, pool, a, b, look, log, log_values,
                  n_log, relabel, n_relabel):
    """Apply the groups of the contraction (a, b) -> a, gathered by the cost: the first
    wedge of each group survives with the group's quadric and new values, the others
    retire, and corners that named a retired wedge name the survivor.

    Logged for the progressive mesh: per member a row (wedge, survivor) of ``log`` with
    its values before the contraction in ``log_values``; per rewritten corner a row
    (face, corner, wedge it named) of ``relabel``. Run before the faces are rewritten (faces
    with both a and b are the dying ones). Returns the new (n_log, n_relabel).
    """
    face_wedges, wedge_quadrics, wedge_values = look[0], look[1], look[2]
    wedge_slot, members, group_rows, values = look[4], look[5], look[6], look[11]
    m = wedge_values.shape[1]
    n = look[7][1]
    for i in range(n):
        w = members[i, 0]
        survivor = members[members[i, 1], 0]
        log[n_log, 0] = w
        log[n_log, 1] = survivor
        for j in range(m):
            log_values[n_log, j] = wedge_values[w, j]
        n_log += 1
    for i in range(n):
        if members[i, 1] != i:
            continue
        w = members[i, 0]
        for j in range(m):
            wedge_values[w, j] = values[i, j]
        for d in range(wedge_quadrics.shape[1]):
            wedge_quadrics[w, d] = group_rows[i, d]
    for side in range(2):
        v, other = (a, b) if side == 0 else (b, a)
        s = start[v]
        for i in range(count[v]):
            f = pool[s + i]
            if not face_alive[f]:
                continue
            if has_corner(faces, f, other):
                continue  # dies with the contraction
            k = corner_of(faces, f, v)
            w = face_wedges[f, k]
            survivor = members[members[wedge_slot[w], 1], 0]
            if survivor != w:
                face_wedges[f, k] = survivor
                relabel[n_relabel, 0] = f
                relabel[n_relabel, 1] = k
                relabel[n_relabel, 2] = w
                n_relabel += 1
    return n_log, n_relabel


merge_wedges = borrowing_kernel(_merge_wedges)


def _fill_costs(vertices, vertex_quadrics, edge_quadrics, edges, exact, rank_tolerance,
                faces, face_alive, start, count, pool, look, heap_entries):
    """First costs of every candidate with wedges or volume (in one thread: the groups
    use shared scratch space). Rows as ``setup.fill_heap`` writes them."""
    quadric = np.zeros(QUADRIC_SIZE)
    position = np.zeros(3)
    for e in range(edges.shape[0]):
        a, b = edges[e, 0], edges[e, 1]
        cost = candidate_cost(vertices, vertex_quadrics, edge_quadrics, a, b, e, exact,
                              rank_tolerance, quadric, position, faces, face_alive, start,
                              count, pool, look)
        heap_entries[e, 0] = cost_key(cost)
        heap_entries[e, 1] = pair(a, b)
        heap_entries[e, 2] = e


fill_costs = numba.njit(cache=True)(_fill_costs)

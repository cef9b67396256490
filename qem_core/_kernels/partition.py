"""Whole-complex passes of a parallel round (rounds.py): its live edges, and the parts."""

import numba
import numpy as np

from .adjacency import chunk_starts
from .link import PART_FROZEN
from .memory import prefetch


def _part_edges(faces, face_alive, face_edge, part, n_edge_ids, region_start, region_end,
                ids, ends, found):
    """The edges of the live faces whose two ends are in one part p (p < found.size),
    each once, in order of first appearance, in one pass: part p's are written from row
    region_start[p] of ``ids`` (their ids) and ``ends`` (their ends, the side's
    direction in the face that lists it first), and counted in ``found[p]``; only those
    that fit before region_end[p] are written (three rows per face with all corners in p
    always hold them).
    """
    seen = np.zeros(n_edge_ids, np.uint8)
    n_parts = found.shape[0]
    found[:] = 0
    for f in range(faces.shape[0]):
        if not face_alive[f]:
            continue
        for k in range(3):
            edge = face_edge[f, k]
            p = part[faces[f, k]]
            if seen[edge] or p >= n_parts or part[faces[f, (k + 1) % 3]] != p:
                continue
            seen[edge] = 1
            i = region_start[p] + found[p]
            found[p] += 1
            if i < region_end[p]:  # else the caller raises on found
                ids[i] = edge
                ends[i, 0] = faces[f, k]
                ends[i, 1] = faces[f, (k + 1) % 3]


part_edges = numba.njit(cache=True)(_part_edges)


def _label_runs(vertex_alive, n_parts, shift, part):
    """part[v] for the live vertices, in index order: n_parts runs of equal size, moved
    on by ``shift`` (a fraction) of a run, the last wrapping round to the first
    vertices; PART_FROZEN for the dead. One pass to count, one to label (numpy's
    flatnonzero, arange and arithmetic over the live vertices took 6-8 ms a round)."""
    n_live = 0
    for v in range(vertex_alive.shape[0]):
        if vertex_alive[v] != 0:
            n_live += 1
    rank = np.int64(int(shift * n_live) // n_parts)
    for v in range(vertex_alive.shape[0]):
        if vertex_alive[v] != 0:
            part[v] = rank * n_parts // n_live % n_parts
            rank += 1
        else:
            part[v] = PART_FROZEN


label_runs = numba.njit(cache=True)(_label_runs)


def _freeze_band(faces, face_alive, part, vertices_in_part, faces_in_part):
    """Every corner of a live face whose corners lie in different parts becomes
    PART_FROZEN: what is left in a part has all its neighbours in that part.

    part : (n,) uint8, in and out (PART_FROZEN for dead vertices too). Counts, out:
    vertices_in_part (256,) int64 the live vertices left in each part, faces_in_part
    (256,) int64 the live faces with all corners in each part (their own or frozen)."""
    label = part.copy()
    vertices_in_part[:] = 0
    faces_in_part[:] = 0
    for f in range(faces.shape[0]):
        if not face_alive[f]:
            continue
        p0, p1, p2 = label[faces[f, 0]], label[faces[f, 1]], label[faces[f, 2]]
        if p0 == p1 and p1 == p2:
            faces_in_part[p0] += 1
            continue
        for k in range(3):
            part[faces[f, k]] = PART_FROZEN
    for v in range(part.shape[0]):
        vertices_in_part[part[v]] += 1


freeze_band = numba.njit(cache=True)(_freeze_band)


def _morton_codes(vertices, low, scale, bits, codes):
    """codes (n,) uint64 out: the z-order code of each vertex on a 2^bits grid, the
    grid cell of a coordinate x being floor((x - low) * scale), clamped to the grid."""
    top = (1 << bits) - 1
    for i in numba.prange(vertices.shape[0]):
        code = np.uint64(0)
        for axis in range(3):
            cell = (vertices[i, axis] - low[axis]) * scale
            q = 0 if not cell > 0.0 else min(int(cell), top)
            for bit in range(bits):
                if (q >> bit) & 1:
                    code |= np.uint64(1) << np.uint64(3 * bit + 2 - axis)
        codes[i] = code


morton_codes = numba.njit(cache=True, parallel=True)(_morton_codes)


# Bits of the code a pass of `order_by_code` sorts on: 2^11 counters fit the L1 cache.
RADIX_BITS = 11


def _order_by_code(codes, code_bits):
    """(n,) int64: the indices 0..n-1 by increasing codes[i] (uint64, below 2^code_bits),
    ties by index, as np.argsort(codes, kind="stable") gives them, by a least-significant-
    digit radix sort, RADIX_BITS a pass (three for the 30-bit z-order codes; the merge
    sort of np.argsort took 30-40 ms for the dragon's vertices)."""
    n = codes.shape[0]
    order = np.arange(n)
    scratch = np.empty(n, np.int64)
    count = np.empty((1 << RADIX_BITS) + 1, np.int64)
    mask = np.uint64((1 << RADIX_BITS) - 1)
    shift = 0
    while shift < code_bits:
        count[:] = 0
        for i in range(n):
            count[((codes[i] >> np.uint64(shift)) & mask) + 1] += 1
        for digit in range(1 << RADIX_BITS):
            count[digit + 1] += count[digit]
        for i in range(n):
            v = order[i]
            digit = (codes[v] >> np.uint64(shift)) & mask
            scratch[count[digit]] = v
            count[digit] += 1
        order, scratch = scratch, order
        shift += RADIX_BITS
    return order


order_by_code = numba.njit(cache=True)(_order_by_code)


def _faces_by_lowest_corner(faces, rank, face_order, renumbered, n_chunks):
    """A stable counting sort of the faces by their lowest corner in the new numbering
    ``rank``: face_order (m,) out, and renumbered (m, 3) int32 out, faces[face_order]
    with each corner v written rank[v]. In ``n_chunks`` chunks of faces, in parallel,
    each chunk's faces of a corner after the earlier chunks' (adjacency.chunk_starts):
    the same order for any number of chunks."""
    n_faces = faces.shape[0]
    offset = np.zeros((n_chunks, rank.shape[0]), np.int64)
    for chunk in numba.prange(n_chunks):
        for f in range(chunk * n_faces // n_chunks, (chunk + 1) * n_faces // n_chunks):
            offset[chunk, min(rank[faces[f, 0]], rank[faces[f, 1]], rank[faces[f, 2]])] += 1
    chunk_starts(offset, np.empty(rank.shape[0], np.int64))
    for chunk in numba.prange(n_chunks):
        for f in range(chunk * n_faces // n_chunks, (chunk + 1) * n_faces // n_chunks):
            a, b, c = rank[faces[f, 0]], rank[faces[f, 1]], rank[faces[f, 2]]
            low = min(a, b, c)
            i = offset[chunk, low]
            offset[chunk, low] = i + 1
            face_order[i] = f
            renumbered[i, 0], renumbered[i, 1], renumbered[i, 2] = a, b, c


faces_by_lowest_corner = numba.njit(cache=True, parallel=True)(_faces_by_lowest_corner)


# How many faces (edges) ahead `renumber_edges` asks for the rows it will read.
RENUMBER_AHEAD = 8


def _renumber_edges(face_edge, face_order, edges, edge_face_count, rank, new_face_edge,
                    new_edges, new_face_count, new_side):
    """The edges of a mesh renumbered by `faces_by_lowest_corner`: numbered in order of
    first appearance in the new face order (neighbouring edges get near ids), with
    (low, high) ends in the new vertex numbering, their face counts, and the last side
    3 f + k on each. The outputs are shaped like prepare.MeshEdges'."""
    new_id = np.full(edges.shape[0], -1, np.int64)
    n_edges = 0
    n_faces = face_order.shape[0]
    for i in range(n_faces):
        # The old faces and edges are met in z-order, all over their arrays: ask ahead
        # for a face's edges, then for their new ids (RENUMBER_AHEAD faces apart).
        if i + 2 * RENUMBER_AHEAD < n_faces:
            prefetch(face_edge, face_order[i + 2 * RENUMBER_AHEAD], 0)
        if i + RENUMBER_AHEAD < n_faces:
            ahead = face_order[i + RENUMBER_AHEAD]
            for k in range(3):
                prefetch(new_id, face_edge[ahead, k], 0)
        f = face_order[i]
        for k in range(3):
            old = face_edge[f, k]
            e = new_id[old]
            if e < 0:
                e = n_edges
                new_id[old] = e
                n_edges += 1
            new_face_edge[i, k] = e
            new_side[e] = 3 * i + k
    # Each old edge writes its own new row: in threads (a third of the serial time).
    for old in numba.prange(edges.shape[0]):
        if old + RENUMBER_AHEAD < edges.shape[0]:
            prefetch(new_edges, new_id[old + RENUMBER_AHEAD], 0)
            prefetch(rank, edges[old + RENUMBER_AHEAD, 0], 0)
            prefetch(rank, edges[old + RENUMBER_AHEAD, 1], 0)
        e = new_id[old]
        a, b = rank[edges[old, 0]], rank[edges[old, 1]]
        new_edges[e, 0] = min(a, b)
        new_edges[e, 1] = max(a, b)
        new_face_count[e] = edge_face_count[old]


renumber_edges = numba.njit(cache=True, parallel=True)(_renumber_edges)


def _renumber_ids(order, ids):
    """ids[i] <- order[ids[i]] in place, where ids[i] >= 0 (-1: none, kept). ids: a flat
    int32 array (a record's vertex or face ids, or faces.reshape(-1)). One pass: numpy's
    where / maximum / gather took ~40 ms for the dragon's record and faces. Each id is
    renumbered on its own, so the threads split them."""
    for i in numba.prange(ids.shape[0]):
        v = ids[i]
        if v >= 0:
            ids[i] = order[v]


renumber_ids = numba.njit(cache=True, parallel=True)(_renumber_ids)


def _move_rows(order, source, out):
    """out[order[i]] = source[i] for every row i (no two rows to one place; out not
    source). The rows of a permutation land all over ``out``: in threads, each
    waits for its own memory (numpy's scatter took ~70 ms of the dragon's build for its
    faces and vertices)."""
    for i in numba.prange(source.shape[0]):
        row = order[i]
        for k in range(source.shape[1]):
            out[row, k] = source[i, k]


move_rows = numba.njit(cache=True, parallel=True)(_move_rows)


def _take_rows(rows, source, out):
    """out[i] = source[rows[i]] for every row i of out: the live rows of a complex
    together (rounds.compacted), in threads, each waiting for its own memory (numpy's
    gather took ~25 ms after the dragon's rounds)."""
    for i in numba.prange(out.shape[0]):
        row = rows[i]
        for k in range(out.shape[1]):
            out[i, k] = source[row, k]


take_rows = numba.njit(cache=True, parallel=True)(_take_rows)


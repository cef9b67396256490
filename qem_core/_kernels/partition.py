"""Whole-complex passes of a parallel round (rounds.py): its live edges, and the parts."""

import numba
import numpy as np

from .link import PART_FROZEN


def _live_edges(faces, face_alive, face_edge, n_edge_ids, ids, ends):
    """The edges of the live faces, each once, in order of first appearance.

    ids : (>= 3 live faces,) int64, ends : (same, 2) int32, out: edge id and its two ends
    (the side's direction in the face that lists it first). Returns how many."""
    seen = np.zeros(n_edge_ids, np.uint8)
    n = 0
    for f in range(faces.shape[0]):
        if not face_alive[f]:
            continue
        for k in range(3):
            edge = face_edge[f, k]
            if seen[edge]:
                continue
            seen[edge] = 1
            ids[n] = edge
            ends[n, 0] = faces[f, k]
            ends[n, 1] = faces[f, (k + 1) % 3]
            n += 1
    return n


live_edges = numba.njit(cache=True)(_live_edges)


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

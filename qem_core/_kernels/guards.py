"""Refusals besides the link condition: flipped faces and bare vertices.

The flip guard: each face that survives a contraction (a, b) -> c has its corner a or b
moved to c. The face's normal after the move is compared with its normal before (a
per-step limit) and with the normal of the original input face it descends from (never
past 90 degrees).

Bare vertices: a contraction must not leave a vertex without a face, since every level
uses all of its vertices.
"""

import numba
import numpy as np

from .adjacency import has_corner, opposite
from .link import NEAR_COUNT_A
from .memory import borrowing_kernel


def _turn_ok(vertices, faces, face_normals, f, moved, px, py, pz, cos_step):
    """Would moving corner ``moved`` of face f to p keep the face from flipping?

    Refused when the new normal turns more than the step limit from the current one, or
    more than 90 degrees from the original face's normal, or the face becomes degenerate.
    A per-step limit below 90 degrees (meshoptimizer uses 75) also stops faces from
    folding over in small steps that each look harmless.
    """
    i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
    p0x, p0y, p0z = vertices[i0, 0], vertices[i0, 1], vertices[i0, 2]
    p1x, p1y, p1z = vertices[i1, 0], vertices[i1, 1], vertices[i1, 2]
    p2x, p2y, p2z = vertices[i2, 0], vertices[i2, 1], vertices[i2, 2]
    ux, uy, uz = p1x - p0x, p1y - p0y, p1z - p0z
    vx, vy, vz = p2x - p0x, p2y - p0y, p2z - p0z
    ox, oy, oz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    if i0 == moved:
        p0x, p0y, p0z = px, py, pz
    elif i1 == moved:
        p1x, p1y, p1z = px, py, pz
    else:
        p2x, p2y, p2z = px, py, pz
    ux, uy, uz = p1x - p0x, p1y - p0y, p1z - p0z
    vx, vy, vz = p2x - p0x, p2y - p0y, p2z - p0z
    nx, ny, nz = uy * vz - uz * vy, uz * vx - ux * vz, ux * vy - uy * vx
    new_length = np.sqrt(nx * nx + ny * ny + nz * nz)
    if new_length == 0.0:
        return False
    old_length = np.sqrt(ox * ox + oy * oy + oz * oz)
    if old_length > 0.0 and ox * nx + oy * ny + oz * nz < cos_step * old_length * new_length:
        return False
    return face_normals[f, 0] * nx + face_normals[f, 1] * ny + face_normals[f, 2] * nz > 0.0


turn_ok = numba.njit(cache=True, inline="always")(_turn_ok)


def _faces_keep_orientation(vertices, faces, face_normals, start, count, pool, a, b, px, py,
                            pz, cos_step):
    """Would every face that survives contracting a and b to p keep from flipping
    (`turn_ok`)? b, the end with fewer faces (the loop keeps the other as survivor), is
    tried first: a refusal at a hub's edge is mostly found at the other end, and then
    costs that end's faces, not the hub's."""
    for v, other in ((b, a), (a, b)):
        s = start[v]
        for i in range(count[v]):
            f = pool[s + i]
            if has_corner(faces, f, other):
                continue  # dies with the contraction
            if not turn_ok(vertices, faces, face_normals, f, v, px, py, pz, cos_step):
                return False
    return True


faces_keep_orientation = borrowing_kernel(_faces_keep_orientation)


def _leaves_a_vertex_bare(faces, start, count, pool, near, a, b):
    """Would contracting a and b leave a vertex with no face? A level must use every one
    of its vertices. It cannot happen on a manifold under the link condition; it can
    once pairs have joined parts, or without the link condition: all faces of an
    opposite vertex x may be faces abx (a lone triangle, faces doubled by a join), or
    a and b may have no other face. ``near`` is gathered for a and b."""
    # The faces abx are found in b's list, the shorter (both ends list them all).
    n_dying = 0
    s = start[b]
    for i in range(count[b]):
        x = opposite(faces, pool[s + i], b, a)
        if x < 0:
            continue
        n_dying += 1
        if count[x] > near[x, NEAR_COUNT_A]:
            continue  # x has a face without a, which survives (the usual case)
        dying_at_x = 0
        for j in range(count[b]):
            h = pool[s + j]
            if has_corner(faces, h, x) and has_corner(faces, h, a):
                dying_at_x += 1
        if dying_at_x == count[x]:
            return True
    return count[a] + count[b] == 2 * n_dying


leaves_a_vertex_bare = borrowing_kernel(_leaves_a_vertex_bare)

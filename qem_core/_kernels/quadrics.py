"""Plane quadrics as flat (10,) float64 rows.

A quadric Q = (A, b, c) measures Q(v) = v^T A v + 2 b^T v + c. Row layout:
``[a00, a01, a02, a11, a12, a22, b0, b1, b2, c]``.

Garland and Heckbert 1997 (plane quadrics); Kim, Kim and Ko 2000 (weighting a plane by
|N|^2 turns distance optimisation into volume optimisation, so "volume" is a weight).
"""

import numba
import numpy as np

QUADRIC_SIZE = 10

# Face weighting codes, mirrored in qem_core.options.WEIGHTING_CODES.
WEIGHT_NONE = 0
WEIGHT_AREA = 1
WEIGHT_VOLUME = 2
WEIGHT_SQRT_AREA = 3


def _add_plane(quadric, normal_x, normal_y, normal_z, offset, weight):
    """Add weight * (n.v + offset)^2 to ``quadric`` in place; n is a unit normal."""
    quadric[0] += weight * normal_x * normal_x
    quadric[1] += weight * normal_x * normal_y
    quadric[2] += weight * normal_x * normal_z
    quadric[3] += weight * normal_y * normal_y
    quadric[4] += weight * normal_y * normal_z
    quadric[5] += weight * normal_z * normal_z
    quadric[6] += weight * offset * normal_x
    quadric[7] += weight * offset * normal_y
    quadric[8] += weight * offset * normal_z
    quadric[9] += weight * offset * offset


add_plane = numba.njit(cache=True)(_add_plane)


def _area_weight(area, weighting):
    """The weight of a plane that stands for a surface patch of ``area``: |N|^k for k = 0
    (none), 1/2 (sqrt_area), 1 (area), 2 (volume), N the patch's area vector."""
    if weighting == WEIGHT_NONE:
        return 1.0
    if weighting == WEIGHT_SQRT_AREA:
        return np.sqrt(area)
    if weighting == WEIGHT_AREA:
        return area
    return area * area


area_weight = numba.njit(cache=True)(_area_weight)


def _evaluate(quadric, x, y, z):
    """Q(v) for v = (x, y, z)."""
    q = quadric
    return (
        q[0] * x * x
        + 2.0 * q[1] * x * y
        + 2.0 * q[2] * x * z
        + q[3] * y * y
        + 2.0 * q[4] * y * z
        + q[5] * z * z
        + 2.0 * (q[6] * x + q[7] * y + q[8] * z)
        + q[9]
    )


evaluate = numba.njit(cache=True, inline="always")(_evaluate)


def _face_quadric(vertices, i0, i1, i2, weighting, quadric):
    """The fundamental quadric of face (i0, i1, i2), written to ``quadric`` (10,);
    returns its unit normal, (0, 0, 0) with a zero quadric for a zero-area face: it has
    no plane."""
    quadric[:] = 0.0
    ux = vertices[i1, 0] - vertices[i0, 0]
    uy = vertices[i1, 1] - vertices[i0, 1]
    uz = vertices[i1, 2] - vertices[i0, 2]
    vx = vertices[i2, 0] - vertices[i0, 0]
    vy = vertices[i2, 1] - vertices[i0, 1]
    vz = vertices[i2, 2] - vertices[i0, 2]
    nx = uy * vz - uz * vy
    ny = uz * vx - ux * vz
    nz = ux * vy - uy * vx
    length = np.sqrt(nx * nx + ny * ny + nz * nz)
    if not length > 0.0:
        return 0.0, 0.0, 0.0
    nx /= length
    ny /= length
    nz /= length
    offset = -(nx * vertices[i0, 0] + ny * vertices[i0, 1] + nz * vertices[i0, 2])
    add_plane(quadric, nx, ny, nz, offset, area_weight(0.5 * length, weighting))
    return nx, ny, nz


face_quadric = numba.njit(cache=True, inline="always")(_face_quadric)


def _fill_face_quadrics(vertices, faces, weighting, face_quadrics, face_normals,
                        vertex_quadrics, n_chunks):
    """Fundamental quadric and unit normal of every face, summed into its corners.

    vertices : (n, 3) float64; faces : (m, 3) int32.
    face_normals : (m, 3) float64, filled.
    vertex_quadrics : (n, 10) float64, set to the sum of its faces' quadrics, added face
    by face (the order of the sums is fixed: levels must be bit-identical).
    face_quadrics : (m, 10) float64, filled; or (0, 10) when the caller needs no face
    quadrics (the additive mode: 80 bytes a face not allocated, nor paged in).
    All three may come uninitialised (np.empty). Each thread zeroes its run of
    vertex_quadrics by writing before it adds: the first touch of a fresh page that
    reads (np.zeros' pages, then +=) maps the zero page and faults again on the write:
    on dragon the kernel took 88 ms so, 35 ms writing first.

    In n_chunks threads, each owning a run of the vertex numbers: a thread goes through
    every face in order and sums the quadric of each face with a corner of its own into
    those corners, so every vertex still receives its faces' quadrics in face order, and
    the sums do not depend on n_chunks (at least 1). A face across runs is priced by
    every run that owns one of its corners; the run of its corner 0 writes its normal
    and quadric.
    """
    n = vertex_quadrics.shape[0]
    n_chunks = max(n_chunks, 1)
    keep = face_quadrics.shape[0] > 0
    for chunk in numba.prange(n_chunks):
        low = n * chunk // n_chunks
        high = n * (chunk + 1) // n_chunks
        quadric = np.zeros(QUADRIC_SIZE)
        for v in range(low, high):
            for d in range(QUADRIC_SIZE):
                vertex_quadrics[v, d] = 0.0
        for f in range(faces.shape[0]):
            i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
            own = low <= i0 < high
            if not (own or low <= i1 < high or low <= i2 < high):
                continue
            nx, ny, nz = face_quadric(vertices, i0, i1, i2, weighting, quadric)
            if own:
                face_normals[f, 0] = nx
                face_normals[f, 1] = ny
                face_normals[f, 2] = nz
                if keep:
                    for d in range(QUADRIC_SIZE):
                        face_quadrics[f, d] = quadric[d]
            for k in range(3):
                v = faces[f, k]
                if low <= v < high:
                    for d in range(QUADRIC_SIZE):
                        vertex_quadrics[v, d] += quadric[d]


fill_face_quadrics = numba.njit(cache=True, parallel=True)(_fill_face_quadrics)


def _boundary_quadric(vertices, a, b, face_normal, weighting, boundary_weight, out):
    """Add the constraint plane of border edge (a, b) to ``out``.

    The plane contains the edge and is perpendicular to its face, so a vertex that slides
    off the border pays for it. Its weight is ``boundary_weight`` times the weight a face
    plane of area |ab|^2 would get, which keeps it in scale with the face planes.
    """
    ex = vertices[b, 0] - vertices[a, 0]
    ey = vertices[b, 1] - vertices[a, 1]
    ez = vertices[b, 2] - vertices[a, 2]
    length2 = ex * ex + ey * ey + ez * ez
    if length2 == 0.0:
        return
    # n = e x face_normal, perpendicular to both the edge and the face.
    nx = ey * face_normal[2] - ez * face_normal[1]
    ny = ez * face_normal[0] - ex * face_normal[2]
    nz = ex * face_normal[1] - ey * face_normal[0]
    length = np.sqrt(nx * nx + ny * ny + nz * nz)
    if length == 0.0:
        return
    nx /= length
    ny /= length
    nz /= length
    offset = -(nx * vertices[a, 0] + ny * vertices[a, 1] + nz * vertices[a, 2])
    weight = boundary_weight * area_weight(length2, weighting)
    add_plane(out, nx, ny, nz, offset, weight)


boundary_quadric = numba.njit(cache=True)(_boundary_quadric)

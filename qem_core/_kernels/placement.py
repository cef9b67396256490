"""Where the contracted vertex goes: the minimiser of its quadric.

When A is singular or ill-conditioned (a flat or cylindrical neighbourhood) the minimiser
is a plane or a line, not a point. We pin it down with a truncated pseudo-inverse around
the edge midpoint m: directions whose eigenvalue is below ``rank_tolerance`` times the
largest are left at m, so of all minimisers of the well-determined directions we take the
one closest to m (Lindstrom 2000 does the same with an SVD). The result is compared with
the endpoints and the midpoint and the cheapest of the four wins.

Eigenvalues come in closed form (Smith 1961); only the eigenvector that is well separated
from the others is ever needed (the flat one for a cylinder, the dominant one for a
plane), and it is the null vector of A - λI, taken from a cross product of its rows.

Most contractions, once a few have merged planes of different directions, are clearly
well conditioned, and need no eigenvalue: ``clearly_well_conditioned`` proves from the
trace, minors and determinant (no arccos, no cos) that the eigenvalues would pass the
tolerance test, with a margin wider than their rounding, so the branch taken, and every
bit of the result, are those the eigenvalues would give.
"""

import numba
import numpy as np

from .memory import borrowing_kernel
from .quadrics import QUADRIC_SIZE, evaluate


def _eigenvalues3(a00, a01, a02, a11, a12, a22):
    """Eigenvalues of a symmetric 3x3 matrix, largest first."""
    p1 = a01 * a01 + a02 * a02 + a12 * a12
    q = (a00 + a11 + a22) / 3.0
    d0, d1, d2 = a00 - q, a11 - q, a22 - q
    p2 = d0 * d0 + d1 * d1 + d2 * d2 + 2.0 * p1
    if p2 <= 0.0:
        return q, q, q
    p = np.sqrt(p2 / 6.0)
    denominator = 2.0 * p * p * p
    if denominator == 0.0:
        return q, q, q  # p^3 underflows (entries near 1e-110): as good as a multiple of I
    # det((A - qI) / p) / 2, clamped: rounding may push it past +-1.
    r = (
        d0 * (d1 * d2 - a12 * a12) - a01 * (a01 * d2 - a12 * a02) + a02 * (a01 * a12 - d1 * a02)
    ) / denominator
    r = min(1.0, max(-1.0, r))
    phi = np.arccos(r) / 3.0
    largest = q + 2.0 * p * np.cos(phi)
    smallest = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    return largest, 3.0 * q - largest - smallest, smallest


eigenvalues3 = numba.njit(cache=True)(_eigenvalues3)


def _null_vector3(a00, a01, a02, a11, a12, a22, shift):
    """Unit vector spanning the null space of A - shift*I, assumed of rank 2."""
    r0x, r0y, r0z = a00 - shift, a01, a02
    r1x, r1y, r1z = a01, a11 - shift, a12
    r2x, r2y, r2z = a02, a12, a22 - shift
    best_x = r0y * r1z - r0z * r1y
    best_y = r0z * r1x - r0x * r1z
    best_z = r0x * r1y - r0y * r1x
    best = best_x * best_x + best_y * best_y + best_z * best_z
    cx = r0y * r2z - r0z * r2y
    cy = r0z * r2x - r0x * r2z
    cz = r0x * r2y - r0y * r2x
    c = cx * cx + cy * cy + cz * cz
    if c > best:
        best_x, best_y, best_z, best = cx, cy, cz, c
    cx = r1y * r2z - r1z * r2y
    cy = r1z * r2x - r1x * r2z
    cz = r1x * r2y - r1y * r2x
    c = cx * cx + cy * cy + cz * cz
    if c > best:
        best_x, best_y, best_z, best = cx, cy, cz, c
    if best <= 0.0:
        return 0.0, 0.0, 0.0
    norm = np.sqrt(best)
    return best_x / norm, best_y / norm, best_z / norm


null_vector3 = numba.njit(cache=True)(_null_vector3)


def _solve3(a00, a01, a02, a11, a12, a22, gx, gy, gz):
    """A^-1 g by cofactors (A symmetric, invertible); (0, 0, 0) if the determinant
    underflows to zero (entries near 1e-110), so the caller stays where it is."""
    c00 = a11 * a22 - a12 * a12
    c01 = a02 * a12 - a01 * a22
    c02 = a01 * a12 - a02 * a11
    c11 = a00 * a22 - a02 * a02
    c12 = a01 * a02 - a00 * a12
    c22 = a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    if det == 0.0:
        return 0.0, 0.0, 0.0
    return (
        (c00 * gx + c01 * gy + c02 * gz) / det,
        (c01 * gx + c11 * gy + c12 * gz) / det,
        (c02 * gx + c12 * gy + c22 * gz) / det,
    )


solve3 = numba.njit(cache=True)(_solve3)

# How far eigenvalues3's results may lie from the exact eigenvalues, as a fraction of the
# trace. Rounding moves r by ~1e-14 (r^3 / p^3 scaled), and arccos near +-1 turns that
# into ~sqrt of it: the worst case over p is ~3.4e-5 of the trace. Three times that.
EIGENVALUE_SLACK = 1e-4
# Relative rounding allowed for the trace, minors and determinant (a few ulps: 1e-12).
ROUNDING_SLACK = 1e-12


def _clearly_well_conditioned(a00, a01, a02, a11, a12, a22, rank_tolerance):
    """True only if ``eigenvalues3`` of A would give largest > 0 and smallest >
    rank_tolerance * largest, decided without computing them (False: don't know).

    With trace T > 0, sum of principal 2x2 minors M > 0 and determinant D > 0, all
    eigenvalues are positive (the characteristic polynomial's coefficients alternate),
    so largest < T and smallest = D / (largest * middle) > D / M. The test asks
    D / M > (rank_tolerance + 2 EIGENVALUE_SLACK) T, each of D, M, T taken at the
    unfavourable end of its rounding, and T within [1e-90, 1e90] so that T^3 neither
    underflows nor overflows.
    """
    trace = a00 + a11 + a22
    if not (1e-90 < trace < 1e90):
        return False
    c00 = a11 * a22 - a12 * a12
    minors = c00 + (a00 * a22 - a02 * a02) + (a00 * a11 - a01 * a01)
    det = a00 * c00 - a01 * (a01 * a22 - a12 * a02) + a02 * (a01 * a12 - a11 * a02)
    minors_error = ROUNDING_SLACK * trace * trace
    det_low = det - minors_error * trace
    if not (minors > minors_error and det_low > 0.0):
        return False
    bound = (rank_tolerance + 2.0 * EIGENVALUE_SLACK) * trace
    return det_low > (minors + minors_error) * bound


clearly_well_conditioned = numba.njit(cache=True, inline="always")(_clearly_well_conditioned)


def _minimise_near(quadric, mx, my, mz, rank_tolerance, out):
    """The minimiser of ``quadric`` closest to m = (mx, my, mz), written to out (3,)."""
    a00, a01, a02 = quadric[0], quadric[1], quadric[2]
    a11, a12, a22 = quadric[3], quadric[4], quadric[5]
    # Gradient at m (over 2): g = A m + b; the step is -A^+ g.
    gx = a00 * mx + a01 * my + a02 * mz + quadric[6]
    gy = a01 * mx + a11 * my + a12 * mz + quadric[7]
    gz = a02 * mx + a12 * my + a22 * mz + quadric[8]
    out[0], out[1], out[2] = mx, my, mz
    largest = middle = smallest = floor = 0.0
    invertible = clearly_well_conditioned(a00, a01, a02, a11, a12, a22, rank_tolerance)
    if not invertible:
        largest, middle, smallest = eigenvalues3(a00, a01, a02, a11, a12, a22)
        if largest <= 0.0:
            return
        floor = rank_tolerance * largest
        invertible = smallest > floor
    if invertible:
        sx, sy, sz = solve3(a00, a01, a02, a11, a12, a22, gx, gy, gz)
    elif middle > floor:
        # A cylinder: one flat direction u. Remove g's component along u and solve with
        # u's eigenvalue raised to the largest, which leaves the other two untouched.
        ux, uy, uz = null_vector3(a00, a01, a02, a11, a12, a22, smallest)
        along = ux * gx + uy * gy + uz * gz
        lift = largest - smallest
        sx, sy, sz = solve3(
            a00 + lift * ux * ux, a01 + lift * ux * uy, a02 + lift * ux * uz,
            a11 + lift * uy * uy, a12 + lift * uy * uz, a22 + lift * uz * uz,
            gx - along * ux, gy - along * uy, gz - along * uz,
        )
    else:
        # A plane: only the dominant direction is determined.
        ux, uy, uz = null_vector3(a00, a01, a02, a11, a12, a22, largest)
        along = (ux * gx + uy * gy + uz * gz) / largest
        sx, sy, sz = along * ux, along * uy, along * uz
    out[0] = mx - sx
    out[1] = my - sy
    out[2] = mz - sz


minimise_near = numba.njit(cache=True, inline="always")(_minimise_near)


def _place(quadric, vertices, a, b, rank_tolerance, out):
    """Best position for contracting (a, b) under ``quadric``; returns its cost (>= 0).

    out : (3,) receives the position.
    """
    ax, ay, az = vertices[a, 0], vertices[a, 1], vertices[a, 2]
    bx, by, bz = vertices[b, 0], vertices[b, 1], vertices[b, 2]
    mx, my, mz = 0.5 * (ax + bx), 0.5 * (ay + by), 0.5 * (az + bz)
    minimise_near(quadric, mx, my, mz, rank_tolerance, out)
    best = evaluate(quadric, out[0], out[1], out[2])
    cost = evaluate(quadric, mx, my, mz)
    if cost < best:
        best = cost
        out[0], out[1], out[2] = mx, my, mz
    cost = evaluate(quadric, ax, ay, az)
    if cost < best:
        best = cost
        out[0], out[1], out[2] = ax, ay, az
    cost = evaluate(quadric, bx, by, bz)
    if cost < best:
        best = cost
        out[0], out[1], out[2] = bx, by, bz
    return max(best, 0.0)


# A kernel of its own, not inlined: it is called at five places, each of which compiled
# its own copy (a tenth of the package's compile time); the call costs nothing measurable.
place = borrowing_kernel(_place)


def _contraction_quadric(vertex_quadrics, edge_quadrics, a, b, edge, exact, quadric):
    """quadric (10,) <- Q_a + Q_b, minus Q_ab in exact mode. Candidates past the edges
    (pairs, which share no face and so no plane) subtract nothing."""
    for k in range(QUADRIC_SIZE):
        quadric[k] = vertex_quadrics[a, k] + vertex_quadrics[b, k]
    if exact and edge < edge_quadrics.shape[0]:
        for k in range(QUADRIC_SIZE):
            quadric[k] -= edge_quadrics[edge, k]


contraction_quadric = numba.njit(cache=True, inline="always")(_contraction_quadric)


def _edge_cost(vertices, vertex_quadrics, edge_quadrics, a, b, edge, exact, rank_tolerance,
               quadric, position):
    """Cost and best position of contracting edge (a, b); quadric (10,) receives Q_c.

    The cost does not depend on the order of a and b (sums commute; the candidates of
    ``place`` are the same), so the heap may compute it from either end."""
    contraction_quadric(vertex_quadrics, edge_quadrics, a, b, edge, exact, quadric)
    return place(quadric, vertices, a, b, rank_tolerance, position)


edge_cost = numba.njit(cache=True, inline="always")(_edge_cost)

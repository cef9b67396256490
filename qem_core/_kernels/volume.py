"""The volume a contraction changes: kept exactly (Hoppe 1999), or priced (soft).

Contracting (a, b) -> p replaces the faces around a and b by the same fan round p. The
volume between the two fans is linear in p: it is zero exactly when g.(p - o) = h
(``volume_constraint``, o a nearby origin), and g.(p - o) - h is the volume the
contraction adds (negative: removes). Where the fans share their outline (a and b
inside the surface) this does not depend on o: it is the volume swept by the moving
part of the surface, on open meshes too. On a border the outline moves with p, and the
volume is that of the cone from o, the midpoint of a and b: still zero for a move that
keeps the faces in their planes.

``preserve_volume`` meets the constraint at every step, with a Lagrange multiplier
(``place_keeping_volume``): closed meshes keep their volume exactly, but the new vertex
may have to bulge far out of a thin part to do it.

``volume_weight`` prices the change instead. Its height, delta = (g.(p - o) - h) / |g|,
is how far the star would have to move along g to make up for it (for a flat star,
|g| is a third of its area, and a cone of height delta over it holds that volume).
``with_volume`` charges it as if every plane the contraction merges were that far, as
the distance term does (distance.py): the total weight W of those planes times delta^2,
for the part of delta^2 beyond ``FREE_RATIO`` times the mean square of the plane
distances (cost / W). Plain quadric placement on a convex part puts the vertex on the
chord side, so each step shaves a little volume and the shaving adds up over the
coarse levels (Spot keeps 69 % of its volume at 17 vertices); the charge both delays
such contractions and moves their vertex: the placement is re-minimised with the term
as one more plane quadric, w W / |g|^2 (g.p - g.o - h)^2, and whichever of the two
positions is charged less wins. Fine levels, where the quadric's placement changes
little volume, pay nothing and keep their order and position. A flat star costs 0 and
so has no free part: its round-off height is charged (~1e-24), which puts it back in the
queue once behind the other candidates of cost 0, and the re-placement, whose
candidates then differ by round-off only, may put it at an end of its edge rather than
the midpoint (in the plane either way). A floor on the free part (a height of
1e-12 of the unit-scaled mesh) stopped that, but moved fandisk's 34-vertex level to a
Hausdorff distance of 1.25x the best peer's: the coarsest levels are that sensitive, so
the measured behaviour stays.

With appearance attributes the cost is that of the whole quadric, attribute errors
included, so "the mean square of the plane distances" (cost / W, W the weight of the
position planes) counts those errors too: a contraction that costs colour or UV error
may change a little more volume for free.
"""

import numba
import numpy as np

from .adjacency import corner_of, has_corner
from .memory import borrowing_kernel
from .placement import minimise_near, place, solve3
from .quadrics import QUADRIC_SIZE, add_plane, evaluate

# The squared height of the volume change a contraction may reach for free, in units of
# the mean square of its plane distances. 0 charges every change, which moves the
# finest levels off the quadric's optimum (RMS 1.05x at the finest of face_rangemap) and
# some coarse ones far (Hausdorff 2.2x at airplane_colored's 29 vertices); 1 and more
# leave Spot's coarsest level short of its volume (measured on the meshes of bench/).
FREE_RATIO = 0.5


def _volume_constraint(vertices, faces, start, count, pool, a, b, ox, oy, oz):
    """(gx, gy, gz, h): the volume under the faces around a and b stays the same when
    the new vertex p meets g.(p - o) = h (o a nearby origin, for precision). Faces with
    both a and b die: their volume after is zero. (A vertex's run holds its live faces
    only, adjacency.py: no face_alive to read.)"""
    gx = gy = gz = 0.0
    h = 0.0
    for side in range(2):
        v, other = (a, b) if side == 0 else (b, a)
        s = start[v]
        for i in range(count[v]):
            f = pool[s + i]
            shared = has_corner(faces, f, other)
            if shared and v == b:
                continue  # counted from a
            k = corner_of(faces, f, v)
            p0, p1, p2 = faces[f, k], faces[f, (k + 1) % 3], faces[f, (k + 2) % 3]
            ux, uy, uz = vertices[p1, 0] - ox, vertices[p1, 1] - oy, vertices[p1, 2] - oz
            wx, wy, wz = vertices[p2, 0] - ox, vertices[p2, 1] - oy, vertices[p2, 2] - oz
            cx, cy, cz = uy * wz - uz * wy, uz * wx - ux * wz, ux * wy - uy * wx
            h += ((vertices[p0, 0] - ox) * cx + (vertices[p0, 1] - oy) * cy
                  + (vertices[p0, 2] - oz) * cz) / 6.0
            if not shared:
                gx += cx / 6.0
                gy += cy / 6.0
                gz += cz / 6.0
    return gx, gy, gz, h


volume_constraint = borrowing_kernel(_volume_constraint)


def _place_keeping_volume(quadric, vertices, faces, start, count, pool, a, b, rank_tolerance,
                          out):
    """The minimiser of ``quadric`` on the plane g.p = h that keeps the volume: from the
    unconstrained minimiser p0, step A^-1 g (h - g.p0) / (g^T A^-1 g) (a Lagrange
    multiplier), with A lifted by a small multiple of I so flat directions take the
    step. Returns the cost."""
    mx = 0.5 * (vertices[a, 0] + vertices[b, 0])
    my = 0.5 * (vertices[a, 1] + vertices[b, 1])
    mz = 0.5 * (vertices[a, 2] + vertices[b, 2])
    minimise_near(quadric, mx, my, mz, rank_tolerance, out)
    gx, gy, gz, h = volume_constraint(vertices, faces, start, count, pool, a, b, mx, my, mz)
    gg = gx * gx + gy * gy + gz * gz
    if gg > 0.0:
        miss = h - (gx * (out[0] - mx) + gy * (out[1] - my) + gz * (out[2] - mz))
        lift = 1e-9 * (quadric[0] + quadric[3] + quadric[5]) + 1e-300
        dx, dy, dz = solve3(quadric[0] + lift, quadric[1], quadric[2], quadric[3] + lift,
                            quadric[4], quadric[5] + lift, gx, gy, gz)
        along = gx * dx + gy * dy + gz * dz
        if not along > 0.0 or not np.isfinite(along):
            dx, dy, dz, along = gx, gy, gz, gg  # A gives no direction: go along g
        step = miss / along
        out[0] += step * dx
        out[1] += step * dy
        out[2] += step * dz
    return max(evaluate(quadric, out[0], out[1], out[2]), 0.0)


place_keeping_volume = borrowing_kernel(_place_keeping_volume)


def _charge(px, py, pz, gx, gy, gz, h, mx, my, mz, gg, weight, free, volume_weight):
    """The charge for the height of the volume change of the new vertex at p."""
    miss = gx * (px - mx) + gy * (py - my) + gz * (pz - mz) - h
    return volume_weight * weight * max(miss * miss / gg - free, 0.0)


charge = numba.njit(cache=True, inline="always")(_charge)


def _with_volume(vertices, faces, start, count, pool, a, b, quadric, weight, cost,
                 volume_weight, rank_tolerance, penalised, position):
    """The cost of contracting (a, b) with the volume term (module docstring), and its
    position, written to ``position`` (3,), which holds the quadric's placement on entry.

    quadric : (10,) the quadric of the contraction, cost its value at ``position``;
    weight : the total weight of its planes (the trace of the position quadric's A);
    penalised : (10,) work space. Returns ``cost`` itself, and leaves the position, when
    the volume change there is within the free part.
    """
    mx = 0.5 * (vertices[a, 0] + vertices[b, 0])
    my = 0.5 * (vertices[a, 1] + vertices[b, 1])
    mz = 0.5 * (vertices[a, 2] + vertices[b, 2])
    gx, gy, gz, h = volume_constraint(vertices, faces, start, count, pool, a, b, mx, my, mz)
    gg = gx * gx + gy * gy + gz * gz
    if not (gg > 0.0 and weight > 0.0):
        return cost
    free = FREE_RATIO * cost / weight
    px, py, pz = position[0], position[1], position[2]
    at_placement = cost + charge(px, py, pz, gx, gy, gz, h, mx, my, mz, gg, weight, free,
                                 volume_weight)
    if at_placement <= cost:
        return cost
    # The term as a plane quadric: (w W / |g|^2) (g.p - level)^2.
    level = h + gx * mx + gy * my + gz * mz
    for k in range(QUADRIC_SIZE):
        penalised[k] = quadric[k]
    add_plane(penalised, gx, gy, gz, -level, volume_weight * weight / gg)
    place(penalised, vertices, a, b, rank_tolerance, position)
    qx, qy, qz = position[0], position[1], position[2]
    at_minimiser = max(evaluate(quadric, qx, qy, qz), 0.0) + charge(
        qx, qy, qz, gx, gy, gz, h, mx, my, mz, gg, weight, free, volume_weight)
    if at_minimiser < at_placement:
        # Never below the cost on entry, the heap's key: placement.py's minimiser can
        # miss the exact one by the rank tolerance, and a cost below the key would
        # read, to the distance term, as no charge priced yet.
        return max(at_minimiser, cost)
    position[0], position[1], position[2] = px, py, pz
    return at_placement


with_volume = borrowing_kernel(_with_volume)

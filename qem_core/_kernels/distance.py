"""How far a contraction moves the surface, priced on top of the quadric cost.

A plane quadric prices the distance from the new vertex to the planes of the faces it
stands for. It does not see a move *along* those planes, nor the surface between the
vertices: contracting the tip of a thin spike or a corner of a thin fin into its
neighbour cuts that part off at almost no cost, since the planes there are parallel to
the move (and with area weighting the few across it are tiny); and a new edge may span a
groove or fold that both its ends sit on. On the dragon these few cuts set the Hausdorff
distance of whole levels. The Hausdorff distance sees them at once.

``star_distance2`` is a local, one-step Hausdorff distance between the star of a and b
before the contraction (a, b) -> p and the star of p after it, taken at the points that
move: the old positions of a and b against the new star (a cut-off tip), p and the
midpoint of every new edge against the old star (an edge spanning a groove, a covered
hole). On a smooth surface it is of the size of the plane distances the quadric already
counts; across a cut it is the size of the cut.

``with_distance`` charges it, as if every plane the contraction merges were that far: the
total weight W of those planes (the trace of A: planes have unit normals) times d^2, for
the part of d^2 beyond ``FREE_RATIO`` times the mean square of the plane distances
(cost / W). Ordinary contractions, where the two agree, pay nothing extra and keep their
order; a cut pays about W d^2, far above its quadric cost. The distances are between two
consecutive levels, not to the input: they catch the step that cuts, not a slow drift,
which the accumulated quadric prices.
"""

import numba
import numpy as np

from .adjacency import corner_of, face_across, has_corner
from .heap import cost_key, key_cost
from .memory import borrowing_kernel

# The squared one-step distance a contraction may reach for free, in units of the mean
# square of its plane distances. Below 4 (twice the RMS distance) ordinary contractions
# on curved parts start paying and the queue churns (each candidate that pays is put back
# once); above it, fewer cuts are caught (measured on the meshes of bench/).
FREE_RATIO = 4.0
# Stars of more faces than this (a and b together) are priced by the quadric alone. The
# search tests each moved point against the star, so it costs the square of the star's
# size, and a vertex of degree d is contracted into d times: a fan of 3000 triangles
# round one vertex took minutes. Meshes of the bench never reach it (their levels are
# byte-identical with and without the cap).
MAX_DISTANCE_STAR = 128


def _segment_distance2(px, py, pz, ax, ay, az, bx, by, bz):
    """Squared distance from p to the segment ab (a point if a == b)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    length2 = abx * abx + aby * aby + abz * abz
    t = 0.0
    if length2 > 0.0:
        t = min(max((abx * apx + aby * apy + abz * apz) / length2, 0.0), 1.0)
    dx, dy, dz = apx - t * abx, apy - t * aby, apz - t * abz
    return dx * dx + dy * dy + dz * dz


segment_distance2 = numba.njit(cache=True, inline="always")(_segment_distance2)


def _flat_triangle_distance2(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Squared distance from p to a triangle without area: to the nearest of its sides."""
    return min(segment_distance2(px, py, pz, ax, ay, az, bx, by, bz),
               segment_distance2(px, py, pz, ax, ay, az, cx, cy, cz),
               segment_distance2(px, py, pz, bx, by, bz, cx, cy, cz))


flat_triangle_distance2 = numba.njit(cache=True)(_flat_triangle_distance2)


def _point_triangle_distance2(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """Squared distance from p to triangle abc (closest point by Voronoi regions,
    Ericson, Real-Time Collision Detection 5.1.5); a degenerate triangle is handled
    through its edges and corners."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    apx, apy, apz = px - ax, py - ay, pz - az
    d1 = abx * apx + aby * apy + abz * apz
    d2 = acx * apx + acy * apy + acz * apz
    if d1 <= 0.0 and d2 <= 0.0:
        return apx * apx + apy * apy + apz * apz  # corner a
    bpx, bpy, bpz = px - bx, py - by, pz - bz
    d3 = abx * bpx + aby * bpy + abz * bpz
    d4 = acx * bpx + acy * bpy + acz * bpz
    if d3 >= 0.0 and d4 <= d3:
        return bpx * bpx + bpy * bpy + bpz * bpz  # corner b
    cpx, cpy, cpz = px - cx, py - cy, pz - cz
    d5 = abx * cpx + aby * cpy + abz * cpz
    d6 = acx * cpx + acy * cpy + acz * cpz
    if d6 >= 0.0 and d5 <= d6:
        return cpx * cpx + cpy * cpy + cpz * cpz  # corner c
    # Each edge's parameter is s / (s + u), where s + u is the edge's squared length
    # (d1 - d3 = |ab|^2, d2 - d6 = |ac|^2, (d4 - d3) + (d5 - d6) = |bc|^2): an edge of
    # length 0 (coincident corners, kept with merge_coincident off) is passed over, and
    # the triangle is then one of its other sides or, with all region weights 0, flat.
    vc = d1 * d4 - d3 * d2
    vb = d5 * d2 - d1 * d6
    va = d3 * d6 - d5 * d4
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0 and d1 - d3 > 0.0:
        t = d1 / (d1 - d3)  # edge ab
        qx, qy, qz = ax + t * abx, ay + t * aby, az + t * abz
    elif vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0 and d2 - d6 > 0.0:
        t = d2 / (d2 - d6)  # edge ac
        qx, qy, qz = ax + t * acx, ay + t * acy, az + t * acz
    elif va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0 and (d4 - d3) + (d5 - d6) > 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))  # edge bc
        qx, qy, qz = bx + t * (cx - bx), by + t * (cy - by), bz + t * (cz - bz)
    else:
        total = va + vb + vc  # inside: > 0 here, or an earlier region held
        if not total > 0.0:
            return flat_triangle_distance2(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz)
        v, w = vb / total, vc / total
        qx = ax + v * abx + w * acx
        qy = ay + v * aby + w * acy
        qz = az + v * abz + w * acz
    dx, dy, dz = px - qx, py - qy, pz - qz
    return dx * dx + dy * dy + dz * dz


point_triangle_distance2 = numba.njit(cache=True, inline="always")(_point_triangle_distance2)


def _to_face2(vertices, faces, f, moved, mx, my, mz, px, py, pz):
    """Squared distance from p to face f, with its corner ``moved`` (-1: none) at m."""
    i0, i1, i2 = faces[f, 0], faces[f, 1], faces[f, 2]
    ax, ay, az = vertices[i0, 0], vertices[i0, 1], vertices[i0, 2]
    bx, by, bz = vertices[i1, 0], vertices[i1, 1], vertices[i1, 2]
    cx, cy, cz = vertices[i2, 0], vertices[i2, 1], vertices[i2, 2]
    if i0 == moved:
        ax, ay, az = mx, my, mz
    elif i1 == moved:
        bx, by, bz = mx, my, mz
    elif i2 == moved:
        cx, cy, cz = mx, my, mz
    return point_triangle_distance2(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz)


to_face2 = numba.njit(cache=True, inline="always")(_to_face2)


def _to_new2(vertices, faces, start, count, pool, v, other, px, py, pz, qx, qy,
             qz, enough):
    """Squared distance from q to the star of p after contracting (v, other) to p: the
    live faces of v and then of ``other`` (the order in which to look), less the faces
    with both, with their corner v or other moved to p. Stops at the first face within
    ``enough`` (squared), whose distance it returns: on a smooth star that is the face
    over q, and v's faces come first because they cover the old position of v."""
    best = np.inf
    for w, u in ((v, other), (other, v)):
        s = start[w]
        for i in range(count[w]):
            f = pool[s + i]
            if not has_corner(faces, f, u):
                best = min(best, to_face2(vertices, faces, f, w, px, py, pz, qx, qy, qz))
                if best <= enough:
                    return best
    return best


# to_new2 and to_old2 are called, not inlined: star_distance2 calls them five times, and
# inlined each copy compiled its own point-triangle test (a fifth of the package's
# compile time). Each call does a loop of face tests, so the call costs nothing measurable.
to_new2 = borrowing_kernel(_to_new2)


def _to_old2(vertices, faces, start, count, pool, a, b, x, tried, tried_too, qx, qy, qz,
             enough):
    """Squared distance from q to the star of a and b before the contraction, less the
    faces ``tried`` and ``tried_too`` (-1: none), which the caller has measured. The faces
    with the corner x (x = -1: the faces abx) are tried first, as those under the point
    measured; stops within ``enough`` like `to_new2`."""
    best = np.inf
    for first_pass in (True, False):
        for v, other in ((a, b), (b, a)):
            s = start[v]
            for i in range(count[v]):
                f = pool[s + i]
                dying = has_corner(faces, f, other)
                if v == b and dying:
                    continue  # seen from a
                if (dying if x < 0 else has_corner(faces, f, x)) != first_pass:
                    continue
                if f == tried or f == tried_too:
                    continue
                best = min(best, to_face2(vertices, faces, f, -1, 0.0, 0.0, 0.0, qx, qy, qz))
                if best <= enough:
                    return best
    return best


to_old2 = borrowing_kernel(_to_old2)


def _star_distance2(vertices, faces, start, count, pool, a, b, px, py, pz,
                    enough):
    """The squared one-step distance of contracting (a, b) to p (module docstring), or
    some value <= ``enough`` (squared) if it is no larger than that.

    Reads the live faces of a and b before the contraction: those with both die, the
    others move their corner a or b to p. Each new edge p-x is the one after corner a or
    b of exactly one surviving face, whose old self is usually under its midpoint and is
    tried first. A point's search stops as soon as it is within ``enough`` of a face, so
    on a smooth star the answer costs one or two tests a point.
    """
    worst = to_new2(vertices, faces, start, count, pool, a, b, px, py, pz,
                    vertices[a, 0], vertices[a, 1], vertices[a, 2], enough)
    if worst == np.inf:
        return 0.0  # no face survives (cannot happen: such contractions are refused)
    enough = max(enough, worst)  # from here on, only a larger distance matters
    worst = max(worst, to_new2(vertices, faces, start, count, pool, b, a, px, py,
                               pz, vertices[b, 0], vertices[b, 1], vertices[b, 2], enough))
    enough = max(enough, worst)
    worst = max(worst, to_old2(vertices, faces, start, count, pool, a, b, -1, -1, -1,
                               px, py, pz, enough))
    enough = max(enough, worst)
    for v, other in ((a, b), (b, a)):
        s = start[v]
        for i in range(count[v]):
            f = pool[s + i]
            if has_corner(faces, f, other):
                continue
            x = faces[f, (corner_of(faces, f, v) + 1) % 3]
            mx = 0.5 * (px + vertices[x, 0])
            my = 0.5 * (py + vertices[x, 1])
            mz = 0.5 * (pz + vertices[x, 2])
            d2 = to_face2(vertices, faces, f, -1, 0.0, 0.0, 0.0, mx, my, mz)
            if d2 <= enough:
                continue
            # Moved off f (half the time, as p moved off v), it is mostly over the face
            # across the edge v-x: that one next, the rest of the star only if it is
            # not close enough either. The distance is the least over the star all the
            # same (values within ``enough`` count for nothing, whichever is found).
            across = face_across(faces, start, count, pool, v, f, x)
            if across >= 0:
                d2 = min(d2, to_face2(vertices, faces, across, -1, 0.0, 0.0, 0.0, mx, my, mz))
            if d2 > enough:
                d2 = min(d2, to_old2(vertices, faces, start, count, pool, a, b, x, f, across,
                                     mx, my, mz, enough))
            worst = max(worst, d2)
            enough = max(enough, worst)
    return worst


star_distance2 = numba.njit(cache=True)(_star_distance2)


def _with_distance(vertices, faces, start, count, pool, a, b, px, py, pz, quadric, cost,
                   key, next_key, distance_weight):
    """The cost of contracting (a, b) to p with the distance term (module docstring), or
    the quadric cost ``cost`` where the full cost would not reach ``next_key``.

    quadric : (10,) the position quadric of the contraction; cost its cost at p so far:
    the quadric's value, plus the volume term's charge when that is on (volume.py), which
    then also counts in the free part. key: the heap key the candidate was popped with.
    A key above ``cost`` is a full cost the loop put the candidate back with, still
    current since neither end has changed, so it is returned as it is. A contraction
    elsewhere in the star that moves neither end leaves it too (the terms are lazy), and
    with the volume term on that key may be one with a volume charge only, priced
    before such a move: the candidate then goes at that cost, its distance unpriced.
    next_key: the key now at the top of the heap. A candidate whose full cost stays at
    or below it is contracted now either way, so the distance only has to be known
    beyond that, and the star search stops early there.
    """
    if key > cost_key(cost):
        return key_cost(key)
    if count[a] + count[b] > MAX_DISTANCE_STAR:
        return cost
    weight = quadric[0] + quadric[3] + quadric[5]
    if not weight > 0.0:
        return cost
    free = FREE_RATIO * cost / weight
    # The largest d^2 at which the full cost stays at or below the next key.
    enough = max(free, free + (key_cost(next_key) - cost) / (distance_weight * weight))
    d2 = star_distance2(vertices, faces, start, count, pool, a, b, px, py, pz, enough)
    if d2 <= enough:
        return cost
    return cost + distance_weight * weight * (d2 - free)


with_distance = numba.njit(cache=True)(_with_distance)

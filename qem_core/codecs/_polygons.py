"""Fan triangulation of polygon lists, shared by the PLY, OBJ and OFF readers.

A polygon with corners c0 c1 ... c(k-1) becomes the k - 2 triangles
(c0, c1, c2), (c0, c2, c3), ..., (c0, c(k-2), c(k-1)): exact for convex polygons, which
is what mesh files hold in practice.
"""

from __future__ import annotations

import numpy as np

from ..errors import MeshFormatError


def fan_corners(corner_counts: np.ndarray, what: str, first_number: int = 0) -> np.ndarray:
    """(t, 3) int64 positions, in the flat corner list, of the fan triangles' corners.

    corner_counts : (p,) int, the number of corners of each polygon, all >= 3; the
        polygons' corners lie one after another in a flat list.
    what : names the polygons in the error message, e.g. "OBJ 'f' line".
    first_number : the number the message gives the first polygon (1 for OBJ lines,
        which editors count from 1; 0 for PLY and OFF face indices).

    Index a flat per-corner array (vertex indices, UV indices) with the result to get
    per-triangle-corner values. Raises MeshFormatError for a polygon of < 3 corners.
    """
    corner_counts = np.asarray(corner_counts, dtype=np.int64)
    if corner_counts.size and corner_counts.min() < 3:
        bad = int(np.flatnonzero(corner_counts < 3)[0])
        raise MeshFormatError(
            f"{what} {bad + first_number} has {int(corner_counts[bad])} corners; "
            "a face needs at least 3"
        )
    first_corner = np.cumsum(corner_counts) - corner_counts
    if corner_counts.size and corner_counts.max() == 3:
        # All triangles: the usual case, no fan to build.
        return first_corner[:, None] + np.arange(3)
    triangle_counts = corner_counts - 2
    polygon_of_triangle = np.repeat(np.arange(corner_counts.size), triangle_counts)
    first_triangle = np.cumsum(triangle_counts) - triangle_counts
    fan_step = np.arange(polygon_of_triangle.size) - first_triangle[polygon_of_triangle] + 1
    apex = first_corner[polygon_of_triangle]
    return np.stack([apex, apex + fan_step, apex + fan_step + 1], axis=1)


def fan_triangulate(corner_counts: np.ndarray, corner_values: np.ndarray, what: str) -> np.ndarray:
    """(t, 3) triangles of per-corner values (vertex indices) of polygons laid end to end.

    Like `fan_corners`, without the gather when every polygon is already a triangle.
    """
    if corner_counts.size and corner_counts.min() == 3 and corner_counts.max() == 3:
        return corner_values.reshape(-1, 3)
    return corner_values[fan_corners(corner_counts, what)]

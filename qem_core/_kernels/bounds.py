"""The bounding box of a point set, in one pass.

numpy's ``vertices.min(axis=0)`` on an (n, 3) array reduces it along the strided axis,
~9 ms for dragon's 435 545 vertices, and a build took it five times (the unit scale and
its diagonal, the metadata, the z-order, the rounds' first axis): ~85 ms. It now takes
this pass three times (simplify.build's box serves the first three), ~2 ms each.
"""

import numba
import numpy as np


def _bounding_box(vertices, alive):
    """(2, 3) float64: the lowest and the highest coordinate on each axis of the points
    (n, 3), or of those with ``alive[i] != 0`` when ``alive`` is not empty; rows +inf
    and -inf when there are none. A zero is +0.0, whichever zero came first (the
    metadata's bounding box does not depend on it)."""
    box = np.empty((2, 3))
    box[0, :] = np.inf
    box[1, :] = -np.inf
    use_alive = alive.shape[0] > 0
    for i in range(vertices.shape[0]):
        if use_alive and not alive[i]:
            continue
        for d in range(3):
            x = vertices[i, d]
            if x < box[0, d]:
                box[0, d] = x
            if x > box[1, d]:
                box[1, d] = x
    return box + 0.0  # -0.0 + 0.0 is +0.0


_bounding_box_kernel = numba.njit(cache=True)(_bounding_box)
_ALL = np.zeros(0, np.uint8)


def bounding_box(vertices: np.ndarray, alive: np.ndarray | None = None) -> np.ndarray:
    """(2, 3) float64 low and high corners of the points (n, 3) float64, or of those
    flagged in ``alive`` (n,) uint8."""
    return _bounding_box_kernel(vertices, _ALL if alive is None else alive)

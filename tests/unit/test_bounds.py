"""The one-pass bounding box against numpy's reductions."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from qem_core._kernels.bounds import bounding_box

POINTS = st.integers(1, 40).flatmap(lambda n: arrays(
    np.float64, (n, 3), elements=st.floats(-1e300, 1e300, allow_nan=False)))


@settings(max_examples=100, deadline=None)
@given(POINTS, st.data())
def test_equals_numpys_min_and_max(points, data):
    np.testing.assert_array_equal(bounding_box(points),
                                  np.stack([points.min(axis=0), points.max(axis=0)]))
    alive = np.array(data.draw(st.lists(st.booleans(), min_size=len(points),
                                        max_size=len(points))), np.uint8)
    box = bounding_box(points, alive)
    if alive.any():
        kept = points[alive.astype(bool)]
        np.testing.assert_array_equal(box, np.stack([kept.min(axis=0), kept.max(axis=0)]))
    else:
        assert (box[0] == np.inf).all() and (box[1] == -np.inf).all()

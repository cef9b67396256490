"""The one-pass bounding box against numpy's reductions."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from qem_core._kernels.bounds import bounding_box

COORDINATES = st.one_of(st.floats(-1e300, 1e300, allow_nan=False), st.sampled_from([0.0, -0.0]))
POINTS = st.integers(1, 40).flatmap(lambda n: arrays(np.float64, (n, 3), elements=COORDINATES))


def assert_same_bits(box, expected):
    """Equal values, and equal signs of zero (assert_array_equal takes -0.0 == 0.0)."""
    np.testing.assert_array_equal(box, expected)
    np.testing.assert_array_equal(np.signbit(box), np.signbit(expected))


@settings(max_examples=100)
@given(POINTS, st.data())
def test_equals_numpys_min_and_max_with_zeros_made_positive(points, data):
    assert_same_bits(bounding_box(points),
                     np.stack([points.min(axis=0), points.max(axis=0)]) + 0.0)
    alive = np.array(data.draw(st.lists(st.booleans(), min_size=len(points),
                                        max_size=len(points))), np.uint8)
    box = bounding_box(points, alive)
    if alive.any():
        kept = points[alive.astype(bool)]
        assert_same_bits(box, np.stack([kept.min(axis=0), kept.max(axis=0)]) + 0.0)
    else:
        assert (box[0] == np.inf).all() and (box[1] == -np.inf).all()


def test_a_negative_zero_is_reported_as_zero():
    box = bounding_box(np.array([[0.0, -0.0, -0.0], [-0.0, 0.0, -0.0]]))
    assert not np.signbit(box).any()

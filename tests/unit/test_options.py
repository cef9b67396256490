"""BuildOptions: every number option takes any real number type and stays a float."""

import json

import numpy as np
import pytest

import qem_core
from qem_core.options import BuildOptions


@pytest.mark.parametrize("value", [np.float32(2.0), np.int64(2), np.float64(2.0), 2, 2.0])
def test_numpy_and_python_numbers_are_accepted_as_floats(value):
    options = BuildOptions(boundary_weight=value, distance_weight=value)
    assert type(options.boundary_weight) is float and options.boundary_weight == 2.0
    json.dumps(options.to_dict())  # the server keeps the options as JSON


@pytest.mark.parametrize("value", [10**400, -(10**400), True, np.bool_(True), "2", None, [2]])
def test_numbers_past_the_float_range_and_non_numbers_are_refused(value):
    """Regression: 10**400 escaped as OverflowError from math.isfinite."""
    with pytest.raises(qem_core.InvalidOptionsError, match="boundary_weight"):
        BuildOptions(boundary_weight=value)

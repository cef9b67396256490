"""The mesh at unit scale and back (simplify.to_unit_scale, in_input_units): every value
times a power of two, in one parallel pass.

numpy's ``np.ldexp`` takes ~9 ns a value and a new array each time: 50 ms of the dragon's
build for its vertices, the record's positions and its costs. The same C ``ldexp`` here,
in place where the caller owns the array, gives the same bits.
"""

import math

import numba


def _ldexp_into(values, exponent, limit, out):
    """out[i] = min(values[i] * 2**exponent, limit), exactly (``ldexp``; NaN stays NaN).
    values, out : flat float64 arrays of one length, out may be values."""
    for i in numba.prange(values.shape[0]):
        scaled = math.ldexp(values[i], exponent)
        out[i] = limit if scaled > limit else scaled


ldexp_into = numba.njit(cache=True, parallel=True)(_ldexp_into)

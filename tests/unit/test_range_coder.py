"""The adaptive range coder (qem_core/_kernels/range_coder.py): any sequence of integers,
tree symbols and bounded values decodes to itself, the decoder reads exactly the bytes
the encoder wrote, and a truncated or extended stream is noticed."""

import numba
import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from qem_core._kernels import range_coder as rc

# kind 0: signed integer, 1: unsigned integer, 2: 5-bit tree symbol, 3: uniform in
# [0, bound); each kind with a few context sets so that contexts interleave.
_SETS = 3
_SLOTS = _SETS * (rc.INTEGER_SLOTS + 32 + rc.UNIFORM_SLOTS)


@numba.njit
def _base(kind, context):
    block = rc.INTEGER_SLOTS + 32 + rc.UNIFORM_SLOTS
    offset = (0, 0, rc.INTEGER_SLOTS, rc.INTEGER_SLOTS + 32)[kind]
    return context * block + offset


@numba.njit
def _encode(kinds, contexts, values, bounds, out):
    enc = np.zeros(rc.ENCODER_STATE, np.int64)
    enc[rc.RANGE] = 0xFFFFFFFF
    enc[rc.HELD] = 1
    enc[rc.WRITTEN] = -1
    probs = np.full(_SLOTS, rc.HALF, np.uint16)
    for i in range(kinds.shape[0]):
        base = _base(kinds[i], contexts[i])
        if kinds[i] <= 1:
            rc.encode_integer(enc, out, probs, base, values[i], kinds[i] == 0)
        elif kinds[i] == 2:
            rc.encode_tree(enc, out, probs, base, 5, values[i])
        else:
            rc.encode_uniform(enc, out, probs, base, values[i], bounds[i])
    return rc.finish(enc, out)


@numba.njit
def _decode(kinds, contexts, bounds, data):
    probs = np.full(_SLOTS, rc.HALF, np.uint16)
    reader = rc.reader_at(data, 0)
    values = np.zeros(kinds.shape[0], np.int64)
    for i in range(kinds.shape[0]):
        base = _base(kinds[i], contexts[i])
        if kinds[i] <= 1:
            values[i], reader = rc.read_integer(reader, data, probs, base, kinds[i] == 0)
        elif kinds[i] == 2:
            values[i], reader = rc.read_tree(reader, data, probs, base, 5)
        else:
            values[i], reader = rc.read_uniform(reader, data, probs, base, bounds[i])
    return values, reader[rc.R_POSITION], reader[rc.R_BROKEN]


_LIMIT = 2**33 - 2  # the largest magnitude encode_integer takes


@st.composite
def _symbols(draw):
    n = draw(st.integers(0, 300))
    kinds, contexts, values, bounds = [], [], [], []
    small = st.integers(-40, 40)
    for _ in range(n):
        kind = draw(st.integers(0, 3))
        bound = draw(st.integers(1, 2**31)) if kind == 3 else 1
        if kind == 0:
            value = draw(st.one_of(small, st.integers(-_LIMIT, _LIMIT)))
        elif kind == 1:
            value = draw(st.one_of(small.map(abs), st.integers(0, _LIMIT)))
        elif kind == 2:
            value = draw(st.integers(0, 31))
        else:
            value = draw(st.integers(0, bound - 1))
        kinds.append(kind)
        contexts.append(draw(st.integers(0, _SETS - 1)))
        values.append(value)
        bounds.append(bound)
    as_array = lambda items: np.array(items, np.int64)  # noqa: E731
    return as_array(kinds), as_array(contexts), as_array(values), as_array(bounds)


@settings(max_examples=200)
@given(_symbols())
def test_any_symbols_round_trip_and_use_every_byte(symbols):
    kinds, contexts, values, bounds = symbols
    out = np.zeros(64 + 16 * kinds.shape[0], np.uint8)
    written = _encode(kinds, contexts, values, bounds, out)
    assert 4 <= written <= out.shape[0]
    data = out[:written].copy()
    decoded, position, broken = _decode(kinds, contexts, bounds, data)
    assert np.array_equal(decoded, values)
    assert position == written and not broken
    # Cut short: the decoder notices it read past the end (it never reads out of bounds).
    if kinds.shape[0]:
        _, position, broken = _decode(kinds, contexts, bounds, data[:-1])
        assert broken
    # One byte more: left unread.
    _, position, broken = _decode(kinds, contexts, bounds, np.append(data, np.uint8(0)))
    assert position == written and not broken


def test_skewed_values_cost_little_and_an_overflowing_buffer_is_reported():
    """Adaptive contexts learn a constant symbol: 10,000 zeros take a few bytes; an
    output buffer too small is flagged (the caller retries), not overrun."""
    n = 10_000
    zeros = np.zeros(n, np.int64)
    out = np.zeros(1 << 16, np.uint8)
    written = _encode(zeros, zeros, zeros, np.ones(n, np.int64), out)
    assert written < 40
    big = np.full(n, 2**30, np.int64)
    small = np.zeros(16, np.uint8)
    enc_written = _encode(np.ones(n, np.int64), zeros, big, np.ones(n, np.int64), small)
    assert enc_written > small.shape[0]


def test_a_code_above_the_range_is_flagged():
    """Only a corrupt stream starts with code >= range (0xFFFFFFFF): flagged at once."""
    kinds = np.zeros(3, np.int64)
    _, _, broken = _decode(kinds, kinds, np.ones(3, np.int64), np.full(8, 0xFF, np.uint8))
    assert broken


def test_uniform_over_at_most_one_value_codes_nothing():
    """v in [0, n) for n <= 1 is 0 and costs nothing: neither end touches its state or
    its contexts (n <= 0 used to loop for ever)."""
    data = np.array([0x12, 0x34, 0x56, 0x78], np.uint8)
    for n in (1, 0, -1, -(2**40)):
        enc, out, probs = rc.new_encoder(), np.zeros(16, np.uint8), rc.new_probs(rc.UNIFORM_SLOTS)
        rc.encode_uniform(enc, out, probs, 0, 0, n)
        assert np.array_equal(enc, rc.new_encoder()) and (probs == rc.HALF).all()
        reader = rc.reader_at(data, 0)
        value, after = rc.read_uniform(reader, data, probs, 0, n)
        assert value == 0 and after == reader and (probs == rc.HALF).all()


def test_an_integer_out_of_range_is_refused_not_coded():
    """A negative value unsigned (its unary prefix would never end) or a magnitude over
    2^33 - 2 (the decoder reads at most 32 ones): encode_integer returns 1 and codes
    nothing; the callers turn that into an error (test_stream.py)."""
    for value, signed in ((-1, False), (-(2**40), False), (_LIMIT + 1, False),
                          (_LIMIT + 1, True), (-(_LIMIT + 1), True)):  # fmt: skip
        enc, out, probs = rc.new_encoder(), np.zeros(16, np.uint8), rc.new_probs(rc.INTEGER_SLOTS)
        assert rc.encode_integer(enc, out, probs, 0, value, signed) == 1
        assert np.array_equal(enc, rc.new_encoder()) and (probs == rc.HALF).all()
    for value, signed in ((_LIMIT, False), (-_LIMIT, True), (0, False)):
        assert rc.encode_integer(rc.new_encoder(), out, probs, 0, value, signed) == 0

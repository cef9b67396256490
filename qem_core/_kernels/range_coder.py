"""Adaptive binary range coder (the LZMA coder: 32-bit range, carry propagation through a
cached byte) and the integer binarisations the split stream (version 3) codes with.

Every decision is a bit coded with an adaptive probability from a context: ``probs`` is
a flat uint16 array of P(bit = 0) in units of 2^-PROB_BITS, each context one slot. A
coded 0 moves its slot towards ONE by ``(ONE - p) >> RATE``, a 1 towards 0 by
``p >> RATE`` (the shift update), so p stays in [2^RATE - 1, ONE - 2^RATE + 1] =
[15, 4081] and no decision is ever certain: any bit string decodes to something, and a
decision costs at least ``-log2(4081 / 4096)`` bits (about 1/189 bit: at most 1512
decisions per byte), which bounds how many decisions a frame of a given size can hold.

Encoder state ``enc`` (int64, ENCODER_STATE slots): low (33 bits), range (32 bits), the
cached byte, the number of bytes held back (the cache and the 0xFF bytes a carry may
still ripple through), bytes written to ``out``, and whether ``out`` overflowed (the
caller retries with a bigger buffer). The first byte LZMA writes is always 0 (a carry
never reaches it): it is not written, so the decoder starts with 4 bytes.

Decoder state, a ``reader``: the tuple (range, code, read position, broken), int64s held
in the caller's locals (``reader_at``; each ``read_*`` step returns the new one), broken
set once it has read past the end of ``data`` (it then reads zeros: never an
out-of-bounds read, and the caller refuses the frame). The encoder's flush writes exactly
the bytes the decoder will read, so a whole frame ends with the read position at
``len(data)``: fewer bytes is a truncation, more is junk. A code that is not below the
range at the start (only a corrupt stream has one) is flagged the same way; with
code < range at the start, every later step keeps it so, so the state stays in 32 bits.

Binarisations (one function per kind, the caller picks the contexts):

- ``*_bit``: one decision;
- ``*_tree``: an n-bit symbol, most significant bit first, each bit's context the node
  of the binary tree above it (2^n - 1 slots): small alphabets;
- ``*_integer``: adaptive Exp-Golomb over INTEGER_SLOTS slots: the exponent
  e = floor(log2(|v| + 1)) in unary (a context per position; none after the 32nd 1),
  the e bits of |v| + 1 below its leading one (the top two with a tree of contexts per
  exponent, the rest direct bits of probability 1/2: they are close to uniform, and an
  adaptive context would cost more than it learns), then the sign of a nonzero v when
  ``signed``. Magnitudes are at most MAX_MAGNITUDE = 2^(MAX_EXPONENT + 1) - 2: the
  encoder codes nothing and returns 1 for a larger one, or a negative value unsigned
  (its caller turns that into a status), else 0.
- ``*_uniform``: v in [0, n) as the bits of v over the bit length of n - 1, most
  significant first, each with the context of its position (slots ``UNIFORM_SLOTS``);
  a bit is not coded (it is 0) while the bits so far equal those of n - 1 and that bit
  of n - 1 is 0, so no value >= n can be coded. n <= 1 codes nothing (v is 0).
"""

import numba
import numpy as np
from numba.cpython.unsafe.numbers import leading_zeros

PROB_BITS = 12
ONE = 1 << PROB_BITS
HALF = ONE >> 1
RATE = 4
TOP = 1 << 24

# enc slots
LOW = 0
RANGE = 1
CACHE = 2
HELD = 3
WRITTEN = 4
OVERFLOW = 5
ENCODER_STATE = 6

MAX_EXPONENT = 32
MAX_MAGNITUDE = (1 << (MAX_EXPONENT + 1)) - 2
_PREFIX = MAX_EXPONENT + 1  # unary exponent contexts 0..MAX_EXPONENT
_TOP_TREE = 3  # per exponent: its first two mantissa bits as a 2-level tree
INTEGER_SLOTS = _PREFIX + (MAX_EXPONENT + 1) * _TOP_TREE + 1  # + the sign
UNIFORM_SLOTS = 64


# The coding steps allocate nothing and return no array: compiled without reference
# counting (numba's ``_nrt=False``), a call costs no atomic increments and decrements of
# its array arguments, which made a coded bit about five times slower.
_kernel = numba.njit(cache=True, _nrt=False)


def new_probs(n_slots: int) -> np.ndarray:
    """Fresh contexts, every bit equally likely."""
    return np.full(n_slots, HALF, np.uint16)


def new_encoder() -> np.ndarray:
    enc = np.zeros(ENCODER_STATE, np.int64)
    enc[RANGE] = 0xFFFFFFFF
    enc[HELD] = 1
    enc[WRITTEN] = -1  # the always-zero first byte is dropped
    return enc


@_kernel
def bit_length(value):
    """The bit length of |value| (0 for 0), as one count-leading-zeros instruction: the
    shift loop it replaces ran a step per bit, for every value coded and most contexts."""
    return 64 - leading_zeros(np.uint64(abs(value)))


@_kernel
def _put(enc, out, byte):
    at = enc[WRITTEN]
    if at >= 0:
        if at < out.shape[0]:
            out[at] = byte
        else:
            enc[OVERFLOW] = 1
    enc[WRITTEN] = at + 1


@_kernel
def _shift_low(enc, out):
    low = enc[LOW]
    if low < 0xFF000000 or low > 0xFFFFFFFF:
        carry = low >> 32
        byte = enc[CACHE]
        while True:
            _put(enc, out, (byte + carry) & 0xFF)
            byte = 0xFF
            enc[HELD] -= 1
            if enc[HELD] == 0:
                break
        enc[CACHE] = (low >> 24) & 0xFF
    enc[HELD] += 1
    enc[LOW] = (low & 0x00FFFFFF) << 8


@_kernel
def encode_bit(enc, out, probs, ctx, bit):
    # The range in a local: a store to probs (or out) could alias enc for the compiler,
    # which would otherwise load enc[RANGE] again after each (a coded bit's latency is
    # what bounds the coder).
    # Without a branch on the bit: the bits coded are what the contexts could not
    # predict, so a branch on them would be guessed wrong about as often as not.
    p = np.int64(probs[ctx])
    range_ = enc[RANGE]
    bound = (range_ >> PROB_BITS) * p
    ones = -np.int64(bit != 0)  # all ones for a 1, else 0
    enc[LOW] += bound & ones
    range_ = bound + ((range_ - 2 * bound) & ones)
    probs[ctx] = p + (((ONE - p) >> RATE) & ~ones) - ((p >> RATE) & ones)
    while range_ < TOP:
        range_ <<= 8
        enc[RANGE] = range_
        _shift_low(enc, out)
    enc[RANGE] = range_


@_kernel
def encode_direct(enc, out, bit):
    """A bit with probability 1/2, no context (LZMA's direct bits)."""
    enc[RANGE] >>= 1
    enc[LOW] += enc[RANGE] & -np.int64(bit != 0)
    while enc[RANGE] < TOP:
        enc[RANGE] <<= 8
        _shift_low(enc, out)


@_kernel
def finish(enc, out):
    """Flush; returns the number of bytes written (more than len(out) if it overflowed)."""
    for _ in range(5):
        _shift_low(enc, out)
    return enc[WRITTEN]


@_kernel
def encode_tree(enc, out, probs, base, n_bits, symbol):
    node = 1
    for j in range(n_bits - 1, -1, -1):
        bit = (symbol >> j) & 1
        encode_bit(enc, out, probs, base + node - 1, bit)
        node = 2 * node + bit


@_kernel
def encode_integer(enc, out, probs, base, value, signed):
    """Returns 0, or 1 (nothing coded) for a magnitude over MAX_MAGNITUDE or a negative
    value when not ``signed`` (its unary prefix would never end)."""
    magnitude = abs(value) if signed else value
    if magnitude < 0 or magnitude > MAX_MAGNITUDE:
        return 1
    n = magnitude + 1
    exponent = bit_length(n) - 1
    for i in range(exponent):
        encode_bit(enc, out, probs, base + i, 1)
    if exponent < MAX_EXPONENT:
        encode_bit(enc, out, probs, base + exponent, 0)
    rows = base + _PREFIX + exponent * _TOP_TREE
    node = 1
    for j in range(exponent):
        bit = (n >> (exponent - 1 - j)) & 1
        if j < 2:
            encode_bit(enc, out, probs, rows + node - 1, bit)
            node = 2 * node + bit
        else:
            encode_direct(enc, out, bit)
    if signed and value != 0:
        encode_bit(enc, out, probs, base + INTEGER_SLOTS - 1, 1 if value < 0 else 0)
    return 0


@_kernel
def encode_uniform(enc, out, probs, base, value, n):
    """value in [0, n); nothing for n <= 1."""
    if n <= 1:
        return
    n_bits = bit_length(n - 1)
    tight = True  # the bits so far equal those of n - 1
    top = n - 1
    for j in range(n_bits - 1, -1, -1):
        bit = (value >> j) & 1
        if tight and ((top >> j) & 1) == 0:
            continue  # forced 0
        encode_bit(enc, out, probs, base + j, bit)
        if bit == 0:
            tight = False


# ---- decoding ---------------------------------------------------------------------------
# The reader is a tuple its user holds in locals and passes to each step, taking the new
# one back: ``reader_at``, then ``read_bit`` and the other binarisations. Held in an array
# instead (as it was), the state went to memory and came back at every decision, since
# LLVM cannot tell that a context's update does not write it (2M integers decoded: 133 ms
# in an array, 89 ms in locals; dragon's stream 0.91-0.93x its time).
R_RANGE = 0
R_CODE = 1
R_POSITION = 2
R_BROKEN = 3


@_kernel
def _read_byte(data, position, broken):
    """The byte at position and the next position; past the end a 0, and broken set."""
    if position < data.shape[0]:
        return np.int64(data[position]), position + 1, broken
    return np.int64(0), position + 1, np.int64(1)


@_kernel
def reader_at(data, offset):
    """A decoder's state over data[offset:]."""
    range_ = np.int64(0xFFFFFFFF)
    code = np.int64(0)
    position = np.int64(offset)
    broken = np.int64(0)
    for _ in range(4):
        byte, position, broken = _read_byte(data, position, broken)
        code = (code << 8) | byte
    if code >= range_:
        broken = np.int64(1)
        code = np.int64(0)
    return (range_, code, position, broken)


@_kernel
def _normalised(range_, code, position, broken, data):
    while range_ < TOP:
        range_ <<= 8
        byte, position, broken = _read_byte(data, position, broken)
        code = (code << 8) | byte
    return (range_, code, position, broken)


@_kernel
def read_bit(reader, data, probs, ctx):
    """(bit, reader). Without a branch on the bit, as encode_bit (the data decides it)."""
    range_, code, position, broken = reader
    p = np.int64(probs[ctx])
    bound = (range_ >> PROB_BITS) * p
    ones = -np.int64(code >= bound)  # all ones for a 1, else 0
    code -= bound & ones
    range_ = bound + ((range_ - 2 * bound) & ones)
    probs[ctx] = p + (((ONE - p) >> RATE) & ~ones) - ((p >> RATE) & ones)
    return ones & 1, _normalised(range_, code, position, broken, data)


@_kernel
def read_direct(reader, data):
    """(bit, reader): a bit of probability 1/2."""
    range_, code, position, broken = reader
    range_ >>= 1
    bit = np.int64(0)
    if code >= range_:
        code -= range_
        bit = np.int64(1)
        if code >= range_:  # only an odd range and a corrupt code get here
            broken = np.int64(1)
            code = np.int64(0)
    return bit, _normalised(range_, code, position, broken, data)


@_kernel
def read_tree(reader, data, probs, base, n_bits):
    node = np.int64(1)
    for _ in range(n_bits):
        bit, reader = read_bit(reader, data, probs, base + node - 1)
        node = 2 * node + bit
    return node - (1 << n_bits), reader


@_kernel
def read_integer(reader, data, probs, base, signed):
    exponent = 0
    while exponent < MAX_EXPONENT:
        more, reader = read_bit(reader, data, probs, base + exponent)
        if not more:
            break
        exponent += 1
    rows = base + _PREFIX + exponent * _TOP_TREE
    n = np.int64(1)
    node = 1
    for j in range(exponent):
        if j < 2:
            bit, reader = read_bit(reader, data, probs, rows + node - 1)
            node = 2 * node + bit
        else:
            bit, reader = read_direct(reader, data)
        n = 2 * n + bit
    magnitude = n - 1
    if signed and magnitude != 0:
        negative, reader = read_bit(reader, data, probs, base + INTEGER_SLOTS - 1)
        if negative:
            return -magnitude, reader
    return magnitude, reader


@_kernel
def read_uniform(reader, data, probs, base, n):
    """A value in [0, n): 0, reading nothing, for n <= 1."""
    if n <= 1:
        return np.int64(0), reader
    n_bits = bit_length(n - 1)
    tight = True
    top = n - 1
    value = np.int64(0)
    for j in range(n_bits - 1, -1, -1):
        if tight and ((top >> j) & 1) == 0:
            value = 2 * value
            continue
        bit, reader = read_bit(reader, data, probs, base + j)
        value = 2 * value + bit
        if bit == 0:
            tight = False
    return value, reader

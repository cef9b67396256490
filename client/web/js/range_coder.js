// The adaptive binary range decoder of the split stream (version 3), bit for bit that of
// qem_core/_kernels/range_coder.py (its docstring explains the coder): 12-bit
// probabilities of a 0 with the shift-4 update, a 32-bit range, the first byte LZMA
// writes (always 0) not stored, so decoding starts by reading 4 bytes.
//
// The range and the code are held as the int32 bit patterns of their uint32 values
// (`x | 0`, read back as `x >>> 0`): the engine keeps int32 fields in the object itself,
// where a number past 2^31 lives in a heap box of its own, which every decision loaded
// and stored through. Every step is exact in 32 bits: the code stays below the range
// (which the start checks), both below 2^32, and a bound (range >>> 12) * p below
// 2^20 * 2^12 (p < 2^12).

// The decisions read private constants only: an exported binding lives in a module
// cell, which optimised code loads (and checks) on every use rather than folding it in.
const PROBABILITY_BITS = 12;
export const PROB_BITS = PROBABILITY_BITS;
const ONE = 1 << PROBABILITY_BITS;
export const HALF = ONE >> 1;
const RATE = 4;
const TOP = 2 ** 24;
const MAX_EXPONENT = 32;
const PREFIX = MAX_EXPONENT + 1;
const TOP_TREE = 3;
const SIGN_SLOT = PREFIX + (MAX_EXPONENT + 1) * TOP_TREE; // after the magnitude's
export const INTEGER_SLOTS = SIGN_SLOT + 1;
export const UNIFORM_SLOTS = 64;

/** Bit length of |value| (stream_coding._bit_length). */
export function bitLength(value) {
  let v = Math.abs(value);
  if (v < 2 ** 31) return 32 - Math.clz32(v);
  let n = 0;
  while (v >= 1) {
    n++;
    v = Math.floor(v / 2);
  }
  return n;
}

/** Fresh contexts, every bit equally likely. */
export function newProbs(nSlots) {
  return new Uint16Array(nSlots).fill(HALF);
}

export class RangeDecoder {
  /** A decoder over all of `data` (Uint8Array). */
  constructor(data) {
    this.data = data;
    this.position = 0;
    this.broken = false; // read past the end, or a code no encoder writes
    this.range = 0xffffffff | 0;
    let code = 0;
    for (let i = 0; i < 4; i++) code = code * 256 + this.nextByte();
    if (code >= 0xffffffff) {
      this.broken = true;
      code = 0;
    }
    this.code = code | 0;
  }

  nextByte() {
    const at = this.position++;
    if (at < this.data.length) return this.data[at];
    this.broken = true;
    return 0;
  }

  normalise() {
    while (this.range >>> 0 < TOP) {
      this.range <<= 8;
      this.code = (this.code << 8) | this.nextByte();
    }
  }

  bit(probs, ctx) {
    const p = probs[ctx];
    const bound = Math.imul(this.range >>> PROBABILITY_BITS, p); // below 2^32: exact
    let bit;
    if (this.code >>> 0 < bound >>> 0) {
      this.range = bound;
      probs[ctx] = p + ((ONE - p) >> RATE);
      bit = 0;
    } else {
      this.code = (this.code - bound) | 0;
      this.range = (this.range - bound) | 0;
      probs[ctx] = p - (p >> RATE);
      bit = 1;
    }
    this.normalise();
    return bit;
  }

  direct() {
    const range = this.range >>> 1;
    this.range = range;
    let bit = 0;
    if (this.code >>> 0 >= range) {
      this.code = (this.code - range) | 0;
      bit = 1;
      if (this.code >>> 0 >= range) {
        this.broken = true;
        this.code = 0;
      }
    }
    this.normalise();
    return bit;
  }

  /** An nBits symbol, most significant bit first, contexts the tree's nodes. */
  tree(probs, base, nBits) {
    let node = 1;
    for (let j = 0; j < nBits; j++) node = 2 * node + this.bit(probs, base + node - 1);
    return node - (1 << nBits);
  }

  /** Adaptive Exp-Golomb (range_coder.read_integer). */
  integer(probs, base, signed) {
    let exponent = 0;
    while (exponent < MAX_EXPONENT && this.bit(probs, base + exponent)) exponent++;
    const rows = base + PREFIX + exponent * TOP_TREE;
    let n = 1;
    let node = 1;
    for (let j = 0; j < exponent; j++) {
      let bit;
      if (j < 2) {
        bit = this.bit(probs, rows + node - 1);
        node = 2 * node + bit;
      } else {
        bit = this.direct();
      }
      n = 2 * n + bit;
    }
    const magnitude = n - 1;
    if (signed && magnitude !== 0 && this.bit(probs, base + SIGN_SLOT)) return -magnitude;
    return magnitude;
  }

  /** A value in [0, n), n <= 2^32 (range_coder.read_uniform): 0, reading nothing,
   * for n <= 1. */
  uniform(probs, base, n) {
    if (n <= 1) return 0;
    const top = n - 1;
    const nBits = 32 - Math.clz32(top);
    let tight = true;
    let value = 0;
    for (let j = nBits - 1; j >= 0; j--) {
      if (tight && ((top >>> j) & 1) === 0) {
        value *= 2;
        continue;
      }
      const bit = this.bit(probs, base + j);
      value = 2 * value + bit;
      if (bit === 0) tight = false;
    }
    return value;
  }
}

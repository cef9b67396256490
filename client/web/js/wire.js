// Bytes to values for the viewer's wire formats: frames cut from a byte stream
// (qem_core/stream.py), bin fields of msgpack maps copied into typed arrays. Errors are
// WireFormatError. (The frames' range-coded fields: range_coder.js.)

const FRAME_LIMIT = 64 << 20; // as qem_core.stream: a larger length means a broken stream

export class WireFormatError extends Error {
  constructor(message) {
    super(message);
    this.name = "WireFormatError";
  }
}

export function fail(message) {
  throw new WireFormatError(message);
}

/** A split decoder's refusals of a frame's coded splits, worded once for both (refine.js
 * and the WebAssembly one, wasm_splits.js, which refuse the same frames the same way):
 * `t` the split's new vertex, `value` what the message names. */
export const SPLITS_REFUSED = {
  short: () => "split frame: the coded splits end early (truncated or corrupt data)",
  notYet: (t) => `split ${t}: names a vertex that does not exist yet`,
  work: (t, limit) => `split frame: the splits walk more than ${limit} corners of their split vertices`,
  counts: () => "split frame: the splits' face counts do not add up to n_new_faces",
  noVertex: (t) => `split ${t}: a new face uses a vertex that does not exist`,
  faceCode: (t, code) => `split frame: bad face code ${code}`,
  third: (t) => `split ${t}: a third corner is not a neighbour of the split vertex`,
  relabel: (t) => `split ${t}: a relabelled face has no corner s`,
  grid: () => "split frame: a position leaves the grid ([0, 2^bits - 1])",
  trailing: () => "split frame: the coded splits hold bytes past the last split",
  memory: () => "split frame: the decoder ran out of memory",
  baseVertex: () => "base mesh: a face names a vertex that does not exist",
};

/** A typed array over a copy of msgpack bin bytes (copied: views may be unaligned). */
export function binArray(bytes, Type, count, what) {
  if (!(bytes instanceof Uint8Array) || bytes.length !== count * Type.BYTES_PER_ELEMENT) {
    fail(
      `base mesh: '${what}' holds ${bytes?.length} bytes, expected ${count * Type.BYTES_PER_ELEMENT}`,
    );
  }
  const copy = new Uint8Array(bytes.length);
  copy.set(bytes);
  return new Type(copy.buffer);
}

export const INDEX_TYPES = { u8: Uint8Array, u16: Uint16Array, u32: Uint32Array };

/** Whether two grid numbers (origins, steps) agree to a relative 1e-9, the tolerance of
 * qem_core.stream._GRID_TOLERANCE: position and attribute grids are compared alike. */
export function gridClose(a, b) {
  return Math.abs(a - b) <= 1e-9 * Math.max(Math.abs(a), Math.abs(b), 1e-300);
}

/** Cuts a byte stream (any chunking) into frame payloads. */
export class FrameCutter {
  constructor() {
    this.buffer = new Uint8Array(1 << 16);
    this.start = 0;
    this.end = 0;
    this.failure = null; // a bad length met after good frames: raised on the next call
  }

  /** Append a chunk; returns the payloads it completed (copies, in stream order). A bad
   * frame length is raised after the frames before it are returned (by the next push or
   * finish), so that how the bytes were chunked does not change what is refined. */
  push(chunk) {
    if (this.failure) fail(this.failure);
    this.reserve(chunk.length);
    this.buffer.set(chunk, this.end);
    this.end += chunk.length;
    const payloads = [];
    while (this.end - this.start >= 4) {
      const b = this.buffer;
      const s = this.start;
      const length = (b[s] | (b[s + 1] << 8) | (b[s + 2] << 16) | (b[s + 3] << 24)) >>> 0;
      if (length > FRAME_LIMIT) {
        this.failure = `split frame declares ${length} bytes, over the limit`;
        if (payloads.length === 0) fail(this.failure);
        break;
      }
      if (this.end - s < 4 + length) break;
      payloads.push(b.slice(s + 4, s + 4 + length));
      this.start = s + 4 + length;
    }
    return payloads;
  }

  /** Raise if the stream ended inside a frame. */
  finish() {
    if (this.failure) fail(this.failure);
    if (this.end > this.start) {
      fail(`split stream ends inside a frame (${this.end - this.start} bytes left)`);
    }
  }

  reserve(extra) {
    const held = this.end - this.start;
    if (this.start > 0 && this.end + extra > this.buffer.length) {
      this.buffer.copyWithin(0, this.start, this.end);
      this.start = 0;
      this.end = held;
    }
    if (held + extra > this.buffer.length) {
      let size = this.buffer.length;
      while (size < held + extra) size *= 2;
      const grown = new Uint8Array(size);
      grown.set(this.buffer.subarray(0, held));
      this.buffer = grown;
    }
  }
}

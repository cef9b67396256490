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

// The progressive mesh in the browser: the base mesh plus every vertex split received,
// held in buffers sized for the full mesh, moved to any received level both ways.
//
// Wire formats (qem_core/stream.py, qem_core/codecs/msgpack_mesh.py):
//   base mesh   one msgpack map "qem-mesh-msgpack" v1, positions "u16" on the grid whose
//               box is `bbox` (the very integers the split stream's deltas refer to);
//   split stream  frames of uint32 LE length L + L bytes holding a msgpack map
//               "qem-splits" v3 and the CRC-32 of its bytes; its `splits` bytes are
//               range-coded (range_coder.js): connectivity relative to the split
//               vertex's neighbourhood, which the decoder below keeps at the received
//               level, positions as residuals (docs/formats.md section 2); a mesh with
//               appearance has wedges, in both (wedges.js; the frame's `wedges` bytes).
//
// Split k (level L = nBase + k -> L + 1), as qem_core/_kernels/refine.py applies it:
//
//   before: s at p           after: s at p + d_s, t = L at p + d_t
//   faces F(L)                      faces F(L + 1): new ones appended (corners as born),
//                                   each listed face gets its corner s -> t
//
// Going down undoes the splits last first: listed faces get t -> s back, s moves back by
// d_s, the face count drops to F(L). Both directions are exact on the integers, so the
// buffers always hold every received face at its state for the current level, and a
// move costs O(splits crossed + relabels), never a refetch.

// A relative path, not the page's import map: the decoder also runs in a Web Worker
// (decoder_worker.js), where import maps do not apply.
import { decode } from "../node_modules/@msgpack/msgpack/dist.esm/index.mjs";
import { bitLength, INTEGER_SLOTS, newProbs, RangeDecoder, UNIFORM_SLOTS } from "./range_coder.js";
import { binArray, fail, FrameCutter, gridClose, INDEX_TYPES, SPLITS_REFUSED, WireFormatError } from "./wire.js";
import { WasmSplits } from "./wasm_splits.js";
import { sortPrefix } from "./sorted.js";
import { decodeBaseWedges, decodeWedgeFields, WedgeLevels } from "./wedges.js";

export { FrameCutter, WireFormatError };

export const STREAM_VERSION = 6;
export const MESH_VERSION = 1;
const EXPLICIT_FACE = 6; // face codes 0-2: (s, t, x) rotated; 3-5: (t, s, x); 6: explicit
const ESCAPE = 255; // a third corner given as a back-distance, not as a neighbour index
const SPAN_RING_LIMIT = 64; // as stream_coding.py: products stay below 2^53
const FAN_SCAN = 16; // fans of up to this many corners are scanned rather than sorted
// s is coded as its gap ahead of the previous split's s, else as its bucket of
// [0, previous s], then its place in it
const S_BUCKETS = 32;
const S_BUCKET_BITS = 5;
const DIFF_BITS = 13; // as stream_coding.py: shifts that keep products below 2^53
const NORMAL_BITS = 12;
const LAPLACE_BITS = 20;
const FAN_BLOCK = 16; // int32s per vertex in SplitState.fan: a 64-byte cache line
const FAN_Q = 2; // where a block holds its vertex's grid position (3 int32s)
const FAN_STAMP = 5; // then a stamp: the last set of neighbours the vertex was put in
const FAN_CORNERS = 6; // where its corners start
const FAN_INLINE = FAN_BLOCK - FAN_CORNERS; // corners a block holds before its list spills
const FRAME_SPLIT_LIMIT = 1 << 16; // as qem_core.stream: what one frame may allocate
// As stream_coding.FRAME_WORK_LIMIT: the corners of split vertices one frame may walk.
const FRAME_WORK_LIMIT = 1 << 21;
const FRAME_FACE_LIMIT = 1 << 22;
const ITEMS_PER_BYTE = 512;
const MIN_BITS = 8; // the grid bits a frame may carry (qem_core.stream, grid_for)
const MAX_BITS = 24;
// The contexts of the coded fields, slots of one probability array
// (qem_core/_kernels/stream_coding.py, same layout).
const ROWS = 21;
const STEP_ROWS = 9;
const IS = INTEGER_SLOTS;
const S_BUCKET_SLOTS = 0;
const S_SLOTS = S_BUCKET_SLOTS + S_BUCKETS;
const S_AHEAD_SLOTS = S_SLOTS + UNIFORM_SLOTS;
const S_GAP_SLOTS = S_AHEAD_SLOTS + 2;
const COUNT_SLOTS = S_GAP_SLOTS + IS;
const CODE_SLOTS = COUNT_SLOTS + IS;
const ESCAPE_SLOT = CODE_SLOTS + 8 * 8;
const THIRD_SLOTS = ESCAPE_SLOT + 1;
const STEP_SLOTS = THIRD_SLOTS + 17 * 8;
const BACK_SLOTS = STEP_SLOTS + STEP_ROWS * IS;
const MASK_SLOTS = BACK_SLOTS + IS;
const SPAN_SLOTS = MASK_SLOTS + 3;
const SPAN_SIGN_SLOTS = SPAN_SLOTS + ROWS * IS;
const NORMAL_SLOTS = SPAN_SIGN_SLOTS + 3;
const PLACE_SLOTS = NORMAL_SLOTS + ROWS * IS;
const MID_SLOTS = PLACE_SLOTS + 2;
const MID1_SLOTS = MID_SLOTS + ROWS * IS;
const MID2_SLOTS = MID1_SLOTS + ROWS * IS;
const MID3_SLOTS = MID2_SLOTS + ROWS * IS;
const MID_SIGN_SLOTS = MID3_SLOTS + ROWS * IS;
const LATTICE_SLOT = MID_SIGN_SLOTS + 6; // the mid's tangent values on the lattice?
const LATTICE1_SLOTS = LATTICE_SLOT + 1;
const LATTICE3_SLOTS = LATTICE1_SLOTS + IS;
export const CONTEXT_SLOTS = LATTICE3_SLOTS + IS;
// The tangent lattice's step is 2^(bitlen(max |e_d|) - LATTICE_BITS) (stream_coding.lattice_step).
const LATTICE_BITS = 4;

// 2 ** n for the shifts below: `2 ** variable` calls the C library's pow (6 % of a
// dragon decode).
const POW2 = Float64Array.from({ length: 64 }, (_, n) => 2 ** n);

/** Context of a sign: 0 for 0, 1 for positive, 2 for negative (stream_coding._sign). */
function signContext(value) {
  return value > 0 ? 1 : value < 0 ? 2 : 0;
}

/** The three values shifted right (floor) until the largest has at most `bits` bits
 * (stream_coding._shift_to). */
function shiftTo(values, bits) {
  const big = Math.max(Math.abs(values[0]), Math.abs(values[1]), Math.abs(values[2]));
  if (big < POW2[bits]) return; // no shift
  const divisor = POW2[bitLength(big) - bits];
  for (let d = 0; d < 3; d++) values[d] = Math.floor(values[d] / divisor);
}

/** num / den rounded to nearest, halves up (stream_coding._round_div). */
function roundDiv(num, den) {
  if (den < 0) {
    num = -num;
    den = -den;
  }
  return Math.floor((2 * num + den) / (2 * den));
}

/** Index of the largest magnitude of the three, the first on ties. */
function dominant(values) {
  let k = 0;
  for (let d = 1; d < 3; d++) if (Math.abs(values[d]) > Math.abs(values[k])) k = d;
  return k;
}

/** A signed value: its magnitude (integer at slots[0]), then its sign at slots[1]. */
function decodeValue(coder, probs, slots) {
  const magnitude = coder.integer(probs, slots[0], false);
  return magnitude !== 0 && coder.bit(probs, slots[1]) ? -magnitude : magnitude;
}

/** The grid p = origin + q * step of `bits` bits over the box low..high (quantise.Grid). */
export function gridOverBox(bbox, bits) {
  const top = 2 ** bits - 1;
  const origin = bbox.slice(0, 3);
  const step = [0, 1, 2].map((d) => (bbox[3 + d] > bbox[d] ? bbox[3 + d] - bbox[d] : 1) / top);
  return { origin, step, bits };
}

/** Decode a "qem-mesh-msgpack" level with u16 positions (the form lod?format=msgpack). */
export function decodeBaseMesh(bytes) {
  let message;
  try {
    message = decode(bytes);
  } catch (error) {
    fail(`base mesh: not msgpack (${error.message})`);
  }
  if (message?.format !== "qem-mesh-msgpack") fail("base mesh: not a qem-mesh-msgpack map");
  if (message.version !== MESH_VERSION) {
    fail(
      `base mesh: version ${message.version} is not supported (this viewer reads ${MESH_VERSION})`,
    );
  }
  if (message.position_encoding !== "u16") {
    fail(
      `base mesh: positions are '${message.position_encoding}', the splits need 'u16' grid integers`,
    );
  }
  const nVertices = message.vertex_count;
  const nFaces = message.face_count;
  // A fraction got past the length checks below (the arrays' sizes are rounded down).
  for (const [name, count] of [["vertex_count", nVertices], ["face_count", nFaces]]) {
    if (!Number.isInteger(count) || count < 0) {
      fail(`base mesh: '${name}' must be a non-negative integer, got ${count}`);
    }
  }
  const IndexType = INDEX_TYPES[message.index_type];
  if (!IndexType) fail(`base mesh: unknown index_type '${message.index_type}'`);
  const bbox = message.bbox;
  if (!Array.isArray(bbox) || bbox.length !== 6 || !bbox.every(Number.isFinite)) {
    fail("base mesh: 'bbox' must be 6 finite numbers");
  }
  if ([0, 1, 2].some((d) => bbox[d] > bbox[3 + d])) {
    fail(`base mesh: 'bbox' [${bbox}]: a min is above its max`);
  }
  const bits = message.position_bits;
  if (!Number.isInteger(bits) || bits < 1 || bits > 16) {
    fail(`base mesh: 'position_bits' must be 1..16, got ${bits}`);
  }
  // As quantise.Grid.check: a box float64 cannot step over would put vertices at infinity.
  const grid = gridOverBox(bbox, bits);
  if (![0, 1, 2].every((d) => Number.isFinite(grid.origin[d] + (2 ** bits - 1) * grid.step[d]))) {
    fail(`base mesh: 'bbox' [${bbox}] spans more than float64 can hold`);
  }
  const texture = message.texture instanceof Uint8Array ? message.texture : null;
  // As qem_core.codecs.msgpack_mesh.read_msgpack: splits refine only a level whose faces
  // name its own vertices and whose integers lie on its grid.
  const positions = binArray(message.positions, Uint16Array, 3 * nVertices, "positions");
  const indices = binArray(message.indices, IndexType, 3 * nFaces, "indices");
  const top = 2 ** bits - 1;
  if (positions.some((q) => q > top)) fail(`base mesh: 'positions' hold values past the ${bits}-bit grid`);
  if (indices.some((v) => v >= nVertices)) {
    fail(`base mesh: 'indices' name a vertex past 'vertex_count' ${nVertices}`);
  }
  return {
    nVertices,
    nFaces,
    bbox,
    bits,
    positions,
    indices,
    wedges: message.wedges === undefined ? null : decodeBaseWedges(message.wedges, nFaces),
    texture: texture && { bytes: texture, type: message.texture_type },
    materials: baseMaterials(message.materials),
  };
}

/** The looks of a mesh of several materials (qem_core.codecs.msgpack_mesh's "materials"),
 * checked: [{ name, color: [r, g, b, a] | null, texture: { bytes, type } | null }], or
 * null for a mesh without them. Each face's material is the wedge value "material". */
function baseMaterials(list) {
  if (list === undefined || list === null) return null;
  if (!Array.isArray(list) || list.length < 2 || list.length > 256) {
    fail("base mesh: 'materials' must be a list of 2 to 256 maps");
  }
  return list.map((entry, i) => {
    const color = entry?.color ?? null;
    const ok =
      entry &&
      typeof entry.name === "string" &&
      (color === null || (Array.isArray(color) && color.length === 4 && color.every((c) => c >= 0 && c <= 1))) &&
      (entry.texture == null || entry.texture instanceof Uint8Array);
    if (!ok) fail(`base mesh: 'materials' entry ${i} is not a material`);
    return {
      name: entry.name,
      color,
      texture: entry.texture ? { bytes: entry.texture, type: entry.texture_type ?? "image/png" } : null,
    };
  });
}

/** msgpack bin bytes of an exact length (any length when `length` is null). */
function binField(body, key, length) {
  const value = body[key];
  if (!(value instanceof Uint8Array) || (length !== null && value.length !== length)) {
    fail(`split frame: '${key}' holds ${value?.length} bytes, expected ${length}`);
  }
  return value;
}

const CRC_TABLE = (() => {
  const table = new Uint32Array(256);
  for (let n = 0; n < 256; n++) {
    let c = n;
    for (let k = 0; k < 8; k++) c = c & 1 ? 0xedb88320 ^ (c >>> 1) : c >>> 1;
    table[n] = c >>> 0;
  }
  return table;
})();

/** CRC-32 (IEEE 802.3, zlib.crc32) of bytes. */
export function crc32(bytes) {
  let c = 0xffffffff;
  for (let i = 0; i < bytes.length; i++) c = CRC_TABLE[(c ^ bytes[i]) & 0xff] ^ (c >>> 8);
  return (c ^ 0xffffffff) >>> 0;
}

/** One frame payload (msgpack map + CRC-32 of it), its counts checked (the splits decode
 * against the mesh). */
export function decodeFrame(payload) {
  const n = payload.length - 4;
  const stored =
    n >= 0
      ? (payload[n] | (payload[n + 1] << 8) | (payload[n + 2] << 16) | (payload[n + 3] << 24)) >>> 0
      : -1;
  if (n < 0 || crc32(payload.subarray(0, n)) !== stored) {
    fail("split frame: the CRC-32 does not match (damaged frame)");
  }
  const bytes = payload.subarray(0, n);
  let body;
  try {
    body = decode(bytes);
  } catch (error) {
    fail(`unreadable split frame: ${error.message}`);
  }
  if (body?.format !== "qem-splits") fail("not a qem-splits frame");
  if (!(body.version <= STREAM_VERSION)) {
    fail(`split frame version ${body.version} is too new (this reads ${STREAM_VERSION})`);
  }
  if (body.version !== STREAM_VERSION) {
    fail(`split frame version ${body.version} is no longer read (this reads ${STREAM_VERSION})`);
  }
  for (const key of ["n_from", "n_to", "faces_from", "n_new_faces"]) {
    if (!Number.isInteger(body[key]) || body[key] < 0)
      fail(`split frame: '${key}' is ${body[key]}`);
  }
  const continues = body.continues ?? false;
  if (continues !== true && continues !== false) fail(`split frame: 'continues' is ${continues}`);
  if (!continues) {
    // A stream's first frame carries the grid; the next ones go on with it.
    if (!Number.isInteger(body.bits) || body.bits < MIN_BITS || body.bits > MAX_BITS) {
      fail(`split frame: 'bits' is ${body.bits}, not an integer in [${MIN_BITS}, ${MAX_BITS}]`);
    }
    if (!Array.isArray(body.grid) || body.grid.length !== 6 || !body.grid.every(Number.isFinite)) {
      fail("split frame: 'grid' must be 6 finite numbers");
    }
  }
  const k = body.n_to - body.n_from;
  const nNew = body.n_new_faces;
  if (k < 0) fail("split frame: inconsistent counts");
  const coded = binField(body, "splits", null);
  // As qem_core.stream._check_frame_size: bounded before anything is allocated.
  if (k > FRAME_SPLIT_LIMIT || nNew > FRAME_FACE_LIMIT) {
    fail(`split frame: ${k} splits / ${nNew} faces, over the limit`);
  }
  if (Math.max(k, nNew) > ITEMS_PER_BYTE * (coded.length + 1)) {
    fail(`split frame: ${coded.length} coded bytes cannot hold ${k} splits and ${nNew} faces`);
  }
  return {
    nFrom: body.n_from,
    nTo: body.n_to,
    facesFrom: body.faces_from,
    continues,
    bits: continues ? null : body.bits,
    grid: continues ? null : body.grid,
    nNewFaces: nNew,
    coded,
    wedges: decodeWedgeFields(body, k),
  };
}

/** A frame whose coded splits ran out before its last split. */
function failShort() {
  fail(SPLITS_REFUSED.short());
}

/** Every split's s of a frame, which it codes before the splits' other fields
 * (stream_coding._decode_split_vertices): the ahead decision and the gap, else the
 * bucket and the offset within it. */
function decodeSplitVertices(coder, probs, nFrom, k) {
  const splitVertex = new Int32Array(k);
  let previousS = -1; // the previous split's s: the build takes them in ascending sweeps
  let wasAhead = 0;
  for (let i = 0; i < k; i++) {
    if (coder.broken) failShort();
    const t = nFrom + i;
    if (t < 1) fail(SPLITS_REFUSED.notYet(t));
    let s;
    if (coder.bit(probs, S_AHEAD_SLOTS + wasAhead)) {
      wasAhead = 1;
      s = previousS + 1 + coder.integer(probs, S_GAP_SLOTS, false);
      if (s >= t) fail(SPLITS_REFUSED.notYet(t));
    } else {
      wasAhead = 0;
      const n = previousS + 1;
      const bucket = coder.tree(probs, S_BUCKET_SLOTS, S_BUCKET_BITS);
      const lo = Math.floor((bucket * n + S_BUCKETS - 1) / S_BUCKETS);
      const hi = Math.floor(((bucket + 1) * n + S_BUCKETS - 1) / S_BUCKETS);
      if (hi <= lo) fail(SPLITS_REFUSED.notYet(t));
      s = lo + coder.uniform(probs, S_SLOTS, hi - lo);
    }
    previousS = s;
    splitVertex[i] = s;
  }
  return splitVertex;
}

/**
 * The connectivity of the received level, as qem_core/_kernels/stream_coding.py keeps
 * it: the faces, and per vertex a list of the corners (3 * face + j) naming it.
 */
class SplitState {
  constructor(base, nFull, fFull) {
    this.faces = new Int32Array(3 * fFull);
    this.faces.set(base.indices);
    // Each vertex's corners and grid position in a block of its own (count, spill
    // offset, position, stamp, then the corners): a split reads its vertex's whole list in one
    // or two cache lines, and a neighbour's position brings in the list that a new face
    // at it appends to, where a linked list through the corners costs a dependent memory
    // miss per corner (the decoder waited on those more than it computed). A list longer
    // than the block moves to `spill`, at offset block[1], its capacity just before it.
    this.fan = new Int32Array(FAN_BLOCK * nFull);
    for (let v = 0; v < base.nVertices; v++) {
      for (let d = 0; d < 3; d++) this.fan[FAN_BLOCK * v + FAN_Q + d] = base.positions[3 * v + d];
    }
    this.spill = new Int32Array(1024);
    this.spillEnd = 1; // offset 0 means "not spilled"
    for (let c = 0; c < 3 * base.nFaces; c++) {
      const v = this.faces[c];
      if (v >= base.nVertices) fail(SPLITS_REFUSED.baseVertex());
      this.link(v, c);
    }
    this.cs = new Int32Array(16); // corners of s, sorted
    this.after = new Int32Array(16); // the corner after s in the face of each
    this.before = new Int32Array(16); // and the one before
    this.nb = new Int32Array(32); // its distinct neighbours, sorted
    this.mark = new Uint8Array(16);
    this.ys = new Int32Array(16); // vertices met walking around s
    this.visits = new Int32Array(16); // the corners the split's last walk took, in order
    // and where it started, which way, how many it took, whether it ended at its stop
    this.walkedFrom = -1;
    this.walkedForward = false;
    this.walkedSteps = 0;
    this.walkedToStop = false;
    this.keys = new Float64Array(16); // the fan's corners by side (fanKeys)
    this.stamps = 0; // the last stamp given (newStamp)
    this.sumA = [0, 0, 0];
    this.sumB = [0, 0, 0];
    // decodeMid's frame: products past 2^31, in float64 arrays of their own (a fresh
    // array per split was garbage, and changed its elements' kind on the way)
    this.binormal = new Float64Array(3);
    this.reduced = new Float64Array(3);
  }

  /** A new stamp: a set of distinct neighbours is made by stamping each in its block
   * (beside the position its user reads next) rather than by searching the set. */
  newStamp() {
    if (this.stamps === 0x7fffffff) {
      for (let at = FAN_STAMP; at < this.fan.length; at += FAN_BLOCK) this.fan[at] = 0;
      this.stamps = 0;
    }
    return ++this.stamps;
  }

  /** v's corners (any order) are list[at .. at + count), count returned, list and at
   * left in this.list and this.listAt. */
  cornersOf(v) {
    const block = FAN_BLOCK * v;
    const spilled = this.fan[block + 1];
    this.list = spilled ? this.spill : this.fan;
    this.listAt = spilled || block + FAN_CORNERS;
    return this.fan[block];
  }

  link(v, c) {
    const fan = this.fan;
    const block = FAN_BLOCK * v;
    const n = fan[block];
    let at = fan[block + 1];
    if (at === 0 && n < FAN_INLINE) {
      fan[block + FAN_CORNERS + n] = c;
      fan[block] = n + 1;
      return;
    }
    if (at === 0 || this.spill[at - 1] === n) at = this.respill(block, at, n);
    this.spill[at + n] = c;
    fan[block] = n + 1;
  }

  /** Move the n corners of the vertex at `block` (in the block, or spilled at `from`) to
   * a new spill area of twice the room; its offset. */
  respill(block, from, n) {
    const capacity = 2 * Math.max(n, FAN_INLINE);
    let at = this.spillEnd + 1;
    if (at + capacity > this.spill.length) {
      let size = this.spill.length;
      while (size < at + capacity) size *= 2;
      const grown = new Int32Array(size);
      grown.set(this.spill);
      this.spill = grown;
    }
    this.spill[at - 1] = capacity;
    if (from === 0) this.spill.set(this.fan.subarray(block + FAN_CORNERS, block + FAN_CORNERS + n), at);
    else this.spill.copyWithin(at, from, from + n);
    this.spillEnd = at + capacity;
    this.fan[block + 1] = at;
    return at;
  }

  /** Drop from s's list the corners its split relabelled to t, in one pass once they are
   * all relabelled, keeping the list in order: lists stay sorted (corners join in
   * increasing order: a new face's are the highest yet, and a relabelled corner goes to
   * the new vertex t, whose list it starts), so gather's sort finds them in order. */
  dropMoved(s) {
    const n = this.cornersOf(s);
    const { list, faces } = this;
    const at = this.listAt;
    let m = 0;
    for (let i = 0; i < n; i++) {
      const c = list[at + i];
      list[at + m] = c;
      if (faces[c] === s) m++;
    }
    this.fan[FAN_BLOCK * s] = m;
  }

  /** Sorted corners of s into cs (this.nc of them), the corners after and before s in
   * their faces into after and before, sorted distinct other vertices into nb
   * (this.nn). */
  gather(s) {
    const faces = this.faces;
    const nc = this.cornersOf(s);
    if (nc > this.cs.length) this.grow(2 * nc);
    const { cs, after, before, nb } = this;
    const list = this.list;
    const at = this.listAt;
    for (let q = 0; q < nc; q++) cs[q] = list[at + q];
    sortPrefix(cs, nc);
    for (let q = 0; q < nc; q++) {
      const c = cs[q];
      const f = c - (c % 3);
      const j = c - f;
      after[q] = faces[f + ((j + 1) % 3)];
      before[q] = faces[f + ((j + 2) % 3)];
    }
    // With s, a face's three corners: its others are those of the two that are not s.
    const fan = this.fan;
    const stamp = this.newStamp();
    let nn = 0;
    for (let q = 0; q < nc; q++) {
      const a = FAN_BLOCK * after[q] + FAN_STAMP;
      const b = FAN_BLOCK * before[q] + FAN_STAMP;
      if (after[q] !== s && fan[a] !== stamp) {
        fan[a] = stamp;
        nb[nn++] = after[q];
      }
      if (before[q] !== s && fan[b] !== stamp) {
        fan[b] = stamp;
        nb[nn++] = before[q];
      }
    }
    sortPrefix(nb, nn);
    this.nc = nc;
    this.nn = nn;
  }

  /** Room for the buffers of `degree` corners of s (cs keeps what it holds). */
  grow(degree) {
    const cs = new Int32Array(degree);
    cs.set(this.cs);
    this.cs = cs;
    this.after = new Int32Array(degree);
    this.before = new Int32Array(degree);
    this.nb = new Int32Array(2 * degree);
    this.mark = new Uint8Array(degree);
    this.ys = new Int32Array(degree);
    this.visits = new Int32Array(degree);
    this.keys = new Float64Array(degree);
  }

  /** keys[0..nc) = side * nc + q sorted, side the corner before s (after s when not
   * `forward`) in the face of cs[q] (stream_coding._fan_keys): for fans of more than
   * FAN_SCAN corners, whose walk looks its steps up rather than scanning for them. */
  fanKeys(nc, forward) {
    if (this.keysFor === forward) return; // this split's corners, keyed so already
    this.keysFor = forward;
    const sides = forward ? this.before : this.after;
    const keys = this.keys;
    for (let q = 0; q < nc; q++) keys[q] = sides[q] * nc + q;
    sortPrefix(keys, nc);
  }

  /** The first corner q (in cs order) not marked in `used` whose side is y, or -1
   * (stream_coding._fan_next), in the keys of fanKeys. */
  fanNext(nc, used, y) {
    const keys = this.keys;
    let lo = 0;
    let hi = nc;
    while (lo < hi) {
      const mid = (lo + hi) >>> 1;
      if (keys[mid] < y * nc) lo = mid + 1;
      else hi = mid;
    }
    for (; lo < nc && keys[lo] < (y + 1) * nc; lo++) {
      const q = keys[lo] - y * nc;
      if (!used[q]) return q;
    }
    return -1;
  }

  /** Walk around s from `start` (stream_coding._walk): the corners taken are marked in
   * mark[0..nc), the vertices met before `stop` go into ys; returns how many. Each step
   * takes the first corner (in cs order) not taken yet whose side (the corner before s,
   * after s when not `forward`) is the vertex reached, and goes on to its other side. */
  walk(nc, start, forward, stop) {
    const { mark, ys, visits } = this;
    const sides = forward ? this.before : this.after;
    const steps = forward ? this.after : this.before;
    for (let q = 0; q < nc; q++) mark[q] = 0; // TypedArray.fill is a runtime call
    let y = start;
    let m = 0;
    let taken = 0;
    let toStop = false;
    // Few corners are scanned for the first one not taken whose side is y; more are
    // looked up in the fan's keys.
    const scan = nc <= FAN_SCAN;
    if (!scan) this.fanKeys(nc, forward);
    for (let step = 0; step < nc; step++) {
      let q = -1;
      if (scan) {
        for (let r = 0; r < nc; r++) {
          if (sides[r] === y && !mark[r]) {
            q = r;
            break;
          }
        }
      } else {
        q = this.fanNext(nc, mark, y);
      }
      if (q < 0) break;
      mark[q] = 1;
      y = steps[q];
      visits[taken++] = q;
      if (y === stop) {
        toStop = true;
        break;
      }
      ys[m++] = y;
    }
    this.walkedFrom = start;
    this.walkedForward = forward;
    this.walkedSteps = taken;
    this.walkedToStop = toStop;
    return m;
  }

  /** The predicted relabel mask into mark[0..nc): the fan of s's faces from wing xl to
   * wing xr, or back from xr without xl (stream_coding._predict). The second wing's walk
   * (the split's first) went forward from xl too in nearly every split, and took the
   * same corners as this one until one of them stopped: its visits give this walk,
   * unless it stopped at xl before reaching xr (this one would go on). */
  predict(nc, xl, xr) {
    if (xl >= 0 && this.walkedSteps > 0 && this.walkedFrom === xl && this.walkedForward) {
      const { mark, visits, after } = this;
      for (let q = 0; q < nc; q++) mark[q] = 0;
      for (let p = 0; p < this.walkedSteps; p++) {
        const q = visits[p];
        mark[q] = 1;
        if (after[q] === xr) return;
      }
      if (!this.walkedToStop) return;
    }
    if (xl >= 0) this.walk(nc, xl, true, xr);
    else if (xr >= 0) this.walk(nc, xr, false, -1);
    else for (let q = 0; q < nc; q++) this.mark[q] = 0;
  }

  /** What the positions' contexts need of s's ring before the split (nn neighbours in
   * nb), into shape (stream_coding._ring_shape): the spread per axis, the ring's normal
   * and the sign context of the curvature along it. */
  ringShape(s, nc, nn, shape) {
    const { after, before, nb } = this;
    const q = this.fan;
    const sx = q[FAN_BLOCK * s + FAN_Q];
    const sy = q[FAN_BLOCK * s + FAN_Q + 1];
    const sz = q[FAN_BLOCK * s + FAN_Q + 2];
    // the bits of every |offset|: its bit length is that of the largest, and OR-ing them
    // has no branch to mispredict, which would hold back the loads of the next ones
    let bits = 0;
    let ax = 0; // sums of |offset|
    let ay = 0;
    let az = 0;
    let lx = 0; // sums of offsets
    let ly = 0;
    let lz = 0;
    for (let j = 0; j < nn; j++) {
      const w = FAN_BLOCK * nb[j] + FAN_Q;
      const ox = q[w] - sx;
      const oy = q[w + 1] - sy;
      const oz = q[w + 2] - sz;
      lx += ox;
      ly += oy;
      lz += oz;
      ax += Math.abs(ox);
      ay += Math.abs(oy);
      az += Math.abs(oz);
      bits |= Math.abs(ox) | Math.abs(oy) | Math.abs(oz);
    }
    const spread = shape.spread;
    spread[0] = nn ? Math.floor(ax / nn) : 0;
    spread[1] = nn ? Math.floor(ay / nn) : 0;
    spread[2] = nn ? Math.floor(az / nn) : 0;
    // Offsets are differences of grid integers (below 2^24 in magnitude), so an
    // arithmetic shift is their floor division by 2^shift.
    const shift = Math.max(0, bitLength(bits) - DIFF_BITS);
    let nx = 0;
    let ny = 0;
    let nz = 0;
    for (let i = 0; i < nc; i++) {
      const u = FAN_BLOCK * after[i] + FAN_Q;
      const w = FAN_BLOCK * before[i] + FAN_Q;
      const ux = (q[u] - sx) >> shift;
      const uy = (q[u + 1] - sy) >> shift;
      const uz = (q[u + 2] - sz) >> shift;
      const wx = (q[w] - sx) >> shift;
      const wy = (q[w + 1] - sy) >> shift;
      const wz = (q[w + 2] - sz) >> shift;
      nx += uy * wz - uz * wy;
      ny += uz * wx - ux * wz;
      nz += ux * wy - uy * wx;
    }
    const normal = shape.normal;
    normal[0] = nx;
    normal[1] = ny;
    normal[2] = nz;
    shiftTo(normal, NORMAL_BITS);
    const laplace = shape.laplace;
    laplace[0] = lx;
    laplace[1] = ly;
    laplace[2] = lz;
    shiftTo(laplace, LAPLACE_BITS);
    shape.bulge = Math.sign(laplace[0] * normal[0] + laplace[1] * normal[1] + laplace[2] * normal[2]);
  }

  /** Sum of the grid positions of v's distinct neighbours other than `other` into
   * total; returns their number (stream_coding._ring_sum). Each is stamped in its
   * block, whose position is read next. */
  ringSum(v, other, total) {
    const { faces, fan } = this;
    const n = this.cornersOf(v);
    const list = this.list;
    const at = this.listAt;
    const stamp = this.newStamp();
    let count = 0;
    let x = 0;
    let y = 0;
    let z = 0;
    for (let i = 0; i < n; i++) {
      // The corner's own vertex is v: only the face's two others can join the set (both
      // are still checked against v, for a face that holds it twice).
      const c = list[at + i];
      const f = c - (c % 3);
      const j = c - f;
      for (let k = 1; k < 3; k++) {
        const w = faces[f + ((j + k) % 3)];
        const block = FAN_BLOCK * w;
        if (w === v || w === other || fan[block + FAN_STAMP] === stamp) continue;
        fan[block + FAN_STAMP] = stamp;
        count++;
        const q = block + FAN_Q;
        x += fan[q];
        y += fan[q + 1];
        z += fan[q + 2];
      }
    }
    total[0] = x;
    total[1] = y;
    total[2] = z;
    return count;
  }

  /** The predicted t - s_new once the split's faces are in place: s and t each at the
   * centroid of its ring, solved for both, floored (stream_coding._span_prediction). */
  spanPrediction(s, t, prediction) {
    const sumA = this.sumA;
    const sumB = this.sumB;
    const a = this.ringSum(t, s, sumA);
    const b = this.ringSum(s, t, sumB);
    prediction[0] = 0;
    prediction[1] = 0;
    prediction[2] = 0;
    if (a === 0 || b === 0 || a > SPAN_RING_LIMIT || b > SPAN_RING_LIMIT) return;
    const den = (a + 1) * (b + 1) - 1;
    for (let d = 0; d < 3; d++) {
      const pt = Math.floor((sumA[d] * (b + 1) + sumB[d]) / den);
      const ps = Math.floor((sumB[d] * (a + 1) + sumA[d]) / den);
      prediction[d] = pt - ps;
    }
  }

  /** The first corner of face f equal to s becomes t, linked to t (it leaves s's list
   * at dropMoved); false if there is none. */
  relabel(f, s, t) {
    for (let j = 0; j < 3; j++) {
      const c = 3 * f + j;
      if (this.faces[c] === s) {
        this.faces[c] = t;
        this.link(t, c);
        return true;
      }
    }
    return false;
  }
}

/** Whether the first nFaces faces of `indices` (rows of three vertices below nVertices)
 * are closed surfaces with every face turned the same way: each edge in two faces that
 * go along it in opposite directions. Seen from outside, such a mesh's back faces lie
 * behind its front ones. */
function closedAndOriented(indices, nFaces, nVertices) {
  if (nFaces === 0 || nVertices > 2 ** 25) return false; // keys below stay exact
  // Each directed edge as its undirected edge's key, doubled, plus 1 when it goes down:
  // closed and oriented, the sorted keys come in pairs 2e, 2e + 1 (then each pair once,
  // the next one starting at an even key past 2e + 1).
  const keys = new Float64Array(3 * nFaces);
  for (let f = 0; f < nFaces; f++) {
    for (let j = 0; j < 3; j++) {
      const a = indices[3 * f + j];
      const b = indices[3 * f + ((j + 1) % 3)];
      keys[3 * f + j] = a < b ? 2 * (a * nVertices + b) : 2 * (b * nVertices + a) + 1;
    }
  }
  keys.sort();
  if (keys.length % 2) return false;
  for (let i = 0; i < keys.length; i += 2) {
    if (keys[i] % 2 !== 0 || keys[i + 1] !== keys[i] + 1) return false;
  }
  return true;
}

/** Six times the volume that the first nFaces faces enclose, positive when they are
 * wound counter-clockwise seen from outside (glTF's and three.js's front faces). */
function enclosedVolume(positions, indices, nFaces) {
  let volume = 0;
  for (let f = 0; f < nFaces; f++) {
    const a = 3 * indices[3 * f];
    const b = 3 * indices[3 * f + 1];
    const c = 3 * indices[3 * f + 2];
    // a . (b x c), the corners' grid positions
    volume +=
      positions[a] * (positions[b + 1] * positions[c + 2] - positions[b + 2] * positions[c + 1]) +
      positions[a + 1] * (positions[b + 2] * positions[c] - positions[b] * positions[c + 2]) +
      positions[a + 2] * (positions[b] * positions[c + 1] - positions[b + 1] * positions[c]);
  }
  return volume;
}

/**
 * The mesh at any received level, in buffers allocated once for the full mesh.
 *
 * positions : Float32Array(3 * nFull), grid integers (exact in float32 below 2^24);
 *   render with origin + q * step as the object's transform.
 * indices : Uint32Array(3 * fFull), every received face at its state for `level`.
 */
export class ProgressiveLevels {
  /** `decoder: false` holds the levels only: frames are decoded elsewhere (a Web Worker,
   * decoder_worker.js) and their splits arrive as records (`addRecord`), so the big
   * decoding state is not kept twice. `wasm`, the compiled split decoder
   * (wasm_splits.js's loadSplitModule), decodes the frames' splits in WebAssembly, with
   * the same results (a mesh's wedge keys are decoded by wedges.js still, at each split). */
  constructor(base, nFull, fFull, { decoder = true, wasm = null } = {}) {
    if (!(nFull >= base.nVertices && fFull >= base.nFaces)) {
      fail(`the full mesh (${nFull} vertices, ${fFull} faces) is smaller than the base mesh`);
    }
    this.nBase = base.nVertices;
    this.nFull = nFull;
    this.fFull = fFull;
    this.bits = base.bits;
    this.grid = gridOverBox(base.bbox, base.bits);
    this.positions = new Float32Array(3 * nFull);
    this.positions.set(base.positions);
    this.indices = new Uint32Array(3 * fFull);
    this.indices.set(base.indices);
    const nSplits = nFull - this.nBase;
    // Split records, kept so that the level can go down as well as up.
    this.splitVertex = new Uint32Array(nSplits);
    this.deltas = new Int32Array(6 * nSplits);
    this.levelFaces = new Uint32Array(nSplits + 1); // faces of level nBase + k
    this.levelFaces[0] = base.nFaces;
    this.relabelOffsets = new Uint32Array(nSplits + 1);
    this.relabelFaces = new Uint32Array(Math.max(16, 2 * nSplits)); // grows if needed
    this.received = this.nBase; // vertex count up to which splits are held
    // The received level, for decoding.
    if (!decoder) {
      this.state = null;
    } else if (wasm !== null) {
      this.state = new WasmSplits(wasm, base, nFull, fFull, { cornersOf: SplitState.prototype.cornersOf });
    } else {
      this.state = new SplitState(base, nFull, fFull);
    }
    this.contexts = null; // the range coder's, as the stream's last frame left them
    this.broken = null; // why a frame was refused half-way
    this.level = this.nBase; // vertex count the buffers hold now
    // Appearance (UVs, colours, normals) when the base mesh has wedges; the stream's
    // wedge fields are ignored without.
    this.wedges = base.wedges ? new WedgeLevels(base, this, { decoder }) : null;
    if (this.wedges && this.state instanceof WasmSplits) {
      // The module decodes the splits and calls out for each one's wedges, which
      // WedgeLevels decodes reading the module's state as it reads a SplitState's: the
      // same arrays (WasmSplits.stateView), and SplitState's own way to a vertex's list.
      const splits = this.state;
      splits.onWedgeSplit = (i, s, t, nc, firstFace, face) =>
        this.wedges.decodeSplit(i, s, t, splits.stateView(), nc, firstFace, face);
    }
    this.texture = base.texture;
    this.materials = base.materials;
    // The levels up to closedTo are closed surfaces with every face turned outwards, so
    // a view from outside sees no back face (scene.js culls them); -1 for none. A mesh
    // turned inside out (its faces wound inwards, a negative volume) is drawn from both
    // sides, as any other, so that it shows its near side.
    const closed = closedAndOriented(base.indices, base.nFaces, base.nVertices);
    this.closedTo = closed && enclosedVolume(base.positions, base.indices, base.nFaces) > 0 ? this.nBase : -1;
  }

  /** Whether level n is known to be a closed surface with its faces turned outwards:
   * the base mesh is, and every split up to n added two faces. Such a split cuts a closed
   * fan into two, its wings, and so keeps the surface closed; any other (at a border,
   * of a pair that shares no edge, a non-manifold one) may open it, and the levels from
   * it on are not known to be closed. */
  closedAt(n) {
    return n <= this.closedTo;
  }

  /** Move closedTo over the splits received since (addFrame, addRecord). Once it stops
   * at a split that may open the surface, it stays there: that split ends the scan at
   * once each time. */
  extendClosed() {
    if (this.closedTo < 0) return;
    let k = this.closedTo - this.nBase;
    const end = this.received - this.nBase;
    while (k < end && this.levelFaces[k + 1] - this.levelFaces[k] === 2) k++;
    this.closedTo = this.nBase + k;
  }

  /** Which decoder decodes the frames: "wasm", "js", or null (levels that take records). */
  get decoder() {
    if (this.state === null) return null;
    return this.state instanceof WasmSplits ? "wasm" : "js";
  }

  facesAt(n) {
    return this.levelFaces[n - this.nBase];
  }

  get nFaces() {
    return this.facesAt(this.level);
  }

  /** Store a decoded frame's splits (they must continue the received ones, or be held
   * already: then skipped); the new faces go into the index buffer as born. Does not
   * move the level. A frame refused half-way
   * leaves the decoder state unusable: later frames are refused too. */
  addFrame(frame) {
    if (!this.state) fail("these levels take records of splits decoded elsewhere, not frames");
    if (this.broken) fail(`an earlier frame was refused: ${this.broken}`);
    const { nFrom, nTo, facesFrom } = frame;
    // A key frame of splits held already (a stored run served from the frame boundary
    // at or below the level asked for): skipped.
    if (!frame.continues && nFrom < nTo && nTo <= this.received) return;
    if (nFrom !== this.received || facesFrom !== this.facesAt(this.received)) {
      fail(
        `frame refines ${nFrom} vertices / ${facesFrom} faces, the viewer holds ` +
          `${this.received} / ${this.facesAt(this.received)}`,
      );
    }
    if (nTo > this.nFull) fail(`frame goes to ${nTo} vertices, past the full ${this.nFull}`);
    if (frame.continues) {
      if (!this.contexts) {
        fail("split frame continues a stream whose previous frame the viewer did not decode");
      }
    } else {
      this.checkGrid(frame);
    }
    const faces = facesFrom + frame.nNewFaces;
    if (faces > this.fFull) fail(`frame brings ${faces} faces, past the full ${this.fFull}`);
    if (!frame.continues) this.contexts = newProbs(CONTEXT_SLOTS); // a stream's first frame
    try {
      this.wedges?.beginFrame(frame.wedges, frame.continues);
      if (this.state instanceof WasmSplits) this.state.decodeSplits(frame, this);
      else this.decodeSplits(frame);
      this.wedges?.endFrame();
    } catch (error) {
      this.broken = error.message;
      throw error;
    }
    this.received = nTo;
    this.extendClosed();
  }

  /** The splits that refine level nFrom to nTo (both received), as copies: what a
   * ProgressiveLevels without a decoder needs to hold them (`addRecord`). Every array
   * is its own buffer, so a worker can transfer them. Read before the level moves past
   * nFrom: the new faces are taken as born. */
  recordOf(nFrom, nTo) {
    const a = nFrom - this.nBase;
    const b = nTo - this.nBase;
    if (!(a >= 0 && a <= b && nTo <= this.received)) fail(`no received splits ${nFrom}..${nTo}`);
    const firstFace = this.levelFaces[a];
    const lastFace = this.levelFaces[b];
    return {
      nFrom,
      nTo,
      splitVertex: this.splitVertex.slice(a, b),
      deltas: this.deltas.slice(6 * a, 6 * b),
      levelFaces: this.levelFaces.slice(a + 1, b + 1),
      relabelOffsets: this.relabelOffsets.slice(a + 1, b + 1),
      relabelFaces: this.relabelFaces.slice(this.relabelOffsets[a], this.relabelOffsets[b]),
      faces: this.indices.slice(3 * firstFace, 3 * lastFace),
      wedges: this.wedges ? this.wedges.recordOf(a, b, firstFace, lastFace) : null,
    };
  }

  /** Hold the splits of a record (`recordOf` of levels decoding the same stream): they
   * must continue the received ones. Does not move the level. */
  addRecord(record) {
    const { nFrom, nTo } = record;
    if (nFrom !== this.received || !(nTo >= nFrom && nTo <= this.nFull)) {
      fail(`a record of splits ${nFrom}..${nTo} does not continue the ${this.received} vertices held`);
    }
    if (!!record.wedges !== !!this.wedges) fail("a record of splits does not match the levels' wedges");
    const a = nFrom - this.nBase;
    const b = nTo - this.nBase;
    const firstFace = this.levelFaces[a];
    this.splitVertex.set(record.splitVertex, a);
    this.deltas.set(record.deltas, 6 * a);
    this.levelFaces.set(record.levelFaces, a + 1);
    this.relabelOffsets.set(record.relabelOffsets, a + 1);
    this.reserveRelabels(this.relabelOffsets[b]);
    this.relabelFaces.set(record.relabelFaces, this.relabelOffsets[a]);
    this.indices.set(record.faces, 3 * firstFace);
    this.wedges?.addRecord(record.wedges, a, b, firstFace);
    this.received = nTo;
    this.extendClosed();
  }

  /** The frame's splits against the received level (stream_coding.decode_connectivity),
   * decoded from its range-coded bytes with the contexts the stream's previous frame
   * left (fresh for its first frame), stored as split vertex, deltas and relabelled
   * faces. */
  decodeSplits(frame) {
    const { nFrom } = frame;
    const k = frame.nTo - nFrom;
    const first = nFrom - this.nBase;
    const state = this.state;
    const sf = state.faces;
    const fan = state.fan;
    const out = this.indices;
    const coder = new RangeDecoder(frame.coded);
    const probs = this.contexts;
    const badThird = (t) => fail(SPLITS_REFUSED.third(t));
    let relabel = this.relabelOffsets[first];
    let face = frame.facesFrom;
    const faceEnd = face + frame.nNewFaces;
    const prediction = [0, 0, 0];
    const shape = { spread: [0, 0, 0], normal: new Float64Array(3), laplace: new Float64Array(3), bulge: 0 };
    const edge = [0, 0, 0];
    const mid = [0, 0, 0];
    const axes = [0, 1, 2];
    const slots = [0, 0];
    let cornersWalked = 0;
    const splitVertex = decodeSplitVertices(coder, probs, nFrom, k);
    for (let i = 0; i < k; i++) {
      if (coder.broken) failShort();
      const t = nFrom + i;
      const s = splitVertex[i];
      state.gather(s);
      const { nc, nn } = state;
      cornersWalked += nc;
      if (i > 0 && cornersWalked > FRAME_WORK_LIMIT) {
        fail(SPLITS_REFUSED.work(t, FRAME_WORK_LIMIT));
      }
      state.keysFor = null; // the fan keys are not this split's yet
      state.walkedSteps = 0; // nor is any walk
      state.ringShape(s, nc, nn, shape);
      const count = coder.integer(probs, COUNT_SLOTS, false);
      if (count > faceEnd - face) fail(SPLITS_REFUSED.counts());
      let xl = -1;
      let xr = -1;
      let firstForward = false;
      let walkLength = -1;
      const firstNew = face;
      let previous = 7;
      for (let j = 0; j < count; j++, face++) {
        const code = coder.tree(probs, CODE_SLOTS + 8 * previous, 3);
        previous = code;
        const f = 3 * face;
        if (code === EXPLICIT_FACE) {
          for (let c = 0; c < 3; c++) {
            const b = coder.integer(probs, BACK_SLOTS, false);
            if (b > t) fail(SPLITS_REFUSED.noVertex(t));
            sf[f + c] = t - b;
          }
          continue;
        }
        if (code > EXPLICIT_FACE) fail(SPLITS_REFUSED.faceCode(t, code));
        const forward = code < 3;
        const wing = xl >= 0 || xr >= 0;
        let x = -1;
        if (wing && walkLength < 0 && forward !== firstForward) {
          // The second wing: its step on the walk around s from the first.
          const start = xl >= 0 ? xl : xr;
          walkLength = state.walk(nc, start, firstForward, start);
          if (walkLength > 0) {
            const step = coder.integer(probs, STEP_SLOTS + Math.min(walkLength, STEP_ROWS - 1) * IS, false);
            if (step > walkLength) badThird(t);
            if (step < walkLength) x = state.ys[step];
          }
        }
        if (!wing) firstForward = forward;
        if (x >= 0) {
          // given by the walk
        } else if (coder.bit(probs, ESCAPE_SLOT)) {
          const b = coder.integer(probs, BACK_SLOTS, false);
          if (b > t) fail(SPLITS_REFUSED.noVertex(t));
          x = t - b;
        } else if (nn > 0) {
          const nIndex = Math.min(nn, ESCAPE);
          x = state.nb[coder.uniform(probs, THIRD_SLOTS + Math.min(nIndex, 16) * 8, nIndex)];
        } else {
          badThird(t);
        }
        const rotation = code % 3;
        sf[f + rotation] = forward ? s : t;
        sf[f + ((rotation + 1) % 3)] = forward ? t : s;
        sf[f + ((rotation + 2) % 3)] = x;
        if (forward && xl < 0) xl = x;
        if (!forward && xr < 0) xr = x;
      }
      for (let c = 3 * firstNew; c < 3 * face; c++) out[c] = sf[c]; // as born
      state.predict(nc, xl, xr);
      const mark = state.mark;
      if (nc && coder.bit(probs, MASK_SLOTS)) {
        for (let j = 0; j < nc; j++) mark[j] = coder.bit(probs, MASK_SLOTS + 1 + mark[j]);
      }
      this.reserveRelabels(relabel + nc);
      for (let j = 0; j < nc; j++) {
        if (!mark[j]) continue;
        const f = Math.floor(state.cs[j] / 3);
        if (!state.relabel(f, s, t)) fail(SPLITS_REFUSED.relabel(t));
        this.relabelFaces[relabel++] = f;
      }
      state.dropMoved(s);
      for (let c = 3 * firstNew; c < 3 * face; c++) state.link(sf[c], c);
      this.wedges?.decodeSplit(i, s, t, state, nc, firstNew, face);
      this.decodePositions(coder, probs, state, s, t, shape, prediction, edge, mid, axes, slots);
      for (let axis = 0; axis < 3; axis++) {
        const old = fan[FAN_BLOCK * s + FAN_Q + axis];
        const a = mid[axis];
        fan[FAN_BLOCK * s + FAN_Q + axis] = a;
        fan[FAN_BLOCK * t + FAN_Q + axis] = a + edge[axis];
        this.deltas[6 * (first + i) + axis] = a - old;
        this.deltas[6 * (first + i) + 3 + axis] = a + edge[axis] - old;
      }
      this.splitVertex[first + i] = s;
      this.levelFaces[first + i + 1] = face;
      this.relabelOffsets[first + i + 1] = relabel;
    }
    if (coder.broken) failShort();
    if (coder.position !== frame.coded.length) {
      fail(SPLITS_REFUSED.trailing());
    }
    if (face !== faceEnd) fail(SPLITS_REFUSED.counts());
  }

  /** A split's positions, its connectivity applied (decode_connectivity's last steps):
   * edge = t - s_new per axis, and into mid the new position of s. */
  decodePositions(coder, probs, state, s, t, shape, prediction, edge, mid, axes, slots) {
    const fan = state.fan;
    const { spread, normal, bulge } = shape;
    state.spanPrediction(s, t, prediction);
    // position_span: the axes other than the normal's dominant one against the rings'
    // prediction, then that one against the plane of the ring (stream_coding._span_slots).
    const k = dominant(normal);
    const plane = normal[k] !== 0;
    axes[0] = plane && k === 0 ? 1 : 0;
    axes[1] = plane && k === 2 ? 1 : plane ? 2 : 1;
    axes[2] = plane ? k : 2;
    for (let n = 0; n < 3; n++) {
      const d = axes[n];
      const row = Math.min(bitLength(spread[d]), ROWS - 1);
      let against;
      if (plane && n === 2) {
        slots[0] = NORMAL_SLOTS + row * IS;
        slots[1] = slots[0] + IS - 1;
        against = roundDiv(-(normal[axes[0]] * edge[axes[0]] + normal[axes[1]] * edge[axes[1]]), normal[d]);
      } else {
        slots[0] = SPAN_SLOTS + row * IS;
        slots[1] = SPAN_SIGN_SLOTS + signContext(prediction[d]);
        against = prediction[d];
      }
      edge[d] = decodeValue(coder, probs, slots) + against;
    }
    let placement = 0;
    if (coder.bit(probs, PLACE_SLOTS)) placement = 1 + coder.bit(probs, PLACE_SLOTS + 1);
    if (placement === 0) this.decodeMid(coder, probs, state, normal, bulge, edge, mid, slots);
    // Every value so far is an exact integer in float64 (the coder's are below 2^34);
    // the 32-bit buffers take only positions on the grid (decode_connectivity refuses
    // the others too, so both decoders refuse the same frames).
    const qMax = POW2[this.bits] - 1;
    for (let axis = 0; axis < 3; axis++) {
      const old = fan[FAN_BLOCK * s + FAN_Q + axis];
      const e = edge[axis];
      if (placement === 1) mid[axis] = old;
      else if (placement === 2) mid[axis] = old - e;
      else mid[axis] = (2 * (old + mid[axis]) + (e & 1) - e) / 2; // a + b = 2 (old + mid) + (e & 1)
      const a = mid[axis];
      if (!(a >= 0 && a <= qMax && a + e >= 0 && a + e <= qMax)) {
        fail(SPLITS_REFUSED.grid());
      }
    }
  }

  /** position_mid into mid (offsets from s's old position), in the frame of e and the
   * normal when there is one (stream_coding._mid_frame, _mid_slots). */
  decodeMid(coder, probs, state, normal, bulge, edge, mid, slots) {
    const binormal = state.binormal;
    binormal[0] = edge[1] * normal[2] - edge[2] * normal[1];
    binormal[1] = edge[2] * normal[0] - edge[0] * normal[2];
    binormal[2] = edge[0] * normal[1] - edge[1] * normal[0];
    const k = dominant(binormal);
    if (binormal[k] === 0) {
      for (let d = 0; d < 3; d++) {
        slots[0] = MID_SLOTS + Math.min(bitLength(edge[d]), ROWS - 1) * IS;
        slots[1] = slots[0] + IS - 1;
        mid[d] = decodeValue(coder, probs, slots);
      }
      return;
    }
    shiftTo(binormal, NORMAL_BITS);
    const first = k === 0 ? 1 : 0;
    const second = k === 2 ? 1 : 2;
    const swap = Math.abs(edge[second]) > Math.abs(edge[first]);
    const a = swap ? second : first;
    const b = swap ? first : second;
    const reduced = state.reduced;
    for (let d = 0; d < 3; d++) reduced[d] = edge[d];
    shiftTo(reduced, NORMAL_BITS);
    const length = Math.min(bitLength(Math.abs(edge[0]) + Math.abs(edge[1]) + Math.abs(edge[2])), ROWS - 1);
    const big = Math.max(Math.abs(edge[0]), Math.abs(edge[1]), Math.abs(edge[2]));
    const step = POW2[Math.max(0, bitLength(big) - LATTICE_BITS)];
    const lattice = step > 1 && coder.bit(probs, LATTICE_SLOT) === 1;
    slots[0] = lattice ? LATTICE1_SLOTS : MID1_SLOTS + Math.min(bitLength(edge[a]), ROWS - 1) * IS;
    slots[1] = MID_SIGN_SLOTS + signContext(bulge * normal[a]);
    const value = decodeValue(coder, probs, slots);
    mid[a] = lattice ? this.onLattice(value, step) : value;
    slots[0] = MID2_SLOTS + length * IS;
    const cross = normal[b] * reduced[a] - normal[a] * reduced[b];
    slots[1] = MID_SIGN_SLOTS + 3 + signContext(bulge * Math.sign(cross) * Math.sign(reduced[a]));
    const along = reduced[a] === 0 ? 0 : roundDiv(mid[a] * reduced[b], reduced[a]);
    mid[b] = decodeValue(coder, probs, slots) + along;
    slots[0] = lattice ? LATTICE3_SLOTS : MID3_SLOTS + length * IS;
    slots[1] = slots[0] + IS - 1;
    const third = decodeValue(coder, probs, slots);
    mid[k] = (lattice ? this.onLattice(third, step) : third) + roundDiv(-(binormal[a] * mid[a] + binormal[b] * mid[b]), binormal[k]);
  }

  /** A tangent value coded in units of the lattice step, in grid units. A mid within
   * the grid has values of a few grid lengths; larger ones are refused, which keeps the
   * product below 2^53 (decode_connectivity refuses the same). */
  onLattice(value, step) {
    if (Math.abs(value) > 8 * POW2[this.bits]) fail(SPLITS_REFUSED.grid());
    return value * step;
  }

  checkGrid(frame) {
    const { origin, step, bits } = this.grid;
    const same =
      frame.bits === bits &&
      [0, 1, 2].every((d) => gridClose(frame.grid[d], origin[d]) && gridClose(frame.grid[3 + d], step[d]));
    if (!same) {
      fail(
        `the split stream's grid (${frame.bits} bits, ${frame.grid}) is not the base mesh's ` +
          `(${bits} bits, ${origin}, ${step}): positions would not refine exactly`,
      );
    }
  }

  reserveRelabels(count) {
    if (count <= this.relabelFaces.length) return;
    let size = this.relabelFaces.length;
    while (size < count) size *= 2;
    const grown = new Uint32Array(size);
    grown.set(this.relabelFaces);
    this.relabelFaces = grown;
  }

  /** Move the buffers to `n` vertices (clamped into [nBase, received]); returns the
   * level reached. */
  setLevel(n) {
    const target = Math.max(this.nBase, Math.min(Math.round(n), this.received));
    if (this.state && !this.wedges && target === this.received && 8 * (target - this.level) > target) {
      this.copyReceivedLevel();
    }
    while (this.level < target) this.applySplit(this.level - this.nBase);
    while (this.level > target) this.undoSplit(this.level - 1 - this.nBase);
    return this.level;
  }

  /** Move the buffers to the received level by copying the decoder's state, which holds
   * it: one pass over the arrays instead of a random access per split crossed. */
  copyReceivedLevel() {
    const { fan, faces } = this.state;
    const positions = this.positions;
    for (let v = 0; v < this.received; v++) {
      const at = FAN_BLOCK * v + FAN_Q;
      positions[3 * v] = fan[at];
      positions[3 * v + 1] = fan[at + 1];
      positions[3 * v + 2] = fan[at + 2];
    }
    this.indices.set(faces.subarray(0, 3 * this.facesAt(this.received)));
    this.level = this.received;
  }

  applySplit(k) {
    const s = this.splitVertex[k];
    const t = this.nBase + k;
    const q = this.positions;
    const d = this.deltas;
    for (let axis = 0; axis < 3; axis++) {
      const old = q[3 * s + axis];
      q[3 * s + axis] = old + d[6 * k + axis];
      q[3 * t + axis] = old + d[6 * k + 3 + axis];
    }
    const faces = this.indices;
    for (let r = this.relabelOffsets[k]; r < this.relabelOffsets[k + 1]; r++) {
      const f = 3 * this.relabelFaces[r];
      // The first corner that is s, as apply_split_run does.
      if (faces[f] === s) faces[f] = t;
      else if (faces[f + 1] === s) faces[f + 1] = t;
      else if (faces[f + 2] === s) faces[f + 2] = t;
    }
    this.wedges?.applySplit(k, s, t);
    this.level = t + 1;
  }

  undoSplit(k) {
    const s = this.splitVertex[k];
    const t = this.nBase + k;
    const faces = this.indices;
    for (let r = this.relabelOffsets[k + 1] - 1; r >= this.relabelOffsets[k]; r--) {
      const f = 3 * this.relabelFaces[r];
      // t did not exist before this split, so the one corner that is t was s.
      if (faces[f] === t) faces[f] = s;
      else if (faces[f + 1] === t) faces[f + 1] = s;
      else if (faces[f + 2] === t) faces[f + 2] = s;
    }
    const q = this.positions;
    for (let axis = 0; axis < 3; axis++) q[3 * s + axis] -= this.deltas[6 * k + axis];
    this.wedges?.undoSplit(k, s, t);
    this.level = t;
  }
}

/**
 * Stream the splits of `url` into `frames` (ProgressiveLevels, or a WorkerDecoder: anything
 * with addFrame): fetch + ReadableStream, frames cut as bytes arrive and added in order
 * (the first that cannot be stops the stream).
 * onFrame(bytesSoFar) runs after each frame is stored; onBytes(bytesSoFar) after each
 * network chunk.
 */
export async function streamSplits(url, frames, { onFrame, onBytes, signal } = {}) {
  const response = await fetch(url, { signal });
  if (!response.ok) throw await problemError(response);
  let bytes = 0;
  await readFrames(response, {
    onChunk: (n) => {
      bytes += n; // counted without onBytes too: onFrame and the result tell it
      onBytes?.(bytes);
    },
    onPayload: (payload) => {
      frames.addFrame(decodeFrame(payload));
      onFrame?.(bytes);
    },
  });
  return bytes;
}

/**
 * Read a response body to its end, cutting it into frame payloads as chunks arrive:
 * onChunk(chunkLength) for each chunk, then onPayload(payload) for each frame it
 * completes. Raises (and cancels the body) if a callback does, or if the body ends
 * inside a frame.
 */
export async function readFrames(response, { onChunk, onPayload }) {
  const reader = response.body.getReader();
  const cutter = new FrameCutter();
  try {
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      onChunk(value.length);
      for (const payload of cutter.push(value)) onPayload(payload);
    }
    cutter.finish();
  } catch (error) {
    reader.cancel().catch(() => {});
    throw error;
  }
}

/** An Error carrying an RFC 9457 problem (or the status line when the body is not one). */
export async function problemError(response) {
  let detail = `${response.status} ${response.statusText}`;
  let problem = null;
  try {
    problem = await response.json();
    detail = problem.detail || problem.title || detail;
  } catch {
    // not JSON: keep the status line
  }
  const error = new Error(detail);
  error.status = response.status;
  error.problem = problem;
  return error;
}

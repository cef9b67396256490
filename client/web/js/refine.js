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

import { decode } from "@msgpack/msgpack";
import { bitLength, INTEGER_SLOTS, newProbs, RangeDecoder, UNIFORM_SLOTS } from "./range_coder.js";
import { binArray, fail, FrameCutter, INDEX_TYPES, WireFormatError } from "./wire.js";
import { decodeBaseWedges, decodeWedgeFields, WedgeLevels } from "./wedges.js";

export { FrameCutter, WireFormatError };

export const STREAM_VERSION = 3;
export const MESH_VERSION = 1;
const EXPLICIT_FACE = 6; // face codes 0-2: (s, t, x) rotated; 3-5: (t, s, x); 6: explicit
const ESCAPE = 255; // a third corner given as a back-distance, not as a neighbour index
const PREDICT_LIMIT = 64; // as qem_core/_kernels/stream_coding.py
const SPAN_RING_LIMIT = 64; // as stream_coding.py: products stay below 2^53
const FRAME_SPLIT_LIMIT = 1 << 16; // as qem_core.stream: what one frame may allocate
const FRAME_FACE_LIMIT = 1 << 22;
const ITEMS_PER_BYTE = 512;
// The contexts of the coded fields, slots of one probability array
// (qem_core/_kernels/stream_coding.py, same layout).
const ROWS = 21;
const S_SLOTS = 0;
const COUNT_SLOTS = S_SLOTS + UNIFORM_SLOTS;
const CODE_SLOTS = COUNT_SLOTS + INTEGER_SLOTS;
const ESCAPE_SLOT = CODE_SLOTS + 8 * 8;
const THIRD_SLOTS = ESCAPE_SLOT + 1;
const BACK_SLOTS = THIRD_SLOTS + 17 * 8;
const MASK_SLOTS = BACK_SLOTS + INTEGER_SLOTS;
const SPAN_SLOTS = MASK_SLOTS + 2;
const MID_SLOTS = SPAN_SLOTS + ROWS * INTEGER_SLOTS;
const CONTEXT_SLOTS = MID_SLOTS + ROWS * INTEGER_SLOTS;

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
  const IndexType = INDEX_TYPES[message.index_type];
  if (!IndexType) fail(`base mesh: unknown index_type '${message.index_type}'`);
  const bbox = message.bbox;
  if (!Array.isArray(bbox) || bbox.length !== 6 || !bbox.every(Number.isFinite)) {
    fail("base mesh: 'bbox' must be 6 finite numbers");
  }
  const texture = message.texture instanceof Uint8Array ? message.texture : null;
  return {
    nVertices,
    nFaces,
    bbox,
    bits: message.position_bits,
    positions: binArray(message.positions, Uint16Array, 3 * nVertices, "positions"),
    indices: binArray(message.indices, IndexType, 3 * nFaces, "indices"),
    wedges: message.wedges === undefined ? null : decodeBaseWedges(message.wedges, nFaces),
    texture: texture && { bytes: texture, type: message.texture_type },
  };
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
  for (const key of ["n_from", "n_to", "faces_from", "bits", "n_new_faces"]) {
    if (!Number.isInteger(body[key]) || body[key] < 0)
      fail(`split frame: '${key}' is ${body[key]}`);
  }
  const k = body.n_to - body.n_from;
  const nNew = body.n_new_faces;
  if (k < 0) fail("split frame: inconsistent counts");
  if (!Array.isArray(body.grid) || body.grid.length !== 6) fail("split frame: bad 'grid'");
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
    bits: body.bits,
    grid: body.grid,
    nNewFaces: nNew,
    coded,
    wedges: decodeWedgeFields(body, k),
  };
}

/**
 * The connectivity of the received level, as qem_core/_kernels/stream_coding.py keeps
 * it: the faces, and per vertex a list of the corners (3 * face + j) naming it.
 */
class SplitState {
  constructor(base, nFull, fFull) {
    this.faces = new Int32Array(3 * fFull);
    this.faces.set(base.indices);
    this.head = new Int32Array(nFull).fill(-1);
    this.next = new Int32Array(3 * fFull);
    this.q = new Int32Array(3 * nFull); // grid positions of the received level
    this.q.set(base.positions);
    for (let c = 0; c < 3 * base.nFaces; c++) {
      const v = this.faces[c];
      if (v >= base.nVertices) fail("base mesh: a face names a vertex that does not exist");
      this.link(v, c);
    }
    this.cs = new Int32Array(16); // corners of s, sorted
    this.nb = new Int32Array(32); // its distinct neighbours, sorted
    this.mark = new Uint8Array(16);
  }

  link(v, c) {
    this.next[c] = this.head[v];
    this.head[v] = c;
  }

  unlink(v, c) {
    let prev = -1;
    let at = this.head[v];
    while (at !== -1 && at !== c) {
      prev = at;
      at = this.next[at];
    }
    if (at === -1) return;
    if (prev === -1) this.head[v] = this.next[c];
    else this.next[prev] = this.next[c];
  }

  /** Sorted corners of s into cs, sorted distinct other vertices into nb; [nc, nn]. */
  gather(s) {
    let degree = 0;
    for (let c = this.head[s]; c !== -1; c = this.next[c]) degree++;
    if (degree > this.cs.length) {
      this.cs = new Int32Array(2 * degree);
      this.nb = new Int32Array(4 * degree);
      this.mark = new Uint8Array(2 * degree);
    }
    const { cs, nb, faces } = this;
    let nc = 0;
    for (let c = this.head[s]; c !== -1; c = this.next[c]) cs[nc++] = c;
    cs.subarray(0, nc).sort();
    let m = 0;
    for (let q = 0; q < nc; q++) {
      const f = 3 * Math.floor(cs[q] / 3);
      for (let j = 0; j < 3; j++) if (faces[f + j] !== s) nb[m++] = faces[f + j];
    }
    nb.subarray(0, m).sort();
    let nn = 0;
    for (let q = 0; q < m; q++) if (nn === 0 || nb[q] !== nb[nn - 1]) nb[nn++] = nb[q];
    return [nc, nn];
  }

  /** The predicted relabel mask into mark[0..nc): the fan of s's faces from wing xl to
   * wing xr (stream_coding._predict). */
  predict(nc, xl, xr) {
    const { cs, faces, mark } = this;
    mark.fill(0, 0, nc);
    if (nc > PREDICT_LIMIT || (xl < 0 && xr < 0)) return;
    const forward = xl >= 0;
    let y = forward ? xl : xr;
    for (let step = 0; step < nc; step++) {
      let found = -1;
      for (let q = 0; q < nc; q++) {
        if (mark[q]) continue;
        const c = cs[q];
        const f = c - (c % 3);
        const j = c % 3;
        const side = forward ? faces[f + ((j + 2) % 3)] : faces[f + ((j + 1) % 3)];
        if (side === y) {
          found = q;
          break;
        }
      }
      if (found < 0) return;
      mark[found] = 1;
      const c = cs[found];
      const f = c - (c % 3);
      const j = c % 3;
      y = forward ? faces[f + ((j + 1) % 3)] : faces[f + ((j + 2) % 3)];
      if (forward && y === xr) return;
    }
  }

  /** spread[d] = mean |Q[w] - Q[s]| along axis d over s's nn neighbours nb[0..nn)
   * (stream_coding._ring_spread): the scale of the split's edges. */
  ringSpread(s, nn, spread) {
    const { nb, q } = this;
    for (let d = 0; d < 3; d++) {
      let total = 0;
      for (let j = 0; j < nn; j++) total += Math.abs(q[3 * nb[j] + d] - q[3 * s + d]);
      spread[d] = nn ? Math.floor(total / nn) : 0;
    }
  }

  /** Sum of the grid positions of v's distinct neighbours other than `other` into
   * total; returns their number (stream_coding._ring_sum). */
  ringSum(v, other, total) {
    const { faces, nb, q } = this;
    let m = 0;
    for (let c = this.head[v]; c !== -1; c = this.next[c]) {
      const f = c - (c % 3);
      for (let j = 0; j < 3; j++) {
        const w = faces[f + j];
        if (w !== v && w !== other) nb[m++] = w;
      }
    }
    nb.subarray(0, m).sort();
    total.fill(0);
    let count = 0;
    for (let j = 0; j < m; j++) {
      if (j > 0 && nb[j] === nb[j - 1]) continue;
      count++;
      for (let d = 0; d < 3; d++) total[d] += q[3 * nb[j] + d];
    }
    return count;
  }

  /** The predicted t - s_new once the split's faces are in place: s and t each at the
   * centroid of its ring, solved for both, floored (stream_coding._span_prediction). */
  spanPrediction(s, t, prediction) {
    let need = 0;
    for (const v of [s, t]) for (let c = this.head[v]; c !== -1; c = this.next[c]) need += 2;
    if (need > this.nb.length) this.nb = new Int32Array(2 * need);
    const sumA = [0, 0, 0];
    const sumB = [0, 0, 0];
    const a = this.ringSum(t, s, sumA);
    const b = this.ringSum(s, t, sumB);
    prediction.fill(0);
    if (a === 0 || b === 0 || a > SPAN_RING_LIMIT || b > SPAN_RING_LIMIT) return;
    const den = (a + 1) * (b + 1) - 1;
    for (let d = 0; d < 3; d++) {
      const pt = Math.floor((sumA[d] * (b + 1) + sumB[d]) / den);
      const ps = Math.floor((sumB[d] * (a + 1) + sumA[d]) / den);
      prediction[d] = pt - ps;
    }
  }

  /** The first corner of face f equal to s becomes t; false if there is none. */
  relabel(f, s, t) {
    for (let j = 0; j < 3; j++) {
      const c = 3 * f + j;
      if (this.faces[c] === s) {
        this.faces[c] = t;
        this.unlink(s, c);
        this.link(t, c);
        return true;
      }
    }
    return false;
  }
}

/**
 * The mesh at any received level, in buffers allocated once for the full mesh.
 *
 * positions : Float32Array(3 * nFull), grid integers (exact in float32 below 2^24);
 *   render with origin + q * step as the object's transform.
 * indices : Uint32Array(3 * fFull), every received face at its state for `level`.
 */
export class ProgressiveLevels {
  constructor(base, nFull, fFull) {
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
    this.state = new SplitState(base, nFull, fFull); // the received level, for decoding
    this.broken = null; // why a frame was refused half-way
    this.level = this.nBase; // vertex count the buffers hold now
    // Appearance (UVs, colours, normals) when the base mesh has wedges; the stream's
    // wedge fields are ignored without.
    this.wedges = base.wedges ? new WedgeLevels(base, this) : null;
    this.texture = base.texture;
  }

  facesAt(n) {
    return this.levelFaces[n - this.nBase];
  }

  get nFaces() {
    return this.facesAt(this.level);
  }

  /** Store a decoded frame's splits (they must continue the received ones); the new faces
   * go into the index buffer as born. Does not move the level. A frame refused half-way
   * leaves the decoder state unusable: later frames are refused too. */
  addFrame(frame) {
    if (this.broken) fail(`an earlier frame was refused: ${this.broken}`);
    const { nFrom, nTo, facesFrom } = frame;
    if (nFrom !== this.received || facesFrom !== this.facesAt(this.received)) {
      fail(
        `frame refines ${nFrom} vertices / ${facesFrom} faces, the viewer holds ` +
          `${this.received} / ${this.facesAt(this.received)}`,
      );
    }
    if (nTo > this.nFull) fail(`frame goes to ${nTo} vertices, past the full ${this.nFull}`);
    this.checkGrid(frame);
    const faces = facesFrom + frame.nNewFaces;
    if (faces > this.fFull) fail(`frame brings ${faces} faces, past the full ${this.fFull}`);
    try {
      this.wedges?.beginFrame(frame.wedges);
      this.decodeSplits(frame);
      this.wedges?.endFrame();
    } catch (error) {
      this.broken = error.message;
      throw error;
    }
    this.received = nTo;
  }

  /** The frame's splits against the received level (stream_coding.decode_connectivity),
   * decoded from its range-coded bytes, stored as split vertex, deltas and relabelled
   * faces. */
  decodeSplits(frame) {
    const { nFrom } = frame;
    const k = frame.nTo - nFrom;
    const first = nFrom - this.nBase;
    const state = this.state;
    const sf = state.faces;
    const q = state.q;
    const out = this.indices;
    const coder = new RangeDecoder(frame.coded);
    const probs = newProbs(CONTEXT_SLOTS);
    const short = () => fail("split frame: the coded splits end early (truncated or corrupt data)");
    let relabel = this.relabelOffsets[first];
    let face = frame.facesFrom;
    const faceEnd = face + frame.nNewFaces;
    const prediction = [0, 0, 0];
    const spread = [0, 0, 0];
    const edge = [0, 0, 0];
    for (let i = 0; i < k; i++) {
      if (coder.broken) short();
      const t = nFrom + i;
      if (t < 1) fail(`split ${t}: names a vertex that does not exist yet`);
      const s = coder.uniform(probs, S_SLOTS, t);
      const [nc, nn] = state.gather(s);
      state.ringSpread(s, nn, spread);
      const count = coder.integer(probs, COUNT_SLOTS, false);
      if (count > faceEnd - face) fail("split frame: the splits' face counts do not add up to n_new_faces");
      let xl = -1;
      let xr = -1;
      const firstNew = face;
      let previous = 7;
      for (let j = 0; j < count; j++, face++) {
        const code = coder.tree(probs, CODE_SLOTS + 8 * previous, 3);
        previous = code;
        const f = 3 * face;
        if (code === EXPLICIT_FACE) {
          for (let c = 0; c < 3; c++) {
            const b = coder.integer(probs, BACK_SLOTS, false);
            if (b > t) fail(`split ${t}: a new face uses a vertex that does not exist`);
            sf[f + c] = t - b;
          }
          continue;
        }
        if (code > EXPLICIT_FACE) fail(`split frame: bad face code ${code}`);
        let x;
        if (coder.bit(probs, ESCAPE_SLOT)) {
          const b = coder.integer(probs, BACK_SLOTS, false);
          if (b > t) fail(`split ${t}: a new face uses a vertex that does not exist`);
          x = t - b;
        } else if (nn > 0) {
          const nIndex = Math.min(nn, ESCAPE);
          x = state.nb[coder.uniform(probs, THIRD_SLOTS + Math.min(nIndex, 16) * 8, nIndex)];
        } else {
          fail(`split ${t}: a third corner is not a neighbour of the split vertex`);
        }
        const rotation = code % 3;
        const swapped = code >= 3;
        sf[f + rotation] = swapped ? t : s;
        sf[f + ((rotation + 1) % 3)] = swapped ? s : t;
        sf[f + ((rotation + 2) % 3)] = x;
        if (!swapped && xl < 0) xl = x;
        if (swapped && xr < 0) xr = x;
      }
      out.set(sf.subarray(3 * firstNew, 3 * face), 3 * firstNew); // as born
      state.predict(nc, xl, xr);
      const mark = state.mark;
      if (nc && coder.bit(probs, MASK_SLOTS)) {
        for (let j = 0; j < nc; j++) mark[j] ^= coder.bit(probs, MASK_SLOTS + 1);
      }
      this.reserveRelabels(relabel + nc);
      for (let j = 0; j < nc; j++) {
        if (!mark[j]) continue;
        const f = Math.floor(state.cs[j] / 3);
        if (!state.relabel(f, s, t)) fail(`split ${t}: a relabelled face has no corner s`);
        this.relabelFaces[relabel++] = f;
      }
      for (let c = 3 * firstNew; c < 3 * face; c++) state.link(sf[c], c);
      this.wedges?.decodeSplit(i, s, t, state, nc, firstNew, face);
      // Positions: e = b - a = span + prediction, a + b = 2 (old + mid) + (e & 1).
      state.spanPrediction(s, t, prediction);
      for (let axis = 0; axis < 3; axis++) {
        const row = Math.min(bitLength(spread[axis]), ROWS - 1);
        edge[axis] = coder.integer(probs, SPAN_SLOTS + row * INTEGER_SLOTS, true) + prediction[axis];
      }
      for (let axis = 0; axis < 3; axis++) {
        const row = Math.min(bitLength(edge[axis]), ROWS - 1);
        const old = q[3 * s + axis];
        const m = coder.integer(probs, MID_SLOTS + row * INTEGER_SLOTS, true) + old;
        const e = edge[axis];
        const a = (2 * m + (e & 1) - e) / 2;
        q[3 * s + axis] = a;
        q[3 * t + axis] = a + e;
        this.deltas[6 * (first + i) + axis] = a - old;
        this.deltas[6 * (first + i) + 3 + axis] = a + e - old;
      }
      this.splitVertex[first + i] = s;
      this.levelFaces[first + i + 1] = face;
      this.relabelOffsets[first + i + 1] = relabel;
    }
    if (coder.broken) short();
    if (coder.position !== frame.coded.length) {
      fail("split frame: the coded splits hold bytes past the last split");
    }
    if (face !== faceEnd) fail("split frame: the splits' face counts do not add up to n_new_faces");
  }

  checkGrid(frame) {
    const { origin, step, bits } = this.grid;
    const close = (a, b) => Math.abs(a - b) <= 1e-9 * Math.max(Math.abs(a), Math.abs(b), 1e-300);
    const same =
      frame.bits === bits &&
      [0, 1, 2].every((d) => close(frame.grid[d], origin[d]) && close(frame.grid[3 + d], step[d]));
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
    while (this.level < target) this.applySplit(this.level - this.nBase);
    while (this.level > target) this.undoSplit(this.level - 1 - this.nBase);
    return this.level;
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
 * Stream the splits of `url` into `levels`: fetch + ReadableStream, frames cut as bytes
 * arrive and applied in order (the first that cannot be stops the stream).
 * onFrame(bytesSoFar) runs after each frame is stored; onBytes(bytesSoFar) after each
 * network chunk.
 */
export async function streamSplits(url, levels, { onFrame, onBytes, signal } = {}) {
  const response = await fetch(url, { signal });
  if (!response.ok) throw await problemError(response);
  const reader = response.body.getReader();
  const cutter = new FrameCutter();
  let bytes = 0;
  try {
    for (;;) {
      const { done, value } = await reader.read();
      if (done) break;
      bytes += value.length;
      onBytes?.(bytes);
      for (const payload of cutter.push(value)) {
        levels.addFrame(decodeFrame(payload));
        onFrame?.(bytes);
      }
    }
    cutter.finish();
  } catch (error) {
    reader.cancel().catch(() => {});
    throw error;
  }
  return bytes;
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

// Appearance in the browser: the wedges of a progressive mesh (UVs, colours, normals on
// the corners of each vertex), refined from the split stream as the positions are, and
// the render vertices three.js draws: one per (vertex, wedge) pair, so a UV seam keeps
// two texture coordinates on one position.
//
// Wire formats (docs/formats.md): the base mesh's `wedges` map (the wedge of each face
// corner, each wedge's values as grid integers) and a frame's wedge fields (version 3,
// range-coded in its `wedges` bytes): per split, symbols naming the wedge of each corner
// of s's fan and of the new faces, mostly 0 (predicted), and value residuals. qem_core/_kernels/wedge_coding.py is the
// reference; its module docstring states the prediction rules this file repeats.
//
// Level moves keep two states, as refine.js does for the geometry: the received level
// (what the next frame is coded against) and the level on screen, moved both ways by
// per-split records of corner and value changes.

import { bitLength, INTEGER_SLOTS, newProbs, RangeDecoder } from "./range_coder.js";
import { distinctSorted, findSorted, sortPrefix } from "./sorted.js";
import { binArray, fail, gridClose, INDEX_TYPES } from "./wire.js";

const ESCAPE = 255; // as wedge_coding.py: a wedge given as a back-distance (symbols
// 1..254 name candidates 0..253 of the corner's list)

/** A typed array of the same type holding `array` and room for at least `need` items. */
function grow(array, need) {
  if (need <= array.length) return array;
  let size = Math.max(array.length, 16);
  while (size < need) size *= 2;
  const grown = new array.constructor(size);
  grown.set(array);
  return grown;
}

/** The attribute grid of a stream (quantise.AttributeGrid.to_dict), checked. */
export function attributeGrid(value, what) {
  const ok =
    value &&
    Array.isArray(value.names) &&
    Array.isArray(value.widths) &&
    Array.isArray(value.bits) &&
    value.names.length === value.widths.length &&
    value.names.length === value.bits.length &&
    value.widths.every((w) => Number.isInteger(w) && w >= 1 && w <= 4) &&
    value.bits.every((b) => Number.isInteger(b) && b >= 1 && b <= 16);
  if (!ok) fail(`${what}: bad wedge grid`);
  const width = value.widths.reduce((a, b) => a + b, 0);
  const numbers = (list) => Array.isArray(list) && list.length === width && list.every(Number.isFinite);
  if (!width || !numbers(value.origin) || !numbers(value.step) || !value.step.every((s) => s > 0)) {
    fail(`${what}: bad wedge grid`);
  }
  const qMax = [];
  value.widths.forEach((w, a) => {
    for (let j = 0; j < w; j++) qMax.push(2 ** value.bits[a] - 1);
  });
  return { ...value, width, qMax };
}

/** Whether two checked attribute grids are the same: names, widths and bits equal,
 * origins and steps to a relative 1e-9 (qem_core.stream._same_attribute_grid). */
function sameGrid(a, b) {
  return (
    a.width === b.width &&
    a.names.length === b.names.length &&
    a.names.every(
      (name, i) => name === b.names[i] && a.widths[i] === b.widths[i] && a.bits[i] === b.bits[i],
    ) &&
    a.origin.every((o, d) => gridClose(o, b.origin[d]) && gridClose(a.step[d], b.step[d]))
  );
}

// The range-coded wedge fields (wedge_coding.code_wedge_fields): context slots, the
// same layout.
const COUNT_SLOTS = 0;
const ZERO_SLOTS = COUNT_SLOTS + 3 * INTEGER_SLOTS;
const SYMBOL_SLOTS = ZERO_SLOTS + 3;
const BACK_SLOTS = SYMBOL_SLOTS + 255;
const ROW_SLOTS = BACK_SLOTS + INTEGER_SLOTS;
const ROW_CLASSES = 8;
const COLUMN_CLASSES = 4;
// As qem_core.stream: what the wedge fields of one frame may allocate.
const FRAME_WEDGE_LIMIT = 2 ** 24;
// As stream_coding.WEDGE_WORK_LIMIT: the corners the wedge side of a frame may read (of
// the vertices of its new faces' corners); refused past twice it, or past eight times
// within the frame's first split.
const WEDGE_WORK_LIMIT = 2 ** 22;
const WEDGE_ITEMS_PER_BYTE = 2048;

/** A frame's wedge keys (null when it has none), counts bounded by the coded bytes; the
 * fields are range-decoded by WedgeLevels.beginFrame (the contexts are the stream's). */
export function decodeWedgeFields(body, k) {
  if (body.wedge_grid === undefined) return null;
  const grid = attributeGrid(body.wedge_grid, "split frame");
  for (const key of ["wedges_from", "n_wedge_symbols", "n_wedge_backs", "n_wedge_rows"]) {
    if (!Number.isInteger(body[key]) || body[key] < 0) fail(`split frame: '${key}' is ${body[key]}`);
  }
  const coded = body.wedges;
  if (!(coded instanceof Uint8Array)) fail("split frame: 'wedges' is not bytes");
  const nSymbols = body.n_wedge_symbols;
  const nBacks = body.n_wedge_backs;
  const nRows = body.n_wedge_rows;
  const items = nSymbols + nBacks + grid.width * nRows + 3 * k;
  if (items > FRAME_WEDGE_LIMIT || items > WEDGE_ITEMS_PER_BYTE * (coded.length + 1)) {
    fail(
      `split frame: the coded wedges (${coded.length} bytes) cannot hold ${nSymbols} ` +
        `symbols, ${nBacks} backs and ${nRows} value rows`,
    );
  }
  return { grid, wedgesFrom: body.wedges_from, k, nSymbols, nBacks, nRows, coded };
}

/** The contexts of the wedge fields of `width` columns, fresh. */
function newWedgeContexts(width) {
  return newProbs(ROW_SLOTS + width * ROW_CLASSES * COLUMN_CLASSES * INTEGER_SLOTS);
}

/** The wedge fields range-decoded with the contexts `probs` (updated), checked
 * (wedge_coding.decode_wedge_fields). */
function rangeDecodeWedgeFields(keys, probs) {
  const { coded, k, nSymbols, nBacks, nRows } = keys;
  const width = keys.grid.width;
  const coder = new RangeDecoder(coded);
  const short = () => fail("split frame: the coded wedges end early (truncated or corrupt data)");
  const counts = new Float64Array(3 * k); // exact up to 2^53, as the coder's integers
  for (let row = 0; row < 3; row++) {
    for (let i = 0; i < k; i++) {
      counts[row * k + i] = coder.integer(probs, COUNT_SLOTS + row * INTEGER_SLOTS, false);
    }
    if (coder.broken) short();
  }
  const symbols = new Uint8Array(nSymbols);
  let previous = 0;
  for (let q = 0; q < nSymbols; q++) {
    const kind = previous === 0 ? 0 : previous === ESCAPE ? 2 : 1;
    let symbol = 0;
    if (coder.bit(probs, ZERO_SLOTS + kind)) symbol = 1 + coder.tree(probs, SYMBOL_SLOTS, 8);
    symbols[q] = symbol;
    previous = symbol;
    if (coder.broken) short();
  }
  const backs = new Float64Array(nBacks);
  for (let q = 0; q < nBacks; q++) {
    backs[q] = coder.integer(probs, BACK_SLOTS, false);
    if (coder.broken) short();
  }
  const rows = new Float64Array(width * nRows); // column by column: rows[d * nRows + r]
  for (let r = 0; r < nRows; r++) {
    for (let d = 0; d < width; d++) {
      const above = r > 0 ? bitLength(rows[d * nRows + r - 1]) : 0;
      const left = d > 0 ? bitLength(rows[(d - 1) * nRows + r]) : 0;
      const block = (d * ROW_CLASSES + Math.min(above, ROW_CLASSES - 1)) * COLUMN_CLASSES;
      const ctx = ROW_SLOTS + (block + Math.min(left, COLUMN_CLASSES - 1)) * INTEGER_SLOTS;
      const value = coder.integer(probs, ctx, true);
      // No residual this large keeps a value on a grid of at most 16 bits (and the
      // received values are 32-bit integers): refused as code_wedges would refuse it.
      if (Math.abs(value) > 0xffff) fail("split frame: a wedge value leaves its grid");
      rows[d * nRows + r] = value;
    }
    if (coder.broken) short();
  }
  if (coder.position !== coded.length) fail("split frame: the coded wedges hold bytes past the last value");
  let rowsNeeded = 0;
  for (let i = 0; i < 2 * k; i++) rowsNeeded += counts[i];
  if (rowsNeeded > nRows) fail("split frame: more new wedges and updates than value rows");
  return { counts, symbols, backs, rows, nRows };
}

/** The base mesh's `wedges` map (msgpack_mesh.py), checked. */
export function decodeBaseWedges(entry, nFaces) {
  const grid = attributeGrid(entry?.grid, "base mesh");
  const count = entry.count;
  if (!Number.isInteger(count) || count < 0) fail("base mesh: bad wedge count");
  const Type = INDEX_TYPES[entry.corner_type];
  if (!Type) fail(`base mesh: unknown wedge corner_type '${entry.corner_type}'`);
  const corners = binArray(entry.corners, Type, 3 * nFaces, "wedges.corners");
  const values = binArray(entry.values, Uint16Array, count * grid.width, "wedges.values");
  for (const w of corners) if (w >= count) fail("base mesh: a corner names a wedge beyond the count");
  // As msgpack_mesh.read_msgpack_wedges: every value on its grid.
  for (let i = 0; i < values.length; i++) {
    if (values[i] > grid.qMax[i % grid.width]) fail("base mesh: 'wedges' values lie outside their grid");
  }
  return { grid, count, corners, values };
}

/**
 * The wedges of a ProgressiveLevels (refine.js) at the received level and at the level on
 * screen, and the render vertices of the level on screen.
 */
export class WedgeLevels {
  constructor(base, levels, { decoder = true } = {}) {
    const { grid, count } = base.wedges;
    this.levels = levels;
    this.grid = grid;
    this.width = grid.width;
    const corners = 3 * levels.fFull;
    // The received level (what frames are decoded against), unless decoded elsewhere.
    if (decoder) {
      this.received = new Int32Array(corners);
      this.received.set(base.wedges.corners);
      this.receivedValues = new Int32Array(Math.max(16, 2 * count * this.width));
      this.receivedValues.set(base.wedges.values);
    }
    this.nWedges = count;
    // The level on screen.
    this.cornerWedge = new Int32Array(corners);
    this.cornerWedge.set(base.wedges.corners);
    this.values = new Int32Array(Math.max(16, 2 * count * this.width));
    this.values.set(base.wedges.values);
    const nSplits = levels.nFull - levels.nBase;
    this.levelWedges = new Uint32Array(nSplits + 1); // wedges of level nBase + k
    this.levelWedges[0] = count;
    // Per split: corner changes (corner, from, to) and value changes (wedge, from, to).
    this.cornerOffsets = new Uint32Array(nSplits + 1);
    this.cornerChanges = new Int32Array(3 * Math.max(16, nSplits));
    this.valueOffsets = new Uint32Array(nSplits + 1);
    this.valueWedges = new Int32Array(Math.max(16, nSplits));
    this.valueChanges = new Int32Array(2 * this.width * this.valueWedges.length);
    this.nCornerChanges = 0;
    this.nValueChanges = 0;
    // Per-split buffers, grown as needed (a split allocates nothing).
    this.scratch = {
      old: new Int32Array(16), ws: new Int32Array(16), list: new Int32Array(32), reads: 0,
      mine: new Int32Array(16), listed: new Int32Array(16), mapTo: new Int32Array(16),
      stays: new Uint8Array(16), used: new Uint8Array(16), before: new Int32Array(16),
      changed: new Int32Array(16), from: new Int32Array(16),
    };
    this.frame = null;
    this.contexts = null; // the wedge fields' range coder contexts, as the last frame left them
    this.render = new RenderVertices(this, levels);
  }

  // -- decoding ----------------------------------------------------------------------------

  /** Check a frame's wedge keys against the received level, decode its fields with the
   * contexts the stream's previous frame left (fresh for a first frame); start reading
   * them. */
  beginFrame(keys, continues) {
    if (!keys) fail("split frame carries no wedges, but the base mesh has some");
    if (!sameGrid(keys.grid, this.grid)) {
      fail("the split stream's wedge grid is not the base mesh's: values would not refine");
    }
    if (keys.wedgesFrom !== this.nWedges) {
      fail(`frame refines ${keys.wedgesFrom} wedges, the viewer holds ${this.nWedges}`);
    }
    if (!continues || !this.contexts) this.contexts = newWedgeContexts(this.width);
    const fields = { ...keys, ...rangeDecodeWedgeFields(keys, this.contexts) };
    const k = fields.counts.length / 3;
    let added = 0;
    for (let i = 0; i < k; i++) added += fields.counts[i];
    const need = (this.nWedges + added) * this.width;
    this.receivedValues = grow(this.receivedValues, need);
    this.values = grow(this.values, need);
    this.frame = { ...fields, k, atSymbol: 0, atBack: 0, atRow: 0, work: 0 };
  }

  /** The wedge side of split i of the frame (split vertex s, new vertex t, nc old corners
   * of s in state.cs; new faces firstFace..face-1), once its connectivity is decoded and
   * linked into the state (wedge_coding.code_wedges, decoding). */
  decodeSplit(i, s, t, state, nc, firstFace, face) {
    const f = this.frame;
    const { faces, cs } = state;
    const cw = this.received;
    const split = t - this.levels.nBase;
    const nNew = f.counts[i];
    const nUpdates = f.counts[f.k + i];
    const nExtra = f.counts[2 * f.k + i];
    const W = this.nWedges;
    const after = W + nNew;
    const sc = this.scratch;
    const workCap = (i > 0 ? 2 : 8) * WEDGE_WORK_LIMIT;
    sc.reads = 0;
    sc.old = grow(sc.old, nc);
    sc.ws = grow(sc.ws, nc);
    const { old, ws } = sc;
    for (let q = 0; q < nc; q++) old[q] = ws[q] = cw[cs[q]];
    const nws = distinctSorted(ws, nc);
    if (f.atRow + nws + nUpdates + nNew > f.nRows) fail("split frame: a field ends before the splits do");
    const nListed = nws + nNew;
    sc.listed = grow(sc.listed, nListed);
    sc.mapTo = grow(sc.mapTo, nws);
    sc.stays = grow(sc.stays, nws);
    sc.used = grow(sc.used, nNew);
    const { listed, mapTo, stays, used } = sc; // L: ws, then the new wedges
    for (let q = 0; q < nws; q++) {
      listed[q] = ws[q];
      mapTo[q] = -1;
      stays[q] = 0;
    }
    for (let j = 0; j < nNew; j++) {
      listed[nws + j] = W + j;
      used[j] = 0;
    }
    for (let q = 0; q < nc; q++) if (faces[cs[q]] === s) stays[findSorted(ws, nws, old[q])] = 1;
    let fresh = 0;
    const nCoded = nc + 3 * (face - firstFace);
    // As code_wedges: the split's symbols are there before any is read.
    if (f.atSymbol + nCoded > f.symbols.length) fail("split frame: a field ends before the splits do");
    for (let z = 0; z < nCoded; z++) {
      const c = z < nc ? cs[z] : 3 * firstFace + z - nc;
      const v = faces[c];
      let list = listed;
      let nList = nListed;
      let nMine = -1; // v's corners below c, in sc.mine, once listed
      if (v !== s && v !== t) {
        nMine = sortedCorners(state, v, c, sc);
        sc.list = grow(sc.list, nMine);
        for (let q = 0; q < nMine; q++) sc.list[q] = cw[sc.mine[q]];
        list = sc.list;
        nList = distinctSorted(list, nMine);
      }
      let predicted;
      let slot = -1;
      if (z < nc) {
        slot = findSorted(ws, nws, old[z]);
        if (v === s) predicted = old[z];
        else if (mapTo[slot] >= 0) predicted = mapTo[slot];
        else if (stays[slot] && fresh < nNew) predicted = W + fresh;
        else predicted = old[z];
      } else {
        predicted = predictNewCorner(state, cw, c, s, t, old, nc, sc, nMine);
        if (predicted < 0 && (v === s || v === t) && nListed > 0) {
          predicted = fresh < nNew ? W + fresh : listed[0];
        }
      }
      f.work += sc.reads;
      sc.reads = 0;
      if (f.work > workCap) {
        fail(
          `split frame: the wedges of its new faces read more than ${2 * WEDGE_WORK_LIMIT} ` +
            `corners (${8 * WEDGE_WORK_LIMIT} in its first split)`,
        );
      }
      const symbol = f.symbols[f.atSymbol++];
      let wedge = -1;
      if (symbol === 0) wedge = predicted;
      else if (symbol === ESCAPE) {
        if (f.atBack >= f.backs.length) fail("split frame: a field ends before the splits do");
        wedge = after - f.backs[f.atBack++];
      } else if (symbol - 1 < nList) wedge = list[symbol - 1];
      if (!(wedge >= 0 && wedge < after)) {
        fail("split frame: a corner or update names a wedge that does not exist");
      }
      if (z < nc) {
        if (wedge !== cw[c]) this.pushCornerChange(c, cw[c], wedge);
      } else {
        this.cornerWedge[c] = wedge; // a new face, as born (like refine.js's indices)
      }
      cw[c] = wedge;
      if (z < nc && v === t && mapTo[slot] < 0) {
        mapTo[slot] = wedge;
        if (wedge >= W && wedge < after) {
          used[wedge - W] = 1;
          while (fresh < nNew && used[fresh]) fresh++;
        }
      }
    }
    for (let e = 0; e < nExtra; e++) {
      if (f.atBack + 2 > f.backs.length) fail("split frame: a field ends before the splits do");
      const c = 3 * face - f.backs[f.atBack];
      const wedge = after - f.backs[f.atBack + 1];
      f.atBack += 2;
      if (!(c >= 0 && c < 3 * face)) fail("split frame: a wedge relabel names a corner that does not exist");
      if (!(wedge >= 0 && wedge < after)) {
        fail("split frame: a corner or update names a wedge that does not exist");
      }
      this.pushCornerChange(c, cw[c], wedge);
      cw[c] = wedge;
    }
    this.decodeValues(split, ws, nws, nUpdates, nNew, mapTo);
    this.levelWedges[split + 1] = after;
    this.cornerOffsets[split + 1] = this.nCornerChanges;
    this.valueOffsets[split + 1] = this.nValueChanges;
  }

  /** The value rows of one split: ws, extra updates, new wedges (code_wedges). Each
   * value is checked as it is written, as code_wedges does: both refuse the same
   * frames, and no sum leaves the 32-bit range. */
  decodeValues(split, ws, nws, nUpdates, nNew, mapTo) {
    const f = this.frame;
    const width = this.width;
    const values = this.receivedValues;
    const W = this.nWedges;
    const qMax = this.grid.qMax;
    const { rows, nRows, atRow } = f;
    const sc = this.scratch;
    // The rows' values before (ws's), and the wedges changed with their old values.
    sc.before = grow(sc.before, nws * width);
    sc.changed = grow(sc.changed, nws + nUpdates);
    sc.from = grow(sc.from, (nws + nUpdates) * width);
    const { before, changed, from } = sc;
    let nChanged = 0;
    for (let q = 0; q < nws; q++) {
      for (let d = 0; d < width; d++) before[q * width + d] = values[ws[q] * width + d];
    }
    if (f.atBack + nUpdates > f.backs.length) fail("split frame: a field ends before the splits do");
    for (let q = 0; q < nws; q++) {
      let same = true;
      for (let d = 0; d < width; d++) {
        const value = onGrid(before[q * width + d] + rows[d * nRows + atRow + q], qMax[d]);
        if (value !== before[q * width + d]) same = false;
        values[ws[q] * width + d] = value;
      }
      if (same) continue;
      for (let d = 0; d < width; d++) from[nChanged * width + d] = before[q * width + d];
      changed[nChanged++] = ws[q];
    }
    for (let e = 0; e < nUpdates; e++) {
      const wedge = W - f.backs[f.atBack + e];
      if (!(wedge >= 0 && wedge < W)) fail("split frame: a corner or update names a wedge that does not exist");
      for (let d = 0; d < width; d++) {
        const old = values[wedge * width + d];
        from[nChanged * width + d] = old;
        values[wedge * width + d] = onGrid(old + rows[d * nRows + atRow + nws + e], qMax[d]);
      }
      changed[nChanged++] = wedge;
    }
    f.atBack += nUpdates;
    for (let j = 0; j < nNew; j++) {
      let parent = -1;
      for (let q = 0; q < nws && parent < 0; q++) if (mapTo[q] === W + j) parent = q;
      if (parent < 0 && nws > 0) parent = 0;
      for (let d = 0; d < width; d++) {
        const predicted = parent >= 0 ? before[parent * width + d] : 0;
        const value = onGrid(predicted + rows[d * nRows + atRow + nws + nUpdates + j], qMax[d]);
        values[(W + j) * width + d] = value;
        this.values[(W + j) * width + d] = value; // unused below its split: set at once
      }
    }
    for (let q = 0; q < nChanged; q++) this.pushValueChange(changed[q], from, q * width, values);
    f.atRow += nws + nUpdates + nNew;
    this.nWedges = W + nNew;
  }

  /** Every field consumed exactly, as the frame ends. */
  endFrame() {
    const f = this.frame;
    if (f.atSymbol !== f.symbols.length || f.atBack !== f.backs.length || f.atRow !== f.nRows) {
      fail("split frame: a field holds more than the splits use");
    }
    this.frame = null;
  }

  pushCornerChange(corner, from, to) {
    const n = this.nCornerChanges++;
    this.cornerChanges = grow(this.cornerChanges, 3 * (n + 1));
    this.cornerChanges[3 * n] = corner;
    this.cornerChanges[3 * n + 1] = from;
    this.cornerChanges[3 * n + 2] = to;
  }

  /** Wedge `wedge` changed from from[at..at + width) to its values in `values`. */
  pushValueChange(wedge, from, at, values) {
    const n = this.nValueChanges;
    const width = this.width;
    this.valueWedges = grow(this.valueWedges, n + 1);
    this.valueChanges = grow(this.valueChanges, 2 * width * (n + 1));
    this.valueWedges[n] = wedge;
    const changes = this.valueChanges;
    for (let d = 0; d < width; d++) {
      changes[2 * width * n + d] = from[at + d];
      changes[2 * width * n + width + d] = values[wedge * width + d];
    }
    this.nValueChanges = n + 1;
  }

  // -- records (ProgressiveLevels.recordOf, addRecord) -----------------------------------

  /** Copies of what splits a..b (split numbers) added, their new faces' corner wedges
   * (faces firstFace..lastFace) and new wedges' values as born. */
  recordOf(a, b, firstFace, lastFace) {
    const width = this.width;
    const [c0, c1] = [this.cornerOffsets[a], this.cornerOffsets[b]];
    const [v0, v1] = [this.valueOffsets[a], this.valueOffsets[b]];
    return {
      levelWedges: this.levelWedges.slice(a + 1, b + 1),
      cornerOffsets: this.cornerOffsets.slice(a + 1, b + 1),
      cornerChanges: this.cornerChanges.slice(3 * c0, 3 * c1),
      valueOffsets: this.valueOffsets.slice(a + 1, b + 1),
      valueWedges: this.valueWedges.slice(v0, v1),
      valueChanges: this.valueChanges.slice(2 * width * v0, 2 * width * v1),
      corners: this.cornerWedge.slice(3 * firstFace, 3 * lastFace),
      values: this.values.slice(width * this.levelWedges[a], width * this.levelWedges[b]),
    };
  }

  /** Hold a record's wedge side (splits a..b, new faces from firstFace). */
  addRecord(record, a, b, firstFace) {
    const width = this.width;
    this.levelWedges.set(record.levelWedges, a + 1);
    this.cornerOffsets.set(record.cornerOffsets, a + 1);
    this.valueOffsets.set(record.valueOffsets, a + 1);
    const [c0, c1] = [this.cornerOffsets[a], this.cornerOffsets[b]];
    const [v0, v1] = [this.valueOffsets[a], this.valueOffsets[b]];
    this.cornerChanges = grow(this.cornerChanges, 3 * c1);
    this.cornerChanges.set(record.cornerChanges, 3 * c0);
    this.valueWedges = grow(this.valueWedges, v1);
    this.valueWedges.set(record.valueWedges, v0);
    this.valueChanges = grow(this.valueChanges, 2 * width * v1);
    this.valueChanges.set(record.valueChanges, 2 * width * v0);
    this.nCornerChanges = c1;
    this.nValueChanges = v1;
    this.cornerWedge.set(record.corners, 3 * firstFace);
    this.values = grow(this.values, width * this.levelWedges[b]);
    this.values.set(record.values, width * this.levelWedges[a]);
    this.nWedges = this.levelWedges[b];
  }

  // -- level moves ---------------------------------------------------------------------

  /** Split k's wedge side on the level on screen, after its geometry (refine.js). */
  applySplit(k, s, t) {
    this.changeValues(k, 1);
    const changes = this.cornerChanges;
    for (let r = this.cornerOffsets[k]; r < this.cornerOffsets[k + 1]; r++) {
      this.cornerWedge[changes[3 * r]] = changes[3 * r + 2];
    }
    this.render.afterSplit(k, s, t, true);
  }

  /** Undo split k's wedge side, after its geometry is undone. */
  undoSplit(k, s, t) {
    const changes = this.cornerChanges;
    for (let r = this.cornerOffsets[k + 1] - 1; r >= this.cornerOffsets[k]; r--) {
      this.cornerWedge[changes[3 * r]] = changes[3 * r + 1];
    }
    this.changeValues(k, -1);
    this.render.afterSplit(k, s, t, false);
  }

  /** Value changes of split k forwards (1: to) or backwards (-1: from, last first). */
  changeValues(k, direction) {
    const width = this.width;
    const first = this.valueOffsets[k];
    const last = this.valueOffsets[k + 1];
    for (let n = 0; n < last - first; n++) {
      const r = direction > 0 ? first + n : last - 1 - n;
      const wedge = this.valueWedges[r];
      const at = 2 * width * r + (direction > 0 ? width : 0);
      for (let d = 0; d < width; d++) this.values[wedge * width + d] = this.valueChanges[at + d];
      this.render.wedgeChanged(wedge);
    }
  }

  wedgesAt(n) {
    return this.levelWedges[n - this.levels.nBase];
  }
}

/** A wedge value checked as code_wedges checks it: on its grid, [0, qMax]. */
function onGrid(value, qMax) {
  if (!(value >= 0 && value <= qMax)) fail("split frame: a wedge value leaves its grid");
  return value;
}

/** v's corners numbered below `below`, ascending, into sc.mine; their count. Adds the
 * corners it reads, all v's, to sc.reads (the frame's wedge work). */
function sortedCorners(state, v, below, sc) {
  const count = state.cornersOf(v);
  const { list, listAt } = state;
  sc.mine = grow(sc.mine, count);
  let n = 0;
  for (let i = 0; i < count; i++) if (list[listAt + i] < below) sc.mine[n++] = list[listAt + i];
  sortPrefix(sc.mine, n);
  sc.reads += count;
  return n;
}

/** 2 if the face at `f` (3 * face) holds a preferred vertex, 1 if it holds u or w. */
function faceScore(faces, f, u, w, preferredA, preferredB) {
  let score = 0;
  for (let j = 0; j < 3; j++) {
    const x = faces[f + j];
    if (x === preferredA || x === preferredB) return 2;
    if (x === u || x === w) score = 1;
  }
  return score;
}

/** wedge_coding._predict_new_corner: the predicted wedge of corner c of a new face.
 * nMine >= 0: v's corners below c are in sc.mine already (they are read again, as the
 * frame's wedge work counts them, but not listed again). */
function predictNewCorner(state, cw, c, s, t, old, nc, sc, nMine) {
  const faces = state.faces;
  const f = c - (c % 3);
  const j = c % 3;
  const v = faces[c];
  const u = faces[f + ((j + 1) % 3)];
  const w = faces[f + ((j + 2) % 3)];
  let preferredA = t;
  let preferredB = -1;
  if (v === s || v === t) {
    preferredA = u !== s && u !== t ? u : -1;
    preferredB = w !== s && w !== t ? w : -1;
  }
  let best = 0;
  let predicted = -1;
  let first = -1;
  if (v === s) {
    for (let q = 0; q < nc; q++) {
      const corner = state.cs[q];
      if (faces[corner] !== t) continue;
      if (first < 0) first = old[q];
      const score = faceScore(faces, corner - (corner % 3), u, w, preferredA, preferredB);
      if (score > best) {
        best = score;
        predicted = old[q];
      }
    }
  }
  if (nMine >= 0) sc.reads += state.cornersOf(v);
  else nMine = sortedCorners(state, v, c, sc);
  for (let q = 0; q < nMine; q++) {
    const corner = sc.mine[q];
    if (first < 0) first = cw[corner];
    const score = faceScore(faces, corner - (corner % 3), u, w, preferredA, preferredB);
    if (score > best) {
      best = score;
      predicted = cw[corner];
    }
  }
  return predicted >= 0 ? predicted : first;
}

/**
 * The vertices three.js draws for a mesh with wedges: one per (vertex, wedge) pair met
 * so far, kept for good (a level move only changes which ones the faces use), each with
 * the grid position of its vertex and the values of its wedge. `indices` holds every
 * face corner's render vertex for the level on screen.
 */
class RenderVertices {
  constructor(wedges, levels) {
    this.wedges = wedges;
    this.levels = levels;
    this.indices = new Uint32Array(3 * levels.fFull);
    this.ofVertex = new Int32Array(levels.nFull).fill(-1); // first pair of each vertex
    this.ofWedge = new Int32Array(16).fill(-1); // first pair of each wedge (grows)
    this.capacity = 0;
    this.count = 0;
    this.generation = 0; // bumped when the buffers are reallocated
    this.reserve(Math.max(64, levels.nBase * 2));
    const nCorners = 3 * levels.facesAt(levels.nBase);
    for (let c = 0; c < nCorners; c++) this.refresh(c);
  }

  reserve(need) {
    if (need <= this.capacity) return;
    let size = Math.max(this.capacity, 64);
    while (size < need) size *= 2;
    const resize = (array, perItem, fill = 0) => {
      const grown = new array.constructor(size * perItem).fill(fill);
      grown.set(array.subarray(0, this.count * perItem));
      return grown;
    };
    this.vertex = resize(this.vertex ?? new Int32Array(0), 1);
    this.wedge = resize(this.wedge ?? new Int32Array(0), 1);
    this.nextOfVertex = resize(this.nextOfVertex ?? new Int32Array(0), 1, -1);
    this.nextOfWedge = resize(this.nextOfWedge ?? new Int32Array(0), 1, -1);
    this.positions = resize(this.positions ?? new Float32Array(0), 3);
    this.attributes = {};
    let column = 0;
    const grid = this.wedges.grid;
    grid.names.forEach((name, a) => {
      const width = grid.widths[a];
      const old = this.attributeArrays?.[name] ?? new Float32Array(0);
      this.attributes[name] = { array: resize(old, width), width, column };
      column += width;
    });
    this.attributeList = Object.values(this.attributes); // writeValues's, without a copy a call
    if ("color" in this.attributes) this.linear ??= linearColours(grid, this.attributes.color.column);
    this.attributeArrays = Object.fromEntries(
      Object.entries(this.attributes).map(([name, entry]) => [name, entry.array]),
    );
    this.capacity = size;
    this.generation++;
  }

  /** The render vertex of (v, w), made when first met. */
  pair(v, w) {
    for (let p = this.ofVertex[v]; p !== -1; p = this.nextOfVertex[p]) {
      if (this.wedge[p] === w) return p;
    }
    this.reserve(this.count + 1);
    const p = this.count++;
    this.vertex[p] = v;
    this.wedge[p] = w;
    this.nextOfVertex[p] = this.ofVertex[v];
    this.ofVertex[v] = p;
    if (w >= this.ofWedge.length) {
      const grown = new Int32Array(Math.max(2 * this.ofWedge.length, w + 1)).fill(-1);
      grown.set(this.ofWedge);
      this.ofWedge = grown;
    }
    this.nextOfWedge[p] = this.ofWedge[w];
    this.ofWedge[w] = p;
    this.writePosition(p);
    this.writeValues(p);
    return p;
  }

  refresh(c) {
    this.indices[c] = this.pair(this.levels.indices[c], this.wedges.cornerWedge[c]);
  }

  writePosition(p) {
    const q = this.levels.positions;
    const v = this.vertex[p];
    for (let d = 0; d < 3; d++) this.positions[3 * p + d] = q[3 * v + d];
  }

  writeValues(p) {
    const { grid, values, width } = this.wedges;
    const w = this.wedge[p];
    const colour = this.attributes.color?.column ?? -1;
    for (const { array, width: n, column } of this.attributeList) {
      for (let d = 0; d < n; d++) {
        const col = column + d;
        const q = values[w * width + col];
        // three.js shades in linear light; files give colours in sRGB (not alpha).
        array[n * p + d] = column === colour && d < 3 ? this.linear[d](q) : grid.origin[col] + q * grid.step[col];
      }
    }
  }

  vertexMoved(v) {
    for (let p = this.ofVertex[v]; p !== -1; p = this.nextOfVertex[p]) this.writePosition(p);
  }

  wedgeChanged(w) {
    if (w >= this.ofWedge.length) return;
    for (let p = this.ofWedge[w]; p !== -1; p = this.nextOfWedge[p]) this.writeValues(p);
  }

  /** After split k was applied (or undone): positions of s and t, and the render vertex
   * of every corner the split touched. */
  afterSplit(k, s, t, applied) {
    const levels = this.levels;
    this.vertexMoved(s);
    if (applied) this.vertexMoved(t);
    for (let r = levels.relabelOffsets[k]; r < levels.relabelOffsets[k + 1]; r++) {
      const f = 3 * levels.relabelFaces[r];
      for (let j = 0; j < 3; j++) this.refresh(f + j);
    }
    const changes = this.wedges.cornerChanges;
    for (let r = this.wedges.cornerOffsets[k]; r < this.wedges.cornerOffsets[k + 1]; r++) {
      this.refresh(changes[3 * r]);
    }
    if (applied) {
      for (let c = 3 * levels.levelFaces[k]; c < 3 * levels.levelFaces[k + 1]; c++) this.refresh(c);
    }
  }
}

function srgbToLinear(c) {
  return c <= 0.04045 ? c / 12.92 : ((c + 0.055) / 1.055) ** 2.4;
}

/** For each of the colour's three sRGB columns (from `column` of the wedge grid), the
 * linear value of each grid integer, computed when first asked for (NaN until then):
 * a table rather than a power a vertex. */
function linearColours(grid, column) {
  return [0, 1, 2].map((d) => {
    const col = column + d;
    const table = new Float32Array(grid.qMax[col] + 1).fill(Number.NaN);
    return (q) => {
      let value = table[q];
      if (value !== value) value = table[q] = srgbToLinear(grid.origin[col] + q * grid.step[col]);
      return value;
    };
  });
}

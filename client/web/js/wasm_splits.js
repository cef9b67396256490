// The split decoder compiled to WebAssembly (client/web/wasm/refine.c, built into
// refine.wasm beside this file by client/build_wasm.py): the same integers as refine.js's
// SplitState and decodeSplits, in about half the time. ProgressiveLevels uses it when it is
// given the compiled module. A mesh's wedge keys (appearance attributes) are decoded by
// wedges.js still: the module calls out to it at each split (`onWedgeSplit`), and it reads
// the module's state through `stateView` as it reads a SplitState.
//
//   const module = await loadSplitModule();          // null where it cannot be had
//   new ProgressiveLevels(base, nFull, fFull, { wasm: module });

import { fail, SPLITS_REFUSED } from "./wire.js";

/** The compiled decoder, or null (no WebAssembly, or refine.wasm not served): the
 * levels then decode in JavaScript. `url` defaults to refine.wasm beside this module. */
export async function loadSplitModule(url = new URL("./refine.wasm", import.meta.url)) {
  if (typeof WebAssembly === "undefined") return null;
  try {
    const response = await fetch(url);
    if (!response.ok) return null;
    return await WebAssembly.compile(await response.arrayBuffer());
  } catch {
    return null;
  }
}

// refine.c's error codes (its enum, in order): the refusals they stand for.
const REFUSALS = [null, "short", "notYet", "work", "counts", "noVertex", "faceCode", "third",
  "relabel", "grid", "trailing", "memory", "baseVertex"];
const OUT_OF_MEMORY = REFUSALS.indexOf("memory");

/**
 * The decoding state of ProgressiveLevels in WebAssembly memory: the received level's
 * faces and each vertex's block of corners and grid position, laid out as SplitState's
 * (`faces`, `fan`), so ProgressiveLevels reads the level it holds from them the same way.
 */
export class WasmSplits {
  /** `cornersOf`: SplitState's, which stateView() uses to find a vertex's list. */
  constructor(module, base, nFull, fFull, { cornersOf } = {}) {
    // Each split of a mesh with wedges: onWedgeSplit(i, s, t, nc, firstFace, face), as
    // refine.js calls WedgeLevels.decodeSplit (ProgressiveLevels sets it).
    this.onWedgeSplit = null;
    const wedgeSplit = (i, s, t, nc, firstFace, face) => this.onWedgeSplit(i, s, t, nc, firstFace, face);
    this.exports = new WebAssembly.Instance(module, { env: { wedge_split: wedgeSplit } }).exports;
    this.nBase = base.nVertices;
    this.nFull = nFull;
    this.fFull = fFull;
    this.view = { buffer: null, cornersOf };
    const w = this.exports;
    if (!w.qem_init(base.nVertices, nFull, fFull, base.nFaces, base.bits, base.wedges ? 1 : 0)) {
      fail("the split decoder has no room for this mesh (WebAssembly memory)");
    }
    this.ints(w.qem_base_positions(), 3 * base.nVertices).set(base.positions);
    this.ints(w.qem_base_faces(), 3 * base.nFaces).set(base.indices);
    this.check(w.qem_link_base());
  }

  /** An Int32Array over the module's memory (made anew: memory growth detaches views). */
  ints(at, length) {
    return new Int32Array(this.exports.memory.buffer, at, length);
  }

  check(code) {
    if (code === 0) return;
    const w = this.exports;
    const refusal = SPLITS_REFUSED[REFUSALS[code]];
    fail(refusal ? refusal(w.qem_error_split(), w.qem_error_value()) : `split decoder error ${code}`);
  }

  /** The received level's faces, as SplitState.faces. */
  get faces() {
    return this.ints(this.exports.qem_faces(), 3 * this.fFull);
  }

  /** Each vertex's block (count, spill offset, grid position, stamp, corners), as
   * SplitState.fan. */
  get fan() {
    return this.ints(this.exports.qem_fan(), this.exports.qem_fan_ints());
  }

  /** The arrays a SplitState holds, as views of the module's memory (`faces`, `fan`,
   * `spill`, and `cs`, the sorted corners of the split being decoded), made anew only
   * when the memory grew or a buffer moved, with SplitState's `cornersOf`: the object
   * WedgeLevels.decodeSplit reads as a SplitState. */
  stateView() {
    const w = this.exports;
    const view = this.view;
    const buffer = w.memory.buffer;
    const cs = w.qem_cs();
    const spill = w.qem_spill();
    if (view.buffer === buffer && view.csAt === cs && view.spillAt === spill) return view;
    Object.assign(view, { buffer, csAt: cs, spillAt: spill });
    view.faces = this.faces;
    view.fan = this.fan;
    view.spill = this.ints(spill, w.qem_spill_ints());
    view.cs = this.ints(cs, w.qem_cs_ints());
    return view;
  }

  /** Decode `frame` (decodeFrame's result, checked by ProgressiveLevels.addFrame) and
   * store its splits in `levels` as ProgressiveLevels.decodeSplits does. */
  decodeSplits(frame, levels) {
    const w = this.exports;
    const { nFrom, nTo, coded } = frame;
    const at = w.qem_coded(coded.length);
    if (at === 0 && coded.length > 0) this.check(OUT_OF_MEMORY);
    new Uint8Array(w.memory.buffer, at, coded.length).set(coded);
    this.check(w.qem_decode(at, coded.length, nFrom, nTo - nFrom, frame.facesFrom, frame.nNewFaces, frame.continues ? 0 : 1));
    const a = nFrom - this.nBase;
    const b = nTo - this.nBase;
    const levelFaces = this.ints(w.qem_level_faces(), b + 1);
    const relabelOffsets = this.ints(w.qem_relabel_offsets(), b + 1);
    levels.splitVertex.set(this.ints(w.qem_split_vertex() + 4 * a, b - a), a);
    levels.deltas.set(this.ints(w.qem_deltas() + 24 * a, 6 * (b - a)), 6 * a);
    levels.levelFaces.set(levelFaces.subarray(a + 1, b + 1), a + 1);
    levels.relabelOffsets.set(relabelOffsets.subarray(a + 1, b + 1), a + 1);
    levels.reserveRelabels(relabelOffsets[b]);
    const relabels = this.ints(w.qem_relabel_faces() + 4 * relabelOffsets[a], relabelOffsets[b] - relabelOffsets[a]);
    levels.relabelFaces.set(relabels, relabelOffsets[a]);
    const first = levelFaces[a];
    levels.indices.set(this.ints(w.qem_out_faces() + 12 * first, 3 * (levelFaces[b] - first)), 3 * first);
  }
}

// The page's side of decoder_worker.js: frames go to the worker, records of their splits
// come back and are added to the page's levels (a ProgressiveLevels without a decoder).
//
//   const decoding = new WorkerDecoder();        // the worker loads its modules meanwhile
//   decoding.start(levels, baseBytes, { onRecord, wasm });
//   decoding.addFrame(decodeFrame(payload));   // checked here (CRC-32, header), decoded there
//   await decoding.finish();                   // every frame answered; rejects on a refusal
//
// A refused frame rejects finish() with the worker's error (its name and message kept)
// and makes every later addFrame throw it, so the download stops at once.

import { WireFormatError } from "./wire.js";

export class WorkerDecoder {
  /** The worker, started at once: a module worker fetches and compiles its scripts
   * before it can decode (about 0.1 s in a browser), which then overlaps the fetch of
   * the mesh's base. */
  constructor() {
    this.levels = null;
    this.onRecord = null;
    this.decoder = null; // "wasm" or "js" once the worker has started
    this.pending = 0; // frames sent and not answered
    this.error = null;
    this.waiting = []; // finish() callers: [resolve, reject]
    this.worker = new Worker(new URL("./decoder_worker.js", import.meta.url), { type: "module" });
    this.worker.onmessage = ({ data }) => this.answer(data);
    this.worker.onerror = (event) => {
      event.preventDefault?.();
      this.fault(new Error(`the decoder's worker failed: ${event.message ?? "it could not start"}`));
    };
  }

  /** Give the worker the mesh: `levels` (the page's, which the records are added to) at
   * the base level `baseBytes` (its msgpack) holds. `wasm`: the compiled split decoder
   * (wasm_splits.js's loadSplitModule), or null for refine.js's. */
  start(levels, baseBytes, { onRecord, wasm = null } = {}) {
    if (this.levels) throw new Error("the decoder's worker has a mesh already");
    this.levels = levels;
    this.onRecord = onRecord;
    this.worker.postMessage({ type: "start", base: baseBytes, nFull: levels.nFull, fFull: levels.fFull, wasm });
  }

  /** Send a frame (decodeFrame's result) to be decoded; throws the first refusal. */
  addFrame(frame) {
    if (this.error) throw this.error;
    if (!this.levels) throw new Error("the decoder's worker has no mesh yet (start first)");
    // Own copies of the coded bytes (a view's whole buffer would be cloned), handed over.
    const coded = frame.coded.slice();
    const wedges = frame.wedges && { ...frame.wedges, coded: frame.wedges.coded.slice() };
    const buffers = [coded.buffer, ...(wedges ? [wedges.coded.buffer] : [])];
    this.pending++;
    this.worker.postMessage({ type: "frame", frame: { ...frame, coded, wedges } }, buffers);
  }

  answer(data) {
    if (this.error) return;
    if (data.type === "started") {
      this.decoder = data.decoder;
      return;
    }
    if (data.type === "error") {
      const error = data.name === "WireFormatError" ? new WireFormatError(data.message) : new Error(data.message);
      this.fault(error);
      return;
    }
    this.pending--;
    try {
      if (data.record) this.levels.addRecord(data.record);
      this.onRecord?.(data.record);
    } catch (error) {
      this.fault(error);
      return;
    }
    if (this.pending === 0) this.settle();
  }

  fault(error) {
    if (this.error) return;
    this.error = error;
    this.worker.terminate();
    this.settle();
  }

  settle() {
    const waiting = this.waiting;
    this.waiting = [];
    for (const [resolve, reject] of waiting) {
      if (this.error) reject(this.error);
      else resolve();
    }
  }

  /** Resolves when every frame sent is decoded and held; rejects with the first refusal. */
  finish() {
    if (this.error) return Promise.reject(this.error);
    if (this.pending === 0) return Promise.resolve();
    return new Promise((resolve, reject) => this.waiting.push([resolve, reject]));
  }

  /** Stop the worker (a new mesh chosen, or the stream done). */
  close() {
    this.worker.terminate();
  }
}

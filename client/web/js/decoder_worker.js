// The split decoder off the page's main thread (a module Web Worker started by
// worker_decoder.js). It holds levels that decode (refine.js's ProgressiveLevels at its
// base level, never moved) and answers each frame with the record of its splits, every
// array transferred; the page holds levels without a decoder and adds the records. So
// the range decoding and the connectivity walks, seconds for a big mesh, never block
// rendering or input.
//
// Messages in:  {type: "start", base: Uint8Array (the base mesh's msgpack), nFull, fFull,
//                wasm: the compiled split decoder (wasm_splits.js) or null}
//               {type: "frame", frame: decodeFrame's result}
// Messages out: {type: "started", decoder: "wasm" or "js" (ProgressiveLevels.decoder)}
//               {type: "record", record: recordOf(...) or null (a frame held already)}
//               {type: "error", name, message}: the first refused frame; later frames
//               are refused too (the decoding state is gone).

import { decodeBaseMesh, ProgressiveLevels } from "./refine.js";

let levels = null;

function transfers(record) {
  const buffers = [];
  for (const value of Object.values(record)) {
    if (ArrayBuffer.isView(value)) buffers.push(value.buffer);
    else if (value && typeof value === "object") buffers.push(...transfers(value));
  }
  return buffers;
}

self.onmessage = ({ data }) => {
  try {
    if (data.type === "start") {
      const base = decodeBaseMesh(data.base);
      levels = new ProgressiveLevels(base, data.nFull, data.fFull, { wasm: data.wasm ?? null });
      self.postMessage({ type: "started", decoder: levels.decoder });
      return;
    }
    if (data.type !== "frame") throw new Error(`decoder worker: unknown message '${data.type}'`);
    if (!levels) throw new Error("decoder worker: a frame came before the base mesh");
    const before = levels.received;
    levels.addFrame(data.frame);
    const record = levels.received > before ? levels.recordOf(before, levels.received) : null;
    self.postMessage({ type: "record", record }, record ? transfers(record) : []);
  } catch (error) {
    self.postMessage({ type: "error", name: error.name, message: error.message });
  }
};

// The viewer's decoder (client/web/js/refine.js) on a case directory of the node
// benchmarks: base.msgpack, stream.qsplits and plan.json ({vertices, faces}).
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";

/** A function turning the case's base mesh plus its whole split stream into the full
 * level (the buffers a renderer reads); it returns { ms, vertices, faces, decoder }.
 * `wasm`: the frames decoded by the WebAssembly split decoder (js/refine.wasm), as the
 * viewer's worker decodes them. */
export async function loadRefineCase(web, dir, { wasm = false } = {}) {
  const { FrameCutter, ProgressiveLevels, decodeBaseMesh, decodeFrame } = await import(
    pathToFileURL(`${web}/js/refine.js`).href
  );
  const plan = JSON.parse(readFileSync(`${dir}/plan.json`, "utf8"));
  const baseBytes = readFileSync(`${dir}/base.msgpack`);
  const stream = readFileSync(`${dir}/stream.qsplits`);
  const module = wasm ? new WebAssembly.Module(readFileSync(`${web}/js/refine.wasm`)) : null;
  return function decodeProgressive() {
    const start = performance.now();
    const base = decodeBaseMesh(baseBytes);
    const levels = new ProgressiveLevels(base, plan.vertices, plan.faces, { wasm: module });
    const cutter = new FrameCutter();
    for (const payload of cutter.push(stream)) levels.addFrame(decodeFrame(payload));
    cutter.finish();
    levels.setLevel(plan.vertices);
    const ms = performance.now() - start;
    return { ms, vertices: levels.level, faces: levels.nFaces, decoder: levels.decoder };
  };
}

// The viewer's decoder (client/web/js/refine.js) on a case directory of the node
// benchmarks: base.msgpack, stream.qsplits and plan.json ({vertices, faces}).
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";

/** A function turning the case's base mesh plus its whole split stream into the full
 * level (the buffers a renderer reads); it returns { ms, vertices, faces }. */
export async function loadRefineCase(web, dir) {
  const { FrameCutter, ProgressiveLevels, decodeBaseMesh, decodeFrame } = await import(
    pathToFileURL(`${web}/js/refine.js`).href
  );
  const plan = JSON.parse(readFileSync(`${dir}/plan.json`, "utf8"));
  const baseBytes = readFileSync(`${dir}/base.msgpack`);
  const stream = readFileSync(`${dir}/stream.qsplits`);
  return function decodeProgressive() {
    const start = performance.now();
    const levels = new ProgressiveLevels(decodeBaseMesh(baseBytes), plan.vertices, plan.faces);
    const cutter = new FrameCutter();
    for (const payload of cutter.push(stream)) levels.addFrame(decodeFrame(payload));
    cutter.finish();
    levels.setLevel(plan.vertices);
    return { ms: performance.now() - start, vertices: levels.level, faces: levels.nFaces };
  };
}

// Times, in one node process, the viewer's decoder (client/web/js/refine.js) turning a
// base mesh plus its whole split stream into the full mesh, and Draco's WebAssembly
// decoder (three.js's copy, as DRACOLoader runs it) decoding the same mesh, alternating.
//
//   node decoder_speed.mjs WEB_DIR CASE_DIR RUNS
//
// CASE_DIR holds base.msgpack, stream.qsplits, mesh.drc and plan.json ({vertices,
// faces}); prints one JSON line: each decoder's times in milliseconds and what the last
// run produced (vertex and face counts), so the caller checks both decoded the mesh.
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";
import vm from "node:vm";

const [web, dir, runsArg] = process.argv.slice(2);
const runs = Number(runsArg);
const { FrameCutter, ProgressiveLevels, decodeBaseMesh, decodeFrame } = await import(
  pathToFileURL(`${web}/js/refine.js`).href
);
const plan = JSON.parse(readFileSync(`${dir}/plan.json`, "utf8"));
const baseBytes = readFileSync(`${dir}/base.msgpack`);
const stream = readFileSync(`${dir}/stream.qsplits`);
const drc = readFileSync(`${dir}/mesh.drc`);

function decodeProgressive() {
  const start = performance.now();
  const levels = new ProgressiveLevels(decodeBaseMesh(baseBytes), plan.vertices, plan.faces);
  const cutter = new FrameCutter();
  for (const payload of cutter.push(stream)) levels.addFrame(decodeFrame(payload));
  cutter.finish();
  levels.setLevel(plan.vertices);
  return { ms: performance.now() - start, vertices: levels.level, faces: levels.nFaces };
}

// draco_wasm_wrapper.js is a classic script defining DracoDecoderModule.
const dracoDir = `${web}/node_modules/three/examples/jsm/libs/draco`;
const sandbox = { console };
vm.runInNewContext(
  `${readFileSync(`${dracoDir}/draco_wasm_wrapper.js`, "utf8")}\nthis.DracoDecoderModule = DracoDecoderModule;`,
  sandbox,
);
const wasmBinary = readFileSync(`${dracoDir}/draco_decoder.wasm`);
const draco = await new Promise((resolve) => {
  sandbox.DracoDecoderModule({ wasmBinary, onModuleLoaded: resolve });
});

/** Decode to positions and indices copied out of the wasm heap, as DRACOLoader does. */
function decodeDraco() {
  const start = performance.now();
  const decoder = new draco.Decoder();
  const buffer = new draco.DecoderBuffer();
  buffer.Init(new Int8Array(drc.buffer, drc.byteOffset, drc.byteLength), drc.byteLength);
  const mesh = new draco.Mesh();
  const status = decoder.DecodeBufferToMesh(buffer, mesh);
  if (!status.ok()) throw new Error(`draco: ${status.error_msg()}`);
  const faces = mesh.num_faces();
  const points = mesh.num_points();
  const indexPtr = draco._malloc(faces * 12);
  decoder.GetTrianglesUInt32Array(mesh, faces * 12, indexPtr);
  new Uint32Array(draco.HEAPU32.buffer, indexPtr, 3 * faces).slice();
  draco._free(indexPtr);
  const attribute = decoder.GetAttribute(mesh, decoder.GetAttributeId(mesh, draco.POSITION));
  const positionPtr = draco._malloc(points * 12);
  decoder.GetAttributeDataArrayForAllPoints(mesh, attribute, draco.DT_FLOAT32, points * 12, positionPtr);
  new Float32Array(draco.HEAPF32.buffer, positionPtr, 3 * points).slice();
  draco._free(positionPtr);
  draco.destroy(mesh);
  draco.destroy(buffer);
  draco.destroy(decoder);
  return { ms: performance.now() - start, vertices: points, faces };
}

const out = { progressive_ms: [], draco_ms: [] };
decodeProgressive(); // untimed: compiles the decoders' code
decodeDraco();
for (let run = 0; run < runs; run++) {
  const ours = decodeProgressive();
  const theirs = decodeDraco();
  out.progressive_ms.push(ours.ms);
  out.draco_ms.push(theirs.ms);
  out.progressive_result = { vertices: ours.vertices, faces: ours.faces };
  out.draco_result = { vertices: theirs.vertices, faces: theirs.faces };
}
console.log(JSON.stringify(out));

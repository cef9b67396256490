// Times, in one node process, the viewer's decoder (client/web/js/refine.js, its frames
// decoded in JavaScript and by the WebAssembly split decoder js/refine.wasm) turning a
// base mesh plus its whole split stream into the full mesh, and Draco's WebAssembly
// decoder (three.js's copy, as DRACOLoader runs it) decoding the same mesh, alternating.
//
//   node decoder_speed.mjs WEB_DIR CASE_DIR RUNS
//
// CASE_DIR holds base.msgpack, stream.qsplits, mesh.drc and plan.json ({vertices,
// faces}); prints one JSON line: each decoder's times in milliseconds and what the last
// run produced (vertex and face counts), so the caller checks each decoded the mesh.
import { readFileSync } from "node:fs";
import { loadDracoDecoder } from "./draco_wasm.mjs";
import { loadRefineCase } from "./refine_case.mjs";

const [web, dir, runsArg] = process.argv.slice(2);
const runs = Number(runsArg);
const decodeProgressive = await loadRefineCase(web, dir);
const decodeInWasm = await loadRefineCase(web, dir, { wasm: true });
const decodeDraco = await loadDracoDecoder(web);
const drc = readFileSync(`${dir}/mesh.drc`);

const out = { progressive_ms: [], wasm_ms: [], draco_ms: [] };
decodeProgressive(); // untimed: compiles the decoders' code
decodeInWasm();
decodeDraco(drc);
for (let run = 0; run < runs; run++) {
  const ours = decodeProgressive();
  const inWasm = decodeInWasm();
  const theirs = decodeDraco(drc);
  out.progressive_ms.push(ours.ms);
  out.wasm_ms.push(inWasm.ms);
  out.draco_ms.push(theirs.ms);
  out.progressive_result = { vertices: ours.vertices, faces: ours.faces };
  out.wasm_result = { vertices: inWasm.vertices, faces: inWasm.faces, decoder: inWasm.decoder };
  out.draco_result = { vertices: theirs.vertices, faces: theirs.faces, attributes: theirs.attributes };
}
console.log(JSON.stringify(out));

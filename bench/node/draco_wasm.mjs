// Draco's WebAssembly decoder (three.js's copy, as DRACOLoader runs it), for the node
// benchmarks that time a decoder against it in one process.
import { readFileSync } from "node:fs";
import vm from "node:vm";

/** A function decoding Draco bytes to indices and every attribute (positions, and any
 * colours or texture coordinates) copied out of the wasm heap, as DRACOLoader does; it
 * returns { ms, vertices, faces, attributes }. `web` is client/web (its node_modules
 * hold three.js). */
export async function loadDracoDecoder(web) {
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
  return function decodeDraco(drc) {
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
    const attributes = mesh.num_attributes();
    for (let id = 0; id < attributes; id++) {
      const attribute = decoder.GetAttribute(mesh, id);
      const values = points * attribute.num_components();
      const at = draco._malloc(values * 4);
      decoder.GetAttributeDataArrayForAllPoints(mesh, attribute, draco.DT_FLOAT32, values * 4, at);
      new Float32Array(draco.HEAPF32.buffer, at, values).slice();
      draco._free(at);
    }
    draco.destroy(mesh);
    draco.destroy(buffer);
    draco.destroy(decoder);
    return { ms: performance.now() - start, vertices: points, faces, attributes };
  };
}

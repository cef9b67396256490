// The least a split-by-split decoder of a mesh's real split sequence costs in node, timed
// beside the viewer's decoder (refine.js) and Draco's WebAssembly decoder in one process.
//
//   node split_floor.mjs WEB_DIR CASE_DIR RUNS SYMBOLS [FLOOR_WASM]
//
// CASE_DIR holds what bench/node/decoder_speed.mjs reads (base.msgpack, stream.qsplits,
// mesh.drc, plan.json) and the progressive mesh's split arrays as little-endian int32
// files (floor.json names their sizes: base_faces, base_q, split_vertex, new_faces,
// new_face_counts, relabel_offsets, relabel_faces).
//
// The floor is a decoder with nothing left of the format but what any split must do: each
// vertex a block of 32 int32s (degree, grid position, up to 14 neighbours in its first
// 64 bytes; the faces around it in the second), the state an ordered-fan coding would
// keep. Split i reads s's block, swaps s for t in the block of every neighbour that moves
// to t, adds t to the blocks of the new faces' third corners (the wings), writes t's block
// and s's, predicts both positions from the wings' and decodes SYMBOLS symbols of a
// static rANS code (12-bit frequencies over 32 letters, about 3.8 bits each) that stand
// for the split's coded fields. It writes what the page needs as a record (relabelled
// faces, new faces, position deltas). Which neighbours move, which faces relabel and the
// wings come from the split arrays (read in order, as decoded symbols would arrive), so
// the floor's memory traffic is the real mesh's; its arithmetic is not a real format's,
// so it is a lower bound, not a decoder. Variant `index` also applies the relabels and
// the new faces to a face index buffer, as a decoder that holds the mesh itself does.
// FLOOR_WASM, split_floor.c built for WebAssembly, times the same two in wasm as well
// (wasm_ms, wasm_index_ms; the records copied out of its memory, as Draco's are).
//
// Prints one JSON line: each decoder's times (ms) and the floor's coded bits a split.
import { readFileSync } from "node:fs";
import { loadDracoDecoder } from "./draco_wasm.mjs";
import { loadRefineCase } from "./refine_case.mjs";

const [web, dir, runsArg, symbolsArg, floorWasm] = process.argv.slice(2);
const runs = Number(runsArg);
const symbols = Number(symbolsArg);
const sizes = JSON.parse(readFileSync(`${dir}/floor.json`, "utf8"));
const read = (name) => {
  const bytes = readFileSync(`${dir}/${name}.i32`);
  return new Int32Array(bytes.buffer, bytes.byteOffset, bytes.byteLength / 4);
};
const baseFaces = read("base_faces");
const baseQ = read("base_q");
const splitVertex = read("split_vertex");
const newFaces = read("new_faces");
const newFaceCounts = read("new_face_counts");
const relabelOffsets = read("relabel_offsets");
const relabelFaces = read("relabel_faces");
const { nBase, nFull, fBase, fFull } = sizes;
const nSplits = nFull - nBase;

// Per split, the neighbours that move to t (the relabelled faces' corners other than s,
// each once) and the wings, from one replay of the faces (untimed: a real decoder reads
// them from its coded symbols and s's block).
const movedOffsets = new Int32Array(nSplits + 1);
const moved = new Int32Array(2 * relabelFaces.length);
const wingOffsets = new Int32Array(nSplits + 1);
const wings = new Int32Array(newFaces.length / 3);
{
  const faces = new Int32Array(3 * fFull);
  faces.set(baseFaces);
  let face = fBase;
  let m = 0;
  let w = 0;
  for (let i = 0; i < nSplits; i++) {
    const s = splitVertex[i];
    const t = nBase + i;
    const first = m;
    for (let r = relabelOffsets[i]; r < relabelOffsets[i + 1]; r++) {
      const f = 3 * relabelFaces[r];
      let relabelled = false;
      for (let j = 0; j < 3; j++) {
        const v = faces[f + j];
        if (v === s && !relabelled) {
          faces[f + j] = t;
          relabelled = true;
        } else if (!moved.subarray(first, m).includes(v)) {
          moved[m++] = v;
        }
      }
    }
    for (let j = 0; j < newFaceCounts[i]; j++, face++) {
      for (let c = 0; c < 3; c++) {
        const v = newFaces[3 * (face - fBase) + c];
        faces[3 * face + c] = v;
        if (v !== s && v !== t && c === 2) wings[w++] = v;
      }
    }
    movedOffsets[i + 1] = m;
    wingOffsets[i + 1] = w;
  }
}

// A static rANS code of `symbols` letters a split (32-bit state, byte renormalisation).
const PROB_BITS = 12;
const PROB_SCALE = 1 << PROB_BITS;
const LETTERS = 32;
const RANS_LOW = 1 << 23;
const freq = new Uint32Array(LETTERS);
{
  const weights = Array.from({ length: LETTERS }, (_, k) => 0.82 ** k);
  const total = weights.reduce((a, b) => a + b);
  let left = PROB_SCALE;
  for (let k = 0; k < LETTERS; k++) {
    freq[k] = Math.max(1, Math.floor((weights[k] / total) * PROB_SCALE));
    left -= freq[k];
  }
  freq[0] += left;
}
const cum = new Uint32Array(LETTERS + 1);
for (let k = 0; k < LETTERS; k++) cum[k + 1] = cum[k] + freq[k];
const letterAt = new Uint8Array(PROB_SCALE);
for (let k = 0; k < LETTERS; k++) letterAt.fill(k, cum[k], cum[k + 1]);
const coded = (() => {
  let seed = 1;
  const n = nSplits * symbols;
  const letters = new Uint8Array(n);
  for (let i = 0; i < n; i++) {
    seed = (Math.imul(seed, 1103515245) + 12345) >>> 0;
    const u = (seed / 2 ** 32) * PROB_SCALE;
    let k = 0;
    while (cum[k + 1] <= u) k++;
    letters[i] = k;
  }
  const out = new Uint8Array(2 * n + 8);
  let at = out.length;
  let x = RANS_LOW;
  for (let i = n - 1; i >= 0; i--) {
    const f = freq[letters[i]];
    const limit = ((RANS_LOW >>> PROB_BITS) << 8) * f;
    while (x >= limit) {
      out[--at] = x & 255;
      x >>>= 8;
    }
    x = Math.floor(x / f) * PROB_SCALE + (x % f) + cum[letters[i]];
  }
  for (let k = 0; k < 4; k++) {
    out[--at] = x & 255;
    x >>>= 8;
  }
  return out.subarray(at);
})();

const BLOCK = 32; // int32s a vertex: degree, position, 14 neighbours | 16 faces
const NEIGHBOURS = 4;
const ROOM = 14;
const FACES = 16;

function decodeFloor(withIndex) {
  const start = performance.now();
  const blocks = new Int32Array(BLOCK * nFull);
  for (let v = 0; v < nBase; v++) {
    for (let d = 0; d < 3; d++) blocks[BLOCK * v + 1 + d] = baseQ[3 * v + d];
  }
  const faces = withIndex ? new Int32Array(3 * fFull) : null;
  if (faces) faces.set(baseFaces);
  const recordFaces = new Int32Array(relabelFaces.length);
  const recordNew = new Int32Array(newFaces.length);
  const deltas = new Int32Array(6 * nSplits);
  let state = ((coded[0] << 24) | (coded[1] << 16) | (coded[2] << 8) | coded[3]) >>> 0;
  let at = 4;
  let face = fBase;
  let relabelled = 0;
  for (let i = 0; i < nSplits; i++) {
    const s = splitVertex[i];
    const t = nBase + i;
    let value = 0;
    for (let k = 0; k < symbols; k++) {
      const slot = state & (PROB_SCALE - 1);
      const letter = letterAt[slot];
      state = freq[letter] * (state >>> PROB_BITS) + slot - cum[letter];
      while (state < RANS_LOW) state = ((state << 8) | coded[at++]) >>> 0;
      value = (value * 5 + letter) & 0xffffff;
    }
    const bs = BLOCK * s;
    const bt = BLOCK * t;
    let degree = blocks[bs];
    // neighbours moving to t: s becomes t in their blocks, and they join t's
    let tDegree = 0;
    for (let r = movedOffsets[i]; r < movedOffsets[i + 1]; r++) {
      const v = moved[r];
      const bv = BLOCK * v;
      const n = Math.min(blocks[bv], ROOM);
      for (let q = 0; q < n; q++) {
        if (blocks[bv + NEIGHBOURS + q] === s) {
          blocks[bv + NEIGHBOURS + q] = t;
          break;
        }
      }
      if (tDegree < ROOM) blocks[bt + NEIGHBOURS + tDegree] = v;
      tDegree++;
    }
    // the wings: t joins their blocks, their positions predict the split's
    let wx = 0;
    let wy = 0;
    let wz = 0;
    for (let r = wingOffsets[i]; r < wingOffsets[i + 1]; r++) {
      const bx = BLOCK * wings[r];
      const n = blocks[bx];
      if (n < ROOM) blocks[bx + NEIGHBOURS + n] = t;
      blocks[bx] = n + 1;
      wx += blocks[bx + 1];
      wy += blocks[bx + 2];
      wz += blocks[bx + 3];
    }
    blocks[bt] = tDegree + 1;
    degree = degree - tDegree + wingOffsets[i + 1] - wingOffsets[i] + 1;
    blocks[bs] = degree;
    if (degree <= ROOM) blocks[bs + NEIGHBOURS + degree - 1] = t;
    // the relabelled faces, as s's block lists them
    for (let r = relabelOffsets[i]; r < relabelOffsets[i + 1]; r++) {
      const f = relabelFaces[r];
      recordFaces[relabelled++] = f;
      blocks[bt + FACES + ((r - relabelOffsets[i]) & 15)] = f;
      if (faces) {
        for (let j = 0; j < 3; j++) {
          if (faces[3 * f + j] === s) {
            faces[3 * f + j] = t;
            break;
          }
        }
      }
    }
    for (let j = 0; j < newFaceCounts[i]; j++, face++) {
      for (let c = 0; c < 3; c++) {
        const v = newFaces[3 * (face - fBase) + c];
        recordNew[3 * (face - fBase) + c] = v;
        if (faces) faces[3 * face + c] = v;
      }
    }
    // both positions: the wings' midpoint, the decoded values against it
    const wingsMet = Math.max(1, wingOffsets[i + 1] - wingOffsets[i]);
    const centre = [wx, wy, wz];
    for (let d = 0; d < 3; d++) {
      const old = blocks[bs + 1 + d];
      const edge = ((value >> (2 * d)) & 15) - 8 + ((Math.trunc(centre[d] / wingsMet) - old) >> 3);
      const a = old + ((value >> (d + 12)) & 7) - 3;
      blocks[bs + 1 + d] = a;
      blocks[bt + 1 + d] = a + edge;
      deltas[6 * i + d] = a - old;
      deltas[6 * i + 3 + d] = a + edge - old;
    }
  }
  if (at !== coded.length) throw new Error(`the floor read ${at} of ${coded.length} coded bytes`);
  return performance.now() - start;
}

/** decodeFloor compiled from split_floor.c: its inputs placed in its memory once. */
function loadWasmFloor(path) {
  const inputs = [baseQ, baseFaces, splitVertex, movedOffsets, moved, wingOffsets, wings,
    relabelOffsets, relabelFaces, newFaces, newFaceCounts, coded, freq, cum, letterAt];
  const outputs = {
    blocks: 4 * BLOCK * nFull,
    faces: 12 * fFull,
    recordFaces: 4 * relabelFaces.length,
    recordNew: 4 * newFaces.length,
    deltas: 24 * nSplits,
  };
  const align = (n) => (n + 15) & ~15;
  const bytes = [...inputs.map((a) => a.byteLength), ...Object.values(outputs)].reduce((a, b) => a + align(b), 1024);
  const memory = new WebAssembly.Memory({ initial: Math.ceil(bytes / 65536) });
  const module = new WebAssembly.Module(readFileSync(path));
  const { floor_decode: floorDecode } = new WebAssembly.Instance(module, { env: { memory } }).exports;
  let heap = 1024; // offset 0 is the null pointer
  const reserve = (n) => {
    const at = heap;
    heap += align(n);
    return at;
  };
  const placed = inputs.map((array) => {
    const at = reserve(array.byteLength);
    new Uint8Array(memory.buffer, at, array.byteLength).set(new Uint8Array(array.buffer, array.byteOffset, array.byteLength));
    return at;
  });
  const at = Object.fromEntries(Object.entries(outputs).map(([name, n]) => [name, reserve(n)]));
  return function decodeWasm(withIndex) {
    const start = performance.now();
    const read = floorDecode(nBase, nFull, fBase, fFull, symbols, ...placed, at.blocks,
      withIndex ? at.faces : 0, at.recordFaces, at.recordNew, at.deltas);
    if (read !== coded.length) throw new Error(`the wasm floor read ${read} of ${coded.length} coded bytes`);
    for (const name of ["recordFaces", "recordNew", "deltas", ...(withIndex ? ["faces"] : [])]) {
      new Int32Array(memory.buffer, at[name], outputs[name] / 4).slice();
    }
    return performance.now() - start;
  };
}

const decodeRefine = await loadRefineCase(web, dir);
const decodeDraco = await loadDracoDecoder(web);
const drc = readFileSync(`${dir}/mesh.drc`);

const decoders = {
  floor_ms: () => decodeFloor(false),
  floor_index_ms: () => decodeFloor(true),
  refine_ms: () => decodeRefine().ms,
  draco_ms: () => decodeDraco(drc).ms,
};
if (floorWasm) {
  const decodeWasm = loadWasmFloor(floorWasm);
  decoders.wasm_ms = () => decodeWasm(false);
  decoders.wasm_index_ms = () => decodeWasm(true);
}
const out = Object.fromEntries(Object.keys(decoders).map((key) => [key, []]));
for (const decode of Object.values(decoders)) decode(); // untimed: compiled
for (let run = 0; run < runs; run++) {
  for (const [key, decode] of Object.entries(decoders)) out[key].push(decode());
}
out.floor_bits_per_split = (8 * coded.length) / nSplits;
console.log(JSON.stringify(out));

"""The WebAssembly split decoder (client/web/wasm/refine.c) against refine.js on damaged
frames: thousands of frames whose coded splits, wedge keys or counts were changed at
random, then sealed again with their right CRC-32 (so they reach the decoders, not the
checksum), go through both in one node process (a mesh's wedge keys are decoded by
wedges.js in both, called from each split of the C decoder), and through a build of the
C decoder that reads ahead (as it does on large levels) on these small ones. On every
one they must agree: the same refusal with the same message and the same levels kept,
or the same levels decoded, bit for bit.
Nothing may hang or crash either (the C decoder checks every index a frame gives).

The levels on undamaged streams, and the hand-made hostile frames, are compared for both
decoders wherever refine.js runs under node (test_viewer.run_refine_js).
"""

from __future__ import annotations

import json
from pathlib import Path

import msgpack
import numpy as np
import pytest

from qem_core.levels import encode_level
from qem_core.stream import encode_split_frames
from tests.tiny_meshes import icosphere, perforated_icosphere
from tests.wedge_meshes import seamed_mesh

from .test_viewer import WEB, require_node, require_wasm, run_node_script, sealed

# Decodes every stream of the case with refine.js and with refine.wasm; one line each:
# both outcomes (the refusal and the vertices held, or a digest of the full level).
_DRIVER = """
import { readFileSync } from "node:fs";
import { createHash } from "node:crypto";
import { pathToFileURL } from "node:url";
const [refinePath, wasmPath, aheadPath, dir] = process.argv.slice(2);
const { FrameCutter, ProgressiveLevels, decodeBaseMesh, decodeFrame } =
  await import(pathToFileURL(refinePath).href);
const wasm = new WebAssembly.Module(readFileSync(wasmPath));
const ahead = new WebAssembly.Module(readFileSync(aheadPath));
const plan = JSON.parse(readFileSync(`${dir}/plan.json`, "utf8"));
const baseBytes = readFileSync(`${dir}/base.msgpack`);
function outcome(stream, module) {
  const base = decodeBaseMesh(baseBytes);
  const levels = new ProgressiveLevels(base, plan.n_full, plan.f_full, { wasm: module });
  try {
    const cutter = new FrameCutter();
    for (const payload of cutter.push(stream)) levels.addFrame(decodeFrame(payload));
    cutter.finish();
  } catch (error) {
    const refusal = `${error.name}: ${error.message}`;
    return { decoder: levels.decoder, error: refusal, held: levels.received };
  }
  levels.setLevel(levels.received);
  const hash = createHash("sha256");
  const wedges = levels.wedges ? [levels.wedges.cornerWedge, levels.wedges.values] : [];
  for (const a of [levels.positions, levels.indices, ...wedges]) {
    hash.update(new Uint8Array(a.buffer));
  }
  return { decoder: levels.decoder, held: levels.received, digest: hash.digest("hex") };
}
for (let i = 0; i < plan.streams; i++) {
  const stream = readFileSync(`${dir}/stream-${i}.bin`);
  console.log(JSON.stringify({
    js: outcome(stream, null), wasm: outcome(stream, wasm), ahead: outcome(stream, ahead),
  }));
}
"""

STREAMS = 400  # damaged streams a mesh


@pytest.fixture(scope="module")
def reading_ahead(tmp_path_factory) -> Path:
    """refine.wasm built to read ahead on every mesh (refine.c reads ahead only on levels
    past 24 MB, which no damaged stream here reaches): its reads of the splits to come
    must stay inside the state whatever a frame holds."""
    pytest.importorskip("ziglang", reason="building refine.wasm needs the dev extra's ziglang")
    from client.build_wasm import build

    return build(tmp_path_factory.mktemp("wasm") / "refine.wasm", {"READ_AHEAD_BYTES": "0"})


def _damaged(frame: bytes, rng: np.random.Generator) -> bytes:
    """The frame with one random change to its coded splits (or, half the time in a frame
    with wedge keys, its coded wedges) or its counts, sealed again. One kind of change
    (a low bit of the last byte, which the range coder's flush mostly absorbs) leaves a
    frame that usually still decodes, so some damaged streams reach the full level."""
    body = msgpack.unpackb(frame[4:-4])
    field = "wedges" if "wedges" in body and rng.integers(2) else "splits"
    coded = bytearray(body[field])
    kind = rng.integers(7)
    if kind == 6 and coded:  # a low bit of the flush
        coded[-1] ^= 1 << int(rng.integers(3))
    elif kind <= 1 and coded:  # bits flipped
        for _ in range(1 + int(rng.integers(3))):
            coded[int(rng.integers(len(coded)))] ^= 1 << int(rng.integers(8))
    elif kind == 2 and coded:  # cut short
        del coded[int(rng.integers(len(coded))) :]
    elif kind == 3:  # bytes added
        coded += bytes(rng.integers(0, 256, int(rng.integers(1, 9)), dtype=np.uint8))
    elif kind == 4 and coded:  # a stretch of random bytes
        at = int(rng.integers(len(coded)))
        for j in range(at, min(len(coded), at + 8)):
            coded[j] = int(rng.integers(256))
    else:  # a count off by a little
        key = ("n_new_faces", "n_to")[int(rng.integers(2))]
        body[key] = max(0, body[key] + int(rng.choice([-2, -1, 1, 2])))
    body[field] = bytes(coded)
    return sealed(msgpack.packb(body))


MESHES = {
    "closed": lambda: icosphere(3, jitter=0.05),
    "holes": lambda: perforated_icosphere(3, jitter=0.05, holes=6),  # open fans, pinches
    "wedges": lambda: seamed_mesh(*icosphere(3, jitter=0.05), seed=5),  # a UV seam, colours
}


@pytest.mark.parametrize("make", MESHES.values(), ids=MESHES.keys())
def test_wasm_decoder_agrees_with_refine_js_on_damaged_frames(make, tmp_path, reading_ahead):
    require_node()  # before the meshes are built
    import qem_core

    made = make()
    if isinstance(made, qem_core.Mesh):
        pm = qem_core.build_mesh(made)
    else:
        pm = qem_core.build(*made)
    frames = list(encode_split_frames(pm, pm.n_base, pm.n_full, splits_per_frame=16))
    rng = np.random.default_rng(20261207)
    for i in range(STREAMS):
        at = int(rng.integers(len(frames)))
        stream = b"".join([*frames[:at], _damaged(frames[at], rng), *frames[at + 1 :]])
        (tmp_path / f"stream-{i}.bin").write_bytes(stream)
    (tmp_path / "base.msgpack").write_bytes(encode_level(pm, pm.n_base, "msgpack").content)
    plan = {"n_full": pm.n_full, "f_full": pm.n_faces_full, "streams": STREAMS}
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    printed = run_node_script(
        tmp_path, _DRIVER, WEB / "js" / "refine.js", require_wasm(), reading_ahead, tmp_path,
        timeout=300,
    )  # fmt: skip
    outcomes = [json.loads(line) for line in printed.splitlines()]
    assert len(outcomes) == STREAMS
    refused = 0
    for i, all_three in enumerate(outcomes):
        decoders = {name: all_three[name].pop("decoder") for name in all_three}
        assert decoders == {"js": "js", "wasm": "wasm", "ahead": "wasm"}
        assert all_three["wasm"] == all_three["js"], f"stream {i}"
        assert all_three["ahead"] == all_three["js"], f"stream {i}"
        refused += "error" in all_three["js"]
    # the damage reaches the decoders: most streams are refused, not all
    assert STREAMS // 2 < refused < STREAMS, refused


def test_wasm_decoder_refuses_a_base_mesh_face_past_its_vertices(tmp_path):
    """The base mesh's faces are checked in C too (the page's decodeBaseMesh checks them
    first; the C decoder does not rely on it)."""
    printed = run_node_script(
        tmp_path,
        """
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";
const [splitsPath, wasmPath] = process.argv.slice(2);
const { WasmSplits } = await import(pathToFileURL(splitsPath).href);
const module = new WebAssembly.Module(readFileSync(wasmPath));
const base = { nVertices: 3, nFaces: 1, bits: 16, positions: new Uint16Array(9),
               indices: new Uint32Array([0, 1, 3]) };
try {
  new WasmSplits(module, base, 5, 4);
  console.log("accepted");
} catch (error) {
  console.log(`${error.name}: ${error.message}`);
}
""",
        WEB / "js" / "wasm_splits.js",
        require_wasm(),
        timeout=60,
    )
    refusal = "WireFormatError: base mesh: a face names a vertex that does not exist"
    assert printed.strip() == refusal

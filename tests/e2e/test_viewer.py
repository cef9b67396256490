"""The web viewer (client/web): its decoder under node, and the whole page in Chromium.

- ``refine.js`` run by node on a hand-drawn progressive mesh whose frames use every face
  code, then on a built one, moved down and up through every level: each level's grid
  integers and faces must equal ``pm.lod(n)`` bit for bit; on meshes with wedges (spot's
  seams, a sphere with seams, colours and normals) its wedges too (``quantised_wedges``),
  and every corner's render vertex names its vertex and wedge.
- Headless Chromium (Debian's, driven by Playwright) on ``qem serve``: upload bunny.ply
  through the page, wait until the refinement reaches the server's vertex count, check
  the figures and the level's digest against the server's lod, move the slider down and
  up (the figures change at once, from data already held), and save a screenshot that
  shows a render (not one colour). Then spot as a GLB with its texture and
  airplane_colored.ply: the wedges' digests against the server's levels, the texture
  shown, a render in many colours.

The browser test skips only where no Chromium can be found; ``.ci/run`` installs it.
"""

from __future__ import annotations

import base64
import functools
import hashlib
import json
import os
import shutil
import struct
import subprocess
import zlib
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import NamedTuple

import httpx
import msgpack
import numpy as np
import pytest

import qem_core
from qem_core import codecs
from qem_core.levels import encode_level
from qem_core.progressive import ProgressiveMesh
from qem_core.stored_stream import encode_stored_stream
from qem_core.stream import (
    STREAM_VERSION,
    SplitStreamDecoder,
    encode_split_frames,
    grid_for,
    iter_frames,
    new_wedge_contexts,
    quantised_wedges,
    split_frame_symbols,
)
from tests.tiny_meshes import bumpy_grid, degenerate_ring_pm, grid, icosphere, perforated_icosphere
from tests.wedge_meshes import seamed_mesh, wedge_arrays, with_wedge_arrays

from .conftest import REPO, shared_mesh

WEB = REPO / "client" / "web"
WASM = WEB / "js" / "refine.wasm"  # built by make install (client/build_wasm.py)
# Without the background-networking flags Chromium dials out at start, which a closed
# network refuses; a fresh profile keeps runs independent.
CHROMIUM_FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
)
READY_TIMEOUT_MS = 300_000  # a cold build compiles numba kernels first


def find_chromium() -> str | None:
    """$QEM_CHROMIUM, else Debian's /usr/bin/chromium, else a chromium or chrome on PATH."""
    candidates = [os.environ.get("QEM_CHROMIUM"), "/usr/bin/chromium"]
    candidates += [shutil.which(name) for name in ("chromium", "chromium-browser", "google-chrome")]
    return next((path for path in candidates if path and os.access(path, os.X_OK)), None)


def require_web_packages() -> None:
    if not (WEB / "node_modules" / "three" / "build" / "three.module.js").is_file():
        pytest.fail("client/web/node_modules is missing: run `make install` (npm ci in client/web)")


def require_node() -> str:
    """node's path, once node and the viewer's packages are known to be there."""
    node = shutil.which("node")
    if node is None:
        pytest.fail("node is missing: it is needed for the viewer's packages (npm ci)")
    require_web_packages()
    return node


def run_node_script(tmp_path: Path, source: str, *arguments: object, timeout: int = 120) -> str:
    """What node prints running `source` (an ES module, written to tmp_path) with
    `arguments`; fails the test, with node's stderr, if it exits otherwise than 0."""
    node = require_node()
    script = tmp_path / "driver.mjs"
    script.write_text(source)
    done = subprocess.run(
        [node, str(script), *map(str, arguments)],
        capture_output=True, text=True, timeout=timeout, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    return done.stdout


def require_wasm() -> Path:
    """The viewer's WebAssembly split decoder, which `make install` builds."""
    if not WASM.is_file():
        pytest.fail(f"{WASM} is missing: run `make install` (python client/build_wasm.py)")
    return WASM


@contextmanager
def chromium_page(user_data_dir: Path, viewport=(1200, 800)) -> Iterator:
    """A Playwright page in headless Debian Chromium with a fresh profile (skips the test
    when no Chromium is found; Playwright's own browser downloads are never used)."""
    executable = find_chromium()
    if executable is None:
        pytest.skip("no Chromium found (apt-get install -y chromium, or set QEM_CHROMIUM)")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as playwright:
        context = playwright.chromium.launch_persistent_context(
            str(user_data_dir),
            executable_path=executable,
            headless=True,
            args=list(CHROMIUM_FLAGS),
            viewport={"width": viewport[0], "height": viewport[1]},
        )
        try:
            page = context.new_page()
            page.errors = []
            page.on("pageerror", lambda error: page.errors.append(str(error)))
            yield page
        finally:
            context.close()


def level_digest(positions: np.ndarray, faces: np.ndarray) -> str:
    """SHA-256 of grid positions as uint16 LE then faces as uint32 LE: what the page's
    ``qemViewer.levelDigest()`` computes over its buffers."""
    data = np.asarray(positions, "<u2").tobytes() + np.asarray(faces, "<u4").tobytes()
    return hashlib.sha256(data).hexdigest()


def pm_digest(pm: ProgressiveMesh, n: int) -> str:
    vertices, faces = pm.lod(n)
    return level_digest(grid_for(pm).quantise(vertices), faces)


def wedges_digest(face_wedges: np.ndarray, values: np.ndarray) -> str:
    """SHA-256 of the corners' wedges as uint32 LE then the wedges' grid integers as
    uint16 LE: what ``qemViewer.wedgeDigest()`` computes."""
    data = np.asarray(face_wedges, "<u4").tobytes() + np.asarray(values, "<u2").tobytes()
    return hashlib.sha256(data).hexdigest()


def pm_wedges_digest(pm: ProgressiveMesh, n: int) -> str:
    wedges = quantised_wedges(pm, n)
    return wedges_digest(wedges.face_wedges, wedges.values)


def served_digest(http: httpx.Client, url: str, n: int) -> tuple[str, int]:
    """Digest and face count of the server's lod(n) in the msgpack form."""
    response = http.get(f"{url}/lod", params={"vertices": n, "format": "msgpack"})
    response.raise_for_status()
    message = msgpack.unpackb(response.content)
    index_dtype = {"u8": "u1", "u16": "<u2", "u32": "<u4"}[message["index_type"]]
    positions = np.frombuffer(message["positions"], "<u2")
    faces = np.frombuffer(message["indices"], index_dtype)
    return level_digest(positions, faces), int(response.headers["X-Lod-Faces"])


def served_wedges_digest(http: httpx.Client, url: str, n: int) -> str:
    """Digest of the wedges of the server's lod(n) in the msgpack form."""
    response = http.get(f"{url}/lod", params={"vertices": n, "format": "msgpack"})
    response.raise_for_status()
    wedges = codecs.msgpack_mesh.read_msgpack_wedges(response.content)
    return wedges_digest(wedges.face_wedges, wedges.values)


# -- refine.js under node -----------------------------------------------------------------

# Feeds the stream to refine.js in uneven chunks, then visits the levels asked for, in
# that order, printing each level's digest (node:crypto, same bytes as the page's). With
# the compiled split decoder's path (refine.wasm) it does it all twice, the frames decoded
# in JavaScript and in WebAssembly, and prints both.
_NODE_DRIVER = """
import { readFileSync } from "node:fs";
import { createHash } from "node:crypto";
import { pathToFileURL } from "node:url";
const [refinePath, dir, wasmPath] = process.argv.slice(2);
const { FrameCutter, ProgressiveLevels, decodeBaseMesh, decodeFrame } =
  await import(pathToFileURL(refinePath).href);
const plan = JSON.parse(readFileSync(`${dir}/plan.json`, "utf8"));
const stream = readFileSync(`${dir}/splits.bin`);
function decodeAll(wasm) {
  const base = decodeBaseMesh(readFileSync(`${dir}/base.msgpack`));
  const levels = new ProgressiveLevels(base, plan.n_full, plan.f_full, { wasm });
  // What the page holds: the splits as records from a decoder elsewhere (its worker).
  const mirror = new ProgressiveLevels(base, plan.n_full, plan.f_full, { decoder: false });
  const cutter = new FrameCutter();
  try {
    for (let at = 0, size = 1; at < stream.length; at += size, size = 2 * size + 1) {
      for (const payload of cutter.push(stream.subarray(at, at + size))) {
        const before = levels.received;
        levels.addFrame(decodeFrame(payload));
        if (levels.received > before) mirror.addRecord(levels.recordOf(before, levels.received));
      }
    }
    cutter.finish();
  } catch (error) {
    const error_ = `${error.name}: ${error.message}`;
    return { error: error_, held: levels.received, decoder: levels.decoder };
  }
  return { levels, mirror };
}
const digest = (...arrays) => {
  const hash = createHash("sha256");
  for (const array of arrays) hash.update(new Uint8Array(array.buffer));
  return hash.digest("hex");
};
function visit(held, n) {
  held.setLevel(n);
  const positions = Uint16Array.from(held.positions.subarray(0, 3 * held.level));
  const faces = held.indices.slice(0, 3 * held.nFaces);
  const out = {
    level: held.level,
    faces: held.nFaces,
    digest: digest(positions, faces),
    closed: held.closedAt(held.level),
  };
  const w = held.wedges;
  if (!w) return out;
  const corners = Uint32Array.from(w.cornerWedge.subarray(0, 3 * held.nFaces));
  const values = Uint16Array.from(w.values.subarray(0, w.wedgesAt(held.level) * w.width));
  out.wedges = digest(corners, values);
  // Every corner drawn from the render vertex of its (vertex, wedge), at its position.
  const r = w.render;
  let wrong = 0;
  for (let c = 0; c < 3 * held.nFaces; c++) {
    const p = r.indices[c];
    const v = held.indices[c];
    if (r.vertex[p] !== v || r.wedge[p] !== w.cornerWedge[c]) wrong++;
    for (let d = 0; d < 3; d++) if (r.positions[3 * p + d] !== held.positions[3 * v + d]) wrong++;
  }
  out.wrongRenderCorners = wrong;
  return out;
}
function visitAll(decoded) {
  if (decoded.error) return decoded;
  const out = {};
  for (const n of plan.visit) {
    out[n] = visit(decoded.levels, n);
    out[n].mirror = visit(decoded.mirror, n);
  }
  return { decoder: decoded.levels.decoder, levels: out };
}
const answers = { js: visitAll(decodeAll(null)) };
if (wasmPath) answers.wasm = visitAll(decodeAll(new WebAssembly.Module(readFileSync(wasmPath))));
console.log(JSON.stringify(answers));
"""


def closed_outwards(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Every edge in two faces that go along it in opposite directions (each directed
    edge once, and its reverse once), wound so that they enclose a positive volume."""
    faces = np.asarray(faces)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    forward = np.unique(directed, axis=0)
    backward = np.unique(directed[:, ::-1], axis=0)
    if not (len(faces) > 0 and len(forward) == len(directed)):
        return False
    corners = np.asarray(vertices, np.float64)[faces]
    volume = np.einsum("ij,ij->", corners[:, 0], np.cross(corners[:, 1], corners[:, 2]))
    return np.array_equal(forward, backward) and volume > 0


def run_refine_js(
    tmp_path: Path,
    pm: ProgressiveMesh,
    visit: list[int],
    stream: bytes | None = None,
    start: int | None = None,
    closed: bool | None = None,
) -> dict:
    """Levels visited by refine.js (level -> level, faces, digest), after it read
    `stream` (default: pm's whole split stream, two splits a frame) from lod(`start`)
    (default: the base); or {"error": ..., "held": vertex count received} if it refused
    the stream. The frames are decoded twice, by refine.js and by the WebAssembly split
    decoder (refine.wasm, with refine.js's wedges.js for a mesh's wedges), which must
    agree on every level and refusal. A level that refine.js takes for closed with its
    faces turned outwards (`closedAt`, where the viewer culls back faces) must be; with
    `closed`, every level visited must be taken for that."""
    start = pm.n_base if start is None else start
    base = encode_level(pm, start, "msgpack").content
    (tmp_path / "base.msgpack").write_bytes(base)
    if stream is None:
        stream = b"".join(encode_split_frames(pm, pm.n_base, pm.n_full, splits_per_frame=2))
    (tmp_path / "splits.bin").write_bytes(stream)
    plan = {"n_full": pm.n_full, "f_full": pm.n_faces_full, "visit": visit}
    (tmp_path / "plan.json").write_text(json.dumps(plan))
    answers = json.loads(
        run_node_script(tmp_path, _NODE_DRIVER, WEB / "js" / "refine.js", tmp_path, require_wasm())
    )
    in_js, in_wasm = answers["js"], answers["wasm"]
    assert in_js["decoder"] == "js"
    assert in_wasm.pop("decoder") == "wasm"
    in_js.pop("decoder")
    assert in_wasm == in_js, "the WebAssembly decoder and refine.js disagree"
    if "error" in in_js:
        return in_js
    levels = {}
    for n, level in in_js["levels"].items():
        # The page's levels (records of splits decoded in its worker) are the decoder's.
        assert level.pop("mirror") == level, f"level {n}: the records do not rebuild it"
        taken_closed = level.pop("closed")
        if taken_closed:
            assert closed_outwards(*pm.lod(int(n))), f"level {n} is not closed"
        assert closed is None or taken_closed == closed, f"level {n}: closed {taken_closed}"
        levels[int(n)] = level
    return levels


def hand_drawn_pm() -> ProgressiveMesh:
    """A triangle refined by three splits whose new faces need every kind of face code.

    base: f0 = (0, 1, 2)
    split 0: s=0 -> t=3   new f1 = (1, 3, 2)  explicit (no s-t edge)   relabel none
    split 1: s=3 -> t=4   new f2 = (4, 3, 1)  code 3 (t, s, x)          relabel f1: 3 -> 4
    split 2: s=1 -> t=5   new f3 = (2, 1, 5)  code 1 (x, s, t)          relabel f0: 1 -> 5
                          new f4 = (1, 4, 5)  code 5 (s, x, t)
    """
    return ProgressiveMesh(
        base_vertices=np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]]),
        split_vertex=np.array([0, 3, 1], np.int32),
        split_positions=np.array(
            [
                [[0.0, 0, 0], [1, 1, 0.5]],
                [[1.0, 1, 0.5], [0.5, 0.5, 1]],
                [[1.0, 0, 0], [1, -0.5, 0.25]],
            ]
        ),
        face_corners=np.array([[0, 1, 2], [1, 3, 2], [4, 3, 1], [2, 1, 5], [1, 4, 5]], np.int32),
        level_faces=np.array([1, 2, 3, 5]),
        relabel_offsets=np.array([0, 0, 1, 2]),
        relabel_faces=np.array([1, 0], np.int32),
        split_cost=np.array([3.0, 2.0, 1.0]),
    )


_STREAM_SPLITS_DRIVER = """
import { createServer } from "node:http";
import { readFileSync } from "node:fs";
const { streamSplits } = await import(process.argv[2]);
const data = readFileSync(process.argv[3]);
const server = createServer((request, response) => response.end(data));
await new Promise((done) => server.listen(0, "127.0.0.1", done));
const url = `http://127.0.0.1:${server.address().port}/splits`;
const runs = [];
for (const withBytes of [false, true]) {
  const frames = [];
  const seen = [];
  const options = { onFrame: (bytes) => seen.push(bytes) };
  if (withBytes) options.onBytes = () => {};
  const bytes = await streamSplits(url, { addFrame: (frame) => frames.push(frame.nTo) }, options);
  runs.push({ bytes, frames, seen });
}
server.close();
console.log(JSON.stringify(runs));
"""


def test_stream_splits_reads_every_frame_and_counts_its_bytes(tmp_path):
    """refine.js's streamSplits over HTTP, with onBytes and without: every frame in order,
    and the bytes read (its result, and onFrame's after each frame) counted either way."""
    vertices, faces = icosphere(2, jitter=0.05, seed=3)
    pm = qem_core.build(vertices, faces)
    stream = b"".join(encode_split_frames(pm, pm.n_base, pm.n_full, splits_per_frame=8))
    (tmp_path / "splits.bin").write_bytes(stream)
    printed = run_node_script(
        tmp_path, _STREAM_SPLITS_DRIVER, WEB / "js" / "refine.js", tmp_path / "splits.bin"
    )
    ends = list(range(pm.n_base + 8, pm.n_full, 8)) + [pm.n_full]
    for run in json.loads(printed):
        assert run["frames"] == ends
        assert run["bytes"] == len(stream) and run["seen"][-1] == len(stream), run
        assert run["seen"] == sorted(run["seen"]) and run["seen"][0] > 0, run


def test_refine_js_decodes_every_face_code_exactly(tmp_path):
    pm = hand_drawn_pm()
    codes = set()
    for symbols in split_frame_symbols(pm, pm.n_base, pm.n_full):
        codes |= set(symbols.face_codes.tolist())
    assert codes == {1, 3, 5, 6}  # the sketch does what it says
    visit = [6, 3, 5, 4, 6]
    levels = run_refine_js(tmp_path, pm, visit)
    for n in visit:
        assert levels[n] == {"level": n, "faces": pm.n_faces(n), "digest": pm_digest(pm, n)}


def test_refine_js_moves_down_and_up_through_every_level(tmp_path):
    vertices, faces = icosphere(2, jitter=0.05, seed=3)
    pm = qem_core.build(vertices, faces)
    down = list(range(pm.n_full, pm.n_base - 1, -1))
    visit = down + list(range(pm.n_base + 1, pm.n_full + 1, 7)) + [pm.n_full]
    assert closed_outwards(*pm.lod(pm.n_full))
    levels = run_refine_js(tmp_path, pm, visit, closed=True)
    assert len(levels) == pm.n_full - pm.n_base + 1
    for n in down:
        assert levels[n] == {"level": n, "faces": pm.n_faces(n), "digest": pm_digest(pm, n)}


def test_refine_js_draws_an_inside_out_mesh_from_both_sides(tmp_path):
    """Closed and oriented, but wound inwards: culling would hide its near side."""
    vertices, faces = icosphere(2, jitter=0.05, seed=3)
    pm = qem_core.build(vertices, faces[:, ::-1])
    full_vertices, full_faces = pm.lod(pm.n_full)
    assert not closed_outwards(full_vertices, full_faces)
    assert closed_outwards(full_vertices, full_faces[:, ::-1])
    run_refine_js(tmp_path, pm, [pm.n_base, pm.n_full], closed=False)


def test_refine_js_takes_the_rarer_coding_paths_exactly(tmp_path):
    """A ring without a normal, an escaped third corner, t left at s's old position, a
    relabel off the predicted fan (tests.tiny_meshes.degenerate_ring_pm): every level."""
    pm = degenerate_ring_pm()
    visit = [pm.n_full, pm.n_base, pm.n_base + 1, pm.n_full]
    levels = run_refine_js(tmp_path, pm, visit)
    for n in visit:
        assert levels[n] == {"level": n, "faces": pm.n_faces(n), "digest": pm_digest(pm, n)}


@pytest.mark.parametrize(
    "mesh",
    [grid(5), bumpy_grid(6, seed=1), perforated_icosphere(2, holes=3, seed=7)],
    ids=["flat_grid", "bumpy_grid", "perforated_icosphere"],
)
def test_refine_js_decodes_built_meshes_exactly(tmp_path, mesh):
    """Ends that stayed (the flat grid), second wings off the walk and relabels off the
    predicted fan (the bumpy grid, the open icosphere), in frames of two splits and in
    the stream's own frames: every level equals lod(n)."""
    pm = qem_core.build(*mesh)
    visit = list(range(pm.n_full, pm.n_base - 1, -1))
    for splits_per_frame in (2, None):
        stream = None
        if splits_per_frame is None:
            stream = b"".join(encode_split_frames(pm, pm.n_base, pm.n_full))
        # Each has a border at every level: drawn from both sides.
        levels = run_refine_js(tmp_path, pm, visit, stream=stream, closed=False)
        for n in visit:
            assert levels[n] == {"level": n, "faces": pm.n_faces(n), "digest": pm_digest(pm, n)}


def test_refine_js_reaches_exactly_lod_to_from_stored_runs(tmp_path):
    """Runs of stored key frames from their first level, as /splits serves them for any
    from..to, each sent twice (the held frames skipped): the level asked for, exactly."""
    pm = qem_core.build(*icosphere(4))
    data, index = encode_stored_stream(pm)
    assert index.n_frames >= 3
    for n1, n2 in ((pm.n_base, pm.n_full), (700, 1900), (1600, 1601), (30, 2561)):
        i, j = index.covering(n1, n2)
        start, stop = index.byte_span(i, j)
        run = data[start:stop]
        visit = [n2, index.vertices[j], n1, n2]
        levels = run_refine_js(tmp_path, pm, visit, stream=run + run, start=index.vertices[i])
        for n in visit:
            assert levels[n] == {"level": n, "faces": pm.n_faces(n), "digest": pm_digest(pm, n)}


@pytest.fixture(scope="module")
def seamed_sphere_pm():
    """A sphere with seamed UVs, 8-bit colours and normals: every attribute."""
    vertices, faces = icosphere(2, jitter=0.05, seed=5)
    return qem_core.build_mesh(seamed_mesh(vertices, faces, seed=5, normals=True))


@pytest.fixture(scope="module")
def spot_pm():
    return qem_core.build_mesh(qem_core.load_mesh(REPO / "server" / "demo" / "spot.obj"))


@pytest.mark.parametrize("fixture", ["spot_pm", "seamed_sphere_pm"])
def test_refine_js_refines_wedges_exactly_down_and_up(tmp_path, fixture, request):
    """refine.js and wedges.js agree with the Python decoder, which agrees with
    quantised_wedges (tests/unit/test_stream_wedges.py): the wedges of every level
    visited, going down and up, bit for bit."""
    pm = request.getfixturevalue(fixture)
    step = max(1, (pm.n_full - pm.n_base) // 40)
    down = list(range(pm.n_full, pm.n_base - 1, -step)) + [pm.n_base]
    visit = down + list(range(pm.n_base + 1, pm.n_full + 1, 2 * step + 1)) + [pm.n_full]
    levels = run_refine_js(tmp_path, pm, visit)
    for n in visit:
        level = levels[n]
        assert (level["level"], level["faces"], level["digest"]) == (
            n,
            pm.n_faces(n),
            pm_digest(pm, n),
        )
        assert level["wedges"] == pm_wedges_digest(pm, n), n
        assert level["wrongRenderCorners"] == 0


def frame_of(payload: bytes) -> bytes:
    return struct.pack("<I", len(payload)) + payload


def sealed(body: bytes) -> bytes:
    """A frame of these msgpack bytes with their right CRC-32 (qem_core.stream)."""
    return frame_of(body + struct.pack("<I", zlib.crc32(body)))


def _continuing(frame: bytes) -> bytes:
    """The frame claiming to continue a stream (no grid, the previous frame's contexts)."""
    body = msgpack.unpackb(frame[4:-4])
    body = {k: v for k, v in body.items() if k not in ("bits", "grid")}
    return sealed(msgpack.packb({**body, "continues": True}))


def _truncated_splits(frame: bytes) -> bytes:
    """The frame with the last byte of its range-coded splits cut off."""
    body = msgpack.unpackb(frame[4:-4])
    return sealed(msgpack.packb({**body, "splits": body["splits"][:-1]}))


def _rewritten(frame: bytes, change) -> bytes:
    return sealed(msgpack.packb(change(msgpack.unpackb(frame[4:-4]))))


class _WedgeArraysChanged(NamedTuple):
    """A change of a frame's decoded wedge arrays (coded again with the contexts the
    stream's previous frame left)."""

    change: Callable


def _wedge_arrays_changed(change):
    return _WedgeArraysChanged(change)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        (
            lambda body: {k: v for k, v in body.items() if not k.startswith("wedge")},
            "WireFormatError: split frame carries no wedges",
        ),
        (lambda body: {**body, "wedges_from": 1}, "WireFormatError: frame refines 1 wedges"),
        (
            _wedge_arrays_changed(
                lambda w: w._replace(symbols=np.full_like(w.symbols, 0xFE))
            ),
            "WireFormatError: split frame: a corner or update names a wedge",
        ),
        (
            _wedge_arrays_changed(lambda w: w._replace(rows=np.full_like(w.rows, 5000))),
            "WireFormatError: split frame: a wedge value leaves its grid",
        ),
        (
            _wedge_arrays_changed(
                lambda w: w._replace(symbols=np.append(w.symbols, np.uint8(0)))
            ),
            "WireFormatError: split frame: a field holds more than the splits use",
        ),
        (
            lambda body: {**body, "wedges": body["wedges"][:-1]},
            "WireFormatError: split frame: the coded wedges end early",
        ),
        (
            lambda body: {**body, "wedges": body["wedges"] + b"\x00"},
            "WireFormatError: split frame: the coded wedges hold bytes past",
        ),
        (
            lambda body: {**body, "n_wedge_symbols": 10**9},
            "WireFormatError: split frame: the coded wedges (",
        ),
        (
            lambda body: {**body, "wedge_grid": {**body["wedge_grid"], "bits": [11]}},
            "WireFormatError: the split stream's wedge grid is not the base mesh's",
        ),
    ],
    ids=[
        "no-wedges", "other-wedge-count", "no-such-wedge", "off-grid", "long", "short-coded",
        "long-coded", "huge-count", "other-grid",
    ],
)  # fmt: skip
def test_refine_js_refuses_damaged_wedge_frames(tmp_path, spot_pm, change, message):
    frames = list(
        encode_split_frames(spot_pm, spot_pm.n_base, spot_pm.n_full, splits_per_frame=200)
    )
    if isinstance(change, _WedgeArraysChanged):
        probs = new_wedge_contexts(2)  # spot's UVs, as the first frame leaves them
        wedge_arrays(msgpack.unpackb(frames[0][4:-4]), probs)
        change = functools.partial(with_wedge_arrays, change=change.change, probs=probs)
    stream = frames[0] + _rewritten(frames[1], change) + b"".join(frames[2:])
    answer = run_refine_js(tmp_path, spot_pm, [], stream=stream)
    assert answer["error"].startswith(message), answer
    assert answer["held"] == spot_pm.n_base + 200  # the first frame is kept


@pytest.mark.parametrize(
    ("damage", "message"),
    [
        (lambda frames: b"".join(frames)[:-3], "WireFormatError: split stream ends inside a frame"),
        (lambda frames: b"".join(frames[1:]), "WireFormatError: frame refines 4 vertices"),
        (
            lambda frames: frames[0] + b"\x09\x00\x00\x00junk!junk",
            "WireFormatError: split frame: the CRC-32 does not match",
        ),
        (
            lambda frames: frames[0] + sealed(b"junk!"),
            "WireFormatError: unreadable split frame",
        ),
        (
            lambda frames: frames[0] + sealed(b"\x92\x01\x02"),
            "WireFormatError: not a qem-splits frame",
        ),
        (
            lambda frames: frames[0] + _truncated_splits(frames[1]),
            "WireFormatError: split frame: the coded splits end early",
        ),
        (
            lambda frames: _continuing(frames[0]) + b"".join(frames[1:]),
            "WireFormatError: split frame continues a stream whose previous frame",
        ),
    ],
    ids=[
        "cut-inside-a-frame",
        "frame-skipped",
        "damaged",
        "not-msgpack",
        "not-a-splits-map",
        "truncated",
        "continues-nothing",
    ],
)
def test_refine_js_refuses_damaged_streams(tmp_path, damage, message):
    pm = hand_drawn_pm()
    frames = list(encode_split_frames(pm, pm.n_base, pm.n_full, splits_per_frame=1))
    answer = run_refine_js(tmp_path, pm, [], stream=damage(frames))
    assert answer["error"].startswith(message)
    assert pm.n_base <= answer["held"] < pm.n_full  # frames before the damage are kept


# -- the page in Chromium -----------------------------------------------------------------

# The canvas screenshot decoded by the browser's own PNG decoder: the share of pixels
# away from the background colour and the number of distinct colours.
# The body of an async function of `data`, a base64 PNG: its `width`, `height` and RGBA
# `pixels`, for the screenshots' checks.
PNG_PIXELS_JS = """
  const blob = await (await fetch(`data:image/png;base64,${data}`)).blob();
  const bitmap = await createImageBitmap(blob);
  const { width, height } = bitmap;
  const canvas = new OffscreenCanvas(width, height);
  const context = canvas.getContext("2d");
  context.drawImage(bitmap, 0, 0);
  const pixels = context.getImageData(0, 0, width, height).data;
"""

_IMAGE_STATS = "async (data) => {" + PNG_PIXELS_JS + """
  const [r0, g0, b0] = pixels;
  let away = 0;
  const colours = new Set();
  for (let i = 0; i < pixels.length; i += 4) {
    const r = pixels[i] - r0, g = pixels[i + 1] - g0, b = pixels[i + 2] - b0;
    if (Math.abs(r) + Math.abs(g) + Math.abs(b) > 24) away++;
    colours.add((pixels[i] << 16) | (pixels[i + 1] << 8) | pixels[i + 2]);
  }
  return { away: away / (pixels.length / 4), colours: colours.size };
}
"""


def on_screen(page, name: str) -> int:
    """A figure of the HUD as a person reads it ("34,834" -> 34834)."""
    return int(page.text_content(f"#stat-{name}").replace(",", ""))


def test_viewer_refines_to_the_full_mesh_and_slides_both_ways(server, tmp_path):
    bunny = shared_mesh("bunny.ply")
    require_web_packages()
    with chromium_page(tmp_path / "profile") as page, httpx.Client(timeout=60) as http:
        page.goto(f"{server.url}/")
        page.set_input_files("#file-input", str(bunny))  # the page's own upload
        page.wait_for_function(
            "() => { const s = window.qemViewer?.state;"
            " return s?.level !== null && s.level === s.full && s.fullShownMs !== null; }",
            timeout=READY_TIMEOUT_MS,
        )
        state = page.evaluate("window.qemViewer.state")
        info = http.get(f"{server.url}/v1/meshes/{state['id']}").json()
        assert info["name"] == "bunny.ply" and info["status"] == "ready"
        assert page.get_by_role("button", name="bunny.ply").count() == 1  # in the list
        assert on_screen(page, "vertices") == info["vertices"] == state["level"]
        assert on_screen(page, "faces") == info["faces"]
        assert page.get_attribute("#stat-received", "data-value") == str(info["vertices"])
        url = f"{server.url}/v1/meshes/{info['id']}"
        assert (
            page.evaluate("window.qemViewer.levelDigest()")
            == served_digest(http, url, info["vertices"])[0]
        )
        # The stream went through the real network path in frames, after the base mesh.
        assert state["baseBytes"] > 0 and state["splitBytes"] > 0
        assert 0 < state["baseShownMs"] <= state["fullShownMs"]
        assert state["decoder"] == "wasm"  # its worker decoded the frames in WebAssembly

        # The figures are read right after each key: the level moves from data held.
        slider = page.locator("#lod-slider")
        slider.focus()
        slider.press("Home")  # all the way down: the base mesh
        assert on_screen(page, "vertices") == info["min_vertices"]
        assert on_screen(page, "faces") == served_digest(http, url, info["min_vertices"])[1]
        slider.press("End")  # and back up
        assert on_screen(page, "vertices") == info["vertices"]
        assert on_screen(page, "faces") == info["faces"]
        for _ in range(3):  # down a few steps of the (logarithmic) slider
            slider.press("PageDown")
        n = on_screen(page, "vertices")
        assert info["min_vertices"] < n < info["vertices"]
        assert on_screen(page, "faces") == served_digest(http, url, n)[1]
        number = page.locator("#lod-number")  # exact counts, down and up
        for n in (info["vertices"] // 3, 1000, info["vertices"] - 5, 100):
            number.fill(str(n))
            number.press("Enter")
            digest, n_faces = served_digest(http, url, n)
            assert on_screen(page, "vertices") == n
            assert on_screen(page, "faces") == n_faces
            assert page.evaluate("window.qemViewer.levelDigest()") == digest
        # The error figure is the server's X-Lod-Error for the level on screen.
        expected = float(http.get(f"{url}/lod", params={"vertices": 100}).headers["X-Lod-Error"])
        page.wait_for_function(
            "() => document.getElementById('stat-error').dataset.value !== ''", timeout=30_000
        )
        assert float(page.get_attribute("#stat-error", "data-value")) == pytest.approx(expected)
        slider.focus()
        slider.press("End")
        assert on_screen(page, "vertices") == info["vertices"]

        page.evaluate("() => new Promise((done) => requestAnimationFrame(() => done()))")
        page.screenshot(path=tmp_path / "viewer.png")
        for overlay in ("#hud", "#controls"):
            page.eval_on_selector(overlay, "node => { node.style.visibility = 'hidden'; }")
        shot = page.locator("#canvas").screenshot(path=tmp_path / "render.png")
        assert (tmp_path / "viewer.png").stat().st_size > 0 and len(shot) > 0
        stats = page.evaluate(_IMAGE_STATS, base64.b64encode(shot).decode())
        assert 0.02 < stats["away"] < 0.95, stats  # a shape, neither nothing nor all
        assert stats["colours"] > 16, stats  # shaded, not a flat fill
        assert page.errors == []


# -- appearance over HTTP and on screen ----------------------------------------------------


def spot_glb() -> bytes:
    """Spot (the demo copy) with its texture (the shared meshes' PNG), as a GLB: the way
    a mesh brings its texture image to the server."""
    spot = qem_core.load_mesh(REPO / "server" / "demo" / "spot.obj")
    spot.texture = shared_mesh("spot_texture.png").read_bytes()
    return codecs.write_mesh(spot, "glb")


@pytest.fixture(scope="module")
def appearance_meshes(server, tmp_path_factory):
    """spot.glb (texture, seams) and airplane_colored.ply (vertex colours) uploaded with
    the Python client, built: their metadata."""
    spot = tmp_path_factory.mktemp("appearance") / "spot.glb"
    spot.write_bytes(spot_glb())
    with server.client() as qem:
        return {
            name: qem.wait_ready(qem.upload(path), timeout=READY_TIMEOUT_MS / 1000)
            for name, path in (("spot", spot), ("airplane", shared_mesh("airplane_colored.ply")))
        }


def test_server_streams_wedges_that_refine_its_levels(server, appearance_meshes):
    """The base level as msgpack and the version 3 stream, decoded by the Python
    decoder, give the server's full level to the integer, wedges included; the texture
    is served as the uploaded PNG."""
    spot, airplane = appearance_meshes["spot"], appearance_meshes["airplane"]
    with httpx.Client(timeout=60) as http:
        for info in (spot, airplane):
            url = f"{server.url}/v1/meshes/{info['id']}"
            base = http.get(f"{url}/lod", params={"vertices": 1, "format": "msgpack"})
            decoder = SplitStreamDecoder.from_msgpack(base.content)
            with http.stream("GET", f"{url}/splits") as response:
                assert response.headers["content-type"] == "application/x-qem-splits"
                for payload in iter_frames(response.iter_bytes()):
                    body = msgpack.unpackb(payload[:-4])
                    assert body["version"] == STREAM_VERSION and "wedges" in body
                    decoder.feed(payload)
            full = http.get(f"{url}/lod", params={"format": "msgpack"}).content
            expected = codecs.msgpack_mesh.read_msgpack_wedges(full)
            assert np.array_equal(decoder.face_wedges, expected.face_wedges)
            assert np.array_equal(decoder.quantised_values, expected.values)
            assert (
                level_digest(decoder.quantised, decoder.faces)
                == served_digest(http, url, info["vertices"])[0]
            )
        texture = http.get(f"{server.url}/v1/meshes/{spot['id']}/texture")
        assert texture.status_code == 200 and texture.headers["content-type"] == "image/png"
        assert texture.content == shared_mesh("spot_texture.png").read_bytes()
        again = http.get(
            f"{server.url}/v1/meshes/{spot['id']}/texture",
            headers={"If-None-Match": texture.headers["etag"]},
        )
        assert again.status_code == 304
        missing = http.get(f"{server.url}/v1/meshes/{airplane['id']}/texture")
        assert missing.status_code == 404
        assert missing.json()["type"] == "/problems/texture-not-found"


def open_at_full_detail(page, server_url: str, mesh_id: str, texture: bool = False) -> dict:
    """Open the viewer on a mesh, wait until it shows full detail (and its texture);
    returns the viewer's state."""
    page.goto(f"{server_url}/#mesh={mesh_id}")
    page.wait_for_function(
        "(id) => { const s = window.qemViewer?.state; return s?.id === id &&"
        " s.level === s.full && s.fullShownMs !== null; }",
        arg=mesh_id,
        timeout=READY_TIMEOUT_MS,
    )
    if texture:
        page.wait_for_function("() => window.qemViewer.state.textureShown")
    return page.evaluate("window.qemViewer.state")


def assert_levels_on_screen_are_served(page, http: httpx.Client, url: str, levels) -> None:
    """Each level set on screen, in turn, is the server's, wedges included."""
    for n in levels:
        page.evaluate("(n) => window.qemViewer.setLevel(n)", n)
        assert page.evaluate("window.qemViewer.levelDigest()") == served_digest(http, url, n)[0]
        assert page.evaluate("window.qemViewer.wedgeDigest()") == served_wedges_digest(
            http, url, n
        )


def upload_ready(server, name: str) -> dict:
    """A shared mesh uploaded and built (the viewer's packages checked first)."""
    require_web_packages()
    with server.client() as qem:
        return qem.wait_ready(qem.upload(shared_mesh(name)), timeout=READY_TIMEOUT_MS / 1000)


def canvas_stats(page, path: Path | None = None) -> dict:
    """_IMAGE_STATS of the canvas alone, the HUD and the controls hidden over it (saved to
    ``path`` when given)."""
    for overlay in ("#hud", "#controls"):
        page.eval_on_selector(overlay, "node => { node.style.visibility = 'hidden'; }")
    shot = page.locator("#canvas").screenshot(path=path)
    return page.evaluate(_IMAGE_STATS, base64.b64encode(shot).decode())


def require_software_gl(page, url: str, otherwise: str) -> None:
    """Open the viewer; skip the test unless its WebGL draws on the CPU."""
    page.goto(f"{url}/")
    page.wait_for_function("() => window.qemViewer?.state.softwareGL !== null")
    if not page.evaluate("window.qemViewer.state.softwareGL"):
        pytest.skip(f"this Chromium draws WebGL on a GPU: {otherwise}")


def test_viewer_draws_off_screen_without_a_gpu(server, tmp_path):
    """With a GL that draws on the CPU (this Chromium's, started without a GPU), frames
    are drawn into a render target and copied to the canvas once finished, so that the
    compositor's readback does not wait for them: every frame so drawn here, the mesh
    must reach the screen shaded and the levels stay the server's."""
    info = upload_ready(server, "bunny.ply")
    with chromium_page(tmp_path / "profile") as page, httpx.Client(timeout=60) as http:
        require_software_gl(page, server.url, "frames go straight to the canvas")
        page.evaluate("window.qemViewer.drawOffScreenAbove(0)")
        state = open_at_full_detail(page, server.url, info["id"])
        assert state["failure"] is None and state["framesOffScreen"] >= 2  # base, full
        url = f"{server.url}/v1/meshes/{info['id']}"
        for n in (info["vertices"], 1000, info["min_vertices"], info["vertices"]):
            page.evaluate("(n) => window.qemViewer.setLevel(n)", n)
            assert page.evaluate("window.qemViewer.levelDigest()") == served_digest(http, url, n)[0]
        page.wait_for_function(
            "(n) => window.qemViewer.state.framesOffScreen > n", arg=state["framesOffScreen"]
        )
        page.evaluate(
            "() => new Promise((done) => requestAnimationFrame(() => setTimeout(done, 500)))"
        )
        stats = canvas_stats(page)
        assert 0.02 < stats["away"] < 0.95, stats  # the copy reached the canvas
        assert stats["colours"] > 16, stats
        assert page.errors == []


def test_viewer_prepares_its_frames_off_screen_after_the_first(server, tmp_path):
    """With a GL that draws on the CPU, a mesh's frames off screen need programs (and the
    GL's code for them) that the canvas's frames do not: the viewer draws its first frame
    once more off screen, while the stream arrives, rather than leave them to the full
    mesh's frame (a view at rest's polish, off screen too, needs them as well). With every
    other frame kept on the canvas (however long the machine takes to draw it), that one
    is drawn off screen by the full mesh's frame, and the levels and the picture are as
    ever."""
    info = upload_ready(server, "bunny.ply")
    with chromium_page(tmp_path / "profile") as page, httpx.Client(timeout=60) as http:
        require_software_gl(page, server.url, "no frame is drawn off screen")
        page.evaluate("window.qemViewer.drawOffScreenAbove(1e9)")
        assert open_at_full_detail(page, server.url, info["id"])["failure"] is None
        # A polish of the view at rest is counted once shown: read the counts, in one
        # task of the page, while no frame off screen is on its way.
        state = page.wait_for_function(
            "() => { const s = window.qemViewer.state; return !s.drawingOffScreen && s; }"
        ).json_value()
        assert state["framesOffScreen"] - state["framesPolished"] == 1, state
        full = served_digest(http, f"{server.url}/v1/meshes/{info['id']}", info["vertices"])
        assert page.evaluate("window.qemViewer.levelDigest()") == full[0]
        page.evaluate(
            "() => new Promise((done) => requestAnimationFrame(() => setTimeout(done, 500)))"
        )
        stats = canvas_stats(page)
        assert 0.02 < stats["away"] < 0.95, stats
        assert page.errors == []


def test_viewer_polishes_a_view_at_rest_without_a_gpu(server, tmp_path):
    """With a GL that draws on the CPU, each sample costs (SwiftShader: three times the
    time at 4 samples as at 1), so the canvas and the frames have one, and a view at rest
    is drawn once more multisampled: the full mesh, then a level moved to, each
    polished once it rests, shaded on screen, the levels still the server's."""
    info = upload_ready(server, "bunny.ply")
    with chromium_page(tmp_path / "profile") as page, httpx.Client(timeout=60) as http:
        require_software_gl(page, server.url, "its frames are multisampled")
        context = "document.querySelector('#canvas').getContext('webgl2')"
        assert page.evaluate(f"{context}.getContextAttributes().antialias") is False
        state = open_at_full_detail(page, server.url, info["id"])
        assert state["failure"] is None
        page.wait_for_function("() => window.qemViewer.state.fullPolishedMs !== null")
        state = page.evaluate("window.qemViewer.state")
        assert state["fullPolishedMs"] > state["fullShownMs"] and state["framesPolished"] >= 1
        url = f"{server.url}/v1/meshes/{info['id']}"
        page.evaluate("() => window.qemViewer.setLevel(1000)")
        assert page.evaluate("window.qemViewer.levelDigest()") == served_digest(http, url, 1000)[0]
        page.wait_for_function(
            "(n) => window.qemViewer.state.framesPolished > n", arg=state["framesPolished"]
        )
        stats = canvas_stats(page)
        assert 0.02 < stats["away"] < 0.95, stats  # the polished copy reached the canvas
        assert stats["colours"] > 16, stats
        assert page.errors == []


def test_viewer_shows_texture_and_colours_while_it_refines(server, appearance_meshes, tmp_path):
    require_web_packages()
    with chromium_page(tmp_path / "profile") as page, httpx.Client(timeout=60) as http:
        for name, attributes in (("spot", ["uv"]), ("airplane", ["color"])):
            info = appearance_meshes[name]
            url = f"{server.url}/v1/meshes/{info['id']}"
            state = open_at_full_detail(page, server.url, info["id"], texture=name == "spot")
            assert state["attributes"] == attributes and state["failure"] is None
            levels = (info["vertices"], info["vertices"] // 5, 100, info["vertices"] - 3)
            assert_levels_on_screen_are_served(page, http, url, levels)
            page.evaluate("() => new Promise((done) => requestAnimationFrame(() => done()))")
            stats = canvas_stats(page, tmp_path / f"{name}.png")
            assert 0.02 < stats["away"] < 0.95, stats
            # The texture's black patches and the colour ramp give many colours.
            assert stats["colours"] > 200, stats
            for overlay in ("#hud", "#controls"):
                page.eval_on_selector(overlay, "node => { node.style.visibility = ''; }")
        assert page.errors == []

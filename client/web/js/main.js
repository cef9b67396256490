// The qem-lod viewer: a list of the server's meshes, uploads, and a mesh refined on screen
// as its vertex splits stream in, with a slider over every level received.
//
// Selecting a mesh (the page's hash is #mesh=ID) fetches the base mesh as msgpack, then
// streams /splits from the base to the full count into buffers allocated once
// (refine.js); the slider moves the level both ways from the splits already held.
// With ?src=URL-of-manifest the page shows a static export instead (static_source.js):
// no server, the stream fetched from any static host by Range requests.

import { getMesh, listMeshes, lodError, lodUrl, splitsUrl, uploadMesh } from "./api.js";
import { ProgressiveLevels, decodeBaseMesh, problemError, streamSplits } from "./refine.js";
import { loadSplitModule } from "./wasm_splits.js";
import { WorkerDecoder } from "./worker_decoder.js";
import { MeshScene } from "./scene.js";
import { openExport, streamExport } from "./static_source.js";
import { zipFiles } from "./zip.js";

const $ = (id) => document.getElementById(id);
const LIST_POLL_MS = 2000; // while some mesh is queued or building
const BUILD_POLL_MS = 500; // while an upload of this page is building
const ERROR_DELAY_MS = 300; // ask for a level's error once the slider rests this long
// While a stream arrives the HUD's figures change at most this often. Each change of its
// text is work for the page and its compositor, and they came with every chunk and
// record, beside the decoder's worker on the same cores: with a GL on the CPU, in six
// alternating runs on two cores, the worker decoded dragon in a median 1.27 s with them
// and 1.22 s so held (1.19 s with no HUD at all while streaming). The figures are exact
// again when the stream ends.
const STREAM_STATS_MS = 250;

// The WebAssembly split decoder, compiled once while the page starts (null without it:
// the worker then decodes in JavaScript).
const splitModule = loadSplitModule();

const count = (n) => Number(n).toLocaleString("en-US");
const sleep = (ms, signal) =>
  new Promise((resolve, reject) => {
    const timer = setTimeout(resolve, ms);
    signal?.addEventListener("abort", () => {
      clearTimeout(timer);
      reject(signal.reason);
    });
  });

function formatBytes(n) {
  if (n < 1024) return `${n} B`;
  const units = ["KiB", "MiB", "GiB"];
  let value = n;
  let unit = -1;
  do {
    value /= 1024;
    unit++;
  } while (value >= 1024 && unit < units.length - 1);
  return `${value.toFixed(value < 10 ? 2 : 1)} ${units[unit]}`;
}

const formatMs = (ms) =>
  ms == null ? "…" : ms < 1000 ? `${Math.round(ms)} ms` : `${(ms / 1000).toFixed(2)} s`;

// -- state ------------------------------------------------------------------------------

let scene = null;
let meshes = [];
let autoPick = true; // show the first ready mesh until the user picks one
let listTimer = null;
let view = null; // the mesh on screen, see load()

function showMessage(text, bad = false) {
  const box = $("message");
  box.hidden = !text;
  box.textContent = text || "";
  box.classList.toggle("bad", bad);
}

// -- the mesh list ----------------------------------------------------------------------

async function refreshList() {
  clearTimeout(listTimer);
  try {
    meshes = await listMeshes();
  } catch (error) {
    $("mesh-list").innerHTML = "";
    $("mesh-list").append(item("li", "muted", `cannot list meshes: ${error.message}`));
    listTimer = setTimeout(refreshList, LIST_POLL_MS);
    return;
  }
  renderList();
  if (meshes.some((m) => m.status === "queued" || m.status === "building")) {
    listTimer = setTimeout(refreshList, LIST_POLL_MS);
  }
  if (autoPick && !currentId()) {
    const ready = meshes.find((m) => m.status === "ready");
    if (ready) select(ready.id, { auto: true });
  }
}

function item(tag, className, text) {
  const node = document.createElement(tag);
  if (className) node.className = className;
  if (text != null) node.textContent = text;
  return node;
}

function renderList() {
  const list = $("mesh-list");
  list.innerHTML = "";
  if (!meshes.length) list.append(item("li", "muted", "no meshes yet: upload one"));
  for (const mesh of meshes) {
    const li = item("li", mesh.status);
    const button = item("button");
    button.type = "button";
    button.dataset.id = mesh.id;
    button.disabled = mesh.status !== "ready";
    button.setAttribute("aria-current", String(mesh.id === currentId()));
    button.append(item("span", "name", mesh.name), item("span", "muted", mesh.status));
    let meta;
    if (mesh.status === "ready") {
      meta = `${count(mesh.min_vertices)}–${count(mesh.vertices)} vertices · ${count(mesh.faces)} faces`;
    } else if (mesh.status === "failed") {
      meta = mesh.error || "build failed";
    } else {
      meta = `${Math.round(100 * mesh.progress)}%`;
      const bar = item("progress");
      bar.max = 1;
      bar.value = mesh.progress;
      button.append(bar);
    }
    button.append(item("span", "meta", meta));
    button.title = `${mesh.name} (${mesh.id})`;
    button.addEventListener("click", () => select(mesh.id));
    li.append(button);
    list.append(li);
  }
}

// -- uploads ----------------------------------------------------------------------------

function setUploadStatus(text, bad = false) {
  const box = $("upload-status");
  box.textContent = text;
  box.classList.toggle("bad", bad);
}

const MODEL_SUFFIX = /\.(ply|obj|stl|off|glb|gltf)$/i;

/** One file as it is; several (an OBJ with its .mtl and images) as one zip archive, named
 * after the model among them, which the server reads with the files it names. */
async function uploadFiles(fileList) {
  const files = [...fileList];
  if (files.length <= 1) return files.length ? upload(files[0]) : undefined;
  const model = files.find((file) => MODEL_SUFFIX.test(file.name));
  const name = `${model ? model.name.replace(MODEL_SUFFIX, "") : "upload"}.zip`;
  setUploadStatus(`packing ${files.length} files into ${name}…`);
  const entries = await Promise.all(
    files.map(async (file) => ({ name: file.name, bytes: new Uint8Array(await file.arrayBuffer()) })),
  );
  return upload(new File([zipFiles(entries)], name, { type: "application/zip" }));
}

async function upload(file) {
  const token = $("token-input").value.trim();
  setUploadStatus(`uploading ${file.name}…`);
  let accepted;
  try {
    accepted = await uploadMesh(file, {
      token,
      onProgress: (sent, total) =>
        setUploadStatus(`uploading ${file.name}: ${total ? Math.round((100 * sent) / total) : 0}%`),
    });
  } catch (error) {
    if (error.status === 401 || error.status === 403) $("token-box").open = true;
    setUploadStatus(`${file.name}: ${error.message}`, true);
    return;
  }
  refreshList();
  for (;;) {
    let info;
    try {
      info = await getMesh(accepted.id);
    } catch (error) {
      setUploadStatus(`${file.name}: ${error.message}`, true);
      return;
    }
    if (info.status === "failed") {
      setUploadStatus(`${file.name}: build failed: ${info.error}`, true);
      refreshList();
      return;
    }
    if (info.status === "ready") {
      setUploadStatus(`${file.name}: ready, ${count(info.vertices)} vertices`);
      await refreshList();
      select(info.id);
      return;
    }
    setUploadStatus(`${file.name}: ${info.status} ${Math.round(100 * info.progress)}%`);
    await sleep(BUILD_POLL_MS);
  }
}

function setUpUploads() {
  const zone = $("drop-zone");
  const input = $("file-input");
  input.addEventListener("change", () => {
    uploadFiles(input.files);
    input.value = "";
  });
  zone.addEventListener("keydown", (event) => {
    if (event.key === "Enter" || event.key === " ") input.click();
  });
  for (const type of ["dragenter", "dragover"]) {
    zone.addEventListener(type, (event) => {
      event.preventDefault();
      zone.classList.add("over");
    });
  }
  zone.addEventListener("dragleave", () => zone.classList.remove("over"));
  zone.addEventListener("drop", (event) => {
    event.preventDefault();
    zone.classList.remove("over");
    uploadFiles(event.dataTransfer.files);
  });
}

// -- one mesh on screen -----------------------------------------------------------------

function currentId() {
  const match = /^#mesh=([\w-]+)$/.exec(location.hash);
  return match ? match[1] : null;
}

function select(id, { auto = false } = {}) {
  if (!auto) autoPick = false;
  if (currentId() === id) {
    if (!view || view.id !== id) load(serverSource(id));
    return;
  }
  location.hash = `mesh=${id}`; // hashchange loads it
}

/** A mesh on the server: polled until built, its base level and /splits from it. */
function serverSource(id) {
  return {
    id,
    async open(signal) {
      // The base mesh is asked for beside the metadata (a count of 1 is served as the
      // base's, min_vertices): a mesh opened from a link or the list is ready, and its
      // base then comes a round trip sooner (on a loaded two-core machine, 60-100 ms).
      // Its answer is dropped if the mesh is still building.
      let early = fetch(lodUrl(id, 1), { signal }).catch(() => null);
      let info = await getMesh(id);
      while (info.status === "queued" || info.status === "building") {
        early = drop(early);
        showMessage(`${info.name} is ${info.status} (${Math.round(100 * info.progress)}%)…`);
        await sleep(BUILD_POLL_MS, signal);
        info = await getMesh(id);
      }
      if (info.status === "failed") {
        drop(early);
        throw new Error(`${info.name} could not be built: ${info.error}`);
      }
      showMessage(`loading ${info.name}…`);
      let response = await early;
      if (!response?.ok) {
        drop(response);
        response = await fetch(lodUrl(id, info.min_vertices), { signal });
      }
      if (!response.ok) throw await problemError(response);
      const bytes = new Uint8Array(await response.arrayBuffer());
      const error = Number(response.headers.get("X-Lod-Error"));
      return { info, base: decodeBaseMesh(bytes), baseData: bytes, baseError: error };
    },
    stream: (levels, frames, options) =>
      streamSplits(splitsUrl(id, levels.received, levels.nFull), frames, options),
    levelError: (n) => lodError(id, n),
  };
}

/** Let go of a response not read (or of a promise of one): its body is cancelled, so
 * that its connection is free for the next request. Returns null. */
function drop(response) {
  Promise.resolve(response)
    .then((answer) => answer?.body?.cancel())
    .catch(() => {});
  return null;
}

/** A static export: its manifest, frame index and base mesh, its stream by Range. */
function exportSource(src) {
  let opened = null;
  return {
    id: src,
    async open(signal) {
      showMessage(`loading ${src}…`);
      opened = await openExport(src, { signal });
      const { manifest } = opened;
      const info = {
        name: manifest.name,
        vertices: manifest.vertices,
        faces: manifest.faces,
        min_vertices: manifest.minVertices,
      };
      return { info, base: opened.base, baseData: opened.baseData, baseError: undefined };
    },
    stream: (levels, frames, options) => streamExport(opened, frames, options),
    levelError: null, // the export holds no error curve
  };
}

async function load(source) {
  view?.abort.abort();
  view?.decoding?.close();
  const abort = new AbortController();
  const signal = abort.signal;
  const id = source.id;
  view = {
    id,
    source,
    abort,
    info: null,
    levels: null,
    decoding: null, // the WorkerDecoder of its stream: made at once, given the mesh with its base
    want: Infinity, // the slider's count; Infinity follows the stream to the full mesh
    baseBytes: 0,
    splitBytes: 0,
    streaming: false,
    started: performance.now(),
    baseShownMs: null,
    fullShownMs: null,
    fullPolishedMs: null, // a software GL's full mesh drawn again multisampled (scene.js)
    streamedMs: null, // every frame received and stored
    errors: new Map(), // level -> quadric error, from X-Lod-Error
    errorTimer: null,
    statsTimer: null, // the HUD's next update while streaming (updateStatsSoon)
    failure: null,
  };
  const current = view;
  renderList();
  $("hud").hidden = true;
  $("controls").hidden = true;
  scene?.clear();
  try {
    current.decoding = new WorkerDecoder(); // its scripts load while the base is fetched
    const { info, base, baseData, baseError } = await source.open(signal);
    current.info = info;
    current.baseBytes = baseData.length;
    if (baseError !== undefined) current.errors.set(base.nVertices, baseError);
    // The page holds the levels; the frames are decoded in a worker (worker_decoder.js).
    const levels = new ProgressiveLevels(base, info.vertices, info.faces, { decoder: false });
    current.levels = levels;
    if (!scene) throw new Error("this browser has no WebGL: the mesh cannot be drawn");
    showMessage("");
    setUpControls(levels);
    scene.show(levels);
    $("title").textContent = info.name;
    $("hud").hidden = false;
    $("controls").hidden = false;
    updateStats();
    current.streaming = true;
    const streamStarted = performance.now();
    const decoding = current.decoding;
    decoding.start(levels, baseData, {
      wasm: await splitModule,
      onRecord: () => {
        if (current !== view) return;
        if (levels.level < current.want) levels.setLevel(current.want);
        // When the stream is due to end, at the pace it has kept so far.
        const done = levels.received - levels.nBase;
        const left = levels.nFull - levels.received;
        scene.changed(true, done > 0 ? ((performance.now() - streamStarted) * left) / done : Infinity);
        updateStatsSoon(current);
      },
    });
    try {
      await source.stream(levels, decoding, {
        signal,
        onBytes: (n) => {
          current.splitBytes = n;
          updateStatsSoon(current);
        },
      });
      await decoding.finish();
    } finally {
      decoding.close();
    }
    current.streaming = false;
    current.streamedMs = performance.now() - current.started;
    scene.changed(); // now, not after a background redraw's wait
    updateStats();
  } catch (error) {
    current.decoding?.close(); // whatever failed, its worker is done
    if (signal.aborted) return;
    current.streaming = false;
    current.failure = error.message;
    showMessage(error.message, true);
    updateStats();
  }
}

// The slider is logarithmic in the vertex count (coarse levels differ most); the number
// box beside it takes any exact count.
const SLIDER_STEPS = 10000;

function sliderToCount(levels, position) {
  if (position >= SLIDER_STEPS) return levels.nFull;
  const low = Math.log(levels.nBase);
  const high = Math.log(levels.nFull);
  return Math.round(Math.exp(low + ((high - low) * position) / SLIDER_STEPS));
}

function countToSlider(levels, n) {
  const low = Math.log(levels.nBase);
  const high = Math.log(levels.nFull);
  return high > low
    ? Math.round((SLIDER_STEPS * (Math.log(n) - low)) / (high - low))
    : SLIDER_STEPS;
}

function setUpControls(levels) {
  const slider = $("lod-slider");
  slider.min = 0;
  slider.max = SLIDER_STEPS;
  slider.value = SLIDER_STEPS;
  slider.disabled = levels.nFull === levels.nBase;
  const number = $("lod-number");
  number.min = levels.nBase;
  number.max = levels.nFull;
  number.value = levels.nFull;
}

/** Move the level to `n` vertices (as far as received); instant both ways. */
function setWant(n) {
  const levels = view?.levels;
  if (!levels || !Number.isFinite(n)) return;
  view.want = n >= levels.nFull ? Infinity : Math.max(levels.nBase, Math.round(n));
  levels.setLevel(Math.min(view.want, levels.received));
  scene.changed();
  updateStats();
}

/** The HUD's update for a change while the stream arrives: one STREAM_STATS_MS later,
 * with every change made meanwhile. */
function updateStatsSoon(current) {
  if (current.statsTimer !== null) return;
  current.statsTimer = setTimeout(() => {
    current.statsTimer = null;
    if (current === view) updateStats();
  }, STREAM_STATS_MS);
}

function updateStats() {
  const current = view;
  const levels = current?.levels;
  if (!levels) return;
  const set = (id, text, value) => {
    const node = $(id);
    node.textContent = text;
    if (value !== undefined) node.dataset.value = value;
  };
  set("stat-vertices", count(levels.level), levels.level);
  set("stat-faces", count(levels.nFaces), levels.nFaces);
  set("stat-received", `${count(levels.received)} / ${count(levels.nFull)}`, levels.received);
  const total = current.baseBytes + current.splitBytes;
  set(
    "stat-bytes",
    `${formatBytes(total)} (base ${formatBytes(current.baseBytes)} + splits ${formatBytes(current.splitBytes)})`,
    total,
  );
  const error = current.errors.get(levels.level);
  set(
    "stat-error",
    error === undefined ? "…" : error === 0 ? "0" : error.toExponential(2),
    error ?? "",
  );
  // Not while streaming: the level moves on anyway, and each lookup makes the server
  // build a level beside the stream it is sending.
  if (error === undefined && !current.streaming && current.source.levelError) {
    scheduleErrorLookup(current);
  }
  set(
    "stat-time",
    `base ${formatMs(current.baseShownMs)} · full ${current.failure ? "–" : formatMs(current.fullShownMs)}`,
  );
  const slider = $("lod-slider");
  const received = countToSlider(levels, levels.received) / SLIDER_STEPS;
  slider.style.setProperty("--received", `${(100 * received).toFixed(2)}%`);
  const shown = current.want === Infinity ? levels.nFull : current.want;
  if (document.activeElement !== slider) slider.value = countToSlider(levels, shown);
  if (document.activeElement !== $("lod-number")) $("lod-number").value = levels.level;
}

/** The split stream carries no per-level error: ask the server for the level's
 * X-Lod-Error once the level has rested a moment (see api.lodError). */
function scheduleErrorLookup(current) {
  clearTimeout(current.errorTimer);
  current.errorTimer = setTimeout(async () => {
    const n = current.levels.level;
    if (current !== view || current.errors.has(n)) return;
    try {
      const answer = await current.source.levelError(n);
      current.errors.set(answer.n, answer.error);
    } catch {
      return; // the figure stays "…"; the mesh itself is unaffected
    }
    if (current === view) updateStats();
  }, ERROR_DELAY_MS);
}

function onRendered(levels, level, polished) {
  const current = view;
  if (!current || current.levels !== levels) return;
  const elapsed = performance.now() - current.started;
  if (polished && current.fullPolishedMs == null && level === levels.nFull) {
    current.fullPolishedMs = elapsed;
  }
  let changed = false;
  if (current.baseShownMs == null) {
    current.baseShownMs = elapsed;
    changed = true;
  }
  if (current.fullShownMs == null && level === levels.nFull) {
    current.fullShownMs = elapsed;
    changed = true;
  }
  if (changed) updateStats();
}

// -- hooks for tests and benchmarks -----------------------------------------------------

async function sha256(parts) {
  const bytes = new Uint8Array(parts.reduce((n, part) => n + part.byteLength, 0));
  let at = 0;
  for (const part of parts) {
    bytes.set(new Uint8Array(part.buffer, part.byteOffset, part.byteLength), at);
    at += part.byteLength;
  }
  const digest = new Uint8Array(await crypto.subtle.digest("SHA-256", bytes));
  return Array.from(digest, (b) => b.toString(16).padStart(2, "0")).join("");
}

async function levelDigest() {
  // SHA-256 of the level's positions as uint16 LE and faces as uint32 LE: equal to the
  // digest of the server's lod(level) in the msgpack form when the refinement is exact.
  const levels = view.levels;
  const positions = Uint16Array.from(levels.positions.subarray(0, 3 * levels.level));
  return sha256([positions, levels.indices.subarray(0, 3 * levels.nFaces)]);
}

async function wedgeDigest() {
  // SHA-256 of the level's corner wedges as uint32 LE and its wedges' grid values as
  // uint16 LE: the digest of the `wedges` of the server's msgpack lod(level). Null
  // without wedges.
  const levels = view.levels;
  const wedges = levels.wedges;
  if (!wedges) return null;
  const corners = Uint32Array.from(wedges.cornerWedge.subarray(0, 3 * levels.nFaces));
  const count = wedges.wedgesAt(levels.level) * wedges.width;
  return sha256([corners, Uint16Array.from(wedges.values.subarray(0, count))]);
}

window.qemViewer = {
  get state() {
    const levels = view?.levels;
    return {
      id: view?.id ?? null,
      level: levels?.level ?? null,
      faces: levels?.nFaces ?? null,
      received: levels?.received ?? null,
      full: levels?.nFull ?? null,
      streaming: view?.streaming ?? false,
      failure: view?.failure ?? null,
      baseBytes: view?.baseBytes ?? 0,
      splitBytes: view?.splitBytes ?? 0,
      startedMs: view?.started ?? null, // performance.now() when the mesh was selected
      baseShownMs: view?.baseShownMs ?? null,
      streamedMs: view?.streamedMs ?? null,
      fullShownMs: view?.fullShownMs ?? null,
      fullPolishedMs: view?.fullPolishedMs ?? null,
      decoder: view?.decoding?.decoder ?? null, // "wasm" or "js": which decodes the frames
      attributes: levels?.wedges?.grid.names ?? [], // appearance carried by the wedges
      renderVertices: levels?.wedges?.render.count ?? null,
      textureShown: scene?.textureShown ?? false,
      softwareGL: scene?.softwareGL ?? null, // the GL draws on the CPU
      framesOffScreen: scene?.framesOffScreen ?? 0, // the mesh's frames drawn off screen (scene.js)
      framesPolished: scene?.framesPolished ?? 0, // its views at rest drawn again multisampled
      drawingOffScreen: scene?.drawing ?? false, // a frame off screen is drawn, not yet shown
      backFacesCulled: scene?.backFacesCulled ?? null, // the last frame drew front faces only
    };
  },
  /** Draw a software GL's frames off screen when they would take over `ms` (0: all). */
  drawOffScreenAbove(ms) {
    if (scene) scene.offscreenMs = ms;
  },
  setLevel: setWant,
  levelDigest,
  wedgeDigest,
};

// -- start ------------------------------------------------------------------------------

function start() {
  try {
    scene = new MeshScene($("canvas"));
    scene.onRendered = onRendered;
  } catch (error) {
    showMessage(
      `WebGL is not available in this browser (${error.message}); meshes cannot be drawn`,
      true,
    );
  }
  const slider = $("lod-slider");
  slider.addEventListener("input", () => {
    if (view?.levels) setWant(sliderToCount(view.levels, Number(slider.value)));
  });
  $("lod-number").addEventListener("change", (event) => setWant(Number(event.target.value)));
  const src = new URLSearchParams(location.search).get("src");
  if (src) {
    // A static export: no server to list meshes from or upload to.
    $("upload").hidden = true;
    $("meshes").hidden = true;
    load(exportSource(src));
    return;
  }
  setUpUploads();
  $("refresh").addEventListener("click", refreshList);
  window.addEventListener("hashchange", () => {
    const id = currentId();
    if (id && id !== view?.id) load(serverSource(id));
    renderList();
  });
  const id = currentId();
  if (id) {
    autoPick = false;
    load(serverSource(id));
  }
  refreshList();
}

start();

// A static export (`qem export`) opened with ?src=URL-of-manifest: the manifest, the frame
// index and the base mesh from any static file server, then the stored stream fetched
// by HTTP Range requests, a run of frames at a time (qem_core/static_export.py,
// docs/formats.md). No qem-lod server is involved.
//
// Nothing the host sends is trusted: the manifest, the index, the base mesh and every
// frame are checked against one another, and a host that lies is refused with a message.

import { decodeBaseMesh, decodeFrame, readFrames, STREAM_VERSION } from "./refine.js";
import { fail } from "./wire.js";

export const MANIFEST_FORMAT = "qem-lod-export";
export const MANIFEST_VERSION = 1;
const INDEX_FORMAT = "qem-split-index";
const INDEX_VERSION = 1;
const FIRST_RUN_FRAMES = 2; // the first request is small, so the mesh refines at once
const RUN_BYTES = 1 << 20; // later requests take whole frames up to about this many bytes
const RETRIES = 2; // a run whose request fails is asked again this many times

const isCount = (value) => Number.isInteger(value) && value >= 0;

async function fetchOk(url, init) {
  let response;
  try {
    response = await fetch(url, init);
  } catch (error) {
    if (init?.signal?.aborted) throw error;
    fail(`${url} cannot be fetched: ${error.message}`);
  }
  if (!response.ok) fail(`${url}: ${response.status} ${response.statusText}`);
  return response;
}

async function fetchJson(url, signal, what) {
  const response = await fetchOk(url, { signal });
  try {
    return await response.json();
  } catch {
    fail(`${what} at ${url} is not JSON`);
  }
}

/** The manifest's checked fields and the URLs of its files (relative to it). */
function readManifest(manifest, url) {
  if (manifest?.format !== MANIFEST_FORMAT) fail(`${url} is not a qem-lod export manifest`);
  if (manifest.version !== MANIFEST_VERSION) {
    fail(`export manifest version ${manifest.version}: this viewer reads ${MANIFEST_VERSION}`);
  }
  for (const key of ["vertices", "faces", "min_vertices", "stream_crc32"]) {
    if (!isCount(manifest[key])) fail(`export manifest: '${key}' is ${manifest[key]}`);
  }
  if (manifest.min_vertices > manifest.vertices) {
    fail("export manifest: min_vertices is above vertices");
  }
  const files = manifest.files ?? {};
  for (const key of ["base", "stream", "frames"]) {
    if (typeof files[key] !== "string") fail(`export manifest: no '${key}' file`);
  }
  const resolve = (name) => new URL(name, url).href;
  return {
    name: typeof manifest.name === "string" ? manifest.name : "export",
    vertices: manifest.vertices,
    faces: manifest.faces,
    minVertices: manifest.min_vertices,
    crc32: manifest.stream_crc32,
    streamBytes: manifest.bytes?.stream,
    urls: {
      base: resolve(files.base),
      stream: resolve(files.stream),
      frames: resolve(files.frames),
    },
  };
}

/** The frame index (as qem_core.stored_stream.StreamIndex.from_json checks it), checked
 * against the manifest. */
function readIndex(index, manifest) {
  if (index?.format !== INDEX_FORMAT) fail("the frame index is not a qem-lod split index");
  if (index.version !== INDEX_VERSION) fail(`frame index version ${index.version}: unknown`);
  if (index.stream_version !== STREAM_VERSION) {
    fail(`the stream's frames are version ${index.stream_version}; this viewer reads ${STREAM_VERSION}`);
  }
  const { vertices, faces, offsets } = index;
  const lists = [vertices, faces, offsets];
  if (!lists.every((list) => Array.isArray(list) && list.every(isCount))) {
    fail("frame index: vertices, faces and offsets must be lists of counts");
  }
  if (!(vertices.length >= 1 && faces.length === vertices.length && offsets.length === vertices.length)) {
    fail("frame index: its three lists differ in length");
  }
  for (let i = 1; i < vertices.length; i++) {
    if (!(vertices[i] > vertices[i - 1] && faces[i] >= faces[i - 1] && offsets[i] > offsets[i - 1])) {
      fail("frame index: its counts or offsets do not grow");
    }
  }
  const last = vertices.length - 1;
  const lies = [
    [offsets[0], 0, "the first offset"],
    [offsets[last], index.bytes, "the last offset against its length"],
    [index.bytes, manifest.streamBytes, "the stream's length against the manifest's"],
    [index.crc32, manifest.crc32, "the stream's CRC-32 against the manifest's"],
    [vertices[0], manifest.minVertices, "its first level against the manifest's min_vertices"],
    [vertices[last], manifest.vertices, "its last level against the manifest's vertices"],
    [faces[last], manifest.faces, "its last face count against the manifest's faces"],
  ];
  for (const [got, want, what] of lies) {
    if (got !== want) fail(`the export does not hold together: frame index, ${what} (${got} ≠ ${want})`);
  }
  return { vertices, faces, offsets, size: index.bytes };
}

/**
 * Open the export whose manifest is at `src` (resolved against the page): its checked
 * manifest, frame index and base mesh.
 */
export async function openExport(src, { signal } = {}) {
  const url = new URL(src, document.baseURI).href;
  const manifest = readManifest(await fetchJson(url, signal, "the manifest"), url);
  const index = readIndex(await fetchJson(manifest.urls.frames, signal, "the frame index"), manifest);
  const baseResponse = await fetchOk(manifest.urls.base, { signal });
  const baseBytes = new Uint8Array(await baseResponse.arrayBuffer());
  const base = decodeBaseMesh(baseBytes);
  if (base.nVertices !== index.vertices[0] || base.nFaces !== index.faces[0]) {
    fail(
      `the base mesh has ${base.nVertices} vertices / ${base.nFaces} faces; the export ` +
        `says ${index.vertices[0]} / ${index.faces[0]}`,
    );
  }
  return { url, manifest, index, base, baseData: baseBytes };
}

/** Runs of frames [i, j): the first small, the next up to about RUN_BYTES each. */
function frameRuns(index) {
  const runs = [];
  const frames = index.vertices.length - 1;
  let i = 0;
  while (i < frames) {
    let j = Math.min(frames, i + (i === 0 ? FIRST_RUN_FRAMES : 1));
    while (i > 0 && j < frames && index.offsets[j + 1] - index.offsets[i] <= RUN_BYTES) j++;
    runs.push([i, j]);
    i = j;
  }
  return runs;
}

/**
 * Stream the export's frames into `frames` (ProgressiveLevels, or a WorkerDecoder: anything
 * with addFrame) by Range requests, checking each frame against
 * the index. A host that ignores Range (a 200 with the whole file) is read to the end in
 * one go. onFrame(bytesSoFar) after each frame, onBytes(bytesSoFar) after each chunk.
 */
export async function streamExport(opened, frames, { onFrame, onBytes, signal } = {}) {
  const { index, manifest } = opened;
  let bytes = 0;
  let frame = 0; // the next frame expected, by its index number
  const take = (payload) => {
    const decoded = decodeFrame(payload);
    if (frame >= index.vertices.length - 1) fail("the stream holds more frames than its index");
    const [from, to] = [index.vertices[frame], index.vertices[frame + 1]];
    if (decoded.nFrom !== from || decoded.nTo !== to) {
      fail(
        `the stream's frame ${frame} refines ${decoded.nFrom}→${decoded.nTo} vertices; ` +
          `its index says ${from}→${to}`,
      );
    }
    frames.addFrame(decoded);
    frame++;
    onFrame?.(bytes);
  };
  const read = (response) =>
    readFrames(response, {
      onChunk: (n) => {
        bytes += n; // counted without onBytes too: onFrame and the result tell it
        onBytes?.(bytes);
      },
      onPayload: take,
    });
  for (const [, j] of frameRuns(index)) {
    let attempts = 0;
    while (frame < j) {
      // From the frame reached: a run cut off by the network resumes where it stopped.
      const start = index.offsets[frame];
      const stop = index.offsets[j];
      let response;
      try {
        response = await fetch(manifest.urls.stream, {
          signal,
          headers: { Range: `bytes=${start}-${stop - 1}` },
        });
        if (!response.ok) fail(`${manifest.urls.stream}: ${response.status} ${response.statusText}`);
        if (response.status === 200) {
          if (start !== 0) fail("the host stopped answering Range requests");
          await read(response); // the whole stream in one answer
          if (frame !== index.vertices.length - 1) fail("the stream ends before its index does");
          return bytes;
        }
        const range = /^bytes (\d+)-(\d+)\/(\d+|\*)$/.exec(response.headers.get("Content-Range") ?? "");
        if (!range || Number(range[1]) !== start || Number(range[2]) !== stop - 1) {
          fail(`the host answered bytes ${start}-${stop - 1} with '${response.headers.get("Content-Range")}'`);
        }
        if (range[3] !== "*" && Number(range[3]) !== index.size) {
          fail(`the stream on the host has ${range[3]} bytes; its index says ${index.size}`);
        }
        await read(response);
        if (frame !== j) fail(`bytes ${start}-${stop - 1} do not hold the frames their index says`);
      } catch (error) {
        // The network broke off (fetch and reads reject with a TypeError): ask again from
        // the frame reached. A host that lies (WireFormatError) is not asked again.
        if (error.name !== "TypeError" || signal?.aborted || ++attempts > RETRIES) throw error;
      }
    }
  }
  return bytes;
}

// The qem-lod HTTP API, version 1, as the viewer uses it (same origin as the page).

import { problemError } from "./refine.js";

const API = new URL("v1/meshes", document.baseURI).pathname;

async function json(url, init) {
  const response = await fetch(url, init);
  if (!response.ok) throw await problemError(response);
  return response.json();
}

export const listMeshes = async () => (await json(API)).meshes;

export const getMesh = (id) => json(`${API}/${encodeURIComponent(id)}`);

export const lodUrl = (id, n, format = "msgpack") =>
  `${API}/${encodeURIComponent(id)}/lod?vertices=${n}&format=${format}`;

export const splitsUrl = (id, from, to) =>
  `${API}/${encodeURIComponent(id)}/splits?from=${from}&to=${to}`;

/** The quadric error of level n, from the X-Lod-Error header of its lod response; the
 * body is not read (the API has no HEAD and the split stream carries no error). */
export async function lodError(id, n) {
  const response = await fetch(lodUrl(id, n));
  response.body?.cancel().catch(() => {});
  if (!response.ok) throw new Error(`${response.status} ${response.statusText}`);
  return {
    n: Number(response.headers.get("X-Lod-Vertices")),
    error: Number(response.headers.get("X-Lod-Error")),
  };
}

/**
 * POST the file as the multipart field `file`; onProgress(sent, total) as it goes.
 * XMLHttpRequest, because fetch reports no upload progress. Resolves to {id, url}.
 */
export function uploadMesh(file, { token, onProgress } = {}) {
  return new Promise((resolve, reject) => {
    const request = new XMLHttpRequest();
    request.open("POST", API);
    if (token) request.setRequestHeader("Authorization", `Bearer ${token}`);
    request.upload.onprogress = (event) => onProgress?.(event.loaded, event.total);
    request.onerror = () => reject(new Error("the server cannot be reached"));
    request.onload = () => {
      let body = null;
      try {
        body = JSON.parse(request.responseText);
      } catch {
        // not JSON
      }
      if (request.status === 202 && body?.id) return resolve(body);
      const error = new Error(body?.detail || `${request.status} ${request.statusText}`);
      error.status = request.status;
      error.problem = body;
      reject(error);
    };
    const form = new FormData();
    form.append("file", file, file.name);
    request.send(form);
  });
}

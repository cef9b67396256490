// Several files dropped at once (an OBJ with its .mtl and images) go to the server as one
// zip archive, which the server reads as a model with the files it names
// (qem_core/codecs/archive.py). Stored, not deflated: the images are compressed already,
// and the page should not spend its time compressing text the network compresses anyway.

import { crc32 } from "./refine.js";

const encoder = new TextEncoder();

/** A zip archive (Blob) of `files`, each {name, bytes: Uint8Array}, stored flat. */
export function zipFiles(files) {
  const parts = [];
  const central = [];
  let offset = 0;
  for (const { name, bytes } of files) {
    const nameBytes = encoder.encode(name);
    const crc = crc32(bytes);
    // Bit 11 of the flags: the name is UTF-8.
    const local = header(0x04034b50, [[20, 2], [0x0800, 2], [0, 2], [0, 2], [0x21, 2],
      [crc, 4], [bytes.length, 4], [bytes.length, 4], [nameBytes.length, 2], [0, 2]]);
    parts.push(local, nameBytes, bytes);
    central.push(header(0x02014b50, [[20, 2], [20, 2], [0x0800, 2], [0, 2], [0, 2], [0x21, 2],
      [crc, 4], [bytes.length, 4], [bytes.length, 4], [nameBytes.length, 2], [0, 2], [0, 2],
      [0, 2], [0, 2], [0, 4], [offset, 4]]), nameBytes);
    offset += local.length + nameBytes.length + bytes.length;
  }
  const size = central.reduce((n, part) => n + part.length, 0);
  const end = header(0x06054b50, [[0, 2], [0, 2], [files.length, 2], [files.length, 2],
    [size, 4], [offset, 4], [0, 2]]);
  return new Blob([...parts, ...central, end], { type: "application/zip" });
}

function header(signature, fields) {
  const out = new Uint8Array(4 + fields.reduce((n, [, width]) => n + width, 0));
  const view = new DataView(out.buffer);
  view.setUint32(0, signature, true);
  let at = 4;
  for (const [value, width] of fields) {
    if (width === 2) view.setUint16(at, value, true);
    else view.setUint32(at, value >>> 0, true);
    at += width;
  }
  return out;
}

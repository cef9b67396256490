"""Static export: a progressive mesh as files any static host or CDN can serve, which the
web viewer opens with ``?src=URL-of-manifest`` and refines by HTTP Range requests, with no
qem-lod server involved (the way Nexus and 3D Tiles are deployed).

    manifest.json    what the files are (MANIFEST_FORMAT, below)
    base.msgpack     the base mesh, msgpack on the stream's grid (as /lod?format=msgpack)
    stream.qsplits   the stored split stream, base to full, every frame a key frame
    frames.json      its frame index (`qem_core.stored_stream.StreamIndex`)
    texture.png|jpg  the texture image, when the mesh has one (also inside base.msgpack)

The manifest (JSON): ``{"format": "qem-lod-export", "version": 1, "name", "vertices",
"faces", "min_vertices", "bbox": [[x, y, z], [x, y, z]], "files": {"base", "stream",
"frames", "texture" (or null)}, "bytes": {"base", "stream"}, "stream_crc32"}``; file
names are relative to the manifest. docs/formats.md gives the details.
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from .codecs._images import IMAGE_SUFFIXES
from .levels import encode_level
from .progressive import ProgressiveMesh
from .stored_stream import StreamIndex, encode_stored_stream

__all__ = [
    "MANIFEST_FORMAT",
    "MANIFEST_VERSION",
    "ExportParts",
    "export_parts",
    "write_export",
]

MANIFEST_FORMAT = "qem-lod-export"
MANIFEST_VERSION = 1


@dataclass(frozen=True)
class ExportParts:
    """What an export holds, from a local .qpm (`export_parts`) or fetched from a server."""

    name: str
    n_full: int
    n_faces_full: int
    n_base: int
    bbox: list[list[float]]
    base: bytes
    stream: bytes
    index: StreamIndex
    texture: bytes | None = None
    texture_type: str | None = None


def export_parts(pm: ProgressiveMesh, name: str) -> ExportParts:
    """The parts of ``pm``'s export: its base level, its stored stream and index."""
    stream, index = encode_stored_stream(pm)
    return ExportParts(
        name=name,
        n_full=pm.n_full,
        n_faces_full=pm.n_faces_full,
        n_base=pm.n_base,
        bbox=[[float(x) for x in corner] for corner in pm.bbox],
        base=encode_level(pm, pm.n_base, "msgpack").content,
        stream=stream,
        index=index,
        texture=pm.texture,
        texture_type=pm.texture_type,
    )


def write_export(parts: ExportParts, directory: Path) -> Path:
    """Write the export's files into ``directory`` (created); returns the manifest."""
    parts.index.check(parts.stream)
    directory.mkdir(parents=True, exist_ok=True)
    files = {"base": "base.msgpack", "stream": "stream.qsplits", "frames": "frames.json"}
    contents = {"base": parts.base, "stream": parts.stream, "frames": parts.index.to_json()}
    texture_name = None
    if parts.texture is not None:
        suffix = IMAGE_SUFFIXES.get(parts.texture_type or "", ".bin")
        texture_name = "texture" + suffix
        contents["texture"] = parts.texture
        files["texture"] = texture_name
    for key, content in contents.items():
        (directory / files[key]).write_bytes(content)
    manifest = {
        "format": MANIFEST_FORMAT,
        "version": MANIFEST_VERSION,
        "name": parts.name,
        "vertices": parts.n_full,
        "faces": parts.n_faces_full,
        "min_vertices": parts.n_base,
        "bbox": parts.bbox,
        "files": {**files, "texture": texture_name},
        "bytes": {"base": len(parts.base), "stream": len(parts.stream)},
        "stream_crc32": parts.index.crc32,
    }
    path = directory / "manifest.json"
    path.write_text(json.dumps(manifest, indent=1) + "\n")
    return path

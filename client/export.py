"""``qem export SOURCE DIR``: a static export of a mesh (`qem_core.static_export`), from
a server (SOURCE a mesh id) or from a local .qpm file, with the web viewer beside it.

    qem export 0123456789abcdef site/dragon     # from the server (--server, $QEM_SERVER)
    qem export dragon.qpm site/dragon           # no server involved
    python -m http.server -d site               # then open
        http://127.0.0.1:8000/dragon/index.html?src=manifest.json

The viewer's files (index.html, viewer.css, js/ and the two npm packages it imports) are
copied next to the data unless ``--no-viewer``: the folder is then a whole static site.
From a server, the frame index is read off the stream's own frames (every frame checked
against its CRC and against the one before), so what is written is what was served.
"""

from __future__ import annotations

import argparse
import shutil
import zlib
from pathlib import Path

from .console import EXIT_OK, EXIT_USAGE, CliError, note, print_json, reading
from .viewer_files import VIEWER_FILES, VIEWER_PACKAGES

__all__ = ["add_export", "copy_viewer"]

WEB_DIR = Path(__file__).resolve().parent / "web"


def add_export(subparsers: argparse._SubParsersAction, remote_parent) -> None:
    parser = subparsers.add_parser(
        "export",
        parents=[remote_parent()],
        help="write a static export (base, stream, frame index, manifest, viewer)",
    )
    parser.add_argument("source", help="a mesh id on the server, or a local .qpm file")
    parser.add_argument("directory", type=Path, help="folder to write (created)")
    parser.add_argument(
        "--no-viewer", action="store_true", help="write the data only, not the viewer's files"
    )
    parser.set_defaults(run=cmd_export)


def cmd_export(args: argparse.Namespace) -> int:
    from qem_core.static_export import export_parts, write_export

    source = Path(args.source)
    if source.is_file():
        import qem_core

        with reading(args.source):
            pm = qem_core.load(source)
        parts = export_parts(pm, pm.metadata.get("name") or source.stem)
    else:
        from .cli import _client

        with _client(args) as qem:
            parts = _parts_from_server(qem, args.source)
    if args.directory.exists() and not args.directory.is_dir():
        raise CliError(f"{args.directory} exists and is not a folder", EXIT_USAGE)
    manifest = write_export(parts, args.directory)
    viewer = not args.no_viewer and copy_viewer(args.directory)
    summary = {
        "manifest": str(manifest),
        "vertices": parts.n_full,
        "min_vertices": parts.n_base,
        "frames": parts.index.n_frames,
        "bytes": len(parts.base) + len(parts.stream),
        "viewer": bool(viewer),
    }
    if args.json:
        print_json(summary)
    else:
        where = "index.html?src=manifest.json" if viewer else "a viewer with ?src=manifest.json"
        note(
            f"wrote {args.directory}: {parts.n_base}-{parts.n_full} vertices, "
            f"{parts.index.n_frames} frames, {summary['bytes']:,} bytes; serve the folder "
            f"and open {where}"
        )
    return EXIT_OK


def _parts_from_server(qem, mesh_id: str):
    from qem_core.static_export import ExportParts
    from qem_core.stored_stream import StreamIndex, index_stream

    from .http import QemClientError, QemHTTPError

    info = qem.info(mesh_id)
    if info["status"] != "ready":
        raise QemClientError(f"mesh {mesh_id} is {info['status']}, not ready: nothing to export")
    base = qem.lod(mesh_id, info["min_vertices"], "msgpack")
    stream = b"".join(_whole_stream(qem, mesh_id))
    if stream:
        index = index_stream(stream)
    else:  # a mesh whose base is its full mesh
        index = StreamIndex((info["vertices"],), (info["faces"],), (0,), zlib.crc32(b""))
    if (index.vertices[0], index.vertices[-1]) != (info["min_vertices"], info["vertices"]):
        raise QemClientError(
            f"the stream of mesh {mesh_id} refines {index.vertices[0]}..{index.vertices[-1]} "
            f"vertices, its record says {info['min_vertices']}..{info['vertices']}"
        )
    try:
        texture_type, texture = qem.texture(mesh_id)
    except QemHTTPError as exc:
        if exc.status != 404:
            raise
        texture_type, texture = None, None
    bbox = info.get("bbox") or [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    return ExportParts(
        name=info["name"],
        n_full=info["vertices"],
        n_faces_full=info["faces"],
        n_base=info["min_vertices"],
        bbox=[list(map(float, bbox[0])), list(map(float, bbox[1]))],
        base=base,
        stream=stream,
        index=index,
        texture=texture,
        texture_type=texture_type,
    )


def _whole_stream(qem, mesh_id: str):
    """The stored stream's bytes as served (each frame with its length prefix)."""
    import struct

    for payload in qem.splits(mesh_id):
        yield struct.pack("<I", len(payload)) + payload


def copy_viewer(directory: Path) -> bool:
    """Copy the web viewer into ``directory``; False (and a note) when its npm packages
    are not installed (``make install`` runs ``npm ci``)."""
    modules = WEB_DIR / "node_modules"
    missing = [name for name in VIEWER_PACKAGES if not (modules / name).exists()]
    if missing:
        note(
            f"the viewer's packages are not installed ({', '.join(missing)}); wrote the data "
            "only (run make install, or npm ci in client/web, then export again)"
        )
        return False
    for pattern in VIEWER_FILES:
        for source in WEB_DIR.glob(pattern):
            target = directory / source.relative_to(WEB_DIR)
            target.parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, target)
    for name in VIEWER_PACKAGES:
        source, target = modules / name, directory / "node_modules" / name
        target.parent.mkdir(parents=True, exist_ok=True)
        if source.is_dir():
            shutil.copytree(source, target, dirs_exist_ok=True)
        else:
            shutil.copy2(source, target)
    return True

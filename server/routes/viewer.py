"""``/``: the web viewer from ``client/web`` when it is there, else a plain list of meshes.

The viewer is served as static files; the server does not import anything from client/.
"""

from __future__ import annotations

import html
from pathlib import Path

from fastapi import APIRouter, FastAPI
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

from ..deps import StorageDep

__all__ = ["DEFAULT_WEB_DIR", "mount_viewer"]

# client/web next to the server package, in a source tree and in an installed wheel alike.
DEFAULT_WEB_DIR = Path(__file__).resolve().parents[2] / "client" / "web"

_fallback = APIRouter(include_in_schema=False)


@_fallback.get("/", response_class=HTMLResponse)
def mesh_list_page(storage: StorageDep) -> str:
    rows = []
    for record in storage.metadata.records():
        mesh_id = html.escape(record.id)
        links = ""
        if record.status == "ready":
            links = " ".join(
                f'<a href="/v1/meshes/{mesh_id}/lod?format={fmt}">{fmt}</a>'
                for fmt in ("ply", "obj", "glb")
            )
        rows.append(
            f'<tr><td><a href="/v1/meshes/{mesh_id}">{html.escape(record.name)}</a></td>'
            f"<td>{html.escape(record.status)}</td><td>{record.n_vertices or ''}</td>"
            f"<td>{record.n_faces or ''}</td><td>{links}</td></tr>"
        )
    body = "\n".join(rows) or '<tr><td colspan="5">no meshes yet</td></tr>'
    return (
        '<!doctype html><html><head><meta charset="utf-8"><title>qem-lod</title></head>'
        "<body><h1>qem-lod</h1><p>The web viewer is not installed; meshes on this server "
        '(API documentation at <a href="/docs">/docs</a>):</p>'
        "<table><tr><th>name</th><th>status</th><th>vertices</th><th>faces</th>"
        f"<th>full mesh</th></tr>\n{body}\n</table></body></html>"
    )


def mount_viewer(app: FastAPI, web_dir: Path | None) -> None:
    """Serve `web_dir` (default `DEFAULT_WEB_DIR`) at ``/``; call after the API routes,
    since the mount answers every path they do not."""
    web_dir = web_dir or DEFAULT_WEB_DIR
    if (web_dir / "index.html").is_file():
        app.mount("/", StaticFiles(directory=web_dir, html=True), name="viewer")
    else:
        app.include_router(_fallback)

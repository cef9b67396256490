"""Zip archives through the real server and the CLI: an OBJ with its .mtl and image
builds textured; hostile archives fail their build with the reason, nothing written
outside the data directory."""

from __future__ import annotations

import io
import re
import stat
import subprocess
import sys
import zipfile
from pathlib import Path

import httpx
import pytest

import qem_core
from client.http import QemBuildFailed

REPO = Path(__file__).resolve().parents[2]
SPOT = REPO / "server" / "demo" / "spot.obj"
PROBLEM = "application/problem+json"


def _zip(members: dict[str, bytes], links: tuple[str, ...] = ()) -> bytes:
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            info = zipfile.ZipInfo(name)
            info.compress_type = zipfile.ZIP_DEFLATED
            if name in links:
                info.external_attr = (stat.S_IFLNK | 0o777) << 16
            archive.writestr(info, data)
    return out.getvalue()


@pytest.fixture(scope="module")
def spot_image() -> bytes:
    return qem_core.load_mesh(SPOT.with_suffix(".glb")).texture


@pytest.fixture(scope="module")
def spot_zip(spot_image) -> bytes:
    """Spot as photogrammetry tools export: OBJ + MTL + PNG, in a folder of the zip."""
    return _zip({
        "spot/spot.obj": b"mtllib spot.mtl\nusemtl spot\n" + SPOT.read_bytes(),
        "spot/spot.mtl": b"newmtl spot\nKd 1 1 1\nmap_Kd textures/spot.png\n",
        "spot/textures/spot.png": spot_image,
    })  # fmt: skip


@pytest.fixture(scope="module")
def http(server):
    with httpx.Client(base_url=server.url, timeout=60) as client:
        yield client


def test_an_obj_with_its_mtl_and_image_in_a_zip_builds_textured(server, http, spot_zip,
                                                                 spot_image, tmp_path):  # fmt: skip
    path = tmp_path / "spot.zip"
    path.write_bytes(spot_zip)
    with server.client() as qem:
        info = qem.wait_ready(qem.upload(path), timeout=300)
    assert info["name"] == "spot.zip" and info["vertices"] == 2930
    level = http.get(f"/v1/meshes/{info['id']}/lod", params={"vertices": 500, "format": "glb"})
    assert level.status_code == 200
    mesh = qem_core.load_mesh(level.content, format="glb")
    assert mesh.n_vertices == 500 and mesh.texture == spot_image
    assert http.get(f"/v1/meshes/{info['id']}/texture").content == spot_image
    # The OBJ level with its .mtl and image, in one download.
    level = http.get(f"/v1/meshes/{info['id']}/lod", params={"vertices": 500, "format": "zip"})
    assert level.headers["content-type"] == "application/zip"
    assert sorted(zipfile.ZipFile(io.BytesIO(level.content)).namelist()) == [
        "mesh.mtl", "mesh.obj", "mesh_texture.png"
    ]  # fmt: skip
    mesh = qem_core.load_mesh(level.content)
    assert mesh.n_vertices == 500 and mesh.texture == spot_image


def test_an_obj_with_a_webp_image_builds_textured_in_webp(server, http, spot_image, tmp_path):
    """A WebP map_Kd (issue #33): kept as WebP, served as image/webp, in GLB levels
    through EXT_texture_webp and in the OBJ zip beside the .mtl."""
    image = pytest.importorskip("PIL.Image", reason="Pillow is not installed")
    out = io.BytesIO()
    image.open(io.BytesIO(spot_image)).save(out, "WEBP", quality=80)
    webp = out.getvalue()
    path = tmp_path / "spot-webp.zip"
    path.write_bytes(_zip({
        "spot.obj": b"mtllib spot.mtl\nusemtl spot\n" + SPOT.read_bytes(),
        "spot.mtl": b"newmtl spot\nKd 1 1 1\nmap_Kd spot.webp\n",
        "spot.webp": webp,
    }))  # fmt: skip
    with server.client() as qem:
        info = qem.wait_ready(qem.upload(path), timeout=300)
    texture = http.get(f"/v1/meshes/{info['id']}/texture")
    assert texture.headers["content-type"] == "image/webp" and texture.content == webp
    level = http.get(f"/v1/meshes/{info['id']}/lod", params={"vertices": 500, "format": "glb"})
    assert b"EXT_texture_webp" in level.content[:4096]
    assert qem_core.load_mesh(level.content, format="glb").texture == webp
    level = http.get(f"/v1/meshes/{info['id']}/lod", params={"vertices": 500, "format": "zip"})
    assert "mesh_texture.webp" in zipfile.ZipFile(io.BytesIO(level.content)).namelist()


def test_the_cli_uploads_a_zip(server, spot_zip, tmp_path):
    (tmp_path / "spot.zip").write_bytes(spot_zip)
    done = subprocess.run(
        [sys.executable, "-m", "client.cli", "upload", "spot.zip", "--server", server.url],
        cwd=tmp_path, env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"},
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr


def _bomb() -> bytes:
    return _zip({"a.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n", "pad.png": b"\0" * (64 << 20)})


HOSTILE = [
    ("parent path", lambda: _zip({"../evil.obj": b"v 0 0 0\n"}), "outside the archive"),
    ("absolute path", lambda: _zip({"/tmp/evil.obj": b"v 0 0 0\n"}), "outside the archive"),
    ("link", lambda: _zip({"a.obj": b"v 0 0 0\n", "b.png": b"/etc/passwd"}, links=("b.png",)),
     "link"),
    ("zip bomb", _bomb, "zip bomb"),
    ("no model", lambda: _zip({"readme.txt": b"hello", "t.png": b"x"}),
     "no model file.*readme.txt, t.png"),
    ("two models", lambda: _zip({"a.obj": b"v 0 0 0\n", "b.ply": b"ply\n"}),
     "2 model files.*a.obj, b.ply"),
    ("not a zip", lambda: b"PK\x03\x04 but nothing after", "not a readable zip"),
]  # fmt: skip


@pytest.mark.parametrize(("case", "make", "words"), HOSTILE, ids=[c[0] for c in HOSTILE])
def test_a_hostile_archive_fails_its_build_with_the_reason(server, http, case, make, words):
    """Checked by the build before any member is read (the upload itself is bytes the
    API takes, as its OpenAPI document says); nothing is written outside the data
    directory, nothing extracted at all."""
    accepted = http.post("/v1/meshes", params={"name": "upload.zip"}, content=make())
    assert accepted.status_code == 202, accepted.text
    with server.client() as qem, pytest.raises(QemBuildFailed) as failed:
        qem.wait_ready(accepted.json()["id"], timeout=120)
    assert re.search(words, failed.value.info["error"]), failed.value.info
    problem = http.get(f"{accepted.json()['url']}/lod")
    assert problem.status_code == 409 and problem.headers["content-type"] == PROBLEM
    assert not list(server.data_dir.parent.rglob("evil.obj"))
    assert http.delete(accepted.json()["url"]).status_code == 204


def test_files_dropped_together_on_the_viewer_upload_as_one_zip(server, http, spot_image,
                                                                tmp_path):  # fmt: skip
    """An OBJ, its .mtl and its image picked at once in the page: packed into spot.zip
    by the page (client/web/js/zip.js), built textured, shown with its texture."""
    from .test_viewer import READY_TIMEOUT_MS, chromium_page, require_web_packages

    require_web_packages()
    (tmp_path / "spot.obj").write_bytes(b"mtllib spot.mtl\nusemtl spot\n" + SPOT.read_bytes())
    (tmp_path / "spot.mtl").write_text("newmtl spot\nmap_Kd spot_texture.png\n")
    (tmp_path / "spot_texture.png").write_bytes(spot_image)
    with chromium_page(tmp_path / "profile") as page:
        page.goto(f"{server.url}/")
        page.set_input_files(
            "#file-input", [str(tmp_path / name) for name in ("spot.obj", "spot.mtl",
                                                              "spot_texture.png")]
        )  # fmt: skip
        page.wait_for_function(
            "() => { const s = window.qemViewer?.state;"
            " return s?.level !== null && s.level === s.full && s.textureShown; }",
            timeout=READY_TIMEOUT_MS,
        )
        state = page.evaluate("window.qemViewer.state")
        assert state["attributes"] == ["uv"] and state["failure"] is None
        info = http.get(f"/v1/meshes/{state['id']}").json()
        assert info["name"] == "spot.zip" and info["vertices"] == 2930
        assert http.get(f"/v1/meshes/{state['id']}/texture").content == spot_image
        assert page.errors == []


def test_a_gltf_with_its_bin_and_image_in_a_zip_builds_textured(server, http, tmp_path):
    from tests.unit.test_gltf import spot_gltf

    files = spot_gltf(external=True)
    image = files.pop("_image")
    path = tmp_path / "spot-gltf.zip"
    path.write_bytes(_zip(files))
    with server.client() as qem:
        info = qem.wait_ready(qem.upload(path), timeout=300)
    assert info["vertices"] == 2930
    assert http.get(f"/v1/meshes/{info['id']}/texture").content == image

"""The ``qem`` commands against a real server (``qem serve`` on 127.0.0.1), run as a
user runs them: a subprocess, stdout for results, stderr for messages, exit statuses.

The HTTP API itself is covered by test_service.py and test_bad_inputs.py; here only what
the command adds: ids and tables on stdout, ``--json``, exact counts in the files it
writes, and clear messages with the documented exit statuses (1 refused, 2 usage,
3 unreachable) for a bad URL, a bad token and an unknown id.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import httpx
import numpy as np
import pytest

import qem_core
from tests.tiny_meshes import icosphere

REPO = Path(__file__).resolve().parents[2]
TOKEN = "cli-e2e-token-0123456789"


def qem(*args: str, cwd: Path, server: str | None = None, token: str | None = None):
    """``python -m client.cli ARGS``; `server` and `token` go through $QEM_SERVER and
    $QEM_TOKEN, as a shell user sets them."""
    env = {"PYTHONPATH": str(REPO), "PATH": os.environ.get("PATH", "/usr/bin:/bin")}
    if server is not None:
        env["QEM_SERVER"] = server
    if token is not None:
        env["QEM_TOKEN"] = token
    return subprocess.run(
        [sys.executable, "-m", "client.cli", *args],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def assert_clean_failure(result: subprocess.CompletedProcess[str], status: int, *words: str):
    assert result.returncode == status, (result.returncode, result.stdout, result.stderr)
    assert "Traceback" not in result.stderr
    for word in words:
        assert word in result.stderr, result.stderr


@pytest.fixture(scope="module")
def workdir(tmp_path_factory) -> Path:
    """A folder holding sphere.ply (642 vertices)."""
    folder = tmp_path_factory.mktemp("cli-remote")
    vertices, faces = icosphere(3, jitter=0.05, seed=5)
    (folder / "sphere.ply").write_bytes(qem_core.encode_mesh(vertices, faces, "ply"))
    return folder


@pytest.fixture(scope="module")
def uploaded(server, workdir) -> str:
    """The id printed by ``qem upload`` (which waits until the mesh is ready)."""
    result = qem("upload", "sphere.ply", cwd=workdir, server=server.url)
    assert result.returncode == 0, result.stderr
    mesh_id = result.stdout.strip()
    assert len(mesh_id.split()) == 1 and mesh_id in result.stderr  # "uploaded ... as ID"
    assert "ready:" in result.stderr
    return mesh_id


def test_upload_prints_the_id_of_a_ready_mesh(server, uploaded):
    with server.client() as client:
        info = client.info(uploaded)
    assert (info["status"], info["name"], info["vertices"]) == ("ready", "sphere.ply", 642)


@pytest.mark.parametrize(("n", "suffix"), [(100, ".ply"), (300, ".obj"), (642, ".glb")])
def test_get_writes_exactly_n_vertices(server, workdir, uploaded, n, suffix):
    output = f"get-{n}{suffix}"
    result = qem(
        "get", uploaded, "-n", str(n), "-o", output, "--json", cwd=workdir, server=server.url
    )
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    mesh = qem_core.load_mesh(workdir / output)
    assert summary["vertices"] == mesh.n_vertices == n
    assert summary["faces"] == mesh.n_faces
    with server.client() as client:
        served = qem_core.load_mesh(client.lod(uploaded, n, "ply"), format="ply")
    assert np.array_equal(mesh.faces, served.faces)


def test_get_reports_the_served_count_when_clamped(server, workdir, uploaded):
    result = qem("get", uploaded, "-n", "100000", "-o", "full.ply", cwd=workdir, server=server.url)
    assert result.returncode == 0, result.stderr
    assert "642 vertices (asked 100000)" in result.stderr
    assert qem_core.load_mesh(workdir / "full.ply").n_vertices == 642


def test_ls_shows_the_mesh(server, workdir, uploaded):
    table = qem("ls", cwd=workdir, server=server.url)
    assert table.returncode == 0, table.stderr
    header, *rows = table.stdout.splitlines()
    assert header.split()[:2] == ["ID", "STATUS"]
    row = next(row.split() for row in rows if row.startswith(uploaded))
    assert row[1:3] == ["ready", "642"] and row[-1] == "sphere.ply"

    listed = qem("ls", "--json", cwd=workdir, server=server.url)
    assert listed.returncode == 0, listed.stderr
    meshes = {mesh["id"]: mesh for mesh in json.loads(listed.stdout)}
    assert meshes[uploaded]["status"] == "ready"


def test_rm_deletes(server, workdir):
    upload = qem("upload", "sphere.ply", "--no-wait", "--json", cwd=workdir, server=server.url)
    assert upload.returncode == 0, upload.stderr
    mesh_id = json.loads(upload.stdout)["id"]

    removed = qem("rm", mesh_id, "--json", cwd=workdir, server=server.url)
    assert removed.returncode == 0, removed.stderr
    assert json.loads(removed.stdout) == {"deleted": [mesh_id]}
    listed = qem("ls", "--json", cwd=workdir, server=server.url)
    assert mesh_id not in {mesh["id"] for mesh in json.loads(listed.stdout)}

    again = qem("rm", mesh_id, cwd=workdir, server=server.url)
    assert_clean_failure(again, 1, "No such mesh (404)", mesh_id)


@pytest.mark.parametrize(
    ("args", "words"),
    [
        (["get", "0123456789abcdef", "-n", "10", "-o", "x.ply"], ["No such mesh (404)"]),
        (["rm", "0123456789abcdef"], ["No such mesh (404)"]),
        (["get", "{id}", "-n", "10", "-o", "x.xyz"], ["cannot tell the format"]),
        (["upload", "missing.ply"], ["missing.ply: no such file"]),
    ],
)
def test_bad_requests_fail_clearly(server, workdir, uploaded, args, words):
    args = [arg.replace("{id}", uploaded) for arg in args]
    result = qem(*args, cwd=workdir, server=server.url)
    usage = "x.xyz" in args or "missing.ply" in args
    assert_clean_failure(result, 2 if usage else 1, *words)
    assert not (workdir / "x.ply").exists() and not (workdir / "x.xyz").exists()


def test_unreachable_server(workdir):
    with socket.socket() as probe:  # a port nothing listens on
        probe.bind(("127.0.0.1", 0))
        url = f"http://127.0.0.1:{probe.getsockname()[1]}"
    for args in (["ls"], ["get", "0123456789abcdef", "-o", "x.ply"], ["upload", "sphere.ply"]):
        result = qem(*args, cwd=workdir, server=url)
        assert_clean_failure(result, 3, "cannot reach the qem-lod server", url)


@pytest.mark.parametrize("url", ["not a url", "localhost:8000", "http://256.1.1.1", "ftp://x"])
def test_malformed_server_url(workdir, url):
    result = qem("ls", "--server", url, cwd=workdir)
    assert_clean_failure(result, 2, "is not a valid server URL", repr(url))


def test_writes_need_the_right_token(start_server, workdir):
    guarded = start_server(env={"QEM_TOKENS": TOKEN})

    missing = qem("upload", "sphere.ply", cwd=workdir, server=guarded.url)
    assert_clean_failure(missing, 1, "(401)", "QEM_TOKEN")
    wrong = qem("upload", "sphere.ply", cwd=workdir, server=guarded.url, token="x" * 24)
    assert_clean_failure(wrong, 1, "(403)", "QEM_TOKEN is not accepted")

    upload = qem(
        "upload", "sphere.ply", "--no-wait", "--json", cwd=workdir, server=guarded.url, token=TOKEN
    )
    assert upload.returncode == 0, upload.stderr
    mesh_id = json.loads(upload.stdout)["id"]
    # Reads are public; deleting needs the token too.
    assert qem("ls", cwd=workdir, server=guarded.url).returncode == 0
    assert_clean_failure(qem("rm", mesh_id, cwd=workdir, server=guarded.url), 1, "(401)")
    assert qem("rm", mesh_id, cwd=workdir, server=guarded.url, token=TOKEN).returncode == 0


def test_serve_demo_loads_textured_spot(start_server, tmp_path):
    """``qem serve --demo`` on an empty data directory builds Spot with its texture: the
    viewer's levels carry per-corner UVs and the texture endpoint serves the image."""
    server = start_server(data_dir=tmp_path / "demo-data", args=("--demo",))
    with server.client() as client:
        (record,) = client.list()
        assert record["name"] == "spot.glb"
        info = client.wait_ready(record["id"], timeout=600)
        assert info["vertices"] == 2930
        level = qem_core.load_mesh(client.lod(record["id"], 300, "obj"), format="obj")
        assert level.n_vertices == 300 and level.corner_uvs is not None
        media_type, image = client.texture(record["id"])
    assert media_type == "image/png"
    assert image == qem_core.load_mesh(REPO / "server" / "demo" / "spot.glb").texture


def test_serve_refuses_an_open_address_without_tokens(tmp_path):
    """Anyone who reaches a server without QEM_TOKENS may upload and delete: on an address
    other than loopback ``qem serve`` says so and does not start."""
    for host in ("0.0.0.0", "::", "192.0.2.7", "example.org"):
        result = qem("serve", "--host", host, "--port", "0", "--data-dir", str(tmp_path / "d"),
                     cwd=tmp_path)  # fmt: skip
        assert_clean_failure(result, 2, f"--host {host}", "QEM_TOKENS", "--allow-anonymous-writes")


def test_serve_listens_on_an_open_address_with_tokens_or_when_told(start_server, tmp_path):
    for name, env, args in (
        ("tokens", {"QEM_TOKENS": TOKEN}, ()),
        ("flag", None, ("--allow-anonymous-writes",)),
        ("variable", {"QEM_ALLOW_ANONYMOUS_WRITES": "true"}, ()),
    ):
        server = start_server(env=env, data_dir=tmp_path / name, args=("--host", "0.0.0.0", *args))
        with server.client() as client:
            assert client.list() == []


def test_serve_logs_json_lines_with_the_request_id(start_server, workdir):
    """QEM_LOG_FORMAT=json: every line, the server's and its build worker's, is one JSON
    object; a request's lines carry its id, the client's X-Request-ID when it sends one."""
    server = start_server(env={"QEM_LOG_FORMAT": "json"})
    with httpx.Client(base_url=server.url, timeout=60) as http:
        answer = http.get("/v1/meshes/nothing-here", headers={"X-Request-ID": "trace-42"})
        assert answer.headers["X-Request-ID"] == "trace-42"
        generated = http.get("/healthz").headers["X-Request-ID"]
        assert len(generated) == 16
        assert http.get("/healthz", headers={"X-Request-ID": "bad id!"}).headers[
            "X-Request-ID"
        ] != "bad id!"
    result = qem("upload", "sphere.ply", cwd=workdir, server=server.url)
    assert result.returncode == 0, result.stderr
    server.stop()
    entries = [json.loads(line) for line in server.log_lines if line.strip()]
    by_id = {entry["request_id"]: entry for entry in entries}
    assert '"GET /v1/meshes/nothing-here HTTP/1.1" 404' in by_id["trace-42"]["message"]
    assert by_id[generated]["logger"] == "uvicorn.access"
    assert any(entry["logger"] == "qem.jobs" for entry in entries), entries  # the worker

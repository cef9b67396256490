"""The app in process (TestClient, real lifespan and worker pool): uploads, limits, auth,
levels, ETags, CORS, deletes, and what a failed or partial upload leaves behind."""

from __future__ import annotations

import json
import math
import sqlite3
import time

import anyio
import numpy as np
import pytest
from fastapi.testclient import TestClient

from server.app import create_app
from server.deps import job_queue
from server.settings import Settings

TOKEN = "write-token-0123456789"
PROBLEM = "application/problem+json"


def sphere_ply(rings: int = 8, segments: int = 12) -> bytes:
    """ASCII PLY of a closed latitude-longitude sphere: 2 + (rings-1)*segments vertices."""
    vertices = [(0.0, 0.0, 1.0)]
    for i in range(1, rings):
        theta = math.pi * i / rings
        for j in range(segments):
            phi = 2 * math.pi * j / segments
            vertices.append(
                (math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta))
            )
    vertices.append((0.0, 0.0, -1.0))
    south = len(vertices) - 1

    def ring(i: int, j: int) -> int:
        return 1 + (i - 1) * segments + j % segments

    faces = []
    for j in range(segments):
        faces.append((0, ring(1, j), ring(1, j + 1)))
        faces.append((south, ring(rings - 1, j + 1), ring(rings - 1, j)))
        for i in range(1, rings - 1):
            a, b = ring(i, j), ring(i, j + 1)
            c, d = ring(i + 1, j), ring(i + 1, j + 1)
            faces += [(a, c, d), (a, d, b)]
    header = (
        f"ply\nformat ascii 1.0\nelement vertex {len(vertices)}\nproperty float x\n"
        f"property float y\nproperty float z\nelement face {len(faces)}\n"
        "property list uchar int vertex_indices\nend_header\n"
    )
    body = "".join(f"{x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in vertices)
    body += "".join(f"3 {a} {b} {c}\n" for a, b, c in faces)
    return (header + body).encode()


SPHERE = sphere_ply()
SPHERE_VERTICES = 2 + 7 * 12


def make_client(tmp_path, **overrides) -> TestClient:
    values = {"data_dir": tmp_path / "data", "workers": 1, "web_dir": tmp_path / "no-web"}
    settings = Settings(**{**values, **overrides}, _env_file=None)
    return TestClient(create_app(settings), raise_server_exceptions=False)


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    with make_client(tmp_path_factory.mktemp("app"), max_upload_bytes=64 * 1024) as test_client:
        yield test_client


def upload(client: TestClient, data: bytes = SPHERE, name: str = "sphere.ply", **params):
    return client.post("/v1/meshes", params={"name": name, **params}, content=data)


def wait_for(client: TestClient, mesh_id: str, timeout: float = 120.0) -> dict:
    """Poll the mesh until its build is over (ready or failed)."""
    deadline = time.monotonic() + timeout
    while True:
        info = client.get(f"/v1/meshes/{mesh_id}").json()
        if info["status"] in ("ready", "failed") or time.monotonic() > deadline:
            return info
        time.sleep(0.05)


@pytest.fixture(scope="module")
def sphere(client) -> dict:
    response = upload(client)
    assert response.status_code == 202, response.text
    info = wait_for(client, response.json()["id"])
    assert info["status"] == "ready", info
    return info


def assert_problem(response, status: int, kind: str | None = None) -> dict:
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == PROBLEM
    body = response.json()
    assert body["status"] == status and body["title"] and body["detail"]
    if kind is not None:
        assert body["type"] == f"/problems/{kind}"
    return body


def leftover_files(client: TestClient) -> list[str]:
    blobs = client.app.state.settings.data_dir / "blobs"
    return sorted(p.relative_to(blobs).as_posix() for p in blobs.rglob("*") if p.is_file())


# -- basics ----------------------------------------------------------------------------


def test_healthz(client):
    response = client.get("/healthz")
    assert response.status_code == 200 and response.json()["status"] == "ok"


def test_openapi_documents_the_api(client):
    schema = client.get("/openapi.json").json()
    assert set(schema["paths"]) >= {
        "/v1/meshes",
        "/v1/meshes/{mesh_id}",
        "/v1/meshes/{mesh_id}/lod",
        "/v1/meshes/{mesh_id}/splits",
        "/healthz",
    }
    upload_params = {p["name"] for p in schema["paths"]["/v1/meshes"]["post"]["parameters"]}
    assert {"name", "weighting", "error_mode", "preserve_topology"} <= upload_params
    not_found = schema["paths"]["/v1/meshes/{mesh_id}"]["get"]["responses"]["404"]
    assert PROBLEM in not_found["content"]
    # Every error, FastAPI's own 422 included, is documented as the body it really is.
    for path_item in schema["paths"].values():
        for operation in path_item.values():
            for status, response in operation["responses"].items():
                if status[0] in "45":
                    body = {PROBLEM: {"schema": {"$ref": "#/components/schemas/ProblemDetails"}}}
                    assert response["content"] == body, (status, response)
    assert "HTTPValidationError" not in schema["components"]["schemas"]


def test_unknown_route_is_a_problem(client):
    assert_problem(client.get("/v2/nothing"), 404)


# -- upload and build ------------------------------------------------------------------


def test_upload_builds_and_lists(client, sphere):
    assert sphere["name"] == "sphere.ply"
    assert sphere["vertices"] == SPHERE_VERTICES and sphere["faces"] == 2 * 12 * 7
    assert 4 <= sphere["min_vertices"] < SPHERE_VERTICES
    assert sphere["progress"] == 1.0 and sphere["error"] is None and sphere["attempts"] == 1
    assert np.allclose(sphere["bbox"], [[-1, -1, -1], [1, 1, 1]], atol=1e-6)
    listed = client.get("/v1/meshes").json()["meshes"]
    assert sphere["id"] in [mesh["id"] for mesh in listed]


def test_multipart_upload_keeps_the_file_name(client):
    response = client.post(
        "/v1/meshes", files={"file": ("dir/ball.ply", SPHERE, "application/octet-stream")}
    )
    assert response.status_code == 202, response.text
    assert response.headers["location"] == f"/v1/meshes/{response.json()['id']}"
    assert client.get(response.headers["location"]).json()["name"] == "ball.ply"


def test_build_options_are_recorded(client):
    response = upload(client, weighting="volume", preserve_topology="true")
    info = client.get(f"/v1/meshes/{response.json()['id']}").json()
    assert info["options"] == {"weighting": "volume", "preserve_topology": True}


def test_malformed_file_fails_with_a_reason(client):
    response = upload(client, b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n")
    info = wait_for(client, response.json()["id"])
    assert info["status"] == "failed" and info["error"]
    body = assert_problem(client.get(f"/v1/meshes/{info['id']}/lod"), 409, "mesh-failed")
    assert info["error"] in body["detail"]


@pytest.mark.parametrize(
    ("request_kwargs", "status", "kind"),
    [
        ({"content": b""}, 400, "bad-upload"),
        ({"content": SPHERE, "params": {"name": "mesh.xyz"}}, 415, "unsupported-format"),
        ({"content": SPHERE, "params": {"weighting": "heavy"}}, 422, "invalid-request"),
        ({"content": SPHERE, "params": {"boundary_weight": "-1"}}, 422, "invalid-options"),
        ({"content": SPHERE, "params": {"max_face_turn_deg": "nan"}}, 422, "invalid-options"),
        ({"content": SPHERE, "params": {"colour": "red"}}, 422, "invalid-request"),
        ({"content": b"x" * (64 * 1024 + 1)}, 413, "upload-too-large"),
        ({"files": {"other": ("a.ply", SPHERE)}}, 400, "bad-upload"),
        (
            {"content": b"--zz\r\nbroken", "headers": {"content-type": "multipart/form-data"}},
            400,
            "bad-upload",
        ),
    ],
)
def test_bad_uploads_are_refused_and_leave_nothing(client, request_kwargs, status, kind):
    before = leftover_files(client)
    count = len(client.get("/v1/meshes").json()["meshes"])
    request_kwargs.setdefault("params", {}).setdefault("name", "mesh.ply")
    assert_problem(client.post("/v1/meshes", **request_kwargs), status, kind)
    assert leftover_files(client) == before
    assert len(client.get("/v1/meshes").json()["meshes"]) == count


def test_oversized_stream_without_length_is_cut_off(client):
    before = leftover_files(client)

    def body():
        for _ in range(100):
            yield b"y" * 4096

    response = client.post("/v1/meshes", params={"name": "big.ply"}, content=body())
    problem = assert_problem(response, 413, "upload-too-large")
    assert "(0.0625 MiB)" in problem["detail"]  # not "(0 MiB)"
    assert leftover_files(client) == before


def post_raw(app, messages: list[dict], headers: list[tuple[bytes, bytes]] = ()) -> tuple:
    """POST /v1/meshes?name=cut.ply straight to the ASGI app, with request `messages` and
    raw header bytes no HTTP client would send; returns (status, body)."""
    incoming = iter(messages)
    sent = []

    async def receive():
        return next(incoming)

    async def send(message):
        sent.append(message)

    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "POST",
        "scheme": "http",
        "path": "/v1/meshes",
        "raw_path": b"/v1/meshes",
        "query_string": b"name=cut.ply",
        "root_path": "",
        "headers": list(headers),
        "client": ("127.0.0.1", 1),
        "server": ("testserver", 80),
    }
    anyio.run(app, scope, receive, send)
    return sent[0]["status"], b"".join(message.get("body", b"") for message in sent[1:])


def test_client_disconnect_mid_upload_leaves_nothing(client):
    before = leftover_files(client)
    messages = [
        {"type": "http.request", "body": SPHERE[:100], "more_body": True},
        {"type": "http.disconnect"},
    ]
    assert post_raw(client.app, messages)[0] == 400
    assert leftover_files(client) == before


@pytest.mark.parametrize(
    ("headers", "status"),
    [
        # '\xb2' is '²' in latin-1: str.isdigit() says yes, int() said 500.
        ([(b"content-length", b"\xb2")], 202),
        # python-multipart refuses boundaries over 256 bytes when the parser is made.
        ([(b"content-type", b"multipart/form-data; boundary=" + b"b" * 300)], 400),
    ],
)
def test_odd_upload_headers_are_not_server_errors(client, headers, status):
    def stored_uploads():  # not meshes/: builds queued by earlier tests may still publish
        return [name for name in leftover_files(client) if not name.startswith("meshes/")]

    before = stored_uploads()
    request = [{"type": "http.request", "body": SPHERE, "more_body": False}]
    got, body = post_raw(client.app, request, headers)
    assert got == status, body
    if status == 202:
        assert wait_for(client, json.loads(body)["id"])["status"] == "ready"
    else:
        assert stored_uploads() == before


def test_not_ready_is_409_with_progress(tmp_path):
    class Parked:  # a queue that never runs anything
        def submit(self, mesh_id):
            pass

    with make_client(tmp_path) as client:
        client.app.dependency_overrides[job_queue] = Parked
        mesh_id = upload(client).json()["id"]
        body = assert_problem(client.get(f"/v1/meshes/{mesh_id}/lod"), 409, "mesh-not-ready")
        assert body["mesh_status"] == "queued"
        assert_problem(client.get(f"/v1/meshes/{mesh_id}/splits"), 409, "mesh-not-ready")
    # The next start picks the parked build up.
    with make_client(tmp_path) as client:
        assert wait_for(client, mesh_id)["status"] == "ready"


# -- levels ----------------------------------------------------------------------------


@pytest.mark.parametrize("fmt", ["ply", "obj", "glb", "msgpack"])
def test_lod_counts_and_headers(client, sphere, fmt):
    n = sphere["min_vertices"] + 10
    response = client.get(f"/v1/meshes/{sphere['id']}/lod", params={"vertices": n, "format": fmt})
    assert response.status_code == 200, response.text
    assert response.headers["x-lod-vertices"] == str(n)
    assert int(response.headers["x-lod-faces"]) > 0
    assert response.headers["cache-control"] == "public, max-age=31536000, immutable"
    assert response.headers["etag"].startswith('"') and len(response.content) > 0


@pytest.mark.parametrize(
    ("asked", "served"), [(1, "min_vertices"), (10**12, "vertices"), (None, "vertices")]
)
def test_lod_is_clamped(client, sphere, asked, served):
    params = {} if asked is None else {"vertices": asked}
    response = client.get(f"/v1/meshes/{sphere['id']}/lod", params=params)
    assert response.headers["x-lod-vertices"] == str(sphere[served])


def test_etag_and_304(client, sphere):
    url = f"/v1/meshes/{sphere['id']}/lod"
    first = client.get(url, params={"vertices": 20})
    etag = first.headers["etag"]
    again = client.get(url, params={"vertices": 20}, headers={"If-None-Match": etag})
    assert again.status_code == 304 and again.content == b""
    assert again.headers["etag"] == etag
    weak = client.get(url, params={"vertices": 20}, headers={"If-None-Match": f'"x", W/{etag}'})
    assert weak.status_code == 304
    assert client.get(url, params={"vertices": 21}).headers["etag"] != etag
    assert client.get(url, params={"vertices": 20, "format": "obj"}).headers["etag"] != etag
    # Requests served by the same clamped level share the tag.
    top = client.get(url, params={"vertices": sphere["vertices"]}).headers["etag"]
    assert client.get(url, params={"vertices": 10**9}).headers["etag"] == top


def test_splits_stream(client, sphere):
    url = f"/v1/meshes/{sphere['id']}/splits"
    response = client.get(url, params={"from": sphere["min_vertices"], "to": 40})
    assert response.status_code == 200, response.text
    assert response.headers["x-splits-from"] == str(sphere["min_vertices"])
    # The stored stream's first frame covers [min_vertices, 40]: it is served whole.
    assert int(response.headers["x-splits-to"]) >= 40
    assert response.headers["accept-ranges"] == "bytes"
    assert len(response.content) > 0
    assert (
        client.get(url, headers={"If-None-Match": client.get(url).headers["etag"]}).status_code
        == 304
    )


@pytest.mark.parametrize(
    "params",
    [{"vertices": 0}, {"vertices": -5}, {"vertices": "many"}, {"format": "fbx"}],
)
def test_bad_lod_parameters(client, sphere, params):
    assert_problem(client.get(f"/v1/meshes/{sphere['id']}/lod", params=params), 422)


@pytest.mark.parametrize(
    "path, params, named",
    [
        ("/lod", {"vertex": 50}, "'vertex'"),
        ("/lod", {"vertices": 50, "fmt": "obj"}, "'fmt'"),
        ("/splits", {"from": 20, "too": 50}, "'too'"),
    ],
)
def test_unknown_query_parameters_are_refused(client, sphere, path, params, named):
    # A misspelt parameter must not quietly serve the full mesh with a 200.
    response = client.get(f"/v1/meshes/{sphere['id']}{path}", params=params)
    detail = assert_problem(response, 422, "invalid-request")["detail"]
    assert named in detail and "takes:" in detail


def test_texture_of_a_mesh_without_one(client, sphere):
    url = f"/v1/meshes/{sphere['id']}/texture"
    assert_problem(client.get(url), 404, "texture-not-found")
    # Not a 304: there is nothing the client could hold.
    assert_problem(client.get(url, headers={"If-None-Match": "*"}), 404, "texture-not-found")


def test_splits_only_refine(client, sphere):
    response = client.get(f"/v1/meshes/{sphere['id']}/splits", params={"from": 50, "to": 20})
    assert "only refine" in assert_problem(response, 422)["detail"]


@pytest.mark.parametrize("path", ["", "/lod", "/splits", "/texture"])
def test_unknown_id(client, path):
    assert_problem(client.get(f"/v1/meshes/0000000000000000{path}"), 404, "mesh-not-found")


# -- delete, auth, CORS, viewer ----------------------------------------------------------


def test_delete_removes_everything(client):
    mesh_id = upload(client).json()["id"]
    wait_for(client, mesh_id)
    assert client.delete(f"/v1/meshes/{mesh_id}").status_code == 204
    assert_problem(client.get(f"/v1/meshes/{mesh_id}"), 404)
    assert not [name for name in leftover_files(client) if mesh_id in name]
    assert_problem(client.delete(f"/v1/meshes/{mesh_id}"), 404)


def test_writes_need_a_token_when_configured(tmp_path):
    with make_client(tmp_path, tokens=TOKEN) as client:
        body = assert_problem(upload(client), 401, "unauthorized")
        assert "Bearer" in body["detail"]
        denied = client.post(
            "/v1/meshes",
            params={"name": "a.ply"},
            content=SPHERE,
            headers={"Authorization": "Bearer not-the-token-at-all"},
        )
        assert_problem(denied, 403, "forbidden")
        assert client.get("/v1/meshes").status_code == 200  # reads stay public
        accepted = client.post(
            "/v1/meshes",
            params={"name": "a.ply"},
            content=SPHERE,
            headers={"Authorization": f"Bearer {TOKEN}"},
        )
        assert accepted.status_code == 202
        mesh_id = accepted.json()["id"]
        assert_problem(client.delete(f"/v1/meshes/{mesh_id}"), 401)
        deleted = client.delete(
            f"/v1/meshes/{mesh_id}", headers={"Authorization": f"Bearer {TOKEN}"}
        )
        assert deleted.status_code == 204


def test_cors_allows_get_from_any_origin(client, sphere):
    response = client.get(
        f"/v1/meshes/{sphere['id']}/lod", headers={"Origin": "https://example.org"}
    )
    assert response.headers["access-control-allow-origin"] == "*"
    assert "x-lod-vertices" in response.headers["access-control-expose-headers"].lower()
    preflight = client.options(
        "/v1/meshes",
        headers={"Origin": "https://example.org", "Access-Control-Request-Method": "POST"},
    )
    assert "POST" not in preflight.headers.get("access-control-allow-methods", "")
    # HEAD answers as GET (server/head_requests.py): a browser's preflight for it passes.
    head = client.options(
        f"/v1/meshes/{sphere['id']}/lod",
        headers={"Origin": "https://example.org", "Access-Control-Request-Method": "HEAD",
                 "Access-Control-Request-Headers": "If-None-Match"},
    )
    assert head.status_code == 200, head.text


def test_root_serves_the_viewer_folder(tmp_path):
    web = tmp_path / "web"
    web.mkdir()
    (web / "index.html").write_text("<h1>viewer</h1>")
    with make_client(tmp_path, web_dir=web) as client:
        assert client.get("/").text == "<h1>viewer</h1>"
        assert client.get("/healthz").status_code == 200


def test_root_lists_meshes_without_a_viewer(client, sphere):
    page = client.get("/")
    assert page.status_code == 200 and "sphere.ply" in page.text


def test_readyz_names_the_part_that_does_not_answer(tmp_path, monkeypatch):
    with make_client(tmp_path) as client:
        assert client.get("/readyz").status_code == 200
        storage = client.app.state.storage
        staging = storage.blobs.root / ".tmp"
        staging.rename(tmp_path / "moved")  # the store's folder gone: no write can start
        answer = client.get("/readyz")
        assert answer.status_code == 503 and answer.headers["Retry-After"] == "5"
        body = answer.json()
        assert body["type"] == "/problems/not-ready" and body["part"] == "blob store"
        assert "is missing" in body["detail"]
        (tmp_path / "moved").rename(staging)
        assert client.get("/readyz").status_code == 200

        def unreachable() -> None:
            raise OSError("connection refused")

        monkeypatch.setattr(storage.metadata, "ping", unreachable)
        body = client.get("/readyz").json()
        assert body["status"] == 503 and body["part"] == "database"
        assert body["detail"] == "the database does not answer: OSError: connection refused"
        assert client.get("/healthz").status_code == 200  # alive, only not ready


def test_metrics_count_requests_builds_and_caches(client, sphere):
    url = f"/v1/meshes/{sphere['id']}/lod"
    for _ in range(3):
        assert client.get(url, params={"vertices": 50}).status_code == 200
    assert client.get("/v1/meshes/nothing-here").status_code == 404
    answer = client.get("/metrics")
    assert answer.status_code == 200 and answer.headers["content-type"].startswith("text/plain")
    text = answer.text

    def value(line_start: str) -> float:
        lines = [line for line in text.splitlines() if line.startswith(line_start)]
        assert lines, f"no {line_start!r} in:\n{text}"
        return float(lines[0].rsplit(" ", 1)[1])

    # Route templates, not ids: one series for every mesh's levels.
    lod = 'qem_http_requests_total{method="GET",route="/v1/meshes/{id}/lod",status="200"}'
    assert value(lod) >= 3
    missing = 'qem_http_requests_total{method="GET",route="/v1/meshes/{id}",status="404"}'
    assert value(missing) >= 1
    assert sphere["id"] not in text
    count = 'qem_http_request_duration_seconds_count{method="GET",route="/v1/meshes/{id}/lod"}'
    assert value(count) >= 3
    assert value('qem_meshes{status="ready"}') >= 1
    assert value('qem_builds_finished_total{outcome="ready"}') >= 1
    assert value('qem_build_duration_seconds_count{outcome="ready"}') >= 1
    # The level was made once and found twice after.
    assert value('qem_cache_misses_total{cache="levels"}') >= 1
    assert value('qem_cache_hits_total{cache="levels"}') >= 2
    assert value('qem_cache_used{cache="levels"}') > 0


class _LockedDatabase:
    """A database connection that answers as SQLite does when another process holds it
    locked past the busy timeout."""

    def execute(self, *args, **kwargs):
        raise sqlite3.OperationalError("database is locked")


def test_a_database_that_does_not_answer_is_a_503_then_recovers(tmp_path, monkeypatch):
    with make_client(tmp_path) as client:
        mesh_id = upload(client).json()["id"]
        metadata = client.app.state.storage.metadata
        with monkeypatch.context() as locked:
            locked.setattr(metadata, "_db", _LockedDatabase())
            for answer in (client.get("/v1/meshes"), upload(client), client.delete(
                f"/v1/meshes/{mesh_id}")):  # fmt: skip
                assert answer.status_code == 503, answer.text
                assert answer.headers["Retry-After"] == "5"
                body = answer.json()
                assert body["type"] == "/problems/not-ready" and body["part"] == "database"
                assert "database is locked" in body["detail"]
        # Nothing half-written: the refused upload left no blob, and all works again.
        assert wait_for(client, mesh_id)["status"] == "ready"
        assert [m["id"] for m in client.get("/v1/meshes").json()["meshes"]] == [mesh_id]
        uploads = client.app.state.storage.blobs.root / "uploads"
        assert sorted(path.name for path in uploads.iterdir()) == [mesh_id]

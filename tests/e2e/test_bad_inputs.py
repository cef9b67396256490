"""Bad input against the real server: each case and the status it gets, never a 5xx.

Files are parsed by the build worker, not the request: a malformed upload is accepted
(202), its build ends ``failed`` with a readable reason, and its levels answer 409 with
that reason. What the request itself can tell (size, extension, options, parameters,
unknown ids) is refused at once.
"""

from __future__ import annotations

import struct
from pathlib import Path

import httpx
import pytest

from client.http import QemBuildFailed
from tests.tiny_meshes import bumpy_grid

PROBLEM = "application/problem+json"
HEADER = "ply\nformat ascii 1.0\nelement vertex {v}\nproperty float x\nproperty float y\n"
HEADER += "property float z\nelement face {f}\nproperty list uchar int vertex_indices\n"
HEADER += "end_header\n"
TRIANGLE = "0 0 0\n1 0 0\n0 1 0\n"


def ascii_ply(vertices: str = TRIANGLE, faces: str = "3 0 1 2\n", v=3, f=1) -> bytes:
    return (HEADER.format(v=v, f=f) + vertices + faces).encode()


def binary_ply_claiming(n_vertices: int) -> bytes:
    header = HEADER.replace("ascii", "binary_little_endian").format(v=n_vertices, f=1)
    return header.encode() + struct.pack("<9f", 0, 0, 0, 1, 0, 0, 0, 1, 0)


# name, file name, content, words expected in the failure reason (any of them)
BUILD_FAILURES = [
    ("malformed header", "a.ply", b"ply\nformat ascii 1.0\nelement vertex three\n", ["ply"]),
    ("NaN coordinates", "a.ply", ascii_ply("nan 0 0\n1 0 0\n0 1 0\n"), ["nan"]),
    ("infinite coordinates", "a.ply", ascii_ply("inf 0 0\n1 0 0\n0 1 0\n"), ["inf"]),
    ("index out of range", "a.ply", ascii_ply(faces="3 0 1 7\n"), ["range", "index"]),
    ("no faces", "a.ply", ascii_ply(faces="", f=0), ["face"]),
    ("counts beyond the file", "a.ply", binary_ply_claiming(10**6), ["vertex", "bytes", "short"]),
    ("unknown content", "mesh", b"\x00\x01 not a mesh at all \xff" * 10, ["format"]),
    ("bad OBJ", "a.obj", b"v 0 0 0\nv 1 0 x\nv 0 1 0\nf 1 2 3\n", ["obj", "x"]),
    ("truncated STL", "a.stl", b"\x00" * 80 + struct.pack("<I", 1000) + b"\x00" * 10, ["stl"]),
    ("OFF counts too large", "a.off", b"OFF\n100 100 0\n0 0 0\n", ["off", "vert"]),
    ("broken GLB", "a.glb", b"glTF" + struct.pack("<II", 2, 9999) + b"\x00" * 8, ["glb", "gltf"]),
    # Levels are written as float32: these built, and were served as inf, or as one point
    # whose split stream broke off mid-answer.
    ("coordinates past float32", "a.obj", b"v 1e300 0 0\nv 0 1 0\nv 0 0 1\nf 1 2 3\n",
     ["float32"]),
    ("a mesh below float32", "a.obj", b"v 1e-320 0 0\nv 0 1e-320 0\nv 0 0 1e-320\nf 1 2 3\n",
     ["float32"]),
]


@pytest.fixture(scope="module")
def http(server):
    with httpx.Client(base_url=server.url, timeout=60) as client:
        yield client


# The demo mesh shipped in the repository (Spot, public domain): the bad reads below run
# on a clone without ../shared too.
DEMO_MESH = Path(__file__).resolve().parents[2] / "server" / "demo" / "spot.obj"


@pytest.fixture(scope="module")
def ready_mesh(server):
    with server.client() as qem:
        mesh_id = qem.upload(DEMO_MESH)
        return qem.wait_ready(mesh_id, timeout=300)


def assert_problem(response: httpx.Response, status: int) -> dict:
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == PROBLEM
    body = response.json()
    assert body["status"] == status and body["title"] and body["detail"]
    return body


@pytest.mark.parametrize(
    ("case", "name", "content", "words"), BUILD_FAILURES, ids=[c[0] for c in BUILD_FAILURES]
)
def test_bad_file_fails_its_build_with_a_reason(server, http, case, name, content, words):
    accepted = http.post("/v1/meshes", params={"name": name}, content=content)
    assert accepted.status_code == 202, accepted.text
    mesh_id = accepted.json()["id"]
    with server.client() as qem, pytest.raises(QemBuildFailed) as failed:
        qem.wait_ready(mesh_id, timeout=120)
    info = failed.value.info
    assert info["status"] == "failed", info
    assert any(word in info["error"].lower() for word in words), info["error"]
    body = assert_problem(http.get(f"/v1/meshes/{mesh_id}/lod"), 409)
    assert body["type"] == "/problems/mesh-failed" and info["error"] in body["detail"]
    assert_problem(http.get(f"/v1/meshes/{mesh_id}/splits"), 409)
    # The upload is kept with the failed record, and goes with it.
    assert f"uploads/{mesh_id}" in server.blob_keys()
    assert http.delete(f"/v1/meshes/{mesh_id}").status_code == 204


REFUSED_UPLOADS = [
    ("empty body", {"params": {"name": "a.ply"}, "content": b""}, 400),
    ("unknown extension", {"params": {"name": "a.xyz"}, "content": ascii_ply()}, 415),
    ("too large", {"params": {"name": "a.ply"}, "content": b"\0" * (5 * 2**20)}, 413),
    ("unknown option", {"params": {"name": "a.ply", "speed": "9"}, "content": b"x"}, 422),
    ("bad option value", {"params": {"name": "a.ply", "weighting": "x"}, "content": b"x"}, 422),
    (
        "option twice",
        {"params": {"name": "a.ply", "weighting": ["none", "area"]}, "content": ascii_ply()},
        422,
    ),
    (
        "option out of range",
        {"params": {"name": "a.ply", "pair_threshold": "2"}, "content": b"x"},
        422,
    ),
    ("multipart without file", {"files": {"mesh": ("a.ply", b"x")}}, 400),
    (
        # Regression: the second file was dropped unseen.
        "multipart with two files",
        {"files": [("file", ("a.ply", ascii_ply())), ("file", ("b.ply", ascii_ply()))]},
        400,
    ),
    (
        "multipart boundary too long",
        {
            "headers": {"content-type": "multipart/form-data; boundary=" + "b" * 300},
            "content": b"x",
        },
        400,
    ),
    (
        # Regression: built from the half that arrived.
        "multipart cut short",
        {
            "headers": {"content-type": "multipart/form-data; boundary=b"},
            "content": b'--b\r\nContent-Disposition: form-data; name="file"; filename="a.ply"'
            b"\r\n\r\n" + ascii_ply()[:40],
        },
        400,
    ),
]


@pytest.mark.parametrize(
    ("case", "request_kwargs", "status"), REFUSED_UPLOADS, ids=[c[0] for c in REFUSED_UPLOADS]
)
def test_refused_upload(server, http, case, request_kwargs, status):
    before = server.blob_keys()
    assert_problem(http.post("/v1/meshes", **request_kwargs), status)
    assert server.blob_keys() == before


BAD_READS = [
    ("unknown id", "GET", "/v1/meshes/ffffffffffffffff", {}, 404),
    ("unknown id lod", "GET", "/v1/meshes/ffffffffffffffff/lod", {}, 404),
    ("unknown id splits", "GET", "/v1/meshes/ffffffffffffffff/splits", {}, 404),
    ("unknown id delete", "DELETE", "/v1/meshes/ffffffffffffffff", {}, 404),
    ("vertices zero", "GET", "{mesh}/lod", {"vertices": 0}, 422),
    ("vertices negative", "GET", "{mesh}/lod", {"vertices": -10}, 422),
    ("vertices not a number", "GET", "{mesh}/lod", {"vertices": "ten"}, 422),
    ("unknown lod format", "GET", "{mesh}/lod", {"format": "stl"}, 422),
    ("splits backwards", "GET", "{mesh}/splits", {"from": 900, "to": 100}, 422),
    ("splits from zero", "GET", "{mesh}/splits", {"from": 0}, 422),
    # A parameter given twice: the last one used to win silently.
    ("vertices twice", "GET", "{mesh}/lod", {"vertices": [10, 20]}, 422),
    ("format twice", "GET", "{mesh}/lod", {"format": ["ply", "glb"]}, 422),
    ("from twice", "GET", "{mesh}/splits", {"from": [10, 20]}, 422),
    # Endpoints without parameters refuse any, as lod and splits do.
    ("parameter on metadata", "GET", "{mesh}", {"x": 1}, 422),
    ("parameter on the list", "GET", "/v1/meshes", {"limit": "abc"}, 422),
    ("parameter on texture", "GET", "{mesh}/texture", {"x": 1}, 422),
    ("parameter on delete", "DELETE", "{mesh}", {"x": 1}, 422),
    ("unknown route", "GET", "/v1/nothing", {}, 404),
    ("wrong method", "PUT", "/v1/meshes", {}, 405),
]


@pytest.mark.parametrize(
    ("case", "method", "path", "params", "status"), BAD_READS, ids=[c[0] for c in BAD_READS]
)
def test_bad_request(http, ready_mesh, case, method, path, params, status):
    path = path.format(mesh=f"/v1/meshes/{ready_mesh['id']}")
    assert_problem(http.request(method, path, params=params), status)


@pytest.mark.parametrize(
    "path",
    [
        "/healthz",
        "/v1/meshes",
        "{mesh}",
        "{mesh}/lod?vertices=100&format=ply",
        "{mesh}/splits?from=10&to=200",
        "{mesh}/texture",
        "/",
    ],
)
def test_head_answers_as_get_without_the_body(http, ready_mesh, path):
    """Regression: HEAD on the API fell through to the viewer's mount, a 404."""
    path = path.format(mesh=f"/v1/meshes/{ready_mesh['id']}")
    get, head = http.get(path), http.head(path)
    assert (head.status_code, head.content) == (get.status_code, b"")
    for name in ("content-type", "content-length", "etag", "cache-control"):
        assert head.headers.get(name) == get.headers.get(name), name


def test_head_on_an_unknown_mesh_is_a_404_without_a_body(http):
    head = http.head("/v1/meshes/nothing-here")
    assert (head.status_code, head.content) == (404, b"")
    assert head.headers["content-type"] == PROBLEM


def _multipart(disposition: bytes, content: bytes) -> dict:
    body = b"--b\r\nContent-Disposition: " + disposition + b"\r\n\r\n" + content + b"\r\n--b--\r\n"
    return {"headers": {"content-type": "multipart/form-data; boundary=b"}, "content": body}


def test_names_are_read_from_rfc_5987_and_cleaned(http):
    # filename* (RFC 5987) is what some clients send for a name outside ASCII.
    extended = b"form-data; name=\"file\"; filename*=UTF-8''caf%C3%A9.ply"
    accepted = http.post("/v1/meshes", **_multipart(extended, ascii_ply()))
    assert accepted.status_code == 202, accepted.text
    assert http.get(accepted.json()["url"]).json()["name"] == "café.ply"
    # A multipart file name, which the OpenAPI document cannot constrain, is kept whatever
    # it ends in; the build then goes by the content (a PLY here).
    misnamed = b"form-data; name=\"file\"; filename*=UTF-8''photo.jpg"
    accepted = http.post("/v1/meshes", **_multipart(misnamed, ascii_ply()))
    assert accepted.status_code == 202, accepted.text
    assert http.get(accepted.json()["url"]).json()["name"] == "photo.jpg"
    # A right-to-left override would show 'bunny\u202egpj.ply' as 'bunnyylp.jpg'.
    spoofing = http.post(
        "/v1/meshes", params={"name": "bunny\u202egpj.ply"}, content=ascii_ply()
    )
    assert http.get(spoofing.json()["url"]).json()["name"] == "bunnygpj.ply"
    # ?name= follows the document's pattern: no extension, or a readable format's.
    assert_problem(http.post("/v1/meshes", params={"name": ".."}, content=ascii_ply()), 415)
    assert_problem(http.post("/v1/meshes", params={"name": "a.jpg"}, content=ascii_ply()), 415)


def test_a_build_past_the_time_limit_fails_with_the_reason(start_server, tmp_path):
    """QEM_MAX_BUILD_SECONDS stops a build that runs too long (a pathological or huge
    mesh must not hold a worker indefinitely): the mesh fails with the reason, at once,
    without being requeued, and its upload stays."""
    server = start_server({"QEM_MAX_BUILD_SECONDS": "0.1"})
    vertices, faces = bumpy_grid(300)  # 90 000 vertices: longer than 0.1 s to build
    obj = "".join(f"v {x:.6f} {y:.6f} {z:.6f}\n" for x, y, z in vertices.tolist())
    obj += "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in faces.tolist())
    path = tmp_path / "big_grid.obj"
    path.write_text(obj)
    with server.client() as qem:
        mesh_id = qem.upload(path)
        with pytest.raises(QemBuildFailed) as failed:
            qem.wait_ready(mesh_id, timeout=300)
    info = failed.value.info
    assert info["status"] == "failed" and info["attempts"] == 1, info
    assert "0.1 s" in info["error"] and "QEM_MAX_BUILD_SECONDS" in info["error"], info
    assert f"uploads/{mesh_id}" in server.blob_keys()

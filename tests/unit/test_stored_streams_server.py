"""Stored split streams through the app (TestClient, real lifespan and worker pool): the
build stores the stream and its index, /splits sends stored bytes (never encodes), Range
and If-Range, resumed downloads, arbitrary from/to, damaged and missing blobs, and meshes
built before streams were stored."""

from __future__ import annotations

import json
import random

import pytest

import qem_core
from qem_core import stream as split_stream
from qem_core.stored_stream import StreamIndex
from server import stored_streams
from tests.reference import assert_decoded_level
from tests.unit.test_server_app import assert_problem, make_client, sphere_ply, upload, wait_for

# 2 + 39 * 60 = 2342 vertices: a stored stream of three frames and more than one boundary
# to serve from.
BIG_SPHERE = sphere_ply(40, 60)


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    with make_client(tmp_path_factory.mktemp("streams")) as test_client:
        yield test_client


def _ready(client, data: bytes = BIG_SPHERE) -> dict:
    response = upload(client, data)
    assert response.status_code == 202, response.text
    info = wait_for(client, response.json()["id"])
    assert info["status"] == "ready", info
    return info


@pytest.fixture(scope="module")
def mesh(client) -> dict:
    return _ready(client)


def _blob(client, info: dict, suffix: str):
    folder = client.app.state.settings.data_dir / "blobs" / "meshes" / info["id"]
    (path,) = folder.glob(f"*{suffix}")
    return path


def _pm(client, info: dict) -> qem_core.ProgressiveMesh:
    return qem_core.load(_blob(client, info, ".qpm"))


def _decode(client, mesh_id: str, start: int, body: bytes) -> split_stream.SplitStreamDecoder:
    """Decode ``body`` from the server's msgpack level ``start``."""
    level = client.get(f"/v1/meshes/{mesh_id}/lod", params={"vertices": start, "format": "msgpack"})
    decoder = split_stream.SplitStreamDecoder.from_msgpack(level.content)
    for payload in split_stream.iter_frames([body]):
        decoder.feed(payload)
    return decoder


def test_the_build_stores_the_stream_and_its_index(client, mesh):
    data = _blob(client, mesh, ".splits").read_bytes()
    index = StreamIndex.from_json(_blob(client, mesh, ".splits.json").read_bytes())
    index.check(data)
    assert index.n_frames >= 3
    assert (index.vertices[0], index.vertices[-1]) == (mesh["min_vertices"], mesh["vertices"])
    # The stored bytes are what /splits sends for the whole range.
    whole = client.get(f"/v1/meshes/{mesh['id']}/splits")
    assert whole.status_code == 200 and whole.content == data


def test_splits_are_sent_from_storage_without_encoding(client, mesh, monkeypatch):
    # Load the stored stream once, then make every encoder in this process fail: the
    # requests below must not need one.
    url = f"/v1/meshes/{mesh['id']}/splits"
    assert client.get(url).status_code == 200

    def refuse(*args, **kwargs):
        raise AssertionError("a /splits request encoded the stream")

    monkeypatch.setattr(split_stream, "encode_frame_run", refuse)
    monkeypatch.setattr(stored_streams, "encode_stored_stream", refuse)
    for params in ({}, {"from": 600, "to": 700}, {"from": 2000}, {"to": 100}):
        assert client.get(url, params=params).status_code == 200
    assert client.app.state.reads.streams.made == 0


def test_arbitrary_from_to_decode_exactly(client, mesh):
    pm = _pm(client, mesh)
    index = StreamIndex.from_json(_blob(client, mesh, ".splits.json").read_bytes())
    rng = random.Random(4)
    pairs = [
        (rng.randint(pm.n_base, pm.n_full), rng.randint(pm.n_base, pm.n_full)) for _ in range(8)
    ]
    pairs += [(pm.n_base, pm.n_full), (index.vertices[1], index.vertices[2]), (900, 901)]
    for a, b in pairs:
        n1, n2 = min(a, b), max(a, b)
        response = client.get(f"/v1/meshes/{mesh['id']}/splits", params={"from": n1, "to": n2})
        assert response.status_code == 200, response.text
        served_from = int(response.headers["x-splits-from"])
        served_to = int(response.headers["x-splits-to"])
        if n1 == n2:
            assert (served_from, served_to, response.content) == (n1, n1, b"")
            continue
        # The smallest run of stored frames covering [n1, n2].
        assert served_from <= n1 < index.vertices[index.vertices.index(served_from) + 1]
        assert index.vertices[index.vertices.index(served_to) - 1] < n2 <= served_to
        assert_decoded_level(
            _decode(client, mesh["id"], served_from, response.content), pm, served_to
        )
        # A decoder holding lod(n1) at a boundary skips nothing; one holding a later
        # boundary skips the frames it holds.
        decoder = _decode(client, mesh["id"], served_from, b"")
        for payload in split_stream.iter_frames([response.content]):
            decoder.feed(payload)
            decoder.feed(payload)  # held now: skipped
        assert_decoded_level(decoder, pm, served_to)


def test_a_decoder_inside_the_first_frame_is_told_where_to_start(client, mesh):
    index = StreamIndex.from_json(_blob(client, mesh, ".splits.json").read_bytes())
    inside = index.vertices[1] + 5
    response = client.get(f"/v1/meshes/{mesh['id']}/splits", params={"from": inside})
    assert int(response.headers["x-splits-from"]) == index.vertices[1]
    with pytest.raises(
        qem_core.InvalidOptionsError, match=f"start from lod\\({index.vertices[1]}\\)"
    ):
        _decode(client, mesh["id"], inside, response.content)


def test_range_requests(client, mesh):
    url = f"/v1/meshes/{mesh['id']}/splits"
    whole = client.get(url)
    data, etag = whole.content, whole.headers["etag"]
    size = len(data)
    assert whole.headers["accept-ranges"] == "bytes"
    for header, (start, stop) in {
        "bytes=0-99": (0, 100),
        "bytes=100-": (100, size),
        "bytes=-50": (size - 50, size),
        f"bytes=10-{size + 1000}": (10, size),
    }.items():
        part = client.get(url, headers={"Range": header})
        assert part.status_code == 206, (header, part.text)
        assert part.content == data[start:stop]
        assert part.headers["content-range"] == f"bytes {start}-{stop - 1}/{size}"
        assert part.headers["etag"] == etag
    # If-Range with the current tag: the range; with another (or a date): everything.
    assert client.get(url, headers={"Range": "bytes=0-9", "If-Range": etag}).status_code == 206
    for if_range in ('"other"', "W/" + etag, "Fri, 04 Dec 2026 10:00:00 GMT"):
        full = client.get(url, headers={"Range": "bytes=0-9", "If-Range": if_range})
        assert full.status_code == 200 and full.content == data
    # A range past the end: 416 with the size; malformed or several: 400.
    past = client.get(url, headers={"Range": f"bytes={size}-"})
    assert_problem(past, 416, "range-not-satisfiable")
    assert past.headers["content-range"] == f"bytes */{size}"
    for bad in (
        "bytes=0-9,20-29",
        "bytes=9-0",
        "bytes=-",
        "bytes=x-1",
        "bytes=" + "9" * 40 + "-",
    ):
        assert_problem(client.get(url, headers={"Range": bad}), 400, "invalid-range")
    assert_problem(client.get(url, headers={"Range": "bytes=-0"}), 416, "range-not-satisfiable")
    # A range of a unit the server does not know is ignored (RFC 9110, 14.2): the whole.
    for other in ("items=0-9", "null"):
        assert client.get(url, headers={"Range": other}).status_code == 200
    # HEAD tells the length and that ranges are served.
    head = client.head(url)
    assert head.status_code == 200 and head.headers["content-length"] == str(size)


def test_a_download_cut_in_the_middle_resumes_by_range(client, mesh):
    pm = _pm(client, mesh)
    url = f"/v1/meshes/{mesh['id']}/splits"
    first = client.get(url)
    cut = len(first.content) // 2 + 7  # inside a frame
    held = first.content[:cut]
    rest = client.get(url, headers={"Range": f"bytes={cut}-", "If-Range": first.headers["etag"]})
    assert rest.status_code == 206
    assert_decoded_level(_decode(client, mesh["id"], pm.n_base, held + rest.content), pm, pm.n_full)


def test_a_damaged_stream_is_a_problem_naming_the_mesh(tmp_path):
    with make_client(tmp_path / "damaged") as client:
        info = _ready(client)
        path = _blob(client, info, ".splits")
        data = bytearray(path.read_bytes())
        data[len(data) // 2] ^= 0x10
        path.write_bytes(bytes(data))
        body = assert_problem(client.get(f"/v1/meshes/{info['id']}/splits"), 500, "corrupt-data")
        assert info["id"] in body["detail"]
        # Its other data is untouched: levels are served, the blob is still there.
        assert (
            client.get(f"/v1/meshes/{info['id']}/lod", params={"vertices": 100}).status_code == 200
        )
        assert path.read_bytes() == bytes(data)


def test_a_missing_stream_is_made_again_once(tmp_path):
    with make_client(tmp_path / "missing") as client:
        info = _ready(client)
        stream, index = _blob(client, info, ".splits"), _blob(client, info, ".splits.json")
        data = stream.read_bytes()
        stream.unlink()
        index.unlink()
        url = f"/v1/meshes/{info['id']}/splits"
        assert client.get(url).content == data  # made again: the same bytes
        assert client.get(url, params={"from": 1000}).status_code == 200
        assert client.app.state.reads.streams.made == 1
        assert stream.read_bytes() == data and index.is_file()


def test_a_stream_stored_in_an_older_version_is_made_again_once(tmp_path):
    """A stream stored before the frame version changed (its index says so) is encoded
    again from the .qpm on first use, stored, and served in this version."""
    with make_client(tmp_path / "outdated") as client:
        info = _ready(client)
        index_path = _blob(client, info, ".splits.json")
        old = json.loads(index_path.read_bytes())
        old["stream_version"] = split_stream.STREAM_VERSION - 1
        index_path.write_bytes(json.dumps(old).encode())
        response = client.get(f"/v1/meshes/{info['id']}/splits")
        assert response.status_code == 200
        pm = _pm(client, info)
        assert_decoded_level(_decode(client, info["id"], pm.n_base, response.content), pm,
                             pm.n_full)
        assert client.app.state.reads.streams.made == 1
        stored = json.loads(index_path.read_bytes())
        assert stored["stream_version"] == split_stream.STREAM_VERSION


def test_a_mesh_built_without_its_stream_gets_it_on_first_use(tmp_path):
    with make_client(tmp_path / "later", stream_at_build=False) as client:
        info = _ready(client)
        folder = client.app.state.settings.data_dir / "blobs" / "meshes" / info["id"]
        assert not list(folder.glob("*.splits*"))
        pm = _pm(client, info)
        response = client.get(f"/v1/meshes/{info['id']}/splits")
        assert_decoded_level(
            _decode(client, info["id"], pm.n_base, response.content), pm, pm.n_full
        )
        assert client.app.state.reads.streams.made == 1
        assert len(list(folder.glob("*.splits*"))) == 2


def test_deleting_a_mesh_removes_its_stream(tmp_path):
    with make_client(tmp_path / "delete") as client:
        info = _ready(client)
        url = f"/v1/meshes/{info['id']}/splits"
        assert client.get(url).status_code == 200
        assert client.delete(f"/v1/meshes/{info['id']}").status_code == 204
        assert_problem(client.get(url), 404, "mesh-not-found")
        folder = client.app.state.settings.data_dir / "blobs" / "meshes" / info["id"]
        assert not folder.exists()


def test_a_restart_keeps_the_stored_stream(tmp_path):
    with make_client(tmp_path / "restart") as client:
        info = _ready(client)
        data = _blob(client, info, ".splits").read_bytes()
    with make_client(tmp_path / "restart") as client:  # collects garbage on start
        assert _blob(client, info, ".splits").read_bytes() == data
        assert client.get(f"/v1/meshes/{info['id']}/splits").content == data
        assert client.app.state.reads.streams.made == 0


def test_answers_from_memory_equal_the_routes_answers(client, mesh):
    # The plain GET is answered from memory (server.memory_answers); a non-matching
    # If-None-Match sends the same request through the routes: the same answer.
    base = f"/v1/meshes/{mesh['id']}"
    requests = [
        ("/lod", {"vertices": 1000, "format": "ply"}),
        ("/lod", {"vertices": 10**9, "format": "msgpack"}),
        ("/lod", {}),
        ("/splits", {}),
        ("/splits", {"from": 700, "to": 1900}),
        ("/splits", {"from": 900, "to": 900}),
    ]
    for path, params in requests:
        client.get(base + path, params=params)  # now in memory
        plain = client.get(base + path, params=params)
        routed = client.get(base + path, params=params, headers={"If-None-Match": '"x"'})
        assert plain.status_code == routed.status_code == 200
        assert plain.content == routed.content
        drop = {"date", "server", "x-request-id"}  # a new id for each request
        assert {k: v for k, v in plain.headers.items() if k not in drop} == {
            k: v for k, v in routed.headers.items() if k not in drop
        }
    # What the memory path does not take still gets the routes' problems.
    for path, query in (("/lod", "vertices=10&vertices=20"), ("/lod", "vertex=5"),
                        ("/lod", "vertices=0"), ("/splits", "from=900&to=800"),
                        ("/lod", "format=fbx")):  # fmt: skip
        assert_problem(client.get(f"{base}{path}?{query}"), 422)

"""The whole path: `qem serve` on 127.0.0.1, the real client, bunny.ply.

Upload, follow the build to ready, fetch levels in every format with exact counts (and
equal to a local build), refine lod(N1) with the split stream into lod(N2), conditional
requests, delete.
"""

from __future__ import annotations

import httpx
import msgpack
import numpy as np
import pytest

import qem_core
from client.http import QemHTTPError
from qem_core import codecs
from qem_core.stream import grid_for

from .conftest import shared_mesh


@pytest.fixture(scope="module")
def bunny_path():
    return shared_mesh("bunny.ply")


@pytest.fixture(scope="module")
def bunny(server, bunny_path) -> dict:
    seen = []
    sent = []
    with server.client() as qem:
        mesh_id = qem.upload(bunny_path, progress=lambda done, total: sent.append((done, total)))
        info = qem.wait_ready(mesh_id, timeout=600, progress=seen.append)
    assert sent[-1][0] == sent[-1][1] == bunny_path.stat().st_size
    statuses = [step["status"] for step in seen]
    assert statuses[-1] == "ready" and set(statuses) <= {"queued", "building", "ready"}
    progress = [step["progress"] for step in seen]
    assert progress == sorted(progress)
    return info


@pytest.fixture(scope="module")
def local_pm(bunny_path):
    """The same mesh built here, with the same (default) options."""
    return qem_core.build_mesh(codecs.load_mesh(bunny_path))


def test_metadata(qem, bunny, local_pm):
    assert bunny["name"] == "bunny.ply"
    assert bunny["vertices"] == local_pm.n_full
    assert bunny["faces"] == local_pm.n_faces_full
    assert bunny["min_vertices"] == local_pm.n_base
    assert np.allclose(bunny["bbox"], local_pm.bbox)
    assert bunny["id"] in [mesh["id"] for mesh in qem.list()]
    assert qem.info(bunny["id"]) == bunny


@pytest.mark.parametrize("fmt", ["ply", "obj", "glb", "msgpack", "zip"])
def test_lod_counts_are_exact(qem, bunny, local_pm, fmt):
    # float32 files round positions; msgpack quantises them to the split stream's grid.
    tolerance = 0.5 * grid_for(local_pm).step + 1e-9 if fmt == "msgpack" else 1e-6
    for n in (bunny["min_vertices"], 100, 1000, 12345, bunny["vertices"]):
        lod = qem.fetch_lod(bunny["id"], n, fmt)
        mesh = codecs.load_mesh(lod.content, format=fmt)
        vertices, faces = local_pm.lod(n)
        assert lod.n_vertices == mesh.n_vertices == n
        assert lod.n_faces == mesh.n_faces == len(faces)
        assert np.array_equal(mesh.faces, faces)
        assert np.all(np.abs(mesh.vertices - vertices) <= tolerance)
        assert lod.error == pytest.approx(local_pm.error(n))


def test_lod_is_clamped_and_says_so(qem, bunny):
    assert qem.fetch_lod(bunny["id"], 10**9).n_vertices == bunny["vertices"]
    assert qem.fetch_lod(bunny["id"], 1).n_vertices == bunny["min_vertices"]


@pytest.mark.parametrize(
    ("n1", "n2"), [(None, 2000), (1000, 20000), (20000, None), (777, 12345), (3000, 3001)]
)
def test_splits_refine_lod_n1_into_lod_n2(qem, bunny, n1, n2):
    # The stored frames covering [n1, n2] start at a frame boundary at or below n1 and end
    # at or above n2; the client starts from the run's first level and stops at n2.
    payloads = list(qem.splits(bunny["id"], n1, n2))
    assert len(payloads) >= (2 if n2 is None or n2 - (n1 or 0) > 5000 else 1)
    start = qem.refine(bunny["id"], n1, n_from=n1) if n1 is not None else None
    decoder = qem.refine(bunny["id"], n2, start=start)
    target_bytes = qem.lod(bunny["id"], n2, "msgpack")
    target = msgpack.unpackb(target_bytes)
    assert decoder.n_vertices == target["vertex_count"]
    assert np.array_equal(decoder.faces, codecs.decode_msgpack_mesh(target_bytes).faces)
    # The grid integers are those of the server's msgpack level: exact.
    positions = np.frombuffer(target["positions"], "<u2").reshape(-1, 3)
    assert np.array_equal(decoder.quantised, positions)


def test_empty_split_range(qem, bunny):
    assert list(qem.splits(bunny["id"], 500, 500)) == []


def test_etags_and_304(server, bunny):
    url = f"{server.url}/v1/meshes/{bunny['id']}"
    with httpx.Client() as http:
        first = http.get(f"{url}/lod", params={"vertices": 777, "format": "glb"})
        assert first.status_code == 200
        assert first.headers["cache-control"] == "public, max-age=31536000, immutable"
        etag = first.headers["etag"]
        assert etag.startswith('"') and etag.endswith('"')
        again = http.get(
            f"{url}/lod",
            params={"vertices": 777, "format": "glb"},
            headers={"If-None-Match": etag},
        )
        assert (again.status_code, again.content, again.headers["etag"]) == (304, b"", etag)
        other = http.get(f"{url}/lod", params={"vertices": 778, "format": "glb"})
        assert other.headers["etag"] != etag
        splits = http.get(f"{url}/splits", params={"from": 100, "to": 200})
        cached = http.get(
            f"{url}/splits",
            params={"from": 100, "to": 200},
            headers={"If-None-Match": splits.headers["etag"]},
        )
        assert cached.status_code == 304
    with server.client() as qem:
        lod = qem.fetch_lod(bunny["id"], 777, "glb")
        assert lod.etag == etag and qem.fetch_lod(bunny["id"], 777, "glb", etag=etag) is None


def test_delete(server, qem):
    path = shared_mesh("spot.ply")
    mesh_id = qem.upload(path)
    qem.wait_ready(mesh_id, timeout=300)
    assert any(mesh_id in key for key in server.blob_keys())
    qem.delete(mesh_id)
    with pytest.raises(QemHTTPError) as caught:
        qem.info(mesh_id)
    assert caught.value.status == 404 and caught.value.type == "/problems/mesh-not-found"
    assert not any(mesh_id in key for key in server.blob_keys())
    assert mesh_id not in [mesh["id"] for mesh in qem.list()]


def test_a_mesh_whose_build_is_lost_from_the_store_fails_alone(server, qem):
    """The store lost a ready mesh's .qpm (and its stream): that mesh fails with the
    reason, saying to upload it again; the others are served as before."""
    lost, kept = (qem.upload(shared_mesh(name)) for name in ("spot.ply", "fandisk.ply"))
    for mesh_id in (lost, kept):
        qem.wait_ready(mesh_id, timeout=300)
    for key in server.blob_keys():
        if key.startswith(f"meshes/{lost}/"):
            server.lose_blob(key)
    with httpx.Client(base_url=server.url, timeout=60) as http:
        answer = http.get(f"/v1/meshes/{lost}/lod", params={"vertices": 123, "format": "obj"})
        assert answer.status_code == 409, answer.text
        assert "missing from the blob store" in answer.json()["reason"]
        info = http.get(f"/v1/meshes/{lost}").json()
        assert info["status"] == "failed" and "upload the mesh again" in info["error"]
        assert http.get(f"/v1/meshes/{lost}/splits").status_code == 409
        answer = http.get(f"/v1/meshes/{kept}/lod", params={"vertices": 123, "format": "obj"})
        assert answer.status_code == 200

"""``qem serve`` with its records in a real PostgreSQL server (QEM_DATABASE_URL) and its
blobs in a real S3 store (QEM_BLOB_URL, SeaweedFS): it refuses a database without this
version's schema, saying to run ``qem db upgrade``; after it, uploads build, levels and
streams are served, deletes hold; with the database or the store stopped, readiness and
requests are 503 problems naming it, nothing is half-written, and the service recovers
when it is back; replicas share one database."""

from __future__ import annotations

import subprocess
import sys
import time

import httpx
import pytest

from server.storage.s3 import S3BlobStore, parse_s3_url

from .conftest import REPO, ServerProcess, WorkerProcess, shared_mesh

psycopg = pytest.importorskip("psycopg", reason="not installed (pip install -e '.[dev]')")

SPOT = REPO / "server" / "demo" / "spot.obj"


def _qem(*args: str, env: dict[str, str]) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "client.cli", *args],
        cwd=REPO, env={"PATH": "/usr/bin:/bin", **env}, capture_output=True, text=True,
        timeout=120, check=False,
    )  # fmt: skip


def _migrated(postgres_server) -> str:
    """A new database with this version's schema (``qem db upgrade``); its URL."""
    url = postgres_server.database()
    assert _qem("db", "upgrade", env={"QEM_DATABASE_URL": url}).returncode == 0
    return url


def test_serve_refuses_a_database_without_the_schema(postgres_url, tmp_path):
    env = {"QEM_DATABASE_URL": postgres_url}
    refused = _qem("serve", "--port", "0", "--data-dir", str(tmp_path / "data"), env=env)
    assert refused.returncode == 2, refused.stderr
    assert "no qem-lod schema yet" in refused.stderr and "qem db upgrade" in refused.stderr
    upgraded = _qem("db", "upgrade", "--json", env=env)
    assert upgraded.returncode == 0, upgraded.stderr
    assert '"before": null' in upgraded.stdout
    again = _qem("db", "upgrade", env=env)
    assert again.returncode == 0 and "nothing to do" in again.stdout


@pytest.mark.parametrize(
    "variables, part",
    [
        ({"QEM_DATABASE_URL": "postgresql://qem@127.0.0.1:1/qem"}, "the database"),
        ({"QEM_BLOB_URL": "s3://qem/x", "AWS_ENDPOINT_URL": "http://127.0.0.1:1",
          "AWS_ACCESS_KEY_ID": "k", "AWS_SECRET_ACCESS_KEY": "s"}, "the blob store"),
    ],
    ids=["database", "blob store"],
)  # fmt: skip
def test_serve_and_worker_say_which_part_does_not_answer(variables, part, tmp_path):
    for command in (("serve", "--port", "0", "--data-dir", str(tmp_path / "d")), ("worker",)):
        if command == ("worker",) and "QEM_DATABASE_URL" not in variables:
            continue  # a worker needs a database before anything
        done = _qem(*command, env=variables)
        assert done.returncode == 3, done.stderr
        assert f"{part} does not answer" in done.stderr and "Traceback" not in done.stderr
        assert len(done.stderr.splitlines()) <= 3, done.stderr


@pytest.fixture(params=["local blobs", "s3"])
def pg_serve(request, postgres_server, tmp_path):
    env = {"QEM_DATABASE_URL": _migrated(postgres_server)}
    if request.param == "s3":
        env.update(request.getfixturevalue("s3_server").env())
    server = ServerProcess(tmp_path / "data", env).start()
    server.blobs_in_s3 = request.param == "s3"
    yield server
    server.stop()


def test_a_mesh_builds_serves_and_deletes_on_postgresql(pg_serve, postgres_server):
    with pg_serve.client() as qem:
        mesh_id = qem.upload(SPOT)
        info = qem.wait_ready(mesh_id, timeout=300)
        assert info["status"] == "ready" and info["vertices"] > info["min_vertices"]
        assert qem.lod(mesh_id, info["min_vertices"], "ply").startswith(b"ply")
    with httpx.Client(base_url=pg_serve.url, timeout=60) as http:
        splits = http.get(f"/v1/meshes/{mesh_id}/splits")
        assert splits.status_code == 200 and len(splits.content) > 0
        assert http.get("/readyz").status_code == 200
        assert [m["id"] for m in http.get("/v1/meshes").json()["meshes"]] == [mesh_id]
        assert http.delete(f"/v1/meshes/{mesh_id}").status_code == 204
        assert http.get(f"/v1/meshes/{mesh_id}").status_code == 404


def test_two_replicas_share_one_database(postgres_server, s3_server, tmp_path):
    """Upload through replica A, read through B; a delete through B is a 404 on A within
    moments, even for what A answers from memory; a replica restarted keeps everything."""
    url = _migrated(postgres_server)
    env = {"QEM_DATABASE_URL": url, **s3_server.env()}  # as on two machines: own folders
    a = ServerProcess(tmp_path / "a", env).start()
    b = ServerProcess(tmp_path / "b", env).start()
    try:
        with a.client() as via_a, b.client() as via_b:
            kept = via_a.upload(SPOT)
            gone = via_a.upload(SPOT)
            for mesh_id in (kept, gone):
                via_b.wait_ready(mesh_id, timeout=300)
        with httpx.Client(timeout=60) as http:
            lod = {"vertices": "100", "format": "ply"}
            for replica in (a, b):
                for _ in range(2):  # the second from memory (server/memory_answers.py)
                    answer = http.get(f"{replica.url}/v1/meshes/{gone}/lod", params=lod)
                    assert answer.status_code == 200
                assert http.get(f"{replica.url}/v1/meshes/{gone}/splits").status_code == 200
            with psycopg.connect(url) as connection:
                attempts = connection.execute("SELECT attempts FROM meshes").fetchall()
            assert attempts == [(1,), (1,)]  # each built once, by one of the replicas

            assert http.delete(f"{b.url}/v1/meshes/{gone}").status_code == 204
            deleted = time.monotonic()
            while http.get(f"{a.url}/v1/meshes/{gone}/lod", params=lod).status_code != 404:
                assert time.monotonic() - deleted < 2.0, "replica A still serves a deleted mesh"
                time.sleep(0.005)
            for path in ("", "/lod", "/splits"):
                assert http.get(f"{a.url}/v1/meshes/{gone}{path}").status_code == 404

            a.stop()
            a.start()
            assert http.get(f"{a.url}/v1/meshes/{kept}/lod", params=lod).status_code == 200
            assert [m["id"] for m in http.get(f"{a.url}/v1/meshes").json()["meshes"]] == [kept]
    finally:
        a.stop()
        b.stop()


@pytest.mark.parametrize("part", ["database", "blob store"])
def test_a_part_down_is_a_503_with_nothing_half_written_then_recovery(
    part, postgres_server, s3_server, tmp_path
):
    env = {"QEM_DATABASE_URL": _migrated(postgres_server), **s3_server.env()}
    server = ServerProcess(tmp_path / "data", env).start()
    down = postgres_server if part == "database" else s3_server
    try:
        with server.client() as qem:
            kept = qem.upload(SPOT)
            qem.wait_ready(kept, timeout=300)
        with httpx.Client(base_url=server.url, timeout=60) as http:
            down.pause()
            try:
                ready = http.get("/readyz")
                assert ready.status_code == 503 and part in ready.json()["detail"]
                upload = http.post("/v1/meshes", files={"file": ("spot.obj", SPOT.read_bytes())})
                assert upload.status_code == 503 and "Retry-After" in upload.headers, upload.text
                assert upload.headers["content-type"].startswith("application/problem+json")
                if part == "database":
                    assert http.get("/v1/meshes").status_code == 503
            finally:
                down.resume()
            assert http.get("/readyz").status_code == 200
            # The refused upload left no record and no blob.
            assert [m["id"] for m in http.get("/v1/meshes").json()["meshes"]] == [kept]
            bucket, prefix = parse_s3_url(env["QEM_BLOB_URL"])
            with pytest.MonkeyPatch.context() as patch:
                for name, value in env.items():
                    patch.setenv(name, value)
                blobs = S3BlobStore(bucket, prefix, tmp_path / "spool")
                assert list(blobs.keys("uploads/")) == [f"uploads/{kept}"]
            answer = http.get(f"/v1/meshes/{kept}/lod", params={"format": "glb"})
            assert answer.status_code == 200, answer.text
            assert answer.content.startswith(b"glTF")
    finally:
        server.stop()


def _serve_only(tmp_path, env: dict[str, str]) -> ServerProcess:
    """``qem serve`` that runs no builds itself (no --workers: the workers do)."""
    return ServerProcess(tmp_path / "data", env, builds=False).start()


def _attempts(url: str) -> dict[str, int]:
    with psycopg.connect(url) as connection:
        return dict(connection.execute("SELECT id, attempts FROM meshes").fetchall())


def test_workers_build_every_upload_once(postgres_server, s3_server, tmp_path):
    """20 uploads, two `qem worker` processes: every mesh ready, none built twice."""
    env = {"QEM_DATABASE_URL": _migrated(postgres_server), **s3_server.env()}
    server = _serve_only(tmp_path, env)
    workers = [WorkerProcess(env), WorkerProcess(env)]
    try:
        small = [REPO / "server" / "demo" / name for name in ("spot.obj", "spot.glb")]
        with server.client() as qem:
            ids = [qem.upload(small[i % 2]) for i in range(20)]
            for mesh_id in ids:
                assert qem.wait_ready(mesh_id, timeout=300)["status"] == "ready"
        assert _attempts(env["QEM_DATABASE_URL"]) == dict.fromkeys(ids, 1)
    finally:
        for worker in workers:
            assert worker.stop() == 0  # SIGTERM: a clean stop
        server.stop()


def test_a_build_whose_worker_is_killed_is_taken_up_by_another(postgres_server, s3_server,
                                                                tmp_path):  # fmt: skip
    dragon = shared_mesh("dragon.ply")
    env = {"QEM_DATABASE_URL": _migrated(postgres_server), **s3_server.env(),
           "QEM_WORKER_STALE_S": "3"}  # fmt: skip
    server = _serve_only(tmp_path, env)
    first = WorkerProcess(env)
    second = None
    try:
        with server.client() as qem:
            mesh_id = qem.upload(dragon)
            deadline = time.monotonic() + 120
            while qem.info(mesh_id)["progress"] < 0.05:  # the first worker is building it
                assert time.monotonic() < deadline, qem.info(mesh_id)
                time.sleep(0.1)
            first.kill()  # SIGKILL of the worker and its build process mid-build
            killed = time.monotonic()
            second = WorkerProcess(env)
            info = qem.wait_ready(mesh_id, timeout=300)
            assert info["status"] == "ready", info
        assert _attempts(env["QEM_DATABASE_URL"]) == {mesh_id: 2}
        assert time.monotonic() - killed < 60
    finally:
        if second is not None:
            second.stop()
        first.stop()
        server.stop()


def test_the_database_stopped_mid_build_delays_the_build_but_loses_nothing(
    postgres_server, s3_server, tmp_path
):
    """PostgreSQL stopped for a few seconds while a worker builds dragon: the build cannot
    record its progress, its slot survives, and once the database is back the build is
    taken back and finished; the server answers 503 meanwhile and nothing is lost."""
    dragon = shared_mesh("dragon.ply")
    env = {"QEM_DATABASE_URL": _migrated(postgres_server), **s3_server.env(),
           "QEM_WORKER_STALE_S": "3"}  # fmt: skip
    server = _serve_only(tmp_path, env)
    worker = WorkerProcess(env)
    try:
        with server.client() as qem:
            spot = qem.upload(SPOT)
            qem.wait_ready(spot, timeout=300)
            mesh_id = qem.upload(dragon)
            deadline = time.monotonic() + 120
            while qem.info(mesh_id)["progress"] < 0.05:
                assert time.monotonic() < deadline, qem.info(mesh_id)
                time.sleep(0.1)
            postgres_server.pause()
            try:
                with httpx.Client(base_url=server.url, timeout=60) as http:
                    assert http.get(f"/v1/meshes/{mesh_id}").status_code == 503
                time.sleep(3)
            finally:
                postgres_server.resume()
            info = qem.wait_ready(mesh_id, timeout=300)
            assert info["status"] == "ready", info
            assert qem.info(spot)["status"] == "ready"
        assert _attempts(env["QEM_DATABASE_URL"])[mesh_id] <= 2
        assert worker.process.poll() is None  # the worker and its slot lived through it
    finally:
        worker.stop()
        server.stop()

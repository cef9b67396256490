"""The storage: records with fenced state changes in SQLite (embedded) and in a real
PostgreSQL server (the scaled deployment; migrations by Alembic), atomic blob writes,
garbage collection and recovery of interrupted builds."""

from __future__ import annotations

import os
import threading
import time

import pytest

from server.jobs.base import JobQueue
from server.migrations import head, upgrade
from server.settings import Settings
from server.storage import (
    MeshRecord,
    Storage,
    StorageUnavailable,
    open_storage,
    qpm_key,
    upload_key,
)


@pytest.fixture(params=["sqlite", "postgresql", "postgresql+s3"])
def settings(request, tmp_path) -> Settings:
    """The embedded settings; with QEM_DATABASE_URL on a migrated database; and with
    QEM_BLOB_URL too, on a real S3 store (SeaweedFS)."""
    if request.param == "sqlite":
        return Settings(data_dir=tmp_path / "data", workers=1, _env_file=None)
    url = request.getfixturevalue("postgres_url")
    upgrade(url)
    blob_url = request.getfixturevalue("s3_env")["QEM_BLOB_URL"] if "s3" in request.param else None
    return Settings(data_dir=tmp_path / "data", workers=1, database_url=url, blob_url=blob_url,
                    _env_file=None)  # fmt: skip


def _scratch_files(settings: Settings) -> list:
    """Files of writes in progress: the local store's staging folder, the S3 store's
    spool."""
    folder = settings.data_dir / ("spool" if settings.blob_url else "blobs/.tmp")
    return [path for path in folder.rglob("*") if path.is_file()]


@pytest.fixture
def storage(settings) -> Storage:
    opened = open_storage(settings)
    yield opened
    opened.close()


def _record(mesh_id: str = "00000000000000aa", **fields) -> MeshRecord:
    return MeshRecord(
        id=mesh_id,
        name="bunny.ply",
        upload_key=upload_key(mesh_id),
        upload_bytes=10,
        **fields,
    )


def _put(storage: Storage, key: str, data: bytes = b"ply\n") -> None:
    with storage.blobs.writer(key) as writer:
        writer.write(data)


# -- records -------------------------------------------------------------------------


def test_record_round_trip(storage):
    record = _record(options={"weighting": "volume"})
    storage.metadata.create(record)
    assert storage.metadata.get(record.id) == record
    assert storage.metadata.records() == [record]
    assert storage.metadata.count() == 1
    assert storage.metadata.get("ffffffffffffffff") is None


def test_records_survive_reopening(settings, storage):
    storage.metadata.create(_record())
    reopened = open_storage(settings)
    try:
        assert reopened.metadata.get("00000000000000aa").name == "bunny.ply"
    finally:
        reopened.close()


def test_build_lifecycle(storage):
    storage.metadata.create(_record())
    claimed = storage.metadata.claim("00000000000000aa", "token-1")
    assert claimed.status == "building" and claimed.attempts == 1 and claimed.claim == "token-1"
    assert storage.metadata.set_progress("00000000000000aa", "token-1", 0.5)
    assert storage.metadata.get("00000000000000aa").progress == 0.5
    assert storage.metadata.finish(
        "00000000000000aa",
        "token-1",
        qpm_key="meshes/00000000000000aa/token-1.qpm",
        n_vertices=10,
        n_faces=16,
        n_base=4,
        bbox=((0, 0, 0), (1, 2, 3)),
    )
    done = storage.metadata.get("00000000000000aa")
    assert (done.status, done.progress, done.claim) == ("ready", 1.0, None)
    assert (done.n_vertices, done.n_faces, done.n_base) == (10, 16, 4)
    assert done.bbox == ((0.0, 0.0, 0.0), (1.0, 2.0, 3.0))
    # Finished records can be neither claimed, nor failed, nor requeued.
    assert storage.metadata.claim("00000000000000aa", "token-2") is None
    assert not storage.metadata.fail("00000000000000aa", "late")
    assert not storage.metadata.requeue("00000000000000aa")


def test_writes_of_a_replaced_attempt_are_fenced(storage):
    storage.metadata.create(_record())
    storage.metadata.claim("00000000000000aa", "old")
    assert storage.metadata.requeue("00000000000000aa")  # e.g. the server restarted
    assert storage.metadata.claim("00000000000000aa", "new").attempts == 2
    assert not storage.metadata.set_progress("00000000000000aa", "old", 0.9)
    assert not storage.metadata.fail("00000000000000aa", "orphan says no", token="old")
    assert not storage.metadata.finish(
        "00000000000000aa",
        "old",
        qpm_key="x",
        n_vertices=1,
        n_faces=1,
        n_base=1,
        bbox=((0, 0, 0), (0, 0, 0)),
    )
    record = storage.metadata.get("00000000000000aa")
    assert (record.status, record.claim, record.error) == ("building", "new", None)
    assert storage.metadata.fail("00000000000000aa", "bad file", token="new")
    assert storage.metadata.get("00000000000000aa").error == "bad file"


def test_only_one_of_many_concurrent_claims_wins(storage):
    storage.metadata.create(_record())
    wins = []
    threads = [
        threading.Thread(
            target=lambda i=i: wins.append(storage.metadata.claim("00000000000000aa", f"t{i}"))
        )
        for i in range(8)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert sum(win is not None for win in wins) == 1


def test_progress_is_clamped(storage):
    storage.metadata.create(_record())
    storage.metadata.claim("00000000000000aa", "t")
    storage.metadata.set_progress("00000000000000aa", "t", 7.0)
    assert storage.metadata.get("00000000000000aa").progress == 1.0


def test_newer_schema_is_refused(settings, storage):
    if settings.database_url:
        storage.metadata._execute("UPDATE alembic_version SET version_num = '9999'")
        match = "revision 9999, this qem-lod needs"
    else:
        storage.metadata._execute("PRAGMA user_version=99")
        match = "newer than this server"
    with pytest.raises(RuntimeError, match=match):
        open_storage(settings)


def test_a_database_without_the_schema_is_refused_until_upgraded(postgres_url, tmp_path):
    settings = Settings(data_dir=tmp_path / "data", database_url=postgres_url, _env_file=None)
    with pytest.raises(RuntimeError, match="no qem-lod schema yet.*qem db upgrade"):
        open_storage(settings)
    assert upgrade(postgres_url) == (None, head())
    assert upgrade(postgres_url) == (head(), head())  # a second run changes nothing
    opened = open_storage(settings)
    assert opened.metadata.count() == 0
    opened.close()


def test_a_database_at_the_first_schema_is_migrated_with_its_records(postgres_url, tmp_path):
    import psycopg

    assert upgrade(postgres_url, "0001") == (None, "0001")  # as the first release left it
    with psycopg.connect(postgres_url, autocommit=True) as connection:
        connection.execute(
            "INSERT INTO meshes (id, name, upload_key, upload_bytes, status, created_at, "
            "updated_at) VALUES ('00000000000000aa', 'old.ply', 'uploads/00000000000000aa', "
            "3, 'queued', 1, 1)"
        )
    settings = Settings(data_dir=tmp_path / "data", database_url=postgres_url, _env_file=None)
    with pytest.raises(RuntimeError, match="at revision 0001, this qem-lod needs"):
        open_storage(settings)
    assert upgrade(postgres_url) == ("0001", head())
    opened = open_storage(settings)
    try:
        assert opened.metadata.get("00000000000000aa").name == "old.ply"
        # The queue of the new schema takes it.
        assert opened.metadata.claim_next("t").id == "00000000000000aa"
        assert opened.metadata.heartbeat("00000000000000aa", "t")
        assert not opened.metadata.heartbeat("00000000000000aa", "other")
    finally:
        opened.close()


def test_stalled_builds_are_taken_back_or_failed(postgres_url, tmp_path):
    upgrade(postgres_url)
    settings = Settings(data_dir=tmp_path / "data", database_url=postgres_url, _env_file=None)
    opened = open_storage(settings)
    metadata = opened.metadata
    try:
        metadata.create(_record("00000000000000aa"))
        metadata.create(_record("00000000000000bb", attempts=2))
        assert metadata.claim_next("a").id == "00000000000000aa"  # the oldest first
        assert metadata.claim_next("b").id == "00000000000000bb"
        assert metadata.claim_next("c") is None  # nothing left queued
        assert metadata.take_back_stalled(60.0, 3) == []  # both beat just now
        time.sleep(0.05)
        taken = dict(metadata.take_back_stalled(0.01, 3))
        assert taken == {"00000000000000aa": "queued", "00000000000000bb": "failed"}
        assert "gave up after 3 attempt(s)" in metadata.get("00000000000000bb").error
        assert not metadata.heartbeat("00000000000000aa", "a")  # its claim is gone
        assert metadata.claim_next("d").attempts == 2
    finally:
        opened.close()


def test_claims_from_many_connections_fence_each_other(settings):
    """Replicas and workers on other machines: each its own connection to PostgreSQL."""
    if not settings.database_url:
        pytest.skip("one SQLite file: the threads share its connection")
    stores = [open_storage(settings) for _ in range(6)]
    try:
        stores[0].metadata.create(_record())
        wins = []
        threads = [
            threading.Thread(
                target=lambda s=s, i=i: wins.append(s.metadata.claim("00000000000000aa", f"t{i}"))
            )
            for i, s in enumerate(stores)
        ]
        for thread in threads:
            thread.start()
        for thread in threads:
            thread.join()
        (winner,) = [win for win in wins if win is not None]
        assert winner.attempts == 1
        assert not stores[1].metadata.finish("00000000000000aa", "not-the-claim", qpm_key="x",
                                             n_vertices=1, n_faces=1, n_base=1,
                                             bbox=((0, 0, 0), (1, 1, 1)))  # fmt: skip
    finally:
        for store in stores:
            store.close()


def test_the_database_down_is_unavailable_then_recovers(postgres_server, tmp_path):
    """PostgreSQL stopped: StorageUnavailable (a 503), nothing written; started again: the
    same store answers, with what it held."""
    url = postgres_server.database()
    upgrade(url)
    settings = Settings(data_dir=tmp_path / "data", database_url=url, _env_file=None)
    storage = open_storage(settings)
    try:
        storage.metadata.create(_record())
        postgres_server.pause()
        try:
            with pytest.raises(StorageUnavailable, match="database"):
                storage.metadata.get("00000000000000aa")
            with pytest.raises(StorageUnavailable):
                storage.metadata.create(_record("00000000000000bb"))
        finally:
            postgres_server.resume()
        assert [r.id for r in storage.metadata.records()] == ["00000000000000aa"]
    finally:
        storage.close()


# -- blobs ---------------------------------------------------------------------------


def test_blob_is_invisible_until_committed(storage):
    writer = storage.blobs.writer("uploads/00000000000000aa")
    writer.write(b"ply\n")
    assert not storage.blobs.exists("uploads/00000000000000aa")
    assert list(storage.blobs.keys()) == []
    writer.commit()
    with storage.blobs.open("uploads/00000000000000aa") as handle:
        assert handle.read() == b"ply\n"
    assert list(storage.blobs.keys()) == ["uploads/00000000000000aa"]


def test_failed_write_leaves_nothing(storage, settings):
    with pytest.raises(OSError), storage.blobs.writer("uploads/00000000000000aa") as writer:
        writer.write(b"half a file")
        raise OSError("client went away")
    assert not storage.blobs.exists("uploads/00000000000000aa")
    assert list(storage.blobs.keys()) == [] and _scratch_files(settings) == []


def test_staged_path_publishes_on_success_only(storage):
    with storage.blobs.staged_path("meshes/a/t.qpm") as path:
        path.write_bytes(b"QPM")
    with storage.blobs.local_path("meshes/a/t.qpm") as path:
        assert path.read_bytes() == b"QPM"
    with pytest.raises(ValueError), storage.blobs.staged_path("meshes/a/u.qpm") as path:
        path.write_bytes(b"half")
        raise ValueError
    assert not storage.blobs.exists("meshes/a/u.qpm")


def test_crashed_write_is_swept_on_start(settings, storage):
    writer = storage.blobs.writer("uploads/00000000000000aa")
    writer.write(b"partial")
    writer._file.close()  # the process dies here: no commit, no abort
    assert storage.collect_garbage() == 1
    assert _scratch_files(settings) == []
    assert not storage.blobs.exists("uploads/00000000000000aa")


@pytest.mark.parametrize("key", ["../etc/passwd", "/abs", "a//b", "a/../b", "", "a b"])
def test_blob_keys_cannot_escape(storage, key):
    with pytest.raises(ValueError, match="invalid blob key"):
        storage.blobs.writer(key)


def test_delete_missing_blob(storage):
    assert not storage.blobs.delete("uploads/nothing")
    with pytest.raises(FileNotFoundError), storage.blobs.local_path("uploads/nothing"):
        pass


# -- storage as a whole --------------------------------------------------------------


def test_garbage_collection_keeps_what_records_use(storage):
    ready = _record("00000000000000aa", status="ready", qpm_key=qpm_key("00000000000000aa", "t1"))
    storage.metadata.create(ready)
    _put(storage, ready.upload_key)
    _put(storage, ready.qpm_key)
    _put(storage, qpm_key("00000000000000aa", "t0"))  # an older attempt's file
    _put(storage, upload_key("00000000000000bb"))  # upload whose record was never written
    building = _record("00000000000000cc", status="building")
    storage.metadata.create(building)
    _put(storage, building.upload_key)
    assert storage.collect_garbage() == 2
    assert sorted(storage.blobs.keys()) == sorted(
        [ready.upload_key, ready.qpm_key, building.upload_key]
    )


def test_garbage_younger_than_the_age_given_is_kept(storage):
    """A shared store: another replica's upload has its blob a moment before its record."""
    _put(storage, upload_key("00000000000000bb"))
    assert storage.collect_garbage(min_age_s=3600) == 0
    assert storage.blobs.exists(upload_key("00000000000000bb"))
    assert storage.collect_garbage() == 1
    assert not storage.blobs.exists(upload_key("00000000000000bb"))


def test_a_spool_is_swept_only_when_its_process_is_gone(settings, storage, tmp_path):
    if not settings.blob_url:
        pytest.skip("the local store stages in its own folder")
    spools = settings.data_dir / "spool"
    dead = spools / f"{2**22 + 1}-x"  # above Linux's largest pid: no such process
    live = spools / f"{os.getppid()}-y"  # a process that is alive (this one's parent)
    for folder in (dead, live):
        folder.mkdir()
        (folder / "write-1").write_bytes(b"half")
    storage.collect_garbage()
    assert not dead.exists() and (live / "write-1").exists()


def test_delete_mesh_removes_record_and_blobs(storage):
    record = _record(status="ready", qpm_key=qpm_key("00000000000000aa", "t"))
    storage.metadata.create(record)
    _put(storage, record.upload_key)
    _put(storage, record.qpm_key)
    assert storage.delete_mesh(record.id) == record
    assert storage.metadata.get(record.id) is None
    assert list(storage.blobs.keys()) == []
    assert storage.delete_mesh(record.id) is None


# -- recovery of interrupted builds --------------------------------------------------


class RecordingQueue(JobQueue):
    """The interface's recovery logic, with submissions recorded instead of run."""

    def __init__(self, settings, storage):
        super().__init__(settings, storage)
        self.submitted: list[str] = []

    def start(self):
        self.recover()

    def submit(self, mesh_id):
        self.submitted.append(mesh_id)

    def close(self):
        pass


def test_recovery_requeues_interrupted_builds_and_fails_exhausted_ones(settings, storage):
    storage.metadata.create(_record("00000000000000aa"))  # queued, never started
    storage.metadata.create(_record("00000000000000bb"))
    storage.metadata.claim("00000000000000bb", "t")  # building when the server died
    storage.metadata.create(_record("00000000000000cc", status="ready"))
    storage.metadata.create(_record("00000000000000dd", status="building", attempts=3))
    queue = RecordingQueue(settings, storage)
    queue.start()
    assert queue.submitted == ["00000000000000aa", "00000000000000bb"]
    requeued = storage.metadata.get("00000000000000bb")
    assert (requeued.status, requeued.attempts, requeued.claim) == ("queued", 1, None)
    exhausted = storage.metadata.get("00000000000000dd")
    assert exhausted.status == "failed"
    assert "interrupted 3 time(s)" in exhausted.error
    assert storage.metadata.get("00000000000000cc").status == "ready"


def test_a_build_interrupted_every_time_ends_failed(settings, storage):
    storage.metadata.create(_record())
    queue = RecordingQueue(settings, storage)
    for attempt in range(1, settings.max_build_attempts + 1):
        queue.start()  # a server start
        assert storage.metadata.claim("00000000000000aa", f"t{attempt}").attempts == attempt
        # ...and the server dies during the build.
    queue.start()
    record = storage.metadata.get("00000000000000aa")
    assert record.status == "failed" and "gave up" in record.error

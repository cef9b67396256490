"""Mesh records in PostgreSQL (psycopg 3), for a deployment of several replicas and
workers sharing one database (``QEM_DATABASE_URL=postgresql://...``).

One connection per store object, guarded by a lock, in autocommit: each statement of
`server.storage.sql` is its own transaction, and every state change checks the expected
state in its WHERE clause, so replicas and workers on other machines never step on one
another. A delete is announced (NOTIFY) to every replica watching (`watch_deletes`),
which forgets the mesh at once. A connection that fails is dropped and the call answers
StorageUnavailable (a 503 with Retry-After); the next call connects again, so the service
recovers by itself when the database is back. The schema is Alembic's (server/migrations, ``qem db
upgrade``); a store refuses to open on a database whose schema is not this code's.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from .base import MeshRecord, StorageUnavailable
from .sql import RETURNING, SqlMetadataStore

__all__ = ["PostgresMetadataStore", "SchemaMismatch", "check_schema"]

CONNECT_TIMEOUT_S = 5
# Each delete is announced on this channel (NOTIFY); every replica LISTENs and forgets
# the mesh, so none keeps answering for it from memory.
DELETES_CHANNEL = "qem_mesh_deleted"
LISTEN_POLL_S = 0.5  # how often the listening thread checks that it should stop
LISTEN_RETRY_S = 1.0

log = logging.getLogger("qem.storage")


class SchemaMismatch(RuntimeError):
    """The database's schema is not the one this code reads (behind: run ``qem db
    upgrade``; ahead: a newer qem-lod migrated it)."""


def _connect(url: str):
    import psycopg

    return psycopg.connect(url, autocommit=True, connect_timeout=CONNECT_TIMEOUT_S)


def check_schema(url: str) -> str:
    """The database's revision, if it is this code's newest; else SchemaMismatch saying
    what to do (StorageUnavailable when the database does not answer)."""
    import psycopg

    from ..migrations import current, head

    try:
        with _connect(url) as connection:
            revision = current(connection)
    except psycopg.Error as error:
        raise StorageUnavailable("database", error) from error
    newest = head()
    if revision == newest:
        return revision
    if revision is None:
        raise SchemaMismatch(
            f"the database has no qem-lod schema yet (this qem-lod needs revision {newest}): "
            "run `qem db upgrade` first"
        )
    raise SchemaMismatch(
        f"the database schema is at revision {revision}, this qem-lod needs {newest}: run "
        "`qem db upgrade` with this version (or run the version that migrated it)"
    )


class PostgresMetadataStore(SqlMetadataStore):
    """Records in the database at ``url`` (``postgresql://user:pass@host:port/db``)."""

    MARK = "%s"
    GREATEST = "GREATEST"

    def __init__(self, url: str) -> None:
        self.url = url
        self._lock = threading.Lock()
        self._connection = None
        check_schema(url)

    @classmethod
    def from_settings(cls, settings) -> PostgresMetadataStore:
        return cls(settings.database_url)

    @contextmanager
    def _cursor(self) -> Iterator[Any]:
        import psycopg

        with self._lock:
            try:
                if self._connection is None or self._connection.closed:
                    self._connection = _connect(self.url)
                with self._connection.cursor() as cursor:
                    yield cursor
            except psycopg.IntegrityError:
                raise  # a caller's bug (a duplicate id), not the database's state
            except psycopg.Error as error:
                # Down, restarted, the network gone: drop the connection, connect again
                # on the next call. Autocommit: nothing was half-written.
                self._drop()
                raise StorageUnavailable("database", error) from error

    def _drop(self) -> None:
        if self._connection is not None:
            try:
                self._connection.close()
            except Exception:  # noqa: BLE001 - already broken
                pass
            self._connection = None

    # -- the build queue (server/jobs/postgres.py) -----------------------------------

    def claim_next(self, token: str) -> MeshRecord | None:
        """Start a build attempt on the oldest queued record, as `claim` does, its
        heartbeat now; None if nothing is queued. Workers on any machine take different
        records (SKIP LOCKED)."""
        found = self._records(
            "UPDATE meshes SET status = 'building', attempts = attempts + 1, progress = 0, "
            "claim = ?, error = NULL, updated_at = ?, heartbeat_at = ? WHERE id = ("
            "SELECT id FROM meshes WHERE status = 'queued' ORDER BY created_at, id "
            f"LIMIT 1 FOR UPDATE SKIP LOCKED) {RETURNING}",
            (token, time.time(), time.time()),
        )
        return found[0] if found else None

    def heartbeat(self, mesh_id: str, token: str) -> bool:
        """The attempt `token` is alive; False if it no longer owns the record."""
        sql = (
            "UPDATE meshes SET heartbeat_at = %s "
            "WHERE id = %s AND status = 'building' AND claim = %s"
        )
        return self._execute(sql, (time.time(), mesh_id, token)) == 1

    def take_back_stalled(self, stale_s: float, max_attempts: int) -> list[tuple[str, str]]:
        """Builds whose worker stopped beating (killed, machine gone) for `stale_s`:
        requeued, or failed with the reason once they used `max_attempts`. Returns
        (mesh id, new status) of each."""
        before = time.time() - stale_s
        stalled = "status = 'building' AND COALESCE(heartbeat_at, updated_at) < %s"
        reason = (
            f"the build's worker stopped answering {{attempts}} time(s) (killed, out of "
            f"memory, or its machine gone); gave up after {max_attempts} attempt(s)"
        )
        failed = self._fetch(
            "UPDATE meshes SET status = 'failed', claim = NULL, updated_at = %s, "
            f"error = replace(%s, '{{attempts}}', attempts::text) WHERE {stalled} "
            "AND attempts >= %s RETURNING id",
            (time.time(), reason, before, max_attempts),
        )
        requeued = self._fetch(
            "UPDATE meshes SET status = 'queued', claim = NULL, progress = 0, updated_at = %s "
            f"WHERE {stalled} AND attempts < %s RETURNING id",
            (time.time(), before, max_attempts),
        )
        return [(row[0], "failed") for row in failed] + [(row[0], "queued") for row in requeued]

    # -- deletes heard by every replica ----------------------------------------------

    def _announce_delete(self, mesh_id: str) -> None:
        self.announce(DELETES_CHANNEL, mesh_id)

    def watch_deletes(self, on_delete) -> Any:
        return self.watch(DELETES_CHANNEL, on_delete)

    def announce(self, channel: str, payload: str = "") -> None:
        """NOTIFY `channel` (best effort: a watcher that misses it hears None)."""
        try:
            self._fetch("SELECT pg_notify(%s, %s)", (channel, payload))
        except StorageUnavailable:
            pass  # the watchers' connections broke too: they hear None

    def watch(self, channel: str, on_notice) -> Any:
        """Call ``on_notice(payload)`` for each NOTIFY on `channel`, from a thread with a
        connection of its own, and ``on_notice(None)`` whenever notices may have been
        missed (on connecting, and after the database was lost); returns a function that
        stops the watch."""
        stop = threading.Event()
        thread = threading.Thread(
            target=self._listen, args=(channel, on_notice, stop), name=f"qem-{channel}",
            daemon=True,
        )  # fmt: skip
        thread.start()

        def stop_watching() -> None:
            stop.set()
            thread.join(LISTEN_POLL_S + CONNECT_TIMEOUT_S)

        return stop_watching

    def _listen(self, channel: str, on_notice, stop: threading.Event) -> None:
        import psycopg

        while not stop.is_set():
            try:
                with _connect(self.url) as connection:
                    connection.execute(f"LISTEN {channel}")
                    on_notice(None)  # whatever was announced before this connection
                    while not stop.is_set():
                        for notice in connection.notifies(timeout=LISTEN_POLL_S):
                            on_notice(notice.payload)
            except psycopg.Error as error:
                log.warning("the watch of %s lost the database (%s); retrying", channel, error)
                on_notice(None)
                stop.wait(LISTEN_RETRY_S)

    def _fetch(self, sql: str, params: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
        with self._cursor() as cursor:
            cursor.execute(sql, params)
            return cursor.fetchall()

    def _execute(self, sql: str, params: tuple[Any, ...] = ()) -> int:
        with self._cursor() as cursor:
            cursor.execute(sql, params)
            return cursor.rowcount

    def close(self) -> None:
        with self._lock:
            self._drop()

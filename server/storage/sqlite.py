"""Mesh records in SQLite (stdlib sqlite3, WAL), the embedded metadata store.

One connection per store object, guarded by a lock; the web process and each build worker
process open their own. WAL lets workers write progress while the server reads; the
statements (each state change one UPDATE checking the expected state) are
`server.storage.sql`'s, shared with PostgreSQL.
"""

from __future__ import annotations

import sqlite3
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .base import StorageUnavailable
from .sql import SqlMetadataStore

__all__ = ["SqliteMetadataStore"]

SCHEMA_VERSION = 1

_SCHEMA = """
CREATE TABLE IF NOT EXISTS meshes (
    id           TEXT PRIMARY KEY,
    name         TEXT NOT NULL,
    upload_key   TEXT NOT NULL,
    upload_bytes INTEGER NOT NULL,
    status       TEXT NOT NULL CHECK (status IN ('queued', 'building', 'ready', 'failed')),
    progress     REAL NOT NULL DEFAULT 0,
    options      TEXT NOT NULL DEFAULT '{}',
    attempts     INTEGER NOT NULL DEFAULT 0,
    claim        TEXT,
    qpm_key      TEXT,
    n_vertices   INTEGER,
    n_faces      INTEGER,
    n_base       INTEGER,
    bbox         TEXT,
    error        TEXT,
    created_at   REAL NOT NULL,
    updated_at   REAL NOT NULL
);
CREATE INDEX IF NOT EXISTS meshes_status ON meshes (status);
"""

class SqliteMetadataStore(SqlMetadataStore):
    """Records in ``<data_dir>/meshes.sqlite3``.

    path : the database file; its folder is created if needed.
    """

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._lock = threading.Lock()
        # isolation_level=None: autocommit; each statement below is its own transaction.
        self._db = sqlite3.connect(
            self.path, timeout=30.0, isolation_level=None, check_same_thread=False
        )
        self._db.execute("PRAGMA journal_mode=WAL")
        self._db.execute("PRAGMA synchronous=NORMAL")
        self._db.execute("PRAGMA busy_timeout=30000")
        version = self._db.execute("PRAGMA user_version").fetchone()[0]
        if version > SCHEMA_VERSION:
            raise RuntimeError(
                f"{self.path} has schema version {version}, newer than this server's "
                f"{SCHEMA_VERSION}; upgrade qem-lod"
            )
        self._db.executescript(_SCHEMA)
        self._db.execute(f"PRAGMA user_version={SCHEMA_VERSION}")

    @classmethod
    def from_settings(cls, settings) -> SqliteMetadataStore:
        return cls(Path(settings.data_dir) / "meshes.sqlite3")

    # -- plumbing (the queries: server.storage.sql) ------------------------------------

    def _fetch(self, sql: str, params: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
        with self._lock, _unavailable_on_error():
            return self._db.execute(sql, params).fetchall()

    def _execute(self, sql: str, params: tuple[Any, ...] = ()) -> int:
        with self._lock, _unavailable_on_error():
            return self._db.execute(sql, params).rowcount

    def close(self) -> None:
        with self._lock:
            self._db.close()


@contextmanager
def _unavailable_on_error() -> Iterator[None]:
    # Locked past the busy timeout, a disk I/O error, a file gone: the database cannot
    # answer now (each statement is its own transaction, so nothing was half-written).
    # IntegrityError is a caller's bug, not the database's state: it goes through.
    try:
        yield
    except sqlite3.IntegrityError:
        raise
    except (sqlite3.OperationalError, sqlite3.DatabaseError) as error:
        raise StorageUnavailable("database", error) from error

"""Mesh records in SQLite (stdlib sqlite3, WAL), the embedded metadata store.

One connection per store object, guarded by a lock; the web process and each build worker
process open their own. WAL lets workers write progress while the server reads, and every
state change is a single UPDATE whose WHERE clause checks the expected state, so
transitions are atomic across processes.
"""

from __future__ import annotations

import json
import sqlite3
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from .base import UNFINISHED, MeshRecord, MetadataStore, StorageUnavailable

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

_COLUMNS = (
    "id name upload_key upload_bytes status progress options attempts claim qpm_key "
    "n_vertices n_faces n_base bbox error created_at updated_at"
).split()


class SqliteMetadataStore(MetadataStore):
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

    # -- plumbing -------------------------------------------------------------------

    def _execute(self, sql: str, params: tuple[Any, ...] = ()) -> sqlite3.Cursor:
        with self._lock, _unavailable_on_error():
            return self._db.execute(sql, params)

    def _query(self, sql: str, params: tuple[Any, ...] = ()) -> list[MeshRecord]:
        with self._lock, _unavailable_on_error():
            rows = self._db.execute(sql, params).fetchall()
        return [_to_record(row) for row in rows]

    def _update(self, mesh_id: str, where: str, params: tuple[Any, ...], **values: Any) -> bool:
        values["updated_at"] = time.time()
        assignments = ", ".join(f"{name} = ?" for name in values)
        sql = f"UPDATE meshes SET {assignments} WHERE id = ? AND ({where})"
        cursor = self._execute(sql, (*values.values(), mesh_id, *params))
        return cursor.rowcount == 1

    # -- MetadataStore ----------------------------------------------------------------

    def create(self, record: MeshRecord) -> None:
        row = _from_record(record)
        placeholders = ", ".join("?" for _ in _COLUMNS)
        self._execute(
            f"INSERT INTO meshes ({', '.join(_COLUMNS)}) VALUES ({placeholders})",
            tuple(row[name] for name in _COLUMNS),
        )

    def get(self, mesh_id: str) -> MeshRecord | None:
        found = self._query(f"SELECT {', '.join(_COLUMNS)} FROM meshes WHERE id = ?", (mesh_id,))
        return found[0] if found else None

    def records(self) -> list[MeshRecord]:
        return self._query(f"SELECT {', '.join(_COLUMNS)} FROM meshes ORDER BY created_at, id")

    def ping(self) -> None:
        with self._lock:
            self._db.execute("SELECT 1 FROM meshes LIMIT 1").fetchall()

    def status_counts(self) -> dict[str, int]:
        with self._lock:
            rows = self._db.execute("SELECT status, COUNT(*) FROM meshes GROUP BY status")
            return {status: int(n) for status, n in rows.fetchall()}

    def count(self) -> int:
        with self._lock:
            return int(self._db.execute("SELECT COUNT(*) FROM meshes").fetchone()[0])

    def delete(self, mesh_id: str) -> MeshRecord | None:
        found = self._query(
            f"DELETE FROM meshes WHERE id = ? RETURNING {', '.join(_COLUMNS)}", (mesh_id,)
        )
        return found[0] if found else None

    def unfinished(self) -> list[MeshRecord]:
        marks = ", ".join("?" for _ in UNFINISHED)
        return self._query(
            f"SELECT {', '.join(_COLUMNS)} FROM meshes WHERE status IN ({marks}) "
            "ORDER BY created_at, id",
            UNFINISHED,
        )

    def claim(self, mesh_id: str, token: str) -> MeshRecord | None:
        found = self._query(
            "UPDATE meshes SET status = 'building', attempts = attempts + 1, progress = 0, "
            "claim = ?, error = NULL, updated_at = ? WHERE id = ? AND status = 'queued' "
            f"RETURNING {', '.join(_COLUMNS)}",
            (token, time.time(), mesh_id),
        )
        return found[0] if found else None

    def set_progress(self, mesh_id: str, token: str, progress: float) -> bool:
        progress = min(1.0, max(0.0, float(progress)))
        return self._update(
            mesh_id, "status = 'building' AND claim = ?", (token,), progress=progress
        )

    def finish(self, mesh_id, token, *, qpm_key, n_vertices, n_faces, n_base, bbox) -> bool:
        return self._update(
            mesh_id,
            "status = 'building' AND claim = ?",
            (token,),
            status="ready",
            progress=1.0,
            claim=None,
            qpm_key=qpm_key,
            n_vertices=int(n_vertices),
            n_faces=int(n_faces),
            n_base=int(n_base),
            bbox=json.dumps([[float(x) for x in corner] for corner in bbox]),
            error=None,
        )

    def fail(self, mesh_id: str, reason: str, *, token: str | None = None) -> bool:
        if token is None:
            where, params = "status IN ('queued', 'building')", ()
        else:
            where, params = "status = 'building' AND claim = ?", (token,)
        return self._update(mesh_id, where, params, status="failed", claim=None, error=reason)

    def release(self, mesh_id: str) -> bool:
        cursor = self._execute(
            "UPDATE meshes SET status = 'queued', attempts = MAX(attempts - 1, 0), "
            "claim = NULL, progress = 0, updated_at = ? WHERE id = ? AND status = 'building'",
            (time.time(), mesh_id),
        )
        return cursor.rowcount == 1

    def requeue(self, mesh_id: str) -> bool:
        return self._update(
            mesh_id,
            "status IN ('queued', 'building')",
            (),
            status="queued",
            claim=None,
            progress=0.0,
        )

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


def _from_record(record: MeshRecord) -> dict[str, Any]:
    row = {name: getattr(record, name) for name in _COLUMNS}
    row["options"] = json.dumps(record.options, sort_keys=True)
    row["bbox"] = None if record.bbox is None else json.dumps(record.bbox)
    return row


def _to_record(row: tuple[Any, ...]) -> MeshRecord:
    values = dict(zip(_COLUMNS, row, strict=True))
    values["options"] = json.loads(values["options"])
    if values["bbox"] is not None:
        values["bbox"] = tuple(tuple(corner) for corner in json.loads(values["bbox"]))
    return MeshRecord(**values)

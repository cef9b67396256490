"""Mesh records in an SQL database: the statements both SQL backends run.

`SqlMetadataStore` holds every query of the `MetadataStore` interface, written once;
SQLite (`server.storage.sqlite`) and PostgreSQL (`server.storage.postgres`) subclasses
supply the connection, the parameter marker and the error mapping. Every state change is
one UPDATE whose WHERE clause checks the expected state (and the claim token), so each
transition is atomic whichever process or machine makes it.

Columns (table ``meshes``): those of `MeshRecord`; ``options`` and ``bbox`` are JSON text,
so both databases store the same rows.
"""

from __future__ import annotations

import abc
import json
import time
from typing import Any

from .base import UNFINISHED, MeshRecord, MetadataStore

__all__ = ["COLUMNS", "RETURNING", "SqlMetadataStore"]

COLUMNS = (
    "id name upload_key upload_bytes status progress options attempts claim qpm_key "
    "n_vertices n_faces n_base bbox error created_at updated_at"
).split()
_SELECT = f"SELECT {', '.join(COLUMNS)} FROM meshes"
RETURNING = f"RETURNING {', '.join(COLUMNS)}"


class SqlMetadataStore(MetadataStore):
    """The queries, over `_fetch` and `_execute` of a subclass.

    MARK : the driver's parameter marker ("?" for sqlite3, "%s" for psycopg).
    GREATEST : the SQL function giving the larger of two values.
    """

    MARK = "?"
    GREATEST = "MAX"

    @abc.abstractmethod
    def _fetch(self, sql: str, params: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
        """Rows of one statement (its own transaction)."""

    @abc.abstractmethod
    def _execute(self, sql: str, params: tuple[Any, ...] = ()) -> int:
        """Run one statement (its own transaction); the number of rows it changed."""

    def _sql(self, sql: str) -> str:
        return sql.replace("?", self.MARK)

    def _records(self, sql: str, params: tuple[Any, ...] = ()) -> list[MeshRecord]:
        return [_to_record(row) for row in self._fetch(self._sql(sql), params)]

    def _update(self, mesh_id: str, where: str, params: tuple[Any, ...], **values: Any) -> bool:
        values["updated_at"] = time.time()
        assignments = ", ".join(f"{name} = ?" for name in values)
        sql = f"UPDATE meshes SET {assignments} WHERE id = ? AND ({where})"
        return self._execute(self._sql(sql), (*values.values(), mesh_id, *params)) == 1

    # -- MetadataStore ----------------------------------------------------------------

    def create(self, record: MeshRecord) -> None:
        row = _from_record(record)
        marks = ", ".join("?" for _ in COLUMNS)
        self._execute(
            self._sql(f"INSERT INTO meshes ({', '.join(COLUMNS)}) VALUES ({marks})"),
            tuple(row[name] for name in COLUMNS),
        )

    def get(self, mesh_id: str) -> MeshRecord | None:
        found = self._records(f"{_SELECT} WHERE id = ?", (mesh_id,))
        return found[0] if found else None

    def records(self) -> list[MeshRecord]:
        return self._records(f"{_SELECT} ORDER BY created_at, id")

    def ping(self) -> None:
        self._fetch("SELECT 1 FROM meshes LIMIT 1")

    def status_counts(self) -> dict[str, int]:
        rows = self._fetch("SELECT status, COUNT(*) FROM meshes GROUP BY status")
        return {status: int(n) for status, n in rows}

    def count(self) -> int:
        return int(self._fetch("SELECT COUNT(*) FROM meshes")[0][0])

    def delete(self, mesh_id: str) -> MeshRecord | None:
        found = self._records(f"DELETE FROM meshes WHERE id = ? {RETURNING}", (mesh_id,))
        if found:
            self._announce_delete(mesh_id)
        return found[0] if found else None

    def _announce_delete(self, mesh_id: str) -> None:  # noqa: B027 - optional hook
        """Tell the other processes watching the database (`watch_deletes`)."""

    def unfinished(self) -> list[MeshRecord]:
        marks = ", ".join("?" for _ in UNFINISHED)
        return self._records(
            f"{_SELECT} WHERE status IN ({marks}) ORDER BY created_at, id", UNFINISHED
        )

    def claim(self, mesh_id: str, token: str) -> MeshRecord | None:
        found = self._records(
            "UPDATE meshes SET status = 'building', attempts = attempts + 1, progress = 0, "
            "claim = ?, error = NULL, updated_at = ? WHERE id = ? AND status = 'queued' "
            f"{RETURNING}",
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

    def lose(self, mesh_id: str, qpm_key: str, reason: str) -> bool:
        return self._update(
            mesh_id, "status = 'ready' AND qpm_key = ?", (qpm_key,), status="failed",
            error=reason,
        )  # fmt: skip

    def release(self, mesh_id: str) -> bool:
        sql = (
            f"UPDATE meshes SET status = 'queued', attempts = {self.GREATEST}(attempts - 1, 0), "
            "claim = NULL, progress = 0, updated_at = ? WHERE id = ? AND status = 'building'"
        )
        return self._execute(self._sql(sql), (time.time(), mesh_id)) == 1

    def requeue(self, mesh_id: str, *, token: str | None = None) -> bool:
        if token is None:
            where, params = "status IN ('queued', 'building')", ()
        else:
            where, params = "status = 'building' AND claim = ?", (token,)
        return self._update(mesh_id, where, params, status="queued", claim=None, progress=0.0)


def _from_record(record: MeshRecord) -> dict[str, Any]:
    row = {name: getattr(record, name) for name in COLUMNS}
    row["options"] = json.dumps(record.options, sort_keys=True)
    row["bbox"] = None if record.bbox is None else json.dumps(record.bbox)
    return row


def _to_record(row: tuple[Any, ...]) -> MeshRecord:
    values = dict(zip(COLUMNS, row, strict=True))
    values["options"] = json.loads(values["options"])
    if values["bbox"] is not None:
        values["bbox"] = tuple(tuple(corner) for corner in json.loads(values["bbox"]))
    return MeshRecord(**values)

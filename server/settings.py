"""Service configuration: one pydantic-settings model, read from ``QEM_*`` environment
variables (and a ``.env`` file if present), validated once.

    QEM_DATA_DIR=/var/lib/qem QEM_TOKENS=tok-aaaaaaaaaaaaaaaa,tok-bbbbbbbbbbbbbbbb qem serve

Storage and jobs are picked by name (``metadata_backend``, ``blob_backend``,
``jobs_backend``) from the registries in `server.storage` and `server.jobs`, so a
deployment that outgrows one machine changes configuration, not code.
"""

from __future__ import annotations

import importlib
import os
from functools import lru_cache
from pathlib import Path
from typing import Annotated, Literal

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

__all__ = [
    "BLOB_BACKENDS",
    "load_backend",
    "JOBS_BACKENDS",
    "METADATA_BACKENDS",
    "MIN_TOKEN_LENGTH",
    "Settings",
    "get_settings",
]

# Backend name -> "module:attribute" of its implementation, imported only when chosen.
METADATA_BACKENDS = {
    "sqlite": "server.storage.sqlite:SqliteMetadataStore",
    "postgresql": "server.storage.postgres:PostgresMetadataStore",
}
BLOB_BACKENDS = {
    "local": "server.storage.files:LocalBlobStore",
    "s3": "server.storage.s3:S3BlobStore",
}
JOBS_BACKENDS = {
    "local": "server.jobs.local:LocalJobQueue",
    "postgresql": "server.jobs.postgres:PostgresJobQueue",
}

# A bearer token shorter than this is guessable; refuse it rather than run half-protected.
MIN_TOKEN_LENGTH = 16


def _default_workers() -> int:
    # Leave one core to the web server; builds are CPU-bound and single-threaded.
    return max(1, min(4, (os.cpu_count() or 2) - 1))


class Settings(BaseSettings):
    """Everything the service reads from its environment.

    data_dir : directory of the embedded storage (SQLite database, uploads, .qpm files);
        created on start.
    database_url : ``postgresql://user:pass@host:port/db`` keeps the mesh records in
        PostgreSQL (>= 15) instead of SQLite in data_dir, for several replicas and
        workers sharing one database; its schema is made and migrated by ``qem db
        upgrade``. Unset: SQLite.
    blob_url : ``s3://bucket/prefix`` keeps uploads, .qpm files and streams in an
        S3-compatible store (endpoint, region and credentials from ``AWS_ENDPOINT_URL``,
        ``AWS_REGION``, ``AWS_ACCESS_KEY_ID``, ``AWS_SECRET_ACCESS_KEY``) instead of
        data_dir, which then holds only the spool of transfers in progress. Unset: data_dir.
    max_upload_bytes : uploads larger than this are refused with 413 (default 512 MiB).
    tokens : bearer tokens allowed to write (upload, delete), comma-separated in
        ``QEM_TOKENS``; empty means writes are open. Reads are always public.
    allow_anonymous_writes : let ``qem serve`` listen on an address other than loopback
        with no tokens (anyone who reaches it may upload and delete); off, it refuses to
        start so.
    workers : number of build worker processes.
    mesh_cache_size : how many loaded progressive meshes stay in memory.
    lod_cache_bytes : memory budget of encoded levels kept for repeated requests.
    stream_at_build : a build encodes the mesh's split stream and stores it beside the
        .qpm before the mesh is ready (default); off, the first request for the stream
        makes and stores it (quicker to ready, slower first viewer).
    stream_cache_bytes : memory budget of stored split streams kept in memory (each is
        read from the store once, its CRC checked, then served from memory).
    max_build_attempts : a build interrupted this many times (restart, worker crash) is
        marked failed instead of being requeued again.
    worker_stale_s : with PostgreSQL, a build whose worker has not beaten its heartbeat
        for this long (killed, its machine gone) is taken back by another worker; workers
        beat every sixth of it.
    max_build_seconds : a build still running after this long is stopped and its mesh
        marked failed with the reason, so that no input (a pathological mesh, a huge one)
        holds a worker indefinitely; dragon (871k faces) takes about 2 s here.
    progress_interval_s : a build writes its progress to the database at most this often.
    worker_keep_memory_bytes : opt-in: a build worker keeps memory its builds free for
        its next build instead of faulting it in again, at the price of holding about its
        largest build's peak while idle (glibc only: server.jobs.memory); 0, the default,
        leaves the C library's defaults.
    cors_allow_origins : origins allowed to GET from a browser ("*" = any).
    log_format : "text" (a line for a person) or "json" (an object a line, for a log
        collector); either way each line of a request carries its request id.
    web_dir : folder served at ``/`` (the web viewer); default ``client/web`` next to the
        installed package, and a plain HTML list of meshes when it does not exist.
    demo_mesh : a mesh file uploaded on start when the storage holds no mesh.
    """

    model_config = SettingsConfigDict(
        env_prefix="QEM_", env_file=".env", extra="ignore", frozen=True
    )

    data_dir: Path = Path("data")
    database_url: str | None = Field(None, repr=False)  # it may hold a password
    blob_url: str | None = None
    max_upload_bytes: int = Field(512 * 2**20, ge=1, le=64 * 2**30)
    tokens: Annotated[tuple[str, ...], NoDecode] = Field((), repr=False)
    allow_anonymous_writes: bool = False
    workers: int = Field(default_factory=_default_workers, ge=1, le=64)
    mesh_cache_size: int = Field(8, ge=1, le=1024)
    lod_cache_bytes: int = Field(256 * 2**20, ge=0, le=64 * 2**30)
    stream_at_build: bool = True
    stream_cache_bytes: int = Field(256 * 2**20, ge=0, le=64 * 2**30)
    max_build_attempts: int = Field(3, ge=1, le=100)
    worker_stale_s: float = Field(30.0, ge=1.0, le=3600.0, allow_inf_nan=False)
    max_build_seconds: float = Field(600.0, gt=0.0, le=7 * 86400.0, allow_inf_nan=False)
    progress_interval_s: float = Field(0.5, gt=0.0, le=60.0, allow_inf_nan=False)
    worker_keep_memory_bytes: int = Field(0, ge=0, le=2**31 - 1)
    metadata_backend: str = "sqlite"
    blob_backend: str = "local"
    jobs_backend: str = "local"
    cors_allow_origins: Annotated[tuple[str, ...], NoDecode] = ("*",)
    log_format: Literal["text", "json"] = "text"
    web_dir: Path | None = None
    demo_mesh: Path | None = None

    @field_validator("tokens", "cors_allow_origins", mode="before")
    @classmethod
    def _split_commas(cls, value: object) -> object:
        if isinstance(value, str):
            return tuple(part.strip() for part in value.split(",") if part.strip())
        return value

    @field_validator("tokens")
    @classmethod
    def _check_tokens(cls, value: tuple[str, ...]) -> tuple[str, ...]:
        for token in value:
            if len(token) < MIN_TOKEN_LENGTH:
                raise ValueError(
                    f"a write token has {len(token)} characters; use at least "
                    f"{MIN_TOKEN_LENGTH} (e.g. `python -c 'import secrets; "
                    f"print(secrets.token_urlsafe(24))'`)"
                )
            if any(ch.isspace() for ch in token):
                raise ValueError("write tokens may not contain whitespace")
        return value

    @field_validator("data_dir")
    @classmethod
    def _check_data_dir(cls, value: Path) -> Path:
        resolved = value.expanduser().resolve()
        if resolved == Path(resolved.anchor):
            raise ValueError(
                f"data_dir={str(value)!r} is a filesystem root; use a dedicated folder"
            )
        if resolved.exists() and not resolved.is_dir():
            raise ValueError(f"data_dir={str(value)!r} exists and is not a directory")
        return resolved

    @field_validator("metadata_backend", "blob_backend", "jobs_backend")
    @classmethod
    def _check_backend(cls, value: str, info) -> str:
        known = {
            "metadata_backend": METADATA_BACKENDS,
            "blob_backend": BLOB_BACKENDS,
            "jobs_backend": JOBS_BACKENDS,
        }[info.field_name]
        if value not in known:
            raise ValueError(f"{info.field_name}={value!r} is not one of {sorted(known)}")
        return value

    @field_validator("database_url")
    @classmethod
    def _check_database_url(cls, value: str | None) -> str | None:
        if not value:
            return None
        scheme = value.partition("://")[0]
        if scheme not in ("postgresql", "postgres") or "://" not in value:
            raise ValueError(
                f"QEM_DATABASE_URL must be postgresql://user:pass@host:port/db, not {scheme}://..."
            )
        return value

    @field_validator("blob_url")
    @classmethod
    def _check_blob_url(cls, value: str | None) -> str | None:
        if not value:
            return None
        from .storage.s3 import parse_s3_url

        parse_s3_url(value)
        return value

    @model_validator(mode="after")
    def _urls_pick_the_backends(self) -> Settings:
        # QEM_DATABASE_URL and QEM_BLOB_URL are the switches users set; the backend
        # names follow from them.
        if self.database_url and self.metadata_backend == "sqlite":
            object.__setattr__(self, "metadata_backend", "postgresql")
        if self.blob_url and self.blob_backend == "local":
            object.__setattr__(self, "blob_backend", "s3")
        # With a database every server and worker shares, builds go through its queue:
        # a pool inside one server would requeue the others' running builds on start.
        if self.database_url:
            object.__setattr__(self, "jobs_backend", "postgresql")
        return self

    @field_validator("demo_mesh")
    @classmethod
    def _check_demo_mesh(cls, value: Path | None) -> Path | None:
        if value is not None and not value.is_file():
            raise ValueError(f"demo_mesh={str(value)!r} is not a file")
        return value

    @property
    def auth_enabled(self) -> bool:
        return bool(self.tokens)


def load_backend(registry: dict[str, str], name: str):
    """The class registered under `name` in one of the ``*_BACKENDS`` registries."""
    module_name, _, attribute = registry[name].partition(":")
    return getattr(importlib.import_module(module_name), attribute)


@lru_cache
def get_settings() -> Settings:
    """The settings of this process, read from the environment once."""
    return Settings()

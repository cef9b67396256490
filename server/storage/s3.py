"""Blobs in an S3-compatible object store (``QEM_BLOB_URL=s3://bucket/prefix``), for
replicas and workers on several machines sharing one store.

The client is obstore (Rust's object_store): endpoint, region and credentials come from
the standard variables (``AWS_ENDPOINT_URL``, ``AWS_REGION``, ``AWS_ACCESS_KEY_ID``,
``AWS_SECRET_ACCESS_KEY``). Large blobs go up in parts and come down in chunks: a write
is spooled to a local file and put from it (multipart past 5 MiB; S3 shows an object only
once its upload completes, so a write is atomic), a read streams into a local file or a
buffered reader; no upload or .qpm is held whole in memory to move it. Any error of the
store but a missing key is StorageUnavailable (a 503 with Retry-After), after a few
retries bounded in time, so a request never hangs on a store that is down.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import timedelta
from pathlib import Path
from typing import Any, BinaryIO

from .base import BlobStore, BlobWriter, StorageUnavailable, check_blob_key
from .files import clear_folder

__all__ = ["S3BlobStore", "parse_s3_url"]

_PING_KEY = ".qem-ping"
_RETRIES = {"max_retries": 2, "retry_timeout": timedelta(seconds=10)}
_TIMEOUTS = {"connect_timeout": "5s", "timeout": "60s"}


def parse_s3_url(url: str) -> tuple[str, str]:
    """``s3://bucket/prefix`` -> (bucket, prefix without slashes at its ends)."""
    scheme, _, rest = url.partition("://")
    bucket, _, prefix = rest.partition("/")
    if scheme != "s3" or not bucket:
        raise ValueError(f"a blob URL is s3://bucket/prefix, not {url!r}")
    return bucket, prefix.strip("/")


@contextmanager
def _answering() -> Iterator[None]:
    from obstore.exceptions import BaseError

    try:
        yield
    except FileNotFoundError:
        raise
    except (BaseError, OSError) as error:
        raise StorageUnavailable("blob store", error) from error


class S3BlobStore(BlobStore):
    """bucket, prefix : where the blobs live; spool : a local folder for writes and
    reads in progress (emptied on start by `sweep`)."""

    def __init__(self, bucket: str, prefix: str, spool: str | Path) -> None:
        from obstore.store import S3Store

        endpoint = os.environ.get("AWS_ENDPOINT_URL", "")
        options: dict[str, Any] = dict(_TIMEOUTS)
        if endpoint.startswith("http://"):
            options["allow_http"] = True  # a store on loopback or a private network
        self.bucket, self.prefix = bucket, prefix
        self._store = S3Store(
            bucket, prefix=prefix or None, client_options=options, retry_config=_RETRIES
        )
        # A folder of this process's own in the spool: replicas on one machine may share
        # a data directory, and one starting must not sweep another's transfers.
        self._spools = Path(spool)
        self._spools.mkdir(parents=True, exist_ok=True)
        self._spool = Path(tempfile.mkdtemp(dir=self._spools, prefix=f"{os.getpid()}-"))

    @classmethod
    def from_settings(cls, settings) -> S3BlobStore:
        bucket, prefix = parse_s3_url(settings.blob_url)
        return cls(bucket, prefix, Path(settings.data_dir) / "spool")

    def _spooled(self, prefix: str) -> Path:
        fd, name = tempfile.mkstemp(dir=self._spool, prefix=prefix)
        os.close(fd)
        return Path(name)

    def _put(self, key: str, path: Path) -> None:
        import obstore

        with _answering(), open(path, "rb") as source:
            obstore.put(self._store, check_blob_key(key), source)

    # -- BlobStore ----------------------------------------------------------------------

    def writer(self, key: str) -> BlobWriter:
        return _SpooledWriter(self, check_blob_key(key))

    @contextmanager
    def staged_path(self, key: str) -> Iterator[Path]:
        check_blob_key(key)
        staged = self._spooled("staged-")
        try:
            yield staged
            self._put(key, staged)
        finally:
            staged.unlink(missing_ok=True)

    @contextmanager
    def local_path(self, key: str) -> Iterator[Path]:
        import obstore

        local = self._spooled("read-")
        try:
            with _answering(), open(local, "wb") as target:
                for chunk in obstore.get(self._store, check_blob_key(key)):
                    target.write(chunk)
            yield local
        finally:
            local.unlink(missing_ok=True)

    def open(self, key: str) -> BinaryIO:
        import obstore

        with _answering():
            return _Reader(obstore.open_reader(self._store, check_blob_key(key)))

    def exists(self, key: str) -> bool:
        import obstore

        try:
            with _answering():
                obstore.head(self._store, check_blob_key(key))
        except FileNotFoundError:
            return False
        return True

    def modified(self, key: str) -> float:
        import obstore

        with _answering():
            return obstore.head(self._store, check_blob_key(key))["last_modified"].timestamp()

    def delete(self, key: str) -> bool:
        import obstore

        if not self.exists(key):
            return False
        with _answering():
            obstore.delete(self._store, key)
        return True

    def keys(self, prefix: str = "") -> Iterator[str]:
        import obstore

        with _answering():
            for batch in obstore.list(self._store, prefix or None):
                for meta in batch:
                    key = meta["path"]
                    if key.startswith(prefix) and key != _PING_KEY:
                        yield key

    def ping(self) -> None:
        import obstore

        with _answering():
            obstore.put(self._store, _PING_KEY, b"")

    def sweep(self) -> int:
        """This process's spool, and those of processes that are gone."""
        removed = clear_folder(self._spool)
        for folder in self._spools.iterdir():
            owner = folder.name.partition("-")[0]
            if folder != self._spool and not (owner.isdigit() and _alive(int(owner))):
                shutil.rmtree(folder, ignore_errors=True)
                removed += 1
        return removed


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True  # another user's process
    return True


class _SpooledWriter(BlobWriter):
    """Chunks into a local file; the commit puts it (in parts when large)."""

    def __init__(self, store: S3BlobStore, key: str) -> None:
        self._store, self._key = store, key
        self._path = store._spooled("write-")
        self._file: BinaryIO | None = open(self._path, "wb")  # noqa: SIM115 - closed below

    def write(self, chunk: bytes) -> None:
        if self._file is None:
            raise ValueError("write after commit or abort")
        try:
            self._file.write(chunk)
        except OSError as error:
            raise StorageUnavailable("blob store", error) from error
        self.size += len(chunk)

    def commit(self) -> None:
        if self._file is None:
            return
        self._file.close()
        self._file = None
        try:
            self._store._put(self._key, self._path)
        finally:
            self._path.unlink(missing_ok=True)

    def abort(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
        self._path.unlink(missing_ok=True)


class _Reader:
    """obstore's buffered reader as the binary file the callers expect (a context
    manager; errors of the store as StorageUnavailable)."""

    def __init__(self, reader) -> None:
        self._reader = reader

    def read(self, size: int = -1) -> bytes:
        with _answering():
            data = self._reader.readall() if size is None or size < 0 else self._reader.read(size)
        return bytes(data)

    def close(self) -> None:
        self._reader.close()

    def __enter__(self) -> _Reader:
        return self

    def __exit__(self, *exc_info) -> None:
        self.close()

"""Blobs as files under ``<data_dir>/blobs``, the embedded blob store.

Every write goes to a temporary file in ``blobs/.tmp`` on the same filesystem, is flushed
to disk, and is renamed over its key only on commit: a reader sees the whole blob or
nothing, and an interrupted upload leaves only a temporary file, removed by `sweep` on the
next start.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import BinaryIO

from .base import BlobStore, BlobWriter, StorageUnavailable, check_blob_key

__all__ = ["LocalBlobStore", "clear_folder"]

_TMP = ".tmp"


class LocalBlobStore(BlobStore):
    """root : folder of the blobs; created if needed."""

    def __init__(self, root: str | Path) -> None:
        self.root = Path(root)
        self._tmp = self.root / _TMP
        self._tmp.mkdir(parents=True, exist_ok=True)

    @classmethod
    def from_settings(cls, settings) -> LocalBlobStore:
        return cls(Path(settings.data_dir) / "blobs")

    def path(self, key: str) -> Path:
        """Where the blob of `key` lives (whether or not it exists)."""
        return self.root / check_blob_key(key)

    def writer(self, key: str) -> BlobWriter:
        return _FileWriter(self, key)

    @contextmanager
    def staged_path(self, key: str) -> Iterator[Path]:
        target = self.path(key)
        fd, name = tempfile.mkstemp(dir=self._tmp, prefix="staged-")
        os.close(fd)
        staged = Path(name)
        try:
            yield staged
            _fsync_file(staged)
            self._publish(staged, target)
        finally:
            staged.unlink(missing_ok=True)

    @contextmanager
    def local_path(self, key: str) -> Iterator[Path]:
        path = self.path(key)
        if not path.is_file():
            raise FileNotFoundError(f"no blob {key!r}")
        yield path

    def open(self, key: str) -> BinaryIO:
        return open(self.path(key), "rb")

    def exists(self, key: str) -> bool:
        return self.path(key).is_file()

    def delete(self, key: str) -> bool:
        path = self.path(key)
        try:
            path.unlink()
        except FileNotFoundError:
            return False
        # Drop folders left empty (meshes/<id>/), never the root.
        parent = path.parent
        while parent != self.root:
            try:
                parent.rmdir()
            except OSError:
                break
            parent = parent.parent
        return True

    def modified(self, key: str) -> float:
        return self.path(key).stat().st_mtime

    def keys(self, prefix: str = "") -> Iterator[str]:
        for dirpath, dirnames, filenames in os.walk(self.root):
            if Path(dirpath) == self.root:
                dirnames[:] = [d for d in dirnames if d != _TMP]
            for filename in filenames:
                key = (Path(dirpath) / filename).relative_to(self.root).as_posix()
                if key.startswith(prefix):
                    yield key

    def ping(self) -> None:
        # Its staging folder is where every write starts: gone or read-only, none can.
        if not self._tmp.is_dir():
            raise FileNotFoundError(f"the blob store's folder {self._tmp} is missing")
        if not os.access(self._tmp, os.W_OK | os.X_OK):
            raise PermissionError(f"the blob store's folder {self._tmp} is not writable")

    def sweep(self) -> int:
        return clear_folder(self._tmp)

    def _publish(self, source: Path, target: Path) -> None:
        target.parent.mkdir(parents=True, exist_ok=True)
        os.replace(source, target)
        _fsync_dir(target.parent)


class _FileWriter(BlobWriter):
    def __init__(self, store: LocalBlobStore, key: str) -> None:
        self._store = store
        self._target = store.path(key)
        fd, name = tempfile.mkstemp(dir=store._tmp, prefix="upload-")
        self._temp = Path(name)
        self._file = os.fdopen(fd, "wb")
        self.size = 0
        self._done = False

    def write(self, chunk: bytes) -> None:
        try:
            self._file.write(chunk)
        except OSError as error:  # out of space, a read-only or lost disk
            raise StorageUnavailable("blob store", error) from error
        self.size += len(chunk)

    def commit(self) -> None:
        if self._done:
            return
        try:
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            self._store._publish(self._temp, self._target)
        except OSError as error:
            raise StorageUnavailable("blob store", error) from error
        self._done = True

    def abort(self) -> None:
        if self._done:
            return
        self._done = True
        self._file.close()
        self._temp.unlink(missing_ok=True)


def clear_folder(folder: Path) -> int:
    """Remove everything in ``folder`` (leftovers of writes that never finished); how
    many entries."""
    removed = 0
    for leftover in folder.iterdir():
        if leftover.is_dir():
            shutil.rmtree(leftover, ignore_errors=True)
        else:
            leftover.unlink(missing_ok=True)
        removed += 1
    return removed


def _fsync_file(path: Path) -> None:
    with open(path, "rb") as handle:
        os.fsync(handle.fileno())


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)

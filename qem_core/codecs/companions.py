"""The files a model file names beside itself: an OBJ's .mtl and the images its
materials use (and, for a .gltf, its .bin and images).

A reader asks a `Companions` for a name as the model file wrote it; the lookup decides
where that may lead. `DirectoryFiles` reads next to a model on the local disk (the CLI:
the user's own files, so relative paths may climb out of the folder, as modelling tools
write them). `NoCompanions` answers nothing (a model given as bytes, or uploaded alone).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Protocol

from ..errors import MeshFormatError

__all__ = ["COMPANION_LIMIT", "Companions", "DirectoryFiles", "NoCompanions"]

# The largest companion file read: a texture of 16k x 16k RGBA PNG is about this much.
COMPANION_LIMIT = 1 << 30


class Companions(Protocol):
    def read(self, name: str) -> bytes | None:
        """The bytes of the file ``name`` (as the model file wrote it, relative to the
        model), or None when there is no such file."""


class NoCompanions:
    def read(self, name: str) -> bytes | None:
        return None


class DirectoryFiles:
    """Files relative to a model file's directory on the local disk."""

    def __init__(self, directory: str | os.PathLike) -> None:
        self.directory = Path(directory)

    def read(self, name: str) -> bytes | None:
        path = self.directory / name.replace("\\", "/")  # Windows tools write backslashes
        try:
            if not path.is_file():
                return None
            if path.stat().st_size > COMPANION_LIMIT:
                raise MeshFormatError(
                    f"{name!r} is over {COMPANION_LIMIT >> 20} MiB: not read as a companion file"
                )
            return path.read_bytes()
        except OSError:
            return None

"""Zip archives holding a model with the files it names (an OBJ with its .mtl and images).

`open_archive` checks the whole archive from its central directory before reading any
member, so that a hostile archive costs nothing: member count, total uncompressed size
and compression ratio within `ArchiveLimits`; member names relative and inside the
archive (no absolute path, drive letter or ``..``), no links, no encrypted members; and
exactly one model file (an archive with none or two is refused with the names it holds).
Members are read into memory only, never extracted to disk, and their declared sizes are
not trusted: a member that inflates past its declared size is refused as it is read.

The model's companions (`ArchiveFiles`) are resolved relative to the model's folder
inside the archive, never outside it.
"""

from __future__ import annotations

import io
import posixpath
import stat
import zipfile
import zlib
from dataclasses import dataclass

from ..errors import MeshFormatError

__all__ = [
    "ArchiveFiles",
    "ArchiveLimits",
    "ArchiveTooLarge",
    "MODEL_SUFFIXES",
    "is_zip",
    "open_archive",
    "write_archive",
]

# The model formats an archive may hold (one of them).
MODEL_SUFFIXES = (".ply", ".obj", ".stl", ".off", ".glb", ".gltf")
_CHUNK = 1 << 20
# What Python's zipfile raises on a damaged archive (found by fuzz/: a version it does not
# read, an offset before the file's start, a name that is not UTF-8 where its flag says
# so): refusals of the archive's bytes, each reported as such.
_ZIP_ERRORS = (
    zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, ValueError, OSError, EOFError,
    NotImplementedError, UnicodeDecodeError, IndexError,
)  # fmt: skip
# Members smaller than this may compress any amount (a short text file of few distinct
# lines does): only a large member inflating many times is a bomb.
_RATIO_FLOOR = 1 << 20


@dataclass(frozen=True)
class ArchiveLimits:
    """What an archive may hold: members, uncompressed bytes in all, and how many times
    larger a member may inflate than it is stored (a zip bomb inflates thousands of
    times; real meshes and images, under a hundred)."""

    max_members: int = 4096
    max_bytes: int = 4 << 30
    max_ratio: float = 200.0


class ArchiveTooLarge(MeshFormatError):
    """The archive would inflate past its limits (a zip bomb, or simply too much)."""


def is_zip(data: bytes) -> bool:
    return data[:4] in (b"PK\x03\x04", b"PK\x05\x06")


class ArchiveFiles:
    """The members of an archive, read relative to its model's folder."""

    def __init__(self, archive: zipfile.ZipFile, folder: str, members: dict[str, zipfile.ZipInfo]):
        self._archive = archive
        self._folder = folder
        self._members = members

    def read(self, name: str) -> bytes | None:
        path = posixpath.normpath(posixpath.join(self._folder, name.replace("\\", "/")))
        if path.startswith("../") or path == ".." or path.startswith("/"):
            return None  # outside the archive: nothing there to read
        info = self._members.get(path)
        return None if info is None else _read_member(self._archive, info)


def open_archive(
    data: bytes, limits: ArchiveLimits = ArchiveLimits()
) -> tuple[str, bytes, ArchiveFiles]:
    """(model name, model bytes, its companions) of a zip archive; MeshFormatError (or
    ArchiveTooLarge) for an archive refused as the module docstring says."""
    archive = _zip(io.BytesIO(data))
    model, members = _checked_members(archive, limits)
    files = ArchiveFiles(archive, posixpath.dirname(model), members)
    return model, _read_member(archive, members[model]), files


def _zip(file) -> zipfile.ZipFile:
    try:
        return zipfile.ZipFile(file)
    except _ZIP_ERRORS as error:
        raise MeshFormatError(f"not a readable zip archive ({error})") from None


def _checked_members(
    archive: zipfile.ZipFile, limits: ArchiveLimits
) -> tuple[str, dict[str, zipfile.ZipInfo]]:
    """(the model's name, the file members by normalised name), after the checks."""
    infos = archive.infolist()
    if len(infos) > limits.max_members:
        raise ArchiveTooLarge(
            f"the archive holds {len(infos)} members, over the limit of {limits.max_members}"
        )
    members: dict[str, zipfile.ZipInfo] = {}
    total = 0
    for info in infos:
        name = _checked_name(info)
        if info.is_dir():
            continue
        if info.flag_bits & 0x1:
            raise MeshFormatError(f"archive member {name!r} is encrypted")
        if stat.S_ISLNK(info.external_attr >> 16):
            raise MeshFormatError(f"archive member {name!r} is a link; links are not followed")
        total += info.file_size
        if total > limits.max_bytes:
            raise ArchiveTooLarge(
                f"the archive inflates to over {limits.max_bytes} bytes, the limit"
            )
        ratio = info.file_size / max(info.compress_size, 1)
        if info.file_size > _RATIO_FLOOR and ratio > limits.max_ratio:
            raise ArchiveTooLarge(
                f"archive member {name!r} inflates {ratio:.0f} times (limit "
                f"{limits.max_ratio:.0f}): a zip bomb?"
            )
        members[posixpath.normpath(name)] = info
    models = sorted(name for name in members if name.lower().endswith(MODEL_SUFFIXES)
                    and not posixpath.basename(name).startswith("._"))  # fmt: skip
    if len(models) != 1:
        found = ", ".join(sorted(members)[:20]) or "nothing"
        what = "no model file" if not models else f"{len(models)} model files"
        raise MeshFormatError(
            f"the archive holds {what} ({', '.join(MODEL_SUFFIXES)}); it must hold exactly "
            f"one, with the files it names. Found: {found}"
        )
    return models[0], members


def _checked_name(info: zipfile.ZipInfo) -> str:
    name = info.filename
    if not name:
        raise MeshFormatError("an archive member has no name")
    parts = name.replace("\\", "/").split("/")
    if name.startswith(("/", "\\")) or (len(name) > 1 and name[1] == ":") or ".." in parts:
        raise MeshFormatError(
            f"archive member {name!r} points outside the archive (absolute or '..')"
        )
    return name


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo) -> bytes:
    """The member's bytes, refused if it inflates past its declared size (the central
    directory can lie) or is damaged."""
    out = bytearray()
    try:
        with archive.open(info) as member:
            # One byte past the declared size is enough to know it lies.
            while len(out) <= info.file_size and (chunk := member.read(_CHUNK)):
                out += chunk
    except _ZIP_ERRORS as error:
        raise MeshFormatError(f"archive member {info.filename!r} is damaged ({error})") from None
    if len(out) > info.file_size:
        raise ArchiveTooLarge(f"archive member {info.filename!r} inflates past its declared size")
    return bytes(out)


def write_archive(files: dict[str, bytes]) -> bytes:
    """A zip archive of ``files`` (name -> bytes), deflated, with a fixed date so that the
    same files give the same bytes (an ETag stays valid)."""
    out = io.BytesIO()
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
        for name, data in files.items():
            info = zipfile.ZipInfo(name, date_time=(1980, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            archive.writestr(info, data)
    return out.getvalue()

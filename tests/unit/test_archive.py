"""qem_core.codecs.archive: a model and the files it names, from a zip, never from
outside it."""

from __future__ import annotations

import pytest

import qem_core
from qem_core.codecs.archive import ArchiveLimits, ArchiveTooLarge, open_archive, write_archive

TRIANGLE_OBJ = b"mtllib m.mtl\nusemtl red\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 4 3\n"


def test_names_resolve_inside_the_archive_only():
    data = write_archive({
        "model/a.obj": TRIANGLE_OBJ,
        "model/m.mtl": b"newmtl red\nKd 1 0 0\n",
        "secret.txt": b"not for the model",
        "__MACOSX/model/._a.obj": b"\0\0",  # macOS's resource fork: not a second model
    })  # fmt: skip
    model, content, files = open_archive(data)
    assert model == "model/a.obj" and content == TRIANGLE_OBJ
    assert files.read("m.mtl") == b"newmtl red\nKd 1 0 0\n"
    assert files.read("../secret.txt") == b"not for the model"  # inside: model/../secret.txt
    assert files.read("../../secret.txt") is None  # past the archive's root
    assert files.read("/secret.txt") is None
    assert files.read("missing.png") is None


def test_load_mesh_reads_a_zip_by_name_or_content():
    mtl = b"newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n"
    data = write_archive({"a.obj": TRIANGLE_OBJ, "m.mtl": mtl})
    for mesh in (qem_core.load_mesh(data), qem_core.load_mesh(data, format="zip")):
        assert mesh.name == "a.obj" and mesh.n_faces == 2


def test_a_member_that_inflates_past_its_declared_size_is_refused():
    data = bytearray(write_archive({"a.obj": TRIANGLE_OBJ * 100}))
    # Lower the uncompressed size in the central directory (the local header is not
    # read for it): the member then inflates past what the archive declared.
    at = data.rfind(b"PK\x01\x02")
    data[at + 24 : at + 28] = (10).to_bytes(4, "little")
    # zipfile stops at the declared size and then finds the CRC wrong; a reader that
    # went on would be stopped one byte past it.
    with pytest.raises(qem_core.MeshFormatError, match="damaged .Bad CRC|declared size"):
        open_archive(bytes(data))


def test_the_limits_are_checked_before_anything_is_read():
    data = write_archive({f"{i}.png": b"x" for i in range(5)} | {"a.obj": TRIANGLE_OBJ})
    with pytest.raises(ArchiveTooLarge, match="6 members"):
        open_archive(data, ArchiveLimits(max_members=5))
    with pytest.raises(ArchiveTooLarge, match="inflates to over 10 bytes"):
        open_archive(data, ArchiveLimits(max_bytes=10))


def test_an_encrypted_member_is_refused():
    data = bytearray(write_archive({"a.obj": TRIANGLE_OBJ}))
    at = data.rfind(b"PK\x01\x02")
    data[at + 8] |= 1  # the central directory's "encrypted" flag
    with pytest.raises(qem_core.MeshFormatError, match="encrypted"):
        open_archive(bytes(data))


def _central(data: bytearray) -> int:
    return data.rfind(b"PK\x01\x02")


def _no_name(data: bytearray) -> None:  # the name's bytes read as the entry's comment
    at = _central(data)
    data[at + 28 : at + 30], data[at + 32 : at + 34] = b"\0\0", (5).to_bytes(2, "little")


def _future_version(data: bytearray) -> None:
    at = _central(data)
    data[at + 4] = data[at + 6] = 163  # "needs zip 16.3"


def _bad_utf8_name(data: bytearray) -> None:  # the local header says UTF-8, holds 0x9b
    data[7] |= 0x08
    data[30] = 0x9B


def _directory_past_its_place(data: bytearray) -> None:  # member offsets go negative
    at = data.rfind(b"PK\x05\x06")
    offset = int.from_bytes(data[at + 16 : at + 20], "little")
    data[at + 16 : at + 20] = (offset + 100).to_bytes(4, "little")


@pytest.mark.parametrize(
    ("damage", "words"),
    [
        (_no_name, "has no name"),
        (_future_version, "not a readable zip archive .zip file version 16.3"),
        (_bad_utf8_name, "is damaged .'utf-8' codec"),
        (_directory_past_its_place, "is damaged .negative seek"),
    ],
)
def test_what_zipfile_raises_on_damaged_archives_is_a_refusal(damage, words):
    """Found by fuzz/ (zip target): IndexError, NotImplementedError, UnicodeDecodeError
    and ValueError from zipfile itself."""
    data = bytearray(write_archive({"a.obj": TRIANGLE_OBJ}))
    damage(data)
    with pytest.raises(qem_core.MeshFormatError, match=words):
        qem_core.load_mesh(bytes(data), format="zip")

"""The .qpm file: a saved and loaded progressive mesh is the same mesh; a damaged, forged
or future-version file is refused with CorruptFileError and a message saying why.

The forged files are written here from the layout documented in qem_core/qpm.py
(magic, uint32 version, uint32 header length, msgpack header, arrays, crc32 of every
byte before it), so a test can change one field and still carry a valid checksum.
"""

import struct
import zlib

import msgpack
import numpy as np
import pytest

import qem_core
from qem_core.qpm import FORMAT_VERSION, MAGIC
from tests.tiny_meshes import OCTAHEDRON, bumpy_grid, icosphere, perforated_icosphere

ARRAYS = (
    "base_vertices",
    "split_vertex",
    "split_positions",
    "face_corners",
    "level_faces",
    "relabel_offsets",
    "relabel_faces",
    "split_cost",
    "vertex_map",
)
MESHES = {
    "sphere": icosphere(2, jitter=0.05, seed=4),
    "perforated_sphere": perforated_icosphere(2, holes=3, seed=5),
    "bumpy_grid": bumpy_grid(6, seed=6),
}


@pytest.fixture(scope="module")
def built():
    return {name: qem_core.build(*mesh) for name, mesh in MESHES.items()}


@pytest.fixture(scope="module")
def saved(built, tmp_path_factory):
    """name -> the bytes of its .qpm file."""
    folder = tmp_path_factory.mktemp("qpm")
    out = {}
    for name, pm in built.items():
        path = folder / f"{name}.qpm"
        pm.save(path)
        out[name] = path.read_bytes()
    return out


def _fixed() -> int:
    return len(MAGIC) + 8


def _split(blob: bytes) -> tuple[int, dict, int]:
    """(version, header, data start) of a .qpm blob, read independently of qpm.py."""
    assert blob[: len(MAGIC)] == MAGIC
    version, header_length = struct.unpack_from("<II", blob, len(MAGIC))
    header = msgpack.unpackb(blob[_fixed() : _fixed() + header_length])
    return version, header, _fixed() + header_length


def _with_crc(body: bytes) -> bytes:
    return body + struct.pack("<I", zlib.crc32(body))


def _forge(blob: bytes, *, version=None, header=None, patch=None) -> bytes:
    """A copy of `blob` with its version, header or data bytes replaced, re-checksummed."""
    old_version, old_header, data_start = _split(blob)
    data = bytearray(blob[data_start:-4])
    if patch is not None:
        patch(data, old_header)
    packed = msgpack.packb(old_header if header is None else header)
    body = (
        MAGIC
        + struct.pack("<II", old_version if version is None else version, len(packed))
        + packed
        + bytes(data)
    )
    return _with_crc(body)


def _array_slice(header: dict, name: str) -> tuple[slice, np.dtype]:
    for entry_name, dtype, shape, offset in header["arrays"]:
        if entry_name == name:
            nbytes = int(np.prod(shape)) * np.dtype(dtype).itemsize
            return slice(offset, offset + nbytes), np.dtype(dtype)
    raise KeyError(name)


# -- round trip -------------------------------------------------------------------------


@pytest.mark.parametrize("name", MESHES)
def test_a_loaded_file_gives_the_same_arrays_metadata_and_levels(built, saved, tmp_path, name):
    pm = built[name]
    path = tmp_path / "copy.qpm"
    path.write_bytes(saved[name])
    for loaded in (qem_core.load(path), qem_core.load(saved[name])):
        assert (loaded.n_base, loaded.n_full) == (pm.n_base, pm.n_full)
        for array in ARRAYS:
            ours, theirs = getattr(pm, array), getattr(loaded, array)
            assert theirs.shape == ours.shape, array
            assert np.array_equal(theirs, ours), array
        assert loaded.metadata == pm.metadata
        np.testing.assert_array_equal(loaded.errors(), pm.errors())
        for n in range(pm.n_base, pm.n_full + 1):
            vertices, faces = pm.lod(n)
            loaded_vertices, loaded_faces = loaded.lod(n)
            assert loaded_vertices.tobytes() == vertices.tobytes()
            assert loaded_faces.tobytes() == faces.tobytes()
            assert loaded.error(n) == pm.error(n)


def test_saving_a_loaded_file_gives_the_same_bytes(saved, tmp_path):
    blob = saved["perforated_sphere"]
    path = tmp_path / "again.qpm"
    qem_core.load(blob).save(path)
    assert path.read_bytes() == blob


def test_saving_leaves_only_the_file_behind(built, tmp_path):
    built["sphere"].save(tmp_path / "a.qpm")
    built["sphere"].save(tmp_path / "a.qpm")  # over an existing file
    assert [p.name for p in tmp_path.iterdir()] == ["a.qpm"]


def test_the_file_follows_the_documented_layout(saved):
    blob = saved["sphere"]
    version, header, data_start = _split(blob)
    assert version == 1
    assert zlib.crc32(blob[:-4]) == struct.unpack("<I", blob[-4:])[0]
    assert [entry[0] for entry in header["arrays"]] == list(ARRAYS)
    assert all(entry[3] % 8 == 0 for entry in header["arrays"])
    # A forged copy with nothing changed is still a valid file.
    assert _forge(blob) == blob


# -- damage -----------------------------------------------------------------------------


def _corrupt(blob: bytes, match: str):
    with pytest.raises(qem_core.CorruptFileError, match=match) as info:
        qem_core.load(blob)
    return info


@pytest.mark.parametrize("where", ["header", "first array", "middle", "last array", "crc"])
def test_a_flipped_byte_is_a_checksum_error(saved, where):
    blob = saved["sphere"]
    _, header, data_start = _split(blob)
    position = {
        "header": _fixed() + 3,
        "first array": data_start + 5,
        "middle": (data_start + len(blob)) // 2,
        "last array": len(blob) - 7,
        "crc": len(blob) - 2,
    }[where]
    for bit in (0x01, 0x80):
        damaged = bytearray(blob)
        damaged[position] ^= bit
        _corrupt(bytes(damaged), "checksum")


@pytest.mark.parametrize("keep", [0, 1, 7, 12, 15, 40, -200, -5, -4, -1])
def test_a_truncated_file_is_refused(saved, keep):
    blob = saved["sphere"]
    _corrupt(blob[:keep], "magic|checksum|truncated")


def test_extra_bytes_after_the_checksum_are_refused(saved):
    _corrupt(saved["sphere"] + b"\0\0\0\0", "checksum")


@pytest.mark.parametrize(
    "magic", [b"QEMPM\x00\n\n", b"qempm\x00\r\n", b"PK\x03\x04\x00\x00\x00\x00", b"ply\n\0\0\0\0"]
)
def test_a_wrong_magic_is_not_a_qpm_file(saved, magic):
    blob = saved["sphere"]
    # Checksummed, so only the magic is wrong.
    info = _corrupt(_with_crc(magic + blob[len(MAGIC) : -4]), "not a .qpm file")
    assert "magic" in str(info.value)


def test_a_text_file_is_not_a_qpm_file(tmp_path):
    path = tmp_path / "mesh.qpm"
    path.write_text("ply\nformat ascii 1.0\nend_header\n")
    with pytest.raises(qem_core.CorruptFileError, match="not a .qpm file"):
        qem_core.load(path)


@pytest.mark.parametrize("version", [FORMAT_VERSION + 1, FORMAT_VERSION + 2, 0xFFFFFFFF])
def test_a_future_version_is_refused_even_with_a_valid_checksum(saved, version):
    forged = _forge(saved["sphere"], version=version)
    info = _corrupt(forged, f"version {version} is newer")
    assert "upgrade" in str(info.value)


def test_version_zero_is_refused(saved):
    _corrupt(_forge(saved["sphere"], version=0), "version 0 is not valid")


def test_an_unreadable_header_is_refused(saved):
    blob = saved["sphere"]
    _, header, data_start = _split(blob)
    length = data_start - _fixed()
    body = MAGIC + struct.pack("<II", 1, length) + b"\xc1" * length + blob[data_start:-4]
    _corrupt(_with_crc(body), "header is unreadable")


def test_a_missing_array_is_refused(saved):
    _, header, _ = _split(saved["sphere"])
    header["arrays"] = [entry for entry in header["arrays"] if entry[0] != "relabel_faces"]
    _corrupt(_forge(saved["sphere"], header=header), "lacks the array 'relabel_faces'")


def test_an_array_reaching_past_the_data_is_refused(saved):
    _, header, _ = _split(saved["sphere"])
    for entry in header["arrays"]:
        if entry[0] == "face_corners":
            entry[3] += 10**6
    _corrupt(_forge(saved["sphere"], header=header), "'face_corners' lies outside the file")


def test_an_array_of_the_wrong_dtype_is_refused(saved):
    _, header, _ = _split(saved["sphere"])
    for entry in header["arrays"]:
        if entry[0] == "split_vertex":
            entry[1] = "<f4"
    _corrupt(_forge(saved["sphere"], header=header), "'split_vertex' has dtype")


def test_metadata_without_the_bounding_box_is_refused(saved):
    _, header, _ = _split(saved["sphere"])
    del header["metadata"]["bbox"]
    _corrupt(_forge(saved["sphere"], header=header), "bounding box")


def _set_value(name: str, index: int, value):
    def patch(data: bytearray, header: dict) -> None:
        where, dtype = _array_slice(header, name)
        values = np.frombuffer(bytes(data[where]), dtype).copy()
        values.reshape(-1)[index] = value
        data[where] = values.tobytes()

    return patch


@pytest.mark.parametrize(
    "name, index, value, match",
    [
        # A split naming a vertex that does not exist yet (the kernel would write
        # out of bounds if this went through).
        ("split_vertex", 0, 10**6, "does not exist yet"),
        ("split_vertex", -1, -3, "does not exist yet"),
        # A face corner beyond the vertices of its level.
        ("face_corners", -1, 2**31 - 1, "does not exist at its level"),
        # The base mesh using a vertex that is not in it.
        ("face_corners", 0, 10**5, "base faces use vertices outside"),
        # A relabel of a face not yet born.
        ("relabel_faces", 0, 10**7, "relabels a face that does not exist"),
        ("relabel_offsets", -1, 0, "relabel"),
        ("level_faces", 1, 0, "face counts per level"),
        # Non-finite numbers: they reached the stream encoder, which raised a bare
        # ValueError or, with an inf and a huge value together, spun for minutes.
        ("split_positions", 4, np.inf, "split_positions holds a non-finite"),
        ("base_vertices", 1, np.nan, "base_vertices holds a non-finite"),
        ("split_cost", 0, np.nan, "split costs hold a NaN"),
    ],
)
def test_checksummed_but_inconsistent_arrays_are_refused(saved, name, index, value, match):
    """A file written by a buggy or hostile writer, with a valid checksum: loading
    checks every index the refinement follows."""
    forged = _forge(saved["perforated_sphere"], patch=_set_value(name, index, value))
    _corrupt(forged, match)


def test_a_relabel_of_a_face_without_the_split_vertex_is_refused(built, saved):
    """Every index in range, checksum valid, but a split relabels a face that has no
    corner at its vertex: the levels would be wrong and the stream encoder would stop,
    so loading replays the splits and refuses the file."""
    pm = built["perforated_sphere"]
    k = int(np.searchsorted(pm.relabel_offsets, 0, side="right")) - 1  # split of entry 0
    s = int(pm.split_vertex[k])
    _, faces = pm.lod(pm.n_base + k)
    elsewhere = next(f for f in range(faces.shape[0]) if s not in faces[f])
    forged = _forge(saved["perforated_sphere"], patch=_set_value("relabel_faces", 0, elsewhere))
    _corrupt(forged, "no corner at their split's vertex")


_DROP = object()  # as a value: delete the entry's field instead


def _entry_changed(blob: bytes, name: str, index: int, value) -> bytes:
    _, header, _ = _split(blob)
    for entry in header["arrays"]:
        if entry[0] == name:
            if value is _DROP:
                del entry[index]
            else:
                entry[index] = value
    return _forge(blob, header=header)


@pytest.mark.parametrize(
    "name, index, value",
    [
        ("split_cost", 3, _DROP),  # an entry without its offset
        ("level_faces", 2, ["x"]),  # a shape that is not integers
        ("level_faces", 2, 7),  # a shape that is not a list
        ("base_vertices", 2, [-4, 3]),  # a negative dimension
        ("level_faces", 3, "zero"),  # an offset that is not an integer
        ("level_faces", 3, -8),  # a negative offset
        # A shape whose byte count wraps around in int64 (2^40 * 2^40 * 8): it must
        # not pass as a small or negative size.
        ("base_vertices", 2, [2**40, 2**40]),
    ],
)
def test_a_malformed_array_entry_is_refused(saved, name, index, value):
    """Regression: these escaped as ValueError or TypeError before qpm.py checked the
    entries (and the int64 overflow read the wrong bytes)."""
    with pytest.raises(qem_core.CorruptFileError, match=name):
        qem_core.load(_entry_changed(saved["sphere"], name, index, value))


@pytest.mark.parametrize(
    "metadata",
    [
        "bbox", ["bbox"], 7, {"bbox": "everywhere"}, {"bbox": [0, 1]}, {"bbox": None},
        {"bbox": [[0, 0, 0], [1, float("inf"), 1]]},
    ],
)
def test_metadata_that_is_not_a_map_with_a_2x3_bbox_is_refused(saved, metadata):
    """Regression: a metadata string or list containing "bbox" passed the check and
    failed in ProgressiveMesh with ValueError; a bbox of the wrong shape failed later."""
    _, header, _ = _split(saved["sphere"])
    header["metadata"] = metadata
    _corrupt(_forge(saved["sphere"], header=header), "bounding box")


def test_a_header_that_is_not_a_map_is_refused(saved):
    _, header, _ = _split(saved["sphere"])
    for forged in ([header], {**header, "arrays": 7}, {**header, "arrays": [[1, 2]]}):
        with pytest.raises(qem_core.CorruptFileError):
            qem_core.load(_forge(saved["sphere"], header=forged))


def test_every_truncation_and_flipped_byte_of_a_small_file_is_refused(tmp_path):
    """Exhaustive on an octahedron's file (a few hundred bytes)."""
    path = tmp_path / "octahedron.qpm"
    qem_core.build(*OCTAHEDRON).save(path)
    blob = path.read_bytes()
    for length in range(len(blob)):
        with pytest.raises(qem_core.CorruptFileError):
            qem_core.load(blob[:length])
    for position in range(len(blob)):
        damaged = bytearray(blob)
        damaged[position] ^= 0x10
        with pytest.raises(qem_core.CorruptFileError):
            qem_core.load(bytes(damaged))

"""Hostile .qpm files with a valid checksum: `qem_core.load` refuses each with a
CorruptFileError naming what is wrong, checked where the value is read (no foreign
exception, no level served wrong).

The reproducer cases of fuzz findings r01 and r08 (attribute metadata, shapes
[2^63 - 1, 0] and [True], widths [inf]) and the raw fuzzer inputs are in
test_fuzz_findings.py; these are the cases found after them, by review and by a run of
the loader and its kernels under NUMBA_BOUNDSCHECK=1 on mutated files.
"""

from __future__ import annotations

import struct
import zlib

import msgpack
import numpy as np
import pytest

import qem_core
from qem_core.progressive import ProgressiveMesh, apply_splits, apply_wedge_splits
from tests.tiny_meshes import TETRAHEDRON, bumpy_grid

TETRAHEDRON_V, TETRAHEDRON_F = TETRAHEDRON


@pytest.fixture(scope="module")
def uv_qpm(tmp_path_factory) -> bytes:
    """A tetrahedron with corner UVs, saved (version 2, with the wedge arrays)."""
    uvs = np.random.default_rng(0).random((4, 3, 2)).astype(np.float32)
    pm = qem_core.build_mesh(qem_core.Mesh(TETRAHEDRON_V, TETRAHEDRON_F, corner_uvs=uvs))
    pm.metadata["name"] = "tetrahedron.obj"
    path = tmp_path_factory.mktemp("qpm") / "a.qpm"
    pm.save(path)
    return path.read_bytes()


@pytest.fixture(scope="module")
def grid_pm():
    """A bumpy grid with corner UVs: dozens of splits, each with wedge records."""
    vertices, faces = bumpy_grid(6, seed=6)[:2]
    uvs = np.random.default_rng(1).random((len(faces), 3, 2)).astype(np.float32)
    return qem_core.build_mesh(qem_core.Mesh(vertices, faces, corner_uvs=uvs))


@pytest.fixture(scope="module")
def grid_qpm(grid_pm, tmp_path_factory) -> bytes:
    path = tmp_path_factory.mktemp("qpm") / "grid.qpm"
    grid_pm.save(path)
    return path.read_bytes()


def _sealed(body: bytes) -> bytes:
    return body + struct.pack("<I", zlib.crc32(body))


def _patched(blob: bytes, change) -> bytes:
    """The .qpm with its msgpack header changed and its CRC-32 made right again."""
    length = struct.unpack_from("<I", blob, 12)[0]
    header = msgpack.unpackb(blob[16 : 16 + length], raw=False)
    change(header)
    packed = msgpack.packb(header)
    return _sealed(blob[:12] + struct.pack("<I", len(packed)) + packed + blob[16 + length : -4])


def _entry(name, index, value):
    def change(header):
        for entry in header["arrays"]:
            if entry[0] == name:
                entry[index] = value

    return change


def _metadata(**values):
    return lambda header: header["metadata"].update(**values)


def _arrays(value):
    return lambda header: header.update(arrays=value)


def _duplicate_entry(header):
    header["arrays"].append(list(header["arrays"][0]))


@pytest.mark.parametrize(
    ("change", "words"),
    [
        # Every dimension within 2^48, but 2^96 elements: numpy raised ValueError at reshape
        # though the array is 0 bytes (r08 a, checked per dimension only, in three).
        pytest.param(
            _entry("split_positions", 2, [2**48, 2**48, 0]),
            r"shape \[2814.*more than 2\^48",
            id="3d-shape-2^96-elements",
        ),
        pytest.param(
            _entry("split_positions", 2, [0, 2**48, 2**48]),
            r"more than 2\^48 elements",
            id="3d-shape-2^96-elements-leading-0",
        ),
        # The messages name the entry and its value.
        pytest.param(
            _entry("relabel_faces", 2, [True]),
            r"'relabel_faces'.*shape \[True\]",
            id="bool-dimension-named",
        ),
        pytest.param(
            _entry("level_faces", 3, 2**49),
            r"'level_faces'.*offset 562949953421312",
            id="offset-past-2^48-named",
        ),
        pytest.param(
            _entry("split_vertex", 1, "<i8"), r"'split_vertex' has dtype '<i8'", id="dtype-named"
        ),
        # The header's structure: these went through one catch-all as "unreadable".
        pytest.param(_arrays(7), "'arrays' is int, not a list", id="arrays-not-a-list"),
        pytest.param(
            _arrays([[["x"], "<f8", [0], 0]]), "array entry without a name", id="entry-name-a-list"
        ),
        pytest.param(_arrays([7]), "array entry without a name", id="entry-not-a-list"),
        pytest.param(_duplicate_entry, "names the array 'base_vertices' twice", id="entry-twice"),
        # The bounding box: plain numbers, min at or below max (numpy read "1", b"1" and
        # True as numbers).
        pytest.param(
            _metadata(bbox=[[0, 0, 0], ["1", 1, 1]]), "not 2 x 3 numbers", id="bbox-string"
        ),
        pytest.param(
            _metadata(bbox=[[0, 0, True], [1, 1, 1]]), "not 2 x 3 numbers", id="bbox-bool"
        ),
        pytest.param(
            _metadata(bbox=[[0, 0, 0], [b"1", 1, None]]),
            "not 2 x 3 numbers",
            id="bbox-bytes-and-none",
        ),
        pytest.param(
            _metadata(bbox=[[0, 0, 0], [1, 1]]), "not 2 x 3 numbers", id="bbox-short-corner"
        ),
        pytest.param(
            _metadata(bbox=[[0, 2, 0], [1, 1, 1]]), "min above max", id="bbox-min-above-max"
        ),
        pytest.param(
            _metadata(name=["tetrahedron"]),
            r"name \['tetrahedron'\] is not a string",
            id="name-not-a-string",
        ),
    ],
)
def test_a_crafted_header_is_refused_by_load(uv_qpm, change, words):
    with pytest.raises(qem_core.CorruptFileError, match=words):
        qem_core.load(_patched(uv_qpm, change))


def test_a_header_length_past_the_end_of_the_file_is_refused(uv_qpm):
    body = bytearray(uv_qpm[:-4])
    struct.pack_into("<I", body, 12, len(uv_qpm))
    with pytest.raises(qem_core.CorruptFileError, match="header length .* runs past the end"):
        qem_core.load(_sealed(bytes(body)))


def test_a_saved_mesh_with_attributes_round_trips(uv_qpm):
    """What the checks above must let through: the file as `save` writes it, its name
    and box included, gives the levels of the mesh it was built from."""
    pm = qem_core.load(uv_qpm)
    assert pm.metadata["name"] == "tetrahedron.obj"
    assert pm.attribute_layout is not None and pm.attribute_layout.corner_uvs
    for n in (pm.n_base, pm.n_full):
        level = pm.lod_mesh(n)
        assert level.name == "tetrahedron.obj"
        assert level.corner_uvs is not None and np.isfinite(level.corner_uvs).all()
    uvs = np.random.default_rng(0).random((4, 3, 2)).astype(np.float32)
    full = pm.lod_mesh(pm.n_full)
    np.testing.assert_allclose(
        _corners(full.vertices, full.faces, full.corner_uvs),
        _corners(TETRAHEDRON_V, TETRAHEDRON_F, uvs),
        atol=1e-5,
    )


def _corners(vertices, faces, uvs) -> np.ndarray:
    """(3F, 5) rows of position and UV per face corner, sorted: the same for a mesh
    whatever its vertex and face numbering."""
    rows = np.concatenate([vertices[faces].reshape(-1, 3), uvs.reshape(-1, 2)], axis=1)
    return rows[np.lexsort(rows.T[::-1])]


def _with_values(blob: bytes, name: str, values: dict[int, float]) -> bytes:
    """The .qpm with elements of array ``name`` set (index -> value), CRC-32 made right."""
    length = struct.unpack_from("<I", blob, 12)[0]
    header = msgpack.unpackb(blob[16 : 16 + length], raw=False)
    (_, dtype, shape, offset) = next(e for e in header["arrays"] if e[0] == name)
    at = 16 + length + offset
    size = int(np.prod(shape)) * np.dtype(dtype).itemsize
    array = np.frombuffer(blob[at : at + size], dtype).copy()
    for index, value in values.items():
        array[index] = value
    return _sealed(blob[:at] + array.tobytes() + blob[at + size : -4])


# Offsets a, 2^63 - 1, -2^63, -2^62, b: every int64 step (np.diff) is positive once
# wrapped around and the steps add up to b - a, so the checks by np.diff passed and
# np.repeat over the steps wrote past the small array it allocated (a segfault, or
# glibc's "malloc(): unaligned tcache chunk detected"). Found under NUMBA_BOUNDSCHECK=1
# (wedge_update_offsets): likely the fuzz findings' two unattributed aborts.
_WRAPPING = {2: 2**63 - 1, 3: -(2**63), 4: -(2**62)}


@pytest.mark.parametrize(
    ("name", "words"),
    [
        ("level_faces", "face counts per level are inconsistent"),
        ("relabel_offsets", "relabel offsets decrease"),
        ("wedge_update_offsets", "update offsets are not one non-decreasing"),
        ("wedge_new_offsets", "new wedge offsets are not one non-decreasing"),
        ("wedge_relabel_offsets", "relabel offsets are not one non-decreasing"),
    ],
)
def test_offsets_whose_steps_wrap_around_in_int64_are_refused(grid_qpm, name, words):
    with pytest.raises(qem_core.CorruptFileError, match=words):
        qem_core.load(_with_values(grid_qpm, name, _WRAPPING))


def _wrapping_counts(splits):
    """(2^62, 2^62, 2^62, 2^62 + F, 0...): int64 adds them up to F, the new faces."""
    counts = np.zeros(splits.new_face_counts.shape, np.int64)
    counts[:4] = 2**62
    counts[3] += splits.new_faces.shape[0]
    return counts


def test_split_counts_that_wrap_around_in_int64_are_refused_by_apply_splits(grid_pm):
    start = grid_pm.n_base
    splits = grid_pm.splits(start, start + 6)
    forged = splits._replace(new_face_counts=_wrapping_counts(splits))
    with pytest.raises(qem_core.CorruptFileError, match="new face counts do not add up"):
        apply_splits(*grid_pm.lod(start), forged)


def _uint64_counts(splits):
    """(2^63, 2^63, F, 0...) as uint64: past int64, and adding up to F in it."""
    counts = np.zeros(splits.new_face_counts.shape, np.uint64)
    counts[:3] = [2**63, 2**63, splits.new_faces.shape[0]]
    return counts


@pytest.mark.parametrize("forge", [_wrapping_counts, _uint64_counts])
def test_split_counts_that_wrap_around_are_refused_by_apply_wedge_splits(grid_pm, forge):
    start = grid_pm.n_base
    splits = grid_pm.splits(start, start + 6)
    forged = splits._replace(new_face_counts=forge(splits))
    with pytest.raises(qem_core.CorruptFileError, match="new face counts do not add up"):
        apply_wedge_splits(*grid_pm.wedge_level(start), forged)


def test_apply_wedge_splits_takes_unsigned_counts(grid_pm):
    """uint64 counts that fit (np.repeat refused them with a TypeError)."""
    start = grid_pm.n_base
    splits = grid_pm.splits(start, start + 6)
    unsigned = splits._replace(new_face_counts=splits.new_face_counts.astype(np.uint64))
    level = grid_pm.wedge_level(start)
    for got, expected in zip(
        apply_wedge_splits(*level, unsigned), apply_wedge_splits(*level, splits), strict=True
    ):
        np.testing.assert_array_equal(got, expected)


def test_positions_wider_apart_than_float64_spans_are_refused(grid_qpm):
    """Found by the run under bounds checking: finite positions at -1e308 and 1e308 loaded,
    and the stream's grid over them put offsets at infinity (numpy's overflow warning)."""
    forged = _with_values(grid_qpm, "base_vertices", {1: 1e308, 4: -1e308})
    with pytest.raises(qem_core.CorruptFileError, match="wider than float64 holds"):
        qem_core.load(forged)


def test_a_mesh_without_vertices_is_refused(tmp_path):
    """Found by review: it loaded, and a level's encoder or the stream raised numpy's
    ValueError taking the minimum of no positions."""
    empty = ProgressiveMesh(
        base_vertices=np.zeros((0, 3)),
        split_vertex=np.zeros(0, np.int32),
        split_positions=np.zeros((0, 2, 3)),
        face_corners=np.zeros((0, 3), np.int32),
        level_faces=np.zeros(1, np.int64),
        relabel_offsets=np.zeros(1, np.int64),
        relabel_faces=np.zeros(0, np.int32),
        split_cost=np.zeros(0),
        metadata={"bbox": [[0, 0, 0], [0, 0, 0]]},
    )
    empty.save(tmp_path / "empty.qpm")
    with pytest.raises(qem_core.CorruptFileError, match="base mesh has no vertices"):
        qem_core.load(tmp_path / "empty.qpm")

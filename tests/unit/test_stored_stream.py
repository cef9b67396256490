"""qem_core.stored_stream: the whole stream of key frames, its index, runs of frames that
decode on their own, and indexes that lie."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import qem_core
from qem_core import stream as split_stream
from qem_core.stored_stream import StreamIndex, encode_stored_stream, index_stream
from tests.reference import assert_decoded_level
from tests.tiny_meshes import icosphere
from tests.wedge_meshes import seamed_mesh


@pytest.fixture(scope="module")
def pm():
    return qem_core.build(*icosphere(4))  # 2562 vertices: several frames


@pytest.fixture(scope="module")
def stored(pm):
    return encode_stored_stream(pm, threads=2)


def _decode_run(pm, index: StreamIndex, data: bytes, i: int, j: int, stop: int | None = None):
    """Decode frames [i, j) from lod(vertices[i]) as a client holding that level would."""
    n = index.vertices[i]
    vertices, faces = pm.lod(n)
    grid = split_stream.grid_for(pm)
    decoder = split_stream.SplitStreamDecoder(
        grid.quantise(vertices), faces, split_stream.quantised_wedges(pm, n), grid
    )
    start, stop_byte = index.byte_span(i, j)
    for payload in split_stream.iter_frames([data[start:stop_byte]]):
        decoder.feed(payload, stop=stop)
    return decoder


def test_the_stored_stream_is_the_stream_of_key_frames(pm, stored):
    data, index = stored
    sequential = b"".join(
        split_stream.encode_split_frames(pm, pm.n_base, pm.n_full, key_frames=True)
    )
    assert data == sequential
    assert encode_stored_stream(pm, threads=1)[0] == data  # threads do not change a byte
    assert index_stream(data) == index
    assert index.vertices[0] == pm.n_base and index.vertices[-1] == pm.n_full
    assert index.faces == tuple(pm.n_faces(n) for n in index.vertices)
    assert index.n_frames >= 3
    index.check(data)


def test_key_frames_cost_little_against_shared_contexts(pm, stored):
    shared = sum(map(len, split_stream.encode_split_frames(pm, pm.n_base, pm.n_full)))
    assert shared < len(stored[0]) < 1.03 * shared


@pytest.mark.parametrize("run", [(0, 1), (1, 3), (2, None), (0, None)])
def test_every_run_of_frames_decodes_on_its_own(pm, stored, run):
    data, index = stored
    i, j = run[0], index.n_frames if run[1] is None else run[1]
    assert_decoded_level(_decode_run(pm, index, data, i, j), pm, index.vertices[j])


def test_a_stream_with_wedges_runs_from_any_frame():
    pm = qem_core.build_mesh(seamed_mesh(*icosphere(4), seed=2, colours=False, normals=True))
    data, index = encode_stored_stream(pm, threads=2)
    assert index.n_frames >= 2
    decoder = _decode_run(pm, index, data, 1, index.n_frames)
    assert_decoded_level(decoder, pm, pm.n_full)
    held = split_stream.quantised_wedges(pm, pm.n_full)
    np.testing.assert_array_equal(decoder.face_wedges, held.face_wedges)
    np.testing.assert_array_equal(decoder.quantised_values, held.values)
    # Stopped inside a frame: exactly that level, wedges too.
    stop = (index.vertices[1] + index.vertices[2]) // 2
    decoder = _decode_run(pm, index, data, 1, 2, stop=stop)
    assert_decoded_level(decoder, pm, stop)
    held = split_stream.quantised_wedges(pm, stop)
    np.testing.assert_array_equal(decoder.face_wedges, held.face_wedges)
    np.testing.assert_array_equal(decoder.quantised_values, held.values)


@settings(max_examples=200, deadline=None)
@given(st.data())
def test_covering_is_the_smallest_run(stored, data):
    index = stored[1]
    low, high = index.vertices[0], index.vertices[-1]
    n1 = data.draw(st.integers(low - 5, high + 5))
    n2 = data.draw(st.integers(n1, high + 10))
    i, j = index.covering(n1, n2)
    c1, c2 = min(max(n1, low), high), min(max(n2, low), high)
    if c1 == c2:
        assert i == j
        return
    assert index.vertices[i] <= c1 < index.vertices[i + 1]
    assert index.vertices[j - 1] < c2 <= index.vertices[j]


def test_a_mesh_without_splits_has_an_empty_stream():
    pm = qem_core.build(*icosphere(0))
    pm_base = qem_core.build(*pm.lod(pm.n_base))
    assert pm_base.n_base == pm_base.n_full
    data, index = encode_stored_stream(pm_base)
    assert data == b"" and index.n_frames == 0 and index.covering(1, 10**9) == (0, 0)


def _index_json(index: StreamIndex, **changes) -> bytes:
    message = json.loads(index.to_json())
    message.update(changes)
    return json.dumps(message).encode()


@pytest.mark.parametrize(
    "changes, message",
    [
        ({"format": "other"}, "not a split stream index"),
        ({"version": 2}, "version 2"),
        ({"version": True}, "version True"),
        ({"vertices": [1, 2]}, "differ in length"),
        ({"offsets": "x"}, "must be lists"),
        ({"crc32": -1}, "must be integers"),
        ({"stream_version": 2}, "frames of version 2"),
        ({"bytes": 5}, "do not span"),
    ],
)
def test_an_index_that_lies_is_refused(stored, changes, message):
    with pytest.raises(qem_core.CorruptFileError, match=message):
        StreamIndex.from_json(_index_json(stored[1], **changes))


def test_an_index_whose_counts_do_not_grow_is_refused(stored):
    index = stored[1]
    vertices = list(index.vertices)
    vertices[1], vertices[2] = vertices[2], vertices[1]
    with pytest.raises(qem_core.CorruptFileError, match="do not grow"):
        StreamIndex.from_json(_index_json(index, vertices=vertices))
    for bad in (b"", b"{", b"[]", "\u2603".encode()):
        with pytest.raises(qem_core.CorruptFileError):
            StreamIndex.from_json(bad)


def test_check_finds_a_flipped_bit_or_a_short_stream(stored):
    data, index = stored
    flipped = bytearray(data)
    flipped[len(data) // 3] ^= 1
    with pytest.raises(qem_core.CorruptFileError, match="CRC-32"):
        index.check(bytes(flipped))
    with pytest.raises(qem_core.CorruptFileError, match="its index says"):
        index.check(data[:-1])


def test_index_stream_refuses_frames_that_do_not_follow(pm, stored):
    data, index = stored
    a, b = index.byte_span(0, 1)
    c, d = index.byte_span(2, 3)
    with pytest.raises(qem_core.CorruptFileError, match="the previous ended"):
        index_stream(data[a:b] + data[c:d])
    shared = b"".join(split_stream.encode_split_frames(pm, pm.n_base, pm.n_full))
    with pytest.raises(qem_core.CorruptFileError, match="key frames only"):
        index_stream(shared)

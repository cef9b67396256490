"""The split stream's wedge side (version 3): splits n1 -> n2 carry the appearance, the
stream refines the quantised wedges of lod(n1) into exactly those of lod(n2), and a
damaged wedge field is refused with CorruptFileError (flipped bytes and truncations of
frames with wedges: test_stream.py).
"""

import re
import struct
import zlib

import msgpack
import numpy as np
import pytest

import qem_core
from qem_core.codecs.msgpack_mesh import read_msgpack_wedges
from qem_core.stream import (
    STREAM_VERSION,
    SplitStreamDecoder,
    encode_split_frames,
    grid_for,
    iter_frames,
    new_wedge_contexts,
    quantised_wedges,
    wedge_grid_for,
)
from tests.tiny_meshes import icosphere
from tests.wedge_meshes import seamed_mesh, wedge_arrays, with_wedge_arrays


@pytest.fixture(scope="module")
def coloured_pm():
    """A small sphere with seamed UVs, 8-bit colours and normals: every attribute."""
    vertices, faces = icosphere(2, jitter=0.05, seed=4)
    return qem_core.build_mesh(seamed_mesh(vertices, faces, seed=4, normals=True))


def _decode(pm, n1, n2, **options):
    """The stream n1 -> n2 decoded onto lod(n1) quantised, wedges included."""
    vertices, faces = pm.lod(n1)
    decoder = SplitStreamDecoder(grid_for(pm).quantise(vertices), faces, quantised_wedges(pm, n1))
    for payload in iter_frames(encode_split_frames(pm, n1, n2, **options)):
        decoder.feed(payload)
    return decoder


def _check_decoded(pm, decoder, n2):
    """Integers bit for bit; the level's attributes within half a grid step."""
    expected = quantised_wedges(pm, n2)
    vertices, faces = pm.lod(n2)
    assert np.array_equal(decoder.faces, faces)
    assert np.array_equal(decoder.quantised, grid_for(pm).quantise(vertices))
    assert np.array_equal(decoder.face_wedges, expected.face_wedges)
    assert np.array_equal(decoder.quantised_values, expected.values)
    scales = pm.attribute_layout.scales
    decoded = pm.as_mesh(
        vertices, faces, decoder.face_wedges, (decoder.wedge_values * scales).astype(np.float32)
    )
    exact = pm.lod_mesh(n2)
    step = expected.grid.step
    column = 0
    for name, width in zip(expected.grid.names, expected.grid.widths, strict=True):
        half = step[column : column + width] / 2 + 1e-6
        column += width
        if name == "uv" and pm.attribute_layout.corner_uvs:
            error = np.abs(decoded.corner_uvs - exact.corner_uvs).reshape(-1, width)
        else:
            error = np.abs(decoded.vertex_attributes[name] - exact.vertex_attributes[name])
        # A normal is a mean renormalised: its error may reach a whole step.
        assert np.all(error <= (2 * half if name == "normal" else half)), name


def _picks(pm, count=5):
    return np.unique(np.linspace(pm.n_base, pm.n_full, count).astype(int)).tolist()


# -- the split data --------------------------------------------------------------------


@pytest.mark.parametrize("fixture", ["spot_pm", "coloured_pm"])
def test_splits_carry_the_wedges_so_lod_n1_refines_into_lod_n2(fixture, request):
    pm = request.getfixturevalue(fixture)
    for n1 in _picks(pm):
        for n2 in _picks(pm):
            if n1 > n2:
                continue
            splits = pm.splits(n1, n2)
            vertices, faces = qem_core.apply_splits(*pm.lod(n1), splits)
            face_wedges, values = qem_core.apply_wedge_splits(*pm.wedge_level(n1), splits)
            expected_wedges, expected_values = pm.wedge_level(n2)
            assert np.array_equal(face_wedges, expected_wedges)
            assert np.array_equal(values, expected_values)
            refined, exact = pm.as_mesh(vertices, faces, face_wedges, values), pm.lod_mesh(n2)
            assert np.array_equal(refined.faces, exact.faces)
            for name, column in exact.vertex_attributes.items():
                assert np.array_equal(refined.vertex_attributes[name], column)
            if exact.corner_uvs is not None:
                assert np.array_equal(refined.corner_uvs, exact.corner_uvs)


def test_wedge_splits_refuse_the_wrong_level_and_damaged_records(spot_pm):
    n1, n2 = spot_pm.n_base + 100, spot_pm.n_base + 300
    splits = spot_pm.splits(n1, n2)
    face_wedges, values = spot_pm.wedge_level(n1)
    with pytest.raises(qem_core.InvalidOptionsError, match="start from"):
        qem_core.apply_wedge_splits(face_wedges[:-1], values, splits)
    with pytest.raises(qem_core.InvalidOptionsError, match="start from"):
        qem_core.apply_wedge_splits(face_wedges, values[:-1], splits)
    geometry_only = qem_core.build(*icosphere(1))
    with pytest.raises(qem_core.InvalidOptionsError, match="no wedges"):
        qem_core.apply_wedge_splits(face_wedges, values, geometry_only.splits(12, 14))
    w = splits.wedges
    damaged = [
        w._replace(relabel_to=w.relabel_to + 10**6),
        w._replace(relabel_corners=w.relabel_corners * 0 - 1),
        w._replace(update_ids=w.update_ids + 10**6),
        w._replace(new_face_wedges=w.new_face_wedges[:-1]),
        w._replace(new_offsets=w.new_offsets[::-1]),
        w._replace(update_values=w.update_values[:, :1]),
    ]
    for wedges in damaged:
        with pytest.raises(qem_core.CorruptFileError, match="inconsistent wedge"):
            qem_core.apply_wedge_splits(face_wedges, values, splits._replace(wedges=wedges))
    # A face corner naming a wedge that is not there (as_mesh then indexed past them).
    with pytest.raises(qem_core.InvalidOptionsError, match="names a wedge outside"):
        qem_core.apply_wedge_splits(face_wedges + values.shape[0], values, splits)
    # Left alone, the inputs are not modified.
    assert np.array_equal(face_wedges, spot_pm.wedge_level(n1)[0])


# -- the stream ------------------------------------------------------------------------


@pytest.mark.parametrize("fixture", ["spot_pm", "coloured_pm"])
def test_stream_refines_the_wedges_exactly(fixture, request):
    pm = request.getfixturevalue(fixture)
    for n1 in _picks(pm):
        for n2 in _picks(pm):
            if n1 < n2:
                _check_decoded(pm, _decode(pm, n1, n2, splits_per_frame=300), n2)


def test_colours_are_8_bit_on_the_grid_exactly(coloured_pm):
    """Colours of the files are k / 255: the colour grid holds them without rounding."""
    grid = wedge_grid_for(coloured_pm)
    colour = grid.names.index("color")
    column = sum(grid.widths[:colour])
    assert grid.bits[colour] == 8
    np.testing.assert_allclose(grid.origin[column : column + 3], 0.0)
    np.testing.assert_allclose(grid.step[column : column + 3], 1 / 255)


def test_symbols_are_mostly_zero_and_values_cost_what_the_bench_says(spot_pm):
    """The predictions hold for most corners of spot (a figure, not a proof), and the
    range-coded wedges cost less than the deflated byte planes did (5.93 B a split)."""
    coded = n_symbols = n_nonzero = 0
    probs = new_wedge_contexts(2)  # spot's UVs; carried from frame to frame
    for frame in encode_split_frames(spot_pm, spot_pm.n_base, spot_pm.n_full):
        body = msgpack.unpackb(frame[4:-4])
        symbols = wedge_arrays(body, probs).symbols
        n_symbols += symbols.size
        n_nonzero += int(np.count_nonzero(symbols))
        coded += len(body["wedges"])
    assert n_nonzero < 0.05 * n_symbols
    assert coded / spot_pm.n_splits < 5.5


def test_meshes_without_attributes_have_no_wedge_keys():
    pm = qem_core.build(*icosphere(2, jitter=0.05, seed=1))
    for frame in encode_split_frames(pm, pm.n_base, pm.n_full):
        body = msgpack.unpackb(frame[4:-4])
        assert body["version"] == STREAM_VERSION
        assert not any(key.startswith("wedge") for key in body)


def test_a_decoder_without_wedges_refines_the_geometry_alone(spot_pm):
    vertices, faces = spot_pm.lod(spot_pm.n_base)
    decoder = SplitStreamDecoder(grid_for(spot_pm).quantise(vertices), faces)
    for payload in iter_frames(encode_split_frames(spot_pm, spot_pm.n_base, spot_pm.n_full)):
        decoder.feed(payload)
    assert np.array_equal(decoder.faces, spot_pm.lod(spot_pm.n_full)[1])
    assert decoder.face_wedges is None and decoder.wedge_values is None


def test_a_served_msgpack_level_starts_a_decoder(spot_pm):
    """lod(n1) as the server writes it (u16 positions, wedges) -> from_msgpack -> the
    stream -> the wedges of lod(n2) written the same way, to the integer."""
    n1, n2 = spot_pm.n_base + 50, spot_pm.n_full - 50

    def served(n):
        level = spot_pm.lod_mesh(n)
        return qem_core.encode_mesh(
            level.vertices, level.faces, "msgpack", level.vertex_attributes, level.texture,
            level.corner_uvs, quantize_bits=16, grid_box=spot_pm.position_bounds,
            wedges=quantised_wedges(spot_pm, n),
        )  # fmt: skip

    decoder = SplitStreamDecoder.from_msgpack(served(n1))
    for payload in iter_frames(encode_split_frames(spot_pm, n1, n2)):
        decoder.feed(payload)
    expected = read_msgpack_wedges(served(n2))
    assert np.array_equal(decoder.face_wedges, expected.face_wedges)
    assert np.array_equal(decoder.quantised_values, expected.values)
    assert (
        expected.grid.names == ("uv",)
        and read_msgpack_wedges(qem_core.encode_mesh(*spot_pm.lod(n1), "msgpack")) is None
    )


@pytest.mark.parametrize("change", [
    lambda w: {**w, "grid": {**w["grid"], "bits": [17]}},
    lambda w: {**w, "grid": {**w["grid"], "step": [0.0, 1.0]}},
    lambda w: {**w, "corner_type": "u64"},
    lambda w: {**w, "corners": w["corners"][:-1]},
    lambda w: {**w, "corners": b"\xff" * len(w["corners"])},
    lambda w: {**w, "values": w["values"][:-2]},
    lambda w: {**w, "count": w["count"] + 1},
    lambda w: "wedges",
])  # fmt: skip
def test_a_damaged_msgpack_wedges_entry_is_refused(spot_pm, change):
    n = spot_pm.n_base + 20
    blob = qem_core.encode_mesh(*spot_pm.lod(n), "msgpack", wedges=quantised_wedges(spot_pm, n))
    message = msgpack.unpackb(blob)
    message["wedges"] = change(message["wedges"])
    with pytest.raises(qem_core.MeshFormatError):
        read_msgpack_wedges(msgpack.packb(message))


def test_values_off_their_grid_in_msgpack_are_refused(spot_pm):
    n = spot_pm.n_base + 20
    wedges = quantised_wedges(spot_pm, n)
    wedges = wedges._replace(values=np.full_like(wedges.values, 4095 + 1))
    blob = qem_core.encode_mesh(*spot_pm.lod(n), "msgpack", wedges=wedges)
    with pytest.raises(qem_core.MeshFormatError, match="outside their grid"):
        read_msgpack_wedges(blob)


# -- damaged frames --------------------------------------------------------------------


def _first_payload(pm, n2):
    return _first_payload_from(pm, pm.n_base, n2)


def _first_payload_from(pm, n1, n2):
    return next(iter_frames(encode_split_frames(pm, n1, n2)))


def _fresh(pm):
    vertices, faces = pm.lod(pm.n_base)
    return SplitStreamDecoder(
        grid_for(pm).quantise(vertices), faces, quantised_wedges(pm, pm.n_base)
    )


def _rewrite(payload, change):
    """The payload with its msgpack map changed, sealed with a right CRC-32."""
    body = msgpack.packb(change(msgpack.unpackb(payload[:-4])))
    return body + struct.pack("<I", zlib.crc32(body))


def _with(**fields):
    return lambda body: {**body, **fields}


def _field(key, transform):
    return lambda body: {**body, key: transform(body[key])}


def _arrays(change):
    """The wedge arrays changed, then range-coded again: well-coded lies."""
    return lambda body: with_wedge_arrays(body, change)


def _escape_first(backs):
    """The first symbol an escape with these back-distances before the others."""

    def change(w):
        symbols = w.symbols.copy()
        symbols[0] = 255
        return w._replace(symbols=symbols, backs=np.concatenate([backs, w.backs]))

    return change


@pytest.mark.parametrize(("change", "message"), [
    (lambda body: {k: v for k, v in body.items() if not k.startswith("wedge")},
     "carries no wedges"),
    (_with(wedge_grid="uv"), "bad 'wedge_grid'"),
    (_field("wedge_grid", lambda g: {**g, "bits": [0]}), "bad 'wedge_grid'"),
    (_field("wedge_grid", lambda g: {**g, "widths": [3]}), "bad 'wedge_grid'"),
    (_field("wedge_grid", lambda g: {**g, "step": [float("nan"), 1.0]}), "bad 'wedge_grid'"),
    (_with(wedges_from=1), "refines 1 wedges"),
    (_with(wedges_from=-1), "a wedge count is -1"),
    (_with(n_wedge_rows=-1), "a wedge count is -1"),
    (_with(n_wedge_symbols="many"), "a wedge count is 'many'"),
    # Counts no coded bytes can hold: refused before anything is allocated.
    (_with(n_wedge_rows=10**6), "cannot hold"),
    (_with(n_wedge_symbols=10**9), "cannot hold"),
    # Counts the bytes could hold but do not: the coder runs out, or has bytes left.
    (_with(n_wedge_backs=7), "the coded wedges hold bytes past"),
    (_field("n_wedge_rows", lambda n: n - 1), "the coded wedges hold bytes past"),
    (_with(wedges=b""), "the coded wedges end early"),
    (_with(wedges="text"), "'wedges' is not"),
    (_field("wedges", lambda b: b[:-1]), "the coded wedges end early"),
    (_field("wedges", lambda b: b + b"\x00"), "the coded wedges hold bytes past"),
    (_field("wedges", lambda b: b"\xff" * len(b)), "the coded wedges end early"),
    # Many new wedges for too few value rows: refused before anything is allocated.
    (_arrays(lambda w: w._replace(counts=np.full_like(w.counts, 1000))),
     "more new wedges and updates than value rows"),
    (_arrays(lambda w: w._replace(symbols=w.symbols[:-1])), "a field ends before the splits"),
    (_arrays(lambda w: w._replace(symbols=np.append(w.symbols, np.uint8(0)))),
     "a field holds more than the splits use"),
    (_arrays(lambda w: w._replace(symbols=np.full_like(w.symbols, 0xFE))),
     "names a wedge that does not exist"),
    # An escape whose back-distance names no wedge, and one with no back-distance left.
    (_arrays(_escape_first(np.array([2**31]))), "names a wedge that does not exist"),
    (_arrays(lambda w: _escape_first(np.zeros(0, np.int64))(w._replace(backs=w.backs[:0]))),
     "a field ends before the splits"),
    (_arrays(lambda w: w._replace(backs=np.append(w.backs, 1))),
     "a field holds more than the splits use"),
    (_arrays(lambda w: w._replace(rows=w.rows[:-1])), "a field ends before the splits"),
    # A residual that takes a value off its grid (the second one is refused as it is
    # read: over 0xffff, as wedges.js refuses it).
    (_arrays(lambda w: w._replace(rows=np.full_like(w.rows, 5000))),
     "a wedge value leaves its grid"),
    (_arrays(lambda w: w._replace(rows=np.full_like(w.rows, -(2**31)))),
     "a wedge value leaves its grid"),
    # Another attribute grid than the wedges held: the values would not refine.
    (_field("wedge_grid", lambda g: {**g, "bits": [16]}), "is not that of the wedges held"),
    (_field("wedge_grid", lambda g: {**g, "origin": [o + 0.25 for o in g["origin"]]}),
     "is not that of the wedges held"),
    (_field("wedge_grid", lambda g: {**g, "step": [3 * x for x in g["step"]]}),
     "is not that of the wedges held"),
    (_field("wedge_grid", lambda g: {**g, "names": ["color"]}), "is not that of the wedges held"),
])  # fmt: skip
def test_a_frame_whose_wedges_lie_is_refused(spot_pm, change, message):
    n2 = spot_pm.n_base + 40
    payload = _first_payload(spot_pm, n2)
    decoder = _fresh(spot_pm)
    before = decoder.face_wedges.copy(), decoder.quantised_values.copy(), decoder.faces.copy()
    with pytest.raises(qem_core.CorruptFileError, match=re.escape(message)):
        decoder.feed(_rewrite(payload, change))
    # A refused frame changes nothing: the good frame still applies.
    assert np.array_equal(decoder.face_wedges, before[0])
    assert np.array_equal(decoder.quantised_values, before[1])
    assert np.array_equal(decoder.faces, before[2])
    decoder.feed(payload)
    _check_decoded(spot_pm, decoder, n2)


def test_a_frame_for_another_wedge_count_is_refused(spot_pm):
    """The first frame of a stream from another level (a later frame of a stream
    continues its contexts: refused for that before its counts are looked at)."""
    later = _first_payload_from(spot_pm, spot_pm.n_base + 20, spot_pm.n_base + 40)
    decoder = _fresh(spot_pm)
    with pytest.raises(qem_core.CorruptFileError, match="refines"):
        decoder.feed(later)
    frames = list(
        iter_frames(
            encode_split_frames(spot_pm, spot_pm.n_base, spot_pm.n_base + 40, splits_per_frame=20)
        )
    )
    with pytest.raises(qem_core.CorruptFileError, match="continues a stream"):
        _fresh(spot_pm).feed(frames[1])


def test_every_frame_needs_the_wedge_grid_held(spot_pm):
    """Each frame carries the wedge grid: it must be the grid of the wedges held (to a
    relative 1e-9, as wedges.js's sameGrid), in a stream's later frames too; the grid
    held stays."""
    n2 = spot_pm.n_base + 40
    frames = list(
        iter_frames(encode_split_frames(spot_pm, spot_pm.n_base, n2, splits_per_frame=20))
    )
    assert len(frames) == 2
    decoder = _fresh(spot_pm)
    held = decoder.wedge_grid
    nearly = _field("wedge_grid", lambda g: {**g, "step": [x * (1 + 1e-12) for x in g["step"]]})
    decoder.feed(_rewrite(frames[0], nearly))
    for change in (
        _field("wedge_grid", lambda g: {**g, "bits": [11]}),
        _field("wedge_grid", lambda g: {**g, "step": [x * (1 + 1e-7) for x in g["step"]]}),
    ):
        with pytest.raises(qem_core.CorruptFileError, match="is not that of the wedges held"):
            decoder.feed(_rewrite(frames[1], change))
    decoder.feed(frames[1])
    _check_decoded(spot_pm, decoder, n2)
    assert decoder.wedge_grid is held


# -- the work of a frame's wedge side ----------------------------------------------------


def hub_wedge_frame(pm, k: int, per: int) -> bytes:
    """A frame payload on lod(n_base) of ``pm`` (a mesh with wedges) whose k splits each
    split the previous split's new vertex and add ``per`` faces (s, t, 1): all hold
    vertex 1, whose corners the wedge side reads for each new corner there, so its work
    grows with the square of the frame's faces while the connectivity's (the corners of
    the split vertices) stays small. Every wedge symbol 0 (predicted), no new wedge."""
    from qem_core import stream
    from qem_core.wedge_stream import WedgeArrays
    from tests.unit.test_stream import crafted_frame

    n = pm.n_base
    vertices, faces = pm.lod(n)
    split_vertex = np.array([0] + [n + i - 1 for i in range(1, k)], np.int32)
    payload = crafted_frame(vertices, faces, grid_for(pm), split_vertex, per)
    body = msgpack.unpackb(payload[:-4])
    wedges = quantised_wedges(pm, n)
    corner_wedges = wedges.face_wedges.reshape(-1)
    of_s = (faces == 0).reshape(-1)
    n_symbols = int(of_s.sum()) + 3 * per + (k - 1) * 4 * per
    n_rows = len(set(corner_wedges[of_s].tolist())) + k - 1
    width = wedges.values.shape[1]
    fields = WedgeArrays(np.zeros((3, k), np.int64), np.zeros(n_symbols, np.uint8),
                         np.zeros(0, np.int64), np.zeros((n_rows, width), np.int64))
    body.update({
        "wedge_grid": wedges.grid.to_dict(), "wedges_from": int(wedges.values.shape[0]),
        "n_wedge_symbols": n_symbols, "n_wedge_backs": 0, "n_wedge_rows": n_rows,
        "wedges": stream.range_code_wedges(fields),
    })  # fmt: skip
    data = msgpack.packb(body)
    return data + struct.pack("<I", zlib.crc32(data))


def test_a_frame_whose_wedges_read_one_vertex_over_and_over_is_refused(spot_pm):
    """Regression: 2000 splits adding 16 faces each at vertex 1, a 9 kB frame, took the
    decoder 16 s (and the viewer 19 s); its wedge side would read 10^9 corners."""
    vertices, faces = spot_pm.lod(spot_pm.n_base)
    decoder = SplitStreamDecoder(grid_for(spot_pm).quantise(vertices), faces,
                                 quantised_wedges(spot_pm, spot_pm.n_base))
    with pytest.raises(qem_core.CorruptFileError, match="wedges of its new faces read more"):
        decoder.feed(hub_wedge_frame(spot_pm, 2000, 16))
    assert decoder.n_vertices == spot_pm.n_base  # left as it was


def _wedge_work(pm, n: int) -> int:
    """The reference: the corners the wedge side reads for split n -> n + 1, counted in
    lod(n + 1) (each new corner's vertex's corners, twice for one other than s and t)."""
    split = pm.splits(n, n + 1)
    s, t = int(split.split_vertex[0]), n
    counts = np.bincount(pm.lod(n + 1)[1].reshape(-1), minlength=n + 1)
    return sum(int(counts[v]) * (1 if v in (s, t) else 2) for v in split.new_faces.reshape(-1))


def test_frames_stay_within_the_wedge_work_a_decoder_accepts(monkeypatch, spot_pm):
    """With a small WEDGE_WORK_LIMIT the encoder ends frames before it (the reference
    counts each split's reads from its levels, independently of the planner), and the
    stream still decodes exactly."""
    pm, n_to = spot_pm, spot_pm.n_base + 400
    limit = 1000
    monkeypatch.setattr(qem_core.stream, "WEDGE_WORK_LIMIT", limit)
    frames = list(iter_frames(encode_split_frames(pm, pm.n_base, n_to)))
    work = [_wedge_work(pm, n) for n in range(pm.n_base, n_to)]
    assert sum(work) > 10 * limit
    vertices, faces = pm.lod(pm.n_base)
    decoder = SplitStreamDecoder(grid_for(pm).quantise(vertices), faces,
                                 quantised_wedges(pm, pm.n_base))
    for payload in frames:
        body = msgpack.unpackb(payload[:-4])
        frame_work = work[body["n_from"] - pm.n_base : body["n_to"] - pm.n_base]
        assert sum(frame_work) <= limit or len(frame_work) == 1
        if body["n_to"] < n_to:  # the next split would not have fitted
            assert sum(frame_work) + work[body["n_to"] - pm.n_base] > limit
        decoder.feed(payload)
    assert len(frames) > 10
    _check_decoded(pm, decoder, n_to)

"""The vertex-split stream: frames encoded from a progressive mesh, cut from any chunking
of the bytes, decoded onto the quantised coarse level, give the fine level; a damaged
frame is refused with CorruptFileError.
"""

import struct
import zlib

import msgpack
import numpy as np
import pytest

import qem_core
from qem_core._kernels import stream_coding
from qem_core.codecs import decode_msgpack_mesh
from qem_core.stream import (
    FIRST_FRAME_SPLITS,
    STREAM_VERSION,
    SplitStreamDecoder,
    encode_split_frames,
    grid_for,
    iter_frames,
    quantised_wedges,
    range_code_fields,
    split_frame_symbols,
)
from tests.reference import assert_decoded_level
from tests.tiny_meshes import (
    FIN,
    bumpy_grid,
    degenerate_ring_pm,
    grid,
    icosphere,
    perforated_icosphere,
)


@pytest.fixture(scope="module")
def pm():
    return qem_core.build(*perforated_icosphere(2, holes=3, seed=7))


@pytest.fixture(scope="module")
def big_pm():
    """More than FIRST_FRAME_SPLITS + 2 * FIRST_FRAME_SPLITS splits: several frames."""
    pm = qem_core.build(*icosphere(4, jitter=0.02, seed=2))
    assert pm.n_full - pm.n_base > 3 * FIRST_FRAME_SPLITS
    return pm


def _decode(pm, n1, n2, bits=16, chunks=None, **options):
    """Decode the stream n1 -> n2 onto quantised lod(n1); returns the decoder."""
    grid = grid_for(pm, bits)
    vertices, faces = pm.lod(n1)
    decoder = SplitStreamDecoder(grid.quantise(vertices), faces)
    stream = b"".join(encode_split_frames(pm, n1, n2, bits=bits, **options))
    for payload in iter_frames(chunks(stream) if chunks else [stream]):
        decoder.feed(payload)
    return decoder


def _check_decoded(pm, decoder, n2, bits=16):
    grid = grid_for(pm, bits)
    vertices, faces = pm.lod(n2)
    assert np.array_equal(decoder.faces, faces)
    # The integers are exactly those of lod(n2) quantised on the same grid ...
    assert np.array_equal(decoder.quantised, grid.quantise(vertices))
    # ... so the positions are within half a grid step (and a rounding ulp).
    error = np.abs(decoder.vertices - vertices)
    assert np.all(error <= grid.step / 2 * (1 + 1e-9))


@pytest.mark.parametrize("bits", [8, 12, 16, 24])
def test_stream_refines_the_coarse_level_into_the_fine_one(pm, bits):
    picks = np.unique(np.linspace(pm.n_base, pm.n_full, 6).astype(int)).tolist()
    for n1 in picks:
        for n2 in picks:
            if n1 < n2:
                _check_decoded(pm, _decode(pm, n1, n2, bits), n2, bits)


@pytest.mark.parametrize(
    "mesh", [FIN, grid(5), bumpy_grid(6, seed=1)], ids=["fin", "flat_grid", "bumpy_grid"]
)
def test_stream_of_awkward_meshes(mesh):
    """A non-manifold fin (explicit face codes), a flat grid (an axis with no extent)."""
    pm = qem_core.build(*mesh)
    _check_decoded(pm, _decode(pm, pm.n_base, pm.n_full), pm.n_full)


def test_empty_range_has_no_frames(pm):
    n = pm.n_base + 10
    assert list(encode_split_frames(pm, n, n)) == []
    assert list(iter_frames([])) == [] and list(iter_frames([b""])) == []


def test_requests_are_clamped_and_must_go_from_coarse_to_fine(pm):
    clamped = _decode(pm, -10, 10**9)
    _check_decoded(pm, clamped, pm.n_full)
    # Refused at the call, not at the first frame asked for.
    with pytest.raises(qem_core.InvalidOptionsError, match="must not exceed"):
        encode_split_frames(pm, pm.n_full, pm.n_base)
    for bits in (7, 25, 16.0, True):
        with pytest.raises(qem_core.InvalidOptionsError, match="bits"):
            encode_split_frames(pm, pm.n_base, pm.n_full, bits=bits)
    with pytest.raises(qem_core.InvalidOptionsError, match="splits_per_frame"):
        encode_split_frames(pm, pm.n_base, pm.n_full, splits_per_frame=0)


def test_decoder_has_no_grid_before_its_first_frame(pm):
    decoder = SplitStreamDecoder(np.zeros((pm.n_base, 3), np.int64), pm.lod(pm.n_base)[1])
    with pytest.raises(qem_core.InvalidOptionsError, match="grid"):
        decoder.vertices  # noqa: B018


def test_big_range_comes_in_frames_that_double_in_size(big_pm):
    """Frames hold 512, 1024, 2048, ... splits up to the cap (the rule in stream.py), so
    the number of splits per frame is known by hand from the range."""
    n1, n2 = big_pm.n_base, big_pm.n_full
    frames = list(encode_split_frames(big_pm, n1, n2))
    sizes = []
    for frame in frames:
        (length,) = struct.unpack_from("<I", frame)
        assert length == len(frame) - 4
        body = msgpack.unpackb(frame[4:-4])
        sizes.append(body["n_to"] - body["n_from"])
    expected, left, size = [], n2 - n1, FIRST_FRAME_SPLITS
    while left:
        expected.append(min(size, left))
        left -= expected[-1]
        size *= 2
    assert sizes == expected and len(sizes) >= 3
    capped = list(encode_split_frames(big_pm, n1, n2, splits_per_frame=300))
    assert len(capped) == -(-(n2 - n1) // 300)


@pytest.mark.parametrize("chunking", ["one_byte", "uneven", "frame_by_frame"])
def test_any_chunking_of_the_bytes_decodes_the_same(big_pm, chunking):
    rng = np.random.default_rng(0)

    def chunks(stream):
        if chunking == "one_byte":
            # Byte by byte is slow in Python for the whole stream: its first 20 kB only,
            # then the rest in one piece (the frame boundaries fall inside both parts).
            yield from (stream[i : i + 1] for i in range(min(len(stream), 20_000)))
            yield stream[20_000:]
        elif chunking == "uneven":
            cuts = np.sort(rng.integers(0, len(stream), 40))
            yield from (stream[a:b] for a, b in zip([0, *cuts], [*cuts, len(stream)], strict=True))
        else:
            yield stream

    n1, n2 = big_pm.n_base + 7, big_pm.n_full - 3
    decoder = _decode(big_pm, n1, n2, chunks=chunks)
    _check_decoded(big_pm, decoder, n2)
    if chunking == "frame_by_frame":
        frames = list(encode_split_frames(big_pm, n1, n2))
        assert len(list(iter_frames(frames))) == len(frames) > 1


def test_msgpack_level_on_the_stream_grid_has_the_streams_integers(pm):
    """A viewer fetches lod(n1) as quantised msgpack over pm.position_bounds, then
    refines it with the stream: the msgpack integers are grid_for(pm).quantise's, and the
    refined mesh's positions equal those of lod(n2) fetched the same way, to the bit."""
    grid = grid_for(pm, 16)
    n1, n2 = pm.n_base + 5, pm.n_full - 5
    fetched = {}
    for n in (n1, n2):
        vertices, faces = pm.lod(n)
        blob = qem_core.encode_mesh(
            vertices, faces, "msgpack", quantize_bits=16, grid_box=pm.position_bounds
        )
        message = msgpack.unpackb(blob)
        integers = np.frombuffer(message["positions"], "<u2").reshape(-1, 3)
        assert np.array_equal(integers, grid.quantise(vertices))
        fetched[n] = integers, decode_msgpack_mesh(blob)
        # Read back through load_mesh and put on the stream's grid again: the same integers.
        loaded = qem_core.load_mesh(blob, format="msgpack")
        assert np.array_equal(grid.quantise(loaded.vertices), grid.quantise(vertices))
        assert np.array_equal(loaded.faces, faces)
    decoder = SplitStreamDecoder(fetched[n1][0], fetched[n1][1].faces)
    for payload in iter_frames(encode_split_frames(pm, n1, n2)):
        decoder.feed(payload)
    assert np.array_equal(decoder.quantised, fetched[n2][0])
    assert np.array_equal(decoder.faces, fetched[n2][1].faces)
    assert np.array_equal(decoder.vertices, fetched[n2][1].vertices)


# -- damaged streams -------------------------------------------------------------------


def _frames(pm, n1=None, n2=None):
    return list(
        encode_split_frames(pm, pm.n_base if n1 is None else n1, pm.n_full if n2 is None else n2)
    )


def _fresh_decoder(pm, n=None):
    """A decoder holding lod(n) (default: the base), with its wedges when it has some."""
    n = pm.n_base if n is None else n
    vertices, faces = pm.lod(n)
    return SplitStreamDecoder(grid_for(pm).quantise(vertices), faces, quantised_wedges(pm, n))


@pytest.fixture(params=["geometry", "wedges"])
def any_pm(request, pm):
    """The geometry-only mesh, then spot with its wedges (stream keys of both kinds)."""
    return pm if request.param == "geometry" else request.getfixturevalue("spot_pm")


def test_a_truncated_stream_is_refused(pm):
    stream = b"".join(_frames(pm))
    for cut in (1, 3, 4, 5, len(stream) // 2, len(stream) - 1):
        with pytest.raises(qem_core.CorruptFileError, match="ends inside a frame"):
            list(iter_frames([stream[:cut]]))


def test_a_frame_declaring_a_huge_length_is_refused_at_once():
    with pytest.raises(qem_core.CorruptFileError, match="over the limit"):
        next(iter_frames([struct.pack("<I", 0xFFFFFFFF) + b"x"]))


def test_every_flipped_byte_of_a_frame_is_refused(any_pm):
    """The frame's CRC-32 catches a flipped byte anywhere (the range-coded bytes decode
    to something whatever they are, so only the checksum can tell)."""
    pm = any_pm
    payload = next(iter_frames(_frames(pm, pm.n_base, pm.n_base + 20)))
    for position in range(len(payload)):
        damaged = bytearray(payload)
        damaged[position] ^= 0x04
        with pytest.raises(qem_core.CorruptFileError, match="CRC-32"):
            _fresh_decoder(pm).feed(bytes(damaged))


def test_every_truncated_frame_is_refused(any_pm):
    payload = next(iter_frames(_frames(any_pm, any_pm.n_base, any_pm.n_base + 20)))
    for length in range(len(payload)):
        with pytest.raises(qem_core.CorruptFileError):
            _fresh_decoder(any_pm).feed(payload[:length])


def test_frames_out_of_order_or_for_another_level_are_refused(pm):
    frames = list(iter_frames(_frames(pm, pm.n_base, pm.n_base + 40)))
    one_frame = next(iter_frames(_frames(pm, pm.n_base + 10, pm.n_base + 20)))
    with pytest.raises(qem_core.CorruptFileError, match="refines"):
        _fresh_decoder(pm).feed(one_frame)
    decoder = _fresh_decoder(pm)
    decoder.feed(frames[0])
    held = decoder.faces.copy()
    decoder.feed(frames[0])  # the same key frame twice: held, so skipped
    decoder.feed(one_frame)  # within the level held: skipped too
    assert decoder.n_vertices == pm.n_base + 40 and np.array_equal(decoder.faces, held)
    later = next(iter_frames(_frames(pm, pm.n_base + 50, pm.n_base + 60)))
    with pytest.raises(qem_core.CorruptFileError, match="refines"):
        decoder.feed(later)  # past the level held: a gap


def test_a_decoder_stops_inside_a_frame_at_exactly_the_level_asked(pm):
    (frame,) = iter_frames(_frames(pm, pm.n_base, pm.n_base + 40))
    for stop in (pm.n_base, pm.n_base + 1, pm.n_base + 17, pm.n_base + 39, pm.n_base + 40):
        decoder = _fresh_decoder(pm)
        decoder.feed(frame, stop=stop)
        assert_decoded_level(decoder, pm, stop)


def _sealed(body: bytes) -> bytes:
    """A frame payload of these msgpack bytes with their right CRC-32."""
    return body + struct.pack("<I", zlib.crc32(body))


def _rewrite(payload: bytes, change) -> bytes:
    """A frame with a right CRC-32 whose msgpack body is change(body)."""
    return _sealed(msgpack.packb(change(msgpack.unpackb(payload[:-4]))))


def _with(**fields):
    return lambda body: {**body, **fields}


def _without(key):
    return lambda body: {k: v for k, v in body.items() if k != key}


def _field_bytes(key, transform):
    def change(body):
        return {**body, key: transform(body[key])}

    return change


def _moved_grid(change):
    """The frame's grid [origin xyz, step xyz] changed by change(grid list)."""
    return lambda body: {**body, "grid": change(list(body["grid"]))}


def _flip_middle(coded: bytes) -> bytes:
    middle = len(coded) // 2
    return coded[:middle] + bytes([coded[middle] ^ 0x10]) + coded[middle + 1 :]


@pytest.mark.parametrize("change", [
    _with(format="qem-mesh-msgpack"),
    _with(version=7),
    _with(version=5),  # version 5 frames (no tangent lattice): not read
    _with(version=4),  # version 4 frames (each split's s before its other fields): not read
    _with(version=3),  # version 3 frames (s coded as an index, not a gap) are no longer read
    _with(version=2),  # version 2 frames (deflated byte planes) are no longer read
    _with(version=1),
    _with(version="6"),
    _without("splits"),
    _without("grid"),
    _with(n_to=10**9),
    _with(n_from=-1),
    _with(n_from=3.5),
    _with(n_to="many"),
    lambda body: {**body, "n_from": float(body["n_from"]), "n_to": float(body["n_to"])},
    _with(faces_from=0),
    _with(grid=[0.0, 1.0]),
    _with(grid="origin"),
    _with(grid=[0.0, 0.0, 0.0, 1.0, float("nan"), 1.0]),
    # Steps of 0 put every vertex at the origin, negative ones mirror it, and a far
    # corner past the float range makes vertices infinite.
    _moved_grid(lambda g: [*g[:3], 0.0, 0.0, 0.0]),
    _moved_grid(lambda g: [*g[:3], -g[3], g[4], g[5]]),
    _moved_grid(lambda g: [*g[:3], 1e308, g[4], g[5]]),
    _with(n_new_faces=True),  # msgpack's true, a Python bool: an int too
    _with(n_from=False),
    _with(bits="sixteen"),
    _with(continues=True),  # the stream's first frame: there are no contexts to go on with
    _with(continues="yes"),
    _with(continues=1),
    _with(n_new_faces=10**6),
    _with(n_new_faces=-1),
    lambda body: {**body, "n_new_faces": body["n_new_faces"] + 1},
    lambda body: {**body, "n_new_faces": body["n_new_faces"] - 1},
    lambda body: {**body, "n_to": body["n_to"] + 1},
    _with(splits="text"),
    # The range-coded splits: cut short (the decoder reads past the end), one byte too
    # many, emptied, damaged in the middle, all ones (a code above the range).
    _field_bytes("splits", lambda b: b[:-1]),
    _field_bytes("splits", lambda b: b[: len(b) // 2]),
    _field_bytes("splits", lambda b: b + b"\x00"),
    _field_bytes("splits", lambda b: b""),
    _field_bytes("splits", _flip_middle),
    _field_bytes("splits", lambda b: b"\xff" * len(b)),
    lambda body: [body],
    lambda body: 42,
])  # fmt: skip
def test_a_frame_whose_content_lies_is_refused(pm, change):
    payload = next(iter_frames(_frames(pm, pm.n_base, pm.n_base + 20)))
    decoder = _fresh_decoder(pm)
    faces_before, quantised_before = decoder.faces.copy(), decoder.quantised.copy()
    with pytest.raises(qem_core.CorruptFileError):
        decoder.feed(_rewrite(payload, change))
    # A refused frame leaves the decoder as it was: the next good frame still applies.
    assert np.array_equal(decoder.faces, faces_before)
    assert np.array_equal(decoder.quantised, quantised_before)
    decoder.feed(payload)
    vertices, faces = pm.lod(pm.n_base + 20)
    assert np.array_equal(decoder.faces, faces)


def test_a_frame_that_is_not_msgpack_or_not_a_splits_map_is_refused(pm):
    decoder = _fresh_decoder(pm)
    for payload in (
        b"",
        b"abc",
        b"no checksum",
        _sealed(b"\xc1 not msgpack"),
        _sealed(msgpack.packb({"format": "qem-splits"})),
    ):
        with pytest.raises(qem_core.CorruptFileError):
            decoder.feed(payload)


def test_counts_a_frame_cannot_hold_are_refused_before_allocating():
    """A small frame claiming a billion splits or faces: refused from the counts and
    the coded length alone (a frame holds at most FRAME_SPLIT_LIMIT splits, and at most
    512 splits or faces per coded byte)."""
    decoder = SplitStreamDecoder(np.zeros((4, 3), np.int64), np.array([[0, 1, 2], [0, 2, 3]]))
    body = {
        "format": "qem-splits", "version": STREAM_VERSION, "n_from": 4, "n_to": 4 + 300,
        "faces_from": 2, "bits": 16, "grid": [0.0, 0.0, 0.0, 1.0, 1.0, 1.0], "n_new_faces": 0,
        "splits": b"\x00" * 4,
    }  # fmt: skip
    for counts, message in (
        ({"n_to": 4 + 10**9}, "over the limit"),
        ({"n_new_faces": 10**9}, "over the limit"),
        ({"n_to": 4 + 5000}, "cannot hold"),
        ({"n_to": 4, "n_new_faces": 5000}, "cannot hold"),
    ):
        with pytest.raises(qem_core.CorruptFileError, match=message):
            decoder.feed(_sealed(msgpack.packb({**body, **counts})))
    with pytest.raises(qem_core.InvalidOptionsError, match="splits_per_frame"):
        list(encode_split_frames(qem_core.build(*icosphere(1)), 0, 100, splits_per_frame=1 << 17))


def test_a_third_corner_that_is_no_neighbour_of_s_is_escaped():
    """Two separate triangles; the split of 0 makes a face (0, 6, 4) bridging them: 4 is
    not a neighbour of 0, so its third corner is escaped to a back-distance."""
    from qem_core.progressive import ProgressiveMesh

    pm = ProgressiveMesh(
        base_vertices=np.array(
            [[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [3, 0, 0], [4, 0, 0], [3, 1, 0]]
        ),
        split_vertex=np.array([0], np.int32),
        split_positions=np.array([[[0.0, 0, 0.5], [2, 0, 1]]]),
        face_corners=np.array([[0, 1, 2], [3, 4, 5], [0, 6, 4]], np.int32),
        level_faces=np.array([2, 3]),
        relabel_offsets=np.array([0, 1]),
        relabel_faces=np.array([0], np.int32),
        split_cost=np.array([1.0]),
    )
    (symbols,) = split_frame_symbols(pm, pm.n_base, pm.n_full)
    assert symbols.third_corners.tolist() == [255] and symbols.corners_back.tolist() == [2]
    _check_decoded(pm, _decode(pm, pm.n_base, pm.n_full), pm.n_full)


def test_the_rarer_coding_paths_round_trip():
    """A ring without a normal (positions axis by axis), an escaped third corner, t left
    at s's old position, a relabel that is not the predicted fan."""
    pm = degenerate_ring_pm()
    (symbols,) = split_frame_symbols(pm, pm.n_base, pm.n_full)
    assert symbols.third_corners.tolist() == [255, 1] and symbols.corners_back.tolist() == [2]
    assert symbols.positions[:, 3].tolist() == [0, 2]  # placement: general, t stayed
    # split 0's ring has no normal: span and mid axis by axis, from their plain blocks
    span_slots, mid_slots = symbols.position_slots[0, 2, 0], symbols.position_slots[0, 4, 0]
    assert span_slots < stream_coding._NORMAL_SLOTS
    assert stream_coding._MID_SLOTS <= mid_slots < stream_coding._MID1_SLOTS
    assert ((symbols.relabel_masks & 1) != (symbols.relabel_masks >> 1)).any()
    for n1 in range(pm.n_base, pm.n_full):
        _check_decoded(pm, _decode(pm, n1, pm.n_full, splits_per_frame=1), pm.n_full)


def test_frames_of_a_stream_go_on_with_the_previous_frames_contexts(big_pm):
    """Only a stream's first frame carries the grid and starts the contexts afresh; a
    later frame needs the decoder to have decoded the one before it. A refused frame
    leaves the contexts as they were."""
    pm = big_pm
    n2 = pm.n_base + 3 * FIRST_FRAME_SPLITS
    frames = list(iter_frames(_frames(pm, pm.n_base, n2)))
    bodies = [msgpack.unpackb(frame[:-4]) for frame in frames]
    assert "grid" in bodies[0] and "continues" not in bodies[0]
    assert all(body["continues"] is True and "grid" not in body for body in bodies[1:])
    with pytest.raises(qem_core.CorruptFileError, match="continues a stream"):
        _fresh_decoder(pm, bodies[1]["n_from"]).feed(frames[1])
    decoder = _fresh_decoder(pm)
    decoder.feed(frames[0])
    for lie in (_field_bytes("splits", _flip_middle), _with(n_new_faces=0)):
        with pytest.raises(qem_core.CorruptFileError):
            decoder.feed(_rewrite(frames[1], lie))
    for frame in frames[1:]:
        decoder.feed(frame)
    _check_decoded(pm, decoder, n2)


# -- the grid a frame carries, and positions off it ---------------------------------------


def _first_frame(pm, n2=None):
    return next(iter_frames(_frames(pm, pm.n_base, pm.n_base + 20 if n2 is None else n2)))


@pytest.mark.parametrize("bits", [99, 7, 25, 0, -16, 16.0, "16", True, None])
def test_a_first_frame_with_bits_off_their_range_is_refused(pm, bits):
    """bits must be an integer in [8, 24] (grid_for's range, as refine.js checks)."""
    with pytest.raises(qem_core.CorruptFileError, match=r"'bits' is .*not an integer in \[8, 24\]"):
        _fresh_decoder(pm).feed(_rewrite(_first_frame(pm), _with(bits=bits)))


@pytest.mark.parametrize("change", [
    _moved_grid(lambda g: [g[0] + 1.0, *g[1:]]),
    _moved_grid(lambda g: [*g[:3], g[3] * 2, *g[4:]]),
    _moved_grid(lambda g: [*g[:5], g[5] * (1 + 1e-7)]),
    _with(bits=12),
    _with(bits=24),
])  # fmt: skip
def test_a_first_frame_on_another_grid_than_the_one_held_is_refused(pm, change):
    """A decoder that knows its grid (given, or from a served level) refuses a first frame
    on another one: the integers it holds would not refine. Agreement to a relative 1e-9
    (refine.js's tolerance) is the same grid."""
    payload = _first_frame(pm)
    vertices, faces = pm.lod(pm.n_base)
    grid = grid_for(pm)
    decoder = SplitStreamDecoder(grid.quantise(vertices), faces, grid=grid)
    with pytest.raises(qem_core.CorruptFileError, match="is not that of the level held"):
        decoder.feed(_rewrite(payload, change))
    nearly = _moved_grid(lambda g: [x * (1 + 1e-12) for x in g])
    decoder.feed(_rewrite(payload, nearly))
    _check_decoded(pm, decoder, pm.n_base + 20)
    assert decoder.grid is grid  # the grid held stays


def test_a_decoder_keeps_the_grid_of_its_first_frame(pm):
    """Without a grid given, the first frame's is taken; a later stream's first frame on
    another grid is refused."""
    n2 = pm.n_base + 20
    decoder = _fresh_decoder(pm)
    decoder.feed(_first_frame(pm))
    other = next(iter_frames(encode_split_frames(pm, n2, n2 + 10, bits=12)))
    with pytest.raises(qem_core.CorruptFileError, match="is not that of the level held"):
        decoder.feed(other)
    decoder.feed(next(iter_frames(encode_split_frames(pm, n2, n2 + 10))))
    _check_decoded(pm, decoder, n2 + 10)


def test_a_served_level_knows_its_grid(pm):
    """from_msgpack takes the grid of the level's bbox and position_bits: a stream on
    another grid (other bits, another box) is refused, the stream's own is decoded."""
    n1, n2 = pm.n_base + 5, pm.n_base + 25
    vertices, faces = pm.lod(n1)
    served = qem_core.encode_mesh(
        vertices, faces, "msgpack", quantize_bits=16, grid_box=pm.position_bounds
    )
    decoder = SplitStreamDecoder.from_msgpack(served)
    assert decoder.grid.bits == 16 and np.allclose(decoder.grid.step, grid_for(pm).step)
    payload = next(iter_frames(encode_split_frames(pm, n1, n2)))
    for change in (_with(bits=12), _moved_grid(lambda g: [g[0] - 0.5, *g[1:]])):
        with pytest.raises(qem_core.CorruptFileError, match="is not that of the level held"):
            decoder.feed(_rewrite(payload, change))
    decoder.feed(payload)
    _check_decoded(pm, decoder, n2)


def off_grid_frame(pm, n2: int, shift: int) -> bytes:
    """The first frame payload of pm's stream n_base -> n2 (one frame) with the last
    third position_mid value of a split placed in the middle moved by ``shift``, well
    range-coded and sealed: that split puts s and t off the grid by about ``shift``
    along one axis (the decoders refuse it before looking at the later symbols, coded
    for the true positions)."""
    (symbols,) = split_frame_symbols(pm, pm.n_base, n2)
    i = np.flatnonzero(symbols.positions[:, 3] == 0)[-1]
    symbols.positions[i, 6] += shift
    body = msgpack.unpackb(_first_frame(pm, n2)[:-4])
    return _sealed(msgpack.packb({**body, "splits": range_code_fields(symbols)}))


@pytest.mark.parametrize("shift", [1 << 32, -(1 << 32), 1 << 20, -(1 << 20), 70_000])
def test_a_position_off_the_grid_is_refused(pm, shift):
    """A crafted frame (right CRC) whose split moves a vertex off [0, 2^bits - 1]: refused
    (refine.js holds 32-bit integers: a shift of 2^32 would wrap to the true position
    there, so both refuse it, tests/e2e/test_stream_checks_node.py)."""
    n2 = pm.n_base + 20
    decoder = _fresh_decoder(pm)
    decoder.feed(off_grid_frame(pm, n2, 0))  # crafted, unchanged: decodes
    _check_decoded(pm, decoder, n2)
    with pytest.raises(qem_core.CorruptFileError, match=r"a position leaves the grid"):
        _fresh_decoder(pm).feed(off_grid_frame(pm, n2, shift))


def test_a_value_the_coder_cannot_take_is_an_error_not_a_hang(pm):
    """range_coder.encode_integer refuses a negative unsigned value (its unary prefix
    would never end) and one over 2^33 - 2: the frame's coding raises."""
    (symbols,) = split_frame_symbols(pm, pm.n_base, pm.n_base + 20)
    for field, value in (("positions", 1 << 40), ("new_face_counts", -1)):
        array = getattr(symbols, field).copy()
        array.flat[0] = value
        with pytest.raises(ValueError, match="cannot code"):
            range_code_fields(symbols._replace(**{field: array}))


def _served(pm, n, **fields):
    """The msgpack level lod(n) on the stream's grid, its fields changed by ``fields``."""
    vertices, faces = pm.lod(n)
    served = qem_core.encode_mesh(
        vertices, faces, "msgpack", quantize_bits=16, grid_box=pm.position_bounds
    )
    return msgpack.packb({**msgpack.unpackb(served), **fields})


@pytest.mark.parametrize("fields", [
    {"attributes": [1]},
    {"attributes": "normal"},
    {"index_type": {}},
    {"index_type": ["u8"]},
])  # fmt: skip
def test_a_served_level_of_the_wrong_shape_is_refused_clearly(pm, fields):
    with pytest.raises(qem_core.MeshFormatError):
        SplitStreamDecoder.from_msgpack(_served(pm, pm.n_base, **fields))


@pytest.mark.parametrize(("bbox", "match"), [
    ([-1e308, 0, 0, 1e308, 1, 1], "spans more than float64"),  # inf steps, inf positions
    ([1, 1, 1, 0, 0, 0], "min is above its max"),  # every position moved off the mesh
])  # fmt: skip
def test_a_served_level_whose_box_is_no_grid_is_refused(pm, bbox, match):
    """Fuzz finding r06: the grid of a level's bbox was taken unchecked, so a decoder held
    inf positions or moved every vertex; load_mesh took the reversed box too."""
    served = _served(pm, pm.n_base, bbox=bbox)
    with pytest.raises(qem_core.MeshFormatError, match=match):
        SplitStreamDecoder.from_msgpack(served)
    with pytest.raises(qem_core.MeshFormatError, match=match):
        qem_core.load_mesh(served, format="msgpack")


def test_a_start_that_frames_could_not_refine_is_refused(pm):
    """A start whose faces name vertices it does not hold (or that come later), or whose
    integers lie off the grid, is refused: frames would refine it into a broken mesh."""
    n = pm.n_base + 5
    message = msgpack.unpackb(_served(pm, n))
    indices = bytearray(message["indices"])
    indices[0] = n  # index_type u8 on this small level: vertex n, one past the last
    with pytest.raises(qem_core.MeshFormatError, match="name vertex"):
        SplitStreamDecoder.from_msgpack(_served(pm, n, indices=bytes(indices)))
    positions = np.frombuffer(message["positions"], "<u2").copy()
    positions[0] = 65535
    fine = SplitStreamDecoder.from_msgpack(_served(pm, n, positions=positions.tobytes()))
    assert fine.quantised.max() == 65535  # the top of a 16-bit grid is on it
    with pytest.raises(qem_core.MeshFormatError, match="past the 8-bit grid"):
        SplitStreamDecoder.from_msgpack(
            _served(pm, n, positions=positions.tobytes(), position_bits=8)
        )
    vertices, faces = pm.lod(n)
    grid = grid_for(pm)
    quantised = grid.quantise(vertices)
    for bad_faces in (faces + 1, -faces - 1, np.where(faces == 0, n + 3, faces)):
        with pytest.raises(qem_core.InvalidMeshError, match="names vertex"):
            SplitStreamDecoder(quantised, bad_faces, grid=grid)
    with pytest.raises(qem_core.InvalidMeshError, match="outside"):
        SplitStreamDecoder(quantised + 70_000, faces, grid=grid)
    with pytest.raises(qem_core.InvalidMeshError, match="must be"):
        SplitStreamDecoder(quantised[:, :2], faces, grid=grid)


def test_a_start_whose_wedges_frames_could_not_refine_is_refused(spot_pm):
    n = spot_pm.n_base + 5
    vertices, faces = spot_pm.lod(n)
    quantised = grid_for(spot_pm).quantise(vertices)
    held = quantised_wedges(spot_pm, n)
    SplitStreamDecoder(quantised, faces, held)  # as it is: fine
    past_the_last, negative = held.face_wedges.copy(), held.face_wedges.copy()
    past_the_last[0, 0] = held.values.shape[0]
    negative[-1, 2] = -1
    for bad in (held._replace(face_wedges=past_the_last), held._replace(face_wedges=negative)):
        with pytest.raises(qem_core.InvalidMeshError, match="names wedge"):
            SplitStreamDecoder(quantised, faces, bad)
    with pytest.raises(qem_core.InvalidMeshError, match="outside its grid"):
        SplitStreamDecoder(quantised, faces, held._replace(values=held.values + (1 << 20)))
    with pytest.raises(qem_core.InvalidMeshError, match="wedge values must be"):
        SplitStreamDecoder(quantised, faces, held._replace(values=held.values[:, :1]))


# -- work per frame ---------------------------------------------------------------------


def _disc(n: int):
    """n triangles round one centre vertex, whose last splits have ~n corners each."""
    angles = np.arange(n) * 2 * np.pi / n
    rim = np.stack([np.cos(angles), np.sin(angles), 0 * angles], axis=1)
    return np.vstack([[0.0, 0.0, 0.0], rim]), [[0, 1 + i, 1 + (i + 1) % n] for i in range(n)]


def test_frames_stay_within_the_work_a_decoder_accepts(monkeypatch):
    """A frame's work is the sum over its splits of the split vertex's corners (the
    decoder walks and sorts them); frames end before it passes FRAME_WORK_LIMIT. With a
    small limit, a disc's stream comes in frames that each stay within it, and decodes."""
    pm = qem_core.build(*_disc(300))
    limit = 150  # below the largest split's own work: that split is a frame alone
    monkeypatch.setattr(qem_core.stream, "FRAME_WORK_LIMIT", limit)
    frames = list(iter_frames(encode_split_frames(pm, pm.n_base, pm.n_full)))
    work = []  # the reference: corners of s in the level it splits, split by split
    for n in range(pm.n_base, pm.n_full):
        s = pm.splits(n, n + 1).split_vertex[0]
        work.append(int(np.count_nonzero(pm.lod(n)[1] == s)))
    assert max(work) > limit and sum(work) > 5 * limit
    decoder = _fresh_decoder(pm)
    for payload in frames:
        body = msgpack.unpackb(payload[:-4])
        frame_work = work[body["n_from"] - pm.n_base : body["n_to"] - pm.n_base]
        assert sum(frame_work) <= limit or len(frame_work) == 1
        if body["n_to"] < pm.n_full:  # the next split would not have fitted
            assert sum(frame_work) + work[body["n_to"] - pm.n_base] > limit
        decoder.feed(payload)
    _check_decoded(pm, decoder, pm.n_full)
    assert len(frames) > 5


def crafted_frame(vertices, faces, grid, split_vertex: np.ndarray, per: int) -> bytes:
    """The geometry payload of a frame no planner makes, on lod (vertices, faces): split
    i splits ``split_vertex[i]`` and adds ``per`` faces (s, t, 1), all at vertex 1, with
    nothing relabelled and every position that of vertex 0."""
    from qem_core import stream
    from qem_core.progressive import VertexSplits

    n, m, k = vertices.shape[0], faces.shape[0], split_vertex.shape[0]
    new_faces = np.array([[split_vertex[i], n + i, 1] for i in range(k) for _ in range(per)],
                         np.int32)  # fmt: skip
    splits = VertexSplits(
        n, n + k, m, split_vertex.astype(np.int32), np.tile(vertices[0], (k, 2, 1)),
        new_faces, np.full(k, per, np.int32), np.zeros(k + 1, np.int64),
        np.zeros(0, np.int32),
    )  # fmt: skip
    held = np.zeros((n + k, 3), np.int64)
    held[:n] = grid.quantise(vertices)
    state = stream._state(faces, n + k, m + k * per)
    return stream._encode_frame(splits, state, held, grid, None, None)[0][4:]


def one_vertex_frame(vertices, faces, grid, k: int, per: int) -> bytes:
    """A frame payload of k splits of vertex 0 on lod (vertices, faces), each adding
    ``per`` faces (0, t, 1) to it, vertex 1 a neighbour of 0 (the encoder's planner
    never makes such a frame: its work grows with the square of k)."""
    return crafted_frame(vertices, faces, grid, np.zeros(k, np.int32), per)


def test_a_frame_past_the_work_limit_is_refused():
    """Regression: 300 splits of one vertex, each adding 64 faces to it, in a 7 KB frame:
    2.9 million corners to walk, refused."""
    vertices = np.array([[x, y, 0] for y in range(3) for x in range(3)], float)
    faces = np.array([[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4], [3, 4, 7], [3, 7, 6],
                      [4, 5, 8], [4, 8, 7]])  # fmt: skip
    grid = qem_core.stream.Grid.over_box([0, 0, 0], [2, 2, 1], 16)
    payload = one_vertex_frame(vertices, faces, grid, k=300, per=64)
    decoder = SplitStreamDecoder(grid.quantise(vertices), faces, grid=grid)
    with pytest.raises(qem_core.CorruptFileError, match="walk more than"):
        decoder.feed(payload)
    assert decoder.n_vertices == 9  # left as it was

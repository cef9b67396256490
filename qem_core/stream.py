"""The vertex-split stream: msgpack frames, connectivity, positions and appearance coded
against the mesh being refined, range-coded.

A stream refining lod(n1) to lod(n2) is a sequence of frames; each frame is

    uint32 little-endian length L, then L bytes: one msgpack map (format "qem-splits",
    version 4) followed by the CRC-32 of its bytes

Positions live on a grid of 2^bits - 1 steps per axis over the box of every position the
progressive mesh uses (``grid`` = [origin xyz, step xyz], in a stream's first frame);
the client keeps its mesh as grid integers. Encoder and decoder keep the connectivity of
the level being refined (per-vertex corner lists), so each split codes its new faces'
third corners as indices into the split vertex's neighbours or steps around it, its
relabelled faces against the fan its new faces predict, and its positions as the edge's
span against a prediction from the two rings and the ring's plane, then the edge's
midpoint against s's old position in a frame of the edge and the ring's normal
(``_kernels/stream_coding.py``). The symbols go through an adaptive binary range coder
(``_kernels/range_coder.py``) in the order the decoder needs them, with contexts the
decoder knows from its state (the split vertex's neighbour count, the scale and shape
of its ring, the edge just decoded); the frames of one stream carry the contexts from
one to the next. A mesh with appearance attributes adds the wedge side
(``_kernels/wedge_coding.py``): each corner of the split's fan and new faces names its
wedge by a symbol, mostly 0 (predicted), and the wedges' values, on a grid per attribute
(``wedge_grid_for``), are residuals against the values they had; these fields are
range-coded by the same coder, with contexts of their own (carried from frame to frame
too), into the frame's ``wedges`` bytes. A mesh without attributes has no wedge keys at
all. docs/formats.md gives every field.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterable, Iterator
from typing import NamedTuple

import msgpack
import numpy as np

from ._kernels import range_coder
from ._kernels.stream_coding import (
    ALL_FIELDS,
    BAD_BACK,
    BAD_CODE,
    BAD_COUNT,
    BAD_POSITION,
    BAD_THIRD,
    BAD_VERTEX,
    CONTEXT_SLOTS,
    FRAME_WORK_LIMIT,
    LONG_DATA,
    NO_CORNER,
    POSITION_SYMBOLS,
    SHORT_DATA,
    SPLIT_CONTEXT,
    TOO_MUCH_WORK,
    WEDGE_WORK_LIMIT,
    build_corner_sets,
    code_splits,
    decode_connectivity,
    encode_connectivity,
    link_corners,
    plan_frame,
    position_box,
    undo_splits,
)
from ._kernels.wedge_coding import (
    BAD_VALUE,
    BAD_WEDGE,
    BAD_WEDGE_CORNER,
    TOO_MUCH_WEDGE_WORK,
    code_wedge_fields,
    decode_wedge_fields,
    wedge_context_slots,
)
from .codecs.msgpack_mesh import read_msgpack, read_msgpack_grid, read_msgpack_wedges
from .errors import CorruptFileError, InvalidMeshError, InvalidOptionsError
from .progressive import ProgressiveMesh, VertexSplits
from .quantise import AttributeGrid, Grid, QuantisedWedges
from .wedge_stream import WEDGE_BITS, WedgeArrays, WedgeCoder, quantised_wedges, wedge_grid_for

__all__ = [
    "MEDIA_TYPE",
    "STREAM_VERSION",
    "WEDGE_BITS",
    "AttributeGrid",
    "Grid",
    "SplitStreamDecoder",
    "encode_split_frames",
    "split_frame_symbols",
    "grid_for",
    "iter_frames",
    "quantised_wedges",
    "wedge_grid_for",
]

MEDIA_TYPE = "application/x-qem-splits"
STREAM_VERSION = 6
# Frames grow from FIRST_FRAME_SPLITS to SPLITS_PER_FRAME splits (doubling), so that a
# viewer refines early in the stream: it gets a first level after a small frame.
FIRST_FRAME_SPLITS = 512
SPLITS_PER_FRAME = 8192
_FRAME_LIMIT = 64 << 20
# What a decoder allocates for one frame is bounded: at most this many splits and new
# faces (a frame of 8192 splits has about 16,000), and at most _ITEMS_PER_BYTE of either
# per coded byte: a decision costs at least -log2(4081/4096), about 1/189 bit
# (range_coder.py), so a byte holds at most 1512 decisions; a split codes at least 6
# (at most 252 splits a byte) and a face at least 3 (at most 504 faces a byte), under
# the 512 allowed.
FRAME_SPLIT_LIMIT = 1 << 16
FRAME_FACE_LIMIT = 1 << 22
_ITEMS_PER_BYTE = 512
# The position grid's bits a frame may carry (``grid_for``'s range).
_MIN_BITS, _MAX_BITS = 8, 24
# Two grids are the same when each origin and step agrees to this relative tolerance
# (as the viewer's checkGrid and sameGrid): the float64 values of one grid, written and
# read back, are equal; another box is not.
_GRID_TOLERANCE = 1e-9
# The wedge fields likewise: at most FRAME_WEDGE_LIMIT symbols + backs + values, and at
# most _WEDGE_ITEMS_PER_BYTE per coded byte of ``wedges`` (each is at least one decision,
# at least 1/189 bit: 1512 per byte at most).
FRAME_WEDGE_LIMIT = 1 << 24
_WEDGE_ITEMS_PER_BYTE = 2048


def grid_for(pm: ProgressiveMesh, bits: int = 16) -> Grid:
    """The grid over every position ``pm`` uses (coarse levels may leave the input box)."""
    if not _grid_bits(bits):
        raise InvalidOptionsError(f"bits={bits!r} must be an integer in [{_MIN_BITS}, {_MAX_BITS}]")
    return Grid.over_box(*_position_bounds(pm), bits)


def _position_bounds(pm: ProgressiveMesh) -> tuple[np.ndarray, np.ndarray]:
    """``pm.position_bounds``, filled in by one pass of a kernel when it is not known
    yet (a mesh just built: numpy took ~60 ms on dragon, before the encoder could
    start), the same values (``position_box`` leaves the cases where they could differ
    to numpy)."""
    if "position_bounds" not in vars(pm):  # functools.cached_property keeps it there
        base = pm.base_vertices.reshape(-1, 3)
        splits = pm.split_positions.reshape(-1, 3)
        if base.dtype == splits.dtype == np.float64:
            low, high = np.empty(3), np.empty(3)
            if position_box(np.ascontiguousarray(base), np.ascontiguousarray(splits), low, high):
                vars(pm)["position_bounds"] = (low, high)
    return pm.position_bounds


def _is_integer(value, low: int = 0, high: float = float("inf")) -> bool:
    """Whether ``value`` is an int in [low, high] (a frame's count by default), not a
    bool: msgpack's true is a Python bool, an int too, which would pass for 1."""
    return isinstance(value, int) and not isinstance(value, bool) and low <= value <= high


def _grid_bits(bits) -> bool:
    """Whether ``bits`` is grid bits a stream may use."""
    return _is_integer(bits, _MIN_BITS, _MAX_BITS)


def _close(a, b) -> bool:
    """Whether the numbers of a and b agree to _GRID_TOLERANCE (relative)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    scale = np.maximum(np.maximum(np.abs(a), np.abs(b)), 1e-300)
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= _GRID_TOLERANCE * scale))


def _same_grid(a: Grid, b: Grid) -> bool:
    return a.bits == b.bits and _close(a.origin, b.origin) and _close(a.step, b.step)


def _same_attribute_grid(a: AttributeGrid, b: AttributeGrid) -> bool:
    return (
        (a.names, a.widths, a.bits) == (b.names, b.widths, b.bits)
        and _close(a.origin, b.origin)
        and _close(a.step, b.step)
    )


class FrameSymbols(NamedTuple):
    """What one frame codes, before the range coder: ``encode_connectivity``'s arrays
    (docs/formats.md gives each field) and the per-split contexts from the state."""

    n_from: int
    split_back: np.ndarray  # (k,) t - s
    new_face_counts: np.ndarray  # (k,)
    face_codes: np.ndarray  # (new faces,) 0..6
    third_corners: np.ndarray  # (faces of code 0-5,) index into nb, 255 escaped, -1 walked
    wing_steps: np.ndarray  # (faces of code 0-5,) the second wing's walk step, or -1
    walk_lengths: np.ndarray  # (faces of code 0-5,) the length of that walk
    corners_back: np.ndarray  # t - corner of escaped and explicit corners
    relabel_masks: np.ndarray  # per corner of s: bit 0 relabelled, bit 1 predicted
    positions: np.ndarray  # (k, 7): position_span x3, placement, position_mid x3
    position_slots: np.ndarray  # (k, 7, 2): their contexts
    split_context: np.ndarray  # (k, SPLIT_CONTEXT)
    wedges: WedgeArrays | None = None  # the wedge side (None without attributes)


def range_code_fields(
    symbols: FrameSymbols, fields: int = ALL_FIELDS, probs: np.ndarray | None = None
) -> bytes:
    """The frame's fields range-coded; ``fields`` picks some of them
    (``stream_coding.FIELD_*``) to measure them one by one. The contexts are ``probs``
    (updated in place: what the stream's next frame starts from), fresh when None."""
    if probs is None:
        probs = new_contexts()
    capacity = 64 + 16 * symbols.split_back.shape[0] + 8 * symbols.face_codes.shape[0]
    return _range_coded(
        lambda enc, out, trial: code_splits(enc, out, trial, fields, *symbols[:-1]),
        capacity,
        probs,
    )


def range_code_wedges(fields: WedgeArrays, probs: np.ndarray | None = None) -> bytes:
    """A frame's wedge fields range-coded (an empty field costs nothing, so passing one
    field and empty others measures that field). The contexts are ``probs`` (updated in
    place, for the stream's next frame), fresh when None."""
    counts = np.require(fields.counts, np.int64, ["C"])
    symbols = np.require(fields.symbols, np.uint8, ["C"])
    backs = np.require(fields.backs, np.int64, ["C"])
    rows = np.require(fields.rows, np.int64, ["C"])
    if probs is None:
        probs = new_wedge_contexts(rows.shape[1])
    capacity = 64 + 2 * counts.size + symbols.shape[0] + 8 * backs.shape[0] + 8 * rows.size
    return _range_coded(
        lambda enc, out, trial: code_wedge_fields(enc, out, trial, counts, symbols, backs, rows),
        capacity,
        probs,
    )


def _range_coded(code, capacity: int, probs: np.ndarray) -> bytes:
    """The bytes ``code(enc, out, contexts)`` writes (a coding kernel called on a fresh
    encoder; it returns 0, or 1 for a value the coder cannot take), first into
    ``capacity`` bytes, again into twice what it wrote when that overflowed (the coder
    counts on past the end). ``probs`` is updated once, with the run that fit."""
    while True:
        out = np.zeros(capacity, np.uint8)
        enc = range_coder.new_encoder()
        trial = probs.copy()
        if code(enc, out, trial):
            raise ValueError(
                "a field holds an integer the range coder cannot code (negative where "
                f"unsigned, or over {range_coder.MAX_MAGNITUDE} in magnitude)"
            )
        written = range_coder.finish(enc, out)
        if written <= capacity:
            probs[:] = trial
            return out[:written].tobytes()
        capacity = 2 * written


def new_contexts() -> np.ndarray:
    """The contexts a stream's first frame starts from."""
    return range_coder.new_probs(CONTEXT_SLOTS)


def new_wedge_contexts(width: int) -> np.ndarray:
    """The wedge fields' contexts a stream's first frame starts from (``width`` value
    columns)."""
    return range_coder.new_probs(wedge_context_slots(width))


class _Contexts(NamedTuple):
    """The contexts a frame leaves to the stream's next one."""

    splits: np.ndarray
    wedges: np.ndarray | None  # None for a mesh without attributes


def _frame_symbols(
    splits: VertexSplits,
    state: _State,
    quantised: np.ndarray,
    grid: Grid,
    wedges: WedgeCoder | None = None,
) -> FrameSymbols:
    k = splits.split_vertex.shape[0]
    positions = np.zeros((k, POSITION_SYMBOLS), np.int64)
    position_slots = np.zeros((k, POSITION_SYMBOLS, 2), np.int64)
    split_context = np.zeros((k, SPLIT_CONTEXT), np.int64)
    codes, thirds, steps, walks, backs, masks, status = encode_connectivity(
        state.faces, splits.faces_from, state.head, state.nxt, splits.n_from,
        splits.split_vertex, splits.new_faces, splits.new_face_counts,
        splits.relabel_offsets, splits.relabel_faces, quantised,
        grid.quantise(splits.split_positions), positions, position_slots, split_context,
    )  # fmt: skip
    if status:
        raise CorruptFileError("inconsistent vertex splits: a relabelled face has no corner s")
    split_back = splits.n_from + np.arange(k) - splits.split_vertex
    return FrameSymbols(
        splits.n_from, split_back, splits.new_face_counts, codes, thirds, steps, walks, backs,
        masks, positions, position_slots, split_context,
        None if wedges is None else wedges.encode(splits),
    )  # fmt: skip


def _encode_frame(
    splits: VertexSplits,
    state: _State,
    quantised: np.ndarray,
    grid: Grid,
    wedges: WedgeCoder | None,
    contexts: _Contexts | None,
) -> tuple[bytes, _Contexts]:
    """One frame and the contexts it leaves; ``contexts`` are those the stream's previous
    frame left (None for the first frame, which starts afresh and carries the grid)."""
    first = contexts is None
    if first:
        width = None if wedges is None else wedges.level.values.shape[1]
        contexts = _Contexts(new_contexts(), None if width is None else new_wedge_contexts(width))
    symbols = _frame_symbols(splits, state, quantised, grid, wedges)
    body: dict = {
        "format": "qem-splits",
        "version": STREAM_VERSION,
        "n_from": splits.n_from,
        "n_to": splits.n_to,
        "faces_from": splits.faces_from,
    }
    if first:
        body["bits"] = grid.bits
        body["grid"] = [*map(float, grid.origin), *map(float, grid.step)]
    else:
        body["continues"] = True
    body["n_new_faces"] = int(splits.new_faces.shape[0])
    body["splits"] = range_code_fields(symbols, probs=contexts.splits)
    if wedges is not None:
        body.update(
            _wedge_body(wedges.grid, splits.wedges.wedges_from, symbols.wedges, contexts.wedges)
        )
    payload = msgpack.packb(body)
    payload += struct.pack("<I", zlib.crc32(payload))
    return struct.pack("<I", len(payload)) + payload, contexts


class _CornerSets(NamedTuple):
    """The decoder's corner sets (``stream_coding.build_corner_sets``)."""

    starts: np.ndarray  # (vertex capacity,) int64
    counts: np.ndarray  # (vertex capacity,) int32
    caps: np.ndarray  # (vertex capacity,) int32
    pool: np.ndarray  # int64, the corners of the sets in pool[:used]
    used: int


class _State(NamedTuple):
    """The connectivity both ends keep (``_kernels/stream_coding.py``)."""

    faces: np.ndarray  # (capacity, 3) int32, the first n rows are the level's faces
    head: np.ndarray  # (vertex capacity,) int64
    nxt: np.ndarray  # (3 * capacity,) int64


def _state(faces: np.ndarray, n_vertices: int, face_capacity: int) -> _State | None:
    """The state of a level with room to grow; None if a face names no vertex."""
    held = np.zeros((face_capacity, 3), np.int32)
    held[: faces.shape[0]] = faces
    state = _State(held, np.empty(n_vertices, np.int64), np.empty(3 * face_capacity, np.int64))
    return state if link_corners(held, faces.shape[0], state.head, state.nxt) else None


def _wedge_body(
    grid: AttributeGrid, wedges_from: int, fields: WedgeArrays, probs: np.ndarray
) -> dict:
    """A frame's wedge keys (absent from the frames of a mesh without attributes), coded
    with the contexts ``probs`` (updated)."""
    return {
        "wedge_grid": grid.to_dict(),
        "wedges_from": int(wedges_from),
        "n_wedge_symbols": int(fields.symbols.shape[0]),
        "n_wedge_backs": int(fields.backs.shape[0]),
        "n_wedge_rows": int(fields.rows.shape[0]),
        "wedges": range_code_wedges(fields, probs),
    }


def _wedge_fields(
    body: dict, k: int, previous: np.ndarray | None, held: AttributeGrid, n_wedges: int
) -> tuple[WedgeArrays, np.ndarray]:
    """The decoded arrays of a frame's wedge keys and the contexts they leave (KeyError,
    TypeError... on a missing or mistyped key, CorruptFileError on a grid other than
    ``held`` (the grid of the wedges the decoder holds), a ``wedges_from`` other than
    their number ``n_wedges``, counts the bytes cannot hold or bytes that do not decode;
    in the order of wedges.js). ``previous``: the wedge contexts the stream's previous
    frame left, for a frame that continues it (else None: fresh contexts)."""
    try:
        grid = AttributeGrid.from_dict(body["wedge_grid"])
    except (ValueError, TypeError, KeyError, AttributeError) as error:
        raise CorruptFileError(f"split frame: bad 'wedge_grid' ({error!r})") from None
    width = int(sum(grid.widths))
    wedges_from, n_symbols = body["wedges_from"], body["n_wedge_symbols"]
    n_backs, n_rows = body["n_wedge_backs"], body["n_wedge_rows"]
    for value in (wedges_from, n_symbols, n_backs, n_rows):
        if not _is_integer(value):
            raise CorruptFileError(f"split frame: a wedge count is {value!r}")
    coded = np.frombuffer(_bin(body["wedges"], None, "wedges"), np.uint8)
    # Bounded before decode_wedge_fields allocates them (as _check_frame_size).
    items = n_symbols + n_backs + width * n_rows + 3 * k
    if items > FRAME_WEDGE_LIMIT or items > _WEDGE_ITEMS_PER_BYTE * (coded.shape[0] + 1):
        raise CorruptFileError(
            f"split frame: the coded wedges ({coded.shape[0]} bytes) cannot hold {n_symbols} "
            f"symbols, {n_backs} backs and {n_rows} value rows"
        )
    if not _same_attribute_grid(grid, held):
        raise CorruptFileError(
            f"split frame: its wedge grid ({grid.to_dict()}) is not that of the wedges held "
            f"({held.to_dict()}): the values would not refine"
        )
    if wedges_from != n_wedges:
        raise CorruptFileError(f"frame refines {wedges_from} wedges, the mesh has {n_wedges}")
    # The same grid: the contexts the previous frame left have this width's slots.
    probs = new_wedge_contexts(width) if previous is None else previous.copy()
    status, counts, symbols, backs, rows = decode_wedge_fields(
        coded, k, n_symbols, n_backs, n_rows, width, probs
    )
    if status:
        raise CorruptFileError(f"split frame: {_WEDGE_FIELD_STATUS[status]}")
    # Each new wedge and extra update has a value row: checked before the decoder
    # allocates wedges for them.
    if int(counts[0].sum() + counts[1].sum()) > n_rows:
        raise CorruptFileError("split frame: more new wedges and updates than value rows")
    return WedgeArrays(counts, symbols, backs, rows), probs


def encode_split_frames(
    pm: ProgressiveMesh,
    n_from: int,
    n_to: int,
    bits: int = 16,
    splits_per_frame: int = SPLITS_PER_FRAME,
    _frame=None,
    *,
    key_frames: bool = False,
) -> Iterator[bytes]:
    """Frames of the splits refining lod(n_from) to lod(n_to), generated lazily; the
    arguments are checked at once (InvalidOptionsError), before the first frame.

    key_frames : every frame starts the range coder's contexts afresh and carries the
    grid, so it decodes given only the level it refines (the stored streams: any run of
    their frames is served as it is); else the frames of the stream share the contexts."""
    grid = grid_for(pm, bits)
    if not 1 <= splits_per_frame <= FRAME_SPLIT_LIMIT:
        raise InvalidOptionsError(
            f"splits_per_frame={splits_per_frame} must be in [1, {FRAME_SPLIT_LIMIT}]"
        )
    n_from, n_to = pm.clamp(n_from), pm.clamp(n_to)
    if n_from > n_to:
        raise InvalidOptionsError(f"from={n_from} must not exceed to={n_to}")
    return _split_frames(pm, n_from, n_to, grid, splits_per_frame, _frame, key_frames)


def _split_frames(
    pm: ProgressiveMesh,
    n_from: int,
    n_to: int,
    grid: Grid,
    splits_per_frame: int,
    _frame,
    key_frames: bool,
) -> Iterator[bytes]:
    """encode_split_frames' generator, its arguments checked."""
    bounds = plan_frames(pm, n_from, n_to, splits_per_frame)
    return encode_frame_run(pm, bounds, grid, key_frames=key_frames, _frame=_frame)


def plan_frames(
    pm: ProgressiveMesh, n_from: int, n_to: int, splits_per_frame: int = SPLITS_PER_FRAME
) -> list[int]:
    """Where the frames of a stream from lod(n_from) to lod(n_to) start and end: the
    vertex counts ``[n_from, ..., n_to]``. Frames grow from FIRST_FRAME_SPLITS splits by
    doubling up to ``splits_per_frame``, and end before a split that would pass the
    decoders' work limits (FRAME_WORK_LIMIT, and WEDGE_WORK_LIMIT for a mesh with
    wedges)."""
    _, faces = pm.lod(n_from)
    corner_counts = np.bincount(faces.ravel(), minlength=n_to).astype(np.int64)
    wedge_limit = WEDGE_WORK_LIMIT if pm.attribute_layout is not None else -1
    frame_splits = min(FIRST_FRAME_SPLITS, splits_per_frame)
    bounds = [n_from]
    start = n_from
    while start < n_to:
        stop = min(start + frame_splits, n_to)
        frame_splits = min(2 * frame_splits, splits_per_frame)
        splits = pm.splits(start, stop)
        taken = plan_frame(
            corner_counts, start, splits.split_vertex, splits.new_faces,
            splits.new_face_counts, splits.relabel_offsets, FRAME_WORK_LIMIT, wedge_limit,
        )  # fmt: skip
        start = min(stop, start + taken)  # a frame the decoder would refuse as too much work
        bounds.append(start)
    return bounds


def encode_frame_run(
    pm: ProgressiveMesh, bounds: list[int], grid: Grid, *, key_frames: bool, _frame=None
) -> Iterator[bytes]:
    """The frames from ``bounds[0]`` to ``bounds[-1]``, frame ``i`` refining
    lod(bounds[i]) to lod(bounds[i + 1]); see `encode_split_frames`."""
    n_from, n_to = bounds[0], bounds[-1]
    vertices, faces = pm.lod(n_from)
    quantised = np.zeros((n_to, 3), np.int64)
    quantised[:n_from] = grid.quantise(vertices)
    state = _state(faces, n_to, pm.n_faces(n_to))
    wedges = None
    held = quantised_wedges(pm, n_from)
    if held is not None:
        wedges = WedgeCoder(
            held.grid, _state(faces, n_to, pm.n_faces(n_to)), held.face_wedges, held.values,
            pm.splits(n_to, n_to).wedges.wedges_from, pm.attribute_layout.scales.astype(np.float32),
        )  # fmt: skip
    contexts = None  # carried from frame to frame unless every frame is a key frame
    for start, stop in zip(bounds[:-1], bounds[1:], strict=True):
        splits = pm.splits(start, stop)
        if _frame is None:
            frame, contexts = _encode_frame(splits, state, quantised, grid, wedges, contexts)
            if key_frames:
                contexts = None
            yield frame
        else:
            yield _frame(splits, state, quantised, grid, wedges)


def split_frame_symbols(
    pm: ProgressiveMesh, n_from: int, n_to: int, bits: int = 16, **options
) -> Iterator[FrameSymbols]:
    """What each frame of ``encode_split_frames`` codes, before the range coder (to
    measure the fields, and to look at them in tests), its wedge arrays included for a
    mesh with attributes."""
    return encode_split_frames(pm, n_from, n_to, bits, **options, _frame=_frame_symbols)


def iter_frames(chunks: Iterable[bytes]) -> Iterator[bytes]:
    """Cut a byte stream (any chunking) into frame payloads."""
    buffer = bytearray()
    for chunk in chunks:
        buffer += chunk
        while len(buffer) >= 4:
            (length,) = struct.unpack_from("<I", buffer)
            if length > _FRAME_LIMIT:
                raise CorruptFileError(f"split frame declares {length} bytes, over the limit")
            if len(buffer) < 4 + length:
                break
            yield bytes(buffer[4 : 4 + length])
            del buffer[: 4 + length]
    if buffer:
        raise CorruptFileError(f"split stream ends inside a frame ({len(buffer)} bytes left)")


class SplitStreamDecoder:
    """Refines a mesh held as grid integers by the frames of a split stream.

    Start from lod(n_from) quantised on the stream's grid (``grid_for(pm, bits)``, given
    as ``grid`` when known), with its wedges for a mesh with attributes
    (``quantised_wedges(pm, n_from)``: the wedge of each face corner and the wedges'
    values on the stream's attribute grid), or from a served msgpack level
    (`from_msgpack`, which knows the grid); feed frame payloads (from ``iter_frames``)
    in order; read ``vertices``, ``faces``, and ``face_wedges``, ``quantised_values``,
    ``wedge_values``. Without starting wedges, a stream's wedge fields are ignored.

    A stream's first frame carries its grid: the decoder refuses one whose grid is not
    the grid it holds (``grid``, else the grid of the first frame it decoded), and wedge
    keys whose attribute grid is not that of ``wedges``: the integers would not refine.
    """

    def __init__(
        self,
        quantised_vertices: np.ndarray,
        faces: np.ndarray,
        wedges: QuantisedWedges | None = None,
        grid: Grid | None = None,
    ) -> None:
        quantised = np.asarray(quantised_vertices, np.int64).copy()
        faces = np.asarray(faces, np.int64)  # checked before the int32 copy could wrap
        self.grid: Grid | None = grid
        # The frames keep these true; a start that breaks them would be refined into
        # faces naming vertices that come later, or positions off the grid.
        if quantised.ndim != 2 or quantised.shape[1] != 3:
            raise InvalidMeshError(f"quantised vertices must be (n, 3), not {quantised.shape}")
        if faces.ndim != 2 or faces.shape[1] != 3:
            raise InvalidMeshError(f"faces must be (m, 3), not {faces.shape}")
        _check_indices(faces, quantised.shape[0], "a face", "vertex")
        if grid is not None:
            _check_on_grid(quantised, (1 << grid.bits) - 1, "a quantised vertex")
        # The level held, in buffers with room to grow (by doubling: a frame appends to
        # them in place rather than copying the level), and its corner sets
        # (``_kernels/stream_coding.py``), built at the first frame and kept up to date by
        # the frames. ``faces`` and ``quantised`` are copies of the level's rows.
        self._quantised = quantised
        self._faces = faces.astype(np.int32)
        self._n_vertices = quantised.shape[0]
        self._n_faces = faces.shape[0]
        self._sets: _CornerSets | None = None
        self._views: dict[str, np.ndarray] = {}
        self._contexts: np.ndarray | None = None  # as the last frame decoded left them
        self._wedge_contexts: np.ndarray | None = None  # the same, of the wedge fields
        self.wedge_grid: AttributeGrid | None = None
        self.face_wedges: np.ndarray | None = None
        self.quantised_values: np.ndarray | None = None
        if wedges is not None:
            self.wedge_grid = wedges.grid
            self.face_wedges = np.asarray(wedges.face_wedges, np.int32).copy()
            self.quantised_values = np.asarray(wedges.values, np.int64).copy()
            if self.face_wedges.shape != faces.shape:
                raise InvalidOptionsError(
                    f"face wedges {self.face_wedges.shape} do not match faces {faces.shape}"
                )
            values = self.quantised_values
            if values.ndim != 2 or values.shape[1] != len(wedges.grid.origin):
                raise InvalidMeshError(
                    f"wedge values must be (W, {len(wedges.grid.origin)}), not {values.shape}"
                )
            _check_indices(self.face_wedges, values.shape[0], "a face corner", "wedge")
            _check_on_grid(values, wedges.grid.q_max, "a wedge value")

    @classmethod
    def from_msgpack(cls, data: bytes) -> SplitStreamDecoder:
        """A decoder starting from a level served as msgpack with "u16" positions (the
        server's ``lod?format=msgpack``), its wedges included when it has some, on the
        grid of the level's ``bbox`` and ``position_bits`` (a stream on another grid is
        refused)."""
        mesh = read_msgpack(data)
        grid = read_msgpack_grid(data)  # checked: a finite box, min <= max
        if grid is None:
            raise InvalidOptionsError("the level's positions are not grid integers ('u16')")
        quantised = np.frombuffer(msgpack.unpackb(data)["positions"], "<u2").reshape(-1, 3)
        return cls(quantised, mesh.faces, read_msgpack_wedges(data), grid)

    @property
    def n_vertices(self) -> int:
        return self._n_vertices

    @property
    def quantised(self) -> np.ndarray:
        """(n, 3) int64, the level's grid integers (a copy: later frames leave it)."""
        if "quantised" not in self._views:
            self._views["quantised"] = self._quantised[: self._n_vertices].copy()
        return self._views["quantised"]

    @property
    def faces(self) -> np.ndarray:
        """(m, 3) int32, the level's faces (a copy: later frames leave it)."""
        if "faces" not in self._views:
            self._views["faces"] = self._faces[: self._n_faces].copy()
        return self._views["faces"]

    @property
    def vertices(self) -> np.ndarray:
        if self.grid is None:
            raise InvalidOptionsError("no frame decoded yet: the grid is unknown")
        return self.grid.dequantise(self._quantised[: self._n_vertices])

    @property
    def wedge_values(self) -> np.ndarray | None:
        """(W, k) float64, the wedges' values in the attributes' units (None without)."""
        if self.quantised_values is None:
            return None
        return self.wedge_grid.dequantise(self.quantised_values)

    def feed(self, payload: bytes, stop: int | None = None) -> None:
        """Refine by one frame (its payload, from ``iter_frames``). A key frame this
        decoder holds already is skipped. ``stop``: refine no further than lod(stop),
        even inside the frame (then the decoder is done: later frames do not follow)."""
        if len(payload) < 4 or zlib.crc32(payload[:-4]) != struct.unpack("<I", payload[-4:])[0]:
            raise CorruptFileError("split frame: the CRC-32 does not match (damaged frame)")
        try:
            body = msgpack.unpackb(payload[:-4])
            if not isinstance(body, dict) or body.get("format") != "qem-splits":
                raise CorruptFileError("not a qem-splits frame")
            version = body["version"]
            if not isinstance(version, int) or version > STREAM_VERSION:
                raise CorruptFileError(
                    f"split frame version {version!r} is too new (this reads {STREAM_VERSION})"
                )
            if version < STREAM_VERSION:
                raise CorruptFileError(
                    f"split frame version {version} is no longer read (this reads {STREAM_VERSION})"
                )
            n_from, n_to, faces_from = body["n_from"], body["n_to"], body["faces_from"]
            n_new = body["n_new_faces"]
            for value in (n_from, n_to, faces_from, n_new):
                if not _is_integer(value):
                    raise CorruptFileError(f"split frame: a count is {value!r}")
            continues = body.get("continues", False)
            if continues is True:
                # The contexts (and the grid) are those the stream's previous frame left.
                if self._contexts is None or self.grid is None:
                    raise CorruptFileError(
                        "split frame continues a stream whose previous frame this decoder "
                        "did not decode"
                    )
                grid = self.grid
                contexts = self._contexts.copy()
            elif continues is False:
                bits = body["bits"]
                if not _grid_bits(bits):
                    raise CorruptFileError(
                        f"split frame: 'bits' is {bits!r}, not an integer in "
                        f"[{_MIN_BITS}, {_MAX_BITS}]"
                    )
                grid_values = np.asarray(body["grid"], np.float64)
                # Checked here: a bad grid would only show later, when the caller reads
                # `vertices` (an unrelated error, infinite positions, or all at one point).
                try:
                    grid = Grid.from_values(grid_values, bits)
                except ValueError as error:
                    raise CorruptFileError(f"split frame: 'grid' {error}") from None
                if self.grid is not None:
                    if not _same_grid(grid, self.grid):
                        raise CorruptFileError(
                            f"split frame: its grid ({bits} bits, {grid_values.tolist()}) is "
                            f"not that of the level held ({self.grid.bits} bits, "
                            f"{[*self.grid.origin.tolist(), *self.grid.step.tolist()]}): "
                            "the positions would not refine exactly"
                        )
                    grid = self.grid
                contexts = new_contexts()
            else:
                raise CorruptFileError(f"split frame: 'continues' is {continues!r}")
            k = n_to - n_from
            if continues is False and 0 <= n_from < n_to <= self.n_vertices:
                # A key frame of splits this decoder holds (a stored run served from a
                # frame boundary below the level asked for): skipped.
                return
            if stop is not None and stop <= n_from:
                return  # nothing of this frame is wanted
            if n_from < self.n_vertices < n_to:
                raise InvalidOptionsError(
                    f"the frame refines lod({n_from}) to lod({n_to}); this decoder holds "
                    f"lod({self.n_vertices}), inside it: start from lod({n_from}) (a stored "
                    "stream is served from the frame boundary at or below 'from')"
                )
            if n_from != self.n_vertices or faces_from != self._n_faces or k < 0:
                raise CorruptFileError(
                    f"frame refines {n_from} vertices / {faces_from} faces, the mesh has "
                    f"{self.n_vertices} / {self._n_faces}"
                )
            coded = np.frombuffer(_bin(body["splits"], None, "splits"), np.uint8)
            _check_frame_size(k, n_new, coded.shape[0])
            wedge_fields = None
            if self.face_wedges is not None:
                if "wedge_grid" not in body:
                    raise CorruptFileError(
                        "split frame carries no wedges, but the mesh being refined has some"
                    )
                wedge_fields = _wedge_fields(
                    body,
                    k,
                    self._wedge_contexts if continues is True else None,
                    self.wedge_grid,
                    self.quantised_values.shape[0],
                )
        except (CorruptFileError, InvalidOptionsError):
            raise
        except Exception as exc:  # msgpack, KeyError, TypeError...
            raise CorruptFileError(f"unreadable split frame: {exc}") from None
        wedges = None
        if wedge_fields is not None:
            wedges = self._wedge_coder(wedge_fields[0], n_to, faces_from + n_new)
        sets = self._room(n_to, faces_from + n_new)
        quantised, faces = self._quantised, self._faces
        born = np.zeros((n_new, 3), np.int32)
        counts = np.zeros(k, np.int64)
        old_positions = np.empty((k, 3), np.int64)
        partial = stop is not None and stop < n_to
        frame_splits = k
        if partial:
            k = stop - n_from
        status, split_vertex, relabel_counts, relabel_faces, pool, used, started, undo = (
            decode_connectivity(
                faces, faces_from, sets.starts, sets.counts, sets.caps, sets.pool, sets.used,
                n_from, k, frame_splits, n_new, coded, quantised, (1 << grid.bits) - 1,
                contexts, born, counts, partial, old_positions,
            )
        )  # fmt: skip
        sets = self._sets = sets._replace(pool=pool, used=used)
        if status:
            self._take_back(split_vertex, old_positions, started, undo)
            raise CorruptFileError(f"split frame: {_STATUS[status]}")
        if partial:
            n_to, n_new = stop, int(counts[:k].sum())
            counts, born = counts[:k], born[:n_new]
        if wedges is not None:
            run = VertexSplits(
                n_from, n_to, faces_from, split_vertex, np.zeros((k, 2, 3)), born, counts,
                np.concatenate([[0], np.cumsum(relabel_counts)]), relabel_faces,
            )  # fmt: skip
            status = wedges.decode(wedge_fields[0], run)
            if partial and status == LONG_DATA:
                status = 0  # the frame's later splits hold the wedge fields left
            if status:
                self._take_back(split_vertex, old_positions, started, undo)
                raise CorruptFileError(f"split frame: {_WEDGE_STATUS.get(status, _STATUS[status])}")
            self.face_wedges = wedges.face_wedges
            self.quantised_values = wedges.values
        self._n_vertices = n_to
        self._n_faces = faces_from + n_new
        self._views.clear()
        self.grid = grid
        # After a partial frame no frame follows: a continuing one is refused.
        self._contexts = None if partial else contexts
        if wedge_fields is not None:
            self._wedge_contexts = wedge_fields[1]

    def _room(self, n_vertices: int, n_faces: int) -> _CornerSets:
        """The corner sets of the level held (built at the first frame), with the level's
        buffers grown (doubling) to hold ``n_vertices`` vertices and ``n_faces`` faces;
        the rows past the level are zeros and the sets of the vertices past it empty."""
        self._faces = _rows_for(self._faces, self._n_faces, n_faces)
        self._quantised = _rows_for(self._quantised, self._n_vertices, n_vertices)
        sets = self._sets
        size = self._quantised.shape[0]
        if sets is None:
            sets = _CornerSets(np.zeros(size, np.int64), np.zeros(size, np.int32),
                               np.zeros(size, np.int32), np.zeros(0, np.int64), 0)  # fmt: skip
            sets = self._sets = self._corner_sets(sets)
        elif sets.starts.shape[0] < size:
            grown = [np.zeros(size, array.dtype) for array in sets[:3]]
            for new, array in zip(grown, sets[:3], strict=True):
                new[: array.shape[0]] = array
            sets = self._sets = sets._replace(starts=grown[0], counts=grown[1], caps=grown[2])
        return sets

    def _corner_sets(self, sets: _CornerSets) -> _CornerSets:
        """``sets`` rebuilt from the level's faces."""
        ok, pool, used = build_corner_sets(
            self._faces, self._n_faces, self._n_vertices, sets.starts, sets.counts, sets.caps
        )
        if not ok:  # the constructor checked the faces, and frames keep them in range
            raise CorruptFileError("the mesh being refined has a face naming no vertex")
        return sets._replace(pool=pool, used=used)

    def _take_back(self, split_vertex, old_positions, started, undo) -> None:
        """Undo what a refused frame changed of the level held (its faces' relabels, its
        split vertices' positions) and rebuild the corner sets: a refused frame changes
        nothing."""
        undo_splits(self._faces, self._quantised, split_vertex, old_positions, started,
                    undo, undo.shape[0])  # fmt: skip
        self._sets = self._corner_sets(self._sets)

    def _wedge_coder(self, fields: WedgeArrays, n_to: int, face_capacity: int) -> WedgeCoder:
        """The wedge side of the level held (its grid, which the frame's equals), with
        room for what ``fields`` add."""
        connectivity = _state(self._faces[: self._n_faces], n_to, face_capacity)
        if connectivity is None:
            raise CorruptFileError("the mesh being refined has a face naming no vertex")
        capacity = self.quantised_values.shape[0] + int(fields.counts[0].sum())
        return WedgeCoder(
            self.wedge_grid, connectivity, self.face_wedges, self.quantised_values, capacity
        )


def _rows_for(buffer: np.ndarray, held: int, need: int) -> np.ndarray:
    """``buffer`` (its first ``held`` rows kept) with room for ``need`` rows, grown by
    doubling, the rows from ``held`` to ``need`` zeros."""
    if buffer.shape[0] < need:
        grown = np.zeros((max(need, 2 * buffer.shape[0]), *buffer.shape[1:]), buffer.dtype)
        grown[:held] = buffer[:held]
        return grown
    buffer[held:need] = 0
    return buffer


def _check_indices(indices: np.ndarray, n: int, what: str, named: str) -> None:
    """InvalidMeshError unless every index lies in [0, n)."""
    if indices.size and not (0 <= indices.min() and indices.max() < n):
        bad = int(indices.min() if indices.min() < 0 else indices.max())
        raise InvalidMeshError(f"{what} names {named} {bad}, of {n}")


def _check_on_grid(values: np.ndarray, q_max, what: str) -> None:
    """InvalidMeshError unless every value lies in [0, q_max] (a bound, or one per
    column)."""
    if values.size and not (values.min() >= 0 and (values <= q_max).all()):
        raise InvalidMeshError(f"{what} lies outside its grid [0, 2^bits - 1]")


def _check_frame_size(n_splits: int, n_new_faces: int, n_bytes: int) -> None:
    """Refuse counts no frame of n_bytes can hold, before allocating for them: every
    split codes at least six decisions and every face three, each at least 1/189 bit
    (range_coder), so a byte holds at most 252 splits or 504 faces, under
    _ITEMS_PER_BYTE."""
    if n_splits > FRAME_SPLIT_LIMIT or n_new_faces > FRAME_FACE_LIMIT:
        raise CorruptFileError(
            f"split frame: {n_splits} splits / {n_new_faces} faces, over the limit "
            f"({FRAME_SPLIT_LIMIT} / {FRAME_FACE_LIMIT})"
        )
    if max(n_splits, n_new_faces) > _ITEMS_PER_BYTE * (n_bytes + 1):
        raise CorruptFileError(
            f"split frame: {n_bytes} coded bytes cannot hold {n_splits} splits and "
            f"{n_new_faces} faces"
        )


def _bin(value, length: int | None, name: str) -> bytes:
    if not isinstance(value, bytes) or (length is not None and len(value) != length):
        raise CorruptFileError(f"split frame: {name!r} is not {length} bytes")
    return value


_WEDGE_FIELD_STATUS = {
    SHORT_DATA: "the coded wedges end early (truncated or corrupt data)",
    LONG_DATA: "the coded wedges hold bytes past the last value",
    BAD_VALUE: "a wedge value leaves its grid",
}

# code_wedges' statuses where they differ from the splits' (its fields are arrays).
_WEDGE_STATUS = {
    SHORT_DATA: "a field ends before the splits do",
    LONG_DATA: "a field holds more than the splits use",
}

_STATUS = {
    BAD_VERTEX: "a split names a vertex that does not exist yet",
    BAD_COUNT: "the splits' face counts do not add up to n_new_faces",
    TOO_MUCH_WORK: (
        f"the splits walk more than {FRAME_WORK_LIMIT} corners of their split vertices "
        "(no encoder makes such a frame; it would take the decoder minutes)"
    ),
    BAD_CODE: "a face code is not 0..6",
    BAD_THIRD: "a third corner is not a neighbour of the split vertex",
    BAD_BACK: "a new face names a vertex that does not exist yet",
    BAD_POSITION: "a position leaves the grid ([0, 2^bits - 1])",
    SHORT_DATA: "the coded splits end early (truncated or corrupt data)",
    LONG_DATA: "the coded splits hold bytes past the last split",
    NO_CORNER: "a relabelled face has no corner s",
    BAD_WEDGE: "a corner or update names a wedge that does not exist",
    BAD_WEDGE_CORNER: "a wedge relabel names a corner that does not exist",
    BAD_VALUE: "a wedge value leaves its grid",
    TOO_MUCH_WEDGE_WORK: (
        f"the wedges of its new faces read more than {2 * WEDGE_WORK_LIMIT} corners "
        f"({8 * WEDGE_WORK_LIMIT} in its first split), more than a decoder takes: the "
        "encoder ends frames before half that, and such a split could take minutes"
    ),
}

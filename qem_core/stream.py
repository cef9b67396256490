"""The vertex-split stream: msgpack frames, connectivity and positions coded against the
mesh being refined, range-coded.

A stream refining lod(n1) to lod(n2) is a sequence of frames; each frame is

    uint32 little-endian length L, then L bytes: one msgpack map (format "qem-splits",
    version 3) followed by the CRC-32 of its bytes

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
one to the next. docs/formats.md gives every field.
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
    BAD_THIRD,
    BAD_VERTEX,
    CONTEXT_SLOTS,
    LONG_DATA,
    NO_CORNER,
    POSITION_SYMBOLS,
    SHORT_DATA,
    SPLIT_CONTEXT,
    code_splits,
    decode_connectivity,
    encode_connectivity,
    link_corners,
)
from .errors import CorruptFileError, InvalidOptionsError
from .progressive import ProgressiveMesh, VertexSplits
from .quantise import Grid

__all__ = [
    "MEDIA_TYPE",
    "STREAM_VERSION",
    "Grid",
    "SplitStreamDecoder",
    "encode_split_frames",
    "split_frame_symbols",
    "grid_for",
    "iter_frames",
]

MEDIA_TYPE = "application/x-qem-splits"
STREAM_VERSION = 3
# Frames grow from FIRST_FRAME_SPLITS to SPLITS_PER_FRAME splits (doubling), so that a
# viewer refines early in the stream (each frame starts its contexts afresh, so the
# first ones cost a little more).
FIRST_FRAME_SPLITS = 512
SPLITS_PER_FRAME = 8192
_FRAME_LIMIT = 64 << 20
# What a decoder allocates for one frame is bounded: at most this many splits and new
# faces (a frame of 8192 splits has about 16,000), and at most _ITEMS_PER_BYTE of either
# per coded byte (a split codes at least 6 decisions, a face at least 3, and a decision
# costs at least 1/177 bit: 512 per byte is well above what any encoder can reach).
FRAME_SPLIT_LIMIT = 1 << 16
FRAME_FACE_LIMIT = 1 << 22
_ITEMS_PER_BYTE = 512


def grid_for(pm: ProgressiveMesh, bits: int = 16) -> Grid:
    """The grid over every position ``pm`` uses (coarse levels may leave the input box)."""
    if not isinstance(bits, int) or not 8 <= bits <= 24:
        raise InvalidOptionsError(f"bits={bits!r} must be an integer in [8, 24]")
    return Grid.over_box(*pm.position_bounds, bits)


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


def range_code_fields(
    symbols: FrameSymbols, fields: int = ALL_FIELDS, probs: np.ndarray | None = None
) -> bytes:
    """The frame's fields range-coded; ``fields`` picks some of them
    (``stream_coding.FIELD_*``) to measure them one by one. The contexts are ``probs``
    (updated in place: what the stream's next frame starts from), fresh when None."""
    if probs is None:
        probs = new_contexts()
    capacity = 64 + 16 * symbols.split_back.shape[0] + 8 * symbols.face_codes.shape[0]
    while True:
        out = np.empty(capacity, np.uint8)
        enc = range_coder.new_encoder()
        trial = probs.copy()
        code_splits(enc, out, trial, fields, *symbols)
        written = range_coder.finish(enc, out)
        if written <= capacity:
            probs[:] = trial
            return out[:written].tobytes()
        capacity = 2 * written


def new_contexts() -> np.ndarray:
    """The contexts a stream's first frame starts from."""
    return range_coder.new_probs(CONTEXT_SLOTS)


def _frame_symbols(
    splits: VertexSplits, state: _State, quantised: np.ndarray, grid: Grid
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
        raise ValueError("inconsistent splits: a relabelled face has no corner s")
    split_back = splits.n_from + np.arange(k) - splits.split_vertex
    return FrameSymbols(
        splits.n_from, split_back, splits.new_face_counts, codes, thirds, steps, walks, backs,
        masks, positions, position_slots, split_context,
    )  # fmt: skip


def _encode_frame(
    splits: VertexSplits,
    state: _State,
    quantised: np.ndarray,
    grid: Grid,
    probs: np.ndarray | None,
) -> tuple[bytes, np.ndarray]:
    """One frame and the contexts it leaves; ``probs`` are those the stream's previous
    frame left (None for the first frame, which starts afresh and carries the grid)."""
    first = probs is None
    if first:
        probs = new_contexts()
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
    body["splits"] = range_code_fields(_frame_symbols(splits, state, quantised, grid), probs=probs)
    payload = msgpack.packb(body)
    payload += struct.pack("<I", zlib.crc32(payload))
    return struct.pack("<I", len(payload)) + payload, probs


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


def encode_split_frames(
    pm: ProgressiveMesh,
    n_from: int,
    n_to: int,
    bits: int = 16,
    splits_per_frame: int = SPLITS_PER_FRAME,
    _frame=None,
) -> Iterator[bytes]:
    """Frames of the splits refining lod(n_from) to lod(n_to), generated lazily."""
    grid = grid_for(pm, bits)
    if not 1 <= splits_per_frame <= FRAME_SPLIT_LIMIT:
        raise InvalidOptionsError(
            f"splits_per_frame={splits_per_frame} must be in [1, {FRAME_SPLIT_LIMIT}]"
        )
    n_from, n_to = pm.clamp(n_from), pm.clamp(n_to)
    if n_from > n_to:
        raise InvalidOptionsError(f"from={n_from} must not exceed to={n_to}")
    vertices, faces = pm.lod(n_from)
    quantised = np.zeros((n_to, 3), np.int64)
    quantised[:n_from] = grid.quantise(vertices)
    state = _state(faces, n_to, pm.n_faces(n_to))
    frame_splits = min(FIRST_FRAME_SPLITS, splits_per_frame)
    start = n_from
    probs = None  # the contexts, carried from frame to frame
    while start < n_to:
        stop = min(start + frame_splits, n_to)
        frame_splits = min(2 * frame_splits, splits_per_frame)
        splits = pm.splits(start, stop)
        if _frame is None:
            frame, probs = _encode_frame(splits, state, quantised, grid, probs)
            yield frame
        else:
            yield _frame(splits, state, quantised, grid)
        start = stop


def split_frame_symbols(
    pm: ProgressiveMesh, n_from: int, n_to: int, bits: int = 16, **options
) -> Iterator[FrameSymbols]:
    """What each frame of ``encode_split_frames`` codes, before the range coder (to
    measure the fields, and to look at them in tests)."""
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

    Start from lod(n_from) quantised on the stream's grid (``grid_for(pm, bits)``), feed
    frame payloads (from ``iter_frames``) in order, read ``vertices`` and ``faces``.
    """

    def __init__(self, quantised_vertices: np.ndarray, faces: np.ndarray) -> None:
        self.quantised = np.asarray(quantised_vertices, np.int64).copy()
        self.faces = np.asarray(faces, np.int32).copy()
        self.grid: Grid | None = None
        self._contexts: np.ndarray | None = None  # as the last frame decoded left them

    @property
    def n_vertices(self) -> int:
        return self.quantised.shape[0]

    @property
    def vertices(self) -> np.ndarray:
        if self.grid is None:
            raise InvalidOptionsError("no frame decoded yet: the grid is unknown")
        return self.grid.dequantise(self.quantised)

    def feed(self, payload: bytes) -> None:
        if len(payload) < 4 or zlib.crc32(payload[:-4]) != struct.unpack("<I", payload[-4:])[0]:
            raise CorruptFileError("split frame: the CRC-32 does not match (damaged frame)")
        try:
            body = msgpack.unpackb(payload[:-4])
            if not isinstance(body, dict) or body.get("format") != "qem-splits":
                raise CorruptFileError("not a qem-splits frame")
            version = body["version"]
            if not isinstance(version, int) or version > STREAM_VERSION:
                raise CorruptFileError(f"split frame version {version!r} is too new")
            if version < STREAM_VERSION:
                raise CorruptFileError(
                    f"split frame version {version} is no longer read (this reads {STREAM_VERSION})"
                )
            n_from, n_to, faces_from = body["n_from"], body["n_to"], body["faces_from"]
            n_new = body["n_new_faces"]
            for value in (n_from, n_to, faces_from, n_new):
                if not isinstance(value, int) or value < 0:
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
                grid_values = np.asarray(body["grid"], np.float64)
                # Checked here: a short or non-finite grid would only fail later, when the
                # caller reads `vertices`, with an unrelated error.
                if grid_values.shape != (6,) or not np.isfinite(grid_values).all():
                    raise CorruptFileError("split frame: 'grid' must be 6 finite numbers")
                grid = Grid(grid_values[:3], grid_values[3:], int(body["bits"]))
                contexts = new_contexts()
            else:
                raise CorruptFileError(f"split frame: 'continues' is {continues!r}")
            k = n_to - n_from
            if n_from != self.n_vertices or faces_from != self.faces.shape[0] or k < 0:
                raise CorruptFileError(
                    f"frame refines {n_from} vertices / {faces_from} faces, the mesh has "
                    f"{self.n_vertices} / {self.faces.shape[0]}"
                )
            coded = np.frombuffer(_bin(body["splits"], None, "splits"), np.uint8)
        except CorruptFileError:
            raise
        except Exception as exc:  # msgpack, KeyError, TypeError...
            raise CorruptFileError(f"unreadable split frame: {exc}") from None
        _check_frame_size(k, n_new, coded.shape[0])
        state = _state(self.faces, n_to, faces_from + n_new)
        if state is None:
            raise CorruptFileError("the mesh being refined has a face naming no vertex")
        quantised = np.zeros((n_to, 3), np.int64)
        quantised[:n_from] = self.quantised
        status, _, _, _ = decode_connectivity(
            state.faces, faces_from, state.head, state.nxt, n_from, k, n_new, coded, quantised,
            contexts,
        )  # fmt: skip
        if status:
            raise CorruptFileError(f"split frame: {_STATUS[status]}")
        self.faces = state.faces
        self.quantised = quantised
        self.grid = grid
        self._contexts = contexts


def _check_frame_size(n_splits: int, n_new_faces: int, n_bytes: int) -> None:
    """Refuse counts no frame of n_bytes can hold, before allocating for them: every
    split codes at least six decisions and every face three, each at least 1/177 bit
    (range_coder), so a frame holds far fewer than _ITEMS_PER_BYTE of either per byte."""
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


_STATUS = {
    BAD_VERTEX: "a split names a vertex that does not exist yet",
    BAD_COUNT: "the splits' face counts do not add up to n_new_faces",
    BAD_CODE: "a face code is not 0..6",
    BAD_THIRD: "a third corner is not a neighbour of the split vertex",
    BAD_BACK: "a new face names a vertex that does not exist yet",
    SHORT_DATA: "the coded splits end early (truncated or corrupt data)",
    LONG_DATA: "the coded splits hold bytes past the last split",
    NO_CORNER: "a relabelled face has no corner s",
}

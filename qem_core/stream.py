"""The vertex-split stream: msgpack frames, connectivity, positions and appearance coded
against the mesh being refined, deflated.

A stream refining lod(n1) to lod(n2) is a sequence of frames; each frame is

    uint32 little-endian length L, then L bytes of zlib (RFC 1950 "deflate") data
    holding one msgpack map (format "qem-splits", version 3)

so a browser decodes it with DecompressionStream("deflate"). Positions live on a grid of
2^bits - 1 steps per axis over the box of every position the progressive mesh uses
(``grid`` = [origin xyz, step xyz]); the client keeps its mesh as grid integers. Encoder
and decoder keep the connectivity of the level being refined (per-vertex corner lists),
so each split codes its new faces' third corners as indices into the split vertex's
neighbours, its relabelled faces as a mask over the split vertex's corners XOR the fan
its new faces predict, and its positions as the edge's midpoint against s's old position
and the edge's span against a prediction from the two rings
(``_kernels/stream_coding.py``). A mesh with appearance attributes adds the wedge
side (``_kernels/wedge_coding.py``): each corner of the split's fan and new faces names
its wedge by a symbol, mostly 0 (predicted), and the wedges' values, on a grid per
attribute (``wedge_grid_for``), are residuals against the values they had; a mesh
without attributes has no wedge keys at all. Integer arrays are stored as byte planes
(all low bytes, then all next bytes...) so that deflate sees the long runs of zero high
bytes. docs/formats.md gives every field.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterable, Iterator
from typing import NamedTuple

import msgpack
import numpy as np

from ._kernels.stream_coding import (
    BAD_BACK,
    BAD_CODE,
    BAD_MASK,
    BAD_THIRD,
    BAD_VERTEX,
    LONG_DATA,
    NO_CORNER,
    SHORT_DATA,
    decode_connectivity,
    encode_connectivity,
    link_corners,
)
from ._kernels.wedge_coding import BAD_VALUE, BAD_WEDGE, BAD_WEDGE_CORNER
from .codecs.msgpack_mesh import read_msgpack, read_msgpack_wedges
from .errors import CorruptFileError, InvalidOptionsError
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
    "grid_for",
    "iter_frames",
    "quantised_wedges",
    "wedge_grid_for",
]

MEDIA_TYPE = "application/x-qem-splits"
STREAM_VERSION = 3
# Frames grow from FIRST_FRAME_SPLITS to SPLITS_PER_FRAME splits (doubling), so that a
# viewer refines early in the stream and big ranges still deflate well.
FIRST_FRAME_SPLITS = 512
SPLITS_PER_FRAME = 8192
_FRAME_LIMIT = 64 << 20
# Deflate level 6, not 9: on dragon's whole stream 9 is 0.4 % smaller but 3.9x slower
# (3.8 s against 1.0 s), and encoding is what a viewer waits for.
_DEFLATE_LEVEL = 6
# A full frame of 8192 splits inflates to well under 1 MiB; 256 MiB leaves room for
# explicit faces and long relabel lists while bounding what a hostile frame costs.
_INFLATED_LIMIT = 256 << 20


def grid_for(pm: ProgressiveMesh, bits: int = 16) -> Grid:
    """The grid over every position ``pm`` uses (coarse levels may leave the input box)."""
    if not isinstance(bits, int) or not 8 <= bits <= 24:
        raise InvalidOptionsError(f"bits={bits!r} must be an integer in [8, 24]")
    return Grid.over_box(*pm.position_bounds, bits)


def _planes(values: np.ndarray, dtype: str) -> bytes:
    """Little-endian integers as byte planes."""
    raw = np.ascontiguousarray(values, dtype=dtype)
    return raw.view(np.uint8).reshape(-1, raw.dtype.itemsize).T.tobytes()


def _from_planes(data: bytes, dtype: str, count: int) -> np.ndarray:
    itemsize = np.dtype(dtype).itemsize
    if len(data) != count * itemsize:
        raise CorruptFileError(
            f"split frame: a field holds {len(data)} bytes, expected {count * itemsize}"
        )
    planes = np.frombuffer(data, np.uint8).reshape(itemsize, count)
    return np.ascontiguousarray(planes.T).view(dtype).reshape(count)


def _zigzag(values: np.ndarray) -> np.ndarray:
    v = values.astype(np.int64)
    return ((v << 1) ^ (v >> 63)).astype(np.uint64)


def _unzigzag(values: np.ndarray) -> np.ndarray:
    v = values.astype(np.uint64)
    return ((v >> np.uint64(1)).astype(np.int64)) ^ -((v & np.uint64(1)).astype(np.int64))


def _encode_frame(
    splits: VertexSplits,
    state: _State,
    quantised: np.ndarray,
    grid: Grid,
    wedges: WedgeCoder | None,
) -> bytes:
    k = splits.split_vertex.shape[0]
    mid = np.zeros((k, 3), np.int64)
    span = np.zeros((k, 3), np.int64)
    codes, thirds, backs, masks, status = encode_connectivity(
        state.faces, splits.faces_from, state.head, state.nxt, splits.n_from,
        splits.split_vertex, splits.new_faces, splits.new_face_counts,
        splits.relabel_offsets, splits.relabel_faces, quantised,
        grid.quantise(splits.split_positions), mid, span,
    )  # fmt: skip
    if status:
        raise ValueError("inconsistent splits: a relabelled face has no corner s")
    body = {
        "format": "qem-splits",
        "version": STREAM_VERSION,
        "n_from": splits.n_from,
        "n_to": splits.n_to,
        "faces_from": splits.faces_from,
        "bits": grid.bits,
        "grid": [*map(float, grid.origin), *map(float, grid.step)],
        "n_new_faces": int(splits.new_faces.shape[0]),
        "n_backs": int(backs.shape[0]),
        "split_back": _planes(splits.n_from + np.arange(k) - splits.split_vertex, "<u4"),
        "new_face_counts": _planes(splits.new_face_counts, "<u2"),
        "face_codes": codes.tobytes(),
        "third_corners": thirds.tobytes(),
        "corners_back": _planes(backs, "<u4"),
        "relabel_masks": masks.tobytes(),
        "position_mid": _planes(_zigzag(mid.T.reshape(-1)), "<u4"),
        "position_span": _planes(_zigzag(span.T.reshape(-1)), "<u4"),
    }
    if wedges is not None:
        body.update(_wedge_body(wedges.grid, splits.wedges.wedges_from, wedges.encode(splits)))
    payload = zlib.compress(msgpack.packb(body), _DEFLATE_LEVEL)
    return struct.pack("<I", len(payload)) + payload


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


def _wedge_body(grid: AttributeGrid, wedges_from: int, fields: WedgeArrays) -> dict:
    """A frame's wedge keys (absent from the frames of a mesh without attributes)."""
    if fields.counts.max(initial=0) > 0xFFFF:
        raise ValueError("a split has more than 65535 new wedges or extra records")
    return {
        "wedge_grid": grid.to_dict(),
        "wedges_from": int(wedges_from),
        "n_wedge_rows": int(fields.rows.shape[0]),
        "n_wedge_backs": int(fields.backs.shape[0]),
        "wedge_counts": _planes(fields.counts.reshape(-1), "<u2"),
        "wedge_corners": fields.symbols.tobytes(),
        "wedge_backs": _planes(fields.backs, "<u4"),
        "wedge_values": _planes(_zigzag(fields.rows.T.reshape(-1)), "<u4"),
    }


def _wedge_fields(body: dict, k: int) -> tuple[AttributeGrid, int, WedgeArrays]:
    """The grid, wedges_from and arrays of a frame's wedge keys (KeyError, TypeError...
    on a missing or mistyped key, CorruptFileError on inconsistent lengths)."""
    try:
        grid = AttributeGrid.from_dict(body["wedge_grid"])
    except (ValueError, AttributeError) as error:
        raise CorruptFileError(f"split frame: bad 'wedge_grid' ({error})") from None
    width = int(sum(grid.widths))
    wedges_from, n_rows, n_backs = body["wedges_from"], body["n_wedge_rows"], body["n_wedge_backs"]
    for value in (wedges_from, n_rows, n_backs):
        if not isinstance(value, int) or value < 0:
            raise CorruptFileError(f"split frame: a wedge count is {value!r}")
    counts = _from_planes(body["wedge_counts"], "<u2", 3 * k).astype(np.int64).reshape(3, k)
    # Each new wedge and extra update has a value row: checked before the decoder
    # allocates wedges for them.
    if int(counts[0].sum() + counts[1].sum()) > n_rows:
        raise CorruptFileError("split frame: more new wedges and updates than value rows")
    rows = _unzigzag(_from_planes(body["wedge_values"], "<u4", width * n_rows))
    return (
        grid,
        wedges_from,
        WedgeArrays(
            counts,
            np.frombuffer(_bin(body["wedge_corners"], None, "wedge_corners"), np.uint8),
            _from_planes(body["wedge_backs"], "<u4", n_backs).astype(np.int64),
            rows.reshape(width, n_rows).T,
        ),
    )


def encode_split_frames(
    pm: ProgressiveMesh,
    n_from: int,
    n_to: int,
    bits: int = 16,
    splits_per_frame: int = SPLITS_PER_FRAME,
) -> Iterator[bytes]:
    """Frames of the splits refining lod(n_from) to lod(n_to), generated lazily."""
    grid = grid_for(pm, bits)
    n_from, n_to = pm.clamp(n_from), pm.clamp(n_to)
    if n_from > n_to:
        raise InvalidOptionsError(f"from={n_from} must not exceed to={n_to}")
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
    frame_splits = min(FIRST_FRAME_SPLITS, splits_per_frame)
    start = n_from
    while start < n_to:
        stop = min(start + frame_splits, n_to)
        frame_splits = min(2 * frame_splits, splits_per_frame)
        yield _encode_frame(pm.splits(start, stop), state, quantised, grid, wedges)
        start = stop


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


def _inflate(payload: bytes) -> bytes:
    """The frame's deflated body, refused beyond _INFLATED_LIMIT bytes: a small frame must
    not be able to expand into gigabytes (a deflate bomb)."""
    inflater = zlib.decompressobj()
    body = inflater.decompress(payload, _INFLATED_LIMIT)
    if inflater.unconsumed_tail:
        raise CorruptFileError(f"split frame inflates beyond {_INFLATED_LIMIT >> 20} MiB")
    if not inflater.eof:
        raise CorruptFileError("split frame: the deflate data is truncated")
    return body


class SplitStreamDecoder:
    """Refines a mesh held as grid integers by the frames of a split stream.

    Start from lod(n_from) quantised on the stream's grid (``grid_for(pm, bits)``), with
    its wedges for a mesh with attributes (``quantised_wedges(pm, n_from)``: the wedge
    of each face corner and the wedges' values on the stream's attribute grid), or from
    a served msgpack level (`from_msgpack`); feed frame payloads (from ``iter_frames``)
    in order; read ``vertices``, ``faces``, and ``face_wedges``, ``quantised_values``,
    ``wedge_values``. Without starting wedges, a stream's wedge fields are ignored.
    """

    def __init__(
        self,
        quantised_vertices: np.ndarray,
        faces: np.ndarray,
        wedges: QuantisedWedges | None = None,
    ) -> None:
        self.quantised = np.asarray(quantised_vertices, np.int64).copy()
        self.faces = np.asarray(faces, np.int32).copy()
        self.grid: Grid | None = None
        self.wedge_grid: AttributeGrid | None = None
        self.face_wedges: np.ndarray | None = None
        self.quantised_values: np.ndarray | None = None
        if wedges is not None:
            self.wedge_grid = wedges.grid
            self.face_wedges = np.asarray(wedges.face_wedges, np.int32).copy()
            self.quantised_values = np.asarray(wedges.values, np.int64).copy()
            if self.face_wedges.shape != self.faces.shape:
                raise InvalidOptionsError(
                    f"face wedges {self.face_wedges.shape} do not match faces {self.faces.shape}"
                )

    @classmethod
    def from_msgpack(cls, data: bytes) -> SplitStreamDecoder:
        """A decoder starting from a level served as msgpack with "u16" positions (the
        server's ``lod?format=msgpack``), its wedges included when it has some."""
        mesh = read_msgpack(data)
        message = msgpack.unpackb(data)
        if message.get("position_encoding") != "u16":
            raise InvalidOptionsError("the level's positions are not grid integers ('u16')")
        quantised = np.frombuffer(message["positions"], "<u2").reshape(-1, 3)
        return cls(quantised, mesh.faces, read_msgpack_wedges(data))

    @property
    def n_vertices(self) -> int:
        return self.quantised.shape[0]

    @property
    def vertices(self) -> np.ndarray:
        if self.grid is None:
            raise InvalidOptionsError("no frame decoded yet: the grid is unknown")
        return self.grid.dequantise(self.quantised)

    @property
    def wedge_values(self) -> np.ndarray | None:
        """(W, k) float64, the wedges' values in the attributes' units (None without)."""
        if self.quantised_values is None:
            return None
        return self.wedge_grid.dequantise(self.quantised_values)

    def feed(self, payload: bytes) -> None:
        try:
            body = msgpack.unpackb(_inflate(payload))
            if body.get("format") != "qem-splits":
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
            n_new, n_backs = body["n_new_faces"], body["n_backs"]
            for value in (n_from, n_to, faces_from, n_new, n_backs):
                if not isinstance(value, int) or value < 0:
                    raise CorruptFileError(f"split frame: a count is {value!r}")
            grid_values = np.asarray(body["grid"], np.float64)
            # Checked here: a short or non-finite grid would only fail later, when the
            # caller reads `vertices`, with an unrelated error.
            if grid_values.shape != (6,) or not np.isfinite(grid_values).all():
                raise CorruptFileError("split frame: 'grid' must be 6 finite numbers")
            grid = Grid(grid_values[:3], grid_values[3:], int(body["bits"]))
            k = n_to - n_from
            if n_from != self.n_vertices or faces_from != self.faces.shape[0] or k < 0:
                raise CorruptFileError(
                    f"frame refines {n_from} vertices / {faces_from} faces, the mesh has "
                    f"{self.n_vertices} / {self.faces.shape[0]}"
                )
            split_back = _from_planes(body["split_back"], "<u4", k).astype(np.int64)
            counts = _from_planes(body["new_face_counts"], "<u2", k).astype(np.int64)
            if int(counts.sum()) != n_new:
                raise CorruptFileError("split frame: face counts do not add up to n_new_faces")
            codes = np.frombuffer(_bin(body["face_codes"], n_new, "face_codes"), np.uint8)
            thirds = np.frombuffer(_bin(body["third_corners"], None, "third_corners"), np.uint8)
            backs = _from_planes(body["corners_back"], "<u4", n_backs).astype(np.int64)
            masks = np.frombuffer(_bin(body["relabel_masks"], None, "relabel_masks"), np.uint8)
            mid = _unzigzag(_from_planes(body["position_mid"], "<u4", 3 * k))
            span = _unzigzag(_from_planes(body["position_span"], "<u4", 3 * k))
            wedge_fields = None
            if self.face_wedges is not None:
                if "wedge_grid" not in body:
                    raise CorruptFileError(
                        "split frame carries no wedges, but the mesh being refined has some"
                    )
                wedge_fields = _wedge_fields(body, k)
        except CorruptFileError:
            raise
        except Exception as exc:  # zlib, msgpack, KeyError, TypeError...
            raise CorruptFileError(f"unreadable split frame: {exc}") from None
        wedges = None
        if wedge_fields is not None:
            wedges = self._wedge_coder(*wedge_fields, n_to, faces_from + n_new)
        state = _state(self.faces, n_to, faces_from + n_new)
        if state is None:
            raise CorruptFileError("the mesh being refined has a face naming no vertex")
        quantised = np.zeros((n_to, 3), np.int64)
        quantised[:n_from] = self.quantised
        born = np.zeros((n_new, 3), np.int32)
        status, split_vertex, relabel_counts, relabel_faces = decode_connectivity(
            state.faces, faces_from, state.head, state.nxt, n_from, split_back, counts,
            codes, thirds, backs, masks, quantised, mid.reshape(3, k).T.copy(),
            span.reshape(3, k).T.copy(), born,
        )  # fmt: skip
        if status:
            raise CorruptFileError(f"split frame: {_STATUS[status]}")
        if wedges is not None:
            run = VertexSplits(
                n_from, n_to, faces_from, split_vertex, np.zeros((k, 2, 3)), born, counts,
                np.concatenate([[0], np.cumsum(relabel_counts)]), relabel_faces,
            )  # fmt: skip
            status = wedges.decode(wedge_fields[2], run)
            if status:
                raise CorruptFileError(f"split frame: {_STATUS[status]}")
            self.face_wedges = wedges.face_wedges
            self.quantised_values = wedges.values
            self.wedge_grid = wedges.grid
        self.faces = state.faces
        self.quantised = quantised
        self.grid = grid

    def _wedge_coder(
        self,
        grid: AttributeGrid,
        wedges_from: int,
        fields: WedgeArrays,
        n_to: int,
        face_capacity: int,
    ) -> WedgeCoder:
        """The wedge side of the level held, with room for what ``fields`` add."""
        n_wedges = self.quantised_values.shape[0]
        if wedges_from != n_wedges:
            raise CorruptFileError(f"frame refines {wedges_from} wedges, the mesh has {n_wedges}")
        if grid.widths != self.wedge_grid.widths:
            raise CorruptFileError(
                "split frame: its wedge grid has other attributes than the mesh being refined"
            )
        connectivity = _state(self.faces, n_to, face_capacity)
        if connectivity is None:
            raise CorruptFileError("the mesh being refined has a face naming no vertex")
        capacity = n_wedges + int(fields.counts[0].sum())
        return WedgeCoder(grid, connectivity, self.face_wedges, self.quantised_values, capacity)


def _bin(value, length: int | None, name: str) -> bytes:
    if not isinstance(value, bytes) or (length is not None and len(value) != length):
        raise CorruptFileError(f"split frame: {name!r} is not {length} bytes")
    return value


_STATUS = {
    BAD_VERTEX: "a split names a vertex that does not exist yet",
    BAD_CODE: "a face code is not 0..6",
    BAD_THIRD: "a third corner is not a neighbour of the split vertex",
    BAD_BACK: "a new face names a vertex that does not exist yet",
    SHORT_DATA: "a field ends before the splits do",
    LONG_DATA: "a field holds more than the splits use",
    BAD_MASK: "a relabel mask sets a bit past the split vertex's corners",
    NO_CORNER: "a relabelled face has no corner s",
    BAD_WEDGE: "a corner or update names a wedge that does not exist",
    BAD_WEDGE_CORNER: "a wedge relabel names a corner that does not exist",
    BAD_VALUE: "a wedge value leaves its grid",
}

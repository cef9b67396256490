"""The vertex-split stream: msgpack frames, positions quantised and delta-coded, deflated.

A stream refining lod(n1) to lod(n2) is a sequence of frames; each frame is

    uint32 little-endian length L, then L bytes of zlib (RFC 1950 "deflate") data
    holding one msgpack map (format "qem-splits", version 1)

so a browser decodes it with DecompressionStream("deflate"). Positions live on a grid of
2^bits - 1 steps per axis over the box of every position the progressive mesh uses
(``grid`` = [origin xyz, step xyz]); the client keeps its mesh as grid integers. Each
split codes the new position of s and the position of t as differences from s's position
just before the split. Integer arrays are stored as byte planes (all low bytes, then all
next bytes...) so that deflate sees the long runs of zero high bytes. docs/formats.md
gives every field.
"""

from __future__ import annotations

import struct
import zlib
from collections.abc import Iterable, Iterator

import msgpack
import numpy as np

from ._kernels.refine import delta_code_positions, undo_delta_positions
from .errors import CorruptFileError, InvalidOptionsError
from .progressive import ProgressiveMesh, VertexSplits, apply_splits, check_splits
from .quantise import Grid

__all__ = [
    "MEDIA_TYPE",
    "STREAM_VERSION",
    "Grid",
    "SplitStreamDecoder",
    "encode_split_frames",
    "grid_for",
    "iter_frames",
]

MEDIA_TYPE = "application/x-qem-splits"
STREAM_VERSION = 1
# Frames grow from FIRST_FRAME_SPLITS to SPLITS_PER_FRAME splits (doubling), so that a
# viewer refines early in the stream and big ranges still deflate well.
FIRST_FRAME_SPLITS = 512
SPLITS_PER_FRAME = 8192
# Face codes: 0-2 the face is (s, t, x) rotated by the code; 3-5 (t, s, x) rotated;
# 6 the three corners are given explicitly (non-manifold or pair-contraction splits).
_EXPLICIT_FACE = 6
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


def _face_codes(splits: VertexSplits) -> tuple[np.ndarray, np.ndarray]:
    """Code each new face relative to its split's s and t; returns (codes, corners)."""
    born = np.repeat(np.arange(splits.split_vertex.shape[0]), splits.new_face_counts)
    s = splits.split_vertex[born][:, None]
    t = (splits.n_from + born)[:, None]
    faces = splits.new_faces
    codes = np.full(faces.shape[0], _EXPLICIT_FACE, np.uint8)
    third = np.zeros(faces.shape[0], np.int64)
    for rotation in range(3):
        c0 = faces[:, rotation][:, None]
        c1 = faces[:, (rotation + 1) % 3][:, None]
        c2 = faces[:, (rotation + 2) % 3]
        for base, first, second in ((0, s, t), (3, t, s)):
            hit = ((c0 == first) & (c1 == second))[:, 0] & (codes == _EXPLICIT_FACE)
            codes[hit] = base + rotation
            third[hit] = (t[:, 0] - c2)[hit]
    explicit = codes == _EXPLICIT_FACE
    corners = np.concatenate([third[~explicit], (t - faces)[explicit].reshape(-1)])
    # The third corners of coded faces in face order, then the explicit triples.
    return codes, corners


def _encode_frame(splits: VertexSplits, deltas: np.ndarray, grid: Grid) -> bytes:
    k = splits.split_vertex.shape[0]
    codes, corners = _face_codes(splits)
    faces_before = splits.faces_from + np.concatenate([[0], np.cumsum(splits.new_face_counts)[:-1]])
    relabel_at = np.repeat(np.arange(k), np.diff(splits.relabel_offsets))
    body = {
        "format": "qem-splits",
        "version": STREAM_VERSION,
        "n_from": splits.n_from,
        "n_to": splits.n_to,
        "faces_from": splits.faces_from,
        "bits": grid.bits,
        "grid": [*map(float, grid.origin), *map(float, grid.step)],
        "n_new_faces": int(splits.new_faces.shape[0]),
        "n_relabels": int(splits.relabel_faces.shape[0]),
        "n_explicit": int(np.count_nonzero(codes == _EXPLICIT_FACE)),
        "split_back": _planes(splits.n_from + np.arange(k) - splits.split_vertex, "<u4"),
        "position_deltas": _planes(_zigzag(deltas.reshape(-1)), "<u4"),
        "new_face_counts": _planes(splits.new_face_counts, "<u2"),
        "face_codes": codes.tobytes(),
        "face_corners_back": _planes(corners, "<u4"),
        "relabel_counts": _planes(np.diff(splits.relabel_offsets), "<u2"),
        "relabel_faces_back": _planes(faces_before[relabel_at] - 1 - splits.relabel_faces, "<u4"),
    }
    payload = zlib.compress(msgpack.packb(body), _DEFLATE_LEVEL)
    return struct.pack("<I", len(payload)) + payload


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
    quantised = np.zeros((n_to, 3), np.int64)
    quantised[:n_from] = grid.quantise(pm.lod(n_from)[0])
    frame_splits = min(FIRST_FRAME_SPLITS, splits_per_frame)
    start = n_from
    while start < n_to:
        stop = min(start + frame_splits, n_to)
        frame_splits = min(2 * frame_splits, splits_per_frame)
        splits = pm.splits(start, stop)
        deltas = np.zeros((stop - start, 2, 3), np.int64)
        delta_code_positions(
            quantised, splits.split_vertex, grid.quantise(splits.split_positions), start, deltas
        )
        yield _encode_frame(splits, deltas, grid)
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

    Start from lod(n_from) quantised on the stream's grid (``grid_for(pm, bits)``), feed
    frame payloads (from ``iter_frames``) in order, read ``vertices`` and ``faces``.
    """

    def __init__(self, quantised_vertices: np.ndarray, faces: np.ndarray) -> None:
        self.quantised = np.asarray(quantised_vertices, np.int64).copy()
        self.faces = np.asarray(faces, np.int32).copy()
        self.grid: Grid | None = None

    @property
    def n_vertices(self) -> int:
        return self.quantised.shape[0]

    @property
    def vertices(self) -> np.ndarray:
        if self.grid is None:
            raise InvalidOptionsError("no frame decoded yet: the grid is unknown")
        return self.grid.dequantise(self.quantised)

    def feed(self, payload: bytes) -> None:
        try:
            body = msgpack.unpackb(_inflate(payload))
            if body.get("format") != "qem-splits":
                raise CorruptFileError("not a qem-splits frame")
            if body["version"] > STREAM_VERSION:
                raise CorruptFileError(f"split frame version {body['version']} is too new")
            n_from, n_to, faces_from = body["n_from"], body["n_to"], body["faces_from"]
            grid_values = np.asarray(body["grid"], np.float64)
            # Checked here: a short or non-finite grid would only fail later, when the
            # caller reads `vertices`, with an unrelated error.
            if grid_values.shape != (6,) or not np.isfinite(grid_values).all():
                raise CorruptFileError("split frame: 'grid' must be 6 finite numbers")
            grid = Grid(grid_values[:3], grid_values[3:], int(body["bits"]))
            k = n_to - n_from
            n_new, n_relabels = body["n_new_faces"], body["n_relabels"]
            n_explicit = body["n_explicit"]
            split_back = _from_planes(body["split_back"], "<u4", k).astype(np.int64)
            deltas = _unzigzag(_from_planes(body["position_deltas"], "<u4", 6 * k))
            counts = _from_planes(body["new_face_counts"], "<u2", k).astype(np.int32)
            codes = np.frombuffer(body["face_codes"], np.uint8)
            corners = _from_planes(
                body["face_corners_back"], "<u4", n_new - n_explicit + 3 * n_explicit
            ).astype(np.int64)
            relabel_counts = _from_planes(body["relabel_counts"], "<u2", k).astype(np.int64)
            relabel_back = _from_planes(body["relabel_faces_back"], "<u4", n_relabels)
        except CorruptFileError:
            raise
        except Exception as exc:  # zlib, msgpack, KeyError, TypeError...
            raise CorruptFileError(f"unreadable split frame: {exc}") from None
        if n_from != self.n_vertices or faces_from != self.faces.shape[0] or k < 0:
            raise CorruptFileError(
                f"frame refines {n_from} vertices / {faces_from} faces, the mesh has "
                f"{self.n_vertices} / {self.faces.shape[0]}"
            )
        if codes.shape[0] != n_new or np.any(codes > _EXPLICIT_FACE):
            raise CorruptFileError("split frame: bad face codes")
        split_vertex = (n_from + np.arange(k) - split_back).astype(np.int32)
        new_faces = self._faces_from_codes(split_vertex, counts, codes, corners, n_from)
        relabel_offsets = np.concatenate([[0], np.cumsum(relabel_counts)])
        relabel_at = np.repeat(np.arange(k), relabel_counts)
        faces_before = faces_from + np.concatenate([[0], np.cumsum(counts)[:-1]])
        relabel_faces = (
            (faces_before[relabel_at] - 1 - relabel_back.astype(np.int64)) if k else relabel_back
        )
        check_splits(
            n_from,
            faces_from,
            split_vertex,
            new_faces,
            counts,
            relabel_offsets,
            np.asarray(relabel_faces, np.int64),
        )
        quantised = np.zeros((n_to, 3), np.int64)
        quantised[:n_from] = self.quantised
        split_quantised = np.zeros((k, 2, 3), np.int64)
        undo_delta_positions(
            quantised, split_vertex, deltas.reshape(k, 2, 3), n_from, split_quantised
        )
        splits = VertexSplits(
            n_from,
            n_to,
            faces_from,
            split_vertex,
            split_quantised.astype(np.float64),
            new_faces,
            counts,
            relabel_offsets.astype(np.int64),
            np.asarray(relabel_faces, np.int32),
        )
        # Positions are already applied on the grid; apply_splits rewrites the faces.
        _, self.faces = apply_splits(np.zeros((n_from, 3)), self.faces, splits)
        self.quantised = quantised
        self.grid = grid

    @staticmethod
    def _faces_from_codes(split_vertex, counts, codes, corners, n_from):
        born = np.repeat(np.arange(split_vertex.shape[0]), counts)
        if born.shape[0] != codes.shape[0]:
            raise CorruptFileError("split frame: face counts do not match the face codes")
        s = split_vertex[born].astype(np.int64)
        t = (n_from + born).astype(np.int64)
        coded = codes != _EXPLICIT_FACE
        faces = np.zeros((codes.shape[0], 3), np.int64)
        n_coded = int(coded.sum())
        third = t[coded] - corners[:n_coded]
        code = codes[coded].astype(np.int64)
        swapped = code >= 3
        rotation = code % 3
        first = np.where(swapped, t[coded], s[coded])
        second = np.where(swapped, s[coded], t[coded])
        rows = np.flatnonzero(coded)
        faces[rows, rotation] = first
        faces[rows, (rotation + 1) % 3] = second
        faces[rows, (rotation + 2) % 3] = third
        faces[~coded] = t[~coded][:, None] - corners[n_coded:].reshape(-1, 3)
        return faces.astype(np.int32)

"""Stored split streams: a mesh's whole stream, base to full, encoded once, and the index
of its frames.

Serving a stream should cost what serving a file costs, so the stream is encoded when
the mesh is built and kept as bytes. Every frame of a stored stream is a *key frame*: it
starts the range coder's contexts afresh and carries the grid (a stream's first frame in
docs/formats.md, section 2), so any run of consecutive frames is itself a valid stream
that decodes given only the level its first frame refines. That is what lets a server
answer ``/splits?from=N1&to=N2`` with a slice of the stored bytes (the frames covering
[N1, N2]) and any static host answer HTTP Range requests on the file. Relearning the
contexts in every frame costs 0.4-0.5 % of the stream's bytes (dragon, bunny, igea; see
docs/formats.md), and it makes frames independent: the encoder runs groups of frames on
several threads, starting each group from its own level.

The index (JSON, ``StreamIndex.to_json``) lists, for each frame boundary, the vertex
count, the face count and the byte offset, with the length and CRC-32 of the whole
stream, so a reader finds a run of frames without parsing the stream and can tell a
damaged or foreign stream from the one indexed.
"""

from __future__ import annotations

import json
import os
import struct
import zlib
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import msgpack
import numpy as np

from .errors import CorruptFileError, InvalidOptionsError
from .progressive import ProgressiveMesh
from .stream import (
    SPLITS_PER_FRAME,
    STREAM_VERSION,
    encode_frame_run,
    grid_for,
    iter_frames,
    plan_frames,
)

__all__ = [
    "INDEX_FORMAT",
    "INDEX_VERSION",
    "OutdatedStreamError",
    "StreamIndex",
    "encode_stored_stream",
    "index_stream",
]

INDEX_FORMAT = "qem-split-index"
INDEX_VERSION = 1
# Groups of frames per thread. Each group starts by extracting its first level and
# linking its corners, O(n): on dragon, four groups a thread took 0.5-0.7 s more CPU than
# one (4.4-4.6 s against 3.9 s, two threads), and groups of equal split counts finish
# close enough together.
_GROUPS_PER_THREAD = 1
# What extracting a run's first level costs (pm.lod, quantising, linking the corners),
# in splits per vertex of that level: 0.05 s for dragon's level of 221 000 vertices,
# against 2.7 µs a split (2026-12-05).
_SETUP_PER_VERTEX = 0.08
_INDEX_LIMIT = 16 << 20  # bytes of index JSON a reader accepts


@dataclass(frozen=True)
class StreamIndex:
    """Where the frames of a stored stream start and end.

    vertices, faces : the level's vertex and face counts at each frame boundary (frame
    ``i`` refines level ``vertices[i]`` to ``vertices[i + 1]``); offsets : the byte
    offset of each boundary in the stream (``offsets[-1]`` is its length); crc32 : of
    the whole stream; stream_version, bits : its frames' version and position grid bits.
    """

    vertices: tuple[int, ...]
    faces: tuple[int, ...]
    offsets: tuple[int, ...]
    crc32: int
    stream_version: int = STREAM_VERSION
    bits: int = 16

    @property
    def n_frames(self) -> int:
        return len(self.vertices) - 1

    @property
    def size(self) -> int:
        """Bytes of the whole stream."""
        return self.offsets[-1]

    def covering(self, n_from: int, n_to: int) -> tuple[int, int]:
        """The frames ``[i, j)`` of the smallest run refining a level at or below
        ``n_from`` to one at or above ``n_to`` (both clamped into the stream's range);
        ``i == j`` (no frame) when ``n_from == n_to`` after clamping."""
        low, high = self.vertices[0], self.vertices[-1]
        n_from, n_to = min(max(n_from, low), high), min(max(n_to, low), high)
        if n_from > n_to:
            raise InvalidOptionsError(f"from={n_from} must not exceed to={n_to}")
        bounds = np.asarray(self.vertices)
        i = int(np.searchsorted(bounds, n_from, side="right")) - 1
        if n_from == n_to:
            return i, i
        j = int(np.searchsorted(bounds, n_to, side="left"))
        return i, j

    def byte_span(self, i: int, j: int) -> tuple[int, int]:
        """The bytes ``[start, stop)`` of frames ``[i, j)``."""
        return self.offsets[i], self.offsets[j]

    def check(self, data: bytes | memoryview) -> None:
        """CorruptFileError unless ``data`` has this index's length and CRC-32."""
        if len(data) != self.size:
            raise CorruptFileError(
                f"stored split stream has {len(data)} bytes, its index says {self.size}"
            )
        if zlib.crc32(data) != self.crc32:
            raise CorruptFileError("stored split stream: the CRC-32 does not match its index")

    def to_json(self) -> bytes:
        return json.dumps(
            {
                "format": INDEX_FORMAT,
                "version": INDEX_VERSION,
                "stream_version": self.stream_version,
                "bits": self.bits,
                "bytes": self.size,
                "crc32": self.crc32,
                "vertices": list(self.vertices),
                "faces": list(self.faces),
                "offsets": list(self.offsets),
            },
            separators=(",", ":"),
        ).encode()

    @classmethod
    def from_json(cls, data: bytes | str) -> StreamIndex:
        """Read and check an index (CorruptFileError: not JSON, another format, a newer
        version, counts that do not grow or disagree)."""
        if len(data) > _INDEX_LIMIT:
            raise CorruptFileError(f"split stream index of {len(data)} bytes is over the limit")
        try:
            message = json.loads(data)
        except (ValueError, UnicodeDecodeError) as error:
            raise CorruptFileError(f"split stream index is not JSON ({error})") from None
        if not isinstance(message, dict) or message.get("format") != INDEX_FORMAT:
            raise CorruptFileError(f"not a split stream index (format {INDEX_FORMAT!r})")
        version = message.get("version")
        if not _is_count(version) or version > INDEX_VERSION or version < 1:
            raise CorruptFileError(
                f"split stream index version {version!r}: this reads version {INDEX_VERSION}"
            )
        try:
            lists = [message[key] for key in ("vertices", "faces", "offsets")]
            scalars = [message[key] for key in ("crc32", "stream_version", "bits", "bytes")]
        except KeyError as error:
            raise CorruptFileError(f"split stream index lacks {error}") from None
        if not all(isinstance(values, list) for values in lists):
            raise CorruptFileError("split stream index: vertices, faces, offsets must be lists")
        if not all(_is_count(value) for values in lists for value in values):
            raise CorruptFileError("split stream index: a count or offset is not an integer >= 0")
        if not all(_is_count(value) for value in scalars):
            raise CorruptFileError("split stream index: crc32, versions, bits must be integers")
        vertices, faces, offsets = map(tuple, lists)
        crc, stream_version, bits, size = scalars
        if not len(vertices) == len(faces) == len(offsets) or not vertices:
            raise CorruptFileError("split stream index: its three lists differ in length")
        steps = (np.diff(vertices), np.diff(faces), np.diff(offsets))
        if (steps[0] <= 0).any() or (steps[1] < 0).any() or (steps[2] <= 0).any():
            raise CorruptFileError("split stream index: its counts or offsets do not grow")
        if offsets[0] != 0 or offsets[-1] != size or crc >= 1 << 32:
            raise CorruptFileError("split stream index: its offsets do not span the stream")
        if stream_version < STREAM_VERSION:
            raise OutdatedStreamError(
                f"split stream index: frames of version {stream_version}, this reads "
                f"{STREAM_VERSION} (encode the stream again)"
            )
        if stream_version != STREAM_VERSION:
            raise CorruptFileError(
                f"split stream index: frames of version {stream_version}, this reads "
                f"{STREAM_VERSION}"
            )
        return cls(vertices, faces, offsets, crc, stream_version, bits)


class OutdatedStreamError(CorruptFileError):
    """A stored stream of an older frame version: sound, but no longer read; the same
    progressive mesh encodes it again in this version."""


def _is_count(value) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def encode_stored_stream(
    pm: ProgressiveMesh,
    *,
    bits: int = 16,
    splits_per_frame: int = SPLITS_PER_FRAME,
    threads: int | None = None,
    progress: Callable[[float], None] | None = None,
) -> tuple[bytes, StreamIndex]:
    """The whole stream of ``pm`` (base to full), every frame a key frame, and its index.

    The frames are those of ``encode_split_frames(pm, n_base, n_full)`` (the same
    boundaries, positions and connectivity), each with fresh contexts and the grid. Groups
    of frames are encoded on ``threads`` threads (default: the cores), each from its own
    starting level; the bytes do not depend on the number of threads. ``progress``
    (fraction done) is called from this thread as groups finish."""
    grid = grid_for(pm, bits)
    bounds = plan_frames(pm, pm.n_base, pm.n_full, splits_per_frame)
    threads = max(1, threads or os.cpu_count() or 1)
    groups = _groups(bounds, threads * _GROUPS_PER_THREAD)

    def encode(group: list[int]) -> list[bytes]:
        return list(encode_frame_run(pm, group, grid, key_frames=True))

    frames: list[bytes] = []
    done = 0
    total = max(1, pm.n_full - pm.n_base)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for group, encoded in zip(groups, pool.map(encode, groups), strict=True):
            frames.extend(encoded)
            done += group[-1] - group[0]
            if progress is not None:
                progress(done / total)
    data = b"".join(frames)
    offsets = np.concatenate([[0], np.cumsum([len(frame) for frame in frames])])
    faces = [pm.n_faces(n) for n in bounds]
    index = StreamIndex(
        tuple(bounds), tuple(faces), tuple(int(x) for x in offsets), zlib.crc32(data),
        STREAM_VERSION, grid.bits,
    )  # fmt: skip
    return data, index


def _groups(bounds: list[int], count: int) -> list[list[int]]:
    """``bounds`` cut into at most ``count`` runs of frames (consecutive runs share their
    boundary) that take about as long each: a run costs its splits, and a run that does
    not start at the first boundary first extracts its level (``_SETUP_PER_VERTEX``)."""
    n_frames = len(bounds) - 1
    if n_frames <= 1 or count <= 1:
        return [bounds]

    def cuts_within(budget: float) -> list[int] | None:
        """The fewest runs, each costing at most ``budget`` (the ends of the runs, as
        frame indices), or None when more than ``count`` are needed."""
        cuts = [0]
        while cuts[-1] < n_frames:
            start = cuts[-1]
            setup = _SETUP_PER_VERTEX * bounds[start] if start else 0.0
            end = start + 1  # a run holds at least one frame
            while end < n_frames and setup + bounds[end + 1] - bounds[start] <= budget:
                end += 1
            cuts.append(end)
            if len(cuts) - 1 > count:
                return None
        return cuts

    low, high = 0.0, float(bounds[-1] - bounds[0]) * (1.0 + _SETUP_PER_VERTEX)
    best = cuts_within(high) or [0, n_frames]
    for _ in range(40):  # bisection on the costliest run's budget
        middle = (low + high) / 2
        cuts = cuts_within(middle)
        if cuts is None:
            low = middle
        else:
            high, best = middle, cuts
    return [bounds[a : b + 1] for a, b in zip(best[:-1], best[1:], strict=True)]


def index_stream(data: bytes) -> StreamIndex:
    """The index of a stored stream, read from its frames' headers (CorruptFileError when
    the bytes are not a stream of key frames, each starting where the last ended)."""
    vertices: list[int] = []
    faces: list[int] = []
    offsets = [0]
    bits = 16
    for payload in iter_frames([data]):
        if zlib.crc32(payload[:-4]) != struct.unpack("<I", payload[-4:])[0]:
            raise CorruptFileError(f"split frame at byte {offsets[-1]}: the CRC-32 does not match")
        try:
            body = msgpack.unpackb(payload[:-4])
            n_from, n_to = body["n_from"], body["n_to"]
            faces_from, n_new = body["faces_from"], body["n_new_faces"]
            if body.get("continues", False):
                raise CorruptFileError("a stored split stream holds key frames only")
            bits = body["bits"]
        except CorruptFileError:
            raise
        except Exception as error:  # msgpack, KeyError, TypeError...
            raise CorruptFileError(f"unreadable split frame ({error!r})") from None
        if vertices and (n_from != vertices[-1] or faces_from != faces[-1]):
            raise CorruptFileError(
                f"split frame refines {n_from} vertices, the previous ended at {vertices[-1]}"
            )
        if not vertices:
            vertices.append(n_from)
            faces.append(faces_from)
        vertices.append(n_to)
        faces.append(faces_from + n_new)
        offsets.append(offsets[-1] + 4 + len(payload))
    if not vertices:
        raise CorruptFileError("an empty split stream has no frames to index")
    return StreamIndex.from_json(
        StreamIndex(
            tuple(vertices), tuple(faces), tuple(offsets), zlib.crc32(data), STREAM_VERSION, bits
        ).to_json()
    )

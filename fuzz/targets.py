"""The fuzz targets: one per reader or decoder. A target takes bytes and must either
succeed or raise a `qem_core.QemError`; `mutate` makes its next input from a corpus
entry (checksums made right again where the format has them, so that a change reaches
the code past the check)."""

from __future__ import annotations

import json
import math
import random
import struct
import zlib
from collections.abc import Callable
from dataclasses import dataclass

import msgpack
import numpy as np

import qem_core
from qem_core.codecs.archive import open_archive
from qem_core.codecs.glb import read_glb, read_gltf
from qem_core.codecs.msgpack_mesh import read_msgpack, read_msgpack_wedges
from qem_core.codecs.mtl import read_mtl
from qem_core.codecs.obj import read_obj
from qem_core.codecs.off import read_off
from qem_core.codecs.ply import read_ply
from qem_core.codecs.stl import read_stl
from qem_core.stream import SplitStreamDecoder, iter_frames

from .mutate import mutate_bytes, mutate_text, mutate_tree

__all__ = ["TARGETS", "Target"]

# Meshes read from a mutated file are built (and a level of them written) when they are
# this small, so that the build and the writers see what the readers let through.
_BUILD_LIMIT = 400


@dataclass(frozen=True)
class Target:
    name: str
    run: Callable[[bytes], None]
    mutate: Callable[[bytes, random.Random, list[bytes]], bytes]


def _reader(fmt: str, read) -> Callable[[bytes], None]:
    """Read with the format's own reader (not `load_mesh`, whose catch-all rewords a
    foreign exception and would hide it), then validate, and build what is small."""

    def run(data: bytes) -> None:
        read(data)
        mesh = qem_core.load_mesh(data, format=fmt)
        if mesh.vertices.shape[0] <= _BUILD_LIMIT:
            pm = qem_core.build_mesh(mesh)
            level = pm.lod_mesh((pm.n_base + pm.n_full) // 2)
            qem_core.codecs.write_mesh(level, "glb")

    return run


def _archive(data: bytes) -> None:
    """The archive's checks and its model's reader (given the archive's files), as
    `load_mesh` of a .zip runs them."""
    model, content, files = open_archive(data)
    if model.lower().endswith(".obj"):
        read_obj(content, files)
    else:
        qem_core.load_mesh(content, name=model.rsplit("/", 1)[-1])


def _msgpack_level(data: bytes) -> None:
    read_msgpack(data)
    read_msgpack_wedges(data)
    try:
        SplitStreamDecoder.from_msgpack(data)
    except qem_core.InvalidOptionsError:
        pass  # float32 positions: a level, but no start for a stream


def _qpm(data: bytes) -> None:
    pm = qem_core.load(data)
    for n in (pm.n_base, (pm.n_base + pm.n_full) // 2, pm.n_full):
        pm.lod_mesh(n)
    pm.splits(pm.n_base, pm.n_full)


def _stream(data: bytes) -> None:
    base, stream = _split_stream_input(data)
    decoder = SplitStreamDecoder.from_msgpack(base)
    for payload in iter_frames([stream]):
        decoder.feed(payload)


def _split_stream_input(data: bytes) -> tuple[bytes, bytes]:
    if len(data) < 4:
        raise qem_core.CorruptFileError("fuzz input: no base length")
    (length,) = struct.unpack_from("<I", data)
    return data[4 : 4 + length], data[4 + length :]


def _mutate_any(data: bytes, rng: random.Random, corpus: list[bytes]) -> bytes:
    text = b"\0" not in data[:512]
    return (
        mutate_text(data, rng, corpus)
        if text and rng.random() < 0.6
        else mutate_bytes(data, rng, corpus)
    )


def _values_or_bytes(loads, dumps):
    """A mutator changing the decoded values (``loads``, ``dumps``) of its input, or its
    bytes when they no longer decode (an earlier byte change) or a value cannot be
    encoded back."""

    def mutate(data: bytes, rng: random.Random, corpus: list[bytes]) -> bytes:
        if rng.random() < 0.6:
            try:
                return dumps(mutate_tree(loads(data), rng))
            except Exception:
                pass
        return mutate_bytes(data, rng, corpus)

    return mutate


_mutate_msgpack = _values_or_bytes(lambda d: msgpack.unpackb(d, raw=False), msgpack.packb)
_mutate_json = _values_or_bytes(json.loads, lambda value: json.dumps(value).encode())


def _mutate_glb(data: bytes, rng: random.Random, corpus: list[bytes]) -> bytes:
    """The JSON chunk's values (the glTF document), chunk lengths made right, or bytes."""
    if rng.random() < 0.6 and len(data) >= 20 and data[:4] == b"glTF":
        (length,) = struct.unpack_from("<I", data, 12)
        try:
            document = json.loads(data[20 : 20 + length])
            text = json.dumps(mutate_tree(document, rng)).encode()
        except Exception:  # not JSON (an earlier change), or a value JSON cannot hold
            return mutate_bytes(data, rng, corpus)
        text += b" " * (-len(text) % 4)
        rest = data[20 + length :]
        return (
            struct.pack("<4sII", b"glTF", 2, 20 + len(text) + len(rest))
            + struct.pack("<II", len(text), 0x4E4F534A)
            + text
            + rest
        )
    return mutate_bytes(data, rng, corpus)


# What `_mutate_qpm_array` sets an element of a stored integer array to, besides small
# changes and other elements' values: counts and ids near the ends of small arrays, and
# the edges of the integer types (offsets whose int64 steps wrap around once got past
# checks by np.diff and made np.repeat write past its array).
_EDGE_INTEGERS = (0, 1, -1, 2, 3, 255, 256, 2**15, 2**16, 2**31 - 1, 2**31, 2**32 - 1,
                  2**62, 2**63 - 1, -(2**31), -(2**62), -(2**63))  # fmt: skip
_EDGE_FLOATS = (0.0, -0.0, 1.0, -1.0, 1e-40, 65504.0, 1e30, -1e30, float("inf"), float("nan"))


def _in_type(value: int, dtype: np.dtype) -> int:
    """``value`` wrapped into the range of the integer type ``dtype``."""
    bits = 8 * dtype.itemsize
    value %= 1 << bits
    return value - (1 << bits) if dtype.kind == "i" and value >= 1 << (bits - 1) else value


def _mutate_qpm_array(body: bytes, rng: random.Random) -> bytes | None:
    """One element of one array stored in the .qpm body (or a run of them) set to an edge
    value, another element's value or itself give or take 2; the header untouched, so
    that the change reaches the loader's checks of the arrays' contents and the kernels
    behind them. None when the header does not name an array held in the body."""
    try:
        (length,) = struct.unpack_from("<I", body, 12)
        header = msgpack.unpackb(body[16 : 16 + length], raw=False)
        entries = []
        for _name, dtype, shape, offset in header["arrays"]:
            dtype, size = np.dtype(dtype), math.prod(shape)  # ints: no overflow warning
            at = 16 + length + offset
            fits = type(offset) is int and 0 <= offset and at + size * dtype.itemsize <= len(body)
            if dtype.kind in "iuf" and type(size) is int and 0 < size and fits:
                entries.append((dtype, size, at))
    except Exception:  # an earlier change: not a header that names arrays
        return None
    if not entries:
        return None
    dtype, size, at = rng.choice(entries)
    values = np.frombuffer(body, dtype, count=size, offset=at).copy()
    first = rng.randrange(size)
    run = rng.choice([1, 1, 1, 2, 3, rng.randrange(1, size + 1)])
    for i in range(first, min(size, first + run)):
        if dtype.kind == "f":
            values[i] = rng.choice(_EDGE_FLOATS)
            continue
        choice = rng.random()
        if choice < 0.3:
            value = int(values[i]) + rng.choice((-2, -1, 1, 2))
        elif choice < 0.5:
            value = int(values[rng.randrange(size)])
        else:
            value = rng.choice(_EDGE_INTEGERS)
        values[i] = _in_type(value, dtype)
    return body[:at] + values.tobytes() + body[at + values.nbytes :]


def _mutate_qpm(data: bytes, rng: random.Random, corpus: list[bytes]) -> bytes:
    """An element of a stored array, the header's values (msgpack at bytes 16..16 + its
    length) or any bytes, then the trailing CRC-32 made right."""
    body = data[:-4]
    choice = rng.random()
    changed = _mutate_qpm_array(body, rng) if choice < 0.3 else None
    if changed is not None:
        body = changed
    elif choice < 0.7 and len(body) >= 16:
        (length,) = struct.unpack_from("<I", body, 12)
        try:
            header = msgpack.unpackb(body[16 : 16 + length], raw=False)
            packed = msgpack.packb(mutate_tree(header, rng))
            body = body[:12] + struct.pack("<I", len(packed)) + packed + body[16 + length :]
        except Exception:  # the header no longer parses: change bytes instead
            body = mutate_bytes(body, rng, corpus)
    else:
        body = mutate_bytes(body, rng, corpus)
    return body + struct.pack("<I", zlib.crc32(body))


def _mutate_stream(data: bytes, rng: random.Random, corpus: list[bytes]) -> bytes:
    """One frame's values, or bytes; every frame's CRC-32 made right (frames are cut by
    their length prefixes as long as those hold)."""
    base, stream = _split_stream_input(data) if len(data) >= 4 else (b"", b"")
    frames = []
    at = 0
    while at + 4 <= len(stream):
        (length,) = struct.unpack_from("<I", stream, at)
        if length < 4 or at + 4 + length > len(stream):
            break
        frames.append(stream[at + 4 : at + 4 + length - 4])
        at += 4 + length
    tail = stream[at:]
    choice = rng.random()
    if frames and choice < 0.5:
        i = rng.randrange(len(frames))
        try:
            frames[i] = msgpack.packb(mutate_tree(msgpack.unpackb(frames[i], raw=False), rng))
        except Exception:
            frames[i] = mutate_bytes(frames[i], rng, corpus)
    elif frames and choice < 0.8:
        i = rng.randrange(len(frames))
        frames[i] = mutate_bytes(frames[i], rng, corpus)
    elif frames and choice < 0.9:
        del frames[rng.randrange(len(frames))]
    else:
        base = _mutate_msgpack(base, rng, corpus)
    sealed = b"".join(
        struct.pack("<I", len(body) + 4) + body + struct.pack("<I", zlib.crc32(body))
        for body in frames
    )
    return struct.pack("<I", len(base)) + base + sealed + tail


TARGETS: dict[str, Target] = {
    target.name: target
    for target in (
        Target("ply", _reader("ply", read_ply), _mutate_any),
        Target("obj", _reader("obj", read_obj), _mutate_any),
        Target("mtl", read_mtl, _mutate_any),
        Target("zip", _archive, mutate_bytes),
        Target("stl", _reader("stl", read_stl), _mutate_any),
        Target("off", _reader("off", read_off), _mutate_any),
        Target("glb", _reader("glb", read_glb), _mutate_glb),
        Target("gltf", _reader("gltf", read_gltf), _mutate_json),
        Target("msgpack", _msgpack_level, _mutate_msgpack),
        Target("qpm", _qpm, _mutate_qpm),
        Target("stream", _stream, _mutate_stream),
    )
}

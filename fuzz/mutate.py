"""Mutators: a random change to an input, at the byte level or, for msgpack-framed
inputs, to the values the msgpack holds."""

from __future__ import annotations

import math
import random
import struct

import msgpack

__all__ = ["mutate_bytes", "mutate_tree", "mutate_text"]

# Integers at the edges of the types readers convert to, and the sizes that overflow them.
INTERESTING_INTEGERS = (
    0, 1, 2, 3, 7, 255, 256, 65535, 65536, 2**31 - 1, 2**31, 2**32 - 1, 2**32,
    2**53 + 1, 2**63 - 1, -1, -2, -(2**31), -(2**63),
)  # fmt: skip
# Tokens a text reader must refuse or read right, put where a number stood.
INTERESTING_TOKENS = (
    b"nan", b"inf", b"-inf", b"1e309", b"-0", b"0x10", b"99999999999999999999", b"1.5",
    b"-1", b"", b"\xff\xfe", b"1e-320", b"+", b"0" * 5000,
)  # fmt: skip


def mutate_bytes(data: bytes, rng: random.Random, corpus: list[bytes]) -> bytes:
    """One to four byte-level changes: bit flips, interesting integers written over
    bytes, chunks deleted, repeated or spliced in from another input, truncation."""
    out = bytearray(data)
    for _ in range(rng.randint(1, 4)):
        choice = rng.randrange(7)
        if not out:
            out += bytes(rng.randrange(256) for _ in range(rng.randint(1, 8)))
            continue
        at = rng.randrange(len(out))
        if choice == 0:
            out[at] ^= 1 << rng.randrange(8)
        elif choice == 1:
            out[at] = rng.choice((0, 0xFF, 0x7F, 0x80, rng.randrange(256)))
        elif choice == 2:
            width, fmt = rng.choice(((1, "b"), (2, "h"), (4, "i"), (8, "q")))
            value = rng.choice(INTERESTING_INTEGERS)
            value = (value + 2 ** (8 * width - 1)) % 2 ** (8 * width) - 2 ** (8 * width - 1)
            packed = struct.pack(rng.choice("<>") + fmt, value)
            out[at : at + width] = packed
        elif choice == 3:
            del out[at : at + rng.randint(1, 64)]
        elif choice == 4:
            chunk = out[at : at + rng.randint(1, 64)]
            out[at:at] = chunk * rng.randint(1, 4)
        elif choice == 5:
            other = rng.choice(corpus)
            if other:
                start = rng.randrange(len(other))
                out[at:at] = other[start : start + rng.randint(1, 256)]
        else:
            del out[at:]
    return bytes(out)


def mutate_text(data: bytes, rng: random.Random, corpus: list[bytes]) -> bytes:
    """For text formats: an interesting token in place of a number (or any word), or a
    line repeated or removed; else a byte-level change."""
    words = data.split(b" ")
    choice = rng.randrange(4)
    if choice == 0 and len(words) > 1:
        words[rng.randrange(len(words))] = rng.choice(INTERESTING_TOKENS)
        return b" ".join(words)
    lines = data.split(b"\n")
    if choice == 1 and len(lines) > 1:
        at = rng.randrange(len(lines))
        lines[at:at] = [lines[rng.randrange(len(lines))]] * rng.randint(1, 3)
        return b"\n".join(lines)
    if choice == 2 and len(lines) > 1:
        del lines[rng.randrange(len(lines))]
        return b"\n".join(lines)
    return mutate_bytes(data, rng, corpus)


def _odd_value(rng: random.Random, value):
    """A value of another type or range than ``value``: what a reader that trusts its
    input's types would mishandle."""
    choices = [
        None, True, False, rng.choice(INTERESTING_INTEGERS), math.nan, math.inf, -math.inf,
        -1.5, 1e308, "", "x" * rng.randint(1, 40), b"", [], {}, [True], [2**63 - 1, 0],
        [rng.choice(INTERESTING_INTEGERS)] * rng.randint(0, 4),
    ]  # fmt: skip
    if isinstance(value, int) and not isinstance(value, bool):
        choices += [value + 1, value - 1, -value, value * 2**20, float(value)]
    if isinstance(value, list) and value:
        choices += [value[:-1], value + value[-1:], value[::-1], [value]]
    if isinstance(value, bytes) and value:
        choices += [value[:-1], value + value[-1:], value[: len(value) // 2]]
    return rng.choice(choices)


def mutate_tree(tree, rng: random.Random):
    """The decoded msgpack ``tree`` with one value (anywhere in it) replaced by an odd
    one, or one map key dropped; a new tree, ``tree`` unchanged."""
    tree = msgpack.unpackb(msgpack.packb(tree, use_bin_type=True), raw=False, strict_map_key=False)
    places = []

    def walk(node):
        if isinstance(node, dict):
            for key in node:
                places.append((node, key))
                walk(node[key])
        elif isinstance(node, list):
            for index in range(len(node)):
                places.append((node, index))
                walk(node[index])

    walk(tree)
    if not places:
        return _odd_value(rng, tree)
    parent, key = rng.choice(places)
    if isinstance(parent, dict) and rng.random() < 0.15:
        del parent[key]
    else:
        parent[key] = _odd_value(rng, parent[key])
    return tree

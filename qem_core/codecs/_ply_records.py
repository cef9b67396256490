"""Record walks for PLY elements whose list properties vary in length.

A PLY record with a list property has no fixed size (a face element mixing triangles
and quads), so where record i starts depends on every count before it: a sequential
walk. These kernels do that walk once, in compiled code, and return where each property
of each record starts and how many items each list holds; the caller then gathers the
values (`gather_items`). Kernels neither validate nor raise: they return a status.

Elements whose lists all have the same length (the usual triangle-only face element)
never come here: the PLY reader maps them with one structured numpy dtype.
"""

from __future__ import annotations

import numba
import numpy as np

# Status codes returned instead of an end position.
TRUNCATED = -1
BAD_COUNT = -2


def _walk_binary(
    data, start, n_records, is_list, sizes, count_sizes, count_signed, big_endian,
    property_starts, list_counts,
):  # fmt: skip
    """Walk `n_records` binary records of `data` (uint8) from byte `start`.

    is_list, sizes, count_sizes, count_signed : (p,) per property: whether it is a list,
        the byte size of its value (of each item for a list), the byte size of a list's
        count and whether that count type is signed.
    property_starts, list_counts : (n_records, p) int64 outputs: the byte where each
        property's value (a list's first item) starts, and each list's item count.

    Returns the byte just past the last record, TRUNCATED if the data ends first, or
    BAD_COUNT for a negative list count (its record and property then hold count -1 and
    the byte where the count starts, for the caller's message).
    """
    end = data.size
    position = start
    for record in range(n_records):
        for prop in range(is_list.size):
            if is_list[prop]:
                n_bytes = count_sizes[prop]
                if position + n_bytes > end:
                    return TRUNCATED
                count = 0
                for k in range(n_bytes):
                    byte = data[position + k] if big_endian else data[position + n_bytes - 1 - k]
                    count = count * 256 + np.int64(byte)
                if count_signed[prop] and count >= np.int64(1) << (8 * n_bytes - 1):
                    property_starts[record, prop] = position
                    list_counts[record, prop] = -1
                    return BAD_COUNT
                position += n_bytes
                property_starts[record, prop] = position
                list_counts[record, prop] = count
                position += count * sizes[prop]
            else:
                property_starts[record, prop] = position
                position += sizes[prop]
            if position > end:
                return TRUNCATED
    return position


def _walk_tokens(tokens, start, n_records, is_list, property_starts, list_counts):
    """The ASCII twin of `_walk_binary`: positions are token indices in `tokens` (float64).

    Returns the token just past the last record, TRUNCATED, or BAD_COUNT for a list
    count that is negative, not an integer or more than the tokens left (marked as in
    `_walk_binary`: count -1, and the count's token).
    """
    end = tokens.size
    position = start
    for record in range(n_records):
        for prop in range(is_list.size):
            if is_list[prop]:
                if position >= end:
                    return TRUNCATED
                value = tokens[position]
                if not (value >= 0.0 and value <= end and value == np.floor(value)):
                    property_starts[record, prop] = position
                    list_counts[record, prop] = -1
                    return BAD_COUNT
                count = np.int64(value)
                position += 1
                property_starts[record, prop] = position
                list_counts[record, prop] = count
                position += count
            else:
                property_starts[record, prop] = position
                position += 1
            if position > end:
                return TRUNCATED
    return position


def _gather_items(data, starts, counts, item_size, out):
    """Copy the items of each record, ``counts[r]`` items of `item_size` bytes from byte
    ``starts[r]`` of `data` (uint8), one record after another into `out` (uint8, the
    sum of the counts times `item_size` bytes). The starts and counts are a walk's, so
    every record's items lie within `data`."""
    at = 0
    for record in range(starts.size):
        begin = starts[record]
        n_bytes = counts[record] * item_size
        for k in range(n_bytes):
            out[at + k] = data[begin + k]
        at += n_bytes


walk_binary = numba.njit(cache=True)(_walk_binary)
gather_items = numba.njit(cache=True)(_gather_items)
walk_tokens = numba.njit(cache=True)(_walk_tokens)

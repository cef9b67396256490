"""HTTP Range requests on stored bytes (RFC 9110, 14): one byte range per request.

An interrupted download resumes with ``Range: bytes=N-`` and any cache or CDN in front of
the server can fill itself by parts. What is refused, as problem details: a header that
is not ``bytes=`` followed by one range (400 ``invalid-range``; several ranges would need
a multipart/byteranges answer, which no client of this API wants), and a range that
starts past the end (416 ``range-not-satisfiable``, with ``Content-Range: bytes */size``).
``If-Range`` with an entity tag other than the current one (or a date: the stored bytes
have no modification time) turns the request into a plain GET of everything.
"""

from __future__ import annotations

import re

from .problems import Problem

__all__ = ["byte_range", "if_range_holds"]

_RANGE = re.compile(r"^\s*bytes\s*=\s*(\d*)\s*-\s*(\d*)\s*$", re.IGNORECASE)
_BYTES_UNIT = re.compile(r"^\s*bytes\s*=", re.IGNORECASE)
_MAX_DIGITS = 19  # a declared position past 2^63 is malformed, not a huge allocation


def if_range_holds(if_range: str | None, etag: str) -> bool:
    """Whether a Range may be honoured: no If-Range, or If-Range naming ``etag``
    (strong comparison: a weak tag never matches)."""
    return if_range is None or if_range.strip() == etag


def byte_range(header: str | None, size: int) -> tuple[int, int] | None:
    """The bytes ``[start, stop)`` a Range header asks of ``size`` bytes, or None for the
    whole (no header). Problem 400 for a malformed or multiple range, 416 for one that
    starts at or past ``size`` (or a suffix of 0 bytes). A header of another unit than
    bytes (or of none, as ``null``) is ignored, as RFC 9110 (14.2) requires: None."""
    if header is None or not _BYTES_UNIT.match(header):
        return None
    match = _RANGE.match(header)
    if match is None or len(match[1]) > _MAX_DIGITS or len(match[2]) > _MAX_DIGITS:
        several = "," in header
        raise Problem(
            "invalid-range",
            f"Range {header[:100]!r} is not "
            + (
                "one range: ask for one range per request"
                if several
                else "'bytes=FIRST-LAST', 'bytes=FIRST-' or 'bytes=-SUFFIX'"
            ),
        )
    first, last = match[1], match[2]
    if not first and not last:
        raise Problem("invalid-range", "Range 'bytes=-' names no bytes")
    unsatisfiable = Problem(
        "range-not-satisfiable",
        f"Range {header[:100]!r} asks for no byte of the {size} there are",
        headers={"Content-Range": f"bytes */{size}"},
        size=size,
    )
    if not first:  # the last N bytes
        suffix = int(last)
        if suffix == 0 or size == 0:
            raise unsatisfiable
        return max(0, size - suffix), size
    start = int(first)
    stop = size if not last else int(last) + 1
    if last and stop <= start:
        raise Problem("invalid-range", f"Range {header[:100]!r} ends before it starts")
    if start >= size:
        raise unsatisfiable
    return start, min(stop, size)

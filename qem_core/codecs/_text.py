"""Number parsing for the text formats (ASCII PLY, OBJ, OFF, ASCII STL).

Numbers are parsed by numpy in C from whole blocks of text, never token by token in
Python: `np.fromstring(text, sep=" ")` reads any run of whitespace (newlines included)
as one separator.
"""

from __future__ import annotations

import re
import warnings

import numpy as np

from ..errors import MeshFormatError

_NON_SPACE = re.compile(rb"\S")


def parse_numbers(text: bytes, dtype: type, what: str) -> np.ndarray:
    """All whitespace-separated numbers in `text` as a 1-D array of `dtype`.

    dtype : np.float64 (accepts nan, inf, exponents) or np.int64 (plain integers only).
    what : names the text in the error message, e.g. "OBJ 'v' lines".

    Raises MeshFormatError if a token is not a number of that kind.
    """
    # numpy reads text holding only whitespace as one bogus value: answer it here.
    if _NON_SPACE.search(text) is None:
        return np.zeros(0, dtype=dtype)
    try:
        with warnings.catch_warnings():
            # numpy < 3 warns (DeprecationWarning) and stops at the first bad token;
            # make that an error so no partial result slips through.
            warnings.simplefilter("error", DeprecationWarning)
            return np.fromstring(text, dtype=dtype, sep=" ")
    except (ValueError, DeprecationWarning):
        kind = "integers" if np.dtype(dtype).kind == "i" else "numbers"
        bad = _first_bad_token(text, dtype)
        raise MeshFormatError(
            f"{what}: expected whitespace-separated {kind}, found {bad!r}; "
            "the file is damaged or not in the format its name says"
        ) from None


def count_tokens(lines: list[bytes]) -> np.ndarray:
    """(len(lines),) int64: the number of whitespace-separated tokens on each line."""
    return np.fromiter(map(len, map(bytes.split, lines)), dtype=np.int64, count=len(lines))


def parse_lines(lines: list[bytes], what: str) -> tuple[np.ndarray, np.ndarray]:
    """(numbers, counts): every number on the lines as float64, one after another, and
    how many numbers each line holds."""
    counts = count_tokens(lines)
    return parse_numbers(b"\n".join(lines), np.float64, what), counts


def _first_bad_token(text: bytes, dtype: type) -> str:
    """The first token of `text` that does not parse (for error messages only)."""
    convert = int if np.dtype(dtype).kind == "i" else float
    for token in text.split():
        try:
            convert(token)
        except ValueError:
            return token[:40].decode("ascii", "replace")
    return "?"

"""What every ``qem`` subcommand shares: exit statuses, the user-facing error, output
helpers and the progress bar."""

from __future__ import annotations

import json
import shutil
import sys
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

__all__ = [
    "EXIT_BROKEN_PIPE",
    "EXIT_FAILED",
    "EXIT_INTERRUPTED",
    "EXIT_OK",
    "EXIT_TIMEOUT",
    "EXIT_UNREACHABLE",
    "EXIT_USAGE",
    "OUTPUT_FORMATS",
    "Bar",
    "CliError",
    "format_of",
    "note",
    "parse_option_pairs",
    "print_json",
    "reading",
    "write_atomically",
]

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_UNREACHABLE, EXIT_TIMEOUT = 0, 1, 2, 3, 4
EXIT_INTERRUPTED = 130
EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, as a process killed by it

# Output suffix -> mesh format.
OUTPUT_FORMATS = {
    ".ply": "ply",
    ".obj": "obj",
    ".glb": "glb",
    ".msgpack": "msgpack",
    ".mpk": "msgpack",
    ".zip": "zip",  # the OBJ with its .mtl and texture
}


class CliError(Exception):
    """A message for the user and an exit status."""

    def __init__(self, message: str, status: int = EXIT_FAILED) -> None:
        super().__init__(message)
        self.status = status


def format_of(output: str, given: str | None, default: str = "ply") -> str:
    """The mesh format to write: `given`, else the suffix of `output` ("-": default)."""
    if given is not None:
        return given
    suffix = "" if output == "-" else Path(output).suffix.lower()
    if suffix and suffix not in OUTPUT_FORMATS:
        raise CliError(
            f"cannot tell the format from {output!r}; use one of "
            f"{', '.join(OUTPUT_FORMATS)} or --format",
            EXIT_USAGE,
        )
    return OUTPUT_FORMATS.get(suffix, default)


def write_atomically(output: str, content: bytes | Callable[[Path], None]) -> None:
    """Write to the path `output` (or stdout for "-"), never leaving half a file.

    content : the bytes, or a function that writes the file at the path it is given."""
    if output == "-":
        assert isinstance(content, bytes)
        sys.stdout.buffer.write(content)
        sys.stdout.buffer.flush()
        return
    path = Path(output)
    try:
        if path.exists() and not path.is_file():
            # A FIFO or a device (through a link: /dev/stdout into a pipe): a rename would
            # replace it; its reader gets the bytes.
            _write_through(path, output, content)
            return
        if path.is_symlink():
            path = path.resolve(strict=True)  # the file the link names; the link stays
    except (OSError, RuntimeError) as exc:  # RuntimeError: a loop of links
        raise CliError(f"cannot write {output}: {getattr(exc, 'strerror', None) or exc}") from None
    partial = path.with_name(path.name + ".part")
    try:
        if isinstance(content, bytes):
            partial.write_bytes(content)
        else:
            content(partial)
        partial.replace(path)
    except OSError as exc:
        partial.unlink(missing_ok=True)
        raise CliError(f"cannot write {output}: {exc.strerror or exc}") from None


def _write_through(path: Path, output: str, content: bytes | Callable[[Path], None]) -> None:
    """Write into the existing non-regular file `path` (a FIFO, /dev/null...)."""
    try:
        with open(path, "wb") as target:
            if isinstance(content, bytes):
                target.write(content)
                return
            with tempfile.TemporaryDirectory() as folder:
                staged = Path(folder) / path.name
                content(staged)
                with open(staged, "rb") as source:
                    shutil.copyfileobj(source, target)
    except OSError as exc:
        raise CliError(f"cannot write {output}: {exc.strerror or exc}") from None


def parse_option_pairs(pairs: list[str]) -> dict[str, str]:
    """Build options given as repeated ``--option NAME=VALUE``, as text."""
    options = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or not key.strip():
            raise CliError(f"option {pair!r} is not NAME=VALUE", EXIT_USAGE)
        if key.strip() in options:
            # The server refuses a repeated parameter; keeping the last would be a guess.
            raise CliError(f"option {key.strip()!r} is given twice", EXIT_USAGE)
        options[key.strip()] = value.strip()
    return options


@contextmanager
def reading(path: str) -> Iterator[None]:
    """Turn the errors of reading the file `path` into messages for the user."""
    from qem_core.errors import QemError  # only local commands pay for importing qem_core

    try:
        yield
    except FileNotFoundError:
        raise CliError(f"{path}: no such file", EXIT_USAGE) from None
    except IsADirectoryError:
        raise CliError(f"{path} is a directory", EXIT_USAGE) from None
    except QemError as exc:
        raise CliError(f"{path}: {exc}") from None


def print_json(value: Any) -> None:
    json.dump(value, sys.stdout, indent=2)
    sys.stdout.write("\n")


def note(message: str) -> None:
    print(message, file=sys.stderr)


class Bar:
    """A one-line progress bar on stderr, drawn only on a terminal."""

    def __init__(self, label: str, enabled: bool) -> None:
        self.label = label
        self.enabled = enabled and sys.stderr.isatty()
        self._last = -1

    def show(self, fraction: float, suffix: str = "") -> None:
        if not self.enabled:
            return
        percent = int(100 * min(1.0, max(0.0, fraction)))
        if percent == self._last and not suffix:
            return
        self._last = percent
        filled = percent * 30 // 100
        sys.stderr.write(
            f"\r{self.label:<7} [{'#' * filled}{'.' * (30 - filled)}] {percent:3d}% {suffix}\033[K"
        )
        sys.stderr.flush()

    def done(self) -> None:
        if self.enabled and self._last >= 0:
            sys.stderr.write("\n")
            sys.stderr.flush()

"""Writing results: number formats, Markdown tables and the JSON files under
bench/results/."""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

__all__ = [
    "RESULTS_DIR",
    "format_mib",
    "format_ms",
    "format_ratio",
    "format_sci",
    "markdown_table",
    "read_json",
    "write_json",
]

RESULTS_DIR = Path(__file__).resolve().parent / "results"


def format_sci(value: float | None) -> str:
    """3 significant digits in scientific notation ("1.23e-04"); "-" for None."""
    return "-" if value is None else f"{value:.2e}"


def format_ms(seconds: float | None) -> str:
    """Seconds as milliseconds: one decimal, three below 1 ms ("0.042"); "-" for None."""
    if seconds is None:
        return "-"
    return f"{seconds * 1e3:.3f}" if seconds < 1e-3 else f"{seconds * 1e3:.1f}"


def format_mib(n_bytes: int | None, increase_bytes: int | None = None) -> str:
    """Bytes as whole MiB, with the increase in parentheses if given: "214 (+84)"."""
    if n_bytes is None:
        return "-"
    text = f"{n_bytes / 2**20:.0f}"
    if increase_bytes is not None:
        text += f" (+{increase_bytes / 2**20:.0f})"
    return text


def format_ratio(value: float | None) -> str:
    """A ratio with two decimals ("0.83"); "-" for None."""
    return "-" if value is None else f"{value:.2f}"


def markdown_table(headers: Sequence[str], rows: Sequence[Sequence[str]], numeric: Sequence[bool]):
    """Lines of a Markdown table; columns flagged in `numeric` are right-aligned."""
    align = ["---:" if is_numeric else "---" for is_numeric in numeric]
    lines = ["| " + " | ".join(headers) + " |", "|" + "|".join(align) + "|"]
    lines += ["| " + " | ".join(row) + " |" for row in rows]
    return lines


def read_json(path: Path) -> dict[str, Any]:
    """The JSON object stored at `path`, or {} if there is none or it does not parse."""
    try:
        with open(path, encoding="utf-8") as stream:
            loaded = json.load(stream)
    except (OSError, ValueError):
        return {}
    return loaded if isinstance(loaded, dict) else {}


def write_json(path: Path, data: dict[str, Any]) -> None:
    """Write `data` as indented JSON, replacing the file atomically."""
    path.parent.mkdir(parents=True, exist_ok=True)
    staging = path.with_suffix(path.suffix + ".tmp")
    with open(staging, "w", encoding="utf-8") as stream:
        json.dump(data, stream, indent=1, sort_keys=False)
        stream.write("\n")
    staging.replace(path)

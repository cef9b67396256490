"""Pieces shared by the lod_speed, stream_size and service benchmarks.

- `measure_or_fail`: `bench.measure.measure_in_child`, with a failure kept as a status
  line instead of raised, so one broken series does not stop a whole report.
- `load_average` / `run_header_lines`: the machine's load average at the start and the
  end of a run, and the opening lines of a results file that state it with the machine,
  the code measured and the command.
- `source_revision`: the commit measured, and which source files differed from it.
- `bench_parser`, `merge_results`: the command-line options every one of them takes,
  and merging a run's entries into its JSON file under bench/results/.
- `now`, `progress`: the timestamp written into results, a progress line on stderr.
- `record_run`: one run's record (when, code, command, load average around it) written
  as its Markdown report and JSON file.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from .machine import describe_machine, machine_header_lines
from .measure import ChildCallError, measure_in_child, median_of_runs
from .meshes import DEFAULT_MESH_DIR
from .report import RESULTS_DIR, read_json, write_json

__all__ = [
    "Measured",
    "bench_parser",
    "merge_results",
    "load_average",
    "measure_or_fail",
    "now",
    "progress",
    "record_run",
    "run_header_lines",
    "source_revision",
]

_REPO_ROOT = Path(__file__).resolve().parents[1]
_SOURCE_DIRS = ("qem_core", "server", "client", "bench")


@dataclass(frozen=True)
class Measured:
    """One `measure_in_child` call, or why it failed.

    status : "ok", or "failed: <last line of the error>".
    times_s : each run's time, seconds; cpu_times_s : each run's CPU time (user + system,
    all threads of the child), seconds; peak_rss_bytes : the child's peak RSS (None when
    failed); result : what the child's `then` returned (None when failed).
    """

    status: str
    times_s: tuple[float, ...] = ()
    cpu_times_s: tuple[float, ...] = ()
    peak_rss_bytes: int | None = None
    result: Any = None

    @property
    def ok(self) -> bool:
        return self.status == "ok" and bool(self.times_s)

    @property
    def median_s(self) -> float | None:
        return median_of_runs(self.times_s) if self.ok else None

    def to_dict(self) -> dict[str, Any]:
        return {
            "status": self.status,
            "times_s": list(self.times_s),
            "median_s": self.median_s,
            "cpu_times_s": list(self.cpu_times_s),
            "cpu_median_s": median_of_runs(self.cpu_times_s) if self.ok else None,
            "peak_rss_bytes": self.peak_rss_bytes,
        }


def measure_or_fail(
    function: Callable[..., Any], args: Sequence[Any] = (), **options: Any
) -> Measured:
    """`measure_in_child(function, args, **options)`; a ChildCallError becomes a status."""
    try:
        measured = measure_in_child(function, args, **options)
    except ChildCallError as error:
        lines = [line.strip() for line in str(error).splitlines() if line.strip()]
        return Measured(status="failed: " + (lines[-1] if lines else type(error).__name__))
    return Measured("ok", measured.times_s, measured.cpu_times_s, measured.peak_rss_bytes,
                    measured.result)


def load_average() -> list[float]:
    """The 1, 5 and 15 minute load averages (empty where the OS does not give them)."""
    try:
        return [round(value, 2) for value in os.getloadavg()]
    except OSError:
        return []


def run_header_lines(record: dict[str, Any], versions: Sequence[str] = ()) -> list[str]:
    """The opening Markdown lines of a results file: when and on which code it was
    measured, the machine and package versions (plus `versions`, e.g. "DracoPy 2.2.0"),
    how busy the machine was (the load averages in `record["load_average"]`, "start"
    and "end"), and the command that produced it (`record["command"]`)."""

    def shown(values: Sequence[float]) -> str:
        return " / ".join(f"{value:.2f}" for value in values) if values else "unknown"

    load = record["load_average"]
    return [
        f"Measured {record['measured_at']} on code {record['source']}.",
        *machine_header_lines(),
        *([f"Also: {', '.join(versions)}."] if versions else []),
        "",
        f"Contention: the machine has {os.cpu_count()} cores and is shared; other work "
        "(tests, builds) may run beside the benchmark, so single runs are noisy and the "
        "figures to quote are medians and ratios measured side by side in the same run. "
        f"Load average (1 / 5 / 15 min) at the start: {shown(load['start'])}, at the end: "
        f"{shown(load['end'])}.",
        "",
        f"Command: `{record['command']}`.",
    ]


def now() -> str:
    """UTC now, ISO 8601 to the second."""
    return datetime.now(UTC).isoformat(timespec="seconds")


def progress(message: str) -> None:
    """A progress line on stderr."""
    print(message, file=sys.stderr, flush=True)


def source_revision() -> str:
    """The checked-out commit (short hash) and the uncommitted source changes the
    figures include, e.g. "3b7fdd3 (uncommitted: qem_core/qpm.py)"; "unknown" outside a
    git checkout."""

    def git(*arguments: str) -> str:
        return subprocess.run(
            ["git", *arguments], cwd=_REPO_ROOT, capture_output=True, text=True, check=True
        ).stdout

    try:
        commit = git("rev-parse", "--short", "HEAD").strip()
        # Not stripped: a porcelain line's status field may start with a space (" M").
        changed = git("status", "--porcelain", "--untracked-files=no", "--", *_SOURCE_DIRS)
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    paths = [line[3:] for line in changed.splitlines() if line.endswith(".py")]
    return f"{commit} (uncommitted: {', '.join(paths)})" if paths else commit


def record_run(
    module: str,
    args: argparse.Namespace,
    name: str,
    measure: Callable[[], dict[str, Any]],
    write_report: Callable[[Path, dict[str, Any]], None],
    **extra: Any,
) -> dict[str, Any]:
    """Run ``measure()`` and record it: when, on which code, the command (``python -m
    module`` and this process's arguments), `extra` items, the load average before and
    after, and what it returned; written as ``<out_dir>/<name>.md`` (by `write_report`)
    and ``.json``. Returns the record."""
    record: dict[str, Any] = {
        "measured_at": now(),
        "source": source_revision(),
        "command": f"python -m {module} " + " ".join(sys.argv[1:]),
        **extra,
        "load_average": {"start": load_average()},
    }
    record.update(measure())
    record["load_average"]["end"] = load_average()
    args.out_dir.mkdir(parents=True, exist_ok=True)
    write_report(args.out_dir / f"{name}.md", record)
    write_json(args.out_dir / f"{name}.json", record)
    progress(f"wrote {args.out_dir / f'{name}.md'}")
    return record


def bench_parser(prog: str, description: str | None) -> argparse.ArgumentParser:
    """An argument parser with the options every benchmark takes: --mesh-dir,
    --timeout (seconds per child process) and --out-dir."""
    parser = argparse.ArgumentParser(
        prog=prog, description=description, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--mesh-dir", type=Path, default=DEFAULT_MESH_DIR)
    parser.add_argument("--timeout", type=float, default=None, help="seconds per child process")
    parser.add_argument("--out-dir", type=Path, default=RESULTS_DIR)
    return parser


def merge_results(path: Path, entries: dict[str, dict[str, Any]]) -> None:
    """Merge mesh name -> entry into the JSON file at `path` ({"machine", "meshes"}),
    keeping the other meshes' entries."""
    meshes = read_json(path).get("meshes", {})
    meshes.update(entries)
    write_json(path, {"machine": describe_machine(), "meshes": meshes})

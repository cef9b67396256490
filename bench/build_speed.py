"""Time and memory of the whole qem-lod forest build, beside single peer simplifications.

    python -m bench.build_speed [--mesh dragon.ply] [--runs 3] [--fraction 0.02]
        [--qem-option name=value ...] [--timeout SECONDS] [--stages]

Every run is a fresh child process (`bench.measure.measure_in_child`); the clock covers
the build call (or the peer's simplify call) alone. qem-lod is measured five ways:

- **cold**: once, with NUMBA_CACHE_DIR pointing at an empty temporary folder, so the
  build compiles every kernel: compile + run.
- **warm cache**: --runs runs with that folder now filled: loading the cached machine
  code + run. What a fresh worker process pays for its first build.
- **hot**: --runs runs, each after `qem_core.warm_up()` and an untimed build of a tiny
  mesh in the same process (`bench.qem_lod.warm_up_build`), so every kernel is loaded:
  the run alone, the figure to set against the peers, whose code is compiled ahead of
  time and loaded by an untimed warm-up call too. (Until 2026-12-03 the tiny build alone
  came first, which does not reach the parallel rounds' kernels: hot builds loaded those
  from the cache in their timed call, 60-90 ms on dragon.)
- **hot without rounds**: the same with `parallel_rounds=false`, one strictly greedy
  sequence: what the parallel rounds (qem_core/rounds.py) gain, in the same run.
- **hot, plain quadric cost**: the same with `distance_weight=0` and `volume_weight=0`,
  the contraction cost of Garland and Heckbert alone: what the build's machinery costs
  without the two terms priced on top of it (their quality is in the quality bench).
- **second build**: --runs runs, each after an untimed build of the same mesh in the
  same process: what a long-lived worker (the server's job pool) pays for its next
  builds. A process's first big build also faults in its memory from the kernel, which
  the next ones, reusing the freed memory, mostly do not.

Every series also reports the median CPU time of its runs (user + system, all threads;
`bench.measure`): over the wall time it is the cores the call kept busy, and over the
machine's cores it is the least wall time the same work could take on this machine,
however well it were spread; the report sets that bound for the hot build against the
peers.

Numba compile time is reported as cold - median(warm cache). The peers are
meshoptimizer and PyMeshLab (default options), each simplifying the same mesh once to
--fraction of its referenced vertices, --runs runs. Runs are interleaved (qem warm, qem
hot, qem hot without rounds, qem second build, meshoptimizer, pymeshlab, then again) so
slow drifts of the machine hit all alike.

With --stages, --runs more hot builds (fresh children) time the stages of the build:
each stage function of `qem_core.simplify` (STAGES) is wrapped, in the child, by a clock
that adds up its calls; what build() spends outside them is "other".

Writes bench/results/build-speed.md and merges the mesh's entry into
bench/results/build-speed.json.
"""

from __future__ import annotations

import argparse
import importlib
import sys
import tempfile
from collections.abc import Sequence
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from . import qem_lod
from .machine import describe_machine, machine_header_lines
from .measure import ChildCallError, ChildMeasurement, measure_in_child, median_of_runs
from .meshes import DEFAULT_MESH_DIR, BenchMesh, count_referenced, load_bench_mesh, target_counts
from .peers import PEERS, warm_up_peer
from .report import (
    RESULTS_DIR,
    format_mib,
    format_ms,
    format_ratio,
    markdown_table,
    read_json,
    write_json,
)

__all__ = ["main", "measure_build_speed"]

PEER_NAMES = ("meshoptimizer", "pymeshlab")
DEFAULT_FRACTION = 0.02

# The stages --stages times: (label, module, function); the functions are looked up as
# module globals when build() runs, so wrapping them there times every call.
STAGES = (
    ("prepare: validate, weld, duplicate faces, edges, components", "qem_core.simplify",
     "prepare_mesh_and_edges"),
    ("z-order of a mesh built in rounds (rounds.spatial_order)", "qem_core.simplify",
     "spatial_order"),
    ("quadrics of faces, borders and vertices", "qem_core.simplify", "_initial_complex"),
    ("vertex -> face lists", "qem_core.simplify", "make_face_lists"),
    ("parallel rounds: cuts, heaps, the parts' loops in threads, merges", "qem_core.simplify",
     "contract_in_rounds"),
    ("live part compacted for the last rounds and the serial loop (rounds.compacted)",
     "qem_core.simplify", "compacted"),
    ("costs and heap of the serial loop (parallel)", "qem_core.simplify", "fill_heap"),
    ("serial contraction loop", "qem_core.simplify", "run_contractions"),
    ("its work told back (rounds.write_back)", "qem_core.simplify", "write_back"),
    ("back to the input's numbering", "qem_core.simplify", "in_input_order"),
    ("assemble the progressive mesh", "qem_core.simplify", "_assemble"),
)


def time_stages(vertices, faces, option_values: qem_lod.OptionValues) -> dict[str, Any]:
    """One build with each of STAGES clocked: {"total_s", "stages_s": {label: s}}.
    Runs in the measuring child (see the module docstring)."""
    import importlib
    import time

    spent = {label: 0.0 for label, _, _ in STAGES}
    wrapped = []

    def clocked(function, label):
        def call(*args, **kwargs):
            start = time.perf_counter()
            try:
                return function(*args, **kwargs)
            finally:
                spent[label] += time.perf_counter() - start

        return call

    for label, module_name, name in STAGES:
        module = importlib.import_module(module_name)
        wrapped.append((module, name, getattr(module, name)))
        setattr(module, name, clocked(getattr(module, name), label))
    try:
        start = time.perf_counter()
        qem_lod.build_progressive_mesh(vertices, faces, option_values)
        total = time.perf_counter() - start
    finally:
        for module, name, function in wrapped:
            setattr(module, name, function)
    return {"total_s": total, "stages_s": spent}


def measure_stages(mesh: BenchMesh, option_values: qem_lod.OptionValues, runs: int,
                   timeout_s: float | None) -> dict[str, Any]:
    """Median seconds of each stage (and of the whole build) over `runs` hot builds."""
    # Imported by name: run as ``python -m``, this module is __main__, whose functions the
    # child cannot import.
    stage_timer = importlib.import_module("bench.build_speed").time_stages
    totals, per_stage = [], {label: [] for label, _, _ in STAGES}
    for _ in range(runs):
        measured = measure_in_child(
            stage_timer,
            (mesh.vertices, mesh.faces, option_values),
            preload=("qem_core",),
            before=qem_lod.warm_up_build,
            before_args=(option_values,),
            timeout_s=timeout_s,
        )
        totals.append(measured.result["total_s"])
        for label, seconds in measured.result["stages_s"].items():
            per_stage[label].append(seconds)
    stages = {label: median_of_runs(times) for label, times in per_stage.items()}
    total = median_of_runs(totals)
    stages["other (record and heap arrays, Python)"] = max(0.0, total - sum(stages.values()))
    return {"runs": runs, "total_s": total, "stages_s": stages}


class _Series:
    """Runs of one kind, each a fresh child: times (s), peak and increase of RSS (bytes)."""

    def __init__(self, name: str) -> None:
        self.name = name
        self.times_s: list[float] = []
        self.cpu_times_s: list[float] = []
        self.peak_rss_bytes = 0
        self.rss_increase_bytes = 0
        self.status = "ok"
        self.detail: dict[str, Any] = {}

    def add(self, measured: ChildMeasurement) -> None:
        self.times_s.extend(measured.times_s)
        self.cpu_times_s.extend(measured.cpu_times_s)
        self.peak_rss_bytes = max(self.peak_rss_bytes, measured.peak_rss_bytes)
        self.rss_increase_bytes = max(self.rss_increase_bytes, measured.rss_increase_bytes)

    def fail(self, error: Exception) -> None:
        lines = [line for line in str(error).splitlines() if line.strip()]
        self.status = "failed: " + (lines[-1].strip() if lines else type(error).__name__)

    @property
    def ok(self) -> bool:
        return self.status == "ok" and bool(self.times_s)

    @property
    def median_s(self) -> float | None:
        return median_of_runs(self.times_s) if self.ok else None

    @property
    def cpu_median_s(self) -> float | None:
        return median_of_runs(self.cpu_times_s) if self.ok and self.cpu_times_s else None

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "status": self.status,
            "times_s": self.times_s,
            "median_s": self.median_s,
            "cpu_times_s": self.cpu_times_s,
            "cpu_median_s": self.cpu_median_s,
            "peak_rss_bytes": self.peak_rss_bytes or None,
            "rss_increase_bytes": self.rss_increase_bytes if self.ok else None,
            **self.detail,
        }


def _measure_into(series: _Series, function, args, **measure_options) -> None:
    if series.status != "ok":
        return  # a failed series is not retried
    try:
        measured = measure_in_child(function, args, **measure_options)
    except ChildCallError as error:
        series.fail(error)
        return
    series.add(measured)
    if isinstance(measured.result, dict):
        series.detail.update(measured.result)
    elif isinstance(measured.result, tuple):
        vertices, faces = measured.result
        series.detail.update(out_vertices=count_referenced(faces), out_faces=int(len(faces)))


def measure_build_speed(
    mesh: BenchMesh,
    option_values: qem_lod.OptionValues,
    runs: int,
    fraction: float,
    timeout_s: float | None,
    qem_note: str | None,
) -> dict[str, Any]:
    """All series for one mesh; returns the JSON entry (see the module docstring)."""
    build_args = (mesh.vertices, mesh.faces, option_values)
    _, target_faces = target_counts(mesh, fraction)
    label = qem_lod.variant_label(option_values)
    cold = _Series(f"{label} cold (compile + run)")
    warm = _Series(f"{label} warm cache (cache load + run)")
    hot = _Series(f"{label} hot (run alone)")
    # The same build in one strictly greedy sequence, for the gain of parallel rounds.
    serial_values = {**option_values, "parallel_rounds": False}
    serial_hot = _Series(f"{qem_lod.variant_label(serial_values)} hot (run alone)")
    if option_values.get("parallel_rounds") is False:
        serial_hot.status = "skipped: the options already turn parallel rounds off"
    # The same build priced by the plain quadric cost, for what the machinery costs alone.
    plain_values = {**option_values, "distance_weight": 0.0, "volume_weight": 0.0}
    plain_hot = _Series(f"{qem_lod.variant_label(plain_values)} hot (run alone)")
    if plain_values == option_values:
        plain_hot.status = "skipped: the options already price the plain quadric cost"
    second = _Series(f"{label} second build (after one untimed build of the same mesh)")
    peers = {name: _Series(f"{name} to {fraction:g}") for name in PEER_NAMES}
    qem_series = (cold, warm, hot, serial_hot, plain_hot, second)
    if qem_note is not None:
        for series in qem_series:
            series.status = f"skipped: {qem_note}"
    with tempfile.TemporaryDirectory(prefix="qem-bench-numba-") as cache_dir:
        qem_options = {
            "preload": ("qem_core",),
            "then": qem_lod.describe_progressive_mesh,
            "env": {"NUMBA_CACHE_DIR": cache_dir},
            "timeout_s": timeout_s,
        }
        _measure_into(cold, qem_lod.build_progressive_mesh, build_args, **qem_options)
        _progress(f"{mesh.name} {cold.name}: {format_ms(cold.median_s)} ms")
        for run in range(runs):
            _measure_into(warm, qem_lod.build_progressive_mesh, build_args, **qem_options)
            for series, values in ((hot, option_values), (serial_hot, serial_values),
                                   (plain_hot, plain_values)):
                _measure_into(
                    series,
                    qem_lod.build_progressive_mesh,
                    (mesh.vertices, mesh.faces, values),
                    before=qem_lod.warm_up_build,
                    before_args=(values,),
                    **qem_options,
                )
            _measure_into(
                second,
                qem_lod.build_progressive_mesh,
                build_args,
                before=qem_lod.build_progressive_mesh,
                before_args=build_args,
                **qem_options,
            )
            for name, series in peers.items():
                peer = PEERS[name]
                _measure_into(
                    series,
                    peer.simplify,
                    (mesh.vertices, mesh.faces, target_faces),
                    preload=peer.modules,
                    before=warm_up_peer,
                    before_args=(peer.simplify,),
                    timeout_s=timeout_s,
                )
            _progress(
                f"{mesh.name} run {run + 1}/{runs}: "
                + ", ".join(
                    f"{s.name} {format_ms(s.times_s[-1] if s.ok else None)} ms"
                    for s in (*qem_series[1:], *peers.values())
                )
            )
    compile_s = None
    if cold.ok and warm.ok:
        compile_s = cold.median_s - warm.median_s
    ratios = {}
    for qem_series_name, series in (("warm_cache", warm), ("hot", hot),
                                    ("hot_without_rounds", serial_hot),
                                    ("hot_plain_quadric_cost", plain_hot),
                                    ("second_build", second)):
        for name, peer_series in peers.items():
            if series.ok and peer_series.ok:
                ratios[f"{qem_series_name}/{name}"] = series.median_s / peer_series.median_s
    machine = describe_machine()
    return {
        "mesh": mesh.name,
        "measured_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "machine": machine,
        "input": {
            "stored_vertices": mesh.n_stored,
            "referenced_vertices": mesh.n_referenced,
            "faces": mesh.n_faces,
        },
        "settings": {
            "runs": runs,
            "peer_fraction": fraction,
            "peer_target_faces": target_faces,
            "qem_options": option_values,
        },
        "qem_note": qem_note,
        "series": [s.to_dict() for s in (*qem_series, *peers.values())],
        "numba_compile_s": compile_s,
        "ratios": ratios,
        "cpu_bound": _cpu_bound(hot, peers, machine["cores"]),
    }


def _cpu_bound(hot: _Series, peers: dict[str, _Series], cores: int | None) -> dict | None:
    """The least wall time the hot build's CPU time allows on ``cores`` cores, and its
    ratio to each peer's median wall time (None where a figure is missing)."""
    if not cores or hot.cpu_median_s is None:
        return None
    least_s = hot.cpu_median_s / cores
    return {
        "cores": cores,
        "hot_cpu_s": hot.cpu_median_s,
        "least_wall_s": least_s,
        "ratios": {name: least_s / series.median_s
                   for name, series in peers.items() if series.ok},
    }


def write_build_speed_report(path: Path, entry: dict[str, Any]) -> None:
    """Write the Markdown report of one mesh's build-speed entry."""
    settings, mesh_info = entry["settings"], entry["input"]
    rows = []
    for series in entry["series"]:
        counts = "-"
        if "n_full" in series:
            counts = f"{series['n_full']} -> {series['n_base']} (whole forest)"
        elif "out_vertices" in series:
            counts = f"{series['out_vertices']} V / {series['out_faces']} F"
        rows.append(
            [
                series["name"],
                str(len(series["times_s"])),
                format_ms(series["median_s"]),
                format_ms(series.get("cpu_median_s")),
                _cores_busy(series),
                ", ".join(format_ms(t) for t in series["times_s"]) or "-",
                format_mib(series["peak_rss_bytes"], series["rss_increase_bytes"]),
                counts,
                series["status"],
            ]
        )
    table = markdown_table(
        [
            "series",
            "runs",
            "median ms",
            "median CPU ms",
            "cores busy",
            "each run ms",
            "peak RSS MiB (+call)",
            "vertices",
            "status",
        ],
        rows,
        [False, True, True, True, True, True, True, False, False],
    )
    ratio_lines = [
        f"- qem-lod {key.split('/')[0].replace('_', ' ')} / {key.split('/')[1]}: "
        f"{format_ratio(value)}"
        for key, value in entry["ratios"].items()
    ] or ["- no ratio: a series is missing (see status)"]
    compile_line = (
        f"Numba compile time (cold - median warm cache): {format_ms(entry['numba_compile_s'])} ms."
        if entry["numba_compile_s"] is not None
        else "Numba compile time: not measured (a qem-lod series is missing)."
    )
    lines = [
        f"# Build speed on `{entry['mesh']}`: the whole qem-lod forest against one peer "
        "simplification",
        "",
        f"Input: {mesh_info['referenced_vertices']} referenced vertices "
        f"({mesh_info['stored_vertices']} stored), {mesh_info['faces']} faces. "
        f"Measured {entry['measured_at']}.",
        *machine_header_lines(),
        "",
        "Every run is a fresh child process; times are of the call alone. qem-lod builds "
        "the whole forest (every contraction down to the base mesh) with options "
        f"`{settings['qem_options'] or 'defaults'}`: cold = empty NUMBA_CACHE_DIR (compile "
        "+ run), warm cache = the same cache dir afterwards (cache load + run), hot = after "
        "`qem_core.warm_up()` (every kernel loaded) and an untimed build of a 22-vertex "
        "mesh in the same process (run alone); "
        "`parallel_rounds=False` is the same build as one strictly greedy sequence, "
        "`distance_weight=0.0,volume_weight=0.0` the same build priced by the plain quadric "
        "cost; cores busy = median CPU time (user + system, all threads) / median wall time; "
        "second "
        "build = after an untimed build of the same mesh in the same process. The peers "
        f"simplify once to {settings['peer_fraction']:g} of the referenced vertices "
        f"({settings['peer_target_faces']} faces), default options, after an untimed call "
        "on the same tiny mesh. Peak RSS: the child's peak during the call (MiB, includes "
        "the input and libraries), its increase over the RSS before the call; the largest "
        "over the runs.",
        "",
    ]
    if entry.get("qem_note"):
        lines += [f"qem-lod: {entry['qem_note']}", ""]
    lines += [*table, "", compile_line, "", "Ratios of medians (above 1: qem-lod is slower):", ""]
    lines += [*ratio_lines, ""]
    bound = entry.get("cpu_bound")
    if bound:
        peer_ratios = ", ".join(f"{format_ratio(value)}x {name}'s median"
                                for name, value in bound["ratios"].items())
        lines += [
            f"CPU bound: the hot build's median CPU time, {format_ms(bound['hot_cpu_s'])} ms, "
            f"spread perfectly over this machine's {bound['cores']} cores would still take "
            f"{format_ms(bound['least_wall_s'])} ms of wall time: {peer_ratios}.",
            "",
        ]
    stages = entry.get("stages")
    if stages:
        total = stages["total_s"]
        lines += [
            f"Stages of a hot build (`--stages`: median of {stages['runs']} fresh children, "
            f"whole build {format_ms(total)} ms; each stage's own median, so they need not "
            "add up exactly):",
            "",
            *markdown_table(
                ["stage", "median ms", "share"],
                [[label, format_ms(seconds), f"{100 * seconds / total:.1f} %"]
                 for label, seconds in stages["stages_s"].items()],
                [False, True, True],
            ),
            "",
        ]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines), encoding="utf-8")


def _cores_busy(series: dict[str, Any]) -> str:
    """Median CPU time over median wall time, as "1.87"; "-" where either is missing."""
    cpu, wall = series.get("cpu_median_s"), series.get("median_s")
    return f"{cpu / wall:.2f}" if cpu is not None and wall else "-"


def _progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bench.build_speed",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("--mesh", default="dragon.ply", help="file name in --mesh-dir")
    parser.add_argument("--mesh-dir", type=Path, default=DEFAULT_MESH_DIR)
    parser.add_argument("--runs", type=int, default=3, help="runs per warm series (median)")
    parser.add_argument(
        "--fraction",
        type=float,
        default=DEFAULT_FRACTION,
        help="peers simplify to this fraction of the referenced vertices",
    )
    qem_lod.add_option_argument(parser, "a qem_core.BuildOptions field for the build; repeatable")
    parser.add_argument("--timeout", type=float, default=None, help="seconds per child process")
    parser.add_argument(
        "--stages",
        action="store_true",
        help="also time the stages of --runs more hot builds (see the module docstring)",
    )
    parser.add_argument("--out-dir", type=Path, default=RESULTS_DIR)
    args = parser.parse_args(argv)
    if args.runs < 1:
        parser.error("--runs must be at least 1")
    option_values = qem_lod.option_values_of(parser, args)
    qem_note = qem_lod.qem_unavailable_reason()
    if qem_note is not None:
        _progress(f"qem-lod: {qem_note}")
    mesh = load_bench_mesh(args.mesh_dir / args.mesh)
    entry = measure_build_speed(
        mesh, option_values, args.runs, args.fraction, args.timeout, qem_note
    )
    if args.stages and qem_note is None:
        entry["stages"] = measure_stages(mesh, option_values, args.runs, args.timeout)
        _progress(f"{mesh.name} stages: " + ", ".join(
            f"{label.split(':')[0]} {format_ms(seconds)} ms"
            for label, seconds in entry["stages"]["stages_s"].items()))
    report_path = args.out_dir / "build-speed.md"
    write_build_speed_report(report_path, entry)
    json_path = args.out_dir / "build-speed.json"
    results = read_json(json_path)
    results.setdefault("meshes", {})[mesh.name] = entry
    write_json(json_path, {"machine": describe_machine(), "meshes": results["meshes"]})
    _progress(f"wrote {report_path} and {json_path}")
    return 0 if qem_note is None else 1


if __name__ == "__main__":
    sys.exit(main())

"""The service's figures (issue 5): upload to ready, uncached and cached GET lod.

    python -m bench.service [--mesh dragon.ply] [--runs 3] [--lod-vertices 100000]
        [--lod-requests 11] [--formats ply msgpack] [--cached-levels 100000 1000]
        [--duration 10] [--threads 2] [--connections 16] [--no-wrk]

Starts the real server, `python -m client.cli serve --host 127.0.0.1 --port 0
--data-dir TMP --workers 1` (`tests.e2e.conftest.ServerProcess`: the port is read from
uvicorn's "Uvicorn running on" line), and talks to it with `client.http.QemClient`:

- **upload -> ready**: first one upload of --warm-up-mesh (spot.ply), so the build worker
  has imported qem_core and loaded its numba kernels (its time is reported apart); then
  --runs uploads of the mesh, each timed from the start of the upload until `wait_ready`
  (polling every 0.1 s) sees `ready`, each followed by `qem_core.build` of the same mesh
  in a fresh child process after an untimed tiny build (`bench.measure.measure_in_child`,
  as bench.build_speed's "hot" series). Ratio of medians upload->ready / build, and the
  median of the per-run ratios; target <= 1.2.
- **uncached GET lod**: one GET at --lod-vertices / 2 first (it loads the .qpm into the
  server: shown as "first GET"), then --lod-requests GETs per format at distinct vertex
  counts from --lod-vertices up, so every one misses the server's level cache; client
  side wall time of each whole request (extraction, encoding, transfer), median.
- **cached GET lod**: each --cached-levels level fetched once (now cached), then a bounded
  load run of --duration seconds on it: `wrk -t THREADS -c CONNECTIONS -d DURATION`
  when wrk is installed, else a Python loop of httpx clients in CONNECTIONS threads;
  the report says which. Requests per second and latency percentiles.

Server, build worker and load generator share the machine's cores (2 here), so the
requests-per-second figure is a floor for a machine where the client runs elsewhere.

Writes bench/results/service.md and merges the mesh's entry into
bench/results/service.json.
"""

from __future__ import annotations

import argparse
import re
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import httpx

from . import qem_lod
from .machine import describe_machine
from .meshes import load_bench_mesh
from .report import format_ms, format_ratio, markdown_table
from .runs import (
    bench_parser,
    load_average,
    measure_or_fail,
    merge_results,
    now,
    progress,
    run_header_lines,
    source_revision,
)

__all__ = ["main", "measure_service"]

TARGET_READY_FACTOR = 1.2
POLL_INTERVAL_S = 0.1
READY_TIMEOUT_S = 1800.0


# -- upload -> ready and the core build ------------------------------------------------


def _upload_to_ready(qem, mesh_path: Path) -> dict[str, Any]:
    start = time.perf_counter()
    mesh_id = qem.upload(mesh_path)
    accepted = time.perf_counter()
    info = qem.wait_ready(mesh_id, interval=POLL_INTERVAL_S, timeout=READY_TIMEOUT_S)
    ready = time.perf_counter()
    return {
        "id": mesh_id,
        "upload_s": accepted - start,
        "ready_s": ready - start,
        "vertices": info.get("vertices"),
        "min_vertices": info.get("min_vertices"),
    }


def _measure_builds(server, mesh, mesh_path: Path, warm_up_path: Path | None, args):
    """The warm-up upload, then --runs uploads of the mesh, each followed by a core build
    in a fresh child process."""
    uploads: list[dict[str, Any]] = []
    build_times: list[float] = []
    build_status = "ok"
    with server.client() as qem:
        warm_up = None
        if warm_up_path is not None:
            warm_up = {"mesh": warm_up_path.name, **_upload_to_ready(qem, warm_up_path)}
            progress(f"warm-up upload of {warm_up_path.name}: {warm_up['ready_s']:.2f} s")
        for run in range(args.runs):
            uploads.append(_upload_to_ready(qem, mesh_path))
            build = measure_or_fail(
                qem_lod.build_progressive_mesh,
                (mesh.vertices, mesh.faces, {}),
                preload=("qem_core",),
                before=qem_lod.warm_up_build,
                before_args=({},),
                then=qem_lod.describe_progressive_mesh,
                timeout_s=args.timeout,
            )
            if build.ok:
                build_times.extend(build.times_s)
                uploads[-1]["paired_build_s"] = build.times_s[0]
            else:
                build_status = build.status
            progress(
                f"run {run + 1}/{args.runs}: upload -> ready {uploads[-1]['ready_s']:.2f} s, "
                f"qem_core.build {format_ms(build.median_s)} ms ({build.status})"
            )
    ready_median = statistics.median(upload["ready_s"] for upload in uploads)
    build_median = statistics.median(build_times) if build_times else None
    paired = [u["ready_s"] / u["paired_build_s"] for u in uploads if "paired_build_s" in u]
    return {
        "warm_up_upload": warm_up,
        "uploads": uploads,
        "ready_median_s": ready_median,
        "build": {"status": build_status, "times_s": build_times, "median_s": build_median},
        "ratio_ready_over_build": None if build_median is None else ready_median / build_median,
        "paired_ratios": paired,
        "median_paired_ratio": statistics.median(paired) if paired else None,
    }


# -- GET lod ---------------------------------------------------------------------------


def _timed_lod(qem, mesh_id: str, n: int, fmt: str) -> dict[str, Any]:
    start = time.perf_counter()
    lod = qem.fetch_lod(mesh_id, n, fmt)
    seconds = time.perf_counter() - start
    return {
        "n": n,
        "format": fmt,
        "seconds": seconds,
        "bytes": len(lod.content),
        "served_vertices": lod.n_vertices,
    }


def _measure_uncached(server, mesh_id: str, n_lod: int, requests: int, formats: Sequence[str]):
    with server.client() as qem:
        first = _timed_lod(qem, mesh_id, max(1, n_lod // 2), formats[0])
        per_format = {}
        for index, fmt in enumerate(formats):
            # Distinct counts per format too, so no request finds its level cached.
            offset = index * (requests + 1)
            timed = [_timed_lod(qem, mesh_id, n_lod + offset + i, fmt) for i in range(requests)]
            times = [t["seconds"] for t in timed]
            per_format[fmt] = {
                "vertex_counts": [t["n"] for t in timed],
                "served_exact": all(t["served_vertices"] == t["n"] for t in timed),
                "times_s": times,
                "median_s": statistics.median(times),
                "min_s": min(times),
                "max_s": max(times),
                "bytes": statistics.median(t["bytes"] for t in timed),
            }
            progress(
                f"uncached GET lod ~{n_lod} {fmt}: median {format_ms(statistics.median(times))} ms"
            )
    return {"n": n_lod, "first_get": first, "formats": per_format}


_WRK_NUMBER = r"([\d.]+)\s*([a-zA-Z%]*)"
_UNIT_SECONDS = {"us": 1e-6, "ms": 1e-3, "s": 1.0, "m": 60.0}


def _wrk_seconds(text: str) -> float | None:
    match = re.fullmatch(_WRK_NUMBER, text.strip())
    if not match or match.group(2) not in _UNIT_SECONDS:
        return None
    return float(match.group(1)) * _UNIT_SECONDS[match.group(2)]


def parse_wrk_output(output: str) -> dict[str, Any]:
    """Requests/s, transfer/s, request count, errors and latency percentiles from the
    text wrk prints with --latency."""
    result: dict[str, Any] = {"latency_s": {}}
    if match := re.search(r"Requests/sec:\s*([\d.]+)", output):
        result["requests_per_s"] = float(match.group(1))
    if match := re.search(r"Transfer/sec:\s*(\S+)", output):
        result["transfer_per_s"] = match.group(1)
    if match := re.search(r"(\d+) requests in ([\d.]+\w+)", output):
        result["requests"] = int(match.group(1))
        result["elapsed_s"] = _wrk_seconds(match.group(2))
    if match := re.search(r"Non-2xx or 3xx responses:\s*(\d+)", output):
        result["non_2xx"] = int(match.group(1))
    if match := re.search(r"Socket errors:(.*)", output):
        result["socket_errors"] = match.group(1).strip()
    for percentile, value in re.findall(r"^\s*(50|75|90|99)%\s+(\S+)", output, re.MULTILINE):
        result["latency_s"][percentile] = _wrk_seconds(value)
    return result


def _run_wrk(url: str, threads: int, connections: int, duration_s: int) -> dict[str, Any]:
    command = [
        "wrk",
        f"-t{threads}",
        f"-c{connections}",
        f"-d{duration_s}s",
        "--latency",
        url,
    ]
    completed = subprocess.run(
        command, capture_output=True, text=True, timeout=duration_s + 60, check=False
    )
    result = parse_wrk_output(completed.stdout)
    result["tool"] = shlex.join(command)
    result["status"] = "ok" if completed.returncode == 0 else f"wrk exit {completed.returncode}"
    return result


def _run_httpx_loop(url: str, connections: int, duration_s: int) -> dict[str, Any]:
    """The fallback load run: `connections` threads, one httpx client each, GET in a loop.
    The clients are made before the clock starts; the threads start together."""
    clients = [httpx.Client(timeout=60.0) for _ in range(connections)]
    latencies: list[float] = []
    non_2xx = [0]
    lock = threading.Lock()
    start_together = threading.Barrier(connections + 1)
    deadline = [0.0]

    def worker(http: httpx.Client) -> None:
        mine, bad = [], 0
        start_together.wait()
        while time.perf_counter() < deadline[0]:
            start = time.perf_counter()
            response = http.get(url)
            mine.append(time.perf_counter() - start)
            bad += not response.is_success
        with lock:
            latencies.extend(mine)
            non_2xx[0] += bad

    workers = [threading.Thread(target=worker, args=(http,)) for http in clients]
    for thread in workers:
        thread.start()
    started = time.perf_counter()
    deadline[0] = started + duration_s
    start_together.wait()
    for thread in workers:
        thread.join()
    elapsed = time.perf_counter() - started
    for http in clients:
        http.close()
    ordered = sorted(latencies)

    def percentile(p: int) -> float | None:
        return ordered[min(len(ordered) - 1, len(ordered) * p // 100)] if ordered else None

    return {
        "tool": f"Python loop: {connections} threads, one httpx.Client each, {duration_s} s",
        "status": "ok" if latencies else "failed: no request finished",
        "requests": len(latencies),
        "elapsed_s": elapsed,
        "requests_per_s": len(latencies) / elapsed,
        "non_2xx": non_2xx[0],
        "latency_s": {str(p): percentile(p) for p in (50, 75, 90, 99)},
    }


def _measure_cached(server, mesh_id: str, levels, fmt: str, args) -> list[dict[str, Any]]:
    runs = []
    with server.client() as qem:
        for n in levels:
            lod = qem.fetch_lod(mesh_id, n, fmt)  # now it is cached
            url = f"{server.url}/v1/meshes/{mesh_id}/lod?vertices={n}&format={fmt}"
            if args.use_wrk:
                measured = _run_wrk(url, args.threads, args.connections, args.duration)
            else:
                measured = _run_httpx_loop(url, args.connections, args.duration)
            runs.append({"n": n, "format": fmt, "bytes": len(lod.content), **measured})
            progress(
                f"cached GET lod {n} {fmt}: {measured.get('requests_per_s', 0):.0f} requests/s"
            )
    return runs


# -- the whole run ---------------------------------------------------------------------


def measure_service(args: argparse.Namespace) -> dict[str, Any]:
    """Start the server, measure, stop it; returns the JSON entry."""
    from tests.e2e.conftest import ServerProcess  # the e2e tests' way to run `qem serve`

    mesh_path = args.mesh_dir / args.mesh
    mesh = load_bench_mesh(mesh_path)
    start_load = load_average()
    entry: dict[str, Any] = {
        "mesh": mesh.name,
        "measured_at": now(),
        "source": source_revision(),
        "machine": describe_machine(),
        "input": {
            "file_bytes": mesh_path.stat().st_size,
            "faces": mesh.n_faces,
            "referenced_vertices": mesh.n_referenced,
        },
        "load_generator": "wrk" if args.use_wrk else "python httpx loop",
    }
    with tempfile.TemporaryDirectory(prefix="qem-bench-service-") as work_dir:
        server = ServerProcess(Path(work_dir) / "data").start()
        try:
            warm_up_path = args.mesh_dir / args.warm_up_mesh if args.warm_up_mesh else None
            entry["ready"] = _measure_builds(server, mesh, mesh_path, warm_up_path, args)
            mesh_id = entry["ready"]["uploads"][-1]["id"]
            entry["uncached"] = _measure_uncached(
                server, mesh_id, args.lod_vertices, args.lod_requests, args.formats
            )
            entry["cached"] = _measure_cached(
                server, mesh_id, args.cached_levels, args.formats[0], args
            )
        finally:
            entry["server_exit"] = server.stop()
            errors = [line for line in server.log_lines if "Traceback" in line or "ERROR" in line]
            entry["server_errors"] = errors[:20]
    entry["load_average"] = {"start": start_load, "end": load_average()}
    ratio = entry["ready"]["ratio_ready_over_build"]
    entry["targets"] = {
        "ready_factor_target": TARGET_READY_FACTOR,
        "ready_factor_met": ratio is not None and ratio <= TARGET_READY_FACTOR,
    }
    return entry


def write_service_report(path: Path, entry: dict[str, Any]) -> None:
    ready, uncached = entry["ready"], entry["uncached"]
    uploads, build = ready["uploads"], ready["build"]
    lines = [
        f"# Service on `{entry['mesh']}`: upload to ready, uncached and cached GET lod",
        "",
        f"Input: {entry['input']['file_bytes']:,} bytes, {entry['input']['referenced_vertices']} "
        f"referenced vertices, {entry['input']['faces']} faces.",
        *run_header_lines(entry),
        "",
        "Server: `python -m client.cli serve --host 127.0.0.1 --port 0 --data-dir TMP "
        "--workers 1 --log-level info`.",
        "",
        "**The server (uvicorn, its access log on at `--log-level info`), its one build "
        "worker process and the load generator all share these 2 cores**, so requests per "
        "second here are a floor for a deployment where clients run elsewhere.",
        "",
        "## Upload to ready against the core's build",
        "",
    ]
    rows = [
        [
            str(run + 1),
            f"{upload['upload_s']:.2f}",
            f"{upload['ready_s']:.2f}",
            f"{upload['paired_build_s']:.2f}" if "paired_build_s" in upload else "-",
            format_ratio(upload["ready_s"] / upload["paired_build_s"])
            if "paired_build_s" in upload
            else "-",
        ]
        for run, upload in enumerate(uploads)
    ]
    lines += markdown_table(
        ["run", "upload answered (202) s", "upload -> ready s", "qem_core.build s", "ratio"],
        rows,
        [True, True, True, True, True],
    )
    target = entry["targets"]
    verdict = "**met**" if target["ready_factor_met"] else "**not met**"
    warm_up = ready["warm_up_upload"]
    lines += [
        "",
        f"Median upload -> ready {ready['ready_median_s']:.2f} s; median `qem_core.build` "
        f"{format_ms(build['median_s'])} ms ({build['status']}; fresh child process each, "
        "after an untimed tiny build, input already in memory). Ratio of medians "
        f"upload->ready / build: **{format_ratio(ready['ratio_ready_over_build'])}** "
        f"(target <= {target['ready_factor_target']:g}: {verdict}); median of the per-run "
        f"ratios (each upload over the build right after it): "
        f"{format_ratio(ready['median_paired_ratio'])}.",
        "",
    ]
    if warm_up is not None:
        lines += [
            f"Before the timed runs, `{warm_up['mesh']}` was uploaded once so that the fresh "
            "build worker had imported qem_core and loaded (or compiled) its numba kernels: "
            f"upload -> ready {warm_up['ready_s']:.2f} s. A first upload into a fresh "
            "worker pays that on top.",
            "",
        ]
    lines += [
        "Upload -> ready covers the HTTP upload, parsing and validating the file in the "
        f"worker, the build, writing the .qpm, and up to {POLL_INTERVAL_S:g} s of polling.",
        "",
        f"## Uncached GET lod near {uncached['n']} vertices",
        "",
    ]
    first = uncached["first_get"]
    rows = [
        [
            fmt,
            f"{figures['vertex_counts'][0]}..{figures['vertex_counts'][-1]}",
            str(len(figures["times_s"])),
            format_ms(figures["median_s"]),
            format_ms(figures["min_s"]),
            format_ms(figures["max_s"]),
            f"{figures['bytes']:,.0f}",
            "yes" if figures["served_exact"] else "NO",
        ]
        for fmt, figures in uncached["formats"].items()
    ]
    lines += markdown_table(
        [
            "format",
            "vertices",
            "requests",
            "median ms",
            "fastest ms",
            "slowest ms",
            "response bytes",
            "exact count",
        ],
        rows,
        [False, False, True, True, True, True, True, False],
    )
    lines += [
        "",
        "Each request asks for a vertex count not asked before, so the server extracts and "
        "encodes the level (its level cache misses); client-side wall time of the whole "
        f"request. Before them, the first GET (at {first['n']}, {first['format']}) also "
        f"loaded the .qpm into the server: {format_ms(first['seconds'])} ms.",
        "",
        f"## Cached GET lod: bounded load run ({entry['load_generator']})",
        "",
    ]
    rows = [
        [
            str(run["n"]),
            run["format"],
            f"{run['bytes']:,}",
            f"{run.get('requests_per_s', 0):.0f}",
            str(run.get("requests", "-")),
            *(format_ms(run["latency_s"].get(p)) for p in ("50", "99")),
            str(run.get("non_2xx", 0)),
            run["status"],
        ]
        for run in entry["cached"]
    ]
    lines += markdown_table(
        [
            "vertices",
            "format",
            "response bytes",
            "requests/s",
            "requests",
            "p50 ms",
            "p99 ms",
            "non-2xx",
            "status",
        ],
        rows,
        [True, False, True, True, True, True, True, True, False],
    )
    lines += ["", "Load runs: " + "; ".join(f"`{run['tool']}`" for run in entry["cached"]), ""]
    if entry["server_errors"]:
        lines += ["Server log lines with errors:", "", "```", *entry["server_errors"], "```", ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines), encoding="utf-8")


def main(argv: Sequence[str] | None = None) -> int:
    parser = bench_parser("python -m bench.service", __doc__)
    parser.add_argument("--mesh", default="dragon.ply", help="file name in --mesh-dir")
    parser.add_argument("--runs", type=int, default=3, help="uploads and core builds (median)")
    parser.add_argument(
        "--warm-up-mesh",
        default="spot.ply",
        help="file in --mesh-dir uploaded once, untimed for the ratio, before the runs "
        "(the worker loads its kernels); '' for none",
    )
    parser.add_argument("--lod-vertices", type=int, default=100_000)
    parser.add_argument("--lod-requests", type=int, default=11, help="uncached GETs per format")
    parser.add_argument(
        "--formats", nargs="+", default=["ply", "msgpack"], choices=["ply", "obj", "glb", "msgpack"]
    )
    parser.add_argument("--cached-levels", type=int, nargs="+", default=[100_000, 1_000])
    parser.add_argument("--duration", type=int, default=10, help="seconds per load run")
    parser.add_argument("--threads", type=int, default=2, help="wrk threads")
    parser.add_argument("--connections", type=int, default=16)
    parser.add_argument(
        "--no-wrk", action="store_true", help="use the Python loop even where wrk is installed"
    )
    arguments = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(arguments)
    if min(args.runs, args.lod_requests, args.duration, args.threads, args.connections) < 1:
        parser.error("--runs, --lod-requests, --duration, --threads, --connections must be >= 1")
    args.use_wrk = not args.no_wrk and shutil.which("wrk") is not None
    if not args.use_wrk and not args.no_wrk:
        progress("wrk is not installed: the load runs use the Python httpx loop")
    entry = measure_service(args)
    entry["command"] = shlex.join(["python", "-m", "bench.service", *arguments])
    report_path = args.out_dir / "service.md"
    write_service_report(report_path, entry)
    json_path = args.out_dir / "service.json"
    merge_results(json_path, {entry["mesh"]: entry})
    progress(f"wrote {report_path} and {json_path}")
    build_ok = entry["ready"]["build"]["status"] == "ok"
    return 0 if build_ok and not entry["server_errors"] else 1


if __name__ == "__main__":
    sys.exit(main())

"""Serving stored streams against a static file (issue 31), side by side in one run.

    python -m bench.stream_serving [--mesh dragon.ply] [--runs 3] [--duration 10]
        [--rounds 2] [--level 1000]

- **upload -> ready**: real servers (`tests.e2e.conftest.ServerProcess`, `qem serve
  --workers 1`), storing the split stream at build time (the default) or not
  (``QEM_STREAM_AT_BUILD=false``: the build as it was before streams were stored), one
  at a time: --runs times each, alternating, a new server each time that first gets an
  untimed upload of spot.ply (its worker loads its kernels), then the timed upload of
  the mesh. Ratio of the medians, stored / not stored; target <= 1.25.
- **whole stream**: ``wrk -t2 -c4`` on ``/splits`` (base to full) of the server that
  stored it, then on `bench.bare_app` serving the same bytes from memory (uvicorn, the
  same log level), --rounds times alternating; responses per second, ratio of the
  medians; target >= 0.5.
- **cached level**: the same with ``wrk -t2 -c16`` on ``lod?vertices=LEVEL&format=ply``
  (fetched once first, so the server has it cached) against the bare app serving those
  bytes; target >= 0.5.
- **the static alternative**: dragon's full level as Draco (DracoPy, 16-bit positions,
  level 7), its bytes beside the base + stream, served by the bare app under the same
  load as the stream (the cost of a static file: what the stream must match).

Server, the load generator and the yardstick share the machine's cores (2 here): the
figures are ratios measured minutes apart on the same machine.

Writes bench/results/stream-serving.md and .json.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from .machine import describe_machine
from .meshes import load_bench_mesh
from .report import format_ratio, markdown_table, write_json
from .runs import (
    bench_parser,
    load_average,
    now,
    progress,
    run_header_lines,
    source_revision,
)
from .service import POLL_INTERVAL_S, READY_TIMEOUT_S, _run_wrk

__all__ = ["main", "measure_stream_serving"]

TARGET_READY_FACTOR = 1.25
TARGET_SERVING_RATIO = 0.5


def _upload_to_ready(server, mesh_path: Path) -> tuple[float, str]:
    with server.client() as qem:
        start = time.perf_counter()
        mesh_id = qem.upload(mesh_path)
        qem.wait_ready(mesh_id, interval=POLL_INTERVAL_S, timeout=READY_TIMEOUT_S)
        return time.perf_counter() - start, mesh_id


def _bare_server(work_dir: Path, name: str, body: bytes, media_type: str):
    from tests.e2e.conftest import ServerProcess

    path = work_dir / name
    path.write_bytes(body)
    command = [sys.executable, "-m", "bench.bare_app", str(path), media_type, "--port", "0"]
    return ServerProcess(work_dir, command=command).start()


def _load_runs(urls: dict[str, str], connections: int, args) -> dict[str, Any]:
    """wrk on each url in turn, --rounds times; the runs and the median per url."""
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in urls}
    for round_ in range(args.rounds):
        for name, url in urls.items():
            measured = _run_wrk(url, 2, connections, args.duration)
            runs[name].append(measured)
            progress(
                f"round {round_ + 1}: {name} -c{connections}: "
                f"{measured.get('requests_per_s', 0):.1f} responses/s"
            )
    medians = {
        name: statistics.median(run.get("requests_per_s", 0.0) for run in measured)
        for name, measured in runs.items()
    }
    return {"connections": connections, "runs": runs, "median_per_s": medians}


def _draco_bytes(mesh) -> bytes | None:
    try:
        import DracoPy
    except ImportError:
        return None
    return DracoPy.encode(mesh.vertices, mesh.faces, quantization_bits=16, compression_level=7)


def measure_stream_serving(args: argparse.Namespace) -> dict[str, Any]:
    from tests.e2e.conftest import ServerProcess

    mesh_path = args.mesh_dir / args.mesh
    warm_up = args.mesh_dir / "spot.ply"
    entry: dict[str, Any] = {
        "mesh": args.mesh,
        "measured_at": now(),
        "source": source_revision(),
        "machine": describe_machine(),
        "command": "python -m bench.stream_serving " + " ".join(sys.argv[1:]),
    }
    start_load = load_average()
    with tempfile.TemporaryDirectory(prefix="qem-bench-streams-") as work:
        work_dir = Path(work)
        configs = {"not stored": {"QEM_STREAM_AT_BUILD": "false"}, "stored": {}}
        ready: dict[str, list[float]] = {name: [] for name in configs}
        stored = None
        bare = []
        try:
            # One server at a time (each new, with its kernels loaded by a spot upload),
            # alternating, so that neither build shares the cores with the other server.
            for run in range(args.runs):
                for name, env in configs.items():
                    server = ServerProcess(work_dir / f"{name}-{run}".replace(" ", "-"), env)
                    server.start()
                    try:
                        _upload_to_ready(server, warm_up)
                        seconds, mesh_id = _upload_to_ready(server, mesh_path)
                    finally:
                        if name != "stored" or run != args.runs - 1:
                            server.stop()
                    ready[name].append(seconds)
                    progress(f"run {run + 1}: upload -> ready ({name}) {seconds:.2f} s")
            stored = server  # the last, kept running for the load runs
            medians = {name: statistics.median(times) for name, times in ready.items()}
            entry["ready"] = {
                "times_s": ready,
                "median_s": medians,
                "ratio": medians["stored"] / medians["not stored"],
            }
            with stored.client() as qem:
                first = time.perf_counter()
                stream = b"".join(qem.splits(mesh_id))
                first_s = time.perf_counter() - first
                info = qem.info(mesh_id)
                base = qem.lod(mesh_id, info["min_vertices"], "msgpack")
                level = qem.lod(mesh_id, args.level, "ply")
            entry["stream"] = {
                "bytes": len(stream),
                "base_bytes": len(base),
                "first_request_s": first_s,
            }
            base_url = f"{stored.url}/v1/meshes/{mesh_id}"
            draco = _draco_bytes(load_bench_mesh(mesh_path))
            bare.append(_bare_server(work_dir, "stream.bin", stream, "application/x-qem-splits"))
            bare.append(_bare_server(work_dir, "level.ply", level, "application/octet-stream"))
            stream_urls = {
                "qem-lod /splits": f"{base_url}/splits",
                "bare app, same bytes": bare[0].url + "/",
            }
            if draco is not None:
                bare.append(_bare_server(work_dir, "mesh.drc", draco, "application/octet-stream"))
                stream_urls["bare app, Draco file"] = bare[2].url + "/"
                entry["draco_bytes"] = len(draco)
            entry["whole_stream"] = _load_runs(stream_urls, 4, args)
            entry["cached_level"] = {
                "vertices": args.level,
                "bytes": len(level),
                **_load_runs(
                    {
                        "qem-lod /lod": f"{base_url}/lod?vertices={args.level}&format=ply",
                        "bare app, same bytes": bare[1].url + "/",
                    },
                    16,
                    args,
                ),
            }
        finally:
            for server in (stored, *bare):
                if server is not None:
                    server.stop()
    entry["load_average"] = {"start": start_load, "end": load_average()}
    whole = entry["whole_stream"]["median_per_s"]
    level_rates = entry["cached_level"]["median_per_s"]
    entry["ratios"] = {
        "ready": entry["ready"]["ratio"],
        "whole_stream": whole["qem-lod /splits"] / whole["bare app, same bytes"],
        "cached_level": level_rates["qem-lod /lod"] / level_rates["bare app, same bytes"],
    }
    entry["targets"] = {
        "ready_met": entry["ratios"]["ready"] <= TARGET_READY_FACTOR,
        "whole_stream_met": entry["ratios"]["whole_stream"] >= TARGET_SERVING_RATIO,
        "cached_level_met": entry["ratios"]["cached_level"] >= TARGET_SERVING_RATIO,
    }
    return entry


def _met(flag: bool) -> str:
    return "**met**" if flag else "**not met**"


def write_report(path: Path, entry: dict[str, Any]) -> None:
    ready, ratios, targets = entry["ready"], entry["ratios"], entry["targets"]
    lines = [
        f"# Serving stored split streams: `{entry['mesh']}` against a static file",
        "",
        *run_header_lines(entry),
        "",
        "Servers: `python -m client.cli serve --host 127.0.0.1 --port 0 --workers 1 "
        "--log-level info` (uvicorn's access log on), and `python -m bench.bare_app` "
        "(uvicorn, the same log level) answering every GET with the same bytes from memory. "
        "Both servers, wrk and the build worker share the machine's cores.",
        "",
        "## Upload to ready",
        "",
    ]
    lines += markdown_table(
        ["build", "runs s", "median s"],
        [
            [name, ", ".join(f"{t:.2f}" for t in times), f"{ready['median_s'][name]:.2f}"]
            for name, times in ready["times_s"].items()
        ],
        [False, False, True],
    )
    lines += [
        "",
        f"Stored / not stored: **{format_ratio(ratios['ready'])}** (target <= "
        f"{TARGET_READY_FACTOR}: {_met(targets['ready_met'])}). 'not stored' is the build "
        "as before this change (`QEM_STREAM_AT_BUILD=false`); one server at a time, a new "
        "one for each upload (its kernels loaded by an untimed spot.ply upload first), the "
        "two kinds alternating.",
        "",
        "## Responses per second (wrk, loopback)",
        "",
    ]
    rows = []
    for key, title in (("whole_stream", "whole stream"), ("cached_level", "cached level")):
        block = entry[key]
        for name, runs in block["runs"].items():
            rows.append(
                [
                    f"{title} ({name})",
                    str(block["connections"]),
                    ", ".join(f"{run.get('requests_per_s', 0):.1f}" for run in runs),
                    f"{block['median_per_s'][name]:.1f}",
                    str(sum(run.get("non_2xx", 0) for run in runs)),
                ]
            )
    lines += markdown_table(
        ["what", "connections", "runs /s", "median /s", "non-2xx"],
        rows,
        [False, True, False, True, True],
    )
    stream = entry["stream"]
    lines += [
        "",
        f"Whole stream, qem-lod / bare app: **{format_ratio(ratios['whole_stream'])}** "
        f"(target >= {TARGET_SERVING_RATIO}: {_met(targets['whole_stream_met'])}); cached "
        f"level ({entry['cached_level']['vertices']} vertices, PLY, "
        f"{entry['cached_level']['bytes']:,} bytes): **{format_ratio(ratios['cached_level'])}** "
        f"(target >= {TARGET_SERVING_RATIO}: {_met(targets['cached_level_met'])}).",
        "",
        f"Bytes: stream {stream['bytes']:,} + base {stream['base_bytes']:,} = "
        f"{stream['bytes'] + stream['base_bytes']:,}"
        + (
            f"; Draco (16 bits, level 7) {entry['draco_bytes']:,}: "
            f"{format_ratio((stream['bytes'] + stream['base_bytes']) / entry['draco_bytes'])} "
            "of it."
            if "draco_bytes" in entry
            else "; DracoPy not installed, no Draco figure."
        ),
        f"The first /splits request after the build (the stream read from the store, its "
        f"CRC checked) took {stream['first_request_s'] * 1000:.0f} ms.",
        "",
    ]
    path.write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = bench_parser("python -m bench.stream_serving", __doc__)
    parser.add_argument("--mesh", default="dragon.ply")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--rounds", type=int, default=2)
    parser.add_argument("--duration", type=int, default=10)
    parser.add_argument("--level", type=int, default=1000)
    args = parser.parse_args(argv)
    entry = measure_stream_serving(args)
    args.out_dir.mkdir(parents=True, exist_ok=True)
    write_json(args.out_dir / "stream-serving.json", entry)
    write_report(args.out_dir / "stream-serving.md", entry)
    progress(f"wrote {args.out_dir / 'stream-serving.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

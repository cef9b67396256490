"""The scaled deployment against the embedded one, side by side in one run (issue 34).

    python -m bench.scaled_deployment [--mesh dragon.ply] [--runs 3] [--duration 10]

Starts real PostgreSQL and SeaweedFS on loopback (tests/postgres_server.py,
tests/s3_server.py), then:

- **upload -> ready** of the mesh: the embedded deployment (`qem serve --workers 1`:
  SQLite, the data directory, a build pool in the server) against the scaled one (`qem
  serve` with QEM_DATABASE_URL and QEM_BLOB_URL, no builds of its own, and one `qem
  worker --slots 1`), a fresh set of processes each time, alternating, --runs each, each
  after an untimed upload of spot (kernels loaded). Ratio of the medians; target <= 1.3.
- **cached level** (``lod?vertices=1000&format=ply``, fetched once first): ``wrk -t2
  -c16`` through one replica, then two wrk at once with 8 connections each on two
  replicas (their responses per second summed). The machine has 2 cores shared by
  replicas, database and load generator: little gain is expected, and the figure says
  how much.
- **a killed build taken up**: the mesh's worker killed with SIGKILL (with its build
  process) once the build has started, a second worker running (``QEM_WORKER_STALE_S``
  given): seconds from the kill to the build claimed again, and to ready.

Writes bench/results/scaled-deployment.md and .json.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx

from .report import format_ratio
from .runs import bench_parser, progress, record_run, run_header_lines
from .service import POLL_INTERVAL_S, READY_TIMEOUT_S, _run_wrk

__all__ = ["main"]

REPO = Path(__file__).resolve().parent.parent
TARGET_READY_FACTOR = 1.3
STALE_S = 5.0


def _serve(data_dir: Path, env: dict[str, str], builds: bool):
    """``qem serve``, building with one worker of its own or leaving builds to the
    `WorkerProcess` es (the tests' helpers)."""
    from tests.e2e.conftest import ServerProcess

    return ServerProcess(data_dir, env, builds=builds).start()


def _worker(env: dict[str, str]):
    from tests.e2e.conftest import WorkerProcess

    return WorkerProcess(env)


def _ready_seconds(server, mesh: Path, warm_up: Path) -> float:
    with server.client() as qem:
        qem.wait_ready(qem.upload(warm_up), interval=POLL_INTERVAL_S, timeout=READY_TIMEOUT_S)
        start = time.perf_counter()
        mesh_id = qem.upload(mesh)
        qem.wait_ready(mesh_id, interval=POLL_INTERVAL_S, timeout=READY_TIMEOUT_S)
        return time.perf_counter() - start


def _scaled_env(postgres, s3) -> dict[str, str]:
    from server.migrations import upgrade

    url = postgres.database()
    upgrade(url)
    return {"QEM_DATABASE_URL": url, **s3.env(), "QEM_WORKER_STALE_S": str(STALE_S)}


def measure(args, postgres, s3, work: Path) -> dict[str, Any]:
    mesh = args.mesh_dir / args.mesh
    warm_up = REPO / "server" / "demo" / "spot.obj"
    times: dict[str, list[float]] = {"embedded": [], "scaled": []}
    for run in range(args.runs):
        server = _serve(work / f"embedded-{run}", {}, builds=True)
        try:
            times["embedded"].append(_ready_seconds(server, mesh, warm_up))
        finally:
            server.stop()
        env = _scaled_env(postgres, s3)
        server = _serve(work / f"scaled-{run}", env, builds=False)
        worker = _worker(env)
        try:
            times["scaled"].append(_ready_seconds(server, mesh, warm_up))
        finally:
            worker.stop()
            server.stop()
        progress(f"run {run + 1}: embedded {times['embedded'][-1]:.2f} s, "
                 f"scaled {times['scaled'][-1]:.2f} s")  # fmt: skip
    ready = {name: statistics.median(values) for name, values in times.items()}

    # Cached level through one replica and through two.
    env = _scaled_env(postgres, s3)
    replicas = [_serve(work / f"replica-{i}", env, builds=False) for i in range(2)]
    worker = _worker(env)
    try:
        with replicas[0].client() as qem:
            mesh_id = qem.upload(mesh)
            qem.wait_ready(mesh_id, interval=POLL_INTERVAL_S, timeout=READY_TIMEOUT_S)
        urls = [f"{r.url}/v1/meshes/{mesh_id}/lod?vertices=1000&format=ply" for r in replicas]
        for url in urls:
            httpx.get(url, timeout=60).raise_for_status()
        one = _run_wrk(urls[0], 2, 16, args.duration)
        with ThreadPoolExecutor(2) as pool:
            both = list(pool.map(lambda url: _run_wrk(url, 1, 8, args.duration), urls))
        serving = {
            "one_replica_per_s": one.get("requests_per_s", 0.0),
            "two_replicas_per_s": sum(run.get("requests_per_s", 0.0) for run in both),
        }
        progress(f"cached level: one replica {serving['one_replica_per_s']:.0f}/s, two "
                 f"{serving['two_replicas_per_s']:.0f}/s")  # fmt: skip
    finally:
        worker.stop()
        for replica in replicas:
            replica.stop()

    # A killed build taken up by another worker.
    env = _scaled_env(postgres, s3)
    server = _serve(work / "takeover", env, builds=False)
    first = _worker(env)
    second = None
    try:
        with server.client() as qem:
            qem.wait_ready(qem.upload(warm_up), interval=POLL_INTERVAL_S, timeout=READY_TIMEOUT_S)
            mesh_id = qem.upload(mesh)
            while qem.info(mesh_id)["progress"] < 0.05:
                time.sleep(0.05)
            second = _worker(env)
            time.sleep(2.0)  # the second worker up and idle
            first.kill()
            killed = time.perf_counter()
            if qem.info(mesh_id)["status"] != "building":
                raise SystemExit(f"{args.mesh} was built before its worker could be killed: "
                                 "take a mesh whose build lasts several seconds (dragon)")
            import psycopg

            with psycopg.connect(env["QEM_DATABASE_URL"], autocommit=True) as connection:
                while connection.execute(
                    "SELECT status, attempts FROM meshes WHERE id = %s", (mesh_id,)
                ).fetchone() != ("building", 2):
                    if time.perf_counter() - killed > READY_TIMEOUT_S:
                        raise SystemExit("the killed build was never taken up")
                    time.sleep(0.02)
            claimed = time.perf_counter() - killed
            qem.wait_ready(mesh_id, interval=POLL_INTERVAL_S, timeout=READY_TIMEOUT_S)
            takeover = {"stale_s": STALE_S, "claimed_again_s": claimed,
                        "ready_after_kill_s": time.perf_counter() - killed}  # fmt: skip
        progress(f"takeover: claimed again {claimed:.2f} s after the kill")
    finally:
        for worker in (first, second):
            if worker is not None:
                worker.stop()
        server.stop()
    return {"mesh": args.mesh, "ready_s": times, "ready_median_s": ready,
            "ready_ratio": ready["scaled"] / ready["embedded"], "serving": serving,
            "takeover": takeover}  # fmt: skip


def write_report(path: Path, record: dict[str, Any]) -> None:
    ready, serving, takeover = record["ready_median_s"], record["serving"], record["takeover"]
    ratio = record["ready_ratio"]
    runs = ", ".join(f"{e:.2f} / {s:.2f}" for e, s in zip(*record["ready_s"].values(), strict=True))
    lines = [
        "# The scaled deployment against the embedded one",
        "",
        *run_header_lines(record),
        "PostgreSQL and SeaweedFS (`weed mini`) on loopback, beside the servers, workers "
        "and load generator on the same 2 cores.",
        "",
        f"- **upload -> ready** of `{record['mesh']}`: embedded {ready['embedded']:.2f} s, "
        f"scaled (PostgreSQL + S3 + one `qem worker`) {ready['scaled']:.2f} s: "
        f"**{format_ratio(ratio)}x** (target <= {TARGET_READY_FACTOR}x: "
        f"{'met' if ratio <= TARGET_READY_FACTOR else 'missed'}). Runs (embedded / scaled, "
        f"s): {runs}.",
        f"- **cached level** (1000 vertices, PLY): {serving['one_replica_per_s']:.0f} "
        f"responses/s through one replica (wrk -c16), {serving['two_replicas_per_s']:.0f} "
        f"through two (two wrk -c8 at once): "
        f"{format_ratio(serving['two_replicas_per_s'] / serving['one_replica_per_s'])}x on "
        "two cores that the replicas share with the load generator.",
        f"- **a killed build taken up**: with QEM_WORKER_STALE_S={takeover['stale_s']:g}, "
        f"claimed again by the other worker {takeover['claimed_again_s']:.2f} s after the "
        f"SIGKILL, ready {takeover['ready_after_kill_s']:.2f} s after it (the stale time "
        "plus at most a third of it for the next sweep, then the whole build again).",
        "",
    ]
    path.write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    from tests.postgres_server import PostgresServer
    from tests.s3_server import S3Server

    parser = bench_parser("python -m bench.scaled_deployment", __doc__)
    parser.add_argument("--mesh", default="dragon.ply")
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--duration", type=int, default=10)
    args = parser.parse_args(argv)

    def measured() -> dict[str, Any]:
        postgres = PostgresServer().start()
        s3 = S3Server().start()
        try:
            with tempfile.TemporaryDirectory(prefix="qem-bench-scaled-") as work:
                return measure(args, postgres, s3, Path(work))
        finally:
            s3.stop()
            postgres.stop()

    record_run("bench.scaled_deployment", args, "scaled-deployment", measured, write_report)
    return 0


if __name__ == "__main__":
    sys.exit(main())

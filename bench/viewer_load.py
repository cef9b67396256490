"""viewer_load: how fast the web viewer shows a mesh, and how many bytes it pulls.

    python -m bench.viewer_load                                  # dragon.ply, 3 runs
    python -m bench.viewer_load --mesh /work/shared/meshes/bunny.ply --runs 1

Starts ``qem serve`` on 127.0.0.1 (a fresh data directory), uploads the mesh and waits
for its build, then opens the viewer at ``/#mesh=ID`` in headless Debian Chromium (the
browser test's set-up: Playwright with executable_path, software GL) with a fresh
profile per run, so the HTTP cache is cold each time. Figures, from the page's own clock
(``window.qemViewer.state``):

- base shown: from selecting the mesh (its metadata request) to the first frame drawn
  with the base mesh; also from navigation start (page, three.js and modules loaded);
- all received: every split frame read, inflated, decoded and stored;
- full shown: the first frame drawn at the full vertex count;
- bytes: the base mesh (msgpack) plus the split stream, as response bodies (the server
  sends no content coding), against the uploaded binary PLY and the server's own binary
  PLY of the full level;
- server alone: the same two requests read by httpx in this process, without the
  browser, to tell the server's share from the viewer's.

Writes bench/results/viewer-load.md (the machine and versions first).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import tempfile
import time
from datetime import UTC, datetime
from pathlib import Path

import httpx

from bench.machine import machine_header_lines
from tests.e2e.conftest import ServerProcess
from tests.e2e.test_viewer import chromium_page, find_chromium

REPO = Path(__file__).resolve().parents[1]
DEFAULT_MESH = REPO.parent / "shared" / "meshes" / "dragon.ply"
DEFAULT_OUT = REPO / "bench" / "results" / "viewer-load.md"
LOAD_TIMEOUT_MS = 600_000

_DONE = "() => { const s = window.qemViewer?.state; return s?.fullShownMs != null; }"
_STATE = "window.qemViewer.state"
# Moving the slider all the way down and back up, timed in the page.
_SLIDE = """() => {
  const s = window.qemViewer.state;
  let t = performance.now();
  window.qemViewer.setLevel(0);
  const down = performance.now() - t;
  t = performance.now();
  window.qemViewer.setLevel(s.full);
  return { down, up: performance.now() - t };
}"""


def server_alone(url: str, n_base: int, n_full: int) -> dict:
    """Base mesh and split stream read by httpx: times (ms) and body sizes."""
    with httpx.Client(timeout=600) as http:
        start = time.perf_counter()
        base = http.get(f"{url}/lod", params={"vertices": n_base, "format": "msgpack"})
        base.raise_for_status()
        base_ms = 1000 * (time.perf_counter() - start)
        size = 0
        with http.stream("GET", f"{url}/splits", params={"from": n_base, "to": n_full}) as r:
            r.raise_for_status()
            for chunk in r.iter_raw():
                size += len(chunk)
        total_ms = 1000 * (time.perf_counter() - start)
        ply = http.get(f"{url}/lod", params={"format": "ply"})
        ply.raise_for_status()
    return {
        "base_ms": base_ms,
        "total_ms": total_ms,
        "base_bytes": len(base.content),
        "split_bytes": size,
        "ply_bytes": len(ply.content),
    }


def one_run(page_url: str, profile: Path) -> dict:
    with chromium_page(profile) as page:
        page.goto(page_url)
        page.wait_for_function(_DONE, timeout=LOAD_TIMEOUT_MS)
        state = page.evaluate(_STATE)
        slide = page.evaluate(_SLIDE)
        assert not page.errors, page.errors
    return {**state, **slide}


def chromium_version() -> str:
    done = subprocess.run([find_chromium(), "--version"], capture_output=True, text=True)
    return done.stdout.strip() or "Chromium (version unknown)"


def median(runs: list[dict], key: str) -> float:
    return statistics.median(run[key] for run in runs)


def mib(n: float) -> str:
    return f"{n / 2**20:.2f} MiB"


def write_report(out: Path, mesh: Path, info: dict, runs: list[dict], alone: list[dict]):
    full_bytes = [run["baseBytes"] + run["splitBytes"] for run in runs]
    ply_in = mesh.stat().st_size
    ply_out = alone[0]["ply_bytes"]
    load = os.getloadavg()
    lines = [
        f"# Viewer load: `{mesh.name}` over loopback",
        "",
        f"Measured {datetime.now(UTC).isoformat(timespec='seconds')} by "
        f"`python -m bench.viewer_load --mesh {mesh} --runs {len(runs)}`.",
        *machine_header_lines(),
        f"Browser: {chromium_version()}, headless, `--disable-gpu` "
        "(WebGL on the CPU, SwiftShader), 1200 x 800; a fresh profile per run (cold HTTP "
        f"cache). Load average after the runs: {load[0]:.2f} / {load[1]:.2f} / {load[2]:.2f} "
        f"(1 / 5 / 15 min; {os.cpu_count()} cores, shared with other work).",
        "",
        f"Mesh: {info['vertices']} vertices, {info['faces']} faces; base mesh "
        f"{info['min_vertices']} vertices. The viewer fetches the base mesh "
        "(`lod?vertices=min&format=msgpack`), then `splits?from=min&to=full` streamed.",
        "",
        "| run | base shown (from select) | base shown (from navigation) | all received "
        "| full shown | bytes (base + splits) | slider full -> base | base -> full |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for i, run in enumerate(runs, 1):
        lines.append(
            f"| {i} | {run['baseShownMs']:.0f} ms | {run['startedMs'] + run['baseShownMs']:.0f} ms "
            f"| {run['streamedMs']:.0f} ms | {run['fullShownMs']:.0f} ms "
            f"| {full_bytes[i - 1]} ({run['baseBytes']} + {run['splitBytes']}) "
            f"| {run['down']:.0f} ms | {run['up']:.0f} ms |"
        )
    lines += [
        f"| median | {median(runs, 'baseShownMs'):.0f} ms | "
        f"{statistics.median(r['startedMs'] + r['baseShownMs'] for r in runs):.0f} ms | "
        f"{median(runs, 'streamedMs'):.0f} ms | {median(runs, 'fullShownMs'):.0f} ms | "
        f"{statistics.median(full_bytes):.0f} | {median(runs, 'down'):.0f} ms | "
        f"{median(runs, 'up'):.0f} ms |",
        "",
        "Bytes against binary PLY:",
        "",
        f"- viewer, base + every split: {full_bytes[0]} bytes ({mib(full_bytes[0])});",
        f"- the uploaded binary PLY `{mesh.name}`: {ply_in} bytes ({mib(ply_in)}): "
        f"the viewer pulls {full_bytes[0] / ply_in:.1%} of it;",
        f"- the server's binary PLY of the full level (`lod?format=ply`, float32 xyz and "
        f"uint32 faces only): {ply_out} bytes ({mib(ply_out)}): "
        f"{full_bytes[0] / ply_out:.1%} of it.",
        "",
        "Server alone (httpx in the benchmark's process, no browser; base mesh then the "
        "whole split stream, read as it comes):",
        "",
        "| run | base mesh | base + all splits |",
        "|---:|---:|---:|",
        *(
            f"| {i} | {a['base_ms']:.0f} ms | {a['total_ms']:.0f} ms |"
            for i, a in enumerate(alone, 1)
        ),
        "",
    ]
    out.write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", type=Path, default=DEFAULT_MESH)
    parser.add_argument("--runs", type=int, default=3)
    parser.add_argument("--out", type=Path, default=DEFAULT_OUT)
    args = parser.parse_args(argv)
    if find_chromium() is None:
        parser.error("no Chromium found (apt-get install -y chromium, or set QEM_CHROMIUM)")
    with tempfile.TemporaryDirectory(prefix="qem-viewer-load-") as scratch:
        server = ServerProcess(Path(scratch) / "data").start()
        try:
            with server.client() as qem:
                mesh_id = qem.upload(args.mesh)
                info = qem.wait_ready(mesh_id, timeout=1800)
            url = f"{server.url}/v1/meshes/{mesh_id}"
            alone = [server_alone(url, info["min_vertices"], info["vertices"])]
            runs = []
            for i in range(args.runs):
                runs.append(one_run(f"{server.url}/#mesh={mesh_id}", Path(scratch) / f"p{i}"))
                print(f"run {i + 1}: {runs[-1]}", flush=True)
                alone.append(server_alone(url, info["min_vertices"], info["vertices"]))
        finally:
            server.stop()
    write_report(args.out, args.mesh, info, runs, alone)
    print(args.out.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

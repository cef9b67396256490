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
- longest task: the longest main-thread task (a ``longtask`` PerformanceObserver in the
  page) from selecting the mesh to the full mesh drawn: what freezes the page while the
  stream arrives;
- server alone: the same two requests read by httpx in this process, without the
  browser, to tell the server's share from the viewer's.

Beside each viewer run, in the same browser build with its own fresh profile, the static
alternative: ``bench/web/draco_glb.html`` loads a Draco GLB of the same input (16 bits,
level 7, ``bench.draco_glb``) with three.js's GLTFLoader + DRACOLoader from
``python -m http.server`` on loopback; its full shown time runs from the load's start
(the page's modules loaded, as the viewer's are when a mesh is chosen) to the first
frame drawn with the mesh, with its own longest task.

Writes bench/results/viewer-load.md (the machine and versions first).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path

import httpx

import qem_core
from bench.draco_glb import draco_glb
from bench.machine import machine_header_lines
from bench.meshes import compact_referenced
from tests.e2e.conftest import ServerProcess
from tests.e2e.test_viewer import chromium_page, find_chromium

REPO = Path(__file__).resolve().parents[1]
DEFAULT_MESH = REPO.parent / "shared" / "meshes" / "dragon.ply"
DEFAULT_OUT = REPO / "bench" / "results" / "viewer-load.md"
LOAD_TIMEOUT_MS = 600_000

_DONE = "() => { const s = window.qemViewer?.state; return s?.fullShownMs != null; }"
# A GL on the CPU draws the view at rest once more, multisampled (scene.js's polish).
_POLISHED = "() => { const s = window.qemViewer.state; return s.fullPolishedMs != null; }"
_STATE = "window.qemViewer.state"
_DRACO_DONE = "() => { const s = window.dracoPage; return s?.fullShownMs != null || !!s?.error; }"
_DRACO_PAGE = Path(__file__).resolve().parent / "web" / "draco_glb.html"
# Every main-thread task over 50 ms, from the page's first script on.
_WATCH_LONG_TASKS = """
window.longTasks = [];
new PerformanceObserver((list) => {
  for (const entry of list.getEntries()) window.longTasks.push([entry.startTime, entry.duration]);
}).observe({ type: "longtask", buffered: true });
"""
_LONGEST = """([from, to]) => Math.max(0, ...window.longTasks
  .filter(([start, duration]) => start + duration > from && start < to)
  .map(([, duration]) => duration))"""
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
        page.add_init_script(_WATCH_LONG_TASKS)
        page.goto(page_url)
        page.wait_for_function(_DONE, timeout=LOAD_TIMEOUT_MS)
        state = page.evaluate(_STATE)
        window = [state["startedMs"], state["startedMs"] + state["fullShownMs"]]
        longest = page.evaluate(_LONGEST, window)
        if state["softwareGL"]:
            page.wait_for_function(_POLISHED, timeout=LOAD_TIMEOUT_MS)
            state["fullPolishedMs"] = page.evaluate(_STATE)["fullPolishedMs"]
        slide = page.evaluate(_SLIDE)
        assert not page.errors, page.errors
    return {**state, **slide, "longestTaskMs": longest}


@contextmanager
def draco_site(mesh: Path, work: Path) -> Iterator[tuple[str, int]]:
    """A static site on loopback (``python -m http.server``): the Draco GLB page, the GLB
    of ``mesh`` and three.js; its URL and the GLB's size."""
    loaded = qem_core.load_mesh(mesh)
    glb = draco_glb(*compact_referenced(loaded.vertices, loaded.faces))
    work.mkdir()
    (work / "mesh.glb").write_bytes(glb)
    (work / "index.html").write_bytes(_DRACO_PAGE.read_bytes())
    (work / "node_modules").symlink_to(REPO / "client" / "web" / "node_modules")
    process = subprocess.Popen(
        [sys.executable, "-m", "http.server", "0", "--bind", "127.0.0.1", "-d", str(work)],
        stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True,
    )  # fmt: skip
    try:
        port = process.stdout.readline().split("port ")[1].split()[0]
        yield f"http://127.0.0.1:{port}/index.html", len(glb)
    finally:
        process.terminate()
        process.wait(10)
        process.stdout.close()


def draco_run(page_url: str, profile: Path) -> dict:
    with chromium_page(profile) as page:
        page.add_init_script(_WATCH_LONG_TASKS)
        page.goto(page_url)
        page.wait_for_function(_DRACO_DONE, timeout=LOAD_TIMEOUT_MS)
        state = page.evaluate("window.dracoPage")
        assert state["error"] is None and not page.errors, (state, page.errors)
        window = [state["startedMs"], state["startedMs"] + state["fullShownMs"]]
        return {**state, "longestTaskMs": page.evaluate(_LONGEST, window)}


def chromium_version() -> str:
    done = subprocess.run([find_chromium(), "--version"], capture_output=True, text=True)
    return done.stdout.strip() or "Chromium (version unknown)"


def median(runs: list[dict], key: str) -> float:
    return statistics.median(run[key] for run in runs)


def _median_or_none(runs: list[dict], key: str) -> float | None:
    values = [run[key] for run in runs if run.get(key) is not None]
    return statistics.median(values) if values else None


def _ms(value: float | None) -> str:
    return "-" if value is None else f"{value:.0f} ms"


def mib(n: float) -> str:
    return f"{n / 2**20:.2f} MiB"


def write_report(
    out: Path, mesh: Path, info: dict, runs: list[dict], alone: list[dict], draco: dict
):
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
        "(`lod?vertices=1&format=msgpack`, served as the base's count, asked for beside "
        "the mesh's metadata), then `splits?from=min&to=full` streamed.",
        "",
        "With WebGL on the CPU the viewer draws its frames with one sample each and a view "
        "at rest once more with four (*full polished*: the full mesh so drawn, 0.5 s after "
        "it rests); the GLB page draws its one frame with four (three.js's usual "
        "`antialias: true`), and, in a run of its own beside it, with one (*GLB, one "
        "sample*: the yardstick for the viewer's single-sampled full frame).",
        "",
        "| run | base shown (from select) | base shown (from navigation) | all received "
        "| full shown | full polished | longest task | bytes (base + splits) "
        "| slider full -> base | base -> full | Draco GLB full shown | its longest task "
        "| GLB, one sample |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    rows = zip(runs, draco["runs"], draco["runs_one_sample"], strict=True)
    for i, (run, glb, glb_one) in enumerate(rows, 1):
        lines.append(
            f"| {i} | {run['baseShownMs']:.0f} ms | {run['startedMs'] + run['baseShownMs']:.0f} ms "
            f"| {run['streamedMs']:.0f} ms | {run['fullShownMs']:.0f} ms "
            f"| {_ms(run.get('fullPolishedMs'))} | {run['longestTaskMs']:.0f} ms "
            f"| {full_bytes[i - 1]} ({run['baseBytes']} + {run['splitBytes']}) "
            f"| {run['down']:.0f} ms | {run['up']:.0f} ms "
            f"| {glb['fullShownMs']:.0f} ms | {glb['longestTaskMs']:.0f} ms "
            f"| {glb_one['fullShownMs']:.0f} ms |"
        )
    full_ms = median(runs, "fullShownMs")
    glb_ms = median(draco["runs"], "fullShownMs")
    glb_one_ms = median(draco["runs_one_sample"], "fullShownMs")
    polished = _median_or_none(runs, "fullPolishedMs")
    # Each run against the GLB run just after it: the machine's load drifts over a set of
    # runs, and the GLB page's own time varies by a third from run to run.
    beside = zip(runs, draco["runs"], strict=True)
    paired = sorted(run["fullShownMs"] / glb["fullShownMs"] for run, glb in beside)
    lines += [
        f"| median | {median(runs, 'baseShownMs'):.0f} ms | "
        f"{statistics.median(r['startedMs'] + r['baseShownMs'] for r in runs):.0f} ms | "
        f"{median(runs, 'streamedMs'):.0f} ms | {full_ms:.0f} ms | "
        f"{_ms(polished)} | "
        f"{median(runs, 'longestTaskMs'):.0f} ms | "
        f"{statistics.median(full_bytes):.0f} | {median(runs, 'down'):.0f} ms | "
        f"{median(runs, 'up'):.0f} ms | {glb_ms:.0f} ms | "
        f"{median(draco['runs'], 'longestTaskMs'):.0f} ms | "
        f"{glb_one_ms:.0f} ms |",
        "",
        "Against the Draco GLB (issue #32's targets, medians):",
        "",
        f"- full detail: {full_ms:.0f} ms against "
        f"{glb_ms:.0f} ms, **{full_ms / glb_ms:.2f}×** (aim ≤ 1.5×); "
        f"against the GLB drawn with one sample as the viewer's frame is, "
        f"{glb_one_ms:.0f} ms, **{full_ms / glb_one_ms:.2f}×**"
        + (
            f"; the viewer's full mesh polished (four samples) at {polished:.0f} ms, "
            f"{polished / glb_ms:.2f}× the GLB's;"
            if polished is not None
            else ";"
        ),
        f"- full detail against the GLB run beside it, run by run: median "
        f"{statistics.median(paired):.2f}× ({paired[0]:.2f}× to {paired[-1]:.2f}×);",
        f"- first paint (base shown from select): {median(runs, 'baseShownMs'):.0f} ms "
        "(aim ≤ 300 ms);",
        f"- longest main-thread task from select to full detail: "
        f"{median(runs, 'longestTaskMs'):.0f} ms (aim ≤ 250 ms);",
        f"- bytes: {full_bytes[0]} against the GLB's {draco['bytes']} "
        f"({full_bytes[0] / draco['bytes']:.2f}×).",
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
            draco: dict = {"runs": [], "runs_one_sample": []}
            with draco_site(args.mesh, Path(scratch) / "draco") as (glb_url, draco["bytes"]):
                for i in range(args.runs):
                    page = f"{server.url}/#mesh={mesh_id}"
                    runs.append(one_run(page, Path(scratch) / f"p{i}"))
                    print(f"run {i + 1}: {runs[-1]}", flush=True)
                    draco["runs"].append(draco_run(glb_url, Path(scratch) / f"d{i}"))
                    print(f"Draco GLB {i + 1}: {draco['runs'][-1]}", flush=True)
                    one_sample = draco_run(f"{glb_url}?antialias=0", Path(scratch) / f"e{i}")
                    draco["runs_one_sample"].append(one_sample)
                    print(f"Draco GLB, one sample, {i + 1}: {one_sample}", flush=True)
                    alone.append(server_alone(url, info["min_vertices"], info["vertices"]))
        finally:
            server.stop()
    write_report(args.out, args.mesh, info, runs, alone, draco)
    print(args.out.read_text())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

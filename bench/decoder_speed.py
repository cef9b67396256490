"""Decoding speed: the progressive stream against Draco, side by side in one process.

    python -m bench.decoder_speed [--meshes dragon.ply bunny.ply igea.ply] [--runs 5]

Each mesh is built as the server builds an upload and exported as the server stores it
(base level as msgpack, the stored split stream: ``qem_core.static_export.export_parts``).
The same input (its referenced positions and faces) is encoded by Draco at 16 bits,
compression level 7 (draco_encoder's default; DracoPy). Then:

- **node**: ``bench/node/decoder_speed.mjs`` times the viewer's decoder
  (client/web/js/refine.js: base + whole stream to the full level, the buffers a renderer
  reads) and Draco's WebAssembly decoder (three.js's copy, as DRACOLoader runs it, positions
  and indices copied out), alternating, in one node process, after one untimed run each;
- **Python**: ``qem_core.stream.SplitStreamDecoder`` (from the base msgpack, every frame
  fed) against ``DracoPy.decode``, alternating, after one untimed run each.

Ratios are progressive over Draco (below 1: the progressive decoder is faster); bytes
are base + stream against the Draco file. Needs node and client/web/node_modules
(`make install`). Writes bench/results/decoder-speed.md and .json.
"""

from __future__ import annotations

import json
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from .meshes import compact_referenced
from .report import format_ms, format_ratio, markdown_table
from .runs import bench_parser, progress, record_run, run_header_lines

__all__ = ["main", "measure_decoder_speed"]

REPO = Path(__file__).resolve().parent.parent
WEB = REPO / "client" / "web"
NODE_DRIVER = Path(__file__).resolve().parent / "node" / "decoder_speed.mjs"
DEFAULT_MESHES = ("dragon.ply", "bunny.ply", "igea.ply")
DRACO_BITS = 16
DRACO_LEVEL = 7
TARGET_TIME_FACTOR = 1.5  # issue #32: decoding <= 1.5x Draco's wasm decoder
TARGET_BYTES_FACTOR = 1.5  # and base + stream <= 1.5x Draco 16-bit level 7


def _write_case(mesh_path: Path, case: Path) -> dict[str, Any]:
    """Build and export the mesh into `case`; its sizes."""
    import DracoPy

    import qem_core
    from qem_core.static_export import export_parts

    mesh = qem_core.load_mesh(mesh_path)
    pm = qem_core.build_mesh(mesh)
    parts = export_parts(pm, mesh_path.stem)
    vertices, faces = compact_referenced(mesh.vertices, mesh.faces)
    drc = DracoPy.encode(
        vertices, faces, quantization_bits=DRACO_BITS, compression_level=DRACO_LEVEL
    )
    case.mkdir(parents=True)
    (case / "base.msgpack").write_bytes(parts.base)
    (case / "stream.qsplits").write_bytes(parts.stream)
    (case / "mesh.drc").write_bytes(drc)
    plan = {"vertices": pm.n_full, "faces": pm.n_faces_full}
    (case / "plan.json").write_text(json.dumps(plan))
    return {**plan, "splits": pm.n_splits, "base_bytes": len(parts.base),
            "stream_bytes": len(parts.stream), "draco_bytes": len(drc),
            "draco_vertices": len(vertices)}  # fmt: skip


def _node_times(case: Path, runs: int, node: str) -> dict[str, Any]:
    done = subprocess.run(
        [node, str(NODE_DRIVER), str(WEB), str(case), str(runs)],
        capture_output=True, text=True, timeout=1800, check=False,
    )  # fmt: skip
    if done.returncode != 0:
        raise RuntimeError(f"node driver failed: {done.stderr.strip()[-2000:]}")
    return json.loads(done.stdout)


def _python_times(case: Path, runs: int) -> dict[str, list[float]]:
    import DracoPy

    from qem_core.stream import SplitStreamDecoder, iter_frames

    base = (case / "base.msgpack").read_bytes()
    stream = (case / "stream.qsplits").read_bytes()
    drc = (case / "mesh.drc").read_bytes()

    def progressive() -> None:
        decoder = SplitStreamDecoder.from_msgpack(base)
        for payload in iter_frames([stream]):
            decoder.feed(payload)
        decoder.vertices  # noqa: B018  (the float positions, as a renderer takes them)

    def draco() -> None:
        DracoPy.decode(drc)

    times: dict[str, list[float]] = {"progressive_s": [], "draco_s": []}
    progressive()  # untimed: numba's kernels compiled or loaded
    draco()
    for _ in range(runs):
        for key, decode in (("progressive_s", progressive), ("draco_s", draco)):
            start = time.perf_counter()
            decode()
            times[key].append(time.perf_counter() - start)
    return times


def measure_decoder_speed(mesh_dir: Path, meshes: list[str], runs: int) -> dict[str, Any]:
    node = shutil.which("node")
    if node is None:
        raise SystemExit("node is missing: install Node.js >= 18 (see the README)")
    if not (WEB / "node_modules" / "three").is_dir():
        raise SystemExit("client/web/node_modules is missing: run `make install`")
    rows = []
    with tempfile.TemporaryDirectory(prefix="qem-bench-decoder-") as work:
        for name in meshes:
            case = Path(work) / Path(name).stem
            sizes = _write_case(mesh_dir / name, case)
            in_node = _node_times(case, runs, node)
            in_python = _python_times(case, runs)
            node_ms = statistics.median(in_node["progressive_ms"])
            draco_ms = statistics.median(in_node["draco_ms"])
            py_s = statistics.median(in_python["progressive_s"])
            dracopy_s = statistics.median(in_python["draco_s"])
            if in_node["progressive_result"]["faces"] != sizes["faces"]:
                raise RuntimeError(f"{name}: the viewer's decoder stopped short of the full mesh")
            rows.append({
                "mesh": name, **sizes, "node": in_node, "python": in_python,
                "node_ratio": node_ms / draco_ms, "python_ratio": py_s / dracopy_s,
                "bytes_ratio": (sizes["base_bytes"] + sizes["stream_bytes"]) / sizes["draco_bytes"],
            })  # fmt: skip
            progress(f"{name}: node {node_ms:.0f} ms vs Draco wasm {draco_ms:.0f} ms; "
                     f"Python {py_s * 1e3:.0f} ms vs DracoPy {dracopy_s * 1e3:.0f} ms")  # fmt: skip
    version = subprocess.run([node, "--version"], capture_output=True, text=True, check=False)
    return {"meshes": rows, "node_version": version.stdout.strip()}


def _verdict(values: list[float], target: float) -> str:
    met = sum(value <= target for value in values)
    return f"met on {met} of {len(values)} meshes (ratios {min(values):.2f} to {max(values):.2f})"


def _per_item_us(ms: float, items: int | None) -> str:
    return "-" if not items else f"{1000 * ms / items:.2f}"


def write_report(path: Path, record: dict[str, Any]) -> None:
    rows = []
    for row in record["meshes"]:
        node_ms = statistics.median(row["node"]["progressive_ms"])
        draco_ms = statistics.median(row["node"]["draco_ms"])
        rows.append([
            row["mesh"], f"{row['vertices']:,}", f"{row['faces']:,}",
            f"{node_ms:.0f}", f"{draco_ms:.0f}", format_ratio(row["node_ratio"]),
            _per_item_us(node_ms, row.get("splits")),
            _per_item_us(draco_ms, row["draco_vertices"]),
            format_ms(statistics.median(row["python"]["progressive_s"])),
            format_ms(statistics.median(row["python"]["draco_s"])),
            format_ratio(row["python_ratio"]),
            f"{row['base_bytes'] + row['stream_bytes']:,}", f"{row['draco_bytes']:,}",
            format_ratio(row["bytes_ratio"]),
        ])  # fmt: skip
    lines = [
        "# Decoding speed: the progressive stream against Draco",
        "",
        *run_header_lines(record),
        f"Node {record['node_version']}.",
        "",
        f"Median of {record['runs']} decodes each, alternating, after one untimed decode "
        "each. *node*: the viewer's decoder (refine.js, base + whole stored stream to the "
        "full level) against Draco's WebAssembly decoder (three.js's copy, as DRACOLoader "
        "runs it) in one node process; *Python*: `SplitStreamDecoder` against "
        f"`DracoPy.decode`. Draco: {DRACO_BITS}-bit positions, compression level "
        f"{DRACO_LEVEL}. Ratios: progressive / Draco (below 1: faster or smaller). Per "
        "split and per vertex: the decode's time over the splits it applies, and Draco's "
        "over the vertices it decodes (a split is one vertex more), which shows whether "
        "the cost grows with the mesh (out of cache) or is a constant of the format.",
        "",
        *markdown_table(
            [
                "mesh",
                "V",
                "F",
                "refine.js ms",
                "Draco wasm ms",
                "node ratio",
                "refine.js µs / split",
                "Draco wasm µs / vertex",
                "Python ms",
                "DracoPy ms",
                "Python ratio",
                "base + stream B",
                "Draco B",
                "bytes ratio",
            ],
            rows,
            [False] + [True] * 13,
        ),  # fmt: skip
        "",
        "## Targets (issue #32)",
        "",
        f"- decoding <= {TARGET_TIME_FACTOR}x Draco's wasm decoder in node: "
        + _verdict([row["node_ratio"] for row in record["meshes"]], TARGET_TIME_FACTOR)
        + ".",
        f"- base + stream <= {TARGET_BYTES_FACTOR}x Draco 16-bit level 7: "
        + _verdict([row["bytes_ratio"] for row in record["meshes"]], TARGET_BYTES_FACTOR)
        + ".",
        "",
    ]
    path.write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = bench_parser("python -m bench.decoder_speed", __doc__)
    parser.add_argument("--meshes", nargs="+", default=list(DEFAULT_MESHES))
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args(argv)
    record_run("bench.decoder_speed", args, "decoder-speed",
               lambda: measure_decoder_speed(args.mesh_dir, args.meshes, args.runs),
               write_report, runs=args.runs)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

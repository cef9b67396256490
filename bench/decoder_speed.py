"""Decoding speed: the progressive stream against Draco, side by side in one process.

    python -m bench.decoder_speed [--meshes dragon.ply bunny.ply igea.ply spot.obj
                                            airplane_colored.ply] [--runs 5]

Each mesh is built as the server builds an upload (``qem_core.build_mesh``, which keeps
texture coordinates and vertex colours: spot.obj's, airplane_colored.ply's) and exported
as the server stores it (base level as msgpack, the stored split stream with its wedge
keys: ``qem_core.static_export.export_parts``). The same input is encoded by Draco at 16
bits, compression level 7 (draco_encoder's default; DracoPy): its referenced positions
and faces, and its colours and texture coordinates, a point for each distinct position
and coordinate pair (seams split, as a glTF file has them). Then:

- **node**: ``bench/node/decoder_speed.mjs`` times the viewer's decoder
  (client/web/js/refine.js: base + whole stream to the full level, the buffers a renderer
  reads), its frames decoded in JavaScript and by the WebAssembly split decoder
  (js/refine.wasm, which the viewer's worker uses), and Draco's
  WebAssembly decoder (three.js's copy, as DRACOLoader runs it, indices and every
  attribute copied out), alternating, in one node process, after one untimed run each;
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
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from qem_core.codecs._corners import split_at_seams

from .meshes import compact_referenced
from .report import format_ms, format_ratio, markdown_table
from .runs import bench_parser, progress, record_run, run_header_lines

__all__ = [
    "draco_input", "main", "measure_decoder_speed", "mesh_cases", "node_version",
    "node_with_viewer_packages", "run_mesh_bench", "run_node_driver", "write_case",
]  # fmt: skip

REPO = Path(__file__).resolve().parent.parent
WEB = REPO / "client" / "web"
NODE_DRIVER = Path(__file__).resolve().parent / "node" / "decoder_speed.mjs"
DEFAULT_MESHES = ("dragon.ply", "bunny.ply", "igea.ply", "spot.obj", "airplane_colored.ply")
DRACO_BITS = 16
DRACO_LEVEL = 7
TARGET_TIME_FACTOR = 1.5  # issue #32: decoding <= 1.5x Draco's wasm decoder
TARGET_BYTES_FACTOR = 1.5  # and base + stream <= 1.5x Draco 16-bit level 7


def write_case(mesh_path: Path, case: Path) -> tuple[Any, dict[str, Any]]:
    """Build and export the mesh into `case` (what bench/node/decoder_speed.mjs reads);
    the progressive mesh and its sizes."""
    import DracoPy

    import qem_core
    from qem_core.static_export import export_parts

    mesh = qem_core.load_mesh(mesh_path)
    pm = qem_core.build_mesh(mesh)
    parts = export_parts(pm, mesh_path.stem)
    vertices, faces, attributes = draco_input(mesh)
    drc = DracoPy.encode(
        vertices, faces, quantization_bits=DRACO_BITS, compression_level=DRACO_LEVEL,
        **attributes,
    )  # fmt: skip
    case.mkdir(parents=True)
    (case / "base.msgpack").write_bytes(parts.base)
    (case / "stream.qsplits").write_bytes(parts.stream)
    (case / "mesh.drc").write_bytes(drc)
    plan = {"vertices": pm.n_full, "faces": pm.n_faces_full}
    (case / "plan.json").write_text(json.dumps(plan))
    return pm, {**plan, "splits": pm.n_splits, "base_bytes": len(parts.base),
            "stream_bytes": len(parts.stream), "draco_bytes": len(drc),
            "draco_vertices": len(vertices), "draco_attributes": 1 + len(attributes)}  # fmt: skip


def draco_input(mesh: Any) -> tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]:
    """The mesh as Draco takes it: points (its referenced vertices, split where a vertex
    has several texture coordinates), faces, and DracoPy's per-point attributes
    (``colors`` as 8 bits, ``tex_coord``) where the mesh has them."""
    if mesh.corner_uvs is None:
        vertices, faces = compact_referenced(mesh.vertices, mesh.faces)
        point_vertex = np.unique(np.asarray(mesh.faces))
        attributes = {}
    else:  # the GLB writer's split, of the referenced vertices
        used = np.unique(np.asarray(mesh.faces))
        remap = np.zeros(len(mesh.vertices), np.int64)
        remap[used] = np.arange(used.size)
        source, uvs, faces = split_at_seams(remap[mesh.faces], mesh.corner_uvs, used.size)
        point_vertex = used[source]
        vertices = np.asarray(mesh.vertices, np.float64)[point_vertex]
        faces = faces.astype(np.int32)
        attributes = {"tex_coord": uvs.astype(np.float64)}
    colours = mesh.vertex_attributes.get("color")
    if colours is not None:
        rgb = np.asarray(colours, np.float64)[point_vertex, :3]
        attributes["colors"] = np.clip(np.rint(255 * rgb), 0, 255).astype(np.uint8)
    return vertices, faces, attributes


def mesh_cases(
    mesh_dir: Path, meshes: list[str], prefix: str
) -> Iterator[tuple[str, Path, Any, dict]]:
    """Each mesh built and written as a case (`write_case`) in a temporary folder that
    lasts while the caller iterates: (name, case folder, progressive mesh, sizes)."""
    with tempfile.TemporaryDirectory(prefix=prefix) as work:
        for name in meshes:
            case = Path(work) / Path(name).stem
            pm, sizes = write_case(mesh_dir / name, case)
            yield name, case, pm, sizes


def run_node_driver(node: str, driver: Path, *arguments: object) -> dict[str, Any]:
    """The JSON line a node driver prints, given client/web and `arguments`."""
    done = subprocess.run(
        [node, str(driver), str(WEB), *map(str, arguments)],
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


def node_with_viewer_packages() -> str:
    """The path of node, once node and client/web/node_modules are known to be there."""
    node = shutil.which("node")
    if node is None:
        raise SystemExit("node is missing: install Node.js >= 18 (see the README)")
    if not (WEB / "node_modules" / "three").is_dir():
        raise SystemExit("client/web/node_modules is missing: run `make install`")
    return node


def node_version(node: str) -> str:
    done = subprocess.run([node, "--version"], capture_output=True, text=True, check=False)
    return done.stdout.strip()


def measure_decoder_speed(mesh_dir: Path, meshes: list[str], runs: int) -> dict[str, Any]:
    node = node_with_viewer_packages()
    rows = []
    for name, case, _, sizes in mesh_cases(mesh_dir, meshes, "qem-bench-decoder-"):
        in_node = run_node_driver(node, NODE_DRIVER, case, runs)
        in_python = _python_times(case, runs)
        node_ms = statistics.median(in_node["progressive_ms"])
        wasm_ms = statistics.median(in_node["wasm_ms"])
        draco_ms = statistics.median(in_node["draco_ms"])
        py_s = statistics.median(in_python["progressive_s"])
        dracopy_s = statistics.median(in_python["draco_s"])
        for result in ("progressive_result", "wasm_result"):
            if in_node[result]["faces"] != sizes["faces"]:
                raise RuntimeError(f"{name}: the viewer's decoder stopped short of the full mesh")
        if in_node["wasm_result"]["decoder"] != "wasm":
            raise RuntimeError(f"{name}: refine.js did not decode in WebAssembly")
        if in_node["draco_result"]["attributes"] != sizes["draco_attributes"]:
            raise RuntimeError(f"{name}: Draco's decoder did not give every attribute")
        rows.append({
            "mesh": name, **sizes, "node": in_node, "python": in_python,
            "node_ratio": node_ms / draco_ms, "wasm_ratio": wasm_ms / draco_ms,
            "python_ratio": py_s / dracopy_s,
            "bytes_ratio": (sizes["base_bytes"] + sizes["stream_bytes"]) / sizes["draco_bytes"],
        })  # fmt: skip
        progress(f"{name}: node {node_ms:.0f} ms, in wasm {wasm_ms:.0f} ms, vs Draco wasm "
                 f"{draco_ms:.0f} ms; "
                 f"Python {py_s * 1e3:.0f} ms vs DracoPy {dracopy_s * 1e3:.0f} ms")  # fmt: skip
    return {"meshes": rows, "node_version": node_version(node)}


def _verdict(values: list[float], target: float) -> str:
    met = sum(value <= target for value in values)
    return f"met on {met} of {len(values)} meshes (ratios {min(values):.2f} to {max(values):.2f})"


def _per_item_us(ms: float, items: int | None) -> str:
    return "-" if not items else f"{1000 * ms / items:.2f}"


def write_report(path: Path, record: dict[str, Any]) -> None:
    rows = []
    for row in record["meshes"]:
        node_ms = statistics.median(row["node"]["progressive_ms"])
        wasm_ms = statistics.median(row["node"]["wasm_ms"])
        draco_ms = statistics.median(row["node"]["draco_ms"])
        rows.append([
            row["mesh"], f"{row['vertices']:,}", f"{row['faces']:,}",
            f"{node_ms:.0f}", f"{wasm_ms:.0f}", f"{draco_ms:.0f}",
            format_ratio(row["node_ratio"]), format_ratio(row["wasm_ratio"]),
            _per_item_us(node_ms, row.get("splits")), _per_item_us(wasm_ms, row.get("splits")),
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
        "full level), its frames decoded in JavaScript (*refine.js*) and by the WebAssembly "
        "split decoder (*in wasm*: js/refine.wasm, what the viewer's worker runs), against "
        "Draco's WebAssembly decoder (three.js's copy, as "
        "DRACOLoader runs it) in one node process; *Python*: `SplitStreamDecoder` against "
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
                "in wasm ms",
                "Draco wasm ms",
                "refine.js ratio",
                "in wasm ratio",
                "refine.js µs / split",
                "in wasm µs / split",
                "Draco wasm µs / vertex",
                "Python ms",
                "DracoPy ms",
                "Python ratio",
                "base + stream B",
                "Draco B",
                "bytes ratio",
            ],
            rows,
            [False] + [True] * 16,
        ),  # fmt: skip
        "",
        "## Targets (issue #32)",
        "",
        f"- decoding <= {TARGET_TIME_FACTOR}x Draco's wasm decoder in node, in wasm (the "
        "viewer's): "
        + _verdict([row["wasm_ratio"] for row in record["meshes"]], TARGET_TIME_FACTOR)
        + "; in JavaScript: "
        + _verdict([row["node_ratio"] for row in record["meshes"]], TARGET_TIME_FACTOR)
        + ".",
        f"- base + stream <= {TARGET_BYTES_FACTOR}x Draco 16-bit level 7: "
        + _verdict([row["bytes_ratio"] for row in record["meshes"]], TARGET_BYTES_FACTOR)
        + ".",
        "",
    ]
    path.write_text("\n".join(lines))


def run_mesh_bench(
    argv: list[str] | None, module: str, doc: str | None, name: str, measure: Any, report: Any
) -> int:
    """The command line of the node decoding benchmarks: --meshes and --runs, then
    ``measure(mesh_dir, meshes, runs)`` recorded as results/<name>.md by ``report``."""
    parser = bench_parser(f"python -m {module}", doc)
    parser.add_argument("--meshes", nargs="+", default=list(DEFAULT_MESHES))
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args(argv)
    record_run(module, args, name, lambda: measure(args.mesh_dir, args.meshes, args.runs),
               report, runs=args.runs)  # fmt: skip
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_mesh_bench(argv, "bench.decoder_speed", __doc__, "decoder-speed",
                          measure_decoder_speed, write_report)  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())

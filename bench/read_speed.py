"""Reading mesh files: qem_core.load_mesh against trimesh on the same file, side by side.

    python -m bench.read_speed [--runs 7]

Each file is read --runs times by each reader, alternating, in this process after one
untimed read each (imports, caches); the median of each and their ratio (qem-lod over
trimesh: below 1, qem-lod is faster). trimesh reads with ``process=False`` (no merging,
as qem-lod's reader does not merge either; qem-lod's reader also validates indices and
coordinates and welds a GLB's seams). The files: the shared meshes as they are (PLY, and
spot.obj), and dragon and spot written by qem-lod as OBJ, GLB, STL (trimesh's writer)
and OFF in a temporary folder (`NAME-written.EXT`), so every format is timed on the
same two meshes.

Writes bench/results/read-speed.md and .json.
"""

from __future__ import annotations

import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

from .report import format_ms, format_ratio, markdown_table
from .runs import bench_parser, progress, record_run, run_header_lines

__all__ = ["main", "measure_read_speed"]


def _timed(read, path: Path, runs: int) -> list[float]:
    times = []
    for _ in range(runs):
        start = time.perf_counter()
        read(path)
        times.append(time.perf_counter() - start)
    return times


def _files(mesh_dir: Path, work: Path) -> list[Path]:
    import trimesh

    import qem_core

    files = [mesh_dir / name for name in ("dragon.ply", "bunny.ply", "spot.obj")]
    for source in (mesh_dir / "dragon.ply", mesh_dir / "spot.obj"):
        mesh = qem_core.load_mesh(source)
        for fmt in ("obj", "glb"):
            path = work / f"{source.stem}-written.{fmt}"
            path.write_bytes(qem_core.encode_mesh(mesh.vertices, mesh.faces, fmt))
            files.append(path)
        loaded = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        for fmt in ("stl", "off"):
            path = work / f"{source.stem}-written.{fmt}"
            loaded.export(path)
            files.append(path)
    return [path for path in files if path.is_file()]


def measure_read_speed(mesh_dir: Path, runs: int) -> dict[str, Any]:
    import trimesh

    import qem_core

    readers = {
        "qem-lod": qem_core.load_mesh,
        "trimesh": lambda path: trimesh.load(path, force="mesh", process=False),
    }
    rows = []
    with tempfile.TemporaryDirectory(prefix="qem-bench-read-") as work:
        for path in _files(mesh_dir, Path(work)):
            for read in readers.values():
                read(path)  # untimed: imports, numba's kernels, the file in the page cache
            medians = {}
            for name, read in readers.items():
                medians[name] = statistics.median(_timed(read, path, runs))
            faces = qem_core.load_mesh(path).n_faces
            rows.append({"file": path.name, "bytes": path.stat().st_size, "faces": faces,
                         "median_s": medians,
                         "ratio": medians["qem-lod"] / medians["trimesh"]})  # fmt: skip
            progress(f"{path.name}: qem-lod {medians['qem-lod'] * 1e3:.1f} ms, "
                     f"trimesh {medians['trimesh'] * 1e3:.1f} ms")  # fmt: skip
    return {"files": rows, "trimesh": trimesh.__version__}


def write_report(path: Path, record: dict[str, Any]) -> None:
    rows = [
        [row["file"], f"{row['faces']:,}", f"{row['bytes']:,}",
         format_ms(row["median_s"]["qem-lod"]), format_ms(row["median_s"]["trimesh"]),
         format_ratio(row["ratio"])]
        for row in record["files"]
    ]  # fmt: skip
    lines = [
        "# Reading mesh files: qem-lod against trimesh",
        "",
        *run_header_lines(record),
        "",
        f"Median of {record['runs']} reads each, alternating readers, after one untimed read "
        "each; qem-lod / trimesh below 1: qem-lod is faster. trimesh with `process=False`.",
        "",
        *markdown_table(
            ["file", "faces", "bytes", "qem-lod ms", "trimesh ms", "qem-lod / trimesh"],
            rows, [False, True, True, True, True, True],
        ),  # fmt: skip
        "",
    ]
    path.write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    parser = bench_parser("python -m bench.read_speed", __doc__)
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args(argv)
    record_run("bench.read_speed", args, "read-speed",
               lambda: measure_read_speed(args.mesh_dir, args.runs), write_report,
               runs=args.runs)  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())

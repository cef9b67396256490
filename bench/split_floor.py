"""The floor under a split-by-split decoder, against refine.js and Draco, in one process.

    python -m bench.split_floor [--meshes dragon.ply bunny.ply igea.ply] [--runs 5]

What a new stream version could gain in decoding speed (issue #32) is bounded by what
applying the mesh's splits costs at all. ``bench/node/split_floor.mjs`` times, alternating
in one node process: a *floor* decoder that keeps only what an ordered-fan coding would
(a 128-byte block a vertex: degree, grid position, neighbours, faces), touches per split
the blocks a split must touch (s, t, every neighbour moving to t, the wings), predicts
both positions from the wings and decodes rANS symbols standing for the coded fields
(as many bits a split as the mesh's real stream has); the same with a face index buffer
kept up to date (a decoder that holds the mesh, not records); the viewer's decoder
(refine.js, stream version 5); and Draco's WebAssembly decoder. The floor's memory
traffic follows the real split sequence, its arithmetic is a stand-in: it is a lower
bound for a decoder of this split order, not a decoder (docs/performance.md, "The floor
under a split decoder").

Needs node and client/web/node_modules (`make install`). Writes
bench/results/split-floor.md and .json.
"""

from __future__ import annotations

import importlib.util
import json
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

import numpy as np

from .decoder_speed import (
    mesh_cases,
    node_version,
    node_with_viewer_packages,
    run_mesh_bench,
    run_node_driver,
)
from .report import format_ratio, markdown_table
from .runs import progress, run_header_lines

__all__ = ["main", "measure_split_floor"]

NODE_DRIVER = Path(__file__).resolve().parent / "node" / "split_floor.mjs"
FLOOR_C = NODE_DRIVER.with_suffix(".c")
# Each floor symbol codes about 3.75 bits: a split decodes as many as its stream's bits
# a split need (dragon 12, bunny 16).
BITS_PER_SYMBOL = 3.75
TARGET_TIME_FACTOR = 1.5  # issue #32: decoding <= 1.5x Draco's wasm decoder
DECODERS = (
    ("floor_ms", "floor"),
    ("floor_index_ms", "floor + index buffer"),
    ("wasm_ms", "wasm floor"),
    ("wasm_index_ms", "wasm floor + index buffer"),
    ("refine_ms", "refine.js"),
    ("draco_ms", "Draco wasm"),
)


def _write_split_arrays(pm: Any, case: Path) -> None:
    """The progressive mesh's splits, as the node driver reads them."""
    from qem_core.stream import grid_for

    base_vertices, base_faces = pm.lod(pm.n_base)
    splits = pm.splits(pm.n_base, pm.n_full)
    arrays = {
        "base_faces": base_faces,
        "base_q": grid_for(pm, 16).quantise(base_vertices),
        "split_vertex": splits.split_vertex,
        "new_faces": splits.new_faces,
        "new_face_counts": splits.new_face_counts,
        "relabel_offsets": splits.relabel_offsets,
        "relabel_faces": splits.relabel_faces,
    }
    for name, values in arrays.items():
        np.ascontiguousarray(values, dtype="<i4").tofile(case / f"{name}.i32")
    sizes = {"nBase": pm.n_base, "nFull": pm.n_full, "fBase": int(base_faces.shape[0]),
             "fFull": pm.n_faces_full}  # fmt: skip
    (case / "floor.json").write_text(json.dumps(sizes))


def _build_floor_wasm(folder: Path) -> Path | None:
    """split_floor.c built for WebAssembly with the dev extra's ziglang; None without
    ziglang (the report says so)."""
    if importlib.util.find_spec("ziglang") is None:
        return None
    wasm = folder / "split_floor.wasm"
    subprocess.run(
        [sys.executable, "-m", "ziglang", "cc", "--target=wasm32-freestanding", "-O3",
         "-mbulk-memory", "-nostdlib", "-Wl,--no-entry", "-Wl,--export=floor_decode",
         "-Wl,--import-memory", "-o", str(wasm), str(FLOOR_C)],
        check=True, capture_output=True, timeout=600,
    )  # fmt: skip
    return wasm


def measure_split_floor(mesh_dir: Path, meshes: list[str], runs: int) -> dict[str, Any]:
    node = node_with_viewer_packages()
    rows = []
    with tempfile.TemporaryDirectory(prefix="qem-bench-floor-wasm-") as folder:
        wasm = _build_floor_wasm(Path(folder))
        for name, case, pm, sizes in mesh_cases(mesh_dir, meshes, "qem-bench-floor-"):
            rows.append(_measure_case(node, wasm, name, case, pm, sizes, runs))
    return {"meshes": rows, "node_version": node_version(node), "wasm_floor": wasm is not None}


def _measure_case(node: str, wasm: Path | None, name: str, case: Path, pm: Any,
                  sizes: dict[str, Any], runs: int) -> dict[str, Any]:  # fmt: skip
    _write_split_arrays(pm, case)
    stream_bits = 8 * sizes["stream_bytes"] / sizes["splits"]
    symbols = max(1, round(stream_bits / BITS_PER_SYMBOL))
    times = run_node_driver(node, NODE_DRIVER, case, runs, symbols, *([wasm] if wasm else []))
    shown = ", ".join(f"{label} {statistics.median(times[key]):.0f} ms"
                      for key, label in DECODERS if key in times)  # fmt: skip
    progress(f"{name}: {shown}")
    return {"mesh": name, **sizes, "times": times, "symbols": symbols,
            "stream_bits_per_split": stream_bits}  # fmt: skip


def _medians(row: dict[str, Any]) -> dict[str, float]:
    return {key: statistics.median(row["times"][key]) for key, _ in DECODERS if key in row["times"]}


def write_report(path: Path, record: dict[str, Any]) -> None:
    shown = [(key, label) for key, label in DECODERS if key in record["meshes"][0]["times"]]
    rows, per_split = [], []
    for row in record["meshes"]:
        medians = _medians(row)
        draco = medians["draco_ms"]
        cells = [row["mesh"], f"{row['splits']:,}"]
        cells += [f"{medians[key]:.0f} ({format_ratio(medians[key] / draco)})" for key, _ in shown]
        floor_bits = row["times"]["floor_bits_per_split"]
        rows.append([*cells, f"{floor_bits:.1f} / {row['stream_bits_per_split']:.1f}"])
        items = {
            key: row["draco_vertices"] if key == "draco_ms" else row["splits"] for key, _ in shown
        }
        per_split.append(
            [row["mesh"], *(f"{1e6 * medians[key] / items[key]:.0f}" for key, _ in shown)]
        )
    headers = ["mesh", "splits", *(f"{label} ms (x Draco)" for _, label in shown),
               "bits a split: floor / stream"]  # fmt: skip
    best_key = "wasm_ms" if record.get("wasm_floor") else "floor_ms"
    floors = [_medians(row)[best_key] / _medians(row)["draco_ms"] for row in record["meshes"]]
    met = [row["mesh"] for row, ratio in zip(record["meshes"], floors, strict=True)
           if ratio <= TARGET_TIME_FACTOR]  # fmt: skip
    wasm_note = (
        "*wasm floor*: the same floor in C (bench/node/split_floor.c) built for "
        "WebAssembly by ziglang's clang, its records copied out of its memory as Draco's "
        "are; "
        if record.get("wasm_floor")
        else "(no *wasm floor*: ziglang, in the dev extra, was not installed); "
    )
    lines = [
        "# The floor under a split-by-split decoder, against refine.js and Draco",
        "",
        *run_header_lines(record),
        f"Node {record['node_version']}.",
        "",
        f"Median of {record['runs']} decodes each, the decoders alternating in one node "
        "process after one untimed decode each. *floor*: the least a decoder of the mesh's "
        "real split sequence does (per-vertex blocks of an ordered-fan state, the blocks "
        "each split must touch, as many rANS symbols a split as its stream's bits need, "
        "records out); *+ index buffer*: the same keeping a face index buffer; "
        + wasm_note
        + "*refine.js*: the viewer's decoder (stream version 5, base + whole stored stream "
        "to the full level); *Draco wasm*: three.js's copy of Draco's decoder on the same "
        "mesh at 16 bits, level 7. The floor is a lower bound (its arithmetic stands in for "
        "a format's), not a decoder: see docs/performance.md, \"The floor under a split "
        'decoder".',
        "",
        *markdown_table(headers, rows, [False] + [True] * (len(headers) - 1)),
        "",
        "Per split (Draco: per vertex), ns:",
        "",
        *markdown_table(
            ["mesh", *(label for _, label in shown)], per_split, [False] + [True] * len(shown)
        ),  # fmt: skip
        "",
        f"## Against issue #32's decoding target (<= {TARGET_TIME_FACTOR}x Draco)",
        "",
        f"- the {'wasm ' if record.get('wasm_floor') else ''}floor is within it on "
        f"{len(met)} of {len(floors)} meshes"
        + (f" ({', '.join(met)})" if met else "")
        + f"; floor / Draco from {min(floors):.2f} to {max(floors):.2f}. A decoder of this "
        "split order does more than its floor.",
        "",
    ]
    path.write_text("\n".join(lines))


def main(argv: list[str] | None = None) -> int:
    return run_mesh_bench(argv, "bench.split_floor", __doc__, "split-floor",
                          measure_split_floor, write_report)  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())

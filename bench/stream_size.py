"""Size of the whole vertex-split stream against single-rate encodings (issues 3 and 4).

    python -m bench.stream_size [--meshes spot.ply dragon.ply ...] [--bits 16]
        [--draco-levels 1 7 10] [--qem-option name=value ...] [--timeout S]

For each mesh (default: the seven shared meshes, and spot.obj with its UVs), in a child
process (`bench.measure.measure_in_child`): `qem_core.build_mesh(qem_core.load_mesh(path))`
as the server builds an upload (appearance attributes kept: spot.obj's UVs,
airplane_colored.ply's colours), with the build options of --qem-option (defaults
otherwise), then

- the split stream from the base mesh to the full mesh, `qem_core.stream.encode_split_frames`
  on a --bits grid: total bytes (frame headers included), bytes per vertex split, and the
  bytes its wedge keys add (the frames rewritten without them, sealed the same way, and
  the difference taken);
- the base mesh as the server's msgpack form (positions on the --bits grid, its
  attributes and quantised wedges), the first thing a client fetches;
- for reference, the full mesh in that same msgpack form (qem-lod's own single-rate).

Beside it, in this process, the input with its unreferenced vertices dropped
(`bench.meshes.compact_referenced`): binary PLY (`qem_core.encode_mesh(v, f, "ply")`)
and Draco single-rate (`DracoPy.encode`, quantization_bits=bits) at each --draco-levels
compression level: 1 is DracoPy's default, 7 draco_encoder's, 10 the smallest.

Ratios are of the whole download, base + stream, over each of them (PLY and Draco hold
positions and faces only). Targets (issue 3): <= 10 bytes per split of geometry (the
stream without its wedge keys); long run: base + stream <= 1.5x Draco.

Writes bench/results/stream-size.md (the meshes of this run) and merges each mesh's
entry into bench/results/stream-size.json (keyed by the mesh's name, followed by
`qem-lod[name=value,...]` for a run with --qem-option, so a variant's entries sit
beside the defaults').
"""

from __future__ import annotations

import shlex
import struct
import sys
import time
import zlib
from collections.abc import Sequence
from importlib.metadata import version
from pathlib import Path
from typing import Any

from . import qem_lod
from .meshes import DEFAULT_MESH_FILES, compact_referenced
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

__all__ = ["build_as_served", "main", "measure_stream_size", "stream_sizes"]

# The shared meshes, and spot with its texture coordinates (seams: the UV wedges).
DEFAULT_STREAM_MESHES = (*DEFAULT_MESH_FILES, "spot.obj")
DEFAULT_BITS = 16
DEFAULT_DRACO_LEVELS = (1, 7, 10)
TARGET_BYTES_PER_SPLIT = 10.0
TARGET_DRACO_FACTOR = 1.5


def build_as_served(path: str, options: dict[str, Any] | None = None):
    """`qem_core.build_mesh` of a mesh file, appearance attributes kept (in the child)."""
    import qem_core

    return qem_core.build_mesh(qem_core.load_mesh(path), options)


def stream_sizes(progressive_mesh, bits: int) -> dict[str, Any]:
    """In the child, on the built mesh: sizes of the split stream and msgpack forms."""
    import qem_core
    from qem_core.stream import encode_split_frames, quantised_wedges

    pm = progressive_mesh
    # A few splits first, untimed: numba compiles (or loads) the coding kernels.
    list(encode_split_frames(pm, pm.n_base, min(pm.n_full, pm.n_base + 8), bits))
    start = time.perf_counter()
    frames = list(encode_split_frames(pm, pm.n_base, pm.n_full, bits))
    encode_s = time.perf_counter() - start
    frame_sizes = [len(frame) for frame in frames]

    def msgpack_bytes(n: int) -> int:
        # As the server writes a level (server/lod_cache.py).
        level = pm.lod_mesh(n)
        encoded = qem_core.encode_mesh(
            level.vertices, level.faces, "msgpack", level.vertex_attributes, level.texture,
            level.corner_uvs, quantize_bits=bits, grid_box=pm.position_bounds,
            wedges=quantised_wedges(pm, n),
        )  # fmt: skip
        return len(encoded)

    return {
        "n_full": pm.n_full,
        "n_base": pm.n_base,
        "n_splits": pm.n_splits,
        "faces_full": pm.n_faces_full,
        "attributes": list(pm.attribute_layout.names) if pm.attribute_layout else [],
        "frames": len(frame_sizes),
        "stream_bytes": sum(frame_sizes),
        "wedge_bytes": sum(frame_sizes) - sum(map(len, without_wedges(frames))),
        "stream_encode_s": encode_s,
        "field_bytes": field_bytes(pm, bits),
        "base_msgpack_bytes": msgpack_bytes(pm.n_base),
        "full_msgpack_bytes": msgpack_bytes(pm.n_full),
    }


def without_wedges(frames: Sequence[bytes]) -> list[bytes]:
    """The frames with their wedge keys dropped, sealed as qem_core.stream does (msgpack
    map + CRC-32): the geometry-only stream of the same splits."""
    import msgpack

    stripped = []
    for frame in frames:
        body = msgpack.unpackb(frame[4:-4])
        geometry = {key: value for key, value in body.items() if not key.startswith("wedge")}
        payload = msgpack.packb(geometry)
        payload += struct.pack("<I", zlib.crc32(payload))
        stripped.append(struct.pack("<I", len(payload)) + payload)
    return stripped


def field_bytes(progressive_mesh, bits: int) -> dict[str, int]:
    """Where a stream's bytes go: each field of the frames range-coded on its own
    (``qem_core.stream.range_code_fields`` with that field's flag, the wedge fields by
    ``range_code_wedges`` one at a time), summed over the frames, by field name
    (bench.stream_entropy also gives the deflated byte planes' sizes)."""
    from .stream_entropy import measure

    return measure(progressive_mesh, bits)["range"]


def _single_rate_sizes(path: Path, bits: int, draco_levels: Sequence[int]) -> dict:
    """Binary PLY and Draco of the input's positions and faces as qem-lod reads it
    (referenced vertices only; an OBJ's UV seams do not split its vertices), with encode
    times."""
    import DracoPy

    import qem_core

    mesh = qem_core.load_mesh(path)
    vertices, faces = compact_referenced(mesh.vertices, mesh.faces)
    sizes: dict[str, Any] = {
        "input_vertices": int(len(vertices)),
        "input_faces": int(len(faces)),
        "ply_bytes": len(qem_core.encode_mesh(vertices, faces, "ply")),
        "draco": {},
    }
    for level in draco_levels:
        start = time.perf_counter()
        encoded = DracoPy.encode(vertices, faces, quantization_bits=bits, compression_level=level)
        sizes["draco"][str(level)] = {
            "bytes": len(encoded),
            "encode_s": time.perf_counter() - start,
        }
    return sizes


def measure_stream_size(
    path: Path,
    bits: int,
    draco_levels: Sequence[int],
    timeout_s: float | None,
    options: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """One mesh's JSON entry: stream, base, PLY and Draco sizes and their ratios, of a
    build with ``options`` (the defaults when None)."""
    built = measure_or_fail(
        build_as_served,
        (str(path), options),
        preload=("qem_core",),
        then=stream_sizes,
        then_args=(bits,),
        timeout_s=timeout_s,
    )
    entry: dict[str, Any] = {
        "mesh": path.name,
        "measured_at": now(),
        "status": built.status,
        "bits": bits,
        "options": options or {},
        **_single_rate_sizes(path, bits, draco_levels),
    }
    if not built.ok:
        return entry
    sizes = built.result
    entry.update(sizes)
    total = sizes["base_msgpack_bytes"] + sizes["stream_bytes"]
    entry["total_bytes"] = total
    entry["bytes_per_split"] = sizes["stream_bytes"] / max(1, sizes["n_splits"])
    entry["wedge_bytes_per_split"] = sizes["wedge_bytes"] / max(1, sizes["n_splits"])
    entry["geometry_bytes_per_split"] = entry["bytes_per_split"] - entry["wedge_bytes_per_split"]
    entry["ratios"] = {
        "total/ply": total / entry["ply_bytes"],
        "stream/ply": sizes["stream_bytes"] / entry["ply_bytes"],
        **{f"total/draco{level}": total / d["bytes"] for level, d in entry["draco"].items()},
        **{
            f"stream/draco{level}": sizes["stream_bytes"] / d["bytes"]
            for level, d in entry["draco"].items()
        },
    }
    entry["targets"] = {
        "bytes_per_split_met": entry["geometry_bytes_per_split"] <= TARGET_BYTES_PER_SPLIT,
        **{
            f"draco{level}_met": entry["ratios"][f"total/draco{level}"] <= TARGET_DRACO_FACTOR
            for level in entry["draco"]
        },
    }
    return entry


def _options_phrase(options: dict[str, Any] | None) -> str:
    if not options:
        return " (default options)"
    return f" with the build options of `{qem_lod.variant_label(options)}`"


def _count(value: int | None) -> str:
    return "-" if value is None else f"{value:,}"


def write_stream_size_report(
    path: Path, entries: Sequence[dict[str, Any]], settings: dict[str, Any]
) -> None:
    """The Markdown report of this run's meshes."""
    levels = [str(level) for level in settings["draco_levels"]]
    bits = settings["bits"]
    lines = [
        f"# Split-stream size at a {bits}-bit grid against binary PLY and Draco",
        "",
        *run_header_lines(
            settings, [f"DracoPy {version('DracoPy')}", f"msgpack {version('msgpack')}"]
        ),
        "",
        "Sizes do not depend on the load; only the encode times do.",
        "",
        "Each mesh is built as the server builds an upload, `qem_core.build_mesh`"
        f"{_options_phrase(settings.get('options'))}, which keeps appearance attributes "
        "(spot.obj's UVs, airplane_colored.ply's colours; spot.ply has none). Stream: "
        "`qem_core.stream.encode_split_frames(pm, n_base, "
        f"n_full, {bits})`, every frame with its 4-byte length; its wedge keys (stream "
        "version 3, range-coded in each frame's `wedges` bytes) carry the attributes: "
        "*wedge* is what they add (the frames sealed without them, the difference "
        "taken), *geometry* the rest. Base: the base mesh "
        f"as the server's msgpack form (positions on the same {bits}-bit grid, "
        "attributes and quantised wedges). Total = base + stream: the whole download "
        "from nothing to the full mesh. Full msgpack: the full mesh in that msgpack form "
        "(qem-lod's own single-rate, for reference). PLY and Draco encode the input's "
        "positions and faces (no attributes) with its unreferenced vertices dropped; "
        f"Draco `quantization_bits={bits}` at compression level L (1: DracoPy's default, "
        "7: draco_encoder's, 10: smallest). Sizes in bytes.",
        "",
    ]
    rows, per_vertex_rows = [], []
    for entry in entries:
        draco = entry["draco"]
        ratios = entry.get("ratios", {})
        rows.append(
            [
                entry["mesh"],
                _count(entry.get("n_full")),
                _count(entry.get("n_splits")),
                _count(entry.get("stream_bytes")),
                _count(entry.get("base_msgpack_bytes")),
                _count(entry.get("total_bytes")),
                _count(entry.get("full_msgpack_bytes")),
                _count(entry["ply_bytes"]),
                *(_count(draco[level]["bytes"]) for level in levels if level in draco),
                format_ratio(ratios.get("total/ply")),
                *(format_ratio(ratios.get(f"total/draco{level}")) for level in levels),
            ]
        )
        n_vertices = entry["input_vertices"]
        per_vertex_rows.append(
            [
                entry["mesh"],
                f"{entry['bytes_per_split']:.2f}" if "bytes_per_split" in entry else "-",
                _per_split(entry, "geometry_bytes_per_split"),
                _per_split(entry, "wedge_bytes_per_split"),
                _verdict(entry.get("targets", {}).get("bytes_per_split_met")),
                f"{entry['ply_bytes'] / n_vertices:.2f}",
                *(f"{draco[level]['bytes'] / n_vertices:.2f}" for level in levels),
                format_ms(entry.get("stream_encode_s")),
                *(format_ms(draco[level]["encode_s"]) for level in levels),
                entry["status"],
            ]
        )
    lines += markdown_table(
        [
            "mesh",
            "V full",
            "splits",
            "stream",
            "base",
            "total",
            "full msgpack",
            "PLY",
            *(f"Draco L{level}" for level in levels),
            "total / PLY",
            *(f"total / Draco L{level}" for level in levels),
        ],
        rows,
        [False] + [True] * (8 + 2 * len(levels)),
    )
    lines += ["", "## Per vertex, and encode times", ""]
    lines += markdown_table(
        [
            "mesh",
            "stream B / split",
            "geometry B / split",
            "wedge B / split",
            f"geometry <= {TARGET_BYTES_PER_SPLIT:g} B",
            "PLY B / V",
            *(f"Draco L{level} B / V" for level in levels),
            "stream encode ms",
            *(f"Draco L{level} encode ms" for level in levels),
            "status",
        ],
        per_vertex_rows,
        [False, True, True, True, False] + [True] * (2 + 2 * len(levels)) + [False],
    )
    lines += ["", *_field_lines(entries)]
    lines += ["", "## Targets (issue 3)", "", *_target_lines(entries, levels), ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines), encoding="utf-8")


def _field_lines(entries: Sequence[dict[str, Any]]) -> list[str]:
    """A table of bytes per split by stream field, each field range-coded on its own."""
    measured = [entry for entry in entries if entry.get("field_bytes")]
    if not measured:
        return []
    names = sorted({name for entry in measured for name in entry["field_bytes"]})
    rows = [
        [
            entry["mesh"],
            *(
                f"{entry['field_bytes'].get(name, 0) / max(1, entry['n_splits']):.2f}"
                for name in names
            ),
            f"{entry['bytes_per_split']:.2f}",
        ]
        for entry in measured
    ]
    return [
        "## Where the stream's bytes go (bytes per split)",
        "",
        "Each field of the frames range-coded on its own (its contexts are its own, so "
        "only the 4 flush bytes per frame are counted again in every field; those of "
        "the `wedges` bytes once, in `wedge_values`) and summed over the frames; the "
        "stream (last column) also holds each frame's msgpack "
        "header and CRC-32. Field meanings: docs/formats.md.",
        "",
        *markdown_table(
            ["mesh", *(f"`{name}`" for name in names), "stream"],
            rows,
            [False] + [True] * (len(names) + 1),
        ),
    ]


def _per_split(entry: dict[str, Any], key: str) -> str:
    """A bytes-per-split figure; "-" when not measured, or for wedges when the mesh has
    no attributes."""
    if key not in entry or (key == "wedge_bytes_per_split" and not entry.get("attributes")):
        return "-"
    return f"{entry[key]:.2f}"


def _verdict(met: bool | None) -> str:
    return "-" if met is None else ("met" if met else "not met")


def _target_lines(entries: Sequence[dict[str, Any]], levels: Sequence[str]) -> list[str]:
    measured = [entry for entry in entries if "targets" in entry]
    if not measured:
        return ["Not assessed: no mesh was built."]

    def meeting(key: str) -> str:
        names = [entry["mesh"] for entry in measured if entry["targets"].get(key)]
        return f"{len(names)} of {len(measured)}" + (f" ({', '.join(names)})" if names else "")

    per_split = [entry["geometry_bytes_per_split"] for entry in measured]
    lines = [
        f"- <= {TARGET_BYTES_PER_SPLIT:g} bytes per split of geometry: met on "
        f"{meeting('bytes_per_split_met')} meshes; from {min(per_split):.2f} to "
        f"{max(per_split):.2f} B per split.",
    ]
    with_wedges = [entry for entry in measured if entry.get("attributes")]
    if with_wedges:
        lines.append(
            "- appearance (issue 4): the wedge keys add "
            + ", ".join(
                f"{entry['wedge_bytes_per_split']:.2f} B per split to {entry['mesh']} "
                f"({'/'.join(entry['attributes'])})"
                for entry in with_wedges
            )
            + "."
        )
    for level in levels:
        ratios = [entry["ratios"][f"total/draco{level}"] for entry in measured]
        lines.append(
            f"- base + stream <= {TARGET_DRACO_FACTOR:g}x Draco L{level} (long-run aim): met "
            f"on {meeting(f'draco{level}_met')} meshes; ratios from {min(ratios):.2f} to "
            f"{max(ratios):.2f}."
        )
    return lines


def main(argv: Sequence[str] | None = None) -> int:
    parser = bench_parser("python -m bench.stream_size", __doc__)
    parser.add_argument("--meshes", nargs="+", default=list(DEFAULT_STREAM_MESHES))
    parser.add_argument("--bits", type=int, default=DEFAULT_BITS, help="grid bits per axis")
    parser.add_argument("--draco-levels", type=int, nargs="+", default=list(DEFAULT_DRACO_LEVELS))
    qem_lod.add_option_argument(
        parser, "a qem_core.BuildOptions field for the builds; repeat to combine"
    )
    arguments = list(sys.argv[1:] if argv is None else argv)
    args = parser.parse_args(arguments)
    options = qem_lod.option_values_of(parser, args)
    qem_note = qem_lod.qem_unavailable_reason()
    if qem_note is not None:
        progress(f"qem-lod: {qem_note}; nothing to measure")
        return 1
    settings = {
        "command": shlex.join(["python", "-m", "bench.stream_size", *arguments]),
        "measured_at": now(),
        "source": source_revision(),
        "bits": args.bits,
        "draco_levels": args.draco_levels,
        "options": options,
        "load_average": {"start": load_average()},
    }
    entries = []
    for name in args.meshes:
        entry = measure_stream_size(
            args.mesh_dir / name, args.bits, args.draco_levels, args.timeout, options
        )
        entries.append(entry)
        progress(
            f"{name}: {entry['status']}, stream {_count(entry.get('stream_bytes'))} B, "
            f"{entry.get('bytes_per_split', float('nan')):.2f} B/split (wedges "
            f"{entry.get('wedge_bytes_per_split', float('nan')):.2f}), PLY "
            f"{_count(entry['ply_bytes'])} B, Draco "
            + ", ".join(f"L{lv} {_count(d['bytes'])} B" for lv, d in entry["draco"].items())
        )
    settings["load_average"]["end"] = load_average()
    report_path = args.out_dir / "stream-size.md"
    write_stream_size_report(report_path, entries, settings)
    json_path = args.out_dir / "stream-size.json"
    # A run with build options is kept beside the default's entries, not over them.
    suffix = f" {qem_lod.variant_label(options)}" if options else ""
    merge_results(
        json_path, {entry["mesh"] + suffix: {**entry, "settings": settings} for entry in entries}
    )
    progress(f"wrote {report_path} and {json_path}")
    return 0 if all(entry["status"] == "ok" for entry in entries) else 1


if __name__ == "__main__":
    # Run the module's own import, not __main__: the child process finds stream_sizes by
    # its module name, bench.stream_size.
    from bench.stream_size import main as imported_main

    sys.exit(imported_main())

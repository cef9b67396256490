"""Geometric error of qem-lod against peer simplifiers, at equal vertex count.

    python -m bench.simplify_quality [--meshes spot.ply bunny.ply ...]
        [--fractions 0.5 0.1 0.02 0.005] [--runs 3] [--samples 200000]
        [--peers meshoptimizer pymeshlab ...] [--qem-option name=value ...]
        [--qem-variant name=value,name=value ...] [--reuse-peers] [--no-qem]

For each mesh and each fraction of its referenced vertex count, every peer simplifies to
the matching face count (`bench.meshes.target_counts`); its time (median of --runs, in a
child process), peak RSS, output counts, topology and distance to the original are
recorded. qem-lod is then built ONCE per mesh and option variant (the whole forest,
timed on its own after a JIT warm-up), and `lod(n)` is extracted at each distinct vertex
count a peer actually produced, so each qem-lod row compares at exactly a peer's count.

Writes bench/results/quality-<mesh stem>.md and merges the mesh's entry into
bench/results/quality.json.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from . import qem_lod
from .machine import describe_machine, machine_header_lines
from .measure import ChildCallError, measure_in_child
from .meshes import (
    DEFAULT_MESH_DIR,
    DEFAULT_MESH_FILES,
    BenchMesh,
    count_referenced,
    load_bench_mesh,
    target_counts,
)
from .peers import PEERS, Peer, warm_up_peer
from .quality import (
    DEFAULT_SAMPLES,
    TopologyCounts,
    count_topology,
    measure_surface_distance,
)
from .report import (
    RESULTS_DIR,
    format_mib,
    format_ms,
    format_ratio,
    format_sci,
    markdown_table,
    read_json,
    write_json,
)

__all__ = ["QualityRow", "main"]

DEFAULT_FRACTIONS = (0.5, 0.1, 0.02, 0.005)
DEFAULT_RUNS = 3


@dataclass
class QualityRow:
    """One simplification of one mesh, peer or qem-lod level.

    Counts are of referenced vertices and of faces. time_s: the peer's call (median of
    its runs) or the `lod(n)` extraction, seconds. Distances are fractions of the
    original's bounding-box diagonal. For qem-lod rows, `best_peer_*` name the peers
    with the lowest figure among those that produced exactly this vertex count, and the
    ratios are qem-lod's figure divided by theirs (below 1: qem-lod is better).
    """

    fraction: float
    simplifier: str
    kind: str  # "peer" or "qem"
    target_vertices: int
    target_faces: int | None
    out_vertices: int | None = None
    out_faces: int | None = None
    time_s: float | None = None
    times_s: list[float] = field(default_factory=list)
    peak_rss_bytes: int | None = None
    rss_increase_bytes: int | None = None
    hausdorff: float | None = None
    rms: float | None = None
    boundary_loops: int | None = None
    non_manifold_edges: int | None = None
    status: str = "ok"
    best_peer_hausdorff: str | None = None
    best_peer_rms: str | None = None
    hausdorff_ratio: float | None = None
    rms_ratio: float | None = None
    measured_at: str | None = None  # UTC, ISO 8601; reused peer rows keep their own

    @property
    def ok(self) -> bool:
        return self.status.startswith("ok")


def _status(topology: TopologyCounts, input_topology: TopologyCounts, notes=()) -> str:
    parts = ["ok", *notes]
    if topology.non_manifold_edges:
        parts.append(f"{topology.non_manifold_edges} non-manifold edges")
    if topology.boundary_loops != input_topology.boundary_loops:
        parts.append(
            f"{topology.boundary_loops} boundary loops (input {input_topology.boundary_loops})"
        )
    return "; ".join(parts)


def _assess(row: QualityRow, mesh: BenchMesh, vertices, faces, samples, input_topology, notes=()):
    """Fill a row's counts, distances and status from a simplified mesh."""
    row.out_vertices = count_referenced(faces)
    row.out_faces = int(len(faces))
    topology = count_topology(faces)
    row.boundary_loops = topology.boundary_loops
    row.non_manifold_edges = topology.non_manifold_edges
    if len(faces) == 0:
        row.status = "failed: no faces left"
        return
    distance = measure_surface_distance(mesh.vertices, mesh.faces, vertices, faces, samples)
    row.hausdorff, row.rms = distance.hausdorff, distance.rms
    row.status = _status(topology, input_topology, notes)


def _failure(error: Exception) -> str:
    lines = [line.strip() for line in str(error).strip().splitlines() if line.strip()]
    return "failed: " + (lines[-1] if lines else type(error).__name__)[:160]


def run_peer(
    mesh: BenchMesh,
    peer: Peer,
    fraction: float,
    runs: int,
    samples: int,
    input_topology: TopologyCounts,
) -> QualityRow:
    """Simplify `mesh` with `peer` to `fraction` of its referenced vertices and assess it."""
    target_vertices, target_faces = target_counts(mesh, fraction)
    row = QualityRow(fraction, peer.name, "peer", target_vertices, target_faces)
    row.measured_at = _now()
    try:
        measured = measure_in_child(
            peer.simplify,
            (mesh.vertices, mesh.faces, target_faces),
            runs=runs,
            preload=peer.modules,
            before=warm_up_peer,
            before_args=(peer.simplify,),
        )
    except ChildCallError as error:
        row.status = _failure(error)
        return row
    row.time_s, row.times_s = measured.median_s, list(measured.times_s)
    row.peak_rss_bytes = measured.peak_rss_bytes
    row.rss_increase_bytes = measured.rss_increase_bytes
    vertices, faces = measured.result
    _assess(row, mesh, vertices, faces, samples, input_topology)
    return row


def _peer_counts_by_fraction(peer_rows: Sequence[QualityRow]) -> dict[float, list[int]]:
    """Distinct output vertex counts of the successful peer rows, per fraction; the
    target count where no peer succeeded."""
    counts: dict[float, set[int]] = {}
    for row in peer_rows:
        counts.setdefault(row.fraction, set())
        if row.ok and row.out_vertices:
            counts[row.fraction].add(row.out_vertices)
    for row in peer_rows:
        if not counts[row.fraction]:
            counts[row.fraction].add(row.target_vertices)
    return {fraction: sorted(values) for fraction, values in counts.items()}


def _compare_with_peers(row: QualityRow, peer_rows: Sequence[QualityRow]) -> None:
    """Fill a qem-lod row's ratios against the best peers that produced the vertex count
    this level was asked for (its status says so if the level served another)."""
    rivals = [
        peer
        for peer in peer_rows
        if peer.fraction == row.fraction and peer.ok and peer.out_vertices == row.target_vertices
    ]
    if not rivals or row.hausdorff is None:
        return
    best_hausdorff = min(rivals, key=lambda peer: peer.hausdorff)
    best_rms = min(rivals, key=lambda peer: peer.rms)
    row.best_peer_hausdorff, row.best_peer_rms = best_hausdorff.simplifier, best_rms.simplifier
    if best_hausdorff.hausdorff > 0:
        row.hausdorff_ratio = row.hausdorff / best_hausdorff.hausdorff
    if best_rms.rms > 0:
        row.rms_ratio = row.rms / best_rms.rms


def run_qem_variant(
    mesh: BenchMesh,
    option_values: qem_lod.OptionValues,
    counts_by_fraction: dict[float, list[int]],
    peer_rows: Sequence[QualityRow],
    samples: int,
    input_topology: TopologyCounts,
) -> tuple[dict[str, Any], list[QualityRow]]:
    """Build the progressive mesh once, extract every wanted level, assess each.

    Returns the build record (time, memory, n_full, n_base, options) and the rows.
    """
    label = qem_lod.variant_label(option_values)
    build = {"simplifier": label, "options": option_values, "status": "ok"}
    wanted = sorted({n for counts in counts_by_fraction.values() for n in counts})
    try:
        measured = measure_in_child(
            qem_lod.build_progressive_mesh,
            (mesh.vertices, mesh.faces, option_values),
            preload=("qem_core",),
            before=qem_lod.warm_up_build,
            before_args=(option_values,),
            then=qem_lod.extract_levels,
            then_args=(wanted,),
        )
    except ChildCallError as error:
        build["status"] = _failure(error)
        return build, []
    extracted = measured.result
    build.update(
        time_s=measured.median_s,
        peak_rss_bytes=measured.peak_rss_bytes,
        rss_increase_bytes=measured.rss_increase_bytes,
        n_full=extracted["n_full"],
        n_base=extracted["n_base"],
    )
    rows = []
    for fraction, counts in counts_by_fraction.items():
        for n in counts:
            level = extracted["levels"][n]
            row = QualityRow(fraction, label, "qem", n, None, time_s=level["seconds"])
            row.measured_at = _now()
            served = count_referenced(level["faces"])
            notes = []
            if served != n:
                notes.append(f"asked {n} V, served {served} (n_base {build['n_base']})")
            _assess(row, mesh, level["vertices"], level["faces"], samples, input_topology, notes)
            _compare_with_peers(row, peer_rows)
            rows.append(row)
    return build, rows


def _reusable_peer_rows(stored_entry: dict[str, Any], samples: int) -> dict[tuple, QualityRow]:
    """Peer rows of an earlier run of the same mesh with the same sample count."""
    if stored_entry.get("settings", {}).get("samples") != samples:
        return {}
    rows = {}
    for stored in stored_entry.get("rows", []):
        if stored.get("kind") == "peer":
            row = QualityRow(**stored)
            row.measured_at = row.measured_at or stored_entry.get("measured_at")
            rows[(row.fraction, row.simplifier)] = row
    return rows


def _table_lines(rows: Sequence[QualityRow]) -> list[str]:
    headers = [
        "fraction",
        "simplifier",
        "target V / F",
        "out V",
        "out F",
        "time ms",
        "peak RSS MiB (+call)",
        "Hausdorff",
        "RMS",
        "H qem/best peer",
        "RMS qem/best peer",
        "status",
    ]
    numeric = [True, False, True, True, True, True, True, True, True, False, False, False]
    body = []
    for row in rows:
        target = (
            f"{row.target_vertices} / {row.target_faces}"
            if row.target_faces
            else (f"{row.target_vertices} / -")
        )
        ratios = ["-", "-"]
        if row.kind == "qem":
            ratios = [
                f"{format_ratio(row.hausdorff_ratio)} ({row.best_peer_hausdorff or '-'})",
                f"{format_ratio(row.rms_ratio)} ({row.best_peer_rms or '-'})",
            ]
        body.append(
            [
                f"{row.fraction:g}",
                row.simplifier,
                target,
                "-" if row.out_vertices is None else str(row.out_vertices),
                "-" if row.out_faces is None else str(row.out_faces),
                format_ms(row.time_s),
                format_mib(row.peak_rss_bytes, row.rss_increase_bytes),
                format_sci(row.hausdorff),
                format_sci(row.rms),
                *ratios,
                row.status,
            ]
        )
    return markdown_table(headers, body, numeric)


def _best_lines(rows: Sequence[QualityRow], fractions: Sequence[float]) -> list[str]:
    lines = ["Best peer per fraction (among ok rows):", ""]
    for fraction in fractions:
        peers = [r for r in rows if r.kind == "peer" and r.fraction == fraction and r.ok]
        if not peers:
            lines.append(f"- {fraction:g}: no peer succeeded")
            continue
        fastest = min(peers, key=lambda r: r.time_s)
        lowest_h = min(peers, key=lambda r: r.hausdorff)
        lowest_rms = min(peers, key=lambda r: r.rms)
        lines.append(
            f"- {fraction:g}: fastest {fastest.simplifier} ({format_ms(fastest.time_s)} ms); "
            f"lowest Hausdorff {lowest_h.simplifier} ({format_sci(lowest_h.hausdorff)}); "
            f"lowest RMS {lowest_rms.simplifier} ({format_sci(lowest_rms.rms)})"
        )
    return lines


def _geometric_mean(values: Sequence[float]) -> float | None:
    values = [v for v in values if v is not None and v > 0]
    return math.exp(sum(map(math.log, values)) / len(values)) if values else None


def _qem_summary_lines(builds: Sequence[dict], rows: Sequence[QualityRow]) -> list[str]:
    lines = []
    for build in builds:
        label = build["simplifier"]
        if not build["status"].startswith("ok"):
            lines.append(f"- `{label}`: build {build['status']}")
            continue
        compared = [r for r in rows if r.simplifier == label and r.rms_ratio is not None]
        rms_wins = sum(r.rms_ratio < 1 for r in compared)
        hausdorff_wins = sum(
            r.hausdorff_ratio is not None and r.hausdorff_ratio < 1 for r in compared
        )
        lines.append(
            f"- `{label}`: build of the whole forest {format_ms(build['time_s'])} ms "
            f"(after a JIT warm-up), peak RSS {format_mib(build['peak_rss_bytes'])} MiB "
            f"(+{build['rss_increase_bytes'] / 2**20:.0f}), {build['n_full']} -> "
            f"{build['n_base']} vertices (n_full -> n_base). Against the best peer at equal "
            f"vertex count: lower RMS at {rms_wins} of {len(compared)} counts, lower "
            f"Hausdorff at {hausdorff_wins} of {len(compared)}; geometric mean of the ratios "
            f"RMS {format_ratio(_geometric_mean([r.rms_ratio for r in compared]))}, "
            f"Hausdorff {format_ratio(_geometric_mean([r.hausdorff_ratio for r in compared]))}."
        )
    return lines


def write_mesh_report(path: Path, entry: dict[str, Any], rows: Sequence[QualityRow]) -> None:
    """Write the Markdown report of one mesh."""
    settings, mesh_info = entry["settings"], entry["input"]
    stored = mesh_info["stored_vertices"]
    referenced = mesh_info["referenced_vertices"]
    stored_note = "" if stored == referenced else f" ({stored} stored)"
    peer_rows = [row for row in rows if row.kind == "peer" and row.times_s]
    run_counts = "/".join(str(n) for n in sorted({len(row.times_s) for row in peer_rows})) or "-"
    reused_from = entry.get("peers_reused_from")
    reused_note = f" Peer rows reused from the run of {reused_from}." if reused_from else ""
    lines = [
        f"# Simplification quality on `{entry['mesh']}`: qem-lod and peers",
        "",
        f"Input: {referenced} referenced vertices{stored_note}, {mesh_info['faces']} faces, "
        f"{mesh_info['boundary_loops']} boundary loops, bbox diagonal "
        f"{mesh_info['bbox_diagonal']:.4g}. Measured {entry['measured_at']}.{reused_note}",
        *machine_header_lines(),
        "",
        f"Peers: each call in a child process, time of the simplification call alone, median "
        f"of {run_counts} run(s), in ms; target F = round(F x target V / V), as in "
        "/work/shared/peer-results. Peak RSS: the child's peak during the call (MiB, "
        "includes the loaded input and the tool's libraries) and its increase over the "
        "RSS before the call. Hausdorff / RMS: symmetric, as a fraction of the original "
        f"bounding-box diagonal, {settings['samples']} face samples per direction "
        "(PyMeshLab get_hausdorff_distance, each measured in a fresh process so it repeats "
        "exactly). Out V counts referenced vertices.",
        "",
        "qem-lod: the whole progressive mesh is built once per option variant (figures "
        "below); each qem-lod row is `pm.lod(n)` at a vertex count some peer produced, its "
        "time the extraction alone. `H qem/best peer` and `RMS qem/best peer`: qem-lod's "
        "figure over the lowest among the peers with exactly that out V (named); below 1 "
        "means qem-lod is closer to the original.",
        "",
    ]
    if entry.get("qem_note"):
        lines += [f"qem-lod: {entry['qem_note']}", ""]
    lines += _qem_summary_lines(entry.get("qem_builds", []), rows)
    lines += ["", *_table_lines(rows), "", *_best_lines(rows, settings["fractions"]), ""]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines), encoding="utf-8")


def run_mesh(
    mesh: BenchMesh,
    fractions: Sequence[float],
    peers: Sequence[Peer],
    variants: Sequence[qem_lod.OptionValues],
    runs: int,
    samples: int,
    reusable: dict[tuple, QualityRow],
    qem_note: str | None,
) -> tuple[dict[str, Any], list[QualityRow]]:
    """All peers and qem-lod variants on one mesh; returns the JSON entry and the rows."""
    input_topology = count_topology(mesh.faces)
    peer_rows, reused_times = [], set()
    for fraction in fractions:
        for peer in peers:
            row = reusable.get((fraction, peer.name))
            if row is None:
                row = run_peer(mesh, peer, fraction, runs, samples, input_topology)
            elif row.measured_at:
                reused_times.add(row.measured_at)
            _progress(
                f"{mesh.name} {fraction:g} {peer.name}: {row.out_vertices} V, "
                f"{format_ms(row.time_s)} ms, RMS {format_sci(row.rms)}, {row.status}"
            )
            peer_rows.append(row)
    builds, qem_rows = [], []
    if qem_note is None:
        counts = _peer_counts_by_fraction(peer_rows)
        for option_values in variants:
            build, rows = run_qem_variant(
                mesh, option_values, counts, peer_rows, samples, input_topology
            )
            _progress(
                f"{mesh.name} {build['simplifier']}: build {build['status']}, "
                f"{format_ms(build.get('time_s'))} ms"
            )
            builds.append(build)
            qem_rows += rows
    order = {fraction: index for index, fraction in enumerate(fractions)}
    rows = sorted(peer_rows + qem_rows, key=lambda r: (order[r.fraction], r.kind == "qem"))
    entry = {
        "mesh": mesh.name,
        "measured_at": _now(),
        "machine": describe_machine(),
        "input": {
            "stored_vertices": mesh.n_stored,
            "referenced_vertices": mesh.n_referenced,
            "faces": mesh.n_faces,
            "boundary_loops": input_topology.boundary_loops,
            "non_manifold_edges": input_topology.non_manifold_edges,
            "bbox_diagonal": mesh.bbox_diagonal,
        },
        "settings": {"fractions": list(fractions), "runs": runs, "samples": samples},
        "peers_reused_from": min(reused_times, default=None),
        "qem_note": qem_note,
        "qem_builds": builds,
        "rows": [asdict(row) for row in rows],
    }
    return entry, rows


def _now() -> str:
    return datetime.now(UTC).isoformat(timespec="seconds")


def _progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _parse_args(argv: Sequence[str] | None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m bench.simplify_quality",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument(
        "--meshes",
        nargs="+",
        default=list(DEFAULT_MESH_FILES),
        help="file names in --mesh-dir (default: all seven)",
    )
    parser.add_argument("--mesh-dir", type=Path, default=DEFAULT_MESH_DIR)
    parser.add_argument(
        "--fractions",
        nargs="+",
        type=float,
        default=list(DEFAULT_FRACTIONS),
        help="fractions of the referenced vertex count",
    )
    parser.add_argument(
        "--runs", type=int, default=DEFAULT_RUNS, help="timed runs per peer call (median reported)"
    )
    parser.add_argument(
        "--samples",
        type=int,
        default=DEFAULT_SAMPLES,
        help="face samples per direction for Hausdorff / RMS",
    )
    parser.add_argument("--peers", nargs="+", choices=sorted(PEERS), default=list(PEERS))
    parser.add_argument(
        "--qem-option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a qem_core.BuildOptions field for the qem-lod build; repeat to "
        "combine (e.g. --qem-option error_mode=exact "
        "--qem-option weighting=volume)",
    )
    parser.add_argument(
        "--qem-variant",
        action="append",
        default=[],
        metavar="NAME=VALUE[,NAME=VALUE]",
        help="an extra qem-lod variant built and compared separately; "
        "'default' for the default options; repeatable",
    )
    parser.add_argument("--no-qem", action="store_true", help="peers only")
    parser.add_argument(
        "--reuse-peers",
        action="store_true",
        help="take peer rows from an earlier run in quality.json (same mesh, "
        "fraction and sample count) instead of rerunning them",
    )
    parser.add_argument("--out-dir", type=Path, default=RESULTS_DIR)
    args = parser.parse_args(argv)
    if args.runs < 1 or args.samples < 1:
        parser.error("--runs and --samples must be at least 1")
    try:
        variants = []
        if args.qem_option or not args.qem_variant:
            variants.append(qem_lod.parse_option_assignments(args.qem_option))
        for text in args.qem_variant:
            default = text.strip().lower() == "default"
            variants.append({} if default else qem_lod.parse_option_assignments([text]))
    except ValueError as error:
        parser.error(str(error))
    args.variants = variants
    return args


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse_args(argv)
    qem_note = "skipped (--no-qem)" if args.no_qem else qem_lod.qem_unavailable_reason()
    if qem_note is None:
        for option_values in args.variants:
            try:
                qem_lod.validate_option_values(option_values)
            except ValueError as error:
                print(f"error: {error}", file=sys.stderr)
                return 2
    else:
        _progress(f"qem-lod: {qem_note}")
    json_path = args.out_dir / "quality.json"
    for mesh_name in args.meshes:
        mesh = load_bench_mesh(args.mesh_dir / mesh_name)
        stored = read_json(json_path).get("meshes", {}).get(mesh.name, {})
        reusable = _reusable_peer_rows(stored, args.samples) if args.reuse_peers else {}
        peers = [PEERS[name] for name in args.peers]
        entry, rows = run_mesh(
            mesh,
            args.fractions,
            peers,
            args.variants,
            args.runs,
            args.samples,
            reusable,
            qem_note,
        )
        write_mesh_report(args.out_dir / f"quality-{Path(mesh.name).stem}.md", entry, rows)
        results = read_json(json_path)  # reread: keep entries written meanwhile
        results.setdefault("meshes", {})[mesh.name] = entry
        write_json(json_path, {"machine": describe_machine(), "meshes": results["meshes"]})
        _progress(f"wrote {args.out_dir / f'quality-{Path(mesh.name).stem}.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

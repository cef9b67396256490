"""Appearance attributes and volume preservation (issue 4): qem-lod against peers that keep
UVs or vertex colours, side by side in one run.

    python -m bench.appearance [--parts texture color volume] [--samples 200000]
        [--texture-fractions 0.5 0.1 0.02] [--color-fractions 0.5 0.1 0.02]
        [--volume-meshes igea.ply fandisk.ply] [--volume-fraction 0.02]
        [--qem-variant NAME=VALUE[,NAME=VALUE] ...] [--volume-variant ...] [--no-qem]

Three parts (`bench/texture_metrics.py` holds the metrics):

1. **texture** on spot.obj + spot_texture.png: each peer that keeps UVs simplifies to a
   fraction of the vertices; its output is scored by the texture-space RMS colour error
   against the original (area-uniform samples with a fixed seed; colour at the original
   UV vs colour at the simplified mesh's interpolated UV at the closest point; forward =
   original's samples, backward = simplified's samples, symmetric = both), corners with
   UVs outside [0, 1], UV triangles flipped against the original face nearest to them,
   and seam cracks (edges left open once coincident vertex records are welded).
2. **color** on airplane_colored.ply: the same with interpolated vertex colours.
3. **volume** on igea.ply and fandisk.ply at 2 %: |dV|/V, and the symmetric Hausdorff and
   RMS distance of `bench.quality` (PyMeshLab, fresh process), for qem-lod with default
   options and with preserve_volume=True, peers for context.

Every simplification runs in a fresh child process (`bench.runs.measure_or_fail`, one
timed run after an untimed warm-up call on a tiny mesh); the metrics run here. qem-lod
builds the progressive mesh once per option variant and extracts `lod_mesh(n)` at each
distinct vertex count (distinct positions) a peer produced, so every qem-lod row has
peers at exactly its count. Writes bench/results/appearance.md and .json (parts not run
this time are kept from the JSON file).
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from . import qem_lod
from . import texture_metrics as tm
from .machine import describe_machine, machine_header_lines
from .meshes import BenchMesh, compact_referenced, load_bench_mesh, target_counts, warm_up_mesh
from .peers import PEERS
from .quality import DEFAULT_SAMPLES, count_topology, measure_surface_distance
from .report import format_ms, format_ratio, format_sci, markdown_table, read_json, write_json
from .runs import bench_parser, load_average, measure_or_fail, now, progress, source_revision

__all__ = ["AppearanceRow", "AttributePeer", "load_textured_obj", "main"]

PARTS = ("texture", "color", "volume")
TEXTURE_MESH = "spot.obj"
TEXTURE_IMAGE = "spot_texture.png"
COLOR_MESH = "airplane_colored.ply"
DEFAULT_FRACTIONS = (0.5, 0.1, 0.02)
VOLUME_MESHES = ("igea.ply", "fandisk.ply")
VOLUME_FRACTION = 0.02
VOLUME_PEERS = (
    "meshoptimizer",
    "fast_simplification",
    "pyfqmr",
    "pymeshlab",
    "pymeshlab_quality",
    "open3d",
)
# qem-lod variants of the texture and colour parts besides the defaults (--qem-variant
# replaces them); the volume part always runs the defaults and preserve_volume=true.
DEFAULT_QEM_VARIANTS: tuple[dict[str, Any], ...] = (
    {},
    {"uv_weight": 0.25, "color_weight": 0.25},
    {"uv_weight": 4.0, "color_weight": 4.0},
)
VOLUME_QEM_VARIANTS: tuple[dict[str, Any], ...] = ({}, {"preserve_volume": True})
VOLUME_TOLERANCE = 1e-4  # issue 4: |dV|/V at 2 % with preserve_volume
VOLUME_RMS_LIMIT = 1.2  # issue 4: RMS no worse than 1.2 x the unconstrained run
_MESHOPTIMIZER_UNBOUNDED_ERROR = 1.0e9  # as in bench.peers: the index count alone stops it


# --------------------------------------------------------------------------- inputs


def load_textured_obj(path: str | Path) -> dict[str, Any]:
    """A triangle OBJ with `v`, `vt` and `f a/ta b/tb c/tc` lines, read as it is stored.

    Returns {"vertices" (n, 3) float64 (one per `v` line), "faces" (m, 3) int64,
    "corner_uvs" (m, 3, 2) float64, "colors": None}. Normals are ignored; polygons with
    more than three corners are refused (ValueError).
    """
    positions, uvs, face_rows = [], [], []
    with open(path, encoding="utf-8") as stream:
        for line in stream:
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "v":
                positions.append([float(x) for x in parts[1:4]])
            elif parts[0] == "vt":
                uvs.append([float(x) for x in parts[1:3]])
            elif parts[0] == "f":
                if len(parts) != 4:
                    raise ValueError(f"{path}: only triangles are read, got {line.strip()!r}")
                face_rows.append([int(x) for corner in parts[1:] for x in corner.split("/")[:2]])
    corners = np.asarray(face_rows, dtype=np.int64).reshape(-1, 3, 2) - 1
    return {
        "vertices": np.asarray(positions, dtype=np.float64),
        "faces": corners[:, :, 0],
        "corner_uvs": np.asarray(uvs, dtype=np.float64)[corners[:, :, 1]],
        "colors": None,
    }


def load_colored_ply(path: str | Path) -> dict[str, Any]:
    """A PLY with per-vertex colours (trimesh, nothing merged), unreferenced vertices
    dropped: {"vertices", "faces" (int64), "corner_uvs": None, "colors" (n, 3) RGB
    float64 in [0, 1]}."""
    import trimesh

    loaded = trimesh.load(path, process=False, force="mesh")
    colors = np.asarray(loaded.visual.vertex_colors, dtype=np.float64)[:, :3] / 255.0
    faces = np.asarray(loaded.faces, dtype=np.int64)
    used = np.unique(faces)
    vertices, faces = compact_referenced(np.asarray(loaded.vertices), faces)
    return {
        "vertices": vertices,
        "faces": faces.astype(np.int64),
        "corner_uvs": None,
        "colors": colors[used],
    }


def _bench_mesh(name: str, mesh: dict[str, Any]) -> BenchMesh:
    vertices, faces = mesh["vertices"], mesh["faces"]
    used = np.unique(faces)
    return BenchMesh(
        name=name,
        vertices=vertices,
        faces=faces.astype(np.int32),
        n_referenced=int(used.size),
        bbox_diagonal=float(np.linalg.norm(np.ptp(vertices[used], axis=0))),
    )


def _warm_up_attribute_mesh() -> dict[str, Any]:
    """`bench.meshes.warm_up_mesh` with UVs and colours made up from the positions."""
    vertices, faces = warm_up_mesh()
    span = np.ptp(vertices, axis=0)
    normalised = (vertices - vertices.min(axis=0)) / np.where(span > 0, span, 1.0)
    return {
        "vertices": vertices,
        "faces": faces.astype(np.int64),
        "corner_uvs": normalised[:, :2][faces],
        "colors": normalised,
    }


def _result(vertices, faces, corner_uvs=None, colors=None) -> dict[str, Any]:
    """A simplification as the metrics take it, unreferenced vertices dropped."""
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    used = np.unique(faces)
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    return {
        "vertices": np.asarray(vertices, dtype=np.float64)[used],
        "faces": remap[faces],
        "corner_uvs": None if corner_uvs is None else np.asarray(corner_uvs, np.float64),
        "colors": None if colors is None else np.asarray(colors, np.float64)[used, :3],
    }


# --------------------------------------------------------------------------- peers


def _write_textured_obj(path: Path, mesh: dict[str, Any]) -> None:
    """An OBJ with one `vt` per face corner (what MeshLab's importer needs to give every
    wedge a texture index: UVs handed to `pymeshlab.Mesh` have none, and the texture
    filter refuses them as "inconsistent tex coordinates")."""
    faces = mesh["faces"].reshape(-1, 3) + 1
    corners = np.arange(1, faces.size + 1).reshape(-1, 3)
    lines = [f"v {x!r} {y!r} {z!r}" for x, y, z in np.asarray(mesh["vertices"]).tolist()]
    lines += [f"vt {u!r} {v!r}" for u, v in np.asarray(mesh["corner_uvs"]).reshape(-1, 2).tolist()]
    lines += [
        f"f {a}/{ta} {b}/{tb} {c}/{tc}"
        for (a, b, c), (ta, tb, tc) in zip(faces.tolist(), corners.tolist(), strict=True)
    ]
    path.write_text("\n".join(lines) + "\n", encoding="ascii")


def pymeshlab_with_texture(mesh: dict[str, Any], target_faces: int, options: dict[str, Any]):
    """PyMeshLab `meshing_decimation_quadric_edge_collapse_with_texture` on per-wedge
    (corner) UVs, to `target_faces`, with `options` (empty: the filter's defaults).

    The mesh goes in through a temporary OBJ file (`_write_textured_obj`); loaded so,
    spot.obj comes back with the same vertices, faces and UVs (float32 rounding). The
    timed call includes that write and load (a few ms on spot)."""
    import tempfile

    import pymeshlab

    mesh_set = pymeshlab.MeshSet()
    with tempfile.TemporaryDirectory(prefix="qem-appearance-") as folder:
        path = Path(folder) / "mesh.obj"
        _write_textured_obj(path, mesh)
        mesh_set.load_new_mesh(str(path))
    mesh_set.meshing_decimation_quadric_edge_collapse_with_texture(
        targetfacenum=int(target_faces), **options
    )
    out = mesh_set.current_mesh()
    faces = out.face_matrix()
    return _result(out.vertex_matrix(), faces, out.wedge_tex_coord_matrix().reshape(-1, 3, 2))


def pymeshlab_with_colors(mesh: dict[str, Any], target_faces: int, options: dict[str, Any]):
    """PyMeshLab `meshing_decimation_quadric_edge_collapse` on a mesh with vertex colours
    (MeshLab interpolates the colour of a collapsed pair), with `options`."""
    import pymeshlab

    colors = np.column_stack([mesh["colors"], np.ones(len(mesh["colors"]))])
    mesh_set = pymeshlab.MeshSet()
    mesh_set.add_mesh(
        pymeshlab.Mesh(
            vertex_matrix=mesh["vertices"],
            face_matrix=mesh["faces"].astype(np.int32),
            v_color_matrix=colors,
        )
    )
    mesh_set.meshing_decimation_quadric_edge_collapse(targetfacenum=int(target_faces), **options)
    out = mesh_set.current_mesh()
    return _result(out.vertex_matrix(), out.face_matrix(), colors=out.vertex_color_matrix())


def open3d_with_colors(mesh: dict[str, Any], target_faces: int, options: dict[str, Any]):
    """Open3D `simplify_quadric_decimation` with `vertex_colors` set (it keeps them,
    averaging the colours of a contracted pair); `options` unused."""
    import open3d

    o3d_mesh = open3d.geometry.TriangleMesh(
        open3d.utility.Vector3dVector(mesh["vertices"]),
        open3d.utility.Vector3iVector(mesh["faces"].astype(np.int32)),
    )
    o3d_mesh.vertex_colors = open3d.utility.Vector3dVector(mesh["colors"])
    out = o3d_mesh.simplify_quadric_decimation(target_number_of_triangles=int(target_faces))
    return _result(
        np.asarray(out.vertices), np.asarray(out.triangles), colors=np.asarray(out.vertex_colors)
    )


def unweld_by_uv(mesh: dict[str, Any]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """An indexed mesh with one vertex record per distinct (position index, UV) pair, as
    a GPU vertex buffer has it: seam vertices are duplicated with bit-identical positions.

    Returns (positions (r, 3) float32, uvs (r, 2) float32, indices (m, 3) uint32)."""
    uv32 = np.ascontiguousarray(mesh["corner_uvs"], dtype=np.float32).reshape(-1, 2)
    keys = np.column_stack(
        [mesh["faces"].reshape(-1).astype(np.int64), uv32.view(np.int32).astype(np.int64)]
    )
    unique_keys, first, inverse = np.unique(keys, axis=0, return_index=True, return_inverse=True)
    positions = np.asarray(mesh["vertices"], dtype=np.float32)[unique_keys[:, 0]]
    return positions, uv32[first], inverse.reshape(-1, 3).astype(np.uint32)


def _declare_simplify_with_attributes() -> None:
    """Give `meshopt_simplifyWithAttributes` its C prototype.

    The meshoptimizer Python package (0.2.30a0) declares argtypes for `meshopt_simplify`
    but not for this function, so ctypes refuses the float `target_error` ("Don't know
    how to convert parameter 13") and would pass the size_t counts as C ints. The
    prototype is meshoptimizer.h's (with vertex_lock, as the wrapper passes it)."""
    import ctypes

    from meshoptimizer import simplifier

    function = simplifier.lib.meshopt_simplifyWithAttributes
    if function.argtypes is not None:
        return
    uint_p, float_p = ctypes.POINTER(ctypes.c_uint), ctypes.POINTER(ctypes.c_float)
    size = ctypes.c_size_t
    function.argtypes = [
        uint_p, uint_p, size,  # destination, indices, index_count
        float_p, size, size,  # vertex_positions, vertex_count, positions stride
        float_p, size,  # vertex_attributes, attributes stride
        float_p, size,  # attribute_weights, attribute_count
        ctypes.POINTER(ctypes.c_ubyte),  # vertex_lock
        size, ctypes.c_float, ctypes.c_uint,  # target_index_count, target_error, options
        float_p,  # result_error
    ]  # fmt: skip
    function.restype = size


def meshoptimizer_with_attributes(mesh: dict[str, Any], target_faces: int, options: dict):
    """meshoptimizer `simplify_with_attributes` to 3 x target_faces indices, error bound
    lifted (as in bench.peers), on the vertex-record mesh: UVs (`unweld_by_uv`) or
    vertex colours as the attributes, each weighted `options["weight"]`.

    meshoptimizer finds UV seams itself: records with bit-identical positions are one
    vertex of the surface, so a seam edge only collapses along the seam and both sides
    move together (its documented seam handling; no vertex_lock is needed, and
    SIMPLIFY_LOCK_BORDER would only pin open borders, which spot has none of). It never
    moves a vertex: kept records keep their position, UV and colour."""
    import meshoptimizer

    _declare_simplify_with_attributes()
    if mesh["corner_uvs"] is not None:
        positions, attributes, indices = unweld_by_uv(mesh)
    else:
        positions = np.asarray(mesh["vertices"], dtype=np.float32)
        attributes = np.asarray(mesh["colors"], dtype=np.float32)
        indices = mesh["faces"].astype(np.uint32)
    weights = np.full(attributes.shape[1], float(options.get("weight", 1.0)), np.float32)
    flat = np.ascontiguousarray(indices).reshape(-1)
    destination = np.zeros(flat.size, dtype=np.uint32)
    count = meshoptimizer.simplify_with_attributes(
        destination,
        flat,
        np.ascontiguousarray(positions),
        np.ascontiguousarray(attributes),
        weights,
        target_index_count=3 * int(target_faces),
        target_error=_MESHOPTIMIZER_UNBOUNDED_ERROR,
        options=int(options.get("flags", 0)),
    )
    faces = destination[:count].reshape(-1, 3).astype(np.int64)
    if mesh["corner_uvs"] is not None:
        return _result(positions, faces, corner_uvs=attributes[faces])
    return _result(positions, faces, colors=attributes)


@dataclass(frozen=True)
class AttributePeer:
    """A peer that keeps an attribute: row name, adapter, its options, modules to
    import before timing. `adapter(mesh, target_faces, options) -> result dict`."""

    name: str
    adapter: Callable[[dict[str, Any], int, dict[str, Any]], dict[str, Any]]
    options: dict[str, Any] = field(default_factory=dict)
    modules: tuple[str, ...] = ()


# MeshLab's quality switches, as bench.peers.PYMESHLAB_QUALITY_OPTIONS (the texture
# filter has no preservetopology).
_PYMESHLAB_TEXTURE_QUALITY = {
    "preserveboundary": True,
    "preservenormal": True,
    "optimalplacement": True,
    "planarquadric": True,
}
_PYMESHLAB_COLOR_QUALITY = {**_PYMESHLAB_TEXTURE_QUALITY, "preservetopology": True}

# meshoptimizer's attribute weights, an order-of-magnitude sweep: with positions scaled to
# the mesh extent, UVs and colours in [0, 1], a weight of 1 lets an attribute error of 1
# cost like the whole extent; the best setting differs per mesh and fraction.
MESHOPTIMIZER_WEIGHTS = (1.0, 10.0, 100.0)


def _meshoptimizer_peers(attribute: str) -> tuple[AttributePeer, ...]:
    return tuple(
        AttributePeer(
            f"meshoptimizer_{attribute}_w{weight:g}",
            meshoptimizer_with_attributes,
            {"weight": weight},
            ("meshoptimizer",),
        )
        for weight in MESHOPTIMIZER_WEIGHTS
    )


TEXTURE_PEERS = (
    AttributePeer("pymeshlab_tex", pymeshlab_with_texture, {}, ("pymeshlab",)),
    AttributePeer(
        "pymeshlab_tex_quality",
        pymeshlab_with_texture,
        {**_PYMESHLAB_TEXTURE_QUALITY, "extratcoordw": 4.0},
        ("pymeshlab",),
    ),
    *_meshoptimizer_peers("uv"),
)
COLOR_PEERS = (
    AttributePeer("pymeshlab", pymeshlab_with_colors, {}, ("pymeshlab",)),
    AttributePeer(
        "pymeshlab_quality", pymeshlab_with_colors, _PYMESHLAB_COLOR_QUALITY, ("pymeshlab",)
    ),
    AttributePeer("open3d", open3d_with_colors, {}, ("open3d",)),
    *_meshoptimizer_peers("rgb"),
)


def warm_up_attribute_peer(adapter: Callable, options: dict[str, Any], attribute: str) -> None:
    """One untimed call of `adapter` on the tiny warm-up mesh with `attribute` ("uv" or
    "color") only."""
    mesh = _warm_up_attribute_mesh()
    if attribute == "uv":
        mesh["colors"] = None
    else:
        mesh["corner_uvs"] = None
    adapter(mesh, len(mesh["faces"]) // 2, options)


# --------------------------------------------------------------------------- qem-lod


def qem_attributes_unavailable() -> str | None:
    """None when qem_core has `build_mesh` and `ProgressiveMesh.lod_mesh`, else why not."""
    reason = qem_lod.qem_unavailable_reason()
    if reason is not None:
        return reason
    import qem_core

    if not callable(getattr(qem_core, "build_mesh", None)):
        return "qem_core.build_mesh does not exist yet"
    if not callable(getattr(qem_core.ProgressiveMesh, "lod_mesh", None)):
        return "qem_core.ProgressiveMesh.lod_mesh does not exist yet"
    return None


def _qem_mesh(mesh: dict[str, Any]):
    import qem_core

    attributes = {}
    if mesh["colors"] is not None:
        attributes["color"] = np.ascontiguousarray(mesh["colors"], dtype=np.float32)
    uvs = mesh["corner_uvs"]
    return qem_core.Mesh(
        vertices=np.ascontiguousarray(mesh["vertices"], dtype=np.float64),
        faces=np.ascontiguousarray(mesh["faces"], dtype=np.int32),
        vertex_attributes=attributes,
        corner_uvs=None if uvs is None else np.ascontiguousarray(uvs, dtype=np.float32),
    )


def build_qem_with_attributes(mesh: dict[str, Any], option_values: dict[str, Any]):
    """`qem_core.build_mesh` of the whole forest, attributes included (in the child)."""
    import qem_core

    options = qem_core.BuildOptions.from_mapping(option_values) if option_values else None
    return qem_core.build_mesh(_qem_mesh(mesh), options)


def warm_up_qem_with_attributes(option_values: dict[str, Any], attribute: str) -> None:
    """Build and extract the tiny warm-up mesh with `attribute` so numba has compiled."""
    mesh = _warm_up_attribute_mesh()
    if attribute == "uv":
        mesh["colors"] = None
    else:
        mesh["corner_uvs"] = None
    progressive_mesh = build_qem_with_attributes(mesh, option_values)
    progressive_mesh.lod_mesh(progressive_mesh.n_base)
    progressive_mesh.lod_mesh(progressive_mesh.n_full)


def extract_attribute_levels(progressive_mesh, vertex_counts: Sequence[int]) -> dict[str, Any]:
    """`lod_mesh(n)` for each n, timed: {"n_full", "n_base", "levels": {n: result dict
    + "seconds"}}."""
    levels = {}
    for n in sorted({int(count) for count in vertex_counts}):
        start = time.perf_counter()
        level = progressive_mesh.lod_mesh(n)
        seconds = time.perf_counter() - start
        color = level.vertex_attributes.get("color")
        levels[n] = {
            **_result(level.vertices, level.faces, level.corner_uvs, color),
            "seconds": seconds,
        }
    return {
        "n_full": int(progressive_mesh.n_full),
        "n_base": int(progressive_mesh.n_base),
        "levels": levels,
    }


# --------------------------------------------------------------------------- rows


@dataclass
class AppearanceRow:
    """One simplification scored. `vertices` = distinct referenced positions (the
    geometric vertex count; records may be more where seams are split), `faces` = faces.
    For qem-lod rows `best_peer` is the lowest-error peer with exactly this vertex count
    and `ratio` qem-lod's error over its (forward / symmetric for texture and colour);
    for peer rows the ratio is over the best peer of the same fraction."""

    part: str
    mesh: str
    fraction: float
    tool: str
    kind: str  # "peer" or "qem"
    target_vertices: int
    target_faces: int | None = None
    vertices: int | None = None
    records: int | None = None
    faces: int | None = None
    time_s: float | None = None
    status: str = "ok"
    forward_rms: float | None = None
    backward_rms: float | None = None
    symmetric_rms: float | None = None
    geometric_rms: float | None = None  # of the same samples, / bbox diagonal
    uv_outside: int | None = None
    uv_flipped: int | None = None
    uv_degenerate: int | None = None
    open_edges: int | None = None
    volume_change: float | None = None  # |dV| / V
    hausdorff: float | None = None
    rms: float | None = None
    best_peer: str | None = None
    forward_ratio: float | None = None
    symmetric_ratio: float | None = None
    rms_ratio_to_default: float | None = None  # volume part, qem variants

    @property
    def ok(self) -> bool:
        return self.status.startswith("ok")


def _failure_status(measured) -> str:
    return measured.status[:200]


def _score_attributes(
    row: AppearanceRow,
    original: dict[str, Any],
    result: dict[str, Any],
    texture: np.ndarray | None,
    samples: int,
    seed: int,
    diagonal: float,
) -> None:
    cracks = tm.seam_cracks(result["vertices"], result["faces"])
    row.vertices, row.records, row.faces = (
        cracks["positions"],
        cracks["records"],
        len(result["faces"]),
    )
    row.open_edges = cracks["open_edges"]
    if len(result["faces"]) == 0:
        row.status = "failed: no faces left"
        return
    if texture is not None:
        if result["corner_uvs"] is None:
            row.status = "failed: UVs dropped"
            return
        pair = (
            (original["vertices"], original["faces"], original["corner_uvs"]),
            (result["vertices"], result["faces"], result["corner_uvs"]),
        )
        error = tm.texture_error(*pair, texture, samples, seed)
        row.uv_outside = tm.uv_outside_count(result["corner_uvs"])
        row.uv_flipped, row.uv_degenerate = tm.uv_flipped_count(*pair)
    else:
        if result["colors"] is None:
            row.status = "failed: colours dropped"
            return
        error = tm.color_error(
            (original["vertices"], original["faces"], original["colors"]),
            (result["vertices"], result["faces"], result["colors"]),
            samples,
            seed,
        )
    row.forward_rms, row.backward_rms = error.forward_rms, error.backward_rms
    row.symmetric_rms = error.symmetric_rms
    row.geometric_rms = error.geometric_rms / diagonal


def _compare(rows: Sequence[AppearanceRow]) -> None:
    """Fill best_peer and the ratios (see AppearanceRow)."""
    peers = [r for r in rows if r.kind == "peer" and r.ok and r.symmetric_rms is not None]
    for row in rows:
        if not row.ok or row.symmetric_rms is None:
            continue
        if row.kind == "peer":
            rivals = [p for p in peers if p.fraction == row.fraction]
        else:
            rivals = [p for p in peers if p.vertices == row.vertices]
        if not rivals:
            continue
        best_forward = min(rivals, key=lambda p: p.forward_rms)
        best_symmetric = min(rivals, key=lambda p: p.symmetric_rms)
        row.best_peer = best_symmetric.tool
        if best_forward.forward_rms > 0:
            row.forward_ratio = row.forward_rms / best_forward.forward_rms
        if best_symmetric.symmetric_rms > 0:
            row.symmetric_ratio = row.symmetric_rms / best_symmetric.symmetric_rms


def run_attribute_part(
    part: str,
    mesh_name: str,
    original: dict[str, Any],
    texture: np.ndarray | None,
    peers: Sequence[AttributePeer],
    fractions: Sequence[float],
    variants: Sequence[dict[str, Any]],
    samples: int,
    seed: int,
    qem_note: str | None,
    timeout: float | None,
) -> dict[str, Any]:
    """Peers and qem-lod variants on one mesh with UVs (part "texture") or colours."""
    attribute = "uv" if part == "texture" else "color"
    bench_mesh = _bench_mesh(mesh_name, original)
    rows: list[AppearanceRow] = []
    for fraction in fractions:
        target_vertices, target_faces = target_counts(bench_mesh, fraction)
        for peer in peers:
            row = AppearanceRow(
                part, mesh_name, fraction, peer.name, "peer", target_vertices, target_faces
            )
            measured = measure_or_fail(
                peer.adapter,
                (original, target_faces, peer.options),
                preload=peer.modules,
                before=warm_up_attribute_peer,
                before_args=(peer.adapter, peer.options, attribute),
                timeout_s=timeout,
            )
            if measured.ok:
                row.time_s = measured.median_s
                _score_attributes(
                    row, original, measured.result, texture, samples, seed, bench_mesh.bbox_diagonal
                )
            else:
                row.status = _failure_status(measured)
            progress(
                f"{part} {mesh_name} {fraction:g} {peer.name}: {row.vertices} V, "
                f"sym RMS {format_sci(row.symmetric_rms)}, {row.status}"
            )
            rows.append(row)
    builds = []
    if qem_note is None:
        for values in variants:
            build, qem_rows = _run_qem_attribute_variant(
                part,
                mesh_name,
                original,
                texture,
                values,
                rows,
                samples,
                seed,
                bench_mesh,
                attribute,
                timeout,
            )
            builds.append(build)
            rows += qem_rows
    _compare(rows)
    order = {fraction: index for index, fraction in enumerate(fractions)}
    rows.sort(key=lambda r: (order[r.fraction], r.kind == "qem", r.vertices or 0))
    return {
        "mesh": mesh_name,
        "input": {
            "vertices": bench_mesh.n_referenced,
            "faces": bench_mesh.n_faces,
            "bbox_diagonal": bench_mesh.bbox_diagonal,
            **(
                {
                    "uv_outside": tm.uv_outside_count(original["corner_uvs"]),
                    "uv_negative_faces": int(
                        np.count_nonzero(tm.uv_signed_areas(original["corner_uvs"]) < 0)
                    ),
                    "uv_records": int(len(unweld_by_uv(original)[0])),
                }
                if part == "texture"
                else {}
            ),
        },
        "qem_builds": builds,
        "rows": [asdict(row) for row in rows],
    }


def _run_qem_attribute_variant(
    part,
    mesh_name,
    original,
    texture,
    values,
    peer_rows,
    samples,
    seed,
    bench_mesh,
    attribute,
    timeout,
):
    label = qem_lod.variant_label(values)
    build: dict[str, Any] = {"tool": label, "options": values, "status": "ok"}
    counts_by_fraction: dict[float, set[int]] = {}
    for row in peer_rows:
        counts_by_fraction.setdefault(row.fraction, set())
        if row.ok and row.vertices:
            counts_by_fraction[row.fraction].add(row.vertices)
    for row in peer_rows:
        if not counts_by_fraction[row.fraction]:
            counts_by_fraction[row.fraction].add(row.target_vertices)
    wanted = sorted({n for counts in counts_by_fraction.values() for n in counts})
    measured = measure_or_fail(
        build_qem_with_attributes,
        (original, values),
        preload=("qem_core",),
        before=warm_up_qem_with_attributes,
        before_args=(values, attribute),
        then=extract_attribute_levels,
        then_args=(wanted,),
        timeout_s=timeout,
    )
    if not measured.ok:
        build["status"] = _failure_status(measured)
        progress(f"{part} {mesh_name} {label}: build {build['status']}")
        return build, []
    extracted = measured.result
    build.update(time_s=measured.median_s, n_full=extracted["n_full"], n_base=extracted["n_base"])
    progress(f"{part} {mesh_name} {label}: build {format_ms(measured.median_s)} ms")
    rows = []
    for fraction, counts in counts_by_fraction.items():
        for n in sorted(counts):
            level = extracted["levels"][n]
            row = AppearanceRow(part, mesh_name, fraction, label, "qem", n, time_s=level["seconds"])
            _score_attributes(
                row, original, level, texture, samples, seed, bench_mesh.bbox_diagonal
            )
            if row.ok and row.vertices != n:
                row.status = f"ok; asked {n} V, served {row.vertices}"
            progress(
                f"{part} {mesh_name} {fraction:g} {label} @{n}: sym RMS "
                f"{format_sci(row.symmetric_rms)}, {row.status}"
            )
            rows.append(row)
    return build, rows


# --------------------------------------------------------------------------- volume


def _score_volume(row: AppearanceRow, mesh: BenchMesh, vertices, faces, volume: float) -> None:
    vertices, faces = compact_referenced(vertices, faces)
    row.vertices, row.records, row.faces = len(vertices), len(vertices), len(faces)
    if len(faces) == 0:
        row.status = "failed: no faces left"
        return
    topology = count_topology(faces)
    row.open_edges = topology.boundary_edges
    row.volume_change = abs(tm.signed_volume(vertices, faces) - volume) / abs(volume)
    distance = measure_surface_distance(mesh.vertices, mesh.faces, vertices, faces)
    row.hausdorff, row.rms = distance.hausdorff, distance.rms
    notes = []
    if topology.boundary_edges:
        notes.append(f"{topology.boundary_edges} open edges (volume not closed)")
    if topology.non_manifold_edges:
        notes.append(f"{topology.non_manifold_edges} non-manifold edges")
    row.status = "; ".join(["ok", *notes])


def run_volume_mesh(
    mesh: BenchMesh,
    fraction: float,
    variants: Sequence[dict[str, Any]],
    qem_note: str | None,
    timeout: float | None,
) -> dict[str, Any]:
    """Peers and qem-lod variants on one closed mesh: |dV|/V, Hausdorff, RMS."""
    from .peers import warm_up_peer

    volume = tm.signed_volume(mesh.vertices, mesh.faces)
    target_vertices, target_faces = target_counts(mesh, fraction)
    rows: list[AppearanceRow] = []
    for name in VOLUME_PEERS:
        peer = PEERS[name]
        row = AppearanceRow(
            "volume", mesh.name, fraction, name, "peer", target_vertices, target_faces
        )
        measured = measure_or_fail(
            peer.simplify,
            (mesh.vertices, mesh.faces, target_faces),
            preload=peer.modules,
            before=warm_up_peer,
            before_args=(peer.simplify,),
            timeout_s=timeout,
        )
        if measured.ok:
            row.time_s = measured.median_s
            _score_volume(row, mesh, *measured.result, volume)
        else:
            row.status = _failure_status(measured)
        progress(
            f"volume {mesh.name} {name}: |dV|/V {format_sci(row.volume_change)}, "
            f"RMS {format_sci(row.rms)}, {row.status}"
        )
        rows.append(row)
    builds = []
    if qem_note is None:
        for values in variants:
            label = qem_lod.variant_label(values)
            build: dict[str, Any] = {"tool": label, "options": values, "status": "ok"}
            measured = measure_or_fail(
                qem_lod.build_progressive_mesh,
                (mesh.vertices, mesh.faces, values),
                preload=("qem_core",),
                before=qem_lod.warm_up_build,
                before_args=(values,),
                then=qem_lod.extract_levels,
                then_args=([target_vertices],),
                timeout_s=timeout,
            )
            row = AppearanceRow("volume", mesh.name, fraction, label, "qem", target_vertices)
            if measured.ok:
                build.update(time_s=measured.median_s, n_base=measured.result["n_base"])
                level = measured.result["levels"][target_vertices]
                row.time_s = level["seconds"]
                _score_volume(row, mesh, level["vertices"], level["faces"], volume)
            else:
                build["status"] = row.status = _failure_status(measured)
            progress(
                f"volume {mesh.name} {label}: |dV|/V {format_sci(row.volume_change)}, "
                f"RMS {format_sci(row.rms)}, {row.status}"
            )
            builds.append(build)
            rows.append(row)
    default = next((r for r in rows if r.kind == "qem" and r.tool == "qem-lod" and r.ok), None)
    for row in rows:
        if row.kind == "qem" and row.ok and default is not None and default.rms:
            row.rms_ratio_to_default = row.rms / default.rms
    return {
        "mesh": mesh.name,
        "input": {
            "vertices": mesh.n_referenced,
            "faces": mesh.n_faces,
            "bbox_diagonal": mesh.bbox_diagonal,
            "volume": volume,
            "open_edges": count_topology(mesh.faces).boundary_edges,
        },
        "qem_builds": builds,
        "rows": [asdict(row) for row in rows],
    }


# --------------------------------------------------------------------------- report


def _count(value: int | None) -> str:
    return "-" if value is None else str(value)


def _attribute_table(rows: Sequence[AppearanceRow], texture: bool) -> list[str]:
    headers = ["fraction", "tool", "V", "F", "fwd RMS", "sym RMS", "fwd / best", "sym / best"]
    if texture:
        headers += ["records", "UV out", "UV flipped", "open edges"]
    headers += ["geom RMS", "time ms", "status"]
    body = []
    for r in rows:
        best = f" ({r.best_peer})" if r.kind == "qem" and r.best_peer else ""
        line = [
            f"{r.fraction:g}",
            r.tool,
            _count(r.vertices),
            _count(r.faces),
            format_sci(r.forward_rms),
            format_sci(r.symmetric_rms),
            format_ratio(r.forward_ratio),
            format_ratio(r.symmetric_ratio) + best,
        ]
        if texture:
            line += [
                _count(r.records),
                _count(r.uv_outside),
                "-" if r.uv_flipped is None else f"{r.uv_flipped} ({r.uv_degenerate})",
                _count(r.open_edges),
            ]
        line += [format_sci(r.geometric_rms), format_ms(r.time_s), r.status]
        body.append(line)
    numeric = [True, False, *[True] * (len(headers) - 3), False]
    numeric[6] = numeric[7] = False
    return markdown_table(headers, body, numeric)


def _volume_table(rows: Sequence[AppearanceRow]) -> list[str]:
    headers = [
        "tool",
        "V",
        "F",
        "abs(dV)/V",
        "Hausdorff",
        "RMS",
        "RMS / qem default",
        "time ms",
        "status",
    ]
    body = [
        [
            r.tool,
            _count(r.vertices),
            _count(r.faces),
            format_sci(r.volume_change),
            format_sci(r.hausdorff),
            format_sci(r.rms),
            format_ratio(r.rms_ratio_to_default),
            format_ms(r.time_s),
            r.status,
        ]
        for r in rows
    ]
    return markdown_table(headers, body, [False, True, True, True, True, True, True, True, False])


def _rows(entry: dict[str, Any]) -> list[AppearanceRow]:
    return [AppearanceRow(**row) for row in entry["rows"]]


def _builds_lines(entry: dict[str, Any]) -> list[str]:
    lines = []
    for build in entry.get("qem_builds", []):
        if build["status"].startswith("ok"):
            base = f", n_base {build['n_base']}" if "n_base" in build else ""
            lines.append(
                f"- `{build['tool']}`: whole-forest build {format_ms(build.get('time_s'))} ms "
                f"(after a JIT warm-up){base}."
            )
        else:
            lines.append(f"- `{build['tool']}`: {build['status']}")
    return lines


def _attribute_verdict(rows: Sequence[AppearanceRow], fractions: Sequence[float]) -> list[str]:
    lines = []
    for tool in sorted({r.tool for r in rows if r.kind == "qem"}):
        compared = [r for r in rows if r.tool == tool and r.symmetric_ratio is not None]
        if fractions:
            compared = [r for r in compared if r.fraction in fractions]
        if not compared:
            continue
        wins = sum(r.symmetric_ratio <= 1.0 for r in compared)
        fwins = sum(r.forward_ratio is not None and r.forward_ratio <= 1.0 for r in compared)
        worst = max(r.symmetric_ratio for r in compared)
        lines.append(
            f"- `{tool}`: symmetric error <= best peer at {wins} of {len(compared)} vertex "
            f"counts, forward at {fwins} of {len(compared)}; worst symmetric ratio "
            f"{format_ratio(worst)}."
        )
    return lines


def _summary_lines(parts: dict[str, Any]) -> list[str]:
    """The issue's three targets, checked on the stored rows of default qem-lod (texture,
    colour) and of qem-lod[preserve_volume=True] (volume)."""
    lines = ["## Issue 4 targets", ""]
    texture = parts.get("texture")
    if texture:
        rows = [r for r in _rows(texture["mesh"]) if r.tool == "qem-lod" and r.ok]
        compared = [r for r in rows if r.symmetric_ratio is not None]
        shown = "; ".join(
            f"{r.fraction:g} ({r.vertices} V): fwd {format_ratio(r.forward_ratio)}, "
            f"sym {format_ratio(r.symmetric_ratio)}"
            for r in compared
        )
        met = bool(compared) and all(
            r.symmetric_ratio <= 1 and (r.forward_ratio or 0) <= 1 for r in compared
        )
        lines.append(
            "- Texture error <= best peer at the same vertex counts (default qem-lod, "
            f"ratio to the best peer): {shown or 'no qem-lod rows'}: "
            f"{'met' if met else 'not met'}."
        )
    color = parts.get("color")
    if color:
        rows = [
            r
            for r in _rows(color["mesh"])
            if r.tool == "qem-lod" and r.ok and r.fraction == 0.1 and r.symmetric_ratio
        ]
        shown = "; ".join(
            f"{r.vertices} V: fwd {format_ratio(r.forward_ratio)}, sym "
            f"{format_ratio(r.symmetric_ratio)} ({r.best_peer})"
            for r in rows
        )
        met = bool(rows) and all(
            r.symmetric_ratio <= 1 and (r.forward_ratio or 0) <= 1 for r in rows
        )
        lines.append(
            "- Colour RMS at 10 % <= best peer that keeps colours (default qem-lod): "
            f"{shown or 'no qem-lod rows'}: {'met' if met else 'not met'}."
        )
    volume = parts.get("volume")
    if volume:
        for mesh in volume["meshes"]:
            rows = [r for r in _rows(mesh) if r.kind == "qem" and r.tool != "qem-lod" and r.ok]
            for r in rows:
                met = (
                    r.volume_change is not None
                    and r.volume_change <= VOLUME_TOLERANCE
                    and r.rms_ratio_to_default is not None
                    and r.rms_ratio_to_default <= VOLUME_RMS_LIMIT
                )
                lines.append(
                    f"- Volume on {mesh['mesh']} at {r.fraction:g} ({r.vertices} V), "
                    f"`{r.tool}`: abs(dV)/V {format_sci(r.volume_change)} (<= "
                    f"{VOLUME_TOLERANCE:g}), RMS {format_ratio(r.rms_ratio_to_default)} x "
                    f"default (<= {VOLUME_RMS_LIMIT:g}): {'met' if met else 'not met'}."
                )
            if not rows:
                lines.append(f"- Volume on {mesh['mesh']}: no preserve_volume row.")
    return [*lines, ""] if len(lines) > 2 else []


def write_report(path: Path, results: dict[str, Any]) -> None:
    """appearance.md from the JSON results (every part stored)."""
    lines = ["# Appearance attributes and volume preservation: qem-lod and peers (issue 4)", ""]
    lines += [*machine_header_lines(), ""]
    parts = results.get("parts", {})
    lines += _summary_lines(parts)
    for part in PARTS:
        entry = parts.get(part)
        if not entry:
            continue
        record = entry["record"]
        lines += [
            f"## {part}",
            "",
            f"Measured {record['measured_at']} on code {record['source']}; load average "
            f"(1 / 5 / 15 min) {record['load_average']['start']} at the start, "
            f"{record['load_average']['end']} at the end. Command: `{record['command']}`.",
            "",
        ]
        if record.get("qem_note"):
            lines += [f"qem-lod: {record['qem_note']}", ""]
        if part in ("texture", "color"):
            lines += _attribute_section(part, entry)
        else:
            lines += _volume_section(entry)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(lines), encoding="utf-8")


def _attribute_section(part: str, entry: dict[str, Any]) -> list[str]:
    mesh = entry["mesh"]
    info = mesh["input"]
    settings = entry["settings"]
    rows = _rows(mesh)
    texture = part == "texture"
    lines = []
    if texture:
        lines += [
            f"`{mesh['mesh']}` with `{TEXTURE_IMAGE}`: {info['vertices']} positions, "
            f"{info['faces']} faces, {info['uv_records']} (position, UV) vertex records; "
            f"the original already has {info['uv_outside']} corners with UVs outside [0, 1] "
            f"and {info['uv_negative_faces']} faces with clockwise UV triangles (mirrored "
            "parts of the atlas).",
            "",
            "Texture-space error: RMS over samples and RGB channels (0..1) of the difference "
            "between the texture colour at the original's interpolated UV and at the "
            "simplified mesh's interpolated corner UVs, at the closest point of the other "
            f"surface; {settings['samples']} area-uniform samples per direction, seed "
            f"{settings['seed']}; bilinear texel lookup, clamped to the edge. fwd = samples "
            "on the original, sym = both directions together. `/ best`: over the lowest "
            "peer at the same fraction (peer rows) or with exactly the same V (qem-lod "
            "rows, peer named). V = distinct positions; records = vertex records (a "
            "meshoptimizer output keeps seam vertices split). UV out: corners outside [0, "
            "1]; UV flipped: faces whose UV triangle turns the other way than the original "
            "face nearest to their centroid (zero-area in parentheses); open edges: edges "
            "with one face once coincident records are welded (spot is closed, so any is "
            "a crack). geom RMS: closest-point distances of the same samples / bbox "
            "diagonal (context only; the geometric figures of record are in quality-*.md). "
            "time: the simplification call, one run after a warm-up, in a child process; "
            "qem-lod rows: the `lod_mesh(n)` extraction.",
            "",
        ]
    else:
        lines += [
            f"`{mesh['mesh']}`: {info['vertices']} referenced vertices with RGB colours "
            f"(unreferenced ones dropped for every tool), {info['faces']} faces.",
            "",
            "Colour error: RMS over samples and RGB channels (0..1) of the difference "
            "between the original's interpolated vertex colour and the simplified mesh's "
            f"at the closest point of the other surface; {settings['samples']} samples per "
            f"direction, seed {settings['seed']}. Columns as in the texture part. PyMeshLab "
            "interpolates the colours of a collapsed pair (most of its output colours are "
            "not input colours), Open3D averages them, meshoptimizer keeps the vertices it "
            "does not remove (colours unchanged) and weighs the colours in its error.",
            "",
        ]
    lines += _builds_lines(mesh)
    lines += _attribute_verdict(rows, ())
    lines += ["", *_attribute_table(rows, texture), ""]
    return lines


def _volume_section(entry: dict[str, Any]) -> list[str]:
    lines = [
        f"Each mesh at {entry['settings']['fraction']:g} of its vertices. abs(dV)/V: change of "
        "the enclosed volume (sum of signed tetrahedra) over the original's. Hausdorff and "
        "RMS: symmetric, / bbox diagonal, PyMeshLab sampling in a fresh process "
        f"({DEFAULT_SAMPLES} face samples per direction), as in quality-*.md. Issue 4: "
        f"preserve_volume=True must keep abs(dV)/V <= {VOLUME_TOLERANCE:g} with RMS <= "
        f"{VOLUME_RMS_LIMIT:g} x the default (unconstrained) qem-lod.",
        "",
    ]
    for mesh in entry["meshes"]:
        info = mesh["input"]
        rows = _rows(mesh)
        lines += [
            f"### {mesh['mesh']}",
            "",
            f"{info['vertices']} vertices, {info['faces']} faces, volume {info['volume']:.6g}.",
            "",
            *_builds_lines(mesh),
        ]
        for row in rows:
            if row.kind == "qem" and row.tool != "qem-lod" and row.ok:
                meets = (
                    row.volume_change is not None
                    and row.volume_change <= VOLUME_TOLERANCE
                    and row.rms_ratio_to_default is not None
                    and row.rms_ratio_to_default <= VOLUME_RMS_LIMIT
                )
                lines.append(
                    f"- `{row.tool}`: abs(dV)/V {format_sci(row.volume_change)}, RMS "
                    f"{format_ratio(row.rms_ratio_to_default)} x default: "
                    f"{'meets' if meets else 'does not meet'} the issue's bound."
                )
        lines += ["", *_volume_table(rows), ""]
    return lines


# --------------------------------------------------------------------------- main


def _parse_args(argv: Sequence[str] | None):
    parser = bench_parser("python -m bench.appearance", __doc__)
    parser.add_argument("--parts", nargs="+", choices=PARTS, default=list(PARTS))
    parser.add_argument(
        "--texture-fractions", nargs="+", type=float, default=list(DEFAULT_FRACTIONS)
    )
    parser.add_argument("--color-fractions", nargs="+", type=float, default=list(DEFAULT_FRACTIONS))
    parser.add_argument("--volume-meshes", nargs="+", default=list(VOLUME_MESHES))
    parser.add_argument("--volume-fraction", type=float, default=VOLUME_FRACTION)
    parser.add_argument(
        "--samples",
        type=int,
        default=DEFAULT_SAMPLES,
        help="samples per direction for the texture and colour errors",
    )
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument(
        "--qem-variant",
        action="append",
        default=[],
        metavar="NAME=VALUE[,NAME=VALUE]",
        help="qem-lod variant of the texture and colour parts ('default' for the "
        "defaults); repeatable; replaces the built-in list",
    )
    parser.add_argument(
        "--volume-variant",
        action="append",
        default=[],
        metavar="NAME=VALUE[,NAME=VALUE]",
        help="qem-lod variant of the volume part; replaces 'default' and 'preserve_volume=true'",
    )
    parser.add_argument("--no-qem", action="store_true", help="peers only")
    parser.add_argument(
        "--report-only",
        action="store_true",
        help="rewrite appearance.md from appearance.json, measure nothing",
    )
    args = parser.parse_args(argv)

    def variants(texts: Sequence[str], fallback):
        if not texts:
            return [dict(values) for values in fallback]
        parsed = []
        for text in texts:
            is_default = text.strip().lower() == "default"
            parsed.append({} if is_default else qem_lod.parse_option_assignments([text]))
        return parsed

    try:
        args.variants = variants(args.qem_variant, DEFAULT_QEM_VARIANTS)
        args.volume_variants = variants(args.volume_variant, VOLUME_QEM_VARIANTS)
    except ValueError as error:
        parser.error(str(error))
    return args


def _command(argv: Sequence[str] | None) -> str:
    arguments = sys.argv[1:] if argv is None else list(argv)
    return " ".join(["python -m bench.appearance", *arguments])


def main(argv: Sequence[str] | None = None) -> int:
    args = _parse_args(argv)
    qem_note = "skipped (--no-qem)" if args.no_qem else qem_attributes_unavailable()
    volume_note = "skipped (--no-qem)" if args.no_qem else qem_lod.qem_unavailable_reason()
    if qem_note:
        progress(f"qem-lod attributes: {qem_note}")
    json_path = args.out_dir / "appearance.json"
    if args.report_only:
        write_report(args.out_dir / "appearance.md", read_json(json_path))
        return 0
    for part in args.parts:
        record = {
            "measured_at": now(),
            "source": source_revision(),
            "command": _command(argv),
            "load_average": {"start": load_average()},
            "qem_note": volume_note if part == "volume" else qem_note,
        }
        if part == "texture":
            original = load_textured_obj(args.mesh_dir / TEXTURE_MESH)
            texture = tm.read_texture(args.mesh_dir / TEXTURE_IMAGE)
            entry = {
                "settings": {
                    "fractions": args.texture_fractions,
                    "samples": args.samples,
                    "seed": args.seed,
                },
                "mesh": run_attribute_part(
                    part,
                    TEXTURE_MESH,
                    original,
                    texture,
                    TEXTURE_PEERS,
                    args.texture_fractions,
                    args.variants,
                    args.samples,
                    args.seed,
                    qem_note,
                    args.timeout,
                ),
            }
        elif part == "color":
            original = load_colored_ply(args.mesh_dir / COLOR_MESH)
            entry = {
                "settings": {
                    "fractions": args.color_fractions,
                    "samples": args.samples,
                    "seed": args.seed,
                },
                "mesh": run_attribute_part(
                    part,
                    COLOR_MESH,
                    original,
                    None,
                    COLOR_PEERS,
                    args.color_fractions,
                    args.variants,
                    args.samples,
                    args.seed,
                    qem_note,
                    args.timeout,
                ),
            }
        else:
            entry = {
                "settings": {"fraction": args.volume_fraction, "samples": DEFAULT_SAMPLES},
                "meshes": [
                    run_volume_mesh(
                        load_bench_mesh(args.mesh_dir / name),
                        args.volume_fraction,
                        args.volume_variants,
                        volume_note,
                        args.timeout,
                    )
                    for name in args.volume_meshes
                ],
            }
        record["load_average"]["end"] = load_average()
        entry["record"] = record
        results = read_json(json_path)
        results.setdefault("parts", {})[part] = entry
        write_json(json_path, {"machine": describe_machine(), "parts": results["parts"]})
        write_report(args.out_dir / "appearance.md", results)
        progress(f"wrote {args.out_dir / 'appearance.md'} ({part})")
    return 0


if __name__ == "__main__":
    # Run from the importable module, not __main__: the child processes import the
    # adapters by their module name.
    from bench.appearance import main as _main

    sys.exit(_main())

"""The Python driver of the greedy contraction: validates, sets up flat arrays, runs the
numba loop in chunks (reporting progress), and hands back the full contraction record.

References: Garland and Heckbert, "Surface simplification using quadric error metrics"
(1997); Edelsbrunner, "Geometry and Topology for Mesh Generation" (2001), III.12.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from ._kernels.adjacency import compact, make_face_lists
from ._kernels.contract import (
    N_PARAMS,
    PARAM_COS_STEP_TURN,
    PARAM_EXACT,
    PARAM_PRESERVE_TOPOLOGY,
    PARAM_RANK_TOLERANCE,
    STATUS_EXHAUSTED,
    STATUS_NEED_PAIR_POOL_SPACE,
    STATUS_NEED_POOL_SPACE,
    STATUS_NEED_RELABEL_SPACE,
    STATUS_STEPS_DONE,
    Complex,
    Record,
    run_contractions,
)
from ._kernels.heap import make_heap
from ._kernels.link import make_neighbourhood, restart_generations
from ._kernels.pairs import candidate_pairs, make_pairs
from ._kernels.quadrics import QUADRIC_SIZE, fill_face_quadrics
from ._kernels.runs import reverse_runs
from ._kernels.setup import fill_border_quadrics, fill_heap, sum_quadrics
from .options import ERROR_MODE_CODES, WEIGHTING_CODES, BuildOptions
from .prepare import MeshEdges, prepare_mesh_and_edges, unique_edges
from .progressive import ProgressiveMesh

__all__ = [
    "ContractionRun",
    "assemble_progressive_mesh",
    "build",
    "contract_greedily",
    "unique_edges",
]

# A direction of the contraction quadric whose eigenvalue is below this fraction of the
# largest is treated as flat (truncated pseudo-inverse, see _kernels/placement.py).
RANK_TOLERANCE = 1e-3
CHUNK_CONTRACTIONS = 16384

ProgressCallback = Callable[[float], None]


class ContractionRun(NamedTuple):
    """What the greedy loop leaves: the record and the final complex."""

    record: Record
    complex: Complex
    n_contractions: int


def _kernel_params(options: BuildOptions) -> np.ndarray:
    params = np.zeros(N_PARAMS)
    params[PARAM_RANK_TOLERANCE] = RANK_TOLERANCE
    params[PARAM_COS_STEP_TURN] = np.cos(np.radians(options.max_face_turn_deg))
    params[PARAM_EXACT] = float(ERROR_MODE_CODES[options.error_mode])
    params[PARAM_PRESERVE_TOPOLOGY] = float(options.preserve_topology)
    return params


def _initial_complex(vertices: np.ndarray, faces: np.ndarray, options: BuildOptions,
                     mesh_edges: MeshEdges):
    n, m = vertices.shape[0], faces.shape[0]
    weighting = WEIGHTING_CODES[options.weighting]
    exact = options.error_mode == "exact"
    # Only the exact mode reads face quadrics again (merging edge quadrics).
    face_quadrics = np.zeros((m if exact else 0, QUADRIC_SIZE))
    face_normals = np.zeros((m, 3))
    vertex_quadrics = np.zeros((n, QUADRIC_SIZE))
    fill_face_quadrics(vertices, faces, weighting, face_quadrics, face_normals,
                       vertex_quadrics)

    edges, face_edge, edge_face_count, edge_side = mesh_edges
    border = np.flatnonzero(edge_face_count == 1)
    # The one face of each border edge, and the side's direction in that face.
    border_sides = edge_side[border]
    border_faces = border_sides // 3
    border_from = faces[border_faces, border_sides % 3]
    border_to = faces[border_faces, (border_sides + 1) % 3]
    border_edges = np.stack([border_from, border_to], axis=1).astype(np.int32)
    border_quadrics = np.zeros((border.size, QUADRIC_SIZE))
    fill_border_quadrics(vertices, border_edges, border_faces, face_normals, weighting,
                         float(options.boundary_weight), border_quadrics)

    edge_quadrics = np.zeros((edges.shape[0] if exact else 0, QUADRIC_SIZE))
    sum_quadrics(faces, face_quadrics, face_edge, border, border_edges, border_quadrics,
                 vertex_quadrics, edge_quadrics, exact)
    cx = Complex(
        vertices=np.array(vertices, np.float64, copy=True),
        vertex_quadrics=vertex_quadrics,
        vertex_alive=(np.bincount(faces.reshape(-1), minlength=n) > 0).astype(np.uint8),
        vertex_refused=np.zeros(n, np.uint8),
        faces=np.array(faces, np.int32, copy=True),
        face_alive=np.ones(m, np.uint8),
        face_normals=face_normals,
        face_quadrics=face_quadrics,
        face_edge=face_edge,
        edge_quadrics=edge_quadrics,
    )
    return cx, edges


def _make_record(n: int, m: int) -> Record:
    return Record(
        a=np.full(n, -1, np.int32),
        b=np.full(n, -1, np.int32),
        position_a=np.zeros((n, 3)),
        position_b=np.zeros((n, 3)),
        cost=np.zeros(n),
        killed_end=np.zeros(n, np.int64),
        killed=np.full(m, -1, np.int32),
        relabel_end=np.zeros(n, np.int64),
        relabel=np.full(max(8 * n, 64), -1, np.int32),
        counts=np.zeros(3, np.int64),
    )


def _grown(array: np.ndarray, fill) -> np.ndarray:
    bigger = np.full((2 * array.shape[0],) + array.shape[1:], fill, array.dtype)
    bigger[: array.shape[0]] = array
    return bigger


def contract_greedily(
    vertices: np.ndarray,
    faces: np.ndarray,
    options: BuildOptions,
    progress: ProgressCallback | None = None,
    max_contractions: int | None = None,
    mesh_edges: MeshEdges | None = None,
) -> ContractionRun:
    """Contract edges (and, with ``options.pair_threshold``, near vertex pairs) greedily
    by quadric error until nothing valid is left.

    vertices : (n, 3) float64, faces : (m, 3) int32, already prepared (every vertex
    referenced, no degenerate or duplicate face). ``max_contractions`` stops early (the
    tests use it to compare a level of detail with the greedy run stopped there).
    ``mesh_edges``: the edges of ``faces`` if already found (`prepare_mesh_and_edges`).
    """
    n, m = vertices.shape[0], faces.shape[0]
    if mesh_edges is None:
        mesh_edges = unique_edges(faces, n)
    cx, edges = _initial_complex(vertices, faces, options, mesh_edges)
    params = _kernel_params(options)
    lists = make_face_lists(cx.faces, n, capacity=6 * m + 1024)
    pairs = make_pairs(_pairs_for(vertices, edges, options.pair_threshold), n, edges.shape[0])
    hood = make_neighbourhood(n)
    # Candidates: the edges, then the pairs; their ids are the heap's ids.
    candidates = np.concatenate([edges, pairs.ends]) if pairs.ends.size else edges
    heap = make_heap(candidates.shape[0])
    fill_heap(cx.vertices, cx.vertex_quadrics, cx.edge_quadrics, candidates,
              options.error_mode == "exact", RANK_TOLERANCE, heap.entries, heap.position,
              heap.size)
    record = _make_record(n, m)
    budget = n if max_contractions is None else max(0, int(max_contractions))
    done = 0
    while done < budget:
        restart_generations(hood)
        status, steps = run_contractions(
            cx, lists, pairs, hood, heap, record, params,
            min(CHUNK_CONTRACTIONS, budget - done),
        )
        done += steps
        if status == STATUS_EXHAUSTED:
            break
        if status == STATUS_NEED_RELABEL_SPACE:
            record = record._replace(relabel=_grown(record.relabel, -1))
        elif status == STATUS_NEED_POOL_SPACE:
            compact(lists.start, lists.count, lists.pool, lists.used, cx.vertex_alive)
            lists = lists._replace(pool=_grown(lists.pool, -1))
        elif status == STATUS_NEED_PAIR_POOL_SPACE:
            compact(pairs.start, pairs.count, pairs.pool, pairs.used, cx.vertex_alive)
            pairs = pairs._replace(pool=_grown(pairs.pool, -1))
        else:
            assert status == STATUS_STEPS_DONE, status
        if progress is not None:
            progress(min(1.0, done / max(1, n - 4)))
    return ContractionRun(record, cx, done)


def _pairs_for(vertices: np.ndarray, edges: np.ndarray, pair_threshold: float) -> np.ndarray:
    """Garland's candidate pairs for ``BuildOptions.pair_threshold`` (a fraction of the
    bounding-box diagonal); (0, 2) when it is 0."""
    if pair_threshold <= 0.0:
        return np.zeros((0, 2), np.int32)
    diagonal = float(np.linalg.norm(vertices.max(axis=0) - vertices.min(axis=0)))
    return candidate_pairs(vertices, edges, pair_threshold * diagonal)


def assemble_progressive_mesh(run: ContractionRun, metadata: dict) -> ProgressiveMesh:
    """Reverse the contraction record into a base mesh plus vertex splits.

    Slot numbers of the run become level numbers: the survivors, in slot order, are
    0..n_base-1, and the vertex retired by contraction j is introduced by split J-1-j.
    A survivor keeps its number, so a slot's level number never changes.
    """
    record, cx, j_count = run
    base_slots = np.flatnonzero(cx.vertex_alive)
    level_of_slot = _level_of_slot(run)

    killed_end = record.killed_end[:j_count]
    n_killed = int(killed_end[-1]) if j_count else 0
    base_faces = np.flatnonzero(cx.face_alive)
    # Faces in order of appearance: the base, then those killed by the last contraction
    # (born at split 0), and so on back to the first.
    face_order = np.zeros(base_faces.size + n_killed, np.int64)
    face_order[: base_faces.size] = base_faces
    reverse_runs(record.killed, killed_end, j_count, face_order[base_faces.size :])
    level_of_face = np.full(cx.faces.shape[0], -1, np.int64)
    level_of_face[face_order] = np.arange(face_order.size)
    born_per_split = np.diff(killed_end, prepend=0)[::-1]
    level_faces = np.concatenate([[base_faces.size], base_faces.size + np.cumsum(born_per_split)])

    relabel_end = record.relabel_end[:j_count]
    relabelled = np.zeros(int(relabel_end[-1]) if j_count else 0, np.int32)
    reverse_runs(record.relabel, relabel_end, j_count, relabelled)
    relabel_faces = level_of_face[relabelled]
    relabel_offsets = np.concatenate([[0], np.cumsum(np.diff(relabel_end, prepend=0)[::-1])])

    reversed_j = np.arange(j_count - 1, -1, -1)
    split_positions = np.stack(
        [record.position_a[reversed_j], record.position_b[reversed_j]], axis=1
    )
    return ProgressiveMesh(
        base_vertices=np.ascontiguousarray(cx.vertices[base_slots]),
        split_vertex=level_of_slot[record.a[reversed_j]].astype(np.int32),
        split_positions=np.ascontiguousarray(split_positions),
        face_corners=level_of_slot[cx.faces[face_order]].astype(np.int32),
        level_faces=level_faces.astype(np.int64),
        relabel_offsets=relabel_offsets.astype(np.int64),
        relabel_faces=relabel_faces.astype(np.int32),
        split_cost=np.ascontiguousarray(record.cost[reversed_j]),
        metadata=metadata,
    )


def build(
    vertices,
    faces,
    options: BuildOptions | dict | None = None,
    progress: ProgressCallback | None = None,
) -> ProgressiveMesh:
    """Simplify a triangle mesh once and record it as a progressive mesh.

    vertices : (n, 3) float, faces : (m, 3) int. The input is validated and prepared
    (unreferenced vertices dropped, exactly coincident vertices welded, degenerate and
    duplicate faces dropped; see `prepare_mesh`), then contracted greedily until nothing
    valid is left. ``progress(fraction)`` is called as the work goes on.
    Raises InvalidMeshError for unusable input and InvalidOptionsError for bad options.
    """
    if not isinstance(options, BuildOptions):
        options = BuildOptions.from_mapping(options)
    prepared, mesh_edges = prepare_mesh_and_edges(vertices, faces, options.merge_coincident)
    if progress is not None:
        progress(0.0)

    def contraction_progress(fraction: float) -> None:
        if progress is not None:
            progress(0.02 + 0.93 * fraction)

    run = contract_greedily(prepared.vertices, prepared.faces, options, contraction_progress,
                            mesh_edges=mesh_edges)
    metadata = {
        "bbox": np.stack([prepared.vertices.min(axis=0), prepared.vertices.max(axis=0)]).tolist(),
        "options": options.to_dict(),
        "prepare_report": {k: int(v) for k, v in prepared.report.items()},
        "input_vertices": int(np.asarray(vertices).shape[0]),
        "input_faces": int(np.asarray(faces).shape[0]),
    }
    pm = assemble_progressive_mesh(run, metadata)
    # For each input vertex, its level number (-1 if dropped by preparation).
    level_of_slot = _level_of_slot(run)
    pm.vertex_map = np.where(
        prepared.vertex_map >= 0, level_of_slot[np.maximum(prepared.vertex_map, 0)], -1
    ).astype(np.int32)
    if progress is not None:
        progress(1.0)
    return pm


def _level_of_slot(run: ContractionRun) -> np.ndarray:
    """(n,) int32: the level number of each slot of the run (its place in refinement)."""
    record, cx, j_count = run
    base_slots = np.flatnonzero(cx.vertex_alive)
    level_of_slot = np.full(cx.vertices.shape[0], -1, np.int32)
    level_of_slot[base_slots] = np.arange(base_slots.size, dtype=np.int32)
    retired = record.b[:j_count][::-1]
    level_of_slot[retired] = base_slots.size + np.arange(j_count, dtype=np.int32)
    return level_of_slot

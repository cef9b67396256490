"""The Python driver of the greedy contraction: validates, sets up flat arrays, runs the
numba loop in chunks (reporting progress), and hands back the full contraction record.

References: Garland and Heckbert, "Surface simplification using quadric error metrics"
(1997); Edelsbrunner, "Geometry and Topology for Mesh Generation" (2001), III.12.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np

from . import rounds
from ._kernels.adjacency import compact, make_face_lists, sort_chunks
from ._kernels.appearance import (
    N_SETTINGS,
    SETTING_UV_OFFSET,
    SETTING_VOLUME,
    fill_costs,
    fill_wedge_quadrics,
    wedge_row_size,
)
from ._kernels.assemble import (
    fill_splits,
    gather_reversed_runs,
    level_corners,
    number_slots,
    order_faces,
    turn_born_faces,
)
from ._kernels.bounds import bounding_box
from ._kernels.contract import (
    N_PARAMS,
    PARAM_COS_STEP_TURN,
    PARAM_DISTANCE_WEIGHT,
    PARAM_EXACT,
    PARAM_PRESERVE_TOPOLOGY,
    PARAM_RANK_TOLERANCE,
    PARAM_STOP_COST,
    PARAM_VOLUME_WEIGHT,
    STATUS_EXHAUSTED,
    STATUS_NEED_PAIR_POOL_SPACE,
    STATUS_NEED_POOL_SPACE,
    STATUS_NEED_RELABEL_SPACE,
    STATUS_NEED_WEDGE_SPACE,
    STATUS_STEPS_DONE,
    Complex,
    Record,
    Scratch,
    run_contractions,
)
from ._kernels.heap import heapify, make_heap
from ._kernels.link import make_neighbourhood, restart_generations
from ._kernels.pairs import candidate_pairs, make_pairs
from ._kernels.partition import take_rows
from ._kernels.quadrics import QUADRIC_SIZE, fill_face_quadrics
from ._kernels.runs import gather_runs
from ._kernels.scale import ldexp_into
from ._kernels.setup import fill_border_quadrics, fill_heap, sum_quadrics
from ._kernels.sweeps import split_dependencies, sweep_order, window_ends
from .attributes import Wedges, check_options_for_wedges, make_wedges
from .lattice import place_on_tangent_lattice
from .mesh import Mesh
from .options import ERROR_MODE_CODES, WEIGHTING_AREA_EXPONENTS, WEIGHTING_CODES, BuildOptions
from .page_advice import without_huge_page_advice
from .prepare import MeshEdges, prepare_mesh_and_edges, unique_edges
from .progressive import ProgressiveMesh
from .record import grown, make_record, permuted, with_room_for
from .rounds import (
    COMPACTED_ROUNDS_MIN_VERTICES,
    RoundsState,
    compacted,
    contract_in_rounds,
    edges_by_part,
    in_input_order,
    mesh_only,
    spatial_order,
    write_back,
)

__all__ = [
    "ContractionRun",
    "assemble_progressive_mesh",
    "build",
    "contract_greedily",
    "unique_edges",
]

# Wedges of one contraction (of a and b together) the scratch space holds; a contraction
# with more is refused (a vertex with hundreds of UV charts meeting at it).
MAX_WEDGES_PER_CONTRACTION = 1024

# Contractions per call of the loop: Python reports progress (and a server job notices a
# delete) between calls. Small meshes take chunks of a sixteenth of their vertices, so
# they report too; chunks change nothing in the result.
CHUNK_CONTRACTIONS = 16384
MIN_CHUNK_CONTRACTIONS = 256

ProgressCallback = Callable[[float], None]


class ContractionRun(NamedTuple):
    """What the greedy loop leaves: the record and the final complex (after parallel
    rounds, its mesh only: see `rounds.in_input_order`)."""

    record: Record
    complex: Complex
    n_contractions: int


def to_unit_scale(vertices: np.ndarray, box: np.ndarray | None = None,
                  in_place: bool = False) -> tuple[np.ndarray, int, float]:
    """(vertices * 2**-e, e, their bounding-box diagonal), e such that the scaled
    vertices have their longest bounding-box side in [0.5, 1): the mesh as `build`
    contracts it. ``box``: the vertices' `bounding_box`, if the caller has it.
    ``in_place``: scale ``vertices`` (a float64 C array) itself, not a copy.

    A power of two scales every product, sum and square root the kernels take exactly
    (short of underflow), so the levels are the same at any scale, and the quadrics of a
    mesh measured in light years or in nanometres neither overflow nor underflow."""
    low, high = bounding_box(vertices) if box is None else box
    half_sides = high / 2 - low / 2  # halves: no overflow
    longest = float(half_sides.max())
    scale = int(np.frexp(longest)[1]) + 1 if longest > 0.0 else 0
    unit_vertices = _scaled(np.ascontiguousarray(vertices, np.float64), -scale,
                            None if in_place else np.empty(vertices.shape))
    # The scaled corners are the corners of the scaled vertices (the scaling is exact).
    diagonal = float(np.linalg.norm(np.ldexp(high, -scale) - np.ldexp(low, -scale)))
    return unit_vertices, scale, diagonal


def in_input_units(run: ContractionRun, scale: int, weighting: str) -> ContractionRun:
    """The run of a mesh contracted at 2**-scale times its size (`to_unit_scale`),
    with its positions and costs back in the input's units.

    A cost is a sum of plane weights times squared distances, the weight a power k of an
    area (`WEIGHTING_AREA_EXPONENTS`): it scales as length^(2 + 2k). Costs past the float
    range are clamped to its largest value. Appearance values stay as they are: weighted
    by the diagonal at the unit scale (attributes.py), they keep the float32 range of the
    file's wedge arrays at any size of mesh."""
    if scale == 0:
        return run
    record, cx = run.record, run.complex
    # Only the rows written: the rest of the record's arrays is uninitialised (make_record).
    # The run's arrays are the build's own: scaled in place.
    j = run.n_contractions
    cost_scale = scale * round(2 + 2 * WEIGHTING_AREA_EXPONENTS[weighting])
    record = record._replace(
        position_a=_scaled(record.position_a[:j], scale),
        position_b=_scaled(record.position_b[:j], scale),
        cost=_scaled(record.cost[:j], cost_scale, limit=float(np.finfo(np.float64).max)),
    )
    return run._replace(record=record, complex=cx._replace(vertices=_scaled(cx.vertices, scale)))


def _scaled(values: np.ndarray, exponent: int, out: np.ndarray | None = None,
            limit: float = np.inf) -> np.ndarray:
    """values * 2**exponent (exactly, as np.ldexp), each at most ``limit``, written to
    ``out`` (a C array of values' shape), or in place; returns it."""
    out = values if out is None else out
    if not (values.flags.c_contiguous and out.flags.c_contiguous):
        raise ValueError("_scaled takes C-contiguous arrays")
    ldexp_into(values.reshape(-1), exponent, limit, out.reshape(-1))
    return out


def _kernel_params(options: BuildOptions) -> np.ndarray:
    params = np.zeros(N_PARAMS)
    params[PARAM_RANK_TOLERANCE] = options.rank_tolerance
    params[PARAM_COS_STEP_TURN] = np.cos(np.radians(options.max_face_turn_deg))
    params[PARAM_EXACT] = float(ERROR_MODE_CODES[options.error_mode])
    params[PARAM_PRESERVE_TOPOLOGY] = float(options.preserve_topology)
    params[PARAM_DISTANCE_WEIGHT] = options.distance_weight
    params[PARAM_VOLUME_WEIGHT] = 0.0 if options.preserve_volume else options.volume_weight
    params[PARAM_STOP_COST] = np.inf
    return params


def _initial_complex(vertices: np.ndarray, faces: np.ndarray, options: BuildOptions,
                     mesh_edges: MeshEdges, wedges: Wedges | None, owned: bool):
    """The complex the loop contracts, and the edges. ``owned``: vertices (float64) and
    faces (int32), C arrays, are the build's own, and become the complex's (the loop
    rewrites them); else they are copied."""
    n, m = vertices.shape[0], faces.shape[0]
    weighting = WEIGHTING_CODES[options.weighting]
    exact = options.error_mode == "exact"
    # Only the exact mode reads face quadrics again (merging edge quadrics).
    # Uninitialised: the kernel writes every row of each (quadrics.py).
    face_quadrics = np.empty((m if exact else 0, QUADRIC_SIZE))
    face_normals = np.empty((m, 3))
    vertex_quadrics = np.empty((n, QUADRIC_SIZE))
    fill_face_quadrics(vertices, faces, weighting, face_quadrics, face_normals,
                       vertex_quadrics, sort_chunks())

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
    # Set where a face uses the vertex (index assignment: no (3m,) int64 copy of the
    # faces, as np.bincount makes).
    vertex_alive = np.zeros(n, np.uint8)
    vertex_alive[faces.reshape(-1)] = 1
    if wedges is None:
        face_wedges, wedge_values = np.zeros((0, 3), np.int32), np.zeros((0, 0))
    else:
        face_wedges = np.array(wedges.face_wedges, np.int32, copy=True)  # rewritten
        wedge_values = np.array(wedges.values, np.float64, copy=True)
    k = wedge_values.shape[1]
    wedge_quadrics = np.zeros((wedge_values.shape[0], wedge_row_size(k)))
    if wedges is not None:
        fill_wedge_quadrics(vertices, faces, face_wedges, wedge_values, weighting,
                            wedge_quadrics)
    cx = Complex(
        vertices=vertices if owned else np.array(vertices, np.float64, copy=True),
        vertex_quadrics=vertex_quadrics,
        vertex_alive=vertex_alive,
        vertex_refused=np.zeros(n, np.uint8),
        faces=faces if owned else np.array(faces, np.int32, copy=True),
        face_alive=np.ones(m, np.uint8),
        face_normals=face_normals,
        face_quadrics=face_quadrics,
        face_edge=face_edge,
        edge_quadrics=edge_quadrics,
        face_wedges=face_wedges,
        wedge_quadrics=wedge_quadrics,
        wedge_values=wedge_values,
    )
    return cx, edges


def _make_scratch(cx: Complex, options: BuildOptions, wedges: Wedges | None) -> Scratch:
    n_wedges, k = cx.wedge_values.shape
    capacity = MAX_WEDGES_PER_CONTRACTION if n_wedges else 0
    settings = np.zeros(N_SETTINGS)
    settings[SETTING_VOLUME] = float(options.preserve_volume)
    settings[SETTING_UV_OFFSET] = -1.0 if wedges is None else float(wedges.layout.offset("uv"))
    bounds = (np.stack([cx.wedge_values.min(axis=0), cx.wedge_values.max(axis=0)])
              if n_wedges else np.zeros((2, k)))
    return Scratch(
        wedge_tag=np.zeros(n_wedges, np.int64),
        wedge_slot=np.zeros(n_wedges, np.int32),
        members=np.zeros((capacity, 2), np.int32),
        group_rows=np.zeros((capacity, cx.wedge_quadrics.shape[1])),
        counter=np.zeros(2, np.int64),
        settings=settings,
        value_bounds=np.ascontiguousarray(bounds),
        total=np.zeros(QUADRIC_SIZE),
        group_values=np.zeros((capacity, k)),
    )


def contract_greedily(
    vertices: np.ndarray,
    faces: np.ndarray,
    options: BuildOptions,
    progress: ProgressCallback | None = None,
    max_contractions: int | None = None,
    mesh_edges: MeshEdges | None = None,
    wedges: Wedges | None = None,
    rounds_above: int | None = None,
) -> ContractionRun:
    """Contract edges (and, with ``options.pair_threshold``, near vertex pairs) greedily
    by quadric error until nothing valid is left.

    vertices : (n, 3) float64, faces : (m, 3) int32, already prepared (every vertex
    referenced, no degenerate or duplicate face). ``max_contractions`` stops early (the
    tests use it to compare a level of detail with the greedy run stopped there).
    ``mesh_edges``: the edges of ``faces`` if already found (`prepare_mesh_and_edges`).
    ``wedges``: appearance attributes (attributes.py), kept in Hoppe's quadric.
    ``rounds_above``: parallel rounds run while more vertices than this are live
    (default `rounds.PARALLEL_MIN_VERTICES`; `warm_up` lowers it for a small mesh).
    """
    return _contract_greedily([vertices, faces, mesh_edges], options, progress,
                              max_contractions, wedges, rounds_above, owned=False)


def _contract_greedily(mesh: list, options: BuildOptions, progress: ProgressCallback | None,
                       max_contractions: int | None, wedges: Wedges | None,
                       rounds_above: int | None, owned: bool) -> ContractionRun:
    """`contract_greedily` of ``mesh`` = [vertices, faces, mesh_edges or None], a list it
    empties, so that the arrays a caller hands over in it alone are freed as soon as the
    build is done with them (a big mesh's peak memory). ``owned``: vertices (float64)
    and faces (int32) are C arrays the build may rewrite (`_initial_complex`)."""
    vertices, faces, mesh_edges = mesh
    mesh.clear()
    if rounds_above is None:
        rounds_above = rounds.PARALLEL_MIN_VERTICES
    if (options.parallel_rounds and _costs_are_geometric(options, wedges)
            and options.pair_threshold == 0.0 and max_contractions is None
            and vertices.shape[0] > rounds_above):
        # Parallel rounds (rounds.py), on the mesh in z-order.
        if mesh_edges is None:
            mesh_edges = unique_edges(faces, vertices.shape[0])
        vertex_order, face_order, ordered_faces, ordered_edges = spatial_order(
            vertices, faces, mesh_edges)
        # A new C array, gathered in threads (numpy's fancy index took 14-39 ms).
        ordered_vertices = np.empty((vertex_order.size, 3))
        take_rows(vertex_order, np.ascontiguousarray(vertices, np.float64), ordered_vertices)
        del vertices, faces, mesh_edges  # the z-ordered copies replace them
        ordered = [ordered_vertices, ordered_faces, ordered_edges]
        del ordered_vertices, ordered_faces, ordered_edges
        run = _contract(ordered, options, progress, None, None, rounds_while_above=rounds_above,
                        owned=True)
        record, cx = in_input_order(run.record, run.complex, vertex_order, face_order)
        return ContractionRun(record, cx, run.n_contractions)
    return _contract([vertices, faces, mesh_edges], options, progress, max_contractions, wedges,
                     rounds_while_above=None, owned=owned)


def _costs_are_geometric(options: BuildOptions, wedges: Wedges | None) -> bool:
    """Whether a candidate's first cost needs only the quadrics (`fill_heap`, the loops
    of parallel rounds), not its faces: no appearance attributes, no hard volume
    constraint (`fill_costs`)."""
    return wedges is None and not options.preserve_volume


def _contract(mesh: list, options: BuildOptions, progress: ProgressCallback | None,
              max_contractions: int | None, wedges: Wedges | None,
              rounds_while_above: int | None, owned: bool) -> ContractionRun:
    """`_contract_greedily` (which says what ``mesh`` and ``owned`` are), in parallel
    rounds first while more than ``rounds_while_above`` vertices are live (None: no
    rounds)."""
    in_rounds = rounds_while_above is not None
    vertices, faces, mesh_edges = mesh
    mesh.clear()
    n, m = vertices.shape[0], faces.shape[0]
    if mesh_edges is None:
        mesh_edges = unique_edges(faces, n)
    cx, edges = _initial_complex(vertices, faces, options, mesh_edges, wedges, owned=owned)
    del mesh_edges  # its face counts and sides are done with; face_edge lives on in cx
    scratch = _make_scratch(cx, options, wedges)
    params = _kernel_params(options)
    pairs = make_pairs(_pairs_for(vertices, edges, options.pair_threshold), n, edges.shape[0])
    del vertices, faces
    n_edges = edges.shape[0]
    if in_rounds:
        edges = None  # rebuilt if the rounds contract nothing (`_edges_of`)
    record = make_record(n, m, *cx.wedge_values.shape)
    budget = n if max_contractions is None else max(0, int(max_contractions))
    chunk = min(CHUNK_CONTRACTIONS, max(MIN_CHUNK_CONTRACTIONS, n // 16))

    def report(done: int) -> None:
        if progress is not None:
            progress(min(1.0, done / max(1, n - 4)))

    done = 0
    hood = make_neighbourhood(n)
    whole, live_rows, counts_before = cx, None, None
    if in_rounds:
        state = RoundsState()

        def run_rounds(min_live: int) -> None:
            nonlocal record, done
            before = done
            record, round_done = contract_in_rounds(
                cx, hood, pairs, record, params, lambda: _make_scratch(cx, options, None),
                chunk, lambda count: report(before + count), min_live, state)
            done += round_done

        # The rounds run on the whole arrays, then on the live part alone, its rows
        # together (rounds.compacted), down to COMPACTED_ROUNDS_MIN_VERTICES live
        # vertices, and the serial loop after them on that part too; the work on it is
        # told back at the end. No pairs in rounds: the pairs' ids would start past the
        # compacted edges' (contract_greedily).
        run_rounds(rounds_while_above)
        if done:
            assert pairs.ends.size == 0
            cx, live_rows = compacted(whole)
            # Only the mesh of the whole arrays is told back (`write_back`).
            whole = mesh_only(whole)
            hood = make_neighbourhood(cx.vertices.shape[0])
            counts_before = record.counts.copy()
            if COMPACTED_ROUNDS_MIN_VERTICES < rounds_while_above:
                run_rounds(COMPACTED_ROUNDS_MIN_VERTICES)
        else:
            edges = _edges_of(cx, n_edges)
    lists = make_face_lists(cx.faces, cx.vertices.shape[0], capacity=6 * cx.faces.shape[0] + 1024,
                            alive=cx.face_alive)
    # Candidates: the edges, then the pairs; their ids are the heap's ids.
    candidates = np.concatenate([edges, pairs.ends]) if pairs.ends.size else edges
    heap = make_heap(n_edges + pairs.ends.shape[0] if live_rows is None else live_rows.edges.size)
    exact = options.error_mode == "exact"
    if _costs_are_geometric(options, wedges):
        if live_rows is not None:
            # After the rounds: all in part 0.
            ids, candidates, run_start, run_end = edges_by_part(
                cx, hood.part, np.array([cx.faces.shape[0]]), live_rows.edges.size)
        else:
            ids = np.arange(candidates.shape[0], dtype=np.int64)
            run_start, run_end = np.zeros(1, np.int64), np.array([ids.size], np.int64)
        fill_heap(cx.vertices, cx.vertex_quadrics, cx.edge_quadrics, candidates, ids, run_start,
                  run_end, exact, options.rank_tolerance, heap.entries)
        heap.size[0] = run_end[0]  # one run, from row 0
    else:
        fill_costs(cx.vertices, cx.vertex_quadrics, cx.edge_quadrics, candidates, exact,
                   options.rank_tolerance, cx.faces, cx.face_alive, lists.start, lists.count,
                   lists.pool, _look(cx, scratch), heap.entries)
        heap.size[0] = candidates.shape[0]
    heapify(heap.entries, heap.position, heap.size)
    while done < budget:
        restart_generations(hood)
        status, steps = run_contractions(
            cx, lists, pairs, hood, heap, record, params, min(chunk, budget - done), scratch,
        )
        done += steps
        if status == STATUS_EXHAUSTED:
            break
        if status in (STATUS_NEED_RELABEL_SPACE, STATUS_NEED_WEDGE_SPACE):
            record = with_room_for(record, status)
        elif status == STATUS_NEED_POOL_SPACE:
            compact(lists.start, lists.count, lists.pool, lists.used, cx.vertex_alive)
            lists = lists._replace(pool=grown(lists.pool, -1))
        elif status == STATUS_NEED_PAIR_POOL_SPACE:
            compact(pairs.start, pairs.count, pairs.pool, pairs.used, cx.vertex_alive)
            pairs = pairs._replace(pool=grown(pairs.pool, -1))
        else:
            assert status == STATUS_STEPS_DONE, status
        report(done)
    if live_rows is not None:
        write_back(cx, live_rows, whole, record, counts_before)
    return ContractionRun(record, whole, done)


def _edges_of(cx: Complex, n_edges: int) -> np.ndarray:
    """(n_edges, 2) int32: the (low, high) ends of each edge id of ``cx``'s faces, as
    `unique_edges` and `spatial_order` give them (every edge is a side of a face)."""
    ends = np.stack([cx.faces, np.roll(cx.faces, -1, axis=1)], axis=-1).reshape(-1, 2)
    edges = np.empty((n_edges, 2), np.int32)
    edges[cx.face_edge.reshape(-1)] = np.sort(ends, axis=1)
    return edges


def _look(cx: Complex, scratch: Scratch) -> tuple:
    """The tuple of appearance arrays the kernels take (appearance.py)."""
    return (cx.face_wedges, cx.wedge_quadrics, cx.wedge_values, scratch.wedge_tag,
            scratch.wedge_slot, scratch.members, scratch.group_rows, scratch.counter,
            scratch.settings, scratch.value_bounds, scratch.total, scratch.group_values)


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
    return _assemble(run, metadata)[0]


def _assemble(run: ContractionRun, metadata: dict) -> tuple[ProgressiveMesh, np.ndarray]:
    """`assemble_progressive_mesh`, and the level number of each slot (`_level_of_slot`)."""
    record, cx, j_count = run
    level_of_slot = _level_of_slot(run)
    m = cx.faces.shape[0]
    # Faces in order of appearance: the base, then those killed by the last contraction
    # (born at split 0), and so on back to the first.
    n_killed = int(record.killed_end[j_count - 1]) if j_count else 0
    face_order = np.zeros(int(np.count_nonzero(cx.face_alive)) + n_killed, np.int64)
    level_of_face = np.full(m, -1, np.int64)
    n_base_faces = order_faces(cx.face_alive, record.killed, record.killed_end, j_count,
                               face_order, level_of_face)
    face_corners = np.zeros((face_order.size, 3), np.int32)
    level_corners(cx.faces, level_of_face, level_of_slot, face_corners)

    split_vertex = np.zeros(j_count, np.int32)
    split_positions = np.zeros((j_count, 2, 3))
    split_cost = np.zeros(j_count)
    level_faces = np.zeros(j_count + 1, np.int64)
    fill_splits(record.a, record.position_a, record.position_b, record.cost,
                record.killed_end, j_count, level_of_slot, n_base_faces, split_vertex,
                split_positions, split_cost, level_faces)
    # Each born face turned and put in its split's order (assemble.py), what follows
    # numbered by the faces' new rows.
    n_base = int(np.count_nonzero(cx.vertex_alive))
    turns = np.zeros(face_order.size, np.int8)
    source = np.empty(face_order.size, np.int64)
    turn_born_faces(face_corners, level_faces, split_vertex, n_base, turns, source)
    face_corners, face_order, turns = face_corners[source], face_order[source], turns[source]
    level_of_face[face_order] = np.arange(face_order.size)

    relabel_faces = np.zeros(int(record.relabel_end[j_count - 1]) if j_count else 0, np.int32)
    relabel_offsets = np.zeros(j_count + 1, np.int64)
    gather_reversed_runs(record.relabel, record.relabel_end, j_count, level_of_face,
                         relabel_faces, relabel_offsets)
    wedge_arrays = (_wedge_splits(run, face_order, level_of_face, turns)
                    if cx.wedge_values.shape[0] else {})
    pm = ProgressiveMesh(
        base_vertices=np.ascontiguousarray(cx.vertices[cx.vertex_alive.astype(bool)]),
        split_vertex=split_vertex,
        split_positions=split_positions,
        face_corners=face_corners,
        level_faces=level_faces,
        relabel_offsets=relabel_offsets,
        relabel_faces=relabel_faces,
        split_cost=split_cost,
        metadata=metadata,
        **wedge_arrays,
    )
    return pm, level_of_slot


def _reversed_run_rows(ends: np.ndarray, j_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Rows of a run-coded record (runs ending at ``ends``) in split order, and the
    split each belongs to."""
    total = int(ends[j_count - 1]) if j_count else 0
    rows = np.zeros(total, np.int64)
    gather_runs(np.arange(total, dtype=np.int64), ends, np.arange(j_count - 1, -1, -1), rows)
    lengths = np.diff(ends[:j_count], prepend=0)[::-1]
    return rows, np.repeat(np.arange(j_count), lengths)


def _offsets(split_of_row: np.ndarray, j_count: int) -> np.ndarray:
    return np.concatenate([[0], np.cumsum(np.bincount(split_of_row, minlength=j_count))]
                          ).astype(np.int64)


def _wedge_splits(run: ContractionRun, face_order: np.ndarray, level_of_face: np.ndarray,
                  turns: np.ndarray) -> dict:
    """The wedge side of the progressive mesh (see `ProgressiveMesh`), from the log of
    `appearance.merge_wedges`: wedges renumbered like vertices (the survivors of the
    whole run first, then those retired by the last contraction, and so on back), each
    face's corners turned as its vertices were (``turns``, `turn_born_faces`)."""
    record, cx, j_count = run
    rows, split_of = _reversed_run_rows(record.wedge_log_end, j_count)
    log, log_values = record.wedge_log[rows], record.wedge_log_values[rows]
    retired = log[:, 0] != log[:, 1]
    base = np.ones(cx.wedge_values.shape[0], bool)
    base[log[retired, 0]] = False
    base_wedges = np.flatnonzero(base)
    level_of_wedge = np.full(base.size, -1, np.int64)
    level_of_wedge[base_wedges] = np.arange(base_wedges.size)
    level_of_wedge[log[retired, 0]] = base_wedges.size + np.arange(int(retired.sum()))

    relabel_rows, relabel_split = _reversed_run_rows(record.wedge_relabel_end, j_count)
    relabel = record.wedge_relabel[relabel_rows].astype(np.int64)
    relabel_face = level_of_face[relabel[:, 0]]
    turned = (np.arange(3)[None, :] + turns[:, None]) % 3
    face_wedges = np.take_along_axis(cx.face_wedges[face_order], turned, axis=1)
    return {
        "base_wedge_values": cx.wedge_values[base_wedges].astype(np.float32),
        "face_wedge_corners": level_of_wedge[face_wedges].astype(np.int32),
        "wedge_update_offsets": _offsets(split_of[~retired], j_count),
        "wedge_update_ids": level_of_wedge[log[~retired, 0]].astype(np.int32),
        "wedge_update_values": log_values[~retired].astype(np.float32),
        "wedge_new_offsets": _offsets(split_of[retired], j_count),
        "wedge_new_values": log_values[retired].astype(np.float32),
        "wedge_relabel_offsets": _offsets(relabel_split, j_count),
        "wedge_relabel_corners": relabel_face * 3 + (relabel[:, 1] - turns[relabel_face]) % 3,
        "wedge_relabel_to": level_of_wedge[relabel[:, 2]].astype(np.int32),
    }


def build(
    vertices,
    faces,
    options: BuildOptions | dict | None = None,
    progress: ProgressCallback | None = None,
    *,
    attributes_of: Mesh | None = None,
) -> ProgressiveMesh:
    """Simplify a triangle mesh once and record it as a progressive mesh.

    vertices : (n, 3) float, faces : (m, 3) int. The input is validated and prepared
    (unreferenced vertices dropped, exactly coincident vertices welded, degenerate and
    duplicate faces dropped; see `prepare_mesh`), then contracted greedily until nothing
    valid is left. ``progress(fraction)`` is called as the work goes on.
    ``attributes_of``: the `Mesh` whose vertex attributes and corner UVs are kept
    (`qem_core.build_mesh` passes it), each weighted by its option.
    Raises InvalidMeshError for unusable input and InvalidOptionsError for bad options.
    """
    if not isinstance(options, BuildOptions):
        options = BuildOptions.from_mapping(options)
    # The build's working arrays are allocated with small pages (page_advice.py).
    with without_huge_page_advice():
        return _build(vertices, faces, options, progress, attributes_of)


def _build(vertices, faces, options: BuildOptions, progress: ProgressCallback | None,
           attributes_of: Mesh | None) -> ProgressiveMesh:
    prepared, mesh_edges = prepare_mesh_and_edges(vertices, faces, options.merge_coincident)
    if progress is not None:
        progress(0.0)

    def contraction_progress(fraction: float) -> None:
        if progress is not None:
            progress(0.02 + 0.93 * fraction)

    box = bounding_box(prepared.vertices)
    # In place: preparation's vertices are a copy of the input's, and nothing else reads them.
    unit_vertices, scale, diagonal = to_unit_scale(prepared.vertices, box, in_place=True)
    wedges = None
    if attributes_of is not None:
        wedges = make_wedges(attributes_of, prepared.face_map, prepared.faces, options,
                             diagonal)
        if wedges is not None:
            check_options_for_wedges(options)
    # Handed over with no other reference kept, each freed once the build is done with it.
    mesh = [unit_vertices, prepared.faces, mesh_edges]
    prepared = prepared._replace(vertices=None, faces=None)
    del unit_vertices, mesh_edges
    run = _contract_greedily(mesh, options, contraction_progress, None, wedges, None,
                             owned=True)
    run = in_input_units(run, scale, options.weighting)
    metadata = {
        "bbox": box.tolist(),
        "options": options.to_dict(),
        "prepare_report": {k: int(v) for k, v in prepared.report.items()},
        "input_vertices": int(np.asarray(vertices).shape[0]),
        "input_faces": int(np.asarray(faces).shape[0]),
    }
    if wedges is not None:
        metadata["attributes"] = wedges.layout.to_dict()
    run = _in_sweep_order(run)  # the greedy order's record freed once reordered
    pm, level_of_slot = _assemble(run, metadata)
    # For each input vertex, its level number (-1 if dropped by preparation).
    pm.vertex_map = np.where(
        prepared.vertex_map >= 0, level_of_slot[np.maximum(prepared.vertex_map, 0)], -1
    ).astype(np.int32)
    if options.tangent_lattice and not options.preserve_volume:
        place_on_tangent_lattice(pm)
    if progress is not None:
        progress(1.0)
    return pm


def _in_sweep_order(run: ContractionRun) -> ContractionRun:
    """The run with its contractions reordered so that the refinement takes its splits
    in sweeps of ascending split vertex, window by window (`_kernels/sweeps.py`): the same
    levels at the windows' ends, a stream that codes each split's vertex in a few bits."""
    record, cx, j_count = run
    if j_count < 2:
        return run
    pred_offsets, preds = split_dependencies(
        cx.faces.copy(), record.a, record.b, record.killed, record.killed_end,
        record.relabel, record.relabel_end, j_count, cx.vertices.shape[0],
    )  # fmt: skip
    level_of_slot = np.full(cx.vertices.shape[0], -1, np.int32)
    n_base = number_slots(cx.vertex_alive, record.b, 0, level_of_slot)
    ends = np.array(window_ends(n_base, j_count), np.int64)
    order = sweep_order(pred_offsets, preds, record.a[:j_count], record.b[:j_count],
                        level_of_slot, n_base, ends)
    # Split k undoes contraction J-1-k: the new contraction i is split J-1-i.
    contractions = (j_count - 1 - order[::-1]).astype(np.int64)
    return run._replace(record=permuted(record, contractions))


def _level_of_slot(run: ContractionRun) -> np.ndarray:
    """(n,) int32: the level number of each slot of the run (its place in refinement)."""
    record, cx, j_count = run
    level_of_slot = np.full(cx.vertices.shape[0], -1, np.int32)
    number_slots(cx.vertex_alive, record.b, j_count, level_of_slot)
    return level_of_slot

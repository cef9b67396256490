"""Garland's pair contraction: vertex pairs closer than a threshold that share no edge.

Garland and Heckbert (1997) let any pair (u, v) with |u - v| < t be contracted, not only
edges, so that separate parts close to each other can join (the topology may change).
Such a pair is a candidate like an edge, with cost Q_u + Q_v (no plane is shared, so the
exact mode subtracts nothing), but no link condition: joining parts is the point. The
flip guard still applies.

The pairs are found once, before the first contraction, on a uniform grid of cells no
smaller than t would need: each vertex looks at the cells around its own, ring by ring,
for the vertices within t that are not its neighbours. A vertex keeps at most
``max_per_vertex`` of them, the nearest (ties by index): with a threshold well above the
edge length nearly every pair of a neighbourhood would qualify, and the cap keeps memory
and time O(n). The pair set is the union of what the vertices kept.

During the run a pair (u, v) follows its ends (when v is contracted into w it becomes
(u, w)), and dies when its ends meet, when it repeats another pair of the same ends, or
when its ends come to share a face (it is an edge then).
"""

from typing import NamedTuple

import numba
import numpy as np

from .adjacency import make_face_lists
from .appearance import candidate_cost
from .heap import cost_key, pair, remove, update
from .link import NEAR_SCRATCH
from .memory import borrowing_kernel

# At most this many pairs per vertex, its nearest (see the module docstring).
MAX_PAIRS_PER_VERTEX = 8


class Pairs(NamedTuple):
    """The candidate pairs of a run; pair p is candidate ``first[0] + p`` in the heap."""

    ends: np.ndarray  # (P, 2) int32, current ends, rewritten as vertices merge
    alive: np.ndarray  # (P,) uint8
    first: np.ndarray  # (1,) int64: candidate id of pair 0 (the number of edges)
    start: np.ndarray  # (n,) int64: vertex -> pairs lists, as adjacency.FaceLists
    count: np.ndarray  # (n,) int32
    pool: np.ndarray  # (capacity,) int32
    used: np.ndarray  # (1,) int64


def make_pairs(ends: np.ndarray, n_vertices: int, first: int) -> Pairs:
    """Pairs (P, 2) int32 as candidates numbered from ``first``, with their lists."""
    ends = np.ascontiguousarray(ends, np.int32).reshape(-1, 2)
    # The lists take no room at all when there are no pairs.
    n_listed = n_vertices if ends.shape[0] else 0
    lists = make_face_lists(ends, n_listed, capacity=4 * ends.size + 1024)
    return Pairs(ends.copy(), np.ones(ends.shape[0], np.uint8), np.array([first], np.int64),
                 *lists)


def candidate_pairs(vertices: np.ndarray, edges: np.ndarray, threshold: float) -> np.ndarray:
    """(P, 2) int32 sorted unique (low, high) pairs closer than ``threshold`` (absolute)
    that are not ``edges`` (E, 2), at most MAX_PAIRS_PER_VERTEX kept per vertex."""
    n = vertices.shape[0]
    if threshold <= 0.0 or n < 2:
        return np.zeros((0, 2), np.int32)
    start = np.zeros(n + 1, np.int64)
    neighbours = np.zeros(2 * edges.shape[0], np.int64)
    neighbour_lists(edges, n, start, neighbours)
    # Cells of one to two typical edges, so that a cell holds a handful of vertices:
    # t itself when it lies in between, and the search stops after a few rings when t is
    # long. Never so small that cell coordinates outgrow their 20 bits in ``cell_key``.
    sample = edges[:: max(1, edges.shape[0] // 65536)]  # a typical length needs no more
    lengths = np.linalg.norm(vertices[sample[:, 0]] - vertices[sample[:, 1]], axis=1)
    typical = float(np.median(lengths)) if lengths.size else threshold
    extent = float((vertices.max(axis=0) - vertices.min(axis=0)).max())
    cell_size = max(min(threshold, 2.0 * typical), typical, extent / (1 << 19), 1e-300)
    pairs = np.zeros((n * MAX_PAIRS_PER_VERTEX, 2), np.int32)
    n_pairs = find_pairs(vertices, start, neighbours, float(threshold), cell_size,
                         MAX_PAIRS_PER_VERTEX, pairs)
    keys = np.unique(pairs[:n_pairs, 0].astype(np.int64) * n + pairs[:n_pairs, 1])
    return np.stack([keys // n, keys % n], axis=1).astype(np.int32)


def _neighbour_lists(edges, n_vertices, start, neighbours):
    """CSR vertex -> edge neighbours. start : (n + 1,) int64 zeros; neighbours : (2E,)."""
    for e in range(edges.shape[0]):
        start[edges[e, 0] + 1] += 1
        start[edges[e, 1] + 1] += 1
    for v in range(n_vertices):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    for e in range(edges.shape[0]):
        a, b = edges[e, 0], edges[e, 1]
        neighbours[fill[a]] = b
        fill[a] += 1
        neighbours[fill[b]] = a
        fill[b] += 1


neighbour_lists = numba.njit(cache=True)(_neighbour_lists)


def _cell_key(ix, iy, iz):
    """One int64 for a cell's integer coordinates (each below 2^20 in magnitude)."""
    return ((ix + (1 << 20)) << 42) | ((iy + (1 << 20)) << 21) | (iz + (1 << 20))


cell_key = numba.njit(cache=True, inline="always")(_cell_key)


def _cell_slot(key, mask):
    """Home slot of a cell key: every bit of the key mixed into the low bits the mask
    keeps (the coordinates sit in separate bit fields; masking the key or a plain
    product of it would keep only the z field and pile whole columns into one slot)."""
    h = np.uint64(key)
    h ^= h >> np.uint64(33)
    h *= np.uint64(0xFF51AFD7ED558CCD)
    h ^= h >> np.uint64(33)
    h *= np.uint64(0xC4CEB9FE1A85EC53)
    h ^= h >> np.uint64(33)
    return np.int64(h & np.uint64(mask))


cell_slot = numba.njit(cache=True, inline="always")(_cell_slot)


def _find_cell(table_keys, table_cells, key):
    """The cell index stored under ``key``, or -1 (open addressing, linear probing)."""
    mask = table_keys.shape[0] - 1
    slot = cell_slot(key, mask)
    while table_keys[slot] != -1:
        if table_keys[slot] == key:
            return table_cells[slot]
        slot = (slot + 1) & mask
    return -1


find_cell = numba.njit(cache=True, inline="always")(_find_cell)


def _find_pairs(vertices, start, neighbours, threshold, cell_size, max_per_vertex, pairs):
    """Fill pairs (n * max_per_vertex, 2) int32 with (low, high) candidate pairs; returns
    their count (a pair kept by both of its ends appears twice).

    vertices : (n, 3) float64; start, neighbours : CSR edge neighbours of each vertex;
    threshold : t, the largest distance (exclusive); cell_size : the grid's cell edge,
    at most t (t / cell_size rings of cells are searched at most).
    """
    n = vertices.shape[0]
    if n == 0:
        return 0
    low = np.zeros(3)
    for d in range(3):
        low[d] = vertices[:, d].min()
    cell_of = np.zeros((n, 3), np.int64)
    for v in range(n):
        for d in range(3):
            cell_of[v, d] = np.int64(np.floor((vertices[v, d] - low[d]) / cell_size))
    # Cells: a hash table from cell key to cell index, then CSR cell -> vertices.
    size = 1
    while size < 2 * n:
        size *= 2
    table_keys = np.full(size, -1, np.int64)
    table_cells = np.full(size, -1, np.int64)
    cell_of_vertex = np.zeros(n, np.int64)
    n_cells = 0
    mask = size - 1
    for v in range(n):
        key = cell_key(cell_of[v, 0], cell_of[v, 1], cell_of[v, 2])
        slot = cell_slot(key, mask)
        while table_keys[slot] != -1 and table_keys[slot] != key:
            slot = (slot + 1) & mask
        if table_keys[slot] == -1:
            table_keys[slot] = key
            table_cells[slot] = n_cells
            n_cells += 1
        cell_of_vertex[v] = table_cells[slot]
    cell_start = np.zeros(n_cells + 1, np.int64)
    for v in range(n):
        cell_start[cell_of_vertex[v] + 1] += 1
    for c in range(n_cells):
        cell_start[c + 1] += cell_start[c]
    fill = cell_start[:-1].copy()
    cell_vertices = np.zeros(n, np.int64)
    for v in range(n):
        c = cell_of_vertex[v]
        cell_vertices[fill[c]] = v
        fill[c] += 1

    max_ring = int(np.ceil(threshold / cell_size))
    limit = threshold * threshold
    best_distance = np.zeros(max_per_vertex)
    best_vertex = np.zeros(max_per_vertex, np.int64)
    n_pairs = 0
    for index in range(n):
        # Cell by cell: the vertices of a cell look up the same neighbouring cells.
        u = cell_vertices[index]
        n_best = 0
        for ring in range(max_ring + 1):
            # Vertices in ring r are at least (r - 1) cells away.
            reach = (ring - 1) * cell_size
            if ring > 1 and reach * reach >= limit:
                break
            if n_best == max_per_vertex and ring > 1 and best_distance[n_best - 1] < reach * reach:
                break
            for dx in range(-ring, ring + 1):
                for dy in range(-ring, ring + 1):
                    for dz in range(-ring, ring + 1):
                        if max(abs(dx), abs(dy), abs(dz)) != ring:
                            continue
                        c = find_cell(table_keys, table_cells, cell_key(
                            cell_of[u, 0] + dx, cell_of[u, 1] + dy, cell_of[u, 2] + dz))
                        if c < 0:
                            continue
                        for i in range(cell_start[c], cell_start[c + 1]):
                            v = cell_vertices[i]
                            if v == u:
                                continue
                            distance = 0.0
                            for d in range(3):
                                step = vertices[v, d] - vertices[u, d]
                                distance += step * step
                            if distance >= limit:
                                continue
                            if n_best == max_per_vertex and (
                                distance > best_distance[n_best - 1]
                                or (distance == best_distance[n_best - 1]
                                    and v > best_vertex[n_best - 1])
                            ):
                                continue
                            adjacent = False
                            for j in range(start[u], start[u + 1]):
                                if neighbours[j] == v:
                                    adjacent = True
                                    break
                            if adjacent:
                                continue
                            # Insert into the sorted list of the nearest, by (distance, v).
                            k = min(n_best, max_per_vertex - 1)
                            while k > 0 and (
                                best_distance[k - 1] > distance
                                or (best_distance[k - 1] == distance and best_vertex[k - 1] > v)
                            ):
                                best_distance[k] = best_distance[k - 1]
                                best_vertex[k] = best_vertex[k - 1]
                                k -= 1
                            best_distance[k] = distance
                            best_vertex[k] = v
                            n_best = min(n_best + 1, max_per_vertex)
        for k in range(n_best):
            v = best_vertex[k]
            pairs[n_pairs, 0] = min(u, v)
            pairs[n_pairs, 1] = max(u, v)
            n_pairs += 1
    return n_pairs


find_pairs = numba.njit(cache=True)(_find_pairs)


def _merge_pairs(ends, alive, start, count, pool, used, first, heap_entries, heap_position,
                 heap_size, a, b):
    """Contracting b into a: b's pairs now end at a; pairs between a and b die; a's new
    list (its pairs, then b's) is written at the end of the pool. Repeated pairs and
    pairs whose ends now share a face are weeded out when a's costs are updated."""
    out = used[0]
    for v, other in ((a, b), (b, a)):
        s = start[v]
        for i in range(count[v]):
            p = pool[s + i]
            if not alive[p]:
                continue
            end = 0 if ends[p, 0] == v else 1
            if ends[p, 1 - end] == other:
                alive[p] = 0
                remove(heap_entries, heap_position, heap_size, first + p)
                continue
            ends[p, end] = a
            pool[out] = p
            out += 1
    start[a] = used[0]
    count[a] = out - used[0]
    used[0] = out
    count[b] = 0


merge_pairs = borrowing_kernel(_merge_pairs)


def _update_vertex_pairs(vertices, vertex_quadrics, edge_quadrics, near, generation,
                         heap_entries, heap_position, heap_size, ends, alive, first,
                         pair_start, pair_count, pair_pool, v, g_faces, only_missing, exact,
                         rank_tolerance, quadric, position, faces, face_alive, start, count,
                         pool, look):
    """``update_vertex_edges`` for the pairs of v, which must have run first (its
    neighbours carry tag ``g_faces``): a pair whose other end now shares a face with v is
    an edge, and one that repeats an earlier pair of v is a duplicate; both die."""
    generation[0] += 1
    g = generation[0]
    s = pair_start[v]
    for i in range(pair_count[v]):
        p = pair_pool[s + i]
        if not alive[p]:
            continue
        y = ends[p, 1] if ends[p, 0] == v else ends[p, 0]
        candidate = first + p
        if near[y, NEAR_SCRATCH] == g_faces or near[y, NEAR_SCRATCH] == g:
            alive[p] = 0
            remove(heap_entries, heap_position, heap_size, candidate)
            continue
        near[y, NEAR_SCRATCH] = g
        if only_missing and heap_position[candidate] >= 0:
            continue
        cost = candidate_cost(vertices, vertex_quadrics, edge_quadrics, v, y, candidate,
                              exact, rank_tolerance, quadric, position, faces, face_alive,
                              start, count, pool, look)
        update(heap_entries, heap_position, heap_size, cost_key(cost), pair(v, y), candidate)


update_vertex_pairs = borrowing_kernel(_update_vertex_pairs)

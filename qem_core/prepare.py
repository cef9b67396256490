"""Entry check and clean-up of a triangle mesh before it is simplified.

`prepare_mesh` is the single gate between user data and the kernels: it validates the
arrays (`validate_mesh_arrays`), welds vertices with exactly equal coordinates (STL
triangle soups), drops degenerate and duplicate faces and unreferenced vertices, and
reports what it found. Everything is vectorised numpy; the order of what is kept is
stable, so the same input always gives the same output, bit for bit.

    input vertices   0  1  2  3  4          (3 coincides with 0, 4 is unreferenced)
    input faces      (0 1 2) (3 2 1) (1 2 3)
                        |       |       |
    welded faces     (0 1 2) (0 2 1) (1 2 0)   3 -> 0
    kept faces       (0 1 2)                  (0 2 1) and (1 2 0) duplicate face 0
    vertex_map       0  1  2  0 -1            face_map  0 -1 -1
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from .errors import InvalidMeshError

__all__ = ["PreparedMesh", "prepare_mesh", "validate_mesh_arrays"]

# Indices are stored as int32 everywhere in qem_core.
_MAX_VERTICES = int(np.iinfo(np.int32).max)


class PreparedMesh(NamedTuple):
    """The cleaned mesh and how it relates to the input.

    vertices : (k, 3) float64, the kept vertices in their input order.
    faces : (j, 3) int32 indices into `vertices`, the kept faces in their input order.
    vertex_map : (n,) int32, for each input vertex its index in `vertices` (a welded
        vertex maps to the vertex it was welded onto), or -1 if it was dropped.
    face_map : (m,) int32, for each input face its index in `faces`, or -1 if it was
        dropped as degenerate or duplicate.
    report : dict of int counts, see `prepare_mesh`.
    """

    vertices: np.ndarray
    faces: np.ndarray
    vertex_map: np.ndarray
    face_map: np.ndarray
    report: dict[str, int]


def validate_mesh_arrays(
    vertices: object, faces: object, *, what: str = "mesh", require_faces: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Check a mesh's arrays and return them as (float64 (n, 3), int32 (m, 3)) C arrays.

    vertices : (n, 3) array of real numbers, all finite, n >= 1.
    faces : (m, 3) array of integers in [0, n), m >= 1.
    what : how messages name the mesh (a file name, say).
    require_faces : False lets m be 0 (writing a coarse level of a build without topology
        preservation, which may have collapsed to points).

    Raises InvalidMeshError naming the first bad value and how to fix it.
    """
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    if vertices.ndim != 2 or vertices.shape[1] != 3:
        raise InvalidMeshError(
            f"{what}: vertices must be an (n, 3) array of x, y, z, got shape {vertices.shape}"
        )
    if vertices.dtype.kind not in "fiu":
        raise InvalidMeshError(
            f"{what}: vertices must hold real numbers, got dtype {vertices.dtype}"
        )
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InvalidMeshError(
            f"{what}: faces must be an (m, 3) array of vertex indices (triangles), "
            f"got shape {faces.shape}; triangulate polygons first"
        )
    if faces.size and faces.dtype.kind not in "iu":
        raise InvalidMeshError(
            f"{what}: faces must hold integer vertex indices, got dtype {faces.dtype}"
        )
    n_vertices = vertices.shape[0]
    if n_vertices == 0:
        raise InvalidMeshError(f"{what}: the mesh has no vertices; give at least one triangle")
    if faces.shape[0] == 0 and require_faces:
        raise InvalidMeshError(
            f"{what}: the mesh has no faces; qem-lod simplifies triangle meshes, not point "
            "clouds: give faces (a PLY 'face' element, OBJ 'f' lines, ...)"
        )
    if n_vertices > _MAX_VERTICES:
        raise InvalidMeshError(
            f"{what}: {n_vertices} vertices is more than the {_MAX_VERTICES} int32 indices allow"
        )
    vertices = np.ascontiguousarray(vertices, dtype=np.float64)
    finite = np.isfinite(vertices).all(axis=1)
    if not finite.all():
        bad = np.flatnonzero(~finite)
        raise InvalidMeshError(
            f"{what}: vertex {bad[0]} has a non-finite coordinate "
            f"{tuple(float(x) for x in vertices[bad[0]])} ({bad.size} such vertices); "
            "remove or repair them (NaN and inf cannot be simplified)"
        )
    low = faces.min() if faces.size else 0
    high = faces.max() if faces.size else 0
    if low < 0 or high >= n_vertices:
        bad_value = low if low < 0 else high
        face = int(np.flatnonzero((faces == bad_value).any(axis=1))[0])
        reason = "is negative" if low < 0 else f"is not below the vertex count {n_vertices}"
        raise InvalidMeshError(
            f"{what}: face {face} {faces[face].tolist()} has vertex index {int(bad_value)}, "
            f"which {reason}; indices are 0-based and must lie in [0, {n_vertices - 1}]"
        )
    return vertices, np.ascontiguousarray(faces, dtype=np.int32)


def prepare_mesh(vertices: object, faces: object, merge_coincident: bool = True) -> PreparedMesh:
    """Validate and clean a triangle mesh.

    vertices : (n, 3) float, finite.
    faces : (m, 3) int in [0, n).
    merge_coincident : weld vertices whose coordinates are exactly equal (-0.0 == 0.0)
        onto the first of them, as STL triangle soups need. Attributes of welded vertices
        are the caller's business: `vertex_map` says where each went.

    Steps, in order: weld; drop degenerate faces (two corners on the same vertex after
    welding; zero-area faces on three distinct vertices are kept); drop duplicate faces
    (the same three vertices in any order or orientation: the first is kept); drop the
    vertices no kept face uses. Kept vertices and faces keep their relative input order.

    report counts, on the input: ``unreferenced_vertices`` (input vertices dropped
    because no kept face uses them or the vertex they were welded onto),
    ``merged_vertices`` (input vertices welded onto an earlier kept one), so that
    ``len(vertices) + merged_vertices + unreferenced_vertices == n``;
    ``degenerate_faces`` and ``duplicate_faces`` (faces dropped); and on the output:
    ``boundary_edges`` (edges of one face), ``non_manifold_edges`` (edges of more than
    two faces), ``components`` (sets of faces connected through shared vertices).

    Raises InvalidMeshError for bad input (see `validate_mesh_arrays`), or when no face
    is left after cleaning.
    """
    vertices, faces = validate_mesh_arrays(vertices, faces)
    n_vertices = vertices.shape[0]
    n_faces = faces.shape[0]

    if merge_coincident:
        weld_map = _weld_map(vertices)
    else:
        weld_map = np.arange(n_vertices, dtype=np.int32)
    welded_faces = weld_map[faces]

    degenerate = (
        (welded_faces[:, 0] == welded_faces[:, 1])
        | (welded_faces[:, 1] == welded_faces[:, 2])
        | (welded_faces[:, 2] == welded_faces[:, 0])
    )
    duplicate = _duplicate_faces(welded_faces, ~degenerate)
    face_kept = ~(degenerate | duplicate)
    if not face_kept.any():
        raise InvalidMeshError(
            f"all {n_faces} faces are degenerate (two corners on the same vertex); "
            "nothing is left to simplify"
        )

    # A vertex is kept when it is a weld representative used by a kept face.
    vertex_used = np.zeros(n_vertices, dtype=bool)
    vertex_used[welded_faces[face_kept].ravel()] = True
    kept_vertices = np.flatnonzero(vertex_used)
    new_index = np.full(n_vertices, -1, dtype=np.int32)
    new_index[kept_vertices] = np.arange(kept_vertices.size, dtype=np.int32)
    vertex_map = new_index[weld_map]

    out_faces = vertex_map[welded_faces[face_kept]]
    face_map = np.full(n_faces, -1, dtype=np.int32)
    face_map[face_kept] = np.arange(out_faces.shape[0], dtype=np.int32)

    n_dropped = int(np.count_nonzero(vertex_map < 0))
    n_kept = int(kept_vertices.size)
    edge_keys = _edge_keys(out_faces, n_kept)
    edge_starts = np.flatnonzero(np.concatenate(([True], edge_keys[1:] != edge_keys[:-1])))
    edge_face_counts = np.diff(np.append(edge_starts, edge_keys.size))
    unique_edges = edge_keys[edge_starts]
    report = {
        "unreferenced_vertices": n_dropped,
        "merged_vertices": n_vertices - n_dropped - n_kept,
        "degenerate_faces": int(np.count_nonzero(degenerate)),
        "duplicate_faces": int(np.count_nonzero(duplicate)),
        "non_manifold_edges": int(np.count_nonzero(edge_face_counts > 2)),
        "boundary_edges": int(np.count_nonzero(edge_face_counts == 1)),
        "components": _count_components(unique_edges // n_kept, unique_edges % n_kept, n_kept),
    }
    return PreparedMesh(
        vertices=np.ascontiguousarray(vertices[kept_vertices]),
        faces=np.ascontiguousarray(out_faces, dtype=np.int32),
        vertex_map=vertex_map,
        face_map=face_map,
        report=report,
    )


def _weld_map(vertices: np.ndarray) -> np.ndarray:
    """(n,) int32: each vertex -> the lowest-index vertex with exactly its coordinates."""
    # Adding 0.0 turns -0.0 into 0.0, so that equal coordinates have equal bits.
    bits = np.ascontiguousarray(vertices + 0.0).view(np.uint64)
    return _first_equal_rows(bits).astype(np.int32)


def _duplicate_faces(faces: np.ndarray, candidate: np.ndarray) -> np.ndarray:
    """(m,) bool: faces among `candidate` whose vertex set repeats an earlier candidate's."""
    rows = np.flatnonzero(candidate)
    a, b, c = faces[rows].T
    low = np.minimum(np.minimum(a, b), c)
    high = np.maximum(np.maximum(a, b), c)
    middle = a ^ b ^ c ^ low ^ high
    corners = np.stack([low, middle, high], axis=1).astype(np.uint64)
    first = _first_equal_rows(corners)
    duplicate = np.zeros(faces.shape[0], dtype=bool)
    duplicate[rows[first != np.arange(rows.size)]] = True
    return duplicate


def _first_equal_rows(rows: np.ndarray) -> np.ndarray:
    """(r,) int64: for each row of the (r, c) uint64 array, the index of its first equal row.

    A 64-bit hash per row finds the candidates (rows whose hash repeats, usually few);
    only those are sorted row by row, so hash collisions cost time, never correctness.
    """
    key = _row_hash(rows)
    first = np.arange(rows.shape[0], dtype=np.int64)
    sorted_key = np.sort(key)
    if not (sorted_key[1:] == sorted_key[:-1]).any():
        return first
    order = np.argsort(key)
    same_as_next = key[order[1:]] == key[order[:-1]]
    in_repeat = np.zeros(order.size, dtype=bool)
    in_repeat[1:] |= same_as_next
    in_repeat[:-1] |= same_as_next
    candidates = np.sort(order[in_repeat])
    first[candidates] = candidates[_first_equal_rows_by_lexsort(rows[candidates])]
    return first


def _first_equal_rows_by_lexsort(rows: np.ndarray) -> np.ndarray:
    """`_first_equal_rows` by sorting whole rows: exact, slower on many rows."""
    order = np.lexsort(rows.T[::-1])
    sorted_rows = rows[order]
    starts_group = np.ones(order.size, dtype=bool)
    starts_group[1:] = (sorted_rows[1:] != sorted_rows[:-1]).any(axis=1)
    group_of_sorted = np.cumsum(starts_group) - 1
    group_first = np.minimum.reduceat(order, np.flatnonzero(starts_group))
    first = np.zeros(order.size, dtype=np.int64)
    first[order] = group_first[group_of_sorted]
    return first


def _row_hash(rows: np.ndarray) -> np.ndarray:
    """(r,) uint64 hash of each row of an (r, c) uint64 array (splitmix64-style mixing)."""
    key = np.zeros(rows.shape[0], dtype=np.uint64)
    for column in rows.T:
        key = (key ^ column) * np.uint64(0x9E3779B97F4A7C15)
        key ^= key >> np.uint64(29)
    return key


def _edge_keys(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """Sorted int64 keys ``low * n_vertices + high`` of every face side (3 per face)."""
    a = faces.astype(np.int64)
    u = a.ravel()
    v = a[:, [1, 2, 0]].ravel()
    return np.sort(np.minimum(u, v) * n_vertices + np.maximum(u, v))


def _count_components(edges_low: np.ndarray, edges_high: np.ndarray, n_vertices: int) -> int:
    """Connected components of the graph of the given edges (low < high) on n vertices.

    Union-find done in bulk: hook each edge's larger root under the smaller one, then
    compress paths by pointer jumping, until no edge joins two roots (a handful of rounds
    on real scans, each on the edges still joining two roots).
    """
    parent = np.arange(n_vertices, dtype=np.int32)
    low = edges_low.astype(np.int32)
    high = edges_high.astype(np.int32)
    # In the first round every vertex is its own root: hook the edges as they are.
    root_low, root_high = low, high
    while root_low.size:
        np.minimum.at(parent, np.maximum(root_low, root_high), np.minimum(root_low, root_high))
        while True:
            jumped = parent[parent]
            if np.array_equal(jumped, parent):
                break
            parent = jumped
        root_low = parent[low]
        root_high = parent[high]
        joins = root_low != root_high
        low, high = low[joins], high[joins]
        root_low, root_high = root_low[joins], root_high[joins]
    return int(np.count_nonzero(parent == np.arange(n_vertices)))

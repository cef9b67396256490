"""Entry check and clean-up of a triangle mesh before it is simplified.

`prepare_mesh` is the single gate between user data and the kernels: it validates the
arrays (`validate_mesh_arrays`), welds vertices with exactly equal coordinates (STL
triangle soups), drops degenerate and duplicate faces and unreferenced vertices, and
reports what it found. The whole-mesh passes (equal rows, degenerate faces, the
renumbering, edges and the duplicate faces found on them, components) are O(size) numba
kernels (`_kernels/topology.py`), the rest vectorised numpy; the order of what is kept is
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

from ._kernels.adjacency import sort_chunks
from ._kernels.topology import (
    count_components,
    find_edges,
    first_equal_rows,
    mark_degenerate_faces,
    renumber_kept_faces,
    sorted_corner_keys,
)
from .errors import InvalidMeshError

__all__ = [
    "MeshEdges",
    "PreparedMesh",
    "prepare_mesh",
    "prepare_mesh_and_edges",
    "unique_edges",
    "validate_mesh_arrays",
]

# Indices are stored as int32 everywhere in qem_core.
_MAX_VERTICES = int(np.iinfo(np.int32).max)


class MeshEdges(NamedTuple):
    """The undirected edges of a prepared mesh (``find_edges``), for the build to reuse.

    edges : (E, 2) int32 (low, high) in increasing order; face_edge : (m, 3) int32, the
    edge of side k (corner k to k + 1) of each face; edge_face_count : (E,) int32;
    edge_side : (E,) int64, the last side 3 f + k on each edge.
    """

    edges: np.ndarray
    face_edge: np.ndarray
    edge_face_count: np.ndarray
    edge_side: np.ndarray


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
    try:
        vertices = np.asarray(vertices)
        faces = np.asarray(faces)
    except (TypeError, ValueError) as error:  # ragged lists, objects numpy cannot hold
        raise InvalidMeshError(f"{what}: vertices and faces must be arrays: {error}") from None
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
    return prepare_mesh_and_edges(vertices, faces, merge_coincident)[0]


def prepare_mesh_and_edges(
    vertices: object, faces: object, merge_coincident: bool = True
) -> tuple[PreparedMesh, MeshEdges]:
    """`prepare_mesh`, and the edges of the prepared mesh it found for the report."""
    vertices, faces = validate_mesh_arrays(vertices, faces)
    n_vertices = vertices.shape[0]
    n_faces = faces.shape[0]

    weld_map = (_weld_map(vertices) if merge_coincident
                else np.arange(n_vertices, dtype=np.int32))
    # Degenerate faces and the vertices the others use, in one pass. A duplicate face
    # uses the vertices of the face it repeats: dropping it drops no vertex.
    degenerate = np.empty(n_faces, np.uint8)
    vertex_used = np.zeros(n_vertices, np.uint8)
    n_degenerate = mark_degenerate_faces(faces, weld_map, degenerate, vertex_used)
    if n_degenerate == n_faces:
        raise InvalidMeshError(
            f"all {n_faces} faces are degenerate (two corners on the same vertex); "
            "nothing is left to simplify"
        )
    kept_vertices = np.flatnonzero(vertex_used)
    n_kept = int(kept_vertices.size)
    if n_kept == n_vertices:
        vertex_map = weld_map  # no vertex dropped, so none welded either
    else:
        new_index = np.full(n_vertices, -1, dtype=np.int32)
        new_index[kept_vertices] = np.arange(n_kept, dtype=np.int32)
        vertex_map = new_index[weld_map]
    out_faces = np.empty((n_faces - n_degenerate, 3), np.int32)
    renumber_kept_faces(faces, degenerate, vertex_map, out_faces)
    # The edges of the faces left find their duplicates too; in the rare mesh with any,
    # the edges are found again without them.
    mesh_edges, duplicate = _edges_and_duplicates(out_faces, n_kept)
    n_duplicate = int(np.count_nonzero(duplicate))
    kept_rows = np.flatnonzero(degenerate == 0)
    if n_duplicate:
        kept_rows = kept_rows[duplicate == 0]
        out_faces = np.ascontiguousarray(out_faces[duplicate == 0])
        mesh_edges = unique_edges(out_faces, n_kept)
    face_map = np.full(n_faces, -1, dtype=np.int32)
    face_map[kept_rows] = np.arange(kept_rows.size, dtype=np.int32)

    n_dropped = int(np.count_nonzero(vertex_map < 0))
    edge_face_counts = mesh_edges.edge_face_count
    report = {
        "unreferenced_vertices": n_dropped,
        "merged_vertices": n_vertices - n_dropped - n_kept,
        "degenerate_faces": n_degenerate,
        "duplicate_faces": n_duplicate,
        "non_manifold_edges": int(np.count_nonzero(edge_face_counts > 2)),
        "boundary_edges": int(np.count_nonzero(edge_face_counts == 1)),
        "components": int(count_components(out_faces, n_kept)),
    }
    prepared = PreparedMesh(
        # A copy, not a gather, when every vertex is kept (scans: 10 MB, 5x faster).
        vertices=(vertices.copy() if n_kept == n_vertices
                  else np.ascontiguousarray(vertices[kept_vertices])),
        faces=out_faces,
        vertex_map=vertex_map,
        face_map=face_map,
        report=report,
    )
    return prepared, mesh_edges


def unique_edges(faces: np.ndarray, n_vertices: int) -> MeshEdges:
    """The undirected edges of ``faces`` (m, 3) int32 with indices below n_vertices."""
    return _find_edges(faces, n_vertices, search_duplicates=False)[0]


def _edges_and_duplicates(faces: np.ndarray, n_vertices: int) -> tuple[MeshEdges, np.ndarray]:
    """`unique_edges`, and (m,) uint8: 1 for each face with the corners of an earlier one
    (in any order or orientation)."""
    mesh_edges, duplicate, unsearched = _find_edges(faces, n_vertices, search_duplicates=True)
    if unsearched:  # edges of very many faces: compare the faces' sorted corners instead
        duplicate = _duplicate_faces(faces)
    return mesh_edges, duplicate


def _find_edges(faces: np.ndarray, n_vertices: int, search_duplicates: bool
                ) -> tuple[MeshEdges, np.ndarray, int]:
    """(edges, duplicate flags or (0,), edges not searched): see topology.find_edges."""
    faces = np.ascontiguousarray(faces, np.int32)
    m = faces.shape[0]
    face_edge = np.empty((m, 3), np.int32)  # every side written
    # Room for 3m edges, uninitialised: rows past the count are never touched, so they
    # take no memory, and the edges are views of them, not copies (each copy's pages
    # would be faulted in afresh: 26 MB on dragon).
    edges = np.empty((3 * m, 2), np.int32)
    edge_face_count = np.empty(3 * m, np.int32)
    edge_side = np.empty(3 * m, np.int64)
    duplicate = np.zeros(m if search_duplicates else 0, np.uint8)
    n_edges, unsearched = find_edges(faces, n_vertices, face_edge, edges, edge_face_count,
                                     edge_side, sort_chunks(), duplicate)
    mesh_edges = MeshEdges(edges[:n_edges], face_edge, edge_face_count[:n_edges],
                           edge_side[:n_edges])
    return mesh_edges, duplicate, int(unsearched)


def _weld_map(vertices: np.ndarray) -> np.ndarray:
    """(n,) int32: each vertex -> the lowest-index vertex with exactly its coordinates."""
    # Adding 0.0 turns -0.0 into 0.0, so that equal coordinates have equal bits.
    bits = np.ascontiguousarray(vertices + 0.0).view(np.uint64)
    return _first_equal_rows(bits).astype(np.int32)


def _duplicate_faces(faces: np.ndarray) -> np.ndarray:
    """(m,) uint8: 1 for each face whose vertex set repeats an earlier face's."""
    corners = np.empty((faces.shape[0], 2), np.uint64)  # every row written
    sorted_corner_keys(faces, corners)
    return (_first_equal_rows(corners) != np.arange(faces.shape[0])).astype(np.uint8)


def _first_equal_rows(rows: np.ndarray) -> np.ndarray:
    """(r,) int64: for each row of the (r, c) uint64 array, the index of its first equal row."""
    first = np.zeros(rows.shape[0], dtype=np.int64)
    first_equal_rows(np.ascontiguousarray(rows), first)
    return first

"""Peer simplifiers behind one signature.

Each adapter is ``simplify(vertices, faces, target_faces) -> (vertices, faces)``:

- vertices : (n, 3) float64; faces : (m, 3) int32; unreferenced input vertices allowed.
- target_faces : the face count asked of the tool. The harness derives it from a target
  vertex count (`bench.meshes.target_counts`), because every one of these tools stops on
  a face (or index) count.
- returns vertices (k, 3) float64 holding only the referenced vertices, and faces (f, 3)
  int32. What a tool really reaches (k, f) is recorded, not assumed.

The adapter is the timed unit: conversion into the tool's own structure, the
simplification, and the copy back to numpy (plus compaction where the tool leaves
unreferenced vertices). Settings are each tool's defaults unless stated, as in
/work/shared/peer-results. Each adapter imports its tool on use; `Peer.modules` lists what
a caller should import before timing.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from .meshes import compact_referenced, warm_up_mesh

__all__ = [
    "PEERS",
    "Peer",
    "simplify_fast_simplification",
    "simplify_meshoptimizer",
    "simplify_open3d",
    "simplify_pyfqmr",
    "simplify_pymeshlab",
    "simplify_pymeshlab_quality",
    "warm_up_peer",
]

# meshoptimizer's target_error is relative to the mesh extent (1.0 = the whole mesh), so
# any value above 1 never stops it early: the index count alone decides.
_MESHOPTIMIZER_UNBOUNDED_ERROR = 1.0e9

# MeshLab's quadric edge collapse with its quality switches on: keep open borders, refuse
# normal flips, keep the topology, place optimally, add planar quadrics; the triangle
# quality threshold stays at its default (0.3). This is the "pymeshlab_quality" of
# /work/shared/peer-results: recomputed here, it reproduces that table's Hausdorff and RMS
# on spot (0.5, 0.1, 0.005), bunny (0.5, 0.1) and fandisk (0.1) within sampling noise;
# qualitythr=1 or dropping planarquadric do not.
PYMESHLAB_QUALITY_OPTIONS = {
    "preserveboundary": True,
    "preservenormal": True,
    "preservetopology": True,
    "optimalplacement": True,
    "planarquadric": True,
}


def simplify_meshoptimizer(
    vertices: np.ndarray, faces: np.ndarray, target_faces: int
) -> tuple[np.ndarray, np.ndarray]:
    """meshoptimizer `simplify` to 3 * target_faces indices, error bound lifted, then
    compacted (meshoptimizer keeps the input vertex buffer)."""
    import meshoptimizer

    indices = np.ascontiguousarray(faces, dtype=np.uint32).reshape(-1)
    destination = np.zeros(indices.size, dtype=np.uint32)
    n_indices = meshoptimizer.simplify(
        destination,
        indices,
        np.ascontiguousarray(vertices, dtype=np.float32),
        target_index_count=3 * int(target_faces),
        target_error=_MESHOPTIMIZER_UNBOUNDED_ERROR,
    )
    return compact_referenced(vertices, destination[:n_indices].reshape(-1, 3))


def simplify_fast_simplification(
    vertices: np.ndarray, faces: np.ndarray, target_faces: int
) -> tuple[np.ndarray, np.ndarray]:
    """fast_simplification `simplify(target_count=...)`, defaults (agg=7, borders free)."""
    import fast_simplification

    out_vertices, out_faces = fast_simplification.simplify(
        vertices, faces, target_count=int(target_faces)
    )
    return compact_referenced(out_vertices, out_faces)


def simplify_pyfqmr(
    vertices: np.ndarray, faces: np.ndarray, target_faces: int
) -> tuple[np.ndarray, np.ndarray]:
    """pyfqmr `simplify_mesh(target_count=...)`, defaults (aggressiveness=7,
    preserve_border=True)."""
    import pyfqmr

    simplifier = pyfqmr.Simplify()
    simplifier.setMesh(vertices, faces)
    simplifier.simplify_mesh(target_count=int(target_faces), verbose=False)
    out_vertices, out_faces, _normals = simplifier.getMesh()
    return compact_referenced(out_vertices, out_faces)


def _pymeshlab_quadric_edge_collapse(
    vertices: np.ndarray, faces: np.ndarray, target_faces: int, **options: object
) -> tuple[np.ndarray, np.ndarray]:
    import pymeshlab

    mesh_set = pymeshlab.MeshSet()
    mesh_set.add_mesh(pymeshlab.Mesh(vertex_matrix=vertices, face_matrix=faces))
    mesh_set.meshing_decimation_quadric_edge_collapse(targetfacenum=int(target_faces), **options)
    result = mesh_set.current_mesh()
    return compact_referenced(result.vertex_matrix(), result.face_matrix())


def simplify_pymeshlab(
    vertices: np.ndarray, faces: np.ndarray, target_faces: int
) -> tuple[np.ndarray, np.ndarray]:
    """PyMeshLab `meshing_decimation_quadric_edge_collapse`, default options."""
    return _pymeshlab_quadric_edge_collapse(vertices, faces, target_faces)


def simplify_pymeshlab_quality(
    vertices: np.ndarray, faces: np.ndarray, target_faces: int
) -> tuple[np.ndarray, np.ndarray]:
    """PyMeshLab quadric edge collapse with `PYMESHLAB_QUALITY_OPTIONS`."""
    return _pymeshlab_quadric_edge_collapse(
        vertices, faces, target_faces, **PYMESHLAB_QUALITY_OPTIONS
    )


def simplify_open3d(
    vertices: np.ndarray, faces: np.ndarray, target_faces: int
) -> tuple[np.ndarray, np.ndarray]:
    """Open3D `simplify_quadric_decimation(target_number_of_triangles=...)`, defaults.

    open3d-cpu needs the system library libusb-1.0 to import (Debian: libusb-1.0-0).
    """
    import open3d

    mesh = open3d.geometry.TriangleMesh(
        open3d.utility.Vector3dVector(np.ascontiguousarray(vertices, dtype=np.float64)),
        open3d.utility.Vector3iVector(np.ascontiguousarray(faces, dtype=np.int32)),
    )
    simplified = mesh.simplify_quadric_decimation(target_number_of_triangles=int(target_faces))
    return compact_referenced(np.asarray(simplified.vertices), np.asarray(simplified.triangles))


@dataclass(frozen=True)
class Peer:
    """A peer simplifier: its row name, adapter, and the modules to import before timing."""

    name: str
    simplify: Callable[[np.ndarray, np.ndarray, int], tuple[np.ndarray, np.ndarray]]
    modules: tuple[str, ...]


PEERS: dict[str, Peer] = {
    peer.name: peer
    for peer in (
        Peer("meshoptimizer", simplify_meshoptimizer, ("meshoptimizer",)),
        Peer("fast_simplification", simplify_fast_simplification, ("fast_simplification",)),
        Peer("pyfqmr", simplify_pyfqmr, ("pyfqmr",)),
        Peer("pymeshlab", simplify_pymeshlab, ("pymeshlab",)),
        Peer("pymeshlab_quality", simplify_pymeshlab_quality, ("pymeshlab",)),
        Peer("open3d", simplify_open3d, ("open3d",)),
    )
}


def warm_up_peer(simplify: Callable[[np.ndarray, np.ndarray, int], tuple]) -> None:
    """One untimed call of a peer adapter on `bench.meshes.warm_up_mesh`."""
    vertices, faces = warm_up_mesh()
    simplify(vertices, faces, len(faces) // 2)

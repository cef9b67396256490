"""The shared test meshes: where they are, how they are loaded, and the targets derived
from them.

Counts follow /work/shared/meshes/SOURCES.md: vertex fractions are taken of the
*referenced* vertex count (bunny, airplane_colored and face_rangemap store unreferenced
vertices), and a mesh is loaded with nothing merged or removed.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = [
    "DEFAULT_MESH_DIR",
    "DEFAULT_MESH_FILES",
    "BenchMesh",
    "compact_referenced",
    "count_referenced",
    "load_bench_mesh",
    "target_counts",
    "warm_up_mesh",
]

# The repository sits beside the shared folder: /work/main and /work/shared.
DEFAULT_MESH_DIR = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"

# Smallest first; spot as PLY (positions only; the OBJ splits vertices at UV seams).
DEFAULT_MESH_FILES = (
    "spot.ply",
    "fandisk.ply",
    "airplane_colored.ply",
    "bunny.ply",
    "face_rangemap.ply",
    "igea.ply",
    "dragon.ply",
)


@dataclass(frozen=True)
class BenchMesh:
    """A loaded test mesh.

    vertices : (n_stored, 3) float64, every stored vertex (unreferenced ones kept).
    faces : (n_faces, 3) int32.
    n_referenced : vertices used by at least one face; fractions are taken of this.
    bbox_diagonal : length of the bounding-box diagonal of the referenced vertices, in the
        mesh's units; errors are reported as fractions of it.
    """

    name: str
    vertices: np.ndarray
    faces: np.ndarray
    n_referenced: int
    bbox_diagonal: float

    @property
    def n_stored(self) -> int:
        return int(self.vertices.shape[0])

    @property
    def n_faces(self) -> int:
        return int(self.faces.shape[0])


def count_referenced(faces: np.ndarray) -> int:
    """Number of distinct vertex indices in `faces` ((m, 3) int)."""
    return int(np.unique(faces).size) if faces.size else 0


def compact_referenced(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop unreferenced vertices, keeping the order of the rest.

    vertices : (n, 3) float; faces : (m, 3) int.
    Returns (vertices (k, 3) float64, faces (m, 3) int32) with k = referenced count.
    """
    faces = np.asarray(faces)
    used = np.unique(faces)
    remap = np.full(len(vertices), -1, dtype=np.int64)
    remap[used] = np.arange(used.size)
    compact_vertices = np.asarray(vertices, dtype=np.float64)[used]
    return compact_vertices, remap[faces].astype(np.int32).reshape(-1, 3)


def load_bench_mesh(path: str | Path) -> BenchMesh:
    """Load a mesh file with trimesh, `process=False` (no merging, no removal).

    Raises ValueError if the file holds no triangles.
    """
    import trimesh

    path = Path(path)
    loaded = trimesh.load(path, process=False, force="mesh")
    vertices = np.ascontiguousarray(loaded.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(loaded.faces, dtype=np.int32)
    if faces.ndim != 2 or faces.shape[1] != 3 or faces.shape[0] == 0:
        raise ValueError(f"{path} holds no triangles (faces shape {faces.shape})")
    used = np.unique(faces)
    extent = vertices[used].max(axis=0) - vertices[used].min(axis=0)
    return BenchMesh(
        name=path.name,
        vertices=vertices,
        faces=faces,
        n_referenced=int(used.size),
        bbox_diagonal=float(np.linalg.norm(extent)),
    )


def target_counts(mesh: BenchMesh, fraction: float) -> tuple[int, int]:
    """(target vertices, target faces) for a fraction of the referenced vertex count.

    Same rule as /work/shared/peer-results: target V = round(fraction * referenced V), and
    target F = round(F * target V / referenced V), i.e. the input's faces-per-vertex ratio
    (about 2 on a closed surface, less on open scans like face_rangemap). Every peer is
    asked for target F, since all of them stop on a face count.
    """
    target_vertices = max(4, round(fraction * mesh.n_referenced))
    target_faces = max(4, round(mesh.n_faces * target_vertices / mesh.n_referenced))
    return target_vertices, target_faces


def warm_up_mesh() -> tuple[np.ndarray, np.ndarray]:
    """A 22-vertex, 26-face mesh for warm-up calls, never for figures: a closed part (an
    octahedron) and an open part (a 4 x 4 grid), so code for both gets loaded or compiled.

    Returns (vertices (22, 3) float64, faces (26, 3) int32).
    """
    octahedron_vertices = np.array(
        [[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=np.float64
    )
    octahedron_faces = np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    )
    side = 4
    grid_x, grid_y = np.meshgrid(np.arange(side, dtype=np.float64), np.arange(side))
    grid_vertices = np.column_stack(
        [grid_x.ravel() + 3.0, grid_y.ravel(), 0.1 * np.sin(grid_x.ravel() * grid_y.ravel())]
    )
    corner = (np.arange(side - 1)[:, None] * side + np.arange(side - 1)[None, :]).ravel()
    grid_faces = np.concatenate(
        [
            np.column_stack([corner, corner + 1, corner + side + 1]),
            np.column_stack([corner, corner + side + 1, corner + side]),
        ]
    )
    vertices = np.concatenate([octahedron_vertices, grid_vertices])
    faces = np.concatenate([octahedron_faces, grid_faces + len(octahedron_vertices)])
    return vertices, faces.astype(np.int32)

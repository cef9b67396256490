"""The progressive mesh: a base mesh plus an ordered list of vertex splits (Hoppe 1996).

Vertices are numbered in the order refinement introduces them and faces in the order
they appear, so the mesh at N vertices is vertices 0..N-1 and a prefix of the faces.
Split k (level L = n_base + k -> L + 1) undoes contraction J-1-k of the greedy run:

    before:  s at p_c                   after:  s at p_s, t = L at p_t
    faces:   F(L) of them               faces:  F(L + 1), the new ones appended,
                                                listed faces get corner s -> t

``lod(n)`` replays splits 0..n-n_base-1 over the base mesh: O(n) work and memory, no
rerun of the simplification.

Appearance attributes (built with `qem_core.build_mesh`) live on wedges (attributes.py),
numbered like the vertices in the order refinement introduces them. Split k also
restores the values of the wedges contraction J-1-k kept, brings back the wedges it
retired, and points the corners that named them back at them; ``lod_mesh(n)`` replays
both sides.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from ._kernels.refine import apply_split_run
from ._kernels.refine_wedges import apply_wedge_run
from .attributes import AttributeLayout, corner_values_to_mesh
from .errors import CorruptFileError, InvalidOptionsError
from .mesh import Mesh

__all__ = ["ProgressiveMesh", "VertexSplits", "apply_splits", "check_splits",
           "check_wedge_arrays"]


class VertexSplits(NamedTuple):
    """The splits refining lod(n_from) to lod(n_to); indices are global (level numbering).

    split_vertex : (K,) int32, s_k (always < n_from + k).
    split_positions : (K, 2, 3) float64: new position of s_k, position of t = n_from + k.
    new_faces : (F(n_to) - F(n_from), 3) int32, corners as of their birth.
    new_face_counts : (K,) int32, how many of new_faces each split appends.
    relabel_offsets : (K + 1,) int64 into relabel_faces (starts at 0).
    relabel_faces : (R,) int32 global face indices whose corner s_k becomes t.
    """

    n_from: int
    n_to: int
    faces_from: int
    split_vertex: np.ndarray
    split_positions: np.ndarray
    new_faces: np.ndarray
    new_face_counts: np.ndarray
    relabel_offsets: np.ndarray
    relabel_faces: np.ndarray


# The wedge arrays of a progressive mesh with attributes (all absent without): the
# values of the base wedges, the wedge of every face corner as of the face's birth, and
# per split (offsets (K + 1,) int64 into each run) the wedges it updates, those it
# introduces, and the corners (face * 3 + corner) it points at a new wedge.
WEDGE_ARRAYS = (
    "base_wedge_values", "face_wedge_corners",
    "wedge_update_offsets", "wedge_update_ids", "wedge_update_values",
    "wedge_new_offsets", "wedge_new_values",
    "wedge_relabel_offsets", "wedge_relabel_corners", "wedge_relabel_to",
)


class ProgressiveMesh:
    """A mesh that can be served at any vertex count between n_base and n_full.

    Build one with `qem_core.build` or `qem_core.build_mesh` (which keeps appearance
    attributes); load one with `qem_core.load`.
    """

    def __init__(
        self,
        *,
        base_vertices: np.ndarray,
        split_vertex: np.ndarray,
        split_positions: np.ndarray,
        face_corners: np.ndarray,
        level_faces: np.ndarray,
        relabel_offsets: np.ndarray,
        relabel_faces: np.ndarray,
        split_cost: np.ndarray,
        metadata: dict | None = None,
        texture: bytes | None = None,
        **wedge_arrays: np.ndarray,
    ) -> None:
        self.base_vertices = base_vertices
        self.split_vertex = split_vertex
        self.split_positions = split_positions
        self.face_corners = face_corners
        self.level_faces = level_faces
        self.relabel_offsets = relabel_offsets
        self.relabel_faces = relabel_faces
        self.split_cost = split_cost
        self.metadata = dict(metadata or {})
        self.texture = texture
        unknown = set(wedge_arrays) - set(WEDGE_ARRAYS)
        if unknown:
            raise TypeError(f"unknown progressive mesh arrays {sorted(unknown)}")
        if wedge_arrays and set(wedge_arrays) != set(WEDGE_ARRAYS):
            raise CorruptFileError("a progressive mesh with attributes lacks some wedge arrays")
        self.wedge_arrays = dict(wedge_arrays)
        # error(n) is the worst contraction made to get from n_full down to n: a suffix
        # maximum of the split costs, so it never decreases as n falls.
        suffix = np.maximum.accumulate(split_cost[::-1])[::-1] if split_cost.size else split_cost
        self._level_error = np.append(suffix, 0.0)

    @functools.cached_property
    def position_bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """(low, high) corners of the box of every position any level uses (a coarse
        level's optimal positions may leave the input's box)."""
        points = [self.base_vertices.reshape(-1, 3), self.split_positions.reshape(-1, 3)]
        everything = np.concatenate(points)
        return everything.min(axis=0), everything.max(axis=0)

    # -- sizes ---------------------------------------------------------------------
    @property
    def n_base(self) -> int:
        return int(self.base_vertices.shape[0])

    @property
    def n_splits(self) -> int:
        return int(self.split_vertex.shape[0])

    @property
    def n_full(self) -> int:
        return self.n_base + self.n_splits

    @property
    def n_faces_full(self) -> int:
        return int(self.level_faces[-1])

    @property
    def bbox(self) -> np.ndarray:
        """(2, 3) float64: min and max corner of the full mesh."""
        return np.asarray(self.metadata["bbox"], np.float64).reshape(2, 3)

    def n_faces(self, n: int) -> int:
        """Number of faces of lod(n)."""
        return int(self.level_faces[self.clamp(n) - self.n_base])

    def clamp(self, n: int) -> int:
        """The vertex count actually served for a request of n."""
        if isinstance(n, bool) or not isinstance(n, int | np.integer):
            raise InvalidOptionsError(f"a vertex count must be an integer, got {n!r}")
        return int(min(max(int(n), self.n_base), self.n_full))

    # -- levels --------------------------------------------------------------------
    def error(self, n: int) -> float:
        """Quadric error of lod(n): the largest contraction cost paid to reach it."""
        return float(self._level_error[self.clamp(n) - self.n_base])

    def errors(self) -> np.ndarray:
        """(n_full - n_base + 1,) float64, error of every level from n_base up."""
        return self._level_error.copy()

    def lod(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """The mesh at n vertices (clamped into [n_base, n_full]).

        Returns vertices (n, 3) float64 and faces (F, 3) int32; every vertex is
        referenced. The served n is ``len(vertices)``.
        """
        n = self.clamp(n)
        k = n - self.n_base
        vertices = np.zeros((n, 3))
        vertices[: self.n_base] = self.base_vertices
        faces = self.face_corners[: self.level_faces[k]].copy()
        apply_split_run(
            vertices, faces, self.split_vertex[:k], self.split_positions[:k],
            self.relabel_offsets[: k + 1], self.relabel_faces, self.n_base,
        )
        return vertices, faces

    def splits(self, n_from: int, n_to: int) -> VertexSplits:
        """The vertex splits that refine lod(n_from) into lod(n_to), n_from <= n_to."""
        n_from, n_to = self.clamp(n_from), self.clamp(n_to)
        if n_from > n_to:
            raise InvalidOptionsError(
                f"splits go from fewer to more vertices; got from={n_from} > to={n_to}"
            )
        k1, k2 = n_from - self.n_base, n_to - self.n_base
        r1, r2 = self.relabel_offsets[k1], self.relabel_offsets[k2]
        f1, f2 = self.level_faces[k1], self.level_faces[k2]
        return VertexSplits(
            n_from=n_from,
            n_to=n_to,
            faces_from=int(f1),
            split_vertex=self.split_vertex[k1:k2],
            split_positions=self.split_positions[k1:k2],
            new_faces=self.face_corners[f1:f2],
            new_face_counts=np.diff(self.level_faces[k1 : k2 + 1]).astype(np.int32),
            relabel_offsets=self.relabel_offsets[k1 : k2 + 1] - r1,
            relabel_faces=self.relabel_faces[r1:r2],
        )

    # -- attributes ----------------------------------------------------------------
    @property
    def attribute_layout(self) -> AttributeLayout | None:
        """Which appearance attributes the levels carry; None for geometry only."""
        values = self.metadata.get("attributes")
        return AttributeLayout.from_dict(values) if values and self.wedge_arrays else None

    def lod_mesh(self, n: int) -> Mesh:
        """The mesh at n vertices (clamped) with its appearance attributes: per-vertex
        colours and normals, per-corner UVs when the input had them (so seams stay
        sharp), and the input's texture. Positions and faces are those of ``lod(n)``."""
        vertices, faces = self.lod(n)
        layout = self.attribute_layout
        name = self.metadata.get("name")
        if layout is None:
            return Mesh(vertices=vertices, faces=faces, texture=self.texture, name=name)
        face_wedges, values = self.wedge_level(vertices.shape[0])
        mesh = corner_values_to_mesh(vertices, faces, face_wedges, values, layout)
        mesh.texture = self.texture
        mesh.name = name
        return mesh

    def wedge_level(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(face_wedges (F, 3) int32, wedge values (W, k) float32, as weighted) of lod(n)."""
        w = self.wedge_arrays
        k = self.clamp(n) - self.n_base
        n_base_wedges = w["base_wedge_values"].shape[0]
        new = w["wedge_new_offsets"]
        values = np.zeros((n_base_wedges + int(new[k]), w["base_wedge_values"].shape[1]),
                          np.float32)
        values[:n_base_wedges] = w["base_wedge_values"]
        face_wedges = w["face_wedge_corners"][: self.level_faces[k]].copy()
        apply_wedge_run(
            values, face_wedges, w["wedge_update_offsets"][: k + 1], w["wedge_update_ids"],
            w["wedge_update_values"], new[: k + 1], w["wedge_new_values"],
            w["wedge_relabel_offsets"][: k + 1], w["wedge_relabel_corners"],
            w["wedge_relabel_to"], n_base_wedges,
        )
        return face_wedges, values

    # -- files ---------------------------------------------------------------------
    def save(self, path) -> None:
        """Write this progressive mesh to one versioned .qpm file."""
        from .qpm import save_qpm

        save_qpm(self, path)

    def __repr__(self) -> str:
        return (
            f"ProgressiveMesh(n_base={self.n_base}, n_full={self.n_full}, "
            f"faces={self.n_faces(self.n_base)}..{self.n_faces_full})"
        )


def apply_splits(
    vertices: np.ndarray, faces: np.ndarray, splits: VertexSplits
) -> tuple[np.ndarray, np.ndarray]:
    """Refine lod(n_from) = (vertices, faces) by ``splits``; returns lod(n_to).

    The inputs are not modified. Raises InvalidOptionsError when the mesh is not at the
    level the splits start from.
    """
    check_splits(splits.n_from, splits.faces_from, splits.split_vertex, splits.new_faces,
                 splits.new_face_counts, splits.relabel_offsets, splits.relabel_faces)
    if vertices.shape[0] != splits.n_from or faces.shape[0] != splits.faces_from:
        raise InvalidOptionsError(
            f"these splits start from {splits.n_from} vertices and {splits.faces_from} "
            f"faces; the mesh has {vertices.shape[0]} and {faces.shape[0]}"
        )
    out_vertices = np.zeros((splits.n_to, 3))
    out_vertices[: splits.n_from] = vertices
    out_faces = np.concatenate([faces.astype(np.int32, copy=False), splits.new_faces])
    misses = apply_split_run(
        out_vertices, out_faces, splits.split_vertex, splits.split_positions,
        splits.relabel_offsets, splits.relabel_faces, splits.n_from,
    )
    if misses:
        raise InvalidOptionsError(f"{misses} face corners did not match the splits")
    return out_vertices, out_faces


def check_splits(
    n_from: int,
    faces_from: int,
    split_vertex: np.ndarray,
    new_faces: np.ndarray,
    new_face_counts: np.ndarray,
    relabel_offsets: np.ndarray,
    relabel_faces: np.ndarray,
) -> None:
    """Refuse split data that would index outside the mesh it refines.

    Every index the refinement kernel follows is checked against the level it is used
    at, so a damaged file or stream frame raises CorruptFileError instead of writing out
    of bounds. Vectorised: O(size of the data).
    """
    k = split_vertex.shape[0]

    def fail(what: str) -> None:
        raise CorruptFileError(f"inconsistent vertex splits: {what}")

    if new_face_counts.shape != (k,) or relabel_offsets.shape != (k + 1,):
        fail("array lengths do not match the number of splits")
    if new_faces.ndim != 2 or new_faces.shape[1] != 3:
        fail(f"faces have shape {new_faces.shape}, expected (F, 3)")
    if np.any(new_face_counts < 0) or int(new_face_counts.sum()) != new_faces.shape[0]:
        fail("new face counts do not add up to the new faces")
    if relabel_offsets[0] != 0 or relabel_offsets[-1] != relabel_faces.shape[0]:
        fail("relabel offsets do not cover the relabel list")
    if np.any(np.diff(relabel_offsets) < 0):
        fail("relabel offsets decrease")
    levels = n_from + np.arange(k)
    if np.any(split_vertex < 0) or np.any(split_vertex >= levels):
        fail("a split names a vertex that does not exist yet")
    # A face born at split k may use vertices up to n_from + k.
    born_at = np.repeat(np.arange(k), new_face_counts)
    if new_faces.size and (
        np.any(new_faces < 0) or np.any(new_faces > (n_from + born_at)[:, None])
    ):
        fail("a new face uses a vertex that does not exist at its level")
    faces_before = faces_from + np.concatenate([[0], np.cumsum(new_face_counts)[:-1]])
    relabel_at = np.repeat(np.arange(k), np.diff(relabel_offsets))
    if relabel_faces.size and (
        np.any(relabel_faces < 0) or np.any(relabel_faces >= faces_before[relabel_at])
    ):
        fail("a split relabels a face that does not exist yet")


def check_wedge_arrays(arrays: dict, level_faces: np.ndarray, layout: object) -> None:
    """Refuse wedge arrays (see WEDGE_ARRAYS) that would index outside the level they
    are used at, as `check_splits` does for the vertex side. O(size of the data)."""

    def fail(what: str) -> None:
        raise CorruptFileError(f"inconsistent wedge arrays: {what}")

    k = level_faces.shape[0] - 1
    base = arrays["base_wedge_values"]
    try:
        width = AttributeLayout.from_dict(layout).width
    except (TypeError, KeyError, ValueError):
        fail("the metadata does not describe the attributes")
    if base.ndim != 2 or base.shape[1] != width:
        fail(f"wedge values have shape {base.shape}, expected (W, {width})")
    for name in ("wedge_update_offsets", "wedge_new_offsets", "wedge_relabel_offsets"):
        offsets = arrays[name]
        if offsets.shape != (k + 1,) or np.any(np.diff(offsets) < 0):
            fail(f"{name} is not one non-decreasing offset per split")
        if offsets[0] != 0:
            fail(f"{name} does not start at 0")
    updates, new = arrays["wedge_update_offsets"], arrays["wedge_new_offsets"]
    relabels = arrays["wedge_relabel_offsets"]
    if (arrays["wedge_update_ids"].shape != (updates[-1],)
            or arrays["wedge_update_values"].shape != (updates[-1], width)
            or arrays["wedge_new_values"].shape != (new[-1], width)
            or arrays["wedge_relabel_corners"].shape != (relabels[-1],)
            or arrays["wedge_relabel_to"].shape != (relabels[-1],)):
        fail("array lengths do not match their offsets")
    corners = arrays["face_wedge_corners"]
    if corners.shape != (level_faces[-1], 3):
        fail("there is not one wedge per face corner")
    # Wedges that exist once split i is applied (index i + 1; 0 for the base).
    wedges_at = base.shape[0] + new
    born_at = np.repeat(np.arange(k + 1), np.diff(np.concatenate([[0], level_faces])))
    if corners.size and (np.any(corners < 0)
                         or np.any(corners >= wedges_at[born_at][:, None])):
        fail("a face corner names a wedge that does not exist at its level")
    update_at = np.repeat(np.arange(k), np.diff(updates))
    ids = arrays["wedge_update_ids"]
    if ids.size and (np.any(ids < 0) or np.any(ids >= wedges_at[update_at])):
        fail("a split updates a wedge that does not exist yet")
    relabel_at = np.repeat(np.arange(k), np.diff(relabels))
    to, corner = arrays["wedge_relabel_to"], arrays["wedge_relabel_corners"]
    if to.size and (np.any(to < 0) or np.any(to >= wedges_at[relabel_at + 1])
                    or np.any(corner < 0) or np.any(corner >= 3 * level_faces[relabel_at + 1])):
        fail("a split points a corner outside its level")

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
both sides, and ``splits(n1, n2)`` carries both (``VertexSplits.wedges``).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from ._kernels.refine import apply_split_run
from ._kernels.refine_wedges import apply_wedge_run
from .attributes import AttributeLayout, corner_values_to_mesh
from .codecs._images import image_media_type
from .errors import CorruptFileError, InvalidOptionsError
from .mesh import Material, Mesh
from .split_checks import (
    WEDGE_RUN_ARRAYS,
    check_level,
    check_splits,
    check_wedge_arrays,
    check_wedge_splits,
    coerced_splits,
)

__all__ = [
    "ProgressiveMesh",
    "VertexSplits",
    "WedgeSplits",
    "apply_splits",
    "apply_wedge_splits",
    "check_splits",
    "check_wedge_arrays",
    "check_wedge_splits",
]


class WedgeSplits(NamedTuple):
    """The wedge side of the splits refining lod(n_from) to lod(n_to).

    wedges_from : wedges of lod(n_from); the run's new wedges are numbered on from it.
    new_face_wedges : (F_new, 3) int32, the wedge of each corner of the new faces as of
        their birth (rows as in ``VertexSplits.new_faces``).
    update_offsets, new_offsets, relabel_offsets : (K + 1,) int64 runs per split,
        starting at 0.
    update_ids (U,) int32, update_values (U, k) float32: wedges whose values a split
        sets (scaled values, see ``AttributeLayout.scales``).
    new_values : (N, k) float32, the values of the new wedges.
    relabel_corners (R,) int64 (face * 3 + corner, global face numbers), relabel_to (R,)
        int32: corners a split points at another wedge.
    """

    wedges_from: int
    new_face_wedges: np.ndarray
    update_offsets: np.ndarray
    update_ids: np.ndarray
    update_values: np.ndarray
    new_offsets: np.ndarray
    new_values: np.ndarray
    relabel_offsets: np.ndarray
    relabel_corners: np.ndarray
    relabel_to: np.ndarray

    @property
    def wedges_to(self) -> int:
        return self.wedges_from + int(self.new_offsets[-1])


class VertexSplits(NamedTuple):
    """The splits refining lod(n_from) to lod(n_to); indices are global (level numbering).

    split_vertex : (K,) int32, s_k (always < n_from + k).
    split_positions : (K, 2, 3) float64: new position of s_k, position of t = n_from + k.
    new_faces : (F(n_to) - F(n_from), 3) int32, corners as of their birth.
    new_face_counts : (K,) int32, how many of new_faces each split appends.
    relabel_offsets : (K + 1,) int64 into relabel_faces (starts at 0).
    relabel_faces : (R,) int32 global face indices whose corner s_k becomes t.
    wedges : the appearance side (`WedgeSplits`), None for a mesh without attributes.
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
    wedges: WedgeSplits | None = None


# The wedge arrays of a progressive mesh with attributes (all absent without): the
# values of the base wedges, the wedge of every face corner as of the face's birth, and
# per split (offsets (K + 1,) int64 into each run) the wedges it updates, those it
# introduces, and the corners (face * 3 + corner) it points at a new wedge.
WEDGE_ARRAYS = ("base_wedge_values", "face_wedge_corners", *WEDGE_RUN_ARRAYS)


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
        materials: list[Material] | None = None,
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
        # A mesh of several materials: each one's look; its faces' materials are a wedge
        # value (attributes.MATERIAL_WEIGHT), given back per face by ``lod_mesh``.
        self.materials = materials
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
        referenced. The served n is ``len(vertices)``. Raises CorruptFileError when a
        split relabels a face that has no corner at its vertex (`check_splits` checks
        indices only; `qem_core.load` replays every split once, so this is for meshes
        made from arrays).
        """
        n = self.clamp(n)
        k = n - self.n_base
        vertices = np.zeros((n, 3))
        vertices[: self.n_base] = self.base_vertices
        faces = self.face_corners[: self.level_faces[k]].copy()
        misses = apply_split_run(
            vertices,
            faces,
            self.split_vertex[:k],
            self.split_positions[:k],
            self.relabel_offsets[: k + 1],
            self.relabel_faces,
            self.n_base,
        )
        if misses:
            raise CorruptFileError(
                f"inconsistent vertex splits: {misses} relabelled faces have no corner at "
                "their split's vertex"
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
        wedges = None
        if self.wedge_arrays:
            w = self.wedge_arrays

            def run(name: str, *arrays: str):
                offsets = w[name]
                a, b = offsets[k1], offsets[k2]
                return (offsets[k1 : k2 + 1] - a, *(w[array][a:b] for array in arrays))

            wedges = WedgeSplits(
                int(w["base_wedge_values"].shape[0] + w["wedge_new_offsets"][k1]),
                w["face_wedge_corners"][f1:f2],
                *run("wedge_update_offsets", "wedge_update_ids", "wedge_update_values"),
                *run("wedge_new_offsets", "wedge_new_values"),
                *run("wedge_relabel_offsets", "wedge_relabel_corners", "wedge_relabel_to"),
            )
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
            wedges=wedges,
        )

    # -- attributes ----------------------------------------------------------------
    @property
    def texture_type(self) -> str | None:
        """The media type of ``texture`` ("image/png", "image/jpeg", "image/webp", else
        "application/octet-stream"); None without a texture."""
        if self.texture is None:
            return None
        return image_media_type(self.texture) or "application/octet-stream"

    def texture_image(self, material: int | None = None) -> tuple[bytes, str]:
        """The image bytes and media type of the texture, or with several materials of
        material ``material``'s; LookupError saying what there is when there is none."""
        if self.materials is None:
            if material is not None:
                raise LookupError("it has one material; ask for its texture without one")
            if self.texture is None:
                raise LookupError("it has no texture image")
            return self.texture, self.texture_type
        if material is None:
            textured = [k for k, look in enumerate(self.materials) if look.texture is not None]
            raise LookupError(
                f"it has {len(self.materials)} materials; name one "
                f"(those with an image: {textured or 'none'})"
            )
        if not 0 <= material < len(self.materials):
            raise LookupError(f"it has {len(self.materials)} materials, not a material {material}")
        image = self.materials[material].texture
        if image is None:
            raise LookupError(f"its material {material} has no image")
        return image, image_media_type(image) or "application/octet-stream"

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
        if self.attribute_layout is None:
            return self.as_mesh(vertices, faces)
        return self.as_mesh(vertices, faces, *self.wedge_level(vertices.shape[0]))

    def as_mesh(
        self,
        vertices: np.ndarray,
        faces: np.ndarray,
        face_wedges: np.ndarray | None = None,
        wedge_values: np.ndarray | None = None,
    ) -> Mesh:
        """A level held as arrays (``lod`` and ``wedge_level``, or refined by
        ``apply_splits`` and ``apply_wedge_splits``) as a `Mesh` with this mesh's
        attributes, texture and name, as ``lod_mesh`` gives it."""
        layout = self.attribute_layout
        name = self.metadata.get("name")
        if layout is None or face_wedges is None or wedge_values is None:
            return Mesh(vertices=vertices, faces=faces, texture=self.texture, name=name)
        mesh = corner_values_to_mesh(vertices, faces, face_wedges, wedge_values, layout)
        mesh.texture = self.texture
        mesh.name = name
        if mesh.face_materials is not None:
            mesh.materials = self.materials
        return mesh

    def wedge_level(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(face_wedges (F, 3) int32, wedge values (W, k) float32, as weighted) of lod(n):
        the base wedges refined by ``splits(n_base, n)``."""
        w = self.wedge_arrays
        base_faces = w["face_wedge_corners"][: self.level_faces[0]]
        return apply_wedge_splits(
            base_faces, w["base_wedge_values"], self.splits(self.n_base, n), check=False
        )

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
    level the splits start from, CorruptFileError when the splits are not a consistent
    run of splits.
    """
    splits = coerced_splits(splits)  # checked whole, indices included
    vertices, faces = check_level(vertices, faces, splits.n_from, splits.faces_from)
    out_vertices = np.zeros((splits.n_to, 3))
    out_vertices[: splits.n_from] = vertices
    out_faces = np.concatenate([faces, splits.new_faces])
    misses = apply_split_run(
        out_vertices,
        out_faces,
        splits.split_vertex,
        splits.split_positions,
        splits.relabel_offsets,
        splits.relabel_faces,
        splits.n_from,
    )
    if misses:
        raise InvalidOptionsError(f"{misses} face corners did not match the splits")
    return out_vertices, out_faces


def apply_wedge_splits(
    face_wedges: np.ndarray, wedge_values: np.ndarray, splits: VertexSplits, check: bool = True
) -> tuple[np.ndarray, np.ndarray]:
    """Refine the wedges of lod(n_from), ``wedge_level(n_from)`` = (face_wedges (F, 3),
    wedge_values (W, k)), by ``splits``; returns those of lod(n_to). With
    `apply_splits` on the positions and faces this gives lod(n_to) exactly
    (``ProgressiveMesh.as_mesh`` makes the `Mesh`).

    The inputs are not modified. Raises InvalidOptionsError when the splits carry no
    wedges or the wedges are not at the level they start from, CorruptFileError when
    the wedge records index outside their levels (``check=False`` skips that for
    records known good).
    """
    wedges = splits.wedges
    if wedges is None:
        raise InvalidOptionsError("these splits carry no wedges (a mesh without attributes)")
    if (
        face_wedges.shape != (splits.faces_from, 3)
        or wedge_values.ndim != 2
        or (wedge_values.shape[0] != wedges.wedges_from)
    ):
        raise InvalidOptionsError(
            f"these splits start from {splits.faces_from} faces and {wedges.wedges_from} "
            f"wedges; got face wedges {face_wedges.shape} and values {wedge_values.shape}"
        )
    if check:
        check_wedge_splits(splits, wedge_values.shape[1])
        if face_wedges.size and (
            face_wedges.min() < 0 or face_wedges.max() >= wedges.wedges_from
        ):
            raise InvalidOptionsError(
                f"a face corner names a wedge outside 0..{wedges.wedges_from - 1}"
            )
    values = np.zeros((wedges.wedges_to, wedge_values.shape[1]), np.float32)
    values[: wedges.wedges_from] = wedge_values
    out = np.concatenate([face_wedges.astype(np.int32, copy=False), wedges.new_face_wedges])
    apply_wedge_run(
        values,
        out,
        wedges.update_offsets,
        wedges.update_ids,
        wedges.update_values,
        wedges.new_offsets,
        wedges.new_values,
        wedges.relabel_offsets,
        wedges.relabel_corners,
        wedges.relabel_to,
        wedges.wedges_from,
    )
    return out, values

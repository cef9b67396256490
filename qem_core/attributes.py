"""Appearance attributes as wedges: from a loaded `Mesh` into the contraction, and back.

A *wedge* is one attribute value shared by some corners of one vertex (Hoppe 1998): a
vertex inside a texture chart has one, a vertex on a UV seam or a colour border has one
per side. The corners' attributes (the OBJ's per-corner UVs, per-vertex colours, normals
and UVs) are gathered per face corner, scaled by their weights, and the distinct
(vertex, values) pairs become the wedges; the kernels (`_kernels/appearance.py`) then
carry one value row per wedge.

Scaling: an attribute difference of 1 counts like a distance of ``weight`` times the
bounding-box diagonal, so the defaults do not depend on the mesh's units. The diagonal is
that of the mesh as `build` contracts it (scaled by a power of two to a longest side in
[0.5, 1)), so the weighted values are of the size of the weights at any size of mesh.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import numpy as np

from .errors import InvalidMeshError, InvalidOptionsError
from .mesh import Mesh
from .options import BuildOptions

__all__ = ["AttributeLayout", "Wedges", "corner_values_to_mesh", "make_wedges"]

# Attributes in the order they sit in a value row, with the option that weighs them.
# The largest weighted attribute value kept: half float32's range, so that sums of a few
# stay finite when stored.
FLOAT32_HEADROOM = float(np.finfo(np.float32).max) / 2
_CHANNELS = (("uv", 2, "uv_weight"), ("color", None, "color_weight"),
             ("normal", 3, "normal_weight"))
_CHANNEL_WIDTHS = {"uv": (2,), "color": (3, 4), "normal": (3,), "material": (1,)}
# The material of a mesh of several is one more wedge value, constant over a wedge: so
# faces of two materials never share a wedge (their border is a seam, as at a UV seam),
# contractions merge wedges only within a dying face (one material), and the material
# travels in the .qpm, the levels and the split stream like any wedge value. Constant,
# it adds nothing to a cost; its weight only sets the scale it is stored at.
MATERIAL_WEIGHT = 1.0


def _is_int(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool)


class AttributeLayout(NamedTuple):
    """Where each attribute sits in a value row, and how it was scaled.

    names, widths : per attribute; ``corner_uvs``: the UVs came per corner (OBJ), so a
    level gives them back per corner; ``scales`` (m,): value row = attribute * scale.
    """

    names: tuple[str, ...]
    widths: tuple[int, ...]
    corner_uvs: bool
    scales: np.ndarray

    @property
    def width(self) -> int:
        return int(sum(self.widths))

    def offset(self, name: str) -> int:
        """Column of attribute ``name`` in a value row, -1 if absent."""
        if name not in self.names:
            return -1
        i = self.names.index(name)
        return int(sum(self.widths[:i]))

    def to_dict(self) -> dict:
        return {"names": list(self.names), "widths": list(self.widths),
                "corner_uvs": self.corner_uvs, "scales": self.scales.tolist()}

    @classmethod
    def from_dict(cls, values: object) -> AttributeLayout:
        """The layout ``to_dict`` wrote; ValueError naming what is wrong for anything
        else (a .qpm's metadata comes through here, and levels would otherwise divide by
        its scales, negate or blow up values, or index past the wedge rows)."""
        if not isinstance(values, dict):
            raise ValueError(f"attributes must be a map, not {type(values).__name__}")
        names, widths = values.get("names"), values.get("widths")
        corner_uvs, scales = values.get("corner_uvs"), values.get("scales")
        if not (isinstance(names, list) and names
                and all(isinstance(name, str) and name in _CHANNEL_WIDTHS for name in names)
                and len(set(names)) == len(names)):
            raise ValueError(f"attribute names {names!r:.80}: distinct, some of "
                             f"{sorted(_CHANNEL_WIDTHS)}")
        if not (isinstance(widths, list) and len(widths) == len(names) and all(
                _is_int(w) and w in _CHANNEL_WIDTHS[n]
                for n, w in zip(names, widths, strict=True))):
            raise ValueError(f"attribute widths {widths!r:.80} do not fit the names {names!r:.80}")
        if not isinstance(corner_uvs, bool) or (corner_uvs and "uv" not in names):
            raise ValueError(f"corner_uvs {corner_uvs!r}: a bool, true only with 'uv'")
        # Levels divide float32 values by the scales as float32: each must be one.
        low, high = float(np.finfo(np.float32).tiny), FLOAT32_HEADROOM
        if not (isinstance(scales, list) and len(scales) == sum(widths) and all(
                isinstance(x, int | float) and not isinstance(x, bool) and low <= x <= high
                for x in scales)):
            raise ValueError(f"attribute scales {scales!r:.80}: {sum(widths)} numbers in "
                             f"[{low:.3g}, {high:.3g}] (float32's normal range)")
        return cls(tuple(names), tuple(widths), corner_uvs, np.asarray(scales, np.float64))


class Wedges(NamedTuple):
    """face_wedges (m, 3) int32 over the prepared faces; values (W, k) float64, scaled."""

    face_wedges: np.ndarray
    values: np.ndarray
    layout: AttributeLayout


def make_wedges(mesh: Mesh, face_map: np.ndarray, prepared_faces: np.ndarray,
                options: BuildOptions, diagonal: float) -> Wedges | None:
    """The wedges of ``mesh`` as prepared (``face_map``: input face -> prepared face or
    -1); None when the mesh has no attribute to keep."""
    n_input = mesh.vertices.shape[0]

    # Found when an attribute first needs them: a mesh without attributes (most scans)
    # pays nothing, where the argsort alone took 17 ms of a dragon build.
    @functools.cache
    def input_faces() -> np.ndarray:
        """The input face of each prepared face."""
        kept = np.flatnonzero(face_map >= 0)
        return kept[np.argsort(face_map[kept])]

    @functools.cache
    def input_corners() -> np.ndarray:
        """(m, 3) the input vertex of each prepared corner."""
        return np.asarray(mesh.faces)[input_faces()]

    columns, names, widths, scales = [], [], [], []
    corner_uvs = False
    for name, width, weight_option in _CHANNELS:
        weight = float(getattr(options, weight_option))
        if weight == 0.0:
            continue
        if name == "uv" and mesh.corner_uvs is not None:
            values = np.asarray(mesh.corner_uvs, np.float64)
            if values.shape != (mesh.faces.shape[0], 3, 2):
                raise InvalidMeshError(
                    f"corner UVs have shape {values.shape}; expected ({mesh.faces.shape[0]}, 3, 2)"
                )
            per_corner = values[input_faces()].reshape(-1, 2)
            corner_uvs = True
        elif name in mesh.vertex_attributes:
            values = np.asarray(mesh.vertex_attributes[name], np.float64)
            if values.ndim != 2 or values.shape[0] != n_input:
                raise InvalidMeshError(
                    f"vertex attribute {name!r} has shape {values.shape}; expected ({n_input}, k)"
                )
            per_corner = values[input_corners().reshape(-1)]
        else:
            continue
        if width is not None and per_corner.shape[1] != width:
            raise InvalidMeshError(f"attribute {name!r} must have {width} components")
        if not np.isfinite(per_corner).all():
            raise InvalidMeshError(f"attribute {name!r} holds NaN or infinite values")
        # Weighted values are stored as float32 (the .qpm, the split stream's grid).
        largest = float(np.abs(per_corner).max(initial=0.0))
        if largest * weight * diagonal > FLOAT32_HEADROOM:
            raise InvalidMeshError(
                f"attribute {name!r} has values up to {largest:.3g}; weighted by "
                f"{weight_option}={weight:g} they pass the float32 range they are stored in"
            )
        columns.append(per_corner)
        names.append(name)
        widths.append(per_corner.shape[1])
        scales.extend([weight * diagonal] * per_corner.shape[1])
    if mesh.face_materials is not None:
        materials = np.asarray(mesh.face_materials)
        if materials.shape != (mesh.faces.shape[0],):
            raise InvalidMeshError(
                f"face materials have shape {materials.shape}; expected ({mesh.faces.shape[0]},)"
            )
        columns.append(np.repeat(materials[input_faces()].astype(np.float64), 3)[:, None])
        names.append("material")
        widths.append(1)
        scales.append(MATERIAL_WEIGHT * diagonal)
    if not columns:
        return None
    scale = np.asarray(scales, np.float64)
    corner_values = np.concatenate(columns, axis=1) * scale
    keys = np.concatenate([prepared_faces.reshape(-1, 1).astype(np.float64), corner_values],
                          axis=1)
    unique_rows, corner_wedge = np.unique(keys, axis=0, return_inverse=True)
    layout = AttributeLayout(tuple(names), tuple(widths), corner_uvs, scale)
    return Wedges(
        face_wedges=corner_wedge.reshape(-1, 3).astype(np.int32),
        values=np.ascontiguousarray(unique_rows[:, 1:]),
        layout=layout,
    )


def check_options_for_wedges(options: BuildOptions) -> None:
    if options.error_mode == "exact":
        raise InvalidOptionsError(
            "appearance attributes are simplified in the additive error mode only; "
            "use error_mode='additive', or set the attribute weights to 0"
        )


def corner_values_to_mesh(vertices: np.ndarray, faces: np.ndarray, face_wedges: np.ndarray,
                          wedge_values: np.ndarray, layout: AttributeLayout) -> Mesh:
    """A level as a `Mesh`: per-corner UVs when the input had them, per-vertex values
    (the mean over the vertex's corners) for everything else, in the input's units."""
    n = vertices.shape[0]
    per_corner = wedge_values[face_wedges.reshape(-1)] / layout.scales.astype(np.float32)
    corner_vertex = faces.reshape(-1)
    corners_per_vertex = np.bincount(corner_vertex, minlength=n).astype(np.float64)
    attributes: dict[str, np.ndarray] = {}
    corner_uvs = face_materials = None
    column = 0
    for name, width in zip(layout.names, layout.widths, strict=True):
        values = per_corner[:, column : column + width]
        column += width
        if name == "material":  # one per face, the same at its three corners
            face_materials = np.rint(values[0::3, 0]).astype(np.int32)
            continue
        if name == "uv" and layout.corner_uvs:
            corner_uvs = values.reshape(-1, 3, 2).astype(np.float32)
            continue
        total = np.stack([np.bincount(corner_vertex, weights=values[:, c], minlength=n)
                          for c in range(width)], axis=1)
        mean = total / np.maximum(corners_per_vertex, 1.0)[:, None]
        if name == "normal":
            length = np.linalg.norm(mean, axis=1, keepdims=True)
            mean = np.where(length > 0.0, mean / np.maximum(length, 1e-300), mean)
        attributes[name] = mean.astype(np.float32)
    return Mesh(vertices=vertices, faces=faces, vertex_attributes=attributes,
                corner_uvs=corner_uvs, face_materials=face_materials)

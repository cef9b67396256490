"""The wedge side of the split stream (version 3): the attribute grid, the quantised
wedges a client starts from, and the coder that turns a run of wedge splits into the
frame's wedge arrays and back (``_kernels/wedge_coding.py``).

stream.py range-codes the arrays (``wedge_coding.code_wedge_fields``) into each frame's
``wedges`` bytes; this module never sees bytes. Values travel as integers on a grid per attribute
(`WEDGE_BITS` over the values' range), in the attributes' own units (the progressive
mesh stores them multiplied by ``AttributeLayout.scales``).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ._kernels.wedge_coding import SplitRun, WedgeLevel, code_wedges
from .mesh import MAX_MATERIALS
from .progressive import ProgressiveMesh, VertexSplits, WedgeSplits
from .quantise import AttributeGrid, QuantisedWedges

__all__ = ["WEDGE_BITS", "WedgeArrays", "WedgeCoder", "quantised_wedges", "wedge_grid_for"]

# Grid bits of each appearance attribute: UVs 12 (an eighth of a texel of a 1024-pixel
# texture at most; each 2 more bits cost about 0.75 B a split on spot), colours 8 (the
# 8-bit colours of the files, exactly), normals 10 (0.06 degrees), materials 8 (their
# numbers, exactly: at most MAX_MATERIALS of them).
WEDGE_BITS = {"uv": 12, "color": 8, "normal": 10, "material": 8}
# The grid of an attribute spans at least this box (so that 8-bit colours and material
# numbers land on the grid exactly); UVs span their values' range.
_NOMINAL_BOX = {"color": (0.0, 1.0), "normal": (-1.0, 1.0), "material": (0.0, MAX_MATERIALS - 1.0)}


def wedge_grid_for(pm: ProgressiveMesh) -> AttributeGrid | None:
    """The grid of the appearance values any level of ``pm`` uses, per attribute
    `WEDGE_BITS` over the values' range (and the attribute's natural box); None for a
    mesh without attributes."""
    layout = pm.attribute_layout
    if layout is None:
        return None
    w = pm.wedge_arrays
    every = np.concatenate(
        [w[name] for name in ("base_wedge_values", "wedge_update_values", "wedge_new_values")]
    )
    every = _unscaled(every, pm)
    low, high = every.min(axis=0).astype(np.float64), every.max(axis=0).astype(np.float64)
    column = 0
    for name, width in zip(layout.names, layout.widths, strict=True):
        nominal_low, nominal_high = _NOMINAL_BOX.get(name, (np.inf, -np.inf))
        columns = slice(column, column + width)
        low[columns] = np.minimum(low[columns], nominal_low)
        high[columns] = np.maximum(high[columns], nominal_high)
        column += width
    bits = [WEDGE_BITS.get(name, 16) for name in layout.names]
    return AttributeGrid.over_box(layout.names, layout.widths, bits, low, high)


def quantised_wedges(pm: ProgressiveMesh, n: int) -> QuantisedWedges | None:
    """The wedges of lod(n) on ``wedge_grid_for(pm)``: what a client refining the split
    stream starts from (the server's msgpack levels carry them); None without
    attributes."""
    grid = wedge_grid_for(pm)
    if grid is None:
        return None
    face_wedges, values = pm.wedge_level(n)
    return QuantisedWedges(grid, face_wedges, grid.quantise(_unscaled(values, pm)))


def _unscaled(values: np.ndarray, pm: ProgressiveMesh) -> np.ndarray:
    """Wedge values in the attributes' own units, as ``lod_mesh`` computes them."""
    return values / pm.attribute_layout.scales.astype(np.float32)


class WedgeArrays(NamedTuple):
    """A frame's wedge side as arrays (docs/formats.md names the fields)."""

    counts: np.ndarray  # (3, k) int64: new wedges, extra updates, extra relabels per split
    symbols: np.ndarray  # uint8, one per coded corner
    backs: np.ndarray  # int64 back-distances
    rows: np.ndarray  # (rows, width) int64 value residuals


class WedgeCoder:
    """The wedge side of a stream at one end: its own copy of the level (``code_wedges``
    replays the splits' connectivity on it), the wedge of every corner and the wedges'
    quantised values, advanced frame by frame.

    connectivity : (faces (capacity, 3) int32, head, nxt) of the level held, with room
        for the faces and vertices to come (stream.py's state); face_wedges (F, 3) and
        values (W, k) its wedges on ``grid``; wedge_capacity the wedges to come;
        scales (k,) float32: encoding, the progressive mesh's attribute scales.
    """

    def __init__(
        self,
        grid: AttributeGrid,
        connectivity,
        face_wedges: np.ndarray,
        values: np.ndarray,
        wedge_capacity: int,
        scales: np.ndarray | None = None,
    ) -> None:
        faces, head, nxt = connectivity
        corner_wedge = np.full(3 * faces.shape[0], -1, np.int64)
        corner_wedge[: face_wedges.size] = face_wedges.reshape(-1)
        held = np.zeros((wedge_capacity, int(sum(grid.widths))), np.int64)
        held[: values.shape[0]] = values
        self.level = WedgeLevel(faces, head, nxt, corner_wedge, held, grid.q_max)
        self.grid = grid
        self.n_faces = face_wedges.shape[0]
        self.n_wedges = values.shape[0]
        self.scales = scales

    @property
    def face_wedges(self) -> np.ndarray:
        """(F, 3) int32, the wedge of each face corner of the level held."""
        return self.level.corner_wedge[: 3 * self.n_faces].reshape(-1, 3).astype(np.int32)

    @property
    def values(self) -> np.ndarray:
        """(W, k) int64, the wedges' grid integers at the level held."""
        return self.level.values[: self.n_wedges].copy()

    def encode(self, splits: VertexSplits) -> WedgeArrays:
        """The wedge arrays of ``splits`` (which carry their wedges); ValueError when
        they are inconsistent."""
        w = splits.wedges
        k = splits.split_vertex.shape[0]
        width = self.level.values.shape[1]
        records = w._replace(
            update_values=self._quantise(w.update_values), new_values=self._quantise(w.new_values)
        )
        fields = WedgeArrays(
            np.zeros((3, k), np.int64),
            np.zeros(64, np.uint8),
            np.zeros(64, np.int64),
            np.zeros((64, width), np.int64),
        )
        status, fields = self._code(False, splits, records, fields)
        if status:
            raise ValueError(f"inconsistent wedge splits (status {status})")
        return fields

    def decode(self, fields: WedgeArrays, run: VertexSplits) -> int:
        """Apply a frame's wedge arrays, once ``run`` (its decoded connectivity: the
        fields of VertexSplits up to relabel_faces, new faces as born) is known.
        Returns a status code of ``_kernels/wedge_coding.py`` (0: fine)."""
        width = self.level.values.shape[1]
        no_run = np.zeros(1, np.int64)
        no_values = np.zeros((0, width), np.int64)
        records = WedgeSplits(
            0, np.zeros((0, 3), np.int32), no_run, np.zeros(0, np.int32), no_values,
            no_run, no_values, no_run, np.zeros(0, np.int64), np.zeros(0, np.int32),
        )  # fmt: skip
        status, _ = self._code(True, run, records, fields)
        return status

    def _code(
        self, decoding: bool, splits: VertexSplits, records: WedgeSplits, fields: WedgeArrays
    ) -> tuple[int, WedgeArrays]:
        run = _for_kernel(SplitRun, splits[3:4] + splits[5:9], _RUN_DTYPES)
        records = _for_kernel(WedgeSplits, records, _RECORD_DTYPES)
        fields = _for_kernel(WedgeArrays, fields, _FIELD_DTYPES)
        status, symbols, backs, rows, at, n_wedges = code_wedges(
            decoding, self.level, self.n_faces, self.n_wedges, splits.n_from, run, records,
            *fields,
        )  # fmt: skip
        self.n_faces += splits.new_faces.shape[0]
        self.n_wedges = int(n_wedges)
        return int(status), fields._replace(
            symbols=symbols[: at[0]], backs=backs[: at[1]], rows=rows[: at[2]]
        )

    def _quantise(self, values: np.ndarray) -> np.ndarray:
        return self.grid.quantise(values / self.scales)


def _for_kernel(kind, values, dtypes):
    """``kind(*values)`` with each array of the dtype in ``dtypes`` (None: left as it
    is), writable and contiguous: one compiled kernel serves both ends (arrays of a
    loaded .qpm are read-only views)."""
    return kind(
        *(
            value if dtype is None else np.require(value, dtype, ["C", "W"])
            for value, dtype in zip(values, dtypes, strict=True)
        )
    )


# split_vertex, new_faces, new_face_counts, relabel_offsets, relabel_faces
_RUN_DTYPES = (np.int32, np.int32, np.int64, np.int64, np.int32)
# WedgeSplits' fields, values quantised (int64)
_RECORD_DTYPES = (
    None,
    np.int32,
    np.int64,
    np.int32,
    np.int64,
    np.int64,
    np.int64,
    np.int64,
    np.int64,
    np.int32,
)
_FIELD_DTYPES = (np.int64, np.uint8, np.int64, np.int64)

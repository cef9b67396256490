"""The tangent lattice: inner vertices placed where the split stream codes them cheaply.

Each split codes the midpoint of its two new vertices against the position of the
vertex it splits (docs/formats.md, section 2, step 6), in a frame of the edge and the
ring's normal: one value across the surface and two along it. The quadric optimum puts
the vertex anywhere along the surface within its edge, so those two cost about log2 of
the edge's length in bits each: about a third of the stream. Moving a vertex along
the surface costs its level little error, so the build moves every vertex that splits
again (an inner vertex of the contraction forest; the full level's vertices do not
move) to the point of least quadric error whose two tangent values are multiples of the
lattice step, about a sixteenth of the edge (``stream_coding.lattice_step``). The stream
codes those values in units of the step. docs/algorithm.md gives the figures.
"""

from __future__ import annotations

import numpy as np

from ._kernels.adjacency import sort_chunks
from ._kernels.lattice import flipped_moves, place_inner_vertices, split_fans
from ._kernels.quadrics import QUADRIC_SIZE, fill_face_quadrics
from .errors import CorruptFileError
from .options import WEIGHTING_CODES, BuildOptions
from .progressive import ProgressiveMesh
from .stream import grid_for

__all__ = ["LATTICE_GRID_BITS", "place_on_tangent_lattice"]

# The grid the lattice is laid on: the server's streams (positions of 16 bits). A
# stream of another grid codes the same splits exactly, as if there were no lattice.
LATTICE_GRID_BITS = 16
# How much more quadric error a vertex may take on the lattice than at its optimum
# (the build's, unrounded: so the grid's rounding counts too).
ERROR_TOLERANCE = 0.1
# A move may turn no face of the vertex's fan by more than 30 degrees.
MIN_TURN_COS = float(np.cos(np.radians(30.0)))
# Moves that flip a face are put back this many times over; if one still does, none moves.
MAX_PUT_BACK_ROUNDS = 4


def place_on_tangent_lattice(pm: ProgressiveMesh, bits: int = LATTICE_GRID_BITS) -> int:
    """Move pm's inner vertices onto the tangent lattice of the stream grid of ``bits``
    bits, in place (base_vertices and split_positions); returns how many moved. The
    grid itself does not change: no vertex moves out of it, nor one on its border. No
    face of any level is flipped by a move: a move that would is put back."""
    if pm.n_splits == 0:
        return 0
    grid = grid_for(pm, bits)
    # One row a vertex version (a slot): the base's vertices, then each split's two ends.
    originals = np.concatenate([pm.base_vertices, pm.split_positions.reshape(-1, 3)])
    before = grid.quantise(originals).astype(np.int64)
    q = before.copy()
    splits = pm.splits(pm.n_base, pm.n_full)
    vertices, full_faces = pm.lod(pm.n_full)
    weighting = pm.metadata.get("options", {}).get("weighting", BuildOptions.weighting)
    # The lattice's coordinates: the world scaled so that the grid's mean step is 1.
    scale = float(np.mean(grid.step))
    _, base_faces = pm.lod(pm.n_base)
    faces = np.zeros((pm.n_faces_full, 3), np.int32)
    faces[: base_faces.shape[0]] = base_faces
    parent, fan_offsets, fans, born = split_fans(
        faces, base_faces.shape[0], pm.n_full, splits.split_vertex, pm.n_base,
        splits.new_faces, splits.new_face_counts, splits.relabel_offsets, splits.relabel_faces,
    )  # fmt: skip
    # The full level's planes, weighted as the build weights them.
    quadrics = np.empty((pm.n_full, QUADRIC_SIZE))
    normals = np.empty((full_faces.shape[0], 3))
    fill_face_quadrics(
        (vertices - grid.origin) / scale, full_faces,
        WEIGHTING_CODES.get(weighting, WEIGHTING_CODES[BuildOptions.weighting]),
        np.empty((0, QUADRIC_SIZE)), normals, quadrics, sort_chunks(),
    )  # fmt: skip
    if parent.shape[0] != pm.n_splits:
        raise CorruptFileError("inconsistent vertex splits: a relabelled face has no corner s")
    place_inner_vertices(
        q, (originals - grid.origin) / grid.step, splits.split_vertex, parent, fan_offsets,
        fans, quadrics, normals, grid.step / scale, (1 << bits) - 1, ERROR_TOLERANCE,
        MIN_TURN_COS,
    )  # fmt: skip
    del quadrics
    moved = (q != before).any(axis=1)
    placed = originals.copy()
    placed[moved] = grid.dequantise(q[moved])
    # A move checked against its own fan may still flip a face of a coarser level,
    # where its neighbours were others: those moves are put back, until none flips.
    suspect = moved.copy()
    points = (placed - grid.origin) / scale
    for _ in range(MAX_PUT_BACK_ROUNDS):
        revert = flipped_moves(
            points, base_faces, parent, fan_offsets, fans, born, moved,
            suspect, normals,
        )  # fmt: skip
        if not revert.any():
            break
        placed[revert] = originals[revert]
        points[revert] = (originals[revert] - grid.origin) / scale
        moved &= ~revert
        suspect = revert
    else:
        placed, moved = originals, np.zeros_like(moved)
    pm.base_vertices[:] = placed[: pm.n_base]
    pm.split_positions[:] = placed[pm.n_base :].reshape(-1, 2, 3)
    pm.__dict__.pop("position_bounds", None)  # a cached property: the box is the same
    return int(moved.sum())

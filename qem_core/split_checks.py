"""Checks of vertex-split data against the levels it is used at: every index the
refinement kernels follow (``_kernels/refine.py``, ``_kernels/refine_wedges.py``) is
checked, vectorised, so that a damaged file or stream raises CorruptFileError instead of
writing out of bounds. ``progressive.py`` re-exports them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, NoReturn

import numpy as np

from .attributes import FLOAT32_HEADROOM, AttributeLayout
from .errors import CorruptFileError, InvalidOptionsError

if TYPE_CHECKING:
    from .progressive import VertexSplits

__all__ = [
    "WEDGE_RUN_ARRAYS",
    "check_level",
    "check_splits",
    "check_wedge_arrays",
    "check_wedge_splits",
    "coerced_splits",
    "decreases",
]

# The per-split runs of a progressive mesh's wedge arrays (progressive.WEDGE_ARRAYS
# puts the base values and the face corners' wedges before them).
WEDGE_RUN_ARRAYS = (
    "wedge_update_offsets", "wedge_update_ids", "wedge_update_values",
    "wedge_new_offsets", "wedge_new_values",
    "wedge_relabel_offsets", "wedge_relabel_corners", "wedge_relabel_to",
)  # fmt: skip


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
    if not _counts_add_up(new_face_counts, new_faces.shape[0]):
        fail("new face counts do not add up to the new faces")
    if relabel_offsets[0] != 0 or relabel_offsets[-1] != relabel_faces.shape[0]:
        fail("relabel offsets do not cover the relabel list")
    if decreases(relabel_offsets):
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


def coerced_splits(splits: VertexSplits) -> VertexSplits:
    """``splits`` checked whole (its counts and positions against its number of splits,
    its indices by `check_splits`, both before any narrowing: an int64 index past int32
    would wrap into range), with the dtypes the refinement kernels take.
    Raises CorruptFileError for split data that is not a run of splits."""
    k = np.shape(splits.split_vertex)[0] if np.ndim(splits.split_vertex) == 1 else -1
    integer_arrays = (
        splits.split_vertex,
        splits.new_faces,
        splits.new_face_counts,
        splits.relabel_offsets,
        splits.relabel_faces,
    )
    if k < 0 or not all(np.asarray(a).dtype.kind in "iu" for a in integer_arrays):
        raise CorruptFileError("inconsistent vertex splits: the indices are not integer arrays")
    positions = np.asarray(splits.split_positions)
    if positions.shape != (k, 2, 3) or positions.dtype.kind not in "fiu":
        raise CorruptFileError(
            f"inconsistent vertex splits: positions have shape {positions.shape}, "
            f"expected ({k}, 2, 3)"
        )
    counts = (splits.n_from, splits.n_to, splits.faces_from)
    if not all(isinstance(n, int | np.integer) and n >= 0 for n in counts):
        raise CorruptFileError(
            "inconsistent vertex splits: n_from, n_to and faces_from must be counts"
        )
    if splits.n_to != splits.n_from + k:
        raise CorruptFileError(
            f"inconsistent vertex splits: {k} splits cannot refine {splits.n_from} vertices "
            f"to {splits.n_to}"
        )
    # int32 arrays (what ProgressiveMesh.splits and the decoders give) are checked as they
    # are; others as int64, so the narrowing after the check cannot wrap.
    wide = [
        a if a.dtype == np.int32 else a.astype(np.int64) for a in map(np.asarray, integer_arrays)
    ]
    check_splits(splits.n_from, splits.faces_from, *wide)
    split_vertex, new_faces, new_face_counts, relabel_offsets, relabel_faces = wide
    return splits._replace(
        split_vertex=split_vertex.astype(np.int32, copy=False),
        split_positions=positions.astype(np.float64, copy=False),
        new_faces=new_faces.astype(np.int32, copy=False),
        new_face_counts=new_face_counts.astype(np.int32, copy=False),
        relabel_offsets=relabel_offsets.astype(np.int64, copy=False),
        relabel_faces=relabel_faces.astype(np.int32, copy=False),
    )


def check_level(vertices, faces, n_vertices: int, n_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """The mesh a run of splits starts from, as float64 (n, 3) vertices and int32 (F, 3)
    faces; InvalidOptionsError when it is not a mesh at that level."""
    vertices, faces = np.asarray(vertices), np.asarray(faces)
    if vertices.shape != (n_vertices, 3) or faces.shape != (n_faces, 3):
        raise InvalidOptionsError(
            f"these splits start from {n_vertices} vertices and {n_faces} faces; the mesh "
            f"has vertices of shape {vertices.shape} and faces of shape {faces.shape}"
        )
    if vertices.dtype.kind not in "fiu" or faces.dtype.kind not in "iu":
        raise InvalidOptionsError("vertices must be numbers and faces integers")
    if faces.size and (faces.min() < 0 or faces.max() >= n_vertices):
        raise InvalidOptionsError(f"a face uses a vertex outside 0..{n_vertices - 1}")
    return vertices.astype(np.float64, copy=False), faces.astype(np.int32, copy=False)


def check_wedge_arrays(arrays: dict, level_faces: np.ndarray, layout: object) -> None:
    """Refuse wedge arrays (see WEDGE_ARRAYS) that would index outside the level they
    are used at, as `check_splits` does for the vertex side. O(size of the data)."""
    k = level_faces.shape[0] - 1
    base = arrays["base_wedge_values"]
    try:
        checked = AttributeLayout.from_dict(layout)
    except ValueError as error:  # from_dict checks every field and names the bad one
        _wedge_failure(f"the metadata does not describe the attributes ({error})")
    width = checked.width
    if base.ndim != 2 or base.shape[1] != width:
        _wedge_failure(f"wedge values have shape {base.shape}, expected (W, {width})")
    for name in ("base_wedge_values", "wedge_update_values", "wedge_new_values"):
        values = arrays[name]
        if not np.isfinite(values).all():
            _wedge_failure(f"{name} holds a non-finite value")
        # A level divides each column by its scale in float32 (corner_values_to_mesh):
        # the build keeps what it stores within half float32's range after that.
        if (
            values.size
            and values.shape[-1] == width
            and (np.abs(values.reshape(-1, width)) / checked.scales > FLOAT32_HEADROOM).any()
        ):
            _wedge_failure(f"{name} holds values past float32's range at their scales")
    # Faces of the base are used from level 0, those born by split i from level i + 1.
    born_at = np.repeat(np.arange(k + 1), np.diff(np.concatenate([[0], level_faces])))
    _check_wedge_records(
        width,
        base.shape[0],
        level_faces,
        arrays["face_wedge_corners"],
        born_at,
        *(arrays[name] for name in WEDGE_RUN_ARRAYS),
    )


def check_wedge_splits(splits: VertexSplits, width: int) -> None:
    """`check_wedge_arrays` for the wedge run of ``splits`` (k = ``width`` columns)."""
    wedges = splits.wedges
    counts = np.asarray(splits.new_face_counts)
    if counts.dtype.kind not in "iu" or not _counts_add_up(counts, wedges.new_face_wedges.shape[0]):
        _wedge_failure("the new face counts do not add up to the new faces' wedges")
    counts = counts.astype(np.int64, copy=False)  # np.repeat takes no uint64 counts
    level_faces = splits.faces_from + np.concatenate([[0], np.cumsum(counts)])
    born_at = np.repeat(np.arange(1, counts.shape[0] + 1), counts)
    _check_wedge_records(
        width, wedges.wedges_from, level_faces, wedges.new_face_wedges, born_at, *wedges[2:]
    )


def decreases(values: np.ndarray) -> bool:
    """Whether ``values`` (1-d) ever decreases, by comparing neighbours: np.diff of int64
    offsets wraps around (0, 2^63 - 1, -2^63, -2^62, 5 has no negative step), and np.repeat
    over such steps, whose int64 sum is small, writes past the array it allocates."""
    return bool(np.any(values[1:] < values[:-1]))


def _counts_add_up(counts: np.ndarray, total: int) -> bool:
    """Whether ``counts`` (1-d, integers) are >= 0 and add up to ``total`` without
    wrapping around in int64 ((2^62, 2^62, 2^62, 2^62 + 5) adds up to 5), for the
    np.repeat over them. With no count negative, a wrap shows as a running total that
    decreases."""
    if counts.ndim != 1 or np.any(counts < 0):
        return False
    if counts.size and counts.max() > np.iinfo(np.int64).max:  # uint64 past int64
        return False
    running = np.cumsum(counts, dtype=np.int64)
    return not decreases(running) and int(running[-1] if running.size else 0) == total


def _wedge_failure(what: str) -> NoReturn:
    raise CorruptFileError(f"inconsistent wedge arrays: {what}")


def _check_wedge_records(
    width,
    wedges_before,
    level_faces,
    corners,
    born_at,
    update_offsets,
    update_ids,
    update_values,
    new_offsets,
    new_values,
    relabel_offsets,
    relabel_corners,
    relabel_to,
) -> None:
    """The checks shared by a whole progressive mesh and a run of splits: level_faces
    (K + 1,) is the face count of each level of the run, corners (F, 3) the wedges of
    faces used from level born_at (F,) on (an index into level_faces)."""
    k = level_faces.shape[0] - 1
    for name, offsets in (
        ("update", update_offsets),
        ("new wedge", new_offsets),
        ("relabel", relabel_offsets),
    ):
        if offsets.shape != (k + 1,) or decreases(offsets):
            _wedge_failure(f"the {name} offsets are not one non-decreasing offset per split")
        if offsets[0] != 0:
            _wedge_failure(f"the {name} offsets do not start at 0")
    if (
        update_ids.shape != (update_offsets[-1],)
        or update_values.shape != (update_offsets[-1], width)
        or new_values.shape != (new_offsets[-1], width)
        or relabel_corners.shape != (relabel_offsets[-1],)
        or relabel_to.shape != (relabel_offsets[-1],)
    ):
        _wedge_failure("array lengths do not match their offsets")
    if corners.shape != (born_at.shape[0], 3):
        _wedge_failure("there is not one wedge per face corner")
    # Wedges that exist at each level of the run (index i: after i splits).
    wedges_at = wedges_before + new_offsets
    if corners.size and (np.any(corners < 0) or np.any(corners >= wedges_at[born_at][:, None])):
        _wedge_failure("a face corner names a wedge that does not exist at its level")
    update_at = np.repeat(np.arange(k), np.diff(update_offsets))
    if update_ids.size and (np.any(update_ids < 0) or np.any(update_ids >= wedges_at[update_at])):
        _wedge_failure("a split updates a wedge that does not exist yet")
    relabel_at = np.repeat(np.arange(k), np.diff(relabel_offsets)) + 1
    if relabel_to.size and (
        np.any(relabel_to < 0)
        or np.any(relabel_to >= wedges_at[relabel_at])
        or np.any(relabel_corners < 0)
        or np.any(relabel_corners >= 3 * level_faces[relabel_at])
    ):
        _wedge_failure("a split points a corner outside its level")

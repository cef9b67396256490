"""Per-corner texture coordinates (`Mesh.corner_uvs`), shared by the readers and writers.

A texture seam is a position that carries different UVs on different faces. OBJ and the
PLY ``texcoord`` face list store UVs per face corner, so seams need nothing special;
glTF stores attributes per vertex, so its writer splits a position into one vertex per
distinct (position, UV) pair (`split_at_seams`) and its reader welds them back
(`weld`). The readers derive a per-vertex "uv" attribute only where no seam makes it
ambiguous (`per_vertex`).
"""

from __future__ import annotations

import numpy as np

from ..errors import InvalidMeshError

_HASH_MULTIPLIER = np.uint64(0x9E3779B97F4A7C15)  # 2^64 / golden ratio, odd

__all__ = ["checked_corner_uvs", "finite_float32", "per_vertex", "split_at_seams", "weld"]


def checked_corner_uvs(values: object, n_faces: int, label: str) -> np.ndarray:
    """`values` as a C-contiguous (n_faces, 3, 2) float32 array of finite numbers.

    Raises InvalidMeshError naming the wrong shape, type or the first bad face.
    """
    array = np.asarray(values)
    if array.shape != (n_faces, 3, 2):
        raise InvalidMeshError(
            f"{label}: corner_uvs must have shape ({n_faces}, 3, 2), one (u, v) per face "
            f"corner, got {array.shape}"
        )
    return finite_float32(array, f"{label}: corner_uvs", "face", "them")


def finite_float32(values: np.ndarray, what: str, item: str, fix: str) -> np.ndarray:
    """`values` (numbers) as C-contiguous float32, all finite.

    what : the array in messages ("mesh: corner_uvs"); item : what a row is ("face").
    Raises InvalidMeshError for another dtype, or naming the first row holding NaN or
    infinity and saying to repair or drop `fix`.
    """
    if values.dtype.kind not in "fiu":
        raise InvalidMeshError(f"{what} must hold numbers, got dtype {values.dtype}")
    array = np.ascontiguousarray(values, dtype=np.float32)
    finite = np.isfinite(array).reshape(array.shape[0], array[:1].size).all(axis=1)
    if not finite.all():
        row = int(np.flatnonzero(~finite)[0])
        raise InvalidMeshError(
            f"{what} of {item} {row} is {array[row].tolist()}; NaN and infinite values "
            f"are refused: repair or drop {fix}"
        )
    return array


def per_vertex(
    corner_vertices: np.ndarray, corner_values: np.ndarray, n_vertices: int
) -> np.ndarray | None:
    """(n, k) values per vertex from one value per corner, or None where a vertex
    carries different values at different corners (a seam). Vertices no corner uses get
    zeros.

    corner_vertices : (c,) vertex index of each corner; corner_values : (c, k).
    """
    per_vertex_values = np.zeros((n_vertices, corner_values.shape[1]), corner_values.dtype)
    per_vertex_values[corner_vertices] = corner_values
    if np.array_equal(per_vertex_values[corner_vertices], corner_values):
        return per_vertex_values
    return None


def split_at_seams(
    faces: np.ndarray, corner_uvs: np.ndarray, n_vertices: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One output vertex per distinct (vertex, corner UV) pair, for per-vertex formats.

    Returns (source, uvs, new_faces): source (k,) int64, the input vertex each output
    vertex copies; uvs (k, 2) float32; new_faces (m, 3) indices of output vertices.
    Output vertices come in the order of their input vertex, then of first use; a vertex
    no face uses is kept once, with UV (0, 0), so every position survives. Without seams
    the output is the input (source is 0..n-1).
    """
    corner_vertices = faces.reshape(-1).astype(np.int64)
    uv_bits = np.ascontiguousarray(corner_uvs, dtype=np.float32).reshape(-1, 2).view(np.uint32)
    unused = np.setdiff1d(np.arange(n_vertices, dtype=np.int64), corner_vertices)
    keys = np.empty((corner_vertices.size + unused.size, 3), dtype=np.int64)
    keys[: corner_vertices.size, 0] = corner_vertices
    keys[: corner_vertices.size, 1:] = uv_bits
    keys[corner_vertices.size :, 0] = unused
    keys[corner_vertices.size :, 1:] = 0  # the bits of +0.0
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    source = unique[:, 0]
    uvs = unique[:, 1:].astype(np.uint32).view(np.float32)
    new_faces = inverse.reshape(-1)[: corner_vertices.size].reshape(-1, 3)
    return source, np.ascontiguousarray(uvs), new_faces


def weld(columns: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Merge rows that are bit for bit equal in every column (positions, normals...).

    columns : arrays with n rows each.
    Returns (kept, index): kept (k,) the first row of each group, in their original
    order; index (n,) the group of each row, so row i becomes output row index[i].
    Without duplicates, kept is 0..n-1 and index too.

    Rows are sorted by a 64-bit hash of their bytes (a tenth of the time of sorting the
    rows themselves); equal rows then lie side by side. Should two different rows share
    a hash, the rows themselves are sorted instead, so the answer is always exact.
    """
    n_rows = columns[0].shape[0]
    if n_rows == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    row_width = sum(int(np.prod(c.shape[1:])) * c.itemsize for c in columns)
    row_bytes = np.concatenate(
        [np.ascontiguousarray(c).reshape(n_rows, -1).view(np.uint8) for c in columns]
        + [np.zeros((n_rows, -row_width % 8), np.uint8)],
        axis=1,
    )
    words = np.ascontiguousarray(row_bytes).view(np.uint64)
    hashes = np.zeros(n_rows, dtype=np.uint64)
    for column in words.T:
        hashes = (hashes * _HASH_MULTIPLIER) ^ column
    order = np.argsort(hashes, kind="stable")
    sorted_words = words[order]
    same_row = (sorted_words[1:] == sorted_words[:-1]).all(axis=1)
    if np.any(~same_row & (hashes[order][1:] == hashes[order][:-1])):
        order = np.lexsort(words.T[::-1])  # a hash collision: sort the rows themselves
        sorted_words = words[order]
        same_row = (sorted_words[1:] == sorted_words[:-1]).all(axis=1)
    if not same_row.any():
        return np.arange(n_rows), np.arange(n_rows)
    starts = np.concatenate([[True], ~same_row])
    group_of_sorted = np.cumsum(starts) - 1
    first = order[starts]  # both sorts are stable: a run starts with its lowest row
    by_first = np.argsort(first, kind="stable")
    rank = np.empty_like(by_first)
    rank[by_first] = np.arange(by_first.size)
    index = np.empty(n_rows, dtype=np.int64)
    index[order] = rank[group_of_sorted]
    return first[by_first], index

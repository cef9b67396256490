"""Vertex splits applied to a mesh, the one kernel behind `lod` and `apply_splits`.

Split k refines level L = n_base + k to L + 1: vertex s_k moves to its new position, the
new vertex t = L appears, the new faces are appended, and in each face listed for the
split the corner that was s_k becomes t (Hoppe 1996, with an explicit face list instead of
the one-ring walk, so non-manifold splits need no special case).
"""

import numba


def _apply_split_run(vertices, faces, split_vertex, split_positions, relabel_offsets,
                     relabel_faces, first_new_vertex):
    """Apply splits 0..K-1 of the given arrays to ``vertices`` and ``faces`` in place.

    vertices : (>= first_new_vertex + K, 3) float64, rows of new vertices are written.
    faces : (F, 3) int32 already holding every face the splits append (corners as of
        their birth); corners of listed faces are rewritten.
    relabel_offsets : (K + 1,) int64 into relabel_faces, relative to the run.
    Returns the number of relabels that found no corner s_k (0 for consistent data).
    """
    misses = 0
    for k in range(split_vertex.shape[0]):
        s = split_vertex[k]
        t = first_new_vertex + k
        for d in range(3):
            vertices[s, d] = split_positions[k, 0, d]
            vertices[t, d] = split_positions[k, 1, d]
        for r in range(relabel_offsets[k], relabel_offsets[k + 1]):
            f = relabel_faces[r]
            if faces[f, 0] == s:
                faces[f, 0] = t
            elif faces[f, 1] == s:
                faces[f, 1] = t
            elif faces[f, 2] == s:
                faces[f, 2] = t
            else:
                misses += 1
    return misses


apply_split_run = numba.njit(cache=True)(_apply_split_run)

"""Wedge splits: the attribute side of a vertex split, the kernel behind `lod_mesh`.

Split k undoes contraction J-1-k on the wedges as `refine.py` does on the vertices: the
wedges that survived it get back their values from before it, the wedges it retired
reappear (numbered from the first new wedge on), and the corners that named a retired
wedge name it again.
"""

import numba


def _apply_wedge_run(values, face_wedges, update_offsets, update_ids, update_values,
                     new_offsets, new_values, relabel_offsets, relabel_corners, relabel_to,
                     first_new_wedge):
    """Apply wedge splits 0..K-1 in place.

    values : (>= first_new_wedge + new_offsets[K] - new_offsets[0], k) float32.
    face_wedges : (F, 3) int32, every face the splits append already in place.
    *_offsets : (K + 1,) int64 runs per split, absolute into their arrays;
    the new wedges of the run are numbered from first_new_wedge on.
    relabel_corners : (R,) int64 face * 3 + corner.
    """
    k_splits = update_offsets.shape[0] - 1
    new_base = new_offsets[0]
    for k in range(k_splits):
        for u in range(update_offsets[k], update_offsets[k + 1]):
            for d in range(values.shape[1]):
                values[update_ids[u], d] = update_values[u, d]
        for w in range(new_offsets[k], new_offsets[k + 1]):
            for d in range(values.shape[1]):
                values[first_new_wedge + w - new_base, d] = new_values[w, d]
        for r in range(relabel_offsets[k], relabel_offsets[k + 1]):
            corner = relabel_corners[r]
            face_wedges[corner // 3, corner % 3] = relabel_to[r]


apply_wedge_run = numba.njit(cache=True)(_apply_wedge_run)

"""Runs of the contraction record, gathered in another order.

The record keeps, per contraction j, a run ``values[end[j-1] : end[j]]`` (faces killed,
faces relabelled). The progressive mesh wants the same runs for split k = J-1-j: the runs
in reverse order, each run's own order kept; a parallel round's records are merged in
order of cost (record.py). A slice per run in Python cost ~0.3 s per half a million
contractions; this is one pass.
"""

import numba
import numpy as np


def _gather_runs(values, ends, order, out):
    """out[...] = the runs of ``values`` ending at ``ends``, taken in ``order``, each run's
    own order kept.

    values : (>= ends[-1],); ends : increasing run ends; order : run numbers; out :
    (total length of those runs,) of values' dtype, filled.
    """
    cursor = 0
    for j in order:
        start = ends[j - 1] if j > 0 else 0
        for i in range(start, ends[j]):
            out[cursor] = values[i]
            cursor += 1


gather_runs = numba.njit(cache=True)(_gather_runs)


def _merge_by_running_max(costs, part_ends, order):
    """order (N,) out: the rows of ``costs`` merged part by part on running maxima.

    costs : (N,) float64, the parts' costs one part after another, part p ending at row
    part_ends[p]. Each part's rows keep their order; the next row taken is the head of
    the part whose running maximum (its costs so far, the head's included) is smallest,
    ties to the lower part. The same order as a stable sort of the running maxima by
    (value, part), NaN after every number as numpy sorts it, in one pass: a round's
    parts are each in cost order already (np.lexsort and its keys took ~10 ms of a
    dragon build's 42 ms of merging).
    """
    n_parts = part_ends.shape[0]
    head = np.empty(n_parts, np.int64)
    running = np.full(n_parts, -np.inf)
    for p in range(n_parts):
        head[p] = part_ends[p - 1] if p > 0 else 0
    for i in range(order.shape[0]):
        best = -1
        best_value = 0.0
        for p in range(n_parts):
            h = head[p]
            if h == part_ends[p]:
                continue
            value = costs[h]
            if running[p] != running[p]:
                value = running[p]  # NaN stays
            elif value <= running[p]:
                value = running[p]  # else the head's cost (larger, or NaN) is the maximum
            # Strictly less, NaN last: ties keep the lower part.
            if best < 0 or (value == value and (best_value != best_value or value < best_value)):
                best = p
                best_value = value
        order[i] = head[best]
        head[best] += 1
        running[best] = best_value


merge_by_running_max = numba.njit(cache=True)(_merge_by_running_max)

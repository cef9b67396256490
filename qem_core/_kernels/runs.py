"""Runs of the contraction record, gathered in another order.

The record keeps, per contraction j, a run ``values[end[j-1] : end[j]]`` (faces killed,
faces relabelled). The progressive mesh wants the same runs for split k = J-1-j: the runs
in reverse order, each run's own order kept; a parallel round's records are merged in
order of cost (record.py). A slice per run in Python cost ~0.3 s per half a million
contractions; this is one pass.
"""

import numba


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

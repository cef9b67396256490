"""The contraction record (`_kernels.contract.Record`): made, grown, and merged.

A record lists every contraction (a, b) -> c in order, with its runs of killed and
relabelled faces (and wedge logs) stored as one flat array each, cut by ``*_end``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ._kernels.contract import (
    STATUS_NEED_RELABEL_SPACE,
    STATUS_NEED_WEDGE_SPACE,
    Record,
)
from ._kernels.runs import gather_runs, merge_by_running_max

__all__ = ["make_record", "grown", "with_room_for", "append_merged", "permuted"]


def make_record(n: int, m: int, n_wedges: int = 0, k: int = 0) -> Record:
    """An empty record for at most n contractions of m faces (n_wedges wedges of k
    values).

    Only ``counts`` is set: every other array is read only up to what its count (or its
    run ends) says was written, so the rest is left uninitialised. Filling it cost ~20 ms
    of a dragon build (a record a part a round), and writing the values of the rows
    never used. Filling them with sentinel values instead left every level
    byte-identical (bench meshes, with pairs, exact error and volume preservation)."""
    wedge_capacity = 2 * n_wedges + 64 if n_wedges else 0
    return Record(
        a=np.empty(n, np.int32),
        b=np.empty(n, np.int32),
        position_a=np.empty((n, 3)),
        position_b=np.empty((n, 3)),
        cost=np.empty(n),
        killed_end=np.empty(n, np.int64),
        killed=np.empty(m, np.int32),
        relabel_end=np.empty(n, np.int64),
        relabel=np.empty(max(8 * n, 64), np.int32),
        wedge_log_end=np.empty(n if n_wedges else 0, np.int64),
        wedge_log=np.empty((wedge_capacity, 2), np.int32),
        wedge_log_values=np.empty((wedge_capacity, k)),
        wedge_relabel_end=np.empty(n if n_wedges else 0, np.int64),
        wedge_relabel=np.empty((wedge_capacity, 3), np.int32),
        counts=np.zeros(5, np.int64),
    )


def grown(array: np.ndarray, fill, at_least: int = 0) -> np.ndarray:
    """``array`` in one twice as long (or at_least rows), the new rows set to fill."""
    bigger = np.full((max(2 * array.shape[0], at_least),) + array.shape[1:], fill, array.dtype)
    bigger[: array.shape[0]] = array
    return bigger


def with_room_for(record: Record, status: int) -> Record:
    """The record with its full array grown, for the loop's STATUS_NEED_RELABEL_SPACE
    or STATUS_NEED_WEDGE_SPACE."""
    if status == STATUS_NEED_RELABEL_SPACE:
        return record._replace(relabel=grown(record.relabel, -1))
    if status == STATUS_NEED_WEDGE_SPACE:
        return record._replace(
            wedge_log=grown(record.wedge_log, -1),
            wedge_log_values=grown(record.wedge_log_values, 0.0),
            wedge_relabel=grown(record.wedge_relabel, -1),
        )
    raise ValueError(f"status {status} asks for no record space")


def append_merged(record: Record, parts: Sequence[Record]) -> Record:
    """``record`` followed by the contractions of ``parts`` (records of geometry alone,
    of disjoint parts of the complex), merged by cost.

    Each part keeps its own order (a contraction may rely on the ones before it in its
    part, never on another part's), and within that the cheapest goes first: the merge
    is on the running maximum of each part's costs, ties to the lower part. Returns the
    record, grown where it had to be."""
    counts = [int(part.counts[0]) for part in parts]
    if sum(counts) == 0:
        return record
    order = np.empty(sum(counts), np.int64)  # rows of the parts' concatenation
    merge_by_running_max(np.concatenate([p.cost[:c] for p, c in zip(parts, counts, strict=True)]),
                         np.cumsum(counts), order)

    def merge_into(field: str, out: np.ndarray) -> None:
        """out <- the parts' rows of ``field`` in merged order, gathered straight into
        it (mode "clip": the rows are all in range, and "raise" buffers ``out``)."""
        rows = [getattr(p, field)[:c] for p, c in zip(parts, counts, strict=True)]
        np.take(np.concatenate(rows), order, axis=0, out=out, mode="clip")

    def runs_length(end_field: str) -> int:
        return sum(int(getattr(p, end_field)[c - 1]) if c else 0
                   for p, c in zip(parts, counts, strict=True))

    def merge_runs_into(field: str, end_field: str, out: np.ndarray) -> np.ndarray:
        """out <- the runs' items in merged order, gathered straight into it (no
        merged copy beside the record: a big build's peak memory); returns their
        lengths."""
        items, ends = [], []
        base = 0
        for p, c in zip(parts, counts, strict=True):
            end = getattr(p, end_field)[:c]
            length = int(end[-1]) if c else 0
            items.append(getattr(p, field)[:length])
            ends.append(end + base)
            base += length
        all_ends = np.concatenate(ends)
        gather_runs(np.concatenate(items), all_ends, order, out)
        return np.diff(all_ends, prepend=0)[order]

    j0, killed0, relabel0 = (int(x) for x in record.counts[:3])
    total = sum(counts)
    n_killed, n_relabel = runs_length("killed_end"), runs_length("relabel_end")
    if relabel0 + n_relabel > record.relabel.shape[0]:
        record = record._replace(relabel=grown(record.relabel, -1, relabel0 + n_relabel))
    span = slice(j0, j0 + total)
    for field in ("a", "b", "position_a", "position_b", "cost"):
        merge_into(field, getattr(record, field)[span])
    killed_lengths = merge_runs_into("killed", "killed_end",
                                     record.killed[killed0:killed0 + n_killed])
    record.killed_end[span] = killed0 + np.cumsum(killed_lengths)
    relabel_lengths = merge_runs_into("relabel", "relabel_end",
                                      record.relabel[relabel0:relabel0 + n_relabel])
    record.relabel_end[span] = relabel0 + np.cumsum(relabel_lengths)
    record.counts[0] = j0 + total
    record.counts[1] = killed0 + n_killed
    record.counts[2] = relabel0 + n_relabel
    return record


def permuted(record: Record, order: np.ndarray) -> Record:
    """The record's first ``len(order)`` contractions in ``order`` (new position -> old
    contraction), each with its own runs; a record of just those, sized to fit. Only
    for an order that keeps each contraction after those it relies on (sweeps.py)."""
    j_count = order.shape[0]

    def rows_of_runs(ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The rows of the runs ending at ``ends`` in ``order``, and the new ends."""
        ends = ends[:j_count]
        total = int(ends[-1]) if j_count else 0
        rows = np.empty(total, np.int64)
        gather_runs(np.arange(total, dtype=np.int64), ends, order, rows)
        return rows, np.cumsum(np.diff(ends, prepend=0)[order]).astype(np.int64)

    killed_rows, killed_end = rows_of_runs(record.killed_end)
    relabel_rows, relabel_end = rows_of_runs(record.relabel_end)
    if record.wedge_log_end.shape[0]:
        log_rows, wedge_log_end = rows_of_runs(record.wedge_log_end)
        relabel_wedge_rows, wedge_relabel_end = rows_of_runs(record.wedge_relabel_end)
    else:  # a record of geometry alone keeps its empty wedge arrays
        log_rows = relabel_wedge_rows = np.zeros(0, np.int64)
        wedge_log_end = wedge_relabel_end = record.wedge_log_end
    sizes = (killed_rows, relabel_rows, log_rows, relabel_wedge_rows)
    counts = np.array([j_count, *(rows.size for rows in sizes)], np.int64)
    return Record(
        a=record.a[order],
        b=record.b[order],
        position_a=record.position_a[order],
        position_b=record.position_b[order],
        cost=record.cost[order],
        killed_end=killed_end,
        killed=record.killed[killed_rows],
        relabel_end=relabel_end,
        relabel=record.relabel[relabel_rows],
        wedge_log_end=wedge_log_end,
        wedge_log=record.wedge_log[log_rows],
        wedge_log_values=record.wedge_log_values[log_rows],
        wedge_relabel_end=wedge_relabel_end,
        wedge_relabel=record.wedge_relabel[relabel_wedge_rows],
        counts=counts,
    )

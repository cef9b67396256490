"""Numpy's huge-page advice, turned off while a build allocates its working arrays.

On Linux numpy asks for transparent huge pages (``madvise(MADV_HUGEPAGE)``) on every
array of 4 MiB or more. A dragon build allocates about 880 MiB of such arrays. On this
project's machines (four fresh processes each way, getrusage around each build) its first
build in a process spent 0.66-0.76 s of system time with the advice and 0.18-0.23 s
without, and took 2574-2612 ms instead of 3048-3096 ms (0.84x); the builds after it,
which mostly reuse memory the process already holds, took 2441-2492 ms instead of
2388-2460 ms (1.01x). The time is not compaction (/proc/vmstat's compact_stall stayed 0
over such builds, measured 2026-12-03, with 139-144 huge pages faulted in each): a fresh
process's huge pages come from memory the virtual machine has not touched yet, whose first
write the host pays for, where small pages mostly come from pages freed a moment before;
the second build's 139 huge pages cost about what its small pages do (217-224 ms of
system time).

The setting is numpy's, process-wide, so it is switched off on the first build to enter
and restored when the last one leaves; an array another thread allocates meanwhile only
gets small pages. Where numpy has no such switch, nothing is changed.
"""

from __future__ import annotations

import threading
from collections.abc import Iterator
from contextlib import contextmanager

try:  # numpy 2
    from numpy._core.multiarray import _set_madvise_hugepage
except ImportError:  # numpy 1.26, or a numpy without the switch
    try:
        from numpy.core.multiarray import _set_madvise_hugepage
    except ImportError:
        _set_madvise_hugepage = None

_lock = threading.Lock()
_depth = 0
_saved = False


@contextmanager
def without_huge_page_advice() -> Iterator[None]:
    """Numpy allocates without ``MADV_HUGEPAGE`` inside this block (see the module)."""
    global _depth, _saved
    if _set_madvise_hugepage is None:
        yield
        return
    with _lock:
        if _depth == 0:
            _saved = _set_madvise_hugepage(False)
        _depth += 1
    try:
        yield
    finally:
        with _lock:
            _depth -= 1
            if _depth == 0:
                _set_madvise_hugepage(_saved)

"""A build worker may keep the memory its builds free, for its next build (opt-in).

glibc gives a freed block of 128 KiB or more back to the kernel at once (the threshold
rises towards 32 MiB as such blocks are freed), so every build faults its arrays' pages
in afresh, and a page fault costs several microseconds on virtual machines like these.
Three dragon builds in one process faulted in 410, 410 and 350 MiB; told to serve
blocks up to ``keep_bytes`` (512 MiB) from its heap and to trim the heap only when more
than that lies free at its top, the process faulted in 340, 35 and 0 MiB, and its
second and third builds took 2.06 and 2.02 s against 2.16 and 2.23 s (medians of three
processes each way, alternated in one sitting, 2026-12-03: 0.95x and 0.91x).

The price is memory, and it is not bounded by ``keep_bytes``: blocks freed below one
still in use are never given back, and with this setting most of a build's arrays come
from the heap, so an idle worker may hold about the peak of its largest build (dragon:
618 MB after its builds against 214 MB). Hence off by default
(``QEM_WORKER_KEEP_MEMORY_BYTES=0``): for a deployment that builds many meshes of
known size and has the memory for one peak per worker. It is the worker process's own
setting (`server.jobs.local` calls this when a worker starts), never the library's:
qem_core leaves the C library alone.
"""

from __future__ import annotations

import ctypes
import sys

__all__ = ["MAX_KEEP_BYTES", "keep_freed_memory"]

# mallopt's parameters (glibc's malloc.h).
_M_TRIM_THRESHOLD = -1
_M_MMAP_THRESHOLD = -3
# mallopt takes an int.
MAX_KEEP_BYTES = 2**31 - 1
# glibc before 2.35 refuses an mmap threshold above HEAP_MAX_SIZE / 2, 32 MiB on 64-bit.
OLD_GLIBC_MAX_MMAP_THRESHOLD = 32 * 2**20


def keep_freed_memory(keep_bytes: int) -> int:
    """Let this process keep up to ``keep_bytes`` of freed memory at the top of its heap
    and serve blocks up to that size from the heap (module docstring). Returns the
    largest block size now served from the heap: ``keep_bytes``, or 32 MiB where an older
    glibc refuses more; 0 where nothing was set (0 asked, not Linux, no ``mallopt``: a C
    library other than glibc)."""
    if keep_bytes <= 0 or not sys.platform.startswith("linux"):
        return 0
    if keep_bytes > MAX_KEEP_BYTES:
        raise ValueError(f"keep_bytes={keep_bytes} is above {MAX_KEEP_BYTES}")
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library this process runs on
    except (OSError, AttributeError):
        return 0
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    if mallopt(_M_TRIM_THRESHOLD, keep_bytes) != 1:
        return 0
    for threshold in (keep_bytes, min(keep_bytes, OLD_GLIBC_MAX_MMAP_THRESHOLD)):
        if mallopt(_M_MMAP_THRESHOLD, threshold) == 1:
            return threshold
    return 0

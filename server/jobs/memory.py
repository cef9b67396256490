"""A build worker keeps the memory its builds free, for its next build.

glibc gives a freed block of 128 KiB or more back to the kernel at once (the threshold
rises towards 32 MiB as such blocks are freed), so every build faults its arrays' pages
in afresh, and a page fault costs several microseconds on virtual machines like these.
Three dragon builds in one process faulted in 410, 410 and 350 MiB; told to serve
blocks up to ``keep_bytes`` (512 MiB) from its heap and to trim the heap only when more
than that lies free at its top, the process faulted in 340, 35 and 0 MiB, and its
second and third builds took 2.06 and 2.02 s against 2.16 and 2.23 s (medians of three
processes each way, alternated in one sitting, 2026-12-03: 0.95x and 0.91x). An idle
worker then held 618 MB against 214 MB.

The price is memory: an idle worker holds up to ``keep_bytes`` that its last build
freed. It is the worker process's own setting (`server.jobs.local` calls this when a
worker starts), never the library's: qem_core leaves the C library alone.
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


def keep_freed_memory(keep_bytes: int) -> bool:
    """Let this process keep up to ``keep_bytes`` of freed memory for reuse (module
    docstring). Returns whether the C library took it: False for 0, and where it is not
    glibc (no ``mallopt``, or one that refuses)."""
    if keep_bytes <= 0 or not sys.platform.startswith("linux"):
        return False
    if keep_bytes > MAX_KEEP_BYTES:
        raise ValueError(f"keep_bytes={keep_bytes} is above {MAX_KEEP_BYTES}")
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the C library this process runs on
    except (OSError, AttributeError):
        return False
    mallopt.argtypes = (ctypes.c_int, ctypes.c_int)
    mallopt.restype = ctypes.c_int
    # Blocks up to keep_bytes come from the heap (larger ones are mapped as before), and
    # the heap is trimmed only above keep_bytes free at its top.
    return (mallopt(_M_MMAP_THRESHOLD, keep_bytes) == 1
            and mallopt(_M_TRIM_THRESHOLD, keep_bytes) == 1)

"""A build worker can keep freed memory for its next build (server/jobs/memory.py,
opt-in): the pages of an array freed and allocated again are not faulted in again, where
with the C library's defaults they are; and the worker sets it from its settings."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
from pydantic import ValidationError

from server.jobs import local
from server.jobs.memory import MAX_KEEP_BYTES, keep_freed_memory
from server.settings import Settings

# In a fresh interpreter: the setting is process-wide. Prints what keep_freed_memory
# returned and the pages faulted in when a 48 MiB array, written, freed, is allocated and
# written again, as a share of its pages.
REFAULTED = """
import ctypes, resource, sys
import numpy as np
from server.jobs.memory import keep_freed_memory
# Small pages, each a fault of its own, whatever the machine's huge-page setting:
# PR_SET_THP_DISABLE for this process, and no huge-page advice from numpy.
ctypes.CDLL(None).prctl(41, 1, 0, 0, 0)
try:
    from numpy._core.multiarray import _set_madvise_hugepage
    _set_madvise_hugepage(False)
except ImportError:
    pass
served = keep_freed_memory(int(sys.argv[1]))
size = 48 << 20
array = np.ones(size, np.uint8)
del array
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
array = np.ones(size, np.uint8)
faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
print(served, faults / (size // resource.getpagesize()))
"""
# The C library's own knobs would change the default case.
_MALLOC_ENVIRONMENT = ("MALLOC_MMAP_THRESHOLD_", "MALLOC_TRIM_THRESHOLD_", "MALLOC_TOP_PAD_",
                       "MALLOC_MMAP_MAX_", "GLIBC_TUNABLES", "LD_PRELOAD")


def refaulted(keep_bytes: int) -> tuple[int, float]:
    environment = {k: v for k, v in os.environ.items() if k not in _MALLOC_ENVIRONMENT}
    run = subprocess.run([sys.executable, "-c", REFAULTED, str(keep_bytes)],
                         capture_output=True, text=True, timeout=120, check=True,
                         env=environment)
    served, share = run.stdout.split()
    return int(served), float(share)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc's mallopt: Linux only")
def test_kept_memory_is_not_faulted_in_again():
    served, default_share = refaulted(0)
    assert served == 0
    if default_share < 0.9:
        pytest.skip(f"this machine refaulted {default_share:.0%} of a freed array's pages "
                    "by default (huge pages?): nothing to compare")
    served, share = refaulted(64 << 20)
    if served == 0:
        pytest.skip("the C library has no mallopt that takes it (not glibc)")
    # 64 MiB, or 32 MiB on a glibc before 2.35: the 48 MiB array is mapped afresh then.
    if served < 48 << 20:
        pytest.skip(f"this glibc serves blocks up to {served} bytes from its heap only")
    assert share < 0.1


def test_nothing_is_set_for_zero_and_too_much_is_refused():
    assert keep_freed_memory(0) == 0
    with pytest.raises(ValueError, match="above"):
        keep_freed_memory(MAX_KEEP_BYTES + 1)


def test_the_setting_is_bounded(tmp_path):
    assert Settings(data_dir=tmp_path, _env_file=None).worker_keep_memory_bytes == 0  # opt-in
    assert Settings(data_dir=tmp_path, worker_keep_memory_bytes=2**29,
                    _env_file=None).worker_keep_memory_bytes == 2**29
    for bad in (-1, MAX_KEEP_BYTES + 1):
        with pytest.raises(ValidationError):
            Settings(data_dir=tmp_path, worker_keep_memory_bytes=bad, _env_file=None)


def test_a_worker_sets_it_when_it_starts(tmp_path, monkeypatch):
    asked = []
    for name in ("_worker_storage", "_worker_settings", "_worker_parent"):
        monkeypatch.setattr(local, name, getattr(local, name))  # restored after
    monkeypatch.setattr(local, "keep_freed_memory",
                        lambda keep_bytes: asked.append(keep_bytes) or keep_bytes)
    monkeypatch.setattr(local, "open_storage", lambda settings: None)
    monkeypatch.setattr(local.threading, "Thread", lambda **kwargs: type(
        "NotStarted", (), {"start": lambda self: None})())
    local._init_worker(Settings(data_dir=tmp_path, worker_keep_memory_bytes=12345,
                                _env_file=None))
    assert asked == [12345]
    local._init_worker(Settings(data_dir=tmp_path, _env_file=None))  # the default: off
    assert asked == [12345]

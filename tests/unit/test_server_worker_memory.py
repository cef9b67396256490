"""A build worker keeps freed memory for its next build (server/jobs/memory.py): the
pages of an array freed and allocated again are not faulted in again, where with the C
library's defaults they are; and the worker sets it from its settings when it starts."""

from __future__ import annotations

import subprocess
import sys

import pytest
from pydantic import ValidationError

from server.jobs import local
from server.jobs.memory import MAX_KEEP_BYTES, keep_freed_memory
from server.settings import Settings

# In a fresh interpreter: the setting is process-wide. Prints the pages faulted in when
# a 48 MiB array, written, freed, is allocated and written again, as a share of its pages.
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
kept = keep_freed_memory(int(sys.argv[1]))
size = 48 << 20
array = np.ones(size, np.uint8)
del array
before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
array = np.ones(size, np.uint8)
faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before
print(kept, faults / (size // 4096))
"""


def refaulted(keep_bytes: int) -> tuple[bool, float]:
    run = subprocess.run([sys.executable, "-c", REFAULTED, str(keep_bytes)],
                         capture_output=True, text=True, timeout=120, check=True)
    kept, share = run.stdout.split()
    return kept == "True", float(share)


def test_kept_memory_is_not_faulted_in_again():
    kept, share = refaulted(64 << 20)
    if not kept:
        pytest.skip("the C library is not glibc (no mallopt)")
    assert share < 0.1
    kept, share = refaulted(0)  # the defaults: the freed array went back to the kernel
    assert not kept and share > 0.9


def test_nothing_is_set_for_zero_and_too_much_is_refused():
    assert keep_freed_memory(0) is False
    with pytest.raises(ValueError, match="above"):
        keep_freed_memory(MAX_KEEP_BYTES + 1)


def test_the_setting_is_bounded(tmp_path):
    assert Settings(data_dir=tmp_path, _env_file=None).worker_keep_memory_bytes == 512 * 2**20
    assert Settings(data_dir=tmp_path, worker_keep_memory_bytes=0,
                    _env_file=None).worker_keep_memory_bytes == 0
    for bad in (-1, MAX_KEEP_BYTES + 1):
        with pytest.raises(ValidationError):
            Settings(data_dir=tmp_path, worker_keep_memory_bytes=bad, _env_file=None)


def test_a_worker_sets_it_when_it_starts(tmp_path, monkeypatch):
    asked = []
    for name in ("_worker_storage", "_worker_settings", "_worker_parent"):
        monkeypatch.setattr(local, name, getattr(local, name))  # restored after
    monkeypatch.setattr(local, "keep_freed_memory", asked.append)
    monkeypatch.setattr(local, "open_storage", lambda settings: None)
    monkeypatch.setattr(local.threading, "Thread", lambda **kwargs: type(
        "NotStarted", (), {"start": lambda self: None})())
    local._init_worker(Settings(data_dir=tmp_path, worker_keep_memory_bytes=12345,
                                _env_file=None))
    assert asked == [12345]

"""Cached numba kernels are keyed on the whole kernel package (qem_core/_kernels), since a
kernel compiles the helpers it calls from other files into itself: numba alone would
keep a stream kernel cached with an old range coder after an edit to range_coder.py."""

from __future__ import annotations

import shutil

from qem_core import _kernels
from qem_core._kernels import heap, range_coder, stream_coding


def test_every_cached_kernel_is_keyed_on_the_package():
    for module in (heap, range_coder, stream_coding):
        dispatchers = [
            value for value in vars(module).values() if getattr(value, "_cache", None) is not None
            and hasattr(value._cache, "_impl")
        ]
        assert dispatchers, module.__name__
        for dispatcher in dispatchers:
            locator = dispatcher._cache._impl.locator
            assert type(locator).__name__ == "PackageStampedLocator", dispatcher
            assert locator.get_source_stamp() == _kernels._package_stamp()


def test_the_stamp_follows_any_file_of_the_package(tmp_path, monkeypatch):
    copy = tmp_path / "_kernels"
    shutil.copytree(_kernels._PACKAGE_DIR, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(_kernels, "_PACKAGE_DIR", copy)
    before = _kernels._package_stamp()
    assert before == _kernels._package_stamp()
    helper = copy / "range_coder.py"
    helper.write_text(helper.read_text() + "\n# an edit in a callee only\n")
    assert _kernels._package_stamp() != before

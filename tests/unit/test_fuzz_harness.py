"""The fuzz harness (fuzz/) runs briefly on every target, so that it cannot rot and its
findings stay fixed; `make fuzz` runs it for longer."""

from __future__ import annotations

import struct

import numpy as np
import pytest

import qem_core
from fuzz import targets
from fuzz.runner import fuzz_target
from fuzz.targets import TARGETS, Target


@pytest.mark.parametrize("name", sorted(TARGETS))
def test_a_short_run_of_each_target_finds_nothing(name, tmp_path):
    result = fuzz_target(name, runs=120, seed=0, shared=False, out=tmp_path)
    assert result["executions"] == 120
    reports = [path.read_text() for path in tmp_path.rglob("*.txt")]
    assert result["findings"] == {}, "\n".join(reports)


def test_an_exception_other_than_a_refusal_is_a_finding_saved_with_its_input(
    tmp_path, monkeypatch
):
    def run(data: bytes) -> None:
        if len(data) % 2:
            raise KeyError("a reader that trusts its input")
        raise qem_core.MeshFormatError("a refusal is no finding")

    monkeypatch.setitem(TARGETS, "off", Target("off", run, TARGETS["off"].mutate))
    result = fuzz_target("off", runs=50, seed=1, shared=False, out=tmp_path)
    assert [where.split(":")[0] for where in result["findings"]] == [
        "KeyError at test_fuzz_harness.py"
    ]
    saved = sorted((tmp_path / "off").iterdir())
    assert [path.suffix for path in saved] == [".bin", ".txt"]
    assert len(saved[0].read_bytes()) % 2 == 1
    assert "a reader that trusts its input" in saved[1].read_text()


def test_a_numpy_warning_on_a_hostile_file_is_a_finding(tmp_path, monkeypatch):
    def run(data: bytes) -> None:
        np.array([np.nan]).astype(np.int32)  # "invalid value encountered in cast"

    monkeypatch.setitem(targets.TARGETS, "off", Target("off", run, TARGETS["off"].mutate))
    result = fuzz_target("off", runs=3, seed=0, shared=False, out=tmp_path)
    assert [where.split(" at ")[0] for where in result["findings"]] == ["RuntimeWarning"]


def test_a_binary_stl_with_a_signalling_nan_is_refused_without_a_warning():
    """Found by the harness: a signalling NaN set the invalid flag when the positions were
    widened to float64 (a RuntimeWarning, an error under the tests' filter)."""
    signalling_nan = struct.unpack("<f", struct.pack("<I", 0x7F800001))[0]
    facet = struct.pack("<12fH", 0, 0, 0, signalling_nan, 0, 0, 1, 0, 0, 0, 1, 0, 0)
    data = b"\0" * 80 + struct.pack("<I", 1) + facet
    with pytest.raises(qem_core.InvalidMeshError, match="NaN|finite"):
        qem_core.load_mesh(data, format="stl")

"""Fixtures of the unit tests."""

from pathlib import Path

import pytest

import qem_core

SPOT = Path(__file__).resolve().parents[2] / "server" / "demo" / "spot.obj"


@pytest.fixture(scope="session")
def spot_pm():
    """Spot (the repository's demo copy) built with its UVs: corner UVs with seams."""
    return qem_core.build_mesh(qem_core.load_mesh(SPOT))

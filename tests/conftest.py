"""Fixtures shared by every test folder."""

from __future__ import annotations

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
SHARED_MESHES = REPO.parent / "shared" / "meshes"


@pytest.fixture(scope="session")
def shared_meshes() -> Path:
    """The folder of real test meshes (../shared/meshes beside the repository, described
    in its SOURCES.md); tests using it are skipped when it is absent."""
    if not SHARED_MESHES.is_dir():
        pytest.skip(f"shared test meshes not found at {SHARED_MESHES} (../shared/meshes)")
    return SHARED_MESHES

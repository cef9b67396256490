"""Fixtures shared by every test folder."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from hypothesis import settings

# No per-example deadline: the first example that reaches a numba kernel pays for its
# compile, or its load from the cache (a fresh clone compiles them all), hundreds of
# milliseconds that hypothesis would report as a flaky slow test.
settings.register_profile("qem-lod", deadline=None)
# A long search before a commit that touches a kernel: HYPOTHESIS_PROFILE=thorough make
# test (CI's default draws 100 examples per property, a different 100 on every run).
settings.register_profile("thorough", deadline=None, max_examples=2000)
settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "qem-lod"))

REPO = Path(__file__).resolve().parents[1]
SHARED_MESHES = REPO.parent / "shared" / "meshes"
SHARED_FUZZ_FINDINGS = REPO.parent / "shared" / "fuzz-findings"


@pytest.fixture(scope="session")
def shared_meshes() -> Path:
    """The folder of real test meshes (../shared/meshes beside the repository, described
    in its SOURCES.md); tests using it are skipped when it is absent."""
    if not SHARED_MESHES.is_dir():
        pytest.skip(f"shared test meshes not found at {SHARED_MESHES} (../shared/meshes)")
    return SHARED_MESHES


@pytest.fixture(scope="session")
def fuzz_findings() -> Path:
    """The folder of fuzz findings against the readers (../shared/fuzz-findings beside the
    repository: reproducers and raw inputs); tests using it are skipped when it is absent."""
    if not SHARED_FUZZ_FINDINGS.is_dir():
        pytest.skip(f"fuzz findings not found at {SHARED_FUZZ_FINDINGS} (../shared/fuzz-findings)")
    return SHARED_FUZZ_FINDINGS


@pytest.fixture(scope="session")
def postgres_server():
    """A real PostgreSQL server on loopback for the whole session (tests/postgres_server.py);
    tests using it skip, with the reason, where none can start."""
    pytest.importorskip("psycopg", reason="psycopg is not installed (pip install -e '.[dev]')")
    from .postgres_server import PostgresServer

    try:
        server = PostgresServer().start()
    except RuntimeError as error:
        pytest.skip(f"no PostgreSQL server could start: {error}")
    yield server
    server.stop()


@pytest.fixture
def postgres_url(postgres_server) -> str:
    """The URL of a new, empty database (no schema yet) on the session's server."""
    return postgres_server.database()

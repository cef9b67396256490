"""Fixtures shared by every test folder."""

from __future__ import annotations

import importlib
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


def _started_or_skipped(module: str, factory: str, what: str, needs: str):
    """A server of tests/<module>.py started, or the test skipped saying why."""
    pytest.importorskip(needs, reason=f"{needs} is not installed (pip install -e '.[dev]')")
    server_class = getattr(importlib.import_module(f"tests.{module}"), factory)
    try:
        return server_class().start()
    except RuntimeError as error:
        pytest.skip(f"no {what} could start: {error}")


@pytest.fixture(scope="session")
def postgres_server():
    """A real PostgreSQL server on loopback for the whole session (tests/postgres_server.py);
    tests using it skip, with the reason, where none can start."""
    server = _started_or_skipped("postgres_server", "PostgresServer", "PostgreSQL", "psycopg")
    yield server
    server.stop()


@pytest.fixture
def postgres_url(postgres_server) -> str:
    """The URL of a new, empty database (no schema yet) on the session's server."""
    return postgres_server.database()


@pytest.fixture(scope="session")
def s3_server():
    """A real S3-compatible store (SeaweedFS) on loopback for the whole session
    (tests/s3_server.py); tests using it skip, with the reason, where none can start."""
    server = _started_or_skipped("s3_server", "S3Server", "S3 store", "obstore")
    yield server
    server.stop()


@pytest.fixture
def s3_env(s3_server, monkeypatch) -> dict[str, str]:
    """This process pointed at a fresh prefix of the session's store (QEM_BLOB_URL and
    AWS_*, also set in os.environ for the store's client); the variables, for servers."""
    env = s3_server.env()
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    return env

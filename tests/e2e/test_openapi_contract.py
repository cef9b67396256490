"""The OpenAPI document states what the live server enforces: schemathesis with every
check (positive and negative data, authentication, Allow headers, the stateful phase)
finds nothing against ``qem serve``, with writes open and with write tokens, embedded
and on the scaled deployment (PostgreSQL and an S3 store).

Bounded (a fixed seed, 25 examples an operation) so that it runs in CI in seconds;
``schemathesis run URL/openapi.json --checks all`` without the bound is the long form.
"""

from __future__ import annotations

import subprocess
import sys

import pytest

from qem_core import codecs
from tests.tiny_meshes import icosphere

pytest.importorskip("schemathesis", minversion="4")

SEED = "318116820925628472835971421863374212118"
TOKEN = "contract-e2e-token-0123456789"


@pytest.mark.parametrize(
    "tokens, scaled",
    [(False, False), (True, False), (True, True)],
    ids=["open writes", "write tokens", "scaled deployment"],
)
def test_schemathesis_finds_nothing_against_the_live_server(
    request, start_server, tmp_path, tokens, scaled
):
    env = {"QEM_TOKENS": TOKEN} if tokens else {}
    if scaled:  # PostgreSQL + S3 (SeaweedFS), the server building with its own slot
        from server.migrations import upgrade

        url = request.getfixturevalue("postgres_server").database()
        upgrade(url)
        env.update({"QEM_DATABASE_URL": url, **request.getfixturevalue("s3_server").env()})
    server = start_server(env=env or None)
    mesh = tmp_path / "ball.ply"
    mesh.write_bytes(codecs.encode_mesh(*icosphere(2), "ply"))
    with server.client(TOKEN if tokens else None) as qem:  # a ready mesh for the reads
        qem.wait_ready(qem.upload(mesh), timeout=300)
    auth = ["-H", f"Authorization: Bearer {TOKEN}"] if tokens else []
    run = subprocess.run(
        [sys.executable, "-m", "schemathesis.cli", "run", f"{server.url}/openapi.json",
         "--checks", "all", "--seed", SEED, "--max-examples", "25", *auth],
        capture_output=True, text=True, timeout=600, cwd=tmp_path,  # its .schemathesis/ there
    )  # fmt: skip
    assert run.returncode == 0, run.stdout[-6000:] + run.stderr[-2000:]
    assert " passed" in run.stdout and "failures" not in run.stdout.split("SUMMARY")[-1]

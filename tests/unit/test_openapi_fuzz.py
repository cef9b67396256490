"""schemathesis over the app's own OpenAPI document, in process: every operation gets
generated requests, valid and invalid (examples, boundary and malformed values, random
ones), and no answer may be a server error or disagree with the document (status code,
content type, headers, body schema).

The app runs with its real lifespan (SQLite and one worker process in a temporary folder)
and holds one ready mesh; reads address it, so their query parameters reach real levels
and split streams rather than the 404 of an unknown id. Deletes keep the generated ids
(odd characters, lengths), so they exercise the lookup without removing the mesh.

Bounded and derandomized: the same requests on every run, a few hundred in all.
"""

from __future__ import annotations

import time
from pathlib import Path

import pytest
from hypothesis import HealthCheck, settings

from qem_core import codecs
from server.app import create_app
from server.settings import Settings
from server.uploads import import_file
from tests.tiny_meshes import icosphere

schemathesis = pytest.importorskip("schemathesis", minversion="4")
asgi = pytest.importorskip("schemathesis.python.asgi")

from schemathesis.checks import not_a_server_error  # noqa: E402
from schemathesis.specs.openapi.checks import (  # noqa: E402
    content_type_conformance,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)

CHECKS = [
    not_a_server_error,
    status_code_conformance,
    content_type_conformance,
    response_headers_conformance,
    response_schema_conformance,
]
BASE_URL = f"http://{asgi.HOST}"


def _openapi_document() -> dict:
    # schemathesis parametrizes at collection, so it needs the document now; the app that
    # produces it is only asked for its routes, never started.
    unused = Settings(data_dir="unused-data", web_dir="unused-web", _env_file=None)
    return create_app(unused).openapi()


api = schemathesis.openapi.from_dict(_openapi_document())


@pytest.fixture(scope="module")
def served(tmp_path_factory):
    """(ASGI client of a started app, id of its ready mesh)."""
    root: Path = tmp_path_factory.mktemp("fuzz")
    app_settings = Settings(
        data_dir=root / "data",
        workers=1,
        web_dir=root / "no-web",
        max_upload_bytes=64 * 1024,
        _env_file=None,
    )
    app = create_app(app_settings)
    mesh = root / "ball.ply"
    mesh.write_bytes(codecs.encode_mesh(*icosphere(2), "ply"))
    try:
        with asgi.get_client(app) as client:  # runs the lifespan until shutdown_lifespans
            record = import_file(app.state.storage, app.state.jobs, mesh)
            deadline = time.monotonic() + 120
            while (status := app.state.storage.metadata.get(record.id).status) != "ready":
                assert status != "failed" and time.monotonic() < deadline, status
                time.sleep(0.05)
            # The first level and split stream in a process load (or, on a fresh clone,
            # compile) numba kernels, which on a loaded machine outlasts schemathesis's
            # 10 s read timeout; this test is about the answers, so pay that up front.
            for path in ("lod?format=msgpack", "splits"):
                warm = client.get(f"{BASE_URL}/v1/meshes/{record.id}/{path}", timeout=600)
                assert warm.status_code == 200, (path, warm.status_code)
            yield client, record.id
    finally:
        asgi.shutdown_lifespans()


@api.parametrize()
@settings(
    max_examples=15,
    derandomize=True,
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much],
)
def test_api_never_fails_and_matches_its_document(case, served):
    client, mesh_id = served
    if case.method == "GET" and "mesh_id" in (case.path_parameters or {}):
        case.path_parameters["mesh_id"] = mesh_id
    case.call_and_validate(session=client, base_url=BASE_URL, checks=CHECKS)

"""server.problems: every error becomes RFC 9457 problem details with the right status."""

from __future__ import annotations

import pytest
from fastapi import FastAPI, HTTPException, Query
from fastapi.testclient import TestClient

import qem_core
from server.problems import PROBLEM_MEDIA_TYPE, Problem, install_problem_handlers

ERRORS = {
    "format": qem_core.MeshFormatError("bad PLY header: line 3"),
    "mesh": qem_core.InvalidMeshError("vertex 7 has a NaN coordinate"),
    "options": qem_core.InvalidOptionsError("weighting='x' is not one of ..."),
    "corrupt": qem_core.CorruptFileError("truncated .qpm"),
    "base": qem_core.QemError("something"),
    "problem": Problem("mesh-not-ready", "mesh abc is building", headers={"Retry-After": "1"}),
    "http": HTTPException(status_code=418, detail="short and stout"),
    "bug": RuntimeError("secret internals"),
}


@pytest.fixture(scope="module")
def client():
    app = FastAPI()
    install_problem_handlers(app)

    @app.get("/raise/{name}", responses={404: {"model": None}})
    def raise_(name: str):
        raise ERRORS[name]

    @app.get("/typed")
    def typed(n: int = Query(ge=1)):
        return {"n": n}

    with TestClient(app, raise_server_exceptions=False) as test_client:
        yield test_client


@pytest.mark.parametrize(
    ("name", "status", "type_"),
    [
        ("format", 422, "/problems/malformed-file"),
        ("mesh", 422, "/problems/invalid-mesh"),
        ("options", 422, "/problems/invalid-options"),
        ("corrupt", 500, "/problems/corrupt-data"),
        ("base", 422, "/problems/invalid-request"),
        ("problem", 409, "/problems/mesh-not-ready"),
        ("http", 418, "about:blank"),
        ("bug", 500, "/problems/internal-error"),
    ],
)
def test_exceptions_map_to_problems(client, name, status, type_):
    response = client.get(f"/raise/{name}")
    assert response.status_code == status
    assert response.headers["content-type"] == PROBLEM_MEDIA_TYPE
    body = response.json()
    assert body["type"] == type_ and body["status"] == status
    assert body["title"] and body["instance"] == f"/raise/{name}"
    if name == "bug":
        assert "secret" not in body["detail"]
    else:
        assert body["detail"] == str(ERRORS[name]) or body["detail"] == ERRORS[name].detail


def test_problem_headers_are_kept(client):
    assert client.get("/raise/problem").headers["retry-after"] == "1"


def test_validation_errors_are_listed(client):
    response = client.get("/typed", params={"n": 0})
    assert response.status_code == 422
    body = response.json()
    assert body["type"] == "/problems/invalid-request"
    assert body["errors"][0]["loc"] == ["query", "n"]
    assert "n:" in body["detail"]


def test_unknown_route_and_method(client):
    missing = client.get("/nowhere")
    assert missing.status_code == 404 and missing.json()["title"] == "Not Found"
    assert "/v1" in missing.json()["detail"]
    wrong = client.post("/typed")
    assert wrong.status_code == 405 and wrong.headers["allow"] == "GET"


def test_openapi_documents_problem_media_type():
    app = FastAPI()
    install_problem_handlers(app)

    @app.get(
        "/x", responses={404: {"model": __import__("server.problems").problems.ProblemDetails}}
    )
    def x(n: int):
        return n

    responses = app.openapi()["paths"]["/x"]["get"]["responses"]
    assert PROBLEM_MEDIA_TYPE in responses["404"]["content"]


def test_unknown_problem_kind_is_a_bug():
    with pytest.raises(KeyError):
        Problem("no-such-kind", "x")

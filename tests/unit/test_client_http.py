"""The Python client against answers a qem-lod server never gives (a proxy's redirect,
an HTML page, a broken connection), through httpx's MockTransport: each is a
QemClientError with a message, never a KeyError or JSONDecodeError."""

from __future__ import annotations

import httpx
import pytest

from client.http import QemClient, QemClientError, QemConnectionError, QemTimeoutError

INFO = {"id": "abc", "name": "a.ply", "status": "ready", "progress": 1.0, "vertices": 4,
        "faces": 4, "min_vertices": 4}


def client_answering(handler) -> QemClient:
    return QemClient("http://qem.test", transport=httpx.MockTransport(handler))


def test_a_redirect_is_reported_with_its_target():
    def handler(request):
        return httpx.Response(301, headers={"location": "https://qem.test/v1/meshes"})

    with pytest.raises(QemClientError, match="redirected .* https://qem.test/v1/meshes"):
        client_answering(handler).list()


@pytest.mark.parametrize("call", ["list", "info", "health"])
def test_an_html_page_is_not_taken_for_json(call):
    def handler(request):
        return httpx.Response(200, text="<html>hello</html>", headers={"content-type": "text/html"})

    qem = client_answering(handler)
    with pytest.raises(QemClientError, match="not qem-lod's"):
        qem.info("abc") if call == "info" else getattr(qem, call)()


def test_metadata_without_its_members_is_refused():
    def handler(request):
        return httpx.Response(200, json={"meshes": [{"id": "abc"}]})

    with pytest.raises(QemClientError, match="unknown form"):
        client_answering(handler).list()


def test_a_level_without_its_headers_is_refused():
    def handler(request):
        return httpx.Response(200, content=b"ply", headers={"X-Lod-Vertices": "many"})

    with pytest.raises(QemClientError, match="X-Lod-Vertices"):
        client_answering(handler).fetch_lod("abc", 10)


def test_a_delete_answered_otherwise_than_204_is_not_taken_as_done():
    def handler(request):
        return httpx.Response(200, text="<html>ok</html>")

    with pytest.raises(QemClientError, match="not qem-lod's 204"):
        client_answering(handler).delete("abc")


@pytest.mark.parametrize("mesh_id", ["", ".", ".."])
def test_an_id_a_url_would_resolve_away_is_refused(mesh_id):
    """Regression: delete("..") sent DELETE /v1."""
    with pytest.raises(QemClientError, match="not a mesh id"):
        client_answering(lambda request: httpx.Response(204)).delete(mesh_id)


@pytest.mark.parametrize("mesh_id", ["zzz/../abc", "abc?format=ply", "a b#c"])
def test_an_id_is_one_path_segment(mesh_id):
    """Regression: ``qem rm "zzz/../<id>"`` deleted mesh <id>."""
    paths = []

    def handler(request):
        paths.append(request.url.raw_path.decode())
        return httpx.Response(200, json=INFO)

    client_answering(handler).info(mesh_id)
    assert paths[0].startswith("/v1/meshes/") and paths[0].count("/") == 3
    assert "?" not in paths[0] and "#" not in paths[0]


@pytest.mark.parametrize("token", ["jeton-é", "two\nlines"])
def test_a_token_that_cannot_be_a_header_is_refused(token):
    with pytest.raises(QemClientError, match="printable ASCII"):
        QemClient("http://qem.test", token=token)


def test_a_timeout_is_its_own_error():
    def handler(request):
        raise httpx.ReadTimeout("slow", request=request)

    with pytest.raises(QemTimeoutError, match="did not answer in time"):
        client_answering(handler).info("abc")


def test_a_connection_that_breaks_off_says_so():
    def handler(request):
        raise httpx.RemoteProtocolError("peer closed connection", request=request)

    with pytest.raises(QemConnectionError, match="broke off"):
        client_answering(handler).info("abc")

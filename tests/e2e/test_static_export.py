"""The static export (`qem export`): written from a server and from a local .qpm, opened
by the viewer in headless Chromium from `python -m http.server` (which answers Range
with the whole file) and from a Range-serving static host, refined to the full mesh with
the right digest; a manifest or stream that lies is refused with a message."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import threading
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import msgpack
import pytest

import qem_core
from qem_core.errors import QemError
from qem_core.stored_stream import StreamIndex
from qem_core.stream import SplitStreamDecoder, iter_frames

from .conftest import REPO, ServerProcess, shared_mesh
from .test_viewer import chromium_page, pm_digest, require_web_packages

_SERVING = re.compile(r"port (\d+)")


@contextmanager
def http_server(directory: Path) -> Iterator[str]:
    """``python -m http.server`` on 127.0.0.1 serving ``directory``; its URL."""
    process = subprocess.Popen(
        [sys.executable, "-m", "http.server", "0", "--bind", "127.0.0.1", "-d", str(directory)],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        line = process.stdout.readline()
        match = _SERVING.search(line)
        assert match, line
        drain = threading.Thread(target=process.stdout.read, daemon=True)  # the log
        drain.start()
        yield f"http://127.0.0.1:{match[1]}"
    finally:
        process.terminate()
        process.wait(10)
        if "drain" in locals():
            drain.join(10)
        process.stdout.close()


@pytest.fixture(scope="module")
def bunny_export(tmp_path_factory):
    """bunny.ply built locally, exported from its .qpm with the viewer: (pm, folder)."""
    require_web_packages()
    mesh = qem_core.load_mesh(shared_mesh("bunny.ply"))
    pm = qem_core.build_mesh(mesh)
    folder = tmp_path_factory.mktemp("site")
    pm.save(folder / "bunny.qpm")
    exported = subprocess.run(
        [sys.executable, "-m", "client.cli", "export", str(folder / "bunny.qpm"),
         str(folder / "bunny")],
        cwd=REPO, capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert exported.returncode == 0, exported.stderr
    return pm, folder / "bunny"


def _open(page, url: str) -> dict:
    page.goto(url)
    page.wait_for_function(
        "() => { const s = window.qemViewer?.state;"
        " return s?.failure || (s?.level !== null && s.level === s.full && !s.streaming); }",
        timeout=120_000,
    )
    return page.evaluate("window.qemViewer.state")


def test_the_viewer_opens_an_export_from_python_http_server(bunny_export, tmp_path):
    pm, folder = bunny_export
    with http_server(folder) as url, chromium_page(tmp_path / "profile") as page:
        state = _open(page, f"{url}/index.html?src=manifest.json")
        assert state["failure"] is None, state
        assert state["level"] == pm.n_full and state["received"] == pm.n_full
        assert page.evaluate("window.qemViewer.levelDigest()") == pm_digest(pm, pm.n_full)
        assert state["splitBytes"] == (folder / "stream.qsplits").stat().st_size
        page.evaluate("window.qemViewer.setLevel(5000)")  # any level of those received
        assert page.evaluate("window.qemViewer.levelDigest()") == pm_digest(pm, 5000)
        assert page.is_hidden("#upload") and page.errors == []


def test_the_viewer_refines_an_export_by_range_requests(bunny_export, tmp_path):
    # The qem server's static mount (Starlette's files, which answer Range) as the host.
    pm, folder = bunny_export
    host = ServerProcess(tmp_path / "data", {"QEM_WEB_DIR": str(folder)}).start()
    try:
        with chromium_page(tmp_path / "profile") as page:
            ranges = []
            page.on(
                "request",
                lambda request: (
                    ranges.append(request.headers.get("range"))
                    if request.url.endswith("stream.qsplits")
                    else None
                ),
            )
            state = _open(page, f"{host.url}/index.html?src=manifest.json")
            assert state["failure"] is None, state
            assert page.evaluate("window.qemViewer.levelDigest()") == pm_digest(pm, pm.n_full)
            index = StreamIndex.from_json((folder / "frames.json").read_bytes())
            assert len(ranges) >= 2 and ranges[0] == f"bytes=0-{index.offsets[2] - 1}"
            assert page.errors == []
    finally:
        host.stop()


def _lying_copy(folder: Path, target: Path, change) -> Path:
    """A copy of the export's data files (the viewer's as links) with one file changed."""
    target.mkdir()
    for path in folder.iterdir():
        (target / path.name).symlink_to(path)
    change(target)
    return target


def _manifest_says(**changes):
    def change(target: Path) -> None:
        manifest = json.loads((target / "manifest.json").read_text())
        manifest.update(changes)
        (target / "manifest.json").unlink()
        (target / "manifest.json").write_text(json.dumps(manifest))

    return change


def _frames_swapped(target: Path) -> None:
    index = json.loads((target / "frames.json").read_text())
    index["vertices"][1] += 1  # the index says the first frame ends one vertex later
    (target / "frames.json").unlink()
    (target / "frames.json").write_text(json.dumps(index))


def _stream_damaged(target: Path) -> None:
    data = bytearray((target / "stream.qsplits").read_bytes())
    data[len(data) // 2] ^= 0x40
    (target / "stream.qsplits").unlink()
    (target / "stream.qsplits").write_bytes(bytes(data))


def _frame_recoded(target: Path) -> None:
    """Frame 2's coded splits with one byte changed and its CRC-32 made right again: only
    decoding (in the page's worker) can tell, so the first byte whose change the Python
    decoder refuses (the decoders agree bit for bit)."""
    stream = (target / "stream.qsplits").read_bytes()
    index = StreamIndex.from_json((target / "frames.json").read_bytes())
    payloads = list(iter_frames([stream]))
    body = msgpack.unpackb(payloads[2][:-4])
    for at in range(len(body["splits"]) // 2, len(body["splits"])):
        coded = bytearray(body["splits"])
        coded[at] ^= 0x5A
        packed = msgpack.packb({**body, "splits": bytes(coded)})
        damaged = packed + zlib.crc32(packed).to_bytes(4, "little")
        decoder = SplitStreamDecoder.from_msgpack((target / "base.msgpack").read_bytes())
        for payload in payloads[:2]:
            decoder.feed(payload)
        try:
            decoder.feed(damaged)
        except QemError:
            break
    assert len(damaged) == len(payloads[2])
    start = index.offsets[2] + 4
    data = stream[:start] + damaged + stream[start + len(damaged) :]
    (target / "stream.qsplits").unlink()
    (target / "stream.qsplits").write_bytes(data)


@pytest.mark.parametrize(
    "change, message",
    [
        (_manifest_says(vertices=10**6), "manifest's vertices"),
        (_manifest_says(format="other"), "not a qem-lod export manifest"),
        (_manifest_says(stream_crc32=1), "CRC-32 against the manifest's"),
        (_frames_swapped, "its index says"),
        (_stream_damaged, "CRC-32 does not match"),
    ],
)
def test_an_export_that_lies_is_refused_with_a_message(bunny_export, tmp_path, change, message):
    pm, folder = bunny_export
    lying = _lying_copy(folder, tmp_path / "lying", change)
    with http_server(lying) as url, chromium_page(tmp_path / "profile") as page:
        state = _open(page, f"{url}/index.html?src=manifest.json")
        assert state["failure"] and message in state["failure"], state
        assert message in page.text_content("#message")


def test_a_frame_the_worker_refuses_stops_the_stream_with_its_message(bunny_export, tmp_path):
    """A CRC-valid frame that does not decode: refused in the decoder's worker, with the
    decoder's message on the page; the frames before it stay held and shown."""
    _, folder = bunny_export
    lying = _lying_copy(folder, tmp_path / "lying", _frame_recoded)
    index = StreamIndex.from_json((folder / "frames.json").read_bytes())
    with http_server(lying) as url, chromium_page(tmp_path / "profile") as page:
        state = _open(page, f"{url}/index.html?src=manifest.json")
        assert state["failure"] and state["failure"].startswith("split"), state
        assert state["failure"] in page.text_content("#message")
        assert state["received"] == index.vertices[2] and not state["streaming"], state
        assert state["level"] == index.vertices[2], state

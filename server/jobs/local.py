"""Builds in a local pool of worker processes (the embedded default).

A `concurrent.futures.ProcessPoolExecutor` with the spawn start method (no fork of a
threaded web server). Each worker opens its own storage from the settings once and runs
`run_build` per mesh id.

Failure handling:
- a worker that dies (killed, out of memory, crash in native code) breaks the whole pool;
  the pool is replaced and `recover` requeues the interrupted builds, counting attempts,
  so a mesh that kills its worker every time ends up ``failed`` instead of looping;
- a worker whose server died (SIGKILL) notices at its next progress report and stops; its
  writes are fenced anyway, so it cannot disturb the restarted server;
- `close` terminates running builds; the next start requeues them.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from ..settings import Settings
from ..storage import Storage, open_storage
from .base import JobQueue
from .build import run_build

__all__ = ["LocalJobQueue"]

log = logging.getLogger("qem.jobs")

# Per worker process: set once by _init_worker.
_worker_storage: Storage | None = None
_worker_settings: Settings | None = None
_worker_parent: int | None = None


def _init_worker(settings: Settings) -> None:
    global _worker_storage, _worker_settings, _worker_parent
    logging.basicConfig(level=logging.INFO, format="%(levelname)s: %(name)s: %(message)s")
    _worker_settings = settings
    _worker_storage = open_storage(settings)
    _worker_parent = os.getppid()


def _parent_is_gone() -> bool:
    return os.getppid() != _worker_parent


def _build_in_worker(mesh_id: str) -> str:
    assert _worker_storage is not None and _worker_settings is not None
    return run_build(
        _worker_storage,
        mesh_id,
        progress_interval=_worker_settings.progress_interval_s,
        should_abort=_parent_is_gone,
    )


class LocalJobQueue(JobQueue):
    """settings.workers processes on this machine."""

    def __init__(self, settings: Settings, storage: Storage) -> None:
        super().__init__(settings, storage)
        self._lock = threading.RLock()
        self._executor: ProcessPoolExecutor | None = None
        self._generation = 0
        self._closing = False

    def start(self) -> None:
        with self._lock:
            self._executor = self._new_executor()
            self.recover()

    def submit(self, mesh_id: str) -> None:
        with self._lock:
            if self._closing or self._executor is None:
                raise RuntimeError("the job queue is not running")
            generation = self._generation
            future = self._executor.submit(_build_in_worker, mesh_id)
        future.add_done_callback(lambda done: self._on_done(mesh_id, generation, done))

    def close(self) -> None:
        with self._lock:
            self._closing = True
            executor, self._executor = self._executor, None
        if executor is not None:
            _stop(executor)

    # -- internals ----------------------------------------------------------------------

    def _new_executor(self) -> ProcessPoolExecutor:
        self._generation += 1
        return ProcessPoolExecutor(
            max_workers=self.settings.workers,
            mp_context=multiprocessing.get_context("spawn"),
            initializer=_init_worker,
            initargs=(self.settings,),
        )

    def _on_done(self, mesh_id: str, generation: int, future: Future) -> None:
        if future.cancelled() or self._closing:
            return
        error = future.exception()
        if error is None:
            return
        if isinstance(error, BrokenProcessPool):
            with self._lock:
                if self._closing or generation != self._generation:
                    return  # another callback of the same broken pool already replaced it
                log.error("a build worker process died (mesh %s); restarting the pool", mesh_id)
                broken, self._executor = self._executor, self._new_executor()
                if broken is not None:
                    broken.shutdown(wait=False, cancel_futures=True)
                self.recover()
            return
        # run_build turns bad input into "failed"; reaching here means the worker could
        # not even run it (e.g. storage unreachable). Record it rather than lose the job.
        log.error("build of mesh %s could not run: %r", mesh_id, error)
        self.storage.metadata.fail(
            mesh_id, f"internal error: the build could not run ({type(error).__name__}: {error})"
        )


def _stop(executor: ProcessPoolExecutor) -> None:
    """Shut the pool down now, interrupting running builds.

    Python 3.11 has no public way to stop busy workers (3.14 adds terminate_workers), and
    `shutdown` would wait for running builds to finish, so terminate the processes."""
    processes = list(getattr(executor, "_processes", {}).values())
    executor.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            process.terminate()
    for process in processes:
        process.join(timeout=10)

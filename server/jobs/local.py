"""Builds in a local pool of worker processes (the embedded default).

A `concurrent.futures.ProcessPoolExecutor` with the spawn start method (no fork of a
threaded web server). Each worker opens its own storage from the settings once and runs
`run_build` per mesh id.

Failure handling:
- a worker that dies (killed, out of memory, crash in native code) breaks the whole pool;
  the pool is replaced and `recover` requeues the interrupted builds, counting attempts,
  so a mesh that kills its worker every time ends up ``failed`` instead of looping;
- a worker that dies while idle is noticed by the pool only: the next `submit` finds the
  pool broken, replaces it and recovers the same way;
- a worker whose server died (SIGKILL) notices at its next progress report and stops; its
  writes are fenced anyway, so it cannot disturb the restarted server. A watchdog thread
  then ends the orphaned process, which would otherwise wait for work forever;
- `close` terminates running builds; the next start requeues them.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
import time
from concurrent.futures import Future, ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from ..request_log import configure_logging
from ..settings import Settings
from ..storage import Storage, open_storage
from .base import JobQueue
from .build import build_claimed, run_build
from .memory import keep_freed_memory

__all__ = ["LocalJobQueue", "build_in_worker", "stop_pool", "worker_pool"]

log = logging.getLogger("qem.jobs")

# How often a worker checks that its server is alive, and how long an orphaned worker lets
# its build stop by itself (and remove its temporary files) before it exits anyway.
_PARENT_CHECK_S = 1.0
_ORPHAN_GRACE_S = 10.0

# Per worker process: set once by _init_worker.
_worker_storage: Storage | None = None
_worker_settings: Settings | None = None
_worker_parent: int | None = None
_worker_idle = threading.Event()


def _init_worker(settings: Settings) -> None:
    global _worker_storage, _worker_settings, _worker_parent
    configure_logging("info", settings.log_format)
    _worker_settings = settings
    _keep_freed_memory(settings.worker_keep_memory_bytes)
    _worker_storage = open_storage(settings)
    _worker_parent = os.getppid()
    _worker_idle.set()
    threading.Thread(target=_exit_when_orphaned, name="qem-orphan-watch", daemon=True).start()


def _keep_freed_memory(keep_bytes: int) -> None:
    if keep_bytes <= 0:
        return
    served = keep_freed_memory(keep_bytes)
    if served == 0:
        log.warning("worker %d: cannot keep freed memory (not glibc's malloc); "
                    "QEM_WORKER_KEEP_MEMORY_BYTES is ignored", os.getpid())
    elif served < keep_bytes:
        log.info("worker %d keeps up to %d bytes of freed memory, blocks up to %d bytes "
                 "from its heap (this glibc's limit)", os.getpid(), keep_bytes, served)


def _parent_is_gone() -> bool:
    return os.getppid() != _worker_parent


def _exit_when_orphaned() -> None:
    # A worker whose server was killed outright (SIGKILL, out of memory) is re-parented and
    # nothing tells it: the pool's task queue never reports end of file, so it would wait
    # for work forever, holding its memory, a database connection and the server's stdout.
    while not _parent_is_gone():
        time.sleep(_PARENT_CHECK_S)
    _worker_idle.wait(_ORPHAN_GRACE_S)  # a running build aborts at its next progress report
    os._exit(0)


def build_in_worker(mesh_id: str, token: str | None = None) -> tuple[str, float]:
    """The build's outcome and its seconds. With `token`, the record was claimed by the
    caller (the PostgreSQL queue claims as it takes); without, the build claims it."""
    assert _worker_storage is not None and _worker_settings is not None
    _worker_idle.clear()
    started = time.monotonic()
    options = {
        "progress_interval": _worker_settings.progress_interval_s,
        "max_seconds": _worker_settings.max_build_seconds,
        "store_stream": _worker_settings.stream_at_build,
        "should_abort": _parent_is_gone,
    }
    try:
        if token is None:
            outcome = run_build(_worker_storage, mesh_id, **options)
        else:
            record = _worker_storage.metadata.get(mesh_id)
            outcome = "skipped"
            if record is not None and record.claim == token:
                outcome = build_claimed(_worker_storage, record, token, **options)
        return outcome, time.monotonic() - started
    finally:
        _worker_idle.set()


def worker_pool(settings: Settings, processes: int) -> ProcessPoolExecutor:
    """`processes` build worker processes (spawned, each with its own storage)."""
    return ProcessPoolExecutor(
        max_workers=processes,
        mp_context=multiprocessing.get_context("spawn"),
        initializer=_init_worker,
        initargs=(settings,),
    )


class LocalJobQueue(JobQueue):
    """settings.workers processes on this machine."""

    def __init__(self, settings: Settings, storage: Storage) -> None:
        super().__init__(settings, storage)
        self._lock = threading.RLock()
        self._executor: ProcessPoolExecutor | None = None
        self._generation = 0
        self._closing = False
        self._submitted: set[str] = set()  # ids submitted whose builds have not ended

    def start(self) -> None:
        with self._lock:
            self._executor = self._new_executor()
            self.recover()

    def submit(self, mesh_id: str) -> None:
        with self._lock:
            if self._closing or self._executor is None:
                raise RuntimeError("the job queue is not running")
            generation = self._generation
            try:
                future = self._executor.submit(build_in_worker, mesh_id)
            except BrokenProcessPool:
                # A worker died while idle (killed, out of memory): no build was running to
                # report it, and without a new pool every later upload would stay queued.
                # recover() submits this mesh again, with any other unfinished one.
                self._replace_broken_pool(generation, f"found when submitting mesh {mesh_id}")
                return
            self._submitted.add(mesh_id)
        future.add_done_callback(lambda done: self._on_done(mesh_id, generation, done))

    def close(self) -> None:
        """Stop: the builds running are handed back to the queue, their attempt not
        counted (the next start, or another server's queue, takes them up), then their
        processes are ended (their writes are fenced by the claim they no longer hold)."""
        with self._lock:
            self._closing = True
            executor, self._executor = self._executor, None
            submitted, self._submitted = self._submitted, set()
        for mesh_id in submitted:
            if self.storage.metadata.release(mesh_id):
                log.info("handed the build of mesh %s back to the queue", mesh_id)
        if executor is not None:
            stop_pool(executor)

    # -- internals ----------------------------------------------------------------------

    def _new_executor(self) -> ProcessPoolExecutor:
        self._generation += 1
        return worker_pool(self.settings, self.settings.workers)

    def _on_done(self, mesh_id: str, generation: int, future: Future) -> None:
        with self._lock:
            self._submitted.discard(mesh_id)
        if future.cancelled() or self._closing:
            return
        error = future.exception()
        if error is None:
            if self.on_finished is not None:
                self.on_finished(*future.result())
            return
        if isinstance(error, BrokenProcessPool):
            self._replace_broken_pool(generation, f"building mesh {mesh_id}")
            return
        # run_build turns bad input into "failed"; reaching here means the worker could
        # not even run it (e.g. storage unreachable). Record it rather than lose the job.
        log.error("build of mesh %s could not run: %r", mesh_id, error)
        self.storage.metadata.fail(
            mesh_id, f"internal error: the build could not run ({type(error).__name__}: {error})"
        )

    def _replace_broken_pool(self, generation: int, doing: str) -> None:
        """Start a new pool in place of the broken pool `generation`, and requeue (or fail)
        the builds it interrupted."""
        with self._lock:
            if self._closing or generation != self._generation:
                return  # another caller already replaced this pool
            log.error("a build worker process died (%s); restarting the pool", doing)
            broken, self._executor = self._executor, self._new_executor()
            if broken is not None:
                broken.shutdown(wait=False, cancel_futures=True)
            self.recover()


def stop_pool(executor: ProcessPoolExecutor) -> None:
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

"""Builds through a queue on the PostgreSQL database, run by ``qem worker`` processes on
any machine (and by ``qem serve --workers N`` when asked).

The queue is the meshes table itself: a queued record is a job. A worker slot takes the
oldest (`PostgresMetadataStore.claim_next`, ``FOR UPDATE SKIP LOCKED``: slots on any
machine take different records), runs its build in a child process of its own (a
persistent one, so numba's kernels load once), and beats the record's heartbeat while it
runs. The build's writes are fenced by its claim token, as in every deployment.

- A slot whose child dies (killed, out of memory) requeues the build, or fails it once it
  used ``max_build_attempts``.
- A worker that stops beating altogether (SIGKILL, its machine gone) has its builds taken
  back by any other worker after ``worker_stale_s`` (`take_back_stalled`, attempts
  counted the same way): delivery is at least once, and an attempt that lost its claim
  writes nothing (content-addressed keys, fenced updates).
- A worker stopped on purpose (SIGTERM, Ctrl-C) hands its running builds back to the
  queue without counting the attempt.
- New uploads are announced (NOTIFY ``qem_jobs``): idle slots start at once; they also
  look every ``_POLL_S`` in case a notice was missed.
"""

from __future__ import annotations

import logging
import signal
import threading
import time
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool

from ..settings import Settings
from ..storage import Storage, StorageUnavailable, new_token
from .base import JobQueue
from .local import build_in_worker, stop_pool, worker_pool

__all__ = ["JOBS_CHANNEL", "PostgresJobQueue", "WorkerPool"]

log = logging.getLogger("qem.jobs")

JOBS_CHANNEL = "qem_jobs"
_POLL_S = 5.0


class WorkerPool:
    """`slots` build slots in this process (threads), each running one build at a time in
    a child process. `start`, then `stop` (running builds go back to the queue)."""

    def __init__(
        self,
        settings: Settings,
        storage: Storage,
        slots: int,
        on_finished: Callable[[str, float], None] | None = None,
    ) -> None:
        self.settings = settings
        self.storage = storage
        self.metadata = storage.metadata
        if not hasattr(self.metadata, "claim_next"):
            raise RuntimeError("build workers need the PostgreSQL metadata store")
        self.slots = slots
        self.on_finished = on_finished
        self._stopping = threading.Event()
        self._wake = threading.Condition()
        self._threads: list[threading.Thread] = []
        self._stop_watch: Callable[[], None] | None = None
        self._beat_s = max(0.2, settings.worker_stale_s / 6)
        self._next_sweep = 0.0

    def start(self) -> None:
        self._stop_watch = self.metadata.watch(JOBS_CHANNEL, lambda _payload: self._notify())
        for slot in range(self.slots):
            thread = threading.Thread(target=self._run_slot, name=f"qem-slot-{slot}", daemon=True)
            thread.start()
            self._threads.append(thread)
        log.info("%d build slot(s) taking builds from the database", self.slots)

    def stop(self) -> None:
        self._stopping.set()
        self._notify()
        for thread in self._threads:
            thread.join()
        if self._stop_watch is not None:
            self._stop_watch()

    def _notify(self) -> None:
        with self._wake:
            self._wake.notify_all()

    # -- one slot ---------------------------------------------------------------------

    def _run_slot(self) -> None:
        executor = worker_pool(self.settings, 1)
        try:
            while not self._stopping.is_set():
                try:
                    self._take_back_stalled()
                    token = new_token()
                    record = self.metadata.claim_next(token)
                except Exception as error:  # noqa: BLE001 - the database may come back
                    log.warning("build slot: the queue does not answer (%s)", error)
                    record = None
                if record is None:
                    with self._wake:  # woken by an upload's notice, else look again soon
                        self._wake.wait(min(_POLL_S, self.settings.worker_stale_s / 3))
                    continue
                try:
                    executor = self._build(executor, record.id, token, record.attempts)
                except Exception:  # a slot must outlive any one build
                    log.exception("build slot: the build of mesh %s ended badly", record.id)
                    stop_pool(executor)
                    executor = worker_pool(self.settings, 1)
        finally:
            stop_pool(executor)

    def _build(self, executor: ProcessPoolExecutor, mesh_id: str, token: str, attempts: int):
        """Run one claimed build in the slot's child, beating its heartbeat; returns the
        executor to use next (a new one when the child died or was stopped)."""
        future = executor.submit(build_in_worker, mesh_id, token)
        while True:
            try:
                outcome, seconds = future.result(timeout=self._beat_s)
            except TimeoutError:
                if self._stopping.is_set():
                    if self.metadata.release(mesh_id):
                        log.info("handed the build of mesh %s back to the queue", mesh_id)
                    break
                if not self._beat(mesh_id, token):
                    # Deleted, or taken back as stalled: the child's writes are fenced.
                    log.info("the build of mesh %s lost its claim; stopping it", mesh_id)
                    break
                continue
            except BrokenProcessPool:
                self._record(self._died, mesh_id, token, attempts)
                break
            except StorageUnavailable as error:
                # The build could not record its outcome: the record stays building, its
                # heartbeat stops, and it is taken back once the database answers.
                log.warning("build of mesh %s could not reach the storage: %s", mesh_id, error)
                break
            except Exception as error:  # noqa: BLE001 - the child could not run it
                log.error("build of mesh %s could not run: %r", mesh_id, error)
                reason = f"internal error: the build could not run ({type(error).__name__})"
                self._record(self.metadata.fail, mesh_id, reason, token=token)
                break
            if self.on_finished is not None:
                self.on_finished(outcome, seconds)
            return executor
        stop_pool(executor)
        return worker_pool(self.settings, 1)

    @staticmethod
    def _record(write, *args, **kwargs) -> None:
        """A write of a build's outcome by the slot; the database away, the heartbeat's
        end says the rest (the build is taken back)."""
        try:
            write(*args, **kwargs)
        except StorageUnavailable as error:
            log.warning("could not record a build's outcome: %s", error)

    def _beat(self, mesh_id: str, token: str) -> bool:
        """Beat the heartbeat; False if the attempt lost its claim."""
        try:
            return self.metadata.heartbeat(mesh_id, token)
        except Exception:  # noqa: BLE001 - a missed beat (database away): the next may land
            return True

    def _died(self, mesh_id: str, token: str, attempts: int) -> None:
        limit = self.settings.max_build_attempts
        if attempts >= limit:
            reason = (
                f"the build's process died {attempts} time(s) (killed, out of memory, or a "
                f"crash); gave up after {limit} attempt(s)"
            )
            if self.metadata.fail(mesh_id, reason, token=token):
                log.warning("mesh %s failed: %s", mesh_id, reason)
        elif self.metadata.requeue(mesh_id, token=token):
            log.warning("the build process of mesh %s died; requeued it", mesh_id)

    def _take_back_stalled(self) -> None:
        now = time.monotonic()
        if now < self._next_sweep:
            return
        self._next_sweep = now + self.settings.worker_stale_s / 3
        taken = self.metadata.take_back_stalled(
            self.settings.worker_stale_s, self.settings.max_build_attempts
        )
        for mesh_id, status in taken:
            log.warning("the worker building mesh %s stopped beating; its build is %s",
                        mesh_id, status)  # fmt: skip
        if any(status == "queued" for _, status in taken):
            self._notify()

    def run_until_signalled(self) -> None:
        """`qem worker`: run until SIGTERM or SIGINT, then stop gracefully."""
        stop = threading.Event()
        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, lambda *_: stop.set())
        self.start()
        while not stop.wait(1.0):
            pass
        log.info("stopping: running builds go back to the queue")
        self.stop()


class PostgresJobQueue(JobQueue):
    """``qem serve``'s side of the queue: an upload is announced to the workers; the server
    runs build slots itself only when asked (``--workers N`` or ``QEM_WORKERS``)."""

    def __init__(self, settings: Settings, storage: Storage) -> None:
        super().__init__(settings, storage)
        asked = "workers" in settings.model_fields_set
        self._pool = WorkerPool(settings, storage, settings.workers) if asked else None

    def start(self) -> None:
        # No recover(): other servers' and workers' builds are running; stalled ones are
        # taken back by the workers, by heartbeat.
        if self._pool is not None:
            self._pool.on_finished = self.on_finished
            self._pool.start()

    def submit(self, mesh_id: str) -> None:
        self.storage.metadata.announce(JOBS_CHANNEL, mesh_id)

    def close(self) -> None:
        if self._pool is not None:
            self._pool.stop()

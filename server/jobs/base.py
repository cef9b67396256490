"""The job interface: run the build of an uploaded mesh somewhere, eventually.

A queue only moves mesh ids; the state of every build lives in the metadata store (see
`server.storage.base`), so any queue (a local process pool, Redis, PostgreSQL
``SKIP LOCKED``) can be swapped in without touching the routes.
"""

from __future__ import annotations

import abc
import logging
from collections.abc import Callable

from ..settings import Settings
from ..storage import Storage

__all__ = ["JobQueue"]

log = logging.getLogger("qem.jobs")


class JobQueue(abc.ABC):
    """Runs builds. `start` before the first `submit`; `close` on shutdown."""

    def __init__(self, settings: Settings, storage: Storage) -> None:
        self.settings = settings
        self.storage = storage
        # Told each build's outcome ("ready", "failed", "skipped") and its seconds, from a
        # thread of the queue's (the server's metrics).
        self.on_finished: Callable[[str, float], None] | None = None

    @classmethod
    def from_settings(cls, settings: Settings, storage: Storage) -> JobQueue:
        return cls(settings, storage)

    @abc.abstractmethod
    def start(self) -> None:
        """Get ready to run builds, then `recover` what a previous run left unfinished."""

    @abc.abstractmethod
    def submit(self, mesh_id: str) -> None:
        """Build the queued mesh `mesh_id` when a worker is free. Submitting twice is
        harmless: only one attempt can claim the record."""

    @abc.abstractmethod
    def close(self) -> None:
        """Stop; builds in progress are interrupted and recovered by the next `start`."""

    def recover(self) -> list[str]:
        """Requeue builds left queued or building by an interrupted run, or fail those
        that already used their `max_build_attempts`. Returns the ids submitted again.

        Call only when no build of this deployment is running (on start, or after the
        worker pool was replaced)."""
        resubmitted = []
        limit = self.settings.max_build_attempts
        for record in self.storage.metadata.unfinished():
            if record.status == "building" and record.attempts >= limit:
                reason = (
                    f"the build was interrupted {record.attempts} time(s) (server stopped "
                    f"or worker process died, e.g. out of memory); gave up after "
                    f"{limit} attempt(s)"
                )
                if self.storage.metadata.fail(record.id, reason):
                    log.warning("mesh %s failed: %s", record.id, reason)
                continue
            if self.storage.metadata.requeue(record.id):
                log.info("requeued interrupted build of mesh %s (%s)", record.id, record.name)
                self.submit(record.id)
                resubmitted.append(record.id)
        return resubmitted

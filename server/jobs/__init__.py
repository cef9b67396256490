"""Jobs: where builds run, behind the interface of `server.jobs.base`.

`open_jobs(settings, storage)` builds the queue named by ``jobs_backend``; the build
itself (`server.jobs.build.run_build`) is shared by every queue.
"""

from __future__ import annotations

from ..settings import JOBS_BACKENDS, Settings, load_backend
from ..storage import Storage
from .base import JobQueue

__all__ = ["JobQueue", "open_jobs"]


def open_jobs(settings: Settings, storage: Storage) -> JobQueue:
    """The job queue named by `settings` (not started yet: call `start`)."""
    return load_backend(JOBS_BACKENDS, settings.jobs_backend).from_settings(settings, storage)

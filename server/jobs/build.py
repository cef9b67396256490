"""One build attempt: read the upload, build the progressive mesh, store it, record the
outcome. Independent of the queue that runs it.

The attempt claims the record first; every later write is fenced by the claim token, and
a progress write that finds the record gone or taken over aborts the build.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import qem_core
from qem_core import codecs

from ..storage import MeshRecord, Storage, new_token, qpm_key
from ..stored_streams import write_stream

__all__ = ["BuildAborted", "BuildTimedOut", "build_claimed", "run_build"]

log = logging.getLogger("qem.jobs")

# Shares of the progress bar: reading the upload, the build, encoding the split stream;
# saving takes the last step.
_READ_SHARE = 0.02
_BUILD_SHARE = 0.88
_STREAM_SHARE = 0.08


class BuildAborted(Exception):
    """The attempt lost its claim (mesh deleted, build requeued) or its parent died."""


class BuildTimedOut(Exception):
    """The attempt ran past its time limit (settings.max_build_seconds)."""


class _ProgressWriter:
    """progress(fraction) for qem_core, writing to the record at most every `interval`
    seconds, and aborting the build when it should stop or its `deadline` (a
    time.monotonic() value, or None) has passed. qem_core calls it between chunks of
    contractions, and every 0.1 s while its parallel rounds run."""

    def __init__(
        self,
        storage: Storage,
        mesh_id: str,
        token: str,
        interval: float,
        should_abort: Callable[[], bool] | None,
        deadline: float | None = None,
    ) -> None:
        self._storage = storage
        self._mesh_id = mesh_id
        self._token = token
        self._interval = interval
        self._should_abort = should_abort
        self._deadline = deadline
        self._last = time.monotonic()

    def __call__(self, fraction: float, *, force: bool = False) -> None:
        now = time.monotonic()
        if self._deadline is not None and now > self._deadline:
            raise BuildTimedOut
        if not force and now - self._last < self._interval:
            return
        self._last = now
        if self._should_abort is not None and self._should_abort():
            raise BuildAborted("the server that started this build is gone")
        if not self._storage.metadata.set_progress(self._mesh_id, self._token, fraction):
            raise BuildAborted("the mesh was deleted or its build was requeued")

    def build_share(self, fraction: float) -> None:
        self(_READ_SHARE + _BUILD_SHARE * min(1.0, max(0.0, float(fraction))))

    def stream_share(self, fraction: float) -> None:
        self(_READ_SHARE + _BUILD_SHARE + _STREAM_SHARE * min(1.0, max(0.0, float(fraction))))


def run_build(storage: Storage, mesh_id: str, **options: Any) -> str:
    """Build the queued mesh `mesh_id` and record the outcome (`options`: those of
    `build_claimed`).

    Returns the status it left: ``ready``, ``failed``, or ``skipped`` when the record was
    not queued (already claimed, finished or deleted) or the attempt was aborted. Bad
    input never raises: it becomes ``failed`` with the reason in the record's ``error``.
    A build still running ``max_seconds`` after its start (None: no limit) fails too.
    With ``store_stream`` the split stream is encoded and stored beside the .qpm before
    the mesh is ready; without, the first request for it makes it.
    """
    token = new_token()
    record = storage.metadata.claim(mesh_id, token)
    if record is None:
        return "skipped"
    return build_claimed(storage, record, token, **options)


def build_claimed(
    storage: Storage,
    record: MeshRecord,
    token: str,
    *,
    progress_interval: float = 0.5,
    should_abort: Callable[[], bool] | None = None,
    max_seconds: float | None = None,
    store_stream: bool = True,
) -> str:
    """`run_build` of a record already claimed by the attempt `token` (a queue that
    claims as it takes, server/jobs/postgres.py)."""
    mesh_id = record.id
    started = time.monotonic()
    deadline = None if max_seconds is None else started + max_seconds
    progress = _ProgressWriter(storage, mesh_id, token, progress_interval, should_abort,
                               deadline)
    try:
        with storage.blobs.local_path(record.upload_key) as path:
            mesh = codecs.load_mesh(path, name=record.name)
        # Levels are served as float32 (PLY, OBJ, GLB): refuse now what could not be.
        codecs.check_float32_positions(mesh.vertices, record.name)
        progress(_READ_SHARE, force=True)
        options = qem_core.BuildOptions.from_mapping(record.options)
        pm = qem_core.build_mesh(mesh, options, progress=progress.build_share)
        key = qpm_key(mesh_id, token)

        def save() -> None:
            with storage.blobs.staged_path(key) as staged:
                pm.save(staged)

        if store_stream:  # encoded once here, so that serving it is sending bytes
            # The .qpm is saved while the stream is encoded: saving is one thread, much of
            # it waiting on the disk (fsync), and it would otherwise hold up the encoder,
            # which has both cores (dragon: 0.2 s of the stored stream's ~1 s). Both are
            # stored before the mesh is ready; the progress writes stay on this thread.
            with ThreadPoolExecutor(max_workers=1) as saver:
                saving = saver.submit(save)
                write_stream(storage.blobs, key, pm, progress=progress.stream_share)
                saving.result()
        else:
            save()
        bbox = tuple(tuple(float(x) for x in corner) for corner in pm.bbox)
        finished = storage.metadata.finish(
            mesh_id,
            token,
            qpm_key=key,
            n_vertices=pm.n_full,
            n_faces=pm.n_faces_full,
            n_base=pm.n_base,
            bbox=bbox,
        )
        if not finished:
            storage.delete_build(key)
            return "skipped"
        log.info(
            "mesh %s (%s) ready: %d vertices, %d faces, base %d, %.1f s",
            mesh_id,
            record.name,
            pm.n_full,
            pm.n_faces_full,
            pm.n_base,
            time.monotonic() - started,
        )
        return "ready"
    except BuildAborted as exc:
        log.info("build of mesh %s stopped: %s", mesh_id, exc)
        return "skipped"
    except BuildTimedOut:
        reason = (
            f"the build was stopped after {max_seconds:g} s, the time limit of a build on "
            f"this server (QEM_MAX_BUILD_SECONDS); simplify the mesh in parts or ask the "
            f"operator to raise the limit"
        )
    except qem_core.QemError as exc:
        reason = str(exc) or type(exc).__name__
    except FileNotFoundError:
        reason = "the uploaded file is missing from storage; upload the mesh again"
    except MemoryError:
        reason = "out of memory while building; the mesh is too large for this server"
    except Exception as exc:  # a bug, not bad input: keep the reason and the traceback
        log.exception("build of mesh %s crashed", mesh_id)
        reason = f"internal error while building ({type(exc).__name__}: {exc})"
    if storage.metadata.fail(mesh_id, reason, token=token):
        log.info("mesh %s (%s) failed: %s", mesh_id, record.name, reason)
        return "failed"
    return "skipped"

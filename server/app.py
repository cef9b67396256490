"""The FastAPI application factory.

    uvicorn --factory server.app:create_app     # settings from QEM_* variables
    qem serve --data-dir ./data                 # the same, through the CLI

Nothing is built at import time. The lifespan opens the storage, removes leftovers of
interrupted writes, starts the job queue (which requeues interrupted builds), queues the
demo mesh if asked and the storage is empty, and on shutdown stops the builds (they are
requeued by the next start).
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware
from starlette.concurrency import run_in_threadpool

from . import __version__
from .head_requests import HeadAsGet
from .jobs import JobQueue, open_jobs
from .memory_answers import MemoryAnswers
from .metrics import Metrics, RequestMetrics
from .problems import install_problem_handlers
from .read_path import ReadPath
from .request_log import RequestIds
from .routes import health, meshes
from .routes.viewer import mount_viewer
from .settings import Settings, get_settings
from .storage import Storage, open_storage
from .uploads import import_file

__all__ = ["create_app"]

log = logging.getLogger("qem.server")

# Unreferenced blobs younger than this are left to a later start where the storage is
# shared: an upload through another replica writes its blob just before its record.
_SHARED_GARBAGE_AGE_S = 3600.0

_EXPOSED_HEADERS = sorted(
    {*meshes.LOD_HEADERS, *meshes.SPLIT_HEADERS, "Content-Length", "Content-Range", "Accept-Ranges"}
)


def _start(settings: Settings, metrics: Metrics) -> tuple[Storage, JobQueue]:
    settings.data_dir.mkdir(parents=True, exist_ok=True)
    storage = open_storage(settings)
    try:
        # A database others share: their uploads in flight have blobs without records yet.
        storage.collect_garbage(min_age_s=_SHARED_GARBAGE_AGE_S if settings.database_url else 0.0)
        jobs = open_jobs(settings, storage)
        jobs.on_finished = metrics.build_finished
        jobs.start()
    except BaseException:
        storage.close()
        raise
    if settings.demo_mesh is not None and storage.metadata.count() == 0:
        record = import_file(storage, jobs, settings.demo_mesh)
        log.info("queued the demo mesh %s as %s", settings.demo_mesh, record.id)
    return storage, jobs


def create_app(settings: Settings | None = None) -> FastAPI:
    """A new app serving the storage described by `settings` (default: `get_settings()`,
    read from the environment)."""
    settings = settings or get_settings()
    metrics = Metrics()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        storage, jobs = await run_in_threadpool(_start, settings, metrics)
        app.state.storage = storage
        app.state.jobs = jobs
        app.state.reads = ReadPath(storage, settings)
        stop_watching = storage.metadata.watch_deletes(app.state.reads.evict)
        metrics.watch(storage.metadata.status_counts, app.state.reads.cache_stats)
        log.info("serving %s (%d worker(s))", settings.data_dir, settings.workers)
        try:
            yield
        finally:
            await run_in_threadpool(stop_watching)
            metrics.unwatch()
            await run_in_threadpool(jobs.close)
            storage.close()

    app = FastAPI(
        title="qem-lod",
        version=__version__,
        summary="Progressive meshes served at any level of detail",
        description="Upload a triangle mesh once; fetch it at any vertex count, or the "
        "vertex splits that refine one level to another. Errors are RFC 9457 problem "
        "details.",
        lifespan=lifespan,
    )
    app.state.settings = settings
    app.state.metrics = metrics
    install_problem_handlers(app)
    app.add_middleware(HeadAsGet)
    app.state.head_as_get = True  # a 405's Allow names HEAD where it names GET
    app.add_middleware(
        CORSMiddleware,
        allow_origins=list(settings.cors_allow_origins),
        allow_methods=["GET", "HEAD"],
        allow_headers=["If-None-Match", "Range", "If-Range"],
        expose_headers=_EXPOSED_HEADERS,
        max_age=86400,
    )
    app.add_middleware(MemoryAnswers)  # plain GETs of what is in memory
    app.add_middleware(RequestMetrics, metrics=metrics)  # counts them all
    app.add_middleware(RequestIds)  # outermost: every line of a request carries its id
    app.include_router(health.router)
    app.include_router(meshes.router)
    mount_viewer(app, settings.web_dir)
    if not settings.tokens:
        documented = app.openapi  # the problems' document (problems.py), then this
        app.openapi = lambda: _without_write_tokens(documented())
    return app


def _without_write_tokens(document: dict) -> dict:
    """The OpenAPI document of a server whose writes are open (no QEM_TOKENS): the
    bearer scheme the write routes declare is not required, so the document says none."""
    for operations in document.get("paths", {}).values():
        for operation in operations.values():
            if isinstance(operation, dict):
                operation.pop("security", None)
                operation.get("responses", {}).pop("401", None)
                operation.get("responses", {}).pop("403", None)
    document.get("components", {}).pop("securitySchemes", None)
    return document

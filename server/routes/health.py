"""/healthz: liveness (the process answers); /readyz: readiness (the parts it needs
answer: the database and the blob store), for a load balancer or an orchestrator;
/metrics: Prometheus metrics (server/metrics.py)."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from starlette.concurrency import run_in_threadpool

from .. import __version__
from ..deps import StorageDep
from ..metrics import CONTENT_TYPE_LATEST
from ..problems import problem_responses
from ..schemas import Health
from ..storage import StorageUnavailable

__all__ = ["router"]

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness")
def healthz() -> Health:
    return Health(version=__version__)


@router.get(
    "/readyz",
    response_model=Health,
    summary="Readiness: the database and the blob store answer",
    responses=problem_responses(503),
)
async def readyz(storage: StorageDep) -> Health:
    for part, check in (("database", storage.metadata.ping), ("blob store", storage.blobs.ping)):
        try:
            await run_in_threadpool(check)
        except Exception as error:  # any failure of the part: not ready, and why
            # Answered as any request whose storage does not answer (problems.py).
            raise StorageUnavailable(part, error) from None
    return Health(version=__version__)


@router.get(
    "/metrics",
    summary="Prometheus metrics (text exposition format)",
    response_class=Response,
    responses={200: {"content": {CONTENT_TYPE_LATEST: {}}, "description": "the metrics"}},
)
async def metrics(request: Request) -> Response:
    exposition = await run_in_threadpool(request.app.state.metrics.exposition)
    return Response(exposition, media_type=CONTENT_TYPE_LATEST)

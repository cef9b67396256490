"""/healthz: liveness."""

from __future__ import annotations

from fastapi import APIRouter

from .. import __version__
from ..schemas import Health

__all__ = ["router"]

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Liveness")
def healthz() -> Health:
    return Health(version=__version__)

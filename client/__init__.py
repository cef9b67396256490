"""qem-lod clients: the HTTP client library (`QemClient`), the ``qem`` command
(`client.cli`) and the web viewer (``client/web``)."""

from .http import (
    LodResponse,
    QemBuildFailed,
    QemClient,
    QemClientError,
    QemConnectionError,
    QemHTTPError,
)

__all__ = [
    "LodResponse",
    "QemBuildFailed",
    "QemClient",
    "QemClientError",
    "QemConnectionError",
    "QemHTTPError",
]

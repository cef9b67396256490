"""qem-lod's HTTP service: FastAPI app, storage and build jobs. Start it with `qem serve`,
or ``uvicorn --factory server.app:create_app``."""

from importlib import metadata as _metadata

try:
    __version__ = _metadata.version("qem-lod")
except _metadata.PackageNotFoundError:  # running from a source tree
    __version__ = "0+source"

__all__ = ["__version__"]

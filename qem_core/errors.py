"""Exceptions raised by qem_core.

    QemError
    ├── InvalidMeshError (ValueError)      the mesh data or file cannot be used
    │   └── MeshFormatError                 the file is malformed or of an unknown format
    ├── InvalidOptionsError (ValueError)    a build option or a request parameter is wrong
    └── CorruptFileError (ValueError)       a .qpm file or a split-stream frame is damaged,
                                            truncated or of a future version

Messages carry the offending value and say how to fix it. Kernels never raise: their
Python wrappers turn status codes into these exceptions.
"""

__all__ = [
    "QemError",
    "InvalidMeshError",
    "MeshFormatError",
    "InvalidOptionsError",
    "CorruptFileError",
]


class QemError(Exception):
    """Base class of every error qem_core raises on purpose."""


class InvalidMeshError(QemError, ValueError):
    """The mesh cannot be simplified: NaN coordinates, indices out of range, no faces..."""


class MeshFormatError(InvalidMeshError):
    """A mesh file is malformed, truncated, or in a format qem_core does not read."""


class InvalidOptionsError(QemError, ValueError):
    """A build option or a level request is out of its documented range."""


class CorruptFileError(QemError, ValueError):
    """A .qpm file or a split-stream frame is damaged, truncated, or from a future version."""

"""qem_core: quadric-error edge contraction recorded as a progressive mesh.

The public surface is small; everything else is private to the package.
"""

from .errors import (
    CorruptFileError,
    InvalidMeshError,
    InvalidOptionsError,
    MeshFormatError,
    QemError,
)
from .mesh import Mesh
from .options import BuildOptions

__all__ = [
    "BuildOptions",
    "CorruptFileError",
    "InvalidMeshError",
    "InvalidOptionsError",
    "Mesh",
    "MeshFormatError",
    "QemError",
]

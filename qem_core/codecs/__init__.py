"""Mesh file formats: read PLY, OBJ, STL, OFF, GLB and the msgpack form; write PLY, OBJ,
GLB and the msgpack form.

    load_mesh(source, format=None, name=None) -> Mesh     read and validate
    encode_mesh(vertices, faces, format, ...) -> bytes    write
    write_mesh(mesh, format, ...) -> bytes                write a Mesh
    decode_msgpack_mesh(data) -> Mesh                     the compact msgpack form
    check_float32_positions(vertices)                     refuse what float32 cannot hold
    MEDIA_TYPES                                           format -> HTTP content type

One module per format (`ply`, `obj`, `stl`, `off`, `glb`, `msgpack_mesh`); `registry`
maps format names to them. docs/formats.md documents every layout.
"""

from . import registry
from .registry import *  # noqa: F403 (the package's names are the registry's)

__all__ = registry.__all__

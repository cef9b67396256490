"""Mesh file formats: read PLY, OBJ, STL, OFF, GLB and the msgpack form; write PLY, OBJ,
GLB and the msgpack form.

    load_mesh(source, format=None, name=None) -> Mesh     read and validate
    encode_mesh(vertices, faces, format, ...) -> bytes    write
    write_mesh(mesh, format, ...) -> bytes                write a Mesh
    decode_msgpack_mesh(data) -> Mesh                     the compact msgpack form
    MEDIA_TYPES                                           format -> HTTP content type

One module per format (`ply`, `obj`, `stl`, `off`, `glb`, `msgpack_mesh`); `registry`
maps format names to them. docs/formats.md documents every layout.
"""

from .registry import MEDIA_TYPES, decode_msgpack_mesh, encode_mesh, load_mesh, write_mesh

__all__ = ["MEDIA_TYPES", "decode_msgpack_mesh", "encode_mesh", "load_mesh", "write_mesh"]

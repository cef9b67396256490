"""qem_core: quadric-error edge contraction recorded as a progressive mesh.

    pm = qem_core.build(vertices, faces)        # simplify once, record every contraction
    vertices, faces = pm.lod(10_000)            # any level, exactly that many vertices
    pm.save("bunny.qpm"); pm = qem_core.load("bunny.qpm")

The public surface is small; everything else is private to the package.
"""

from .codecs import encode_mesh, load_mesh
from .errors import (
    CorruptFileError,
    InvalidMeshError,
    InvalidOptionsError,
    MeshFormatError,
    QemError,
)
from .mesh import MAX_MATERIALS, Material, Mesh
from .options import BuildOptions
from .preload import warm_up
from .progressive import (
    ProgressiveMesh,
    VertexSplits,
    WedgeSplits,
    apply_splits,
    apply_wedge_splits,
)
from .qpm import load
from .simplify import build


def build_mesh(mesh: Mesh, options=None, progress=None) -> ProgressiveMesh:
    """`build` for a loaded `Mesh`, keeping its appearance: texture coordinates (per
    corner or per vertex), vertex colours and normals enter Hoppe's quadric with the
    weights of the options, travel with the levels (`ProgressiveMesh.lod_mesh`), and the
    texture image is kept (each material's, for a mesh of several). The name is kept in
    the metadata."""
    pm = build(mesh.vertices, mesh.faces, options=options, progress=progress, attributes_of=mesh)
    if mesh.name:
        pm.metadata["name"] = mesh.name
    pm.texture = mesh.texture
    if mesh.face_materials is not None and pm.attribute_layout is not None:
        pm.materials = mesh.materials
    return pm


__all__ = [
    "BuildOptions",
    "CorruptFileError",
    "InvalidMeshError",
    "InvalidOptionsError",
    "MAX_MATERIALS",
    "Material",
    "Mesh",
    "MeshFormatError",
    "ProgressiveMesh",
    "QemError",
    "VertexSplits",
    "WedgeSplits",
    "apply_splits",
    "apply_wedge_splits",
    "build",
    "build_mesh",
    "encode_mesh",
    "load",
    "load_mesh",
    "warm_up",
]

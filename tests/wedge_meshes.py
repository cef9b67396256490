"""Small meshes with appearance attributes, made to have wedges: texture seams, colours,
normals."""

import numpy as np

import qem_core


def seamed_mesh(
    vertices, faces, seed: int = 0, colours: bool = True, normals: bool = False
) -> qem_core.Mesh:
    """``(vertices, faces)`` with corner UVs cut into two charts by a random plane through
    the centroid (each chart a planar projection, the second shifted right), so every
    vertex on the cut has two UVs: a seam. With ``colours``, random 8-bit vertex colours;
    with ``normals``, unit normals from the centroid outward."""
    rng = np.random.default_rng(seed)
    vertices = np.asarray(vertices, np.float64)
    faces = np.asarray(faces, np.int64)
    centre = vertices.mean(axis=0)
    cut = rng.normal(size=3)
    side = (vertices[faces].mean(axis=1) - centre) @ cut > 0  # (m,) chart of each face
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    unit = (vertices - low) / np.where(high > low, high - low, 1.0)
    axes = rng.permutation(3)[:2]
    corner_uvs = unit[faces][:, :, axes] * 0.5  # (m, 3, 2), chart 0 in [0, 0.5]
    corner_uvs[side, :, 0] += 0.5  # chart 1 to the right
    attributes = {}
    if colours:
        attributes["color"] = rng.integers(0, 256, (len(vertices), 3)) / 255.0
    if normals:
        outward = vertices - centre
        length = np.linalg.norm(outward, axis=1, keepdims=True)
        attributes["normal"] = outward / np.where(length > 0, length, 1.0)
    return qem_core.Mesh(
        vertices=vertices,
        faces=faces,
        vertex_attributes={k: v.astype(np.float32) for k, v in attributes.items()},
        corner_uvs=corner_uvs.astype(np.float32),
    )

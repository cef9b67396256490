"""Small meshes with appearance attributes, made to have wedges: texture seams, colours,
normals."""

import numpy as np

import qem_core
from qem_core._kernels.wedge_coding import decode_wedge_fields
from qem_core.quantise import AttributeGrid
from qem_core.stream import new_wedge_contexts, range_code_wedges
from qem_core.wedge_stream import WedgeArrays


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


def wedge_arrays(body: dict, probs=None):
    """The decoded wedge fields of a frame's msgpack map (a `WedgeArrays`), decoded with
    the contexts ``probs`` (updated; fresh when None: the stream's first frame)."""
    width = int(sum(AttributeGrid.from_dict(body["wedge_grid"]).widths))
    k = body["n_to"] - body["n_from"]
    coded = np.frombuffer(body["wedges"], np.uint8)
    if probs is None:
        probs = new_wedge_contexts(width)
    status, *arrays = decode_wedge_fields(
        coded, k, body["n_wedge_symbols"], body["n_wedge_backs"], body["n_wedge_rows"], width,
        probs,
    )  # fmt: skip
    assert status == 0
    return WedgeArrays(*arrays)


def with_wedge_arrays(body: dict, change, probs=None) -> dict:
    """The frame map with its wedge fields replaced by change(wedge_arrays(body)),
    range-coded again (counts and all): a frame that lies about its wedges, well coded.
    ``probs``: the wedge contexts the stream's previous frame left (None for a first
    frame)."""
    before = None if probs is None else probs.copy()
    fields = change(wedge_arrays(body, None if probs is None else probs.copy()))
    return {
        **body,
        "n_wedge_symbols": int(fields.symbols.shape[0]),
        "n_wedge_backs": int(fields.backs.shape[0]),
        "n_wedge_rows": int(fields.rows.shape[0]),
        "wedges": range_code_wedges(fields, before),
    }

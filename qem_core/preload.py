"""Loading the kernels before the first build that needs them.

numba compiles a kernel on its first call in a process, or loads it from its on-disk
cache (``cache=True``), and a build pays that for every kernel it is the first to call.
A small mesh does not call them all: parallel rounds (rounds.py) run only on meshes of
more than `rounds.PARALLEL_MIN_VERTICES` vertices, so the first big build of a process
loaded the rounds' 19 kernels during its own run, even after small builds (60-90 ms of
a dragon build, measured with `bench.build_speed`). `warm_up` builds a small made-up
mesh along every path a build takes (the rounds too, on a lowered threshold, and with
appearance attributes, and with vertex pairs) and reads its levels, so that a long-lived
process pays the loading once, up front.
"""

from __future__ import annotations

import numpy as np

from .mesh import Mesh
from .options import BuildOptions
from .prepare import prepare_mesh_and_edges
from .simplify import build, contract_greedily

__all__ = ["warm_up", "warm_up_mesh"]

# The made-up mesh: a bumpy torus of RING x TUBE vertices (closed) beside a wavy open
# grid of SHEET x SHEET (a border), 1280 vertices in all. Rounds run on it down to
# WARM_UP_ROUNDS_ABOVE live vertices, then the serial loop, as on a big mesh.
RING, TUBE, SHEET = 48, 24, 16
WARM_UP_ROUNDS_ABOVE = 400


def warm_up_mesh() -> tuple[np.ndarray, np.ndarray]:
    """(vertices (n, 3) float64, faces (m, 3) int32): a closed bumpy torus and an open
    wavy grid beside it, each its own component."""
    u = 2.0 * np.pi * np.arange(RING) / RING
    v = 2.0 * np.pi * np.arange(TUBE) / TUBE
    uu, vv = np.meshgrid(u, v, indexing="ij")
    tube = 0.3 + 0.05 * np.sin(5.0 * uu) * np.cos(3.0 * vv)
    torus = np.stack([(1.0 + tube * np.cos(vv)) * np.cos(uu),
                      (1.0 + tube * np.cos(vv)) * np.sin(uu),
                      tube * np.sin(vv)], axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(RING), np.arange(TUBE), indexing="ij")
    here, right = i * TUBE + j, ((i + 1) % RING) * TUBE + j
    up, diagonal = i * TUBE + (j + 1) % TUBE, ((i + 1) % RING) * TUBE + (j + 1) % TUBE
    torus_faces = np.concatenate([np.stack([here, right, diagonal], -1).reshape(-1, 3),
                                  np.stack([here, diagonal, up], -1).reshape(-1, 3)])

    x, y = np.meshgrid(np.linspace(0.0, 1.0, SHEET), np.linspace(0.0, 1.0, SHEET),
                       indexing="ij")
    sheet = np.stack([x + 2.0, y, 0.1 * np.sin(7.0 * x) * np.cos(5.0 * y)],
                     axis=-1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(SHEET - 1), np.arange(SHEET - 1), indexing="ij")
    here = (i * SHEET + j).reshape(-1)
    sheet_faces = np.concatenate([np.stack([here, here + SHEET, here + SHEET + 1], -1),
                                  np.stack([here, here + SHEET + 1, here + 1], -1)])
    vertices = np.concatenate([torus, sheet])
    faces = np.concatenate([torus_faces, sheet_faces + torus.shape[0]]).astype(np.int32)
    return vertices, faces


def warm_up() -> None:
    """Load (or, with an empty cache, compile) every kernel a build and its levels use,
    so that later builds in this process pay none of it. Takes about a second with
    numba's cache filled; call it once, e.g. when a worker process starts."""
    vertices, faces = warm_up_mesh()
    options = BuildOptions()
    prepared, mesh_edges = prepare_mesh_and_edges(vertices, faces, options.merge_coincident)
    contract_greedily(prepared.vertices, prepared.faces, options, mesh_edges=mesh_edges,
                      rounds_above=WARM_UP_ROUNDS_ABOVE)
    # The whole build (the serial path, the assembly) without and with appearance
    # attributes, then its levels; and the pairs' search (off by default).
    normals = np.zeros_like(vertices, np.float32)
    normals[:, 2] = 1.0
    colours = np.clip(np.abs(vertices), 0.0, 1.0).astype(np.float32)
    for mesh in (Mesh(vertices, faces),
                 Mesh(vertices, faces, {"normal": normals, "color": colours,
                                        "uv": colours[:, :2].copy()})):
        pm = build(mesh.vertices, mesh.faces, attributes_of=mesh)
        middle = (pm.n_base + pm.n_full) // 2
        pm.lod_mesh(middle)
        pm.splits(pm.n_base, pm.n_full)
    build(vertices, faces, BuildOptions(pair_threshold=0.05))

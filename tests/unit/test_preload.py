"""`qem_core.warm_up` loads every kernel a build and its levels use: builds after it, of
other meshes along every path (parallel rounds, the serial loop, appearance attributes
per vertex and per corner, pairs, exact error, volume preservation), load none."""

from __future__ import annotations

import subprocess
import sys

import numpy as np

import qem_core
from qem_core.preload import warm_up_mesh

# Run in a fresh interpreter: in this one, earlier tests have loaded kernels already.
AFTER_WARM_UP = """
import gc
import numpy as np
from numba.core.registry import CPUDispatcher
import qem_core
from qem_core.options import BuildOptions
from qem_core.prepare import prepare_mesh_and_edges
from qem_core.simplify import contract_greedily

def overloads():
    return {(d.py_func.__module__, d.py_func.__qualname__): len(d.overloads)
            for d in gc.get_objects() if isinstance(d, CPUDispatcher)}

def sphere(rings, sectors):
    theta = np.linspace(0.0, np.pi, rings + 1)[1:-1]
    phi = 2.0 * np.pi * np.arange(sectors) / sectors
    t, p = np.meshgrid(theta, phi, indexing="ij")
    ring_vertices = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p),
                              np.cos(t) * (1.0 + 0.1 * np.cos(3.0 * p))], -1).reshape(-1, 3)
    vertices = np.concatenate([[[0.0, 0.0, 1.0]], ring_vertices, [[0.0, 0.0, -1.0]]])
    i, j = np.meshgrid(np.arange(rings - 3), np.arange(sectors), indexing="ij")
    here, right = 1 + i * sectors + j, 1 + i * sectors + (j + 1) % sectors
    faces = [np.stack([here, right + sectors, right], -1).reshape(-1, 3),
             np.stack([here, here + sectors, right + sectors], -1).reshape(-1, 3)]
    j = np.arange(sectors)
    last = vertices.shape[0] - 1
    faces.append(np.stack([np.zeros_like(j), 1 + j, 1 + (j + 1) % sectors], -1))
    below = 1 + (rings - 2) * sectors
    faces.append(np.stack([np.full_like(j, last), below + (j + 1) % sectors, below + j], -1))
    return vertices, np.concatenate(faces).astype(np.int32)

qem_core.warm_up()
before = overloads()
vertices, faces = sphere(30, 40)
prepared, edges = prepare_mesh_and_edges(vertices, faces, True)
contract_greedily(prepared.vertices, prepared.faces, BuildOptions(), mesh_edges=edges,
                  rounds_above=300)
colours = np.abs(vertices).astype(np.float32)
corner_uvs = colours[faces][:, :, :2].copy()
for mesh in (qem_core.Mesh(vertices, faces),
             qem_core.Mesh(vertices, faces, {"color": colours}),
             qem_core.Mesh(vertices, faces, {"normal": colours}, corner_uvs=corner_uvs)):
    pm = qem_core.build_mesh(mesh)
    pm.lod_mesh((pm.n_base + pm.n_full) // 2)
    pm.splits(pm.n_base, pm.n_full)
for options in ({"pair_threshold": 0.1}, {"error_mode": "exact"},
                {"preserve_volume": True}, {"weighting": "volume"}):
    qem_core.build(vertices, faces, options)
after = overloads()
print(sorted(name for name, count in after.items() if count > before.get(name, 0)))
"""


def test_builds_after_warm_up_load_no_kernel():
    run = subprocess.run([sys.executable, "-c", AFTER_WARM_UP], capture_output=True,
                         text=True, timeout=900)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip().splitlines()[-1] == "[]", run.stdout


def test_the_warm_up_mesh_is_one_closed_and_one_open_component_of_valid_faces():
    vertices, faces = warm_up_mesh()
    assert np.isfinite(vertices).all()
    assert faces.min() == 0 and faces.max() == vertices.shape[0] - 1
    prepared = qem_core.build(vertices, faces).metadata["prepare_report"]
    assert prepared["components"] == 2
    assert prepared["unreferenced_vertices"] == 0
    assert prepared["degenerate_faces"] == 0 and prepared["duplicate_faces"] == 0

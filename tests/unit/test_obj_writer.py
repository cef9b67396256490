"""OBJ output with each combination of per-vertex attributes reads back the same."""

from __future__ import annotations

import numpy as np
import pytest

import qem_core
from tests.tiny_meshes import icosphere


@pytest.mark.parametrize("names", [(), ("uv",), ("normal",), ("uv", "normal")])
def test_attribute_combinations_round_trip(names):
    vertices, faces = icosphere(1)
    unit = vertices / np.linalg.norm(vertices, axis=1, keepdims=True)
    attributes = {"uv": (unit[:, :2] + 1) / 2, "normal": unit}
    chosen = {name: attributes[name] for name in names}
    mesh = qem_core.load_mesh(qem_core.encode_mesh(vertices, faces, "obj", chosen), format="obj")
    assert np.array_equal(mesh.faces, faces)
    assert sorted(mesh.vertex_attributes) == sorted(names)
    for name in names:  # written as float32
        assert np.allclose(mesh.vertex_attributes[name], chosen[name], atol=1e-6)


def test_a_level_without_faces_can_be_written():
    # A build without topology preservation may collapse to points at its coarsest level.
    content = qem_core.encode_mesh(np.eye(3), np.zeros((0, 3), np.int32), "ply")
    assert b"element face 0" in content


@pytest.mark.parametrize("names", [(), ("normal",), ("color",), ("normal", "color")])
def test_corner_uvs_with_each_combination_round_trip(names):
    """Corner UVs (one per face corner, seams included) beside the other attributes."""
    vertices, faces = icosphere(1)
    unit = vertices / np.linalg.norm(vertices, axis=1, keepdims=True)
    attributes = {"normal": unit, "color": (unit + 1) / 2}
    chosen = {name: attributes[name] for name in names}
    rng = np.random.default_rng(7)
    corner_uvs = rng.integers(0, 5, (len(faces), 3, 2)) / 4  # few values: shared vt lines
    content = qem_core.encode_mesh(vertices, faces, "obj", chosen, corner_uvs=corner_uvs)
    n_vt = content.count(b"\nvt ")
    assert n_vt == len(np.unique(corner_uvs.reshape(-1, 2), axis=0))
    mesh = qem_core.load_mesh(content, format="obj")
    assert np.array_equal(mesh.faces, faces)
    assert np.array_equal(mesh.corner_uvs, corner_uvs.astype(np.float32))
    assert sorted(mesh.vertex_attributes) == sorted(names)
    for name in names:
        assert np.allclose(mesh.vertex_attributes[name], chosen[name], atol=1e-6)

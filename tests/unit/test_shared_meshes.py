"""The real meshes of ../shared/meshes: every sampled level keeps the input's topology, no
face of a level is flipped, and the full level is the input surface.

Each mesh is built once per session (fandisk, spot, bunny, face_rangemap take 0.1 to
2.5 s; igea, the largest closed one the issue names, about 2 s and 1 s of checks on a quiet
machine); dragon.ply is never used in tests. Whether a mesh is closed is taken from
../shared/meshes/SOURCES.md (the "watertight" column) and checked on the input here.
"""

import numpy as np
import pytest

import qem_core
from tests import reference
from tests.tiny_meshes import (
    BOWTIE,
    CUBE,
    FIN,
    OCTAHEDRON,
    OPEN_BOX,
    SQUARE,
    TETRAHEDRON,
    bumpy_grid,
    icosphere,
    perforated_icosphere,
)

CLOSED = {
    "fandisk.ply": True,
    "igea.ply": True,
    "spot.ply": True,
    "bunny.ply": False,
    "face_rangemap.ply": False,
}
N_LEVELS = 8


@pytest.fixture(scope="session")
def shared_build(shared_meshes):
    cache = {}

    def get(name: str):
        if name not in cache:
            mesh = qem_core.load_mesh(shared_meshes / name)
            cache[name] = mesh, qem_core.build(mesh.vertices, mesh.faces)
        return cache[name]

    return get


def sampled_levels(pm) -> list[int]:
    """N_LEVELS vertex counts spread geometrically from the base to the full count."""
    return np.unique(np.geomspace(pm.n_base, pm.n_full, N_LEVELS).astype(int)).tolist() + [
        pm.n_full
    ]


@pytest.mark.parametrize("name", CLOSED)
def test_every_level_keeps_the_topology_of_the_input(shared_build, name):
    mesh, pm = shared_build(name)
    input_chi = reference.fast_euler_characteristic(mesh.faces)
    input_loops = reference.fast_boundary_loops(mesh.faces)
    assert reference.fast_is_closed_manifold(mesh.faces) == CLOSED[name]
    assert (input_loops == 0) == CLOSED[name]
    for n in sampled_levels(pm):
        _, faces = pm.lod(n)
        where = f"{name} at {n} vertices"
        _, uses = reference.undirected_edges(faces)
        assert uses.max() <= 2, f"{where}: an edge in more than two faces"
        if CLOSED[name]:
            # Every edge in two faces, consistently oriented, every vertex link one cycle.
            assert reference.fast_is_closed_manifold(faces), where
            assert reference.fast_euler_characteristic(faces) == input_chi, where
        else:
            assert reference.fast_boundary_loops(faces) == input_loops, where


@pytest.mark.parametrize("name", CLOSED)
def test_no_level_has_a_flipped_face(shared_build, name):
    """Each face of lod(n) is one of the input's faces with its corners moved to their
    clusters' representatives (faces are numbered by birth, and a level's faces are the
    first faces of the full level, corners relabelled by contraction). The face it came
    from is therefore the full level's face with the same index: we first check that
    identity with the independent ancestor map, then require each level face's normal to
    point the same way as that original face's normal (positive dot product). A flip at
    any contraction, or a slow turn over many, shows up as a negative dot product; the
    test is exact (no nearest-face heuristic) and costs O(faces) per level."""
    _, pm = shared_build(name)
    full_vertices, full_faces = pm.lod(pm.n_full)
    full_normals = reference.face_normals(full_vertices, full_faces)
    for n in sampled_levels(pm):
        vertices, faces = pm.lod(n)
        where = f"{name} at {n} vertices"
        assert np.array_equal(reference.ancestors(pm, n)[full_faces[: len(faces)]], faces), where
        normals = reference.face_normals(vertices, faces)
        dots = np.einsum("ij,ij->i", normals, full_normals[: len(faces)])
        flipped = np.flatnonzero(dots <= 0)
        assert flipped.size == 0, f"{where}: faces {flipped[:10].tolist()} are flipped"


@pytest.mark.parametrize("name", CLOSED)
def test_the_full_level_is_the_input_surface(shared_build, name):
    """These files are clean (SOURCES.md: no duplicate or degenerate faces; bunny and
    face_rangemap carry unreferenced vertices), so the full level must be the input's
    referenced vertices at their own positions and the input's faces, oriented as given."""
    mesh, pm = shared_build(name)
    vertices, faces = pm.lod(pm.n_full)
    referenced = np.zeros(len(mesh.vertices), bool)
    referenced[mesh.faces.reshape(-1)] = True
    assert pm.n_full == np.count_nonzero(referenced)
    assert len(faces) == len(mesh.faces)
    assert np.array_equal(pm.vertex_map >= 0, referenced)
    assert np.array_equal(vertices[pm.vertex_map[referenced]], mesh.vertices[referenced])
    assert np.array_equal(
        reference.canonical_faces(faces), reference.canonical_faces(pm.vertex_map[mesh.faces])
    )


@pytest.mark.parametrize("name", ["spot.ply", "bunny.ply"])
def test_a_saved_and_loaded_file_gives_identical_levels(shared_build, tmp_path, name):
    _, pm = shared_build(name)
    pm.save(tmp_path / "mesh.qpm")
    loaded = qem_core.load(tmp_path / "mesh.qpm")
    for n in sampled_levels(pm):
        vertices, faces = pm.lod(n)
        loaded_vertices, loaded_faces = loaded.lod(n)
        assert loaded_vertices.tobytes() == vertices.tobytes()
        assert loaded_faces.tobytes() == faces.tobytes()


@pytest.mark.parametrize("name", ["spot.ply", "bunny.ply"])
def test_splits_between_sampled_levels_give_the_finer_level(shared_build, name):
    _, pm = shared_build(name)
    levels = sampled_levels(pm)
    for n1, n2 in zip(levels[:-1], levels[1:], strict=True):
        vertices, faces = qem_core.apply_splits(*pm.lod(n1), pm.splits(n1, n2))
        expected_vertices, expected_faces = pm.lod(n2)
        assert faces.tobytes() == expected_faces.tobytes()
        assert vertices.tobytes() == expected_vertices.tobytes()


def test_spot_obj_and_spot_ply_are_the_same_surface(shared_build, shared_meshes):
    """The same cow as OBJ (with UVs) and as PLY (SOURCES.md): the same faces and, to
    float32 precision, the same positions; a check of the OBJ reader on a real file."""
    obj = qem_core.load_mesh(shared_meshes / "spot.obj")
    ply, _ = shared_build("spot.ply")
    np.testing.assert_allclose(obj.vertices, ply.vertices, atol=1e-6)
    assert np.array_equal(obj.faces, ply.faces)
    assert obj.corner_uvs is not None and obj.corner_uvs.shape == (len(obj.faces), 3, 2)


# The vectorised checks above stand in for the slow, obvious ones in tests/reference.py;
# here both kinds must agree on meshes of every kind (closed, open, non-manifold).
TINY = {
    "tetrahedron": TETRAHEDRON[1],
    "octahedron": OCTAHEDRON[1],
    "cube": CUBE[1],
    "square": SQUARE[1],
    "open_box": OPEN_BOX[1],
    "fin": FIN[1],
    "bowtie": BOWTIE[1],
    "sphere": icosphere(2)[1],
    "perforated": perforated_icosphere(2, holes=5, seed=3)[1],
    "grid": bumpy_grid(5)[1],
    "two_spheres_sharing_a_vertex": np.concatenate([OCTAHEDRON[1], OCTAHEDRON[1] + 5]),
    "octahedron_one_face_reversed": np.concatenate([OCTAHEDRON[1][:-1], OCTAHEDRON[1][-1:, ::-1]]),
}


@pytest.mark.parametrize("name", TINY)
def test_fast_reference_checks_agree_with_the_slow_ones(name):
    faces = np.asarray(TINY[name])
    assert reference.fast_euler_characteristic(faces) == reference.euler_characteristic(faces)
    assert reference.fast_boundary_loops(faces) == reference.boundary_loops(faces)
    slow = reference.is_closed_manifold(faces)
    assert reference.fast_is_closed_manifold(faces) == slow
    expected_closed = name in {"tetrahedron", "octahedron", "cube", "sphere"}
    assert slow == expected_closed


def test_the_closed_check_sees_a_pinched_vertex():
    """Two octahedra glued at one vertex: every edge has two faces, but the link of the
    shared vertex is two cycles, so it is not a 2-manifold."""
    faces = np.concatenate([OCTAHEDRON[1], OCTAHEDRON[1] + 5])
    assert np.all(reference.undirected_edges(faces)[1] == 2)
    assert not reference.fast_is_closed_manifold(faces)
    assert reference.fast_is_closed_manifold(OCTAHEDRON[1])

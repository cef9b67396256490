"""The exact error mode (Edelsbrunner's inclusion-exclusion) against a brute force.

After any number of contractions, each vertex c of the current complex stands for a
cluster C of original vertices (itself and every vertex contracted into it). Its quadric
must be the sum, each counted once, of the planes in the star of C: the original faces
with at least one corner in C, plus the border constraint planes of the border edges with
an end in C. The quadric of a current edge (c, x) must be the sum of the planes whose
face (or border edge) has a corner in C and a corner in X. The additive mode, for
contrast, sums the members' initial quadrics, so shared planes count several times.

The brute force rebuilds the clusters from the run's record and sums plane quadrics made
by tests/reference.py from the original positions; it reads the run's quadrics through
`contract_greedily`'s returned complex (vertex_quadrics, edge_slot, edge_quadrics).
"""

import numpy as np
import pytest

import qem_core
from qem_core.options import WEIGHTING_CODES
from qem_core.prepare import prepare_mesh
from qem_core.simplify import contract_greedily
from tests import reference
from tests.tiny_meshes import OPEN_BOX, bumpy_grid, icosphere, perforated_icosphere

MESHES = {
    "sphere": icosphere(2, jitter=0.1, seed=11),
    "perforated_sphere": perforated_icosphere(2, holes=5, seed=12),
    "bumpy_grid": bumpy_grid(7, seed=13),
    "open_box": OPEN_BOX,
}


class Planes:
    """Every original plane (faces, then border edges) with its quadric and the original
    vertices it belongs to (a face's three corners, a border edge's two ends)."""

    def __init__(self, vertices, faces, options: qem_core.BuildOptions):
        self.quadrics, self.corners = [], []
        for face in faces:
            self.quadrics.append(reference.plane_quadric(*vertices[face], options.weighting))
            self.corners.append(face.tolist())
        for edge, count in reference.edge_face_counts(faces).items():
            if count != 1:
                continue
            face = next(f for f in faces if set(edge) <= set(f.tolist()))
            p = vertices[face]
            normal = np.cross(p[1] - p[0], p[2] - p[0])
            self.quadrics.append(reference.border_quadric(
                vertices[edge[0]], vertices[edge[1]], normal / np.linalg.norm(normal),
                options.weighting, options.boundary_weight))  # fmt: skip
            self.corners.append(list(edge))
        self.quadrics = np.array(self.quadrics)
        # A scale for tolerances: the largest quadric coefficient in play.
        self.scale = np.abs(self.quadrics).sum(axis=0).max()

    def stars(self, cluster_of) -> tuple[dict, dict]:
        """Brute-force quadrics for a clustering (cluster_of[v] = the cluster of original
        vertex v): cluster -> sum of the planes touching it, and (c, x) with c < x -> sum
        of the planes touching both; each plane counted once per cluster or pair."""
        vertex, edge = {}, {}
        for quadric, corners in zip(self.quadrics, self.corners, strict=True):
            touched = sorted({int(cluster_of[v]) for v in corners})
            for c in touched:
                vertex[c] = vertex.get(c, 0) + quadric
            for i, c in enumerate(touched):
                for x in touched[i + 1 :]:
                    edge[c, x] = edge.get((c, x), 0) + quadric
        return vertex, edge


def _cluster_steps(record, k, n):
    """After each of the first k contractions: (j, its survivor slot, cluster_of), where
    cluster_of[v] is the survivor slot original vertex v has been contracted into."""
    cluster_of = np.arange(n)
    for j in range(k):
        cluster_of[cluster_of == record.b[j]] = record.a[j]
        yield j, int(record.a[j]), cluster_of


def _final_cluster_of(record, k, n):
    cluster_of = np.arange(n)
    for j in range(k):
        cluster_of[cluster_of == record.b[j]] = record.a[j]
    return cluster_of


def _run(mesh_name, options, k):
    prepared = prepare_mesh(*MESHES[mesh_name])
    run = contract_greedily(prepared.vertices, prepared.faces, options, max_contractions=k)
    return prepared, run


def _current_edges(cx):
    alive = cx.faces[cx.face_alive.astype(bool)]
    edges, _ = reference.undirected_edges(alive)
    return edges


# Every weighting qem_core offers (one the reference lacks fails there, by name).
CASES = [(mesh, weighting) for mesh in MESHES for weighting in WEIGHTING_CODES]


@pytest.mark.parametrize("mesh_name, weighting", CASES)
def test_vertex_and_edge_quadrics_count_each_original_plane_once(mesh_name, weighting):
    options = qem_core.BuildOptions(error_mode="exact", weighting=weighting)
    n = len(prepare_mesh(*MESHES[mesh_name]).vertices)
    for fraction in (0.1, 0.5, 1.0):
        prepared, run = _run(mesh_name, options, int(fraction * n))
        planes = Planes(prepared.vertices, prepared.faces, options)
        cx = run.complex
        vertex_star, edge_star = planes.stars(_final_cluster_of(run.record, run.n_contractions, n))
        tolerance = 1e-9 * planes.scale
        for c in np.flatnonzero(cx.vertex_alive):
            np.testing.assert_allclose(
                cx.vertex_quadrics[c], vertex_star[c], rtol=1e-9, atol=tolerance
            )
        slots = dict(cx.edge_slot.items())
        edges = _current_edges(cx)
        for lo, hi in edges.tolist():
            np.testing.assert_allclose(
                cx.edge_quadrics[slots[lo * n + hi]], edge_star[lo, hi], rtol=1e-9, atol=tolerance
            )
        # Quadrics of edges that no longer exist are dropped, not left to go stale.
        assert len(slots) == len(edges)


@pytest.mark.parametrize("mesh_name", list(MESHES))
def test_every_contraction_cost_is_the_exact_quadric_at_the_new_position(mesh_name):
    """cost_j = Q_C(p_j) for the cluster C made by contraction j and the position p_j it
    got, read from the record: the position the survivor had before its next
    contraction, or at the end of the run. The quadric alone: no distance or volume
    charge."""
    options = qem_core.BuildOptions(error_mode="exact", distance_weight=0.0, volume_weight=0.0)
    prepared, run = _run(mesh_name, options, None)
    planes = Planes(prepared.vertices, prepared.faces, options)
    record, k, n = run.record, run.n_contractions, len(prepared.vertices)
    assert k > 0
    for j, a, cluster_of in _cluster_steps(record, k, n):
        later = np.flatnonzero((record.a[j + 1 : k] == a) | (record.b[j + 1 : k] == a))
        if later.size:
            nxt = j + 1 + later[0]
            position = record.position_a[nxt] if record.a[nxt] == a else record.position_b[nxt]
        else:
            position = run.complex.vertices[a]
        members = cluster_of == a
        star = planes.quadrics[[any(members[v] for v in corners) for corners in planes.corners]]
        expected = max(reference.evaluate_quadric(star.sum(axis=0), position), 0.0)
        assert record.cost[j] == pytest.approx(expected, rel=1e-7, abs=1e-10 * planes.scale)


@pytest.mark.parametrize("mesh_name", ["sphere", "perforated_sphere"])
def test_additive_mode_sums_the_members_quadrics_and_differs_from_exact(mesh_name):
    """The contrast that makes the tests above meaningful: additive quadrics are the sum
    of the members' initial quadrics (shared planes counted more than once), and after a
    few contractions they differ from the brute-force star sums."""
    n = len(prepare_mesh(*MESHES[mesh_name]).vertices)
    additive = qem_core.BuildOptions(error_mode="additive")
    prepared, run = _run(mesh_name, additive, n // 3)
    initial = _run(mesh_name, additive, 0)[1].complex.vertex_quadrics
    planes = Planes(prepared.vertices, prepared.faces, additive)
    cluster_of = _final_cluster_of(run.record, run.n_contractions, n)
    vertex_star, _ = planes.stars(cluster_of)
    differs = 0
    for c in np.flatnonzero(run.complex.vertex_alive):
        np.testing.assert_allclose(
            run.complex.vertex_quadrics[c],
            initial[cluster_of == c].sum(axis=0),
            rtol=1e-9,
            atol=1e-9 * planes.scale,
        )
        differs += not np.allclose(run.complex.vertex_quadrics[c], vertex_star[c], rtol=1e-6)
    assert differs > 0

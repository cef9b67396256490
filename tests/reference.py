"""Slow, obvious reference code the tests compare the kernels with."""

from __future__ import annotations

from collections import Counter, defaultdict
from pathlib import Path

import numpy as np

from qem_core._kernels.sweeps import window_ends
from qem_core.options import WEIGHTING_AREA_EXPONENTS

SHARED_MESHES = Path(__file__).resolve().parents[1].parent / "shared" / "meshes"


def edge_face_counts(faces) -> Counter:
    counts = Counter()
    for face in np.asarray(faces).tolist():
        for k in range(3):
            a, b = face[k], face[(k + 1) % 3]
            counts[(min(a, b), max(a, b))] += 1
    return counts


def euler_characteristic(faces) -> int:
    faces = np.asarray(faces)
    return len(np.unique(faces)) - len(edge_face_counts(faces)) + len(faces)


def is_closed_manifold(faces) -> bool:
    """Every edge in exactly two faces and every vertex link a single cycle."""
    faces = np.asarray(faces)
    if any(c != 2 for c in edge_face_counts(faces).values()):
        return False
    link = defaultdict(list)
    for a, b, c in faces.tolist():
        link[a].append((b, c))
        link[b].append((c, a))
        link[c].append((a, b))
    for edges in link.values():
        following = dict(edges)
        if len(following) != len(edges):
            return False
        start = edges[0][0]
        v, steps = following[start], 1
        while v != start and steps <= len(edges):
            v, steps = following.get(v, start), steps + 1
        if steps != len(edges):
            return False
    return True


def _count_classes(links) -> int:
    """Number of connected classes of the items joined by the pairs in `links`."""
    parent = {}

    def find(x):
        while parent.setdefault(x, x) != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for a, b in links:
        parent[find(a)] = find(b)
    return len({find(v) for v in parent})


def boundary_loops(faces) -> int:
    """Number of closed loops formed by border edges (edges of one face)."""
    return _count_classes(e for e, c in edge_face_counts(faces).items() if c == 1)


def components(faces) -> int:
    """Number of edge-connected pieces of the surface."""
    triangles = np.asarray(faces).tolist()
    return _count_classes(pair for a, b, c in triangles for pair in ((a, b), (b, c)))


def face_normals(vertices, faces) -> np.ndarray:
    p = np.asarray(vertices)[np.asarray(faces)]
    return np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])


def triangle_set(vertices, faces, decimals: int = 12) -> Counter:
    """The surface as a multiset of triangles given by rotated corner positions, so two
    meshes compare equal whatever their vertex and face numbering."""
    out = Counter()
    for tri in np.round(np.asarray(vertices)[np.asarray(faces)], decimals).tolist():
        rotations = [tuple(map(tuple, tri[k:] + tri[:k])) for k in range(3)]
        out[min(rotations)] += 1
    return out


def area_weight(area: float, weighting: str) -> float:
    """Each weighting is a power of the area a plane stands for (BuildOptions)."""
    return float(area) ** WEIGHTING_AREA_EXPONENTS[weighting]


def plane_quadric(p0, p1, p2, weighting: str) -> np.ndarray:
    """The (10,) quadric of the plane through a triangle, weighted as qem_core does."""
    n = np.cross(p1 - p0, p2 - p0)
    length = np.linalg.norm(n)
    if length == 0:
        return np.zeros(10)
    n = n / length
    d = -n @ p0
    return _plane(n, d, area_weight(length / 2, weighting))


def border_quadric(pa, pb, face_normal, weighting: str, weight: float) -> np.ndarray:
    e = pb - pa
    n = np.cross(e, face_normal)
    n = n / np.linalg.norm(n)
    # A border plane weighs as a face of area |e|^2 (qem_core's boundary_quadric).
    return _plane(n, -n @ pa, weight * area_weight(e @ e, weighting))


def _plane(n, d, w) -> np.ndarray:
    a = w * np.outer(n, n)
    return np.array([a[0, 0], a[0, 1], a[0, 2], a[1, 1], a[1, 2], a[2, 2], *(w * d * n), w * d * d])


def evaluate_quadric(q, v) -> float:
    a = np.array([[q[0], q[1], q[2]], [q[1], q[3], q[4]], [q[2], q[4], q[5]]])
    return float(v @ a @ v + 2 * q[6:9] @ v + q[9])


def star_quadric(vertices, faces, a, b, weighting: str = "none") -> np.ndarray:
    """The sum of the plane quadrics of the faces around a and b."""
    vertices = np.asarray(vertices, float)
    total = np.zeros(10)
    for face in faces:
        if a in face or b in face:
            total += plane_quadric(*vertices[list(face)], weighting)
    return total


def enclosed_volume(vertices, faces) -> float:
    """The signed volume a closed surface encloses (sum of tetrahedra from the origin)."""
    v = np.asarray(vertices, float)[np.asarray(faces)]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


# -- Exact comparisons and vectorised topology checks --------------------------------
# The checks above walk Python lists and are too slow for the shared meshes (up to 270k
# faces); the ones below do the same with numpy sorts. test_shared_meshes.py checks that
# both kinds agree on the tiny meshes.


def canonical_faces(faces) -> np.ndarray:
    """(m, 3) int64: each face rotated so its smallest index comes first (orientation
    kept), rows sorted, so two face lists compare equal as multisets of oriented faces."""
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    first = np.argmin(faces, axis=1)
    rows = np.arange(faces.shape[0])[:, None]
    rotated = faces[rows, (first[:, None] + np.arange(3)) % 3]
    return rotated[np.lexsort(rotated.T[::-1])]


def exact_triangle_set(vertices, faces) -> Counter:
    """`triangle_set` without rounding: two meshes are equal only when every corner
    position is equal to the last bit."""
    out = Counter()
    for tri in np.asarray(vertices)[np.asarray(faces)].tolist():
        rotations = [tuple(map(tuple, tri[k:] + tri[:k])) for k in range(3)]
        out[min(rotations)] += 1
    return out


def undirected_edges(faces) -> tuple[np.ndarray, np.ndarray]:
    """(unique (E, 2) int64 low-high edges, (E,) how many faces use each)."""
    faces = np.asarray(faces, np.int64)
    sides = np.sort(np.stack([faces, np.roll(faces, -1, axis=1)], axis=2).reshape(-1, 2), axis=1)
    n = int(faces.max(initial=-1)) + 1
    # One int64 key per edge: a 1-D unique is many times faster than unique(axis=0).
    keys, counts = np.unique(sides[:, 0] * n + sides[:, 1], return_counts=True)
    return np.stack([keys // max(n, 1), keys % max(n, 1)], axis=1), counts


def fast_euler_characteristic(faces) -> int:
    edges, _ = undirected_edges(faces)
    return len(np.unique(faces)) - len(edges) + len(faces)


def _cycle_count(successor: np.ndarray) -> int:
    """Number of cycles of a permutation, by pointer doubling (O(n log n))."""
    label = np.arange(successor.size)
    jump = successor.copy()
    for _ in range(max(1, int(np.ceil(np.log2(max(successor.size, 2)))) + 1)):
        label = np.minimum(label, label[jump])
        jump = jump[jump]
    return int(np.count_nonzero(label == np.arange(successor.size)))


def fast_is_closed_manifold(faces) -> bool:
    """Vectorised `is_closed_manifold`, orientation included: every directed edge once
    and its reverse once, and the faces around each vertex one fan.

    The fan test follows corners: the corner of vertex v in face f is followed by the
    corner of v in the face across f's edge into v. That is a permutation of corners;
    each vertex is manifold when its corners make one cycle, so the mesh is when the
    permutation has as many cycles as there are vertices.
    """
    faces = np.asarray(faces, np.int64)
    m = faces.shape[0]
    tail = faces.reshape(-1)
    head = np.roll(faces, -1, axis=1).reshape(-1)
    n = int(faces.max()) + 1
    key = tail * n + head
    order = np.argsort(key)
    sorted_key = key[order]
    if np.any(sorted_key[1:] == sorted_key[:-1]):
        return False  # a directed edge twice: inconsistent orientation or non-manifold
    reverse = head * n + tail
    position = np.minimum(np.searchsorted(sorted_key, reverse), key.size - 1)
    if not np.array_equal(sorted_key[position], reverse):
        return False  # an edge without its reverse: a border
    twin = order[position]  # side 3 f + k -> the side that runs the other way
    # Corner c = 3 f + k sits at faces[f, k]; the side into it is 3 f + (k - 1).
    corner = np.arange(3 * m)
    side_into = 3 * (corner // 3) + (corner % 3 + 2) % 3
    # The reverse of the side into v leaves v: its side index is v's corner there.
    successor = twin[side_into]
    return _cycle_count(successor) == len(np.unique(faces))


def fast_boundary_loops(faces) -> int:
    """Vectorised `boundary_loops`: border edges found with numpy, joined in Python
    (borders are short)."""
    edges, counts = undirected_edges(faces)
    return _count_classes(map(tuple, edges[counts == 1].tolist()))


def ancestors(pm, n: int) -> np.ndarray:
    """(n_full,) the vertex of lod(n) each vertex of lod(n_full) was contracted into.

    From the progressive mesh model alone (qem_core/progressive.py, docs/formats.md):
    the split that makes level L + 1 from level L creates vertex t = L out of vertex
    split_vertex[L - n_base]. So vertex u >= n was merged into split_vertex[u - n_base],
    and its ancestor at level n is found by following those links below n (pointer
    doubling; every link points to a smaller index).
    """
    parent = np.arange(pm.n_full)
    parent[n:] = pm.split_vertex[n - pm.n_base :]
    while np.any(parent >= n):
        parent = parent[parent]
    return parent


def assert_decoded_level(decoder, pm, n: int) -> None:
    """The split stream decoder holds exactly ``pm.lod(n)`` on the stream's grid."""
    from qem_core.stream import grid_for

    vertices, faces = pm.lod(n)
    assert decoder.n_vertices == n
    np.testing.assert_array_equal(decoder.faces, faces)
    np.testing.assert_array_equal(decoder.quantised, grid_for(pm).quantise(vertices))


def greedy_levels(pm) -> list[int]:
    """The levels of ``pm`` that are the greedy run's stopped there: the base and the
    ends of the sweep order's windows (qem_core/_kernels/sweeps.py); a level inside a
    window holds another subset of the window's splits."""
    return [pm.n_base, *window_ends(pm.n_base, pm.n_full - pm.n_base)]


def greedy_level(pm, n: int) -> int:
    """The greedy level nearest to ``n`` at or below it (the base at least)."""
    return max(level for level in greedy_levels(pm) if level <= max(n, pm.n_base))

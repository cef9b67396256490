"""Hand-drawn meshes with known answers. Every closed one is oriented outward."""

import numpy as np

# Tetrahedron: the smallest closed surface; no edge may be contracted.
TETRAHEDRON = (
    np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], float),
    np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]),
)

# Octahedron: 6 vertices, 8 faces; it can shrink to a tetrahedron and no further.
OCTAHEDRON = (
    np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float),
    np.array(
        [[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]]
    ),
)

#   3 ---- 2
#   |    / |      a square of two triangles: it may become one triangle, not less
#   |  /   |
#   0 ---- 1
SQUARE = (
    np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float),
    np.array([[0, 1, 2], [0, 2, 3]]),
)

# A unit cube with its top face removed: an open box, one border loop of 4 edges.
_CUBE_V = np.array([[x, y, z] for z in (0, 1) for y in (0, 1) for x in (0, 1)], float)
OPEN_BOX = (
    _CUBE_V,
    np.array(
        [
            [0, 2, 1],
            [1, 2, 3],  # bottom z=0
            [0, 1, 5],
            [0, 5, 4],  # y=0
            [2, 6, 7],
            [2, 7, 3],  # y=1
            [0, 4, 6],
            [0, 6, 2],  # x=0
            [1, 3, 7],
            [1, 7, 5],  # x=1
        ]
    ),
)


def grid(n: int = 5):
    """A flat n x n vertex grid in the plane z = 0, triangulated."""
    xs, ys = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float))
    vertices = np.stack([xs.ravel(), ys.ravel(), np.zeros(n * n)], axis=1)
    faces = []
    for j in range(n - 1):
        for i in range(n - 1):
            v = j * n + i
            faces += [[v, v + 1, v + n + 1], [v, v + n + 1, v + n]]
    return vertices, np.array(faces)


def icosphere(subdivisions: int = 1, jitter: float = 0.0, seed: int = 0):
    """A unit icosphere, optionally with its vertices moved radially at random."""
    t = (1 + 5**0.5) / 2
    vertices = [
        [-1, t, 0],
        [1, t, 0],
        [-1, -t, 0],
        [1, -t, 0],
        [0, -1, t],
        [0, 1, t],
        [0, -1, -t],
        [0, 1, -t],
        [t, 0, -1],
        [t, 0, 1],
        [-t, 0, -1],
        [-t, 0, 1],
    ]
    faces = [
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ]
    vertices = [np.array(v, float) / np.linalg.norm(v) for v in vertices]
    for _ in range(subdivisions):
        midpoint = {}

        def middle(a, b, midpoint=midpoint):
            key = (min(a, b), max(a, b))
            if key not in midpoint:
                m = vertices[a] + vertices[b]
                vertices.append(m / np.linalg.norm(m))
                midpoint[key] = len(vertices) - 1
            return midpoint[key]

        refined = []
        for a, b, c in faces:
            ab, bc, ca = middle(a, b), middle(b, c), middle(c, a)
            refined += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        faces = refined
    vertices = np.array(vertices)
    if jitter:
        rng = np.random.default_rng(seed)
        vertices *= 1 + jitter * rng.uniform(-1, 1, size=(len(vertices), 1))
    return vertices, np.array(faces)


# The unit cube, closed: OPEN_BOX and its top face z=1.
CUBE = (_CUBE_V, np.concatenate([OPEN_BOX[1], [[4, 5, 7], [4, 7, 6]]]))

#      3
#     /|\        a fin: three triangles on the edge 0-1, which is non-manifold
#    / | \       (2 and 3 on either side in the plane z = 0, 4 above it)
#   2--0--1 ... 4
FIN = (
    np.array([[0, 0, 0], [1, 0, 0], [0.5, -1, 0], [0.5, 1, 0], [0.5, 0, 1]], float),
    np.array([[0, 1, 3], [1, 0, 2], [0, 1, 4]]),
)

#   3       1
#   | \   / |    a bowtie: two triangles that share only vertex 0
#   |   0   |
#   | /   \ |
#   4       2
BOWTIE = (
    np.array([[0, 0, 0], [1, 1, 0], [1, -1, 0], [-1, 1, 0], [-1, -1, 0]], float),
    np.array([[0, 2, 1], [0, 3, 4]]),
)


def soup(vertices, faces):
    """The mesh as an STL-like triangle soup: three vertex copies per face."""
    vertices, faces = np.asarray(vertices), np.asarray(faces)
    return vertices[faces.reshape(-1)].copy(), np.arange(faces.size).reshape(-1, 3)


def perforated_icosphere(
    subdivisions: int = 2, jitter: float = 0.05, holes: int = 3, seed: int = 0
):
    """A jittered icosphere with `holes` randomly chosen faces removed (an open mesh;
    holes that share a vertex make a pinched border, which is allowed input)."""
    vertices, faces = icosphere(subdivisions, jitter, seed)
    rng = np.random.default_rng(seed)
    keep = np.ones(len(faces), bool)
    keep[rng.choice(len(faces), size=holes, replace=False)] = False
    return vertices, faces[keep]


def bumpy_grid(n: int = 6, amplitude: float = 0.3, seed: int = 0):
    """`grid(n)` with random heights, so no two contractions cost the same."""
    vertices, faces = grid(n)
    vertices[:, 2] = amplitude * np.random.default_rng(seed).uniform(-1, 1, n * n)
    return vertices, faces


def degenerate_ring_pm():
    """A progressive mesh (not built: drawn) whose two splits take the split stream's rarer
    paths: the first splits a vertex whose only face is flat (collinear corners: its ring
    has no normal, so the positions are coded axis by axis), and its new face (0, 6, 4)
    reaches vertex 4, no neighbour of 0 (the third corner is escaped); the second leaves
    t at s's old position (an end stayed), and its relabel is not the predicted fan.

    base: f0 = (0, 1, 2) collinear, f1 = (3, 4, 5)
    split 0: s=0 -> t=6   new f2 = (0, 6, 4)   relabel f0: 0 -> 6
    split 1: s=6 -> t=7   new f3 = (7, 6, 1)   relabel f2: 6 -> 7, t at 6's position
    """
    from qem_core.progressive import ProgressiveMesh

    return ProgressiveMesh(
        base_vertices=np.array(
            [[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [4, 0, 0], [3, 1, 0]]
        ),
        split_vertex=np.array([0, 6], np.int32),
        split_positions=np.array(
            [[[0.0, 0.5, 0.5], [1.5, 1, 0.25]], [[2.5, 1.5, 0.75], [1.5, 1, 0.25]]]
        ),
        face_corners=np.array([[0, 1, 2], [3, 4, 5], [0, 6, 4], [7, 6, 1]], np.int32),
        level_faces=np.array([2, 3, 4]),
        relabel_offsets=np.array([0, 1, 2]),
        relabel_faces=np.array([0, 2], np.int32),
        split_cost=np.array([2.0, 1.0]),
    )

"""The first quadrics (`quadrics.fill_face_quadrics`): each face's plane, summed into its
corners, the same to the last bit whatever the number of threads."""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from qem_core._kernels.quadrics import QUADRIC_SIZE, fill_face_quadrics
from qem_core.options import WEIGHTING_CODES
from tests import reference


def filled(vertices, faces, weighting, n_chunks, keep_face_quadrics=True):
    # NaN where the kernel must write: it takes its arrays uninitialised.
    n, m = vertices.shape[0], faces.shape[0]
    face_quadrics = np.full((m if keep_face_quadrics else 0, QUADRIC_SIZE), np.nan)
    face_normals = np.full((m, 3), np.nan)
    vertex_quadrics = np.full((n, QUADRIC_SIZE), np.nan)
    fill_face_quadrics(vertices, faces, WEIGHTING_CODES[weighting], face_quadrics,
                       face_normals, vertex_quadrics, n_chunks)
    return face_quadrics, face_normals, vertex_quadrics


@given(st.integers(3, 24).flatmap(lambda n: st.tuples(
    # Points on a grid of sixteenths: every cross product is exact, so the kernel and
    # the reference agree on which faces have no area (floats near 1e-160 would make
    # that a matter of rounding).
    st.lists(st.tuples(*[st.integers(-64, 64).map(lambda k: k / 16)] * 3), min_size=n,
             max_size=n),
    st.lists(st.permutations(range(n)).map(lambda p: p[:3]), min_size=1, max_size=60))),
    st.integers(2, 6), st.sampled_from(sorted(WEIGHTING_CODES)))
def test_face_quadrics_do_not_depend_on_the_threads(drawn, n_chunks, weighting):
    """Threads own runs of the vertex numbers and go through the faces in order, so every
    vertex sums its faces' planes in face order: the sums of any number of runs equal one
    run's bit for bit, and the planes those of the reference (a face on repeated points,
    of no area, has none)."""
    points, face_list = drawn
    vertices = np.array(points, np.float64)
    faces = np.array(face_list, np.int32)
    one = filled(vertices, faces, weighting, 1)
    many = filled(vertices, faces, weighting, n_chunks)
    for single, threaded in zip(one, many, strict=True):
        assert np.array_equal(single, threaded)
    face_quadrics, _, vertex_quadrics = one
    planes = [reference.plane_quadric(*vertices[face], weighting) for face in faces]
    expected = np.zeros_like(vertex_quadrics)
    for face, plane in zip(faces, planes, strict=True):
        expected[face] += plane
    scale = max(1.0, float(np.abs(expected).max()))
    np.testing.assert_allclose(face_quadrics, planes, rtol=1e-9, atol=1e-9 * scale)
    np.testing.assert_allclose(vertex_quadrics, expected, rtol=1e-9, atol=1e-9 * scale)
    normals = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                       vertices[faces[:, 2]] - vertices[faces[:, 0]])
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, lengths, out=np.zeros_like(normals), where=lengths > 0)
    np.testing.assert_allclose(one[1], normals, rtol=1e-12, atol=1e-12)
    # The additive mode keeps no face quadrics; the rest is the same.
    _, normals, without = filled(vertices, faces, weighting, n_chunks, keep_face_quadrics=False)
    assert np.array_equal(without, vertex_quadrics) and np.array_equal(normals, one[1])

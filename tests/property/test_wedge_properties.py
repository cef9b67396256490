"""Hypothesis properties of the wedge side of the progressive mesh, on the random small
meshes of test_properties.py given texture seams (and sometimes colours and normals,
tests/wedge_meshes.py): for random n1 <= n2, the splits n1 -> n2 refine the wedges of
lod(n1) into those of lod(n2), and so does the split stream, quantised.
"""

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

import qem_core
from qem_core.stream import (
    SplitStreamDecoder,
    encode_split_frames,
    grid_for,
    iter_frames,
    quantised_wedges,
)
from tests.property.test_properties import PROPERTY_SETTINGS, meshes
from tests.wedge_meshes import seamed_mesh


@st.composite
def seamed_meshes(draw):
    vertices, faces = draw(meshes())
    seed = draw(st.integers(0, 2**31 - 1))
    return seamed_mesh(
        vertices, faces, seed, colours=draw(st.booleans()), normals=draw(st.booleans())
    )


@PROPERTY_SETTINGS
@given(seamed_meshes(), st.data())
def test_splits_and_stream_of_random_seamed_meshes_give_lod_mesh(mesh, data):
    pm = qem_core.build_mesh(mesh)
    n1 = data.draw(st.integers(pm.n_base, pm.n_full), label="n1")
    n2 = data.draw(st.integers(n1, pm.n_full), label="n2")
    per_frame = data.draw(st.integers(1, 64), label="splits per frame")
    splits = pm.splits(n1, n2)
    face_wedges, values = qem_core.apply_wedge_splits(*pm.wedge_level(n1), splits)
    expected_wedges, expected_values = pm.wedge_level(n2)
    assert np.array_equal(face_wedges, expected_wedges)
    assert np.array_equal(values, expected_values)

    vertices, faces = pm.lod(n1)
    decoder = SplitStreamDecoder(grid_for(pm).quantise(vertices), faces, quantised_wedges(pm, n1))
    for payload in iter_frames(encode_split_frames(pm, n1, n2, splits_per_frame=per_frame)):
        decoder.feed(payload)
    expected = quantised_wedges(pm, n2)
    assert np.array_equal(decoder.faces, pm.lod(n2)[1])
    assert np.array_equal(decoder.face_wedges, expected.face_wedges)
    assert np.array_equal(decoder.quantised_values, expected.values)

"""refine.js and wedges.js under node refuse the frames the Python decoder refuses, each
started from the same msgpack base mesh (``SplitStreamDecoder.from_msgpack`` and the
viewer's ``decodeBaseMesh``): a first frame on another grid than the base mesh's, grid
bits off their range, a split that puts a position off the grid (a shift of 2^32 would
wrap to the true position in the viewer's 32-bit buffers), another wedge grid, a wedge
residual no 16-bit grid holds; and a base mesh whose wedge values leave their grid.
"""

from __future__ import annotations

import json
import struct
import zlib
from pathlib import Path

import msgpack
import numpy as np
import pytest

import qem_core
from qem_core import codecs
from qem_core.stream import (
    SplitStreamDecoder,
    encode_split_frames,
    grid_for,
    iter_frames,
    quantised_wedges,
)
from tests.tiny_meshes import icosphere, perforated_icosphere
from tests.unit.conftest import SPOT
from tests.unit.test_stream import _disc, off_grid_frame, one_vertex_frame
from tests.unit.test_stream_wedges import hub_wedge_frame
from tests.wedge_meshes import seamed_mesh, with_wedge_arrays

from .test_viewer import WEB, pm_digest, run_node_script, run_refine_js


@pytest.fixture(scope="module")
def pm():
    return qem_core.build(*perforated_icosphere(2, holes=3, seed=7))


@pytest.fixture(scope="module")
def seamed_pm():
    vertices, faces = icosphere(2, jitter=0.05, seed=4)
    return qem_core.build_mesh(seamed_mesh(vertices, faces, seed=4))


def _sealed(body: dict) -> bytes:
    """A frame payload of this msgpack map with its right CRC-32."""
    data = msgpack.packb(body)
    return data + struct.pack("<I", zlib.crc32(data))


def _frame(payload: bytes) -> bytes:
    return struct.pack("<I", len(payload)) + payload


def _refusals(tmp_path: Path, pm, payload: bytes) -> tuple[dict, str | None]:
    """What refine.js answers for the one-frame stream `payload` on lod(n_base), and the
    Python decoder's refusal of it on the same base mesh (None if it decodes it)."""
    answer = run_refine_js(tmp_path, pm, [pm.n_base + 20], stream=_frame(payload))
    decoder = SplitStreamDecoder.from_msgpack((tmp_path / "base.msgpack").read_bytes())
    try:
        decoder.feed(payload)
    except qem_core.CorruptFileError as error:
        return answer, str(error)
    return answer, None


def _first_payload(pm) -> bytes:
    return next(iter_frames(encode_split_frames(pm, pm.n_base, pm.n_base + 20)))


def _rewritten(payload: bytes, change) -> bytes:
    return _sealed(change(msgpack.unpackb(payload[:-4])))


@pytest.mark.parametrize("shift", [1 << 32, -(1 << 32), 1 << 20, 70_000])
def test_both_decoders_refuse_a_position_off_the_grid(tmp_path, pm, shift):
    answer, python = _refusals(tmp_path, pm, off_grid_frame(pm, pm.n_base + 20, shift))
    message = "split frame: a position leaves the grid ([0, 2^bits - 1])"
    assert answer == {"error": f"WireFormatError: {message}", "held": pm.n_base}
    assert python == message


def test_both_decoders_take_the_crafted_frame_unchanged(tmp_path, pm):
    """off_grid_frame with no shift is the true frame: both decode it."""
    n2 = pm.n_base + 20
    answer, python = _refusals(tmp_path, pm, off_grid_frame(pm, n2, 0))
    assert python is None
    assert answer[n2] == {"level": n2, "faces": pm.n_faces(n2), "digest": pm_digest(pm, n2)}


def _grid(change):
    return lambda body: {**body, "grid": change(list(body["grid"]))}


@pytest.mark.parametrize(
    ("change", "viewer", "python"),
    [
        (_grid(lambda g: [g[0] + 1.0, *g[1:]]), "the split stream's grid", "is not that of"),
        (_grid(lambda g: [*g[:3], 2 * g[3], *g[4:]]), "the split stream's grid", "is not that of"),
        (lambda b: {**b, "bits": 12}, "the split stream's grid", "is not that of"),
        (lambda b: {**b, "bits": 99}, "split frame: 'bits' is 99,", "'bits' is 99,"),
        (lambda b: {**b, "bits": "16"}, "split frame: 'bits' is 16,", "'bits' is '16',"),
        (lambda b: {**b, "bits": 7}, "split frame: 'bits' is 7,", "'bits' is 7,"),
    ],
    ids=["origin", "step", "other-bits", "bits-99", "bits-str", "bits-7"],
)
def test_both_decoders_refuse_a_first_frame_on_another_grid(tmp_path, pm, change, viewer, python):
    answer, refused = _refusals(tmp_path, pm, _rewritten(_first_payload(pm), change))
    assert answer["error"].startswith(f"WireFormatError: {viewer}"), answer
    assert answer["held"] == pm.n_base
    assert refused is not None and python in refused, refused


def _wedge_grid(change):
    return lambda body: {**body, "wedge_grid": change(dict(body["wedge_grid"]))}


@pytest.mark.parametrize(
    ("change", "viewer", "python"),
    [
        (
            _wedge_grid(lambda g: {**g, "origin": [x + 0.25 for x in g["origin"]]}),
            "the split stream's wedge grid is not the base mesh's",
            "is not that of the wedges held",
        ),
        (
            _wedge_grid(lambda g: {**g, "names": g["names"][::-1], "widths": g["widths"][::-1]}),
            "the split stream's wedge grid is not the base mesh's",
            "is not that of the wedges held",
        ),
        (
            lambda body: with_wedge_arrays(body, lambda w: w._replace(rows=w.rows + 70_000)),
            "split frame: a wedge value leaves its grid",
            "split frame: a wedge value leaves its grid",
        ),
    ],
    ids=["other-origin", "other-order", "residual-over-16-bits"],
)
def test_both_decoders_refuse_wedge_keys_they_cannot_refine(
    tmp_path, seamed_pm, change, viewer, python
):
    assert len(quantised_wedges(seamed_pm, seamed_pm.n_base).grid.names) == 2
    answer, refused = _refusals(tmp_path, seamed_pm, _rewritten(_first_payload(seamed_pm), change))
    assert answer["error"].startswith(f"WireFormatError: {viewer}"), answer
    assert refused is not None and python in refused, refused


_BASE_DRIVER = """
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";
const { decodeBaseMesh } = await import(pathToFileURL(process.argv[2]).href);
try {
  decodeBaseMesh(readFileSync(process.argv[3]));
  console.log(JSON.stringify({ error: null }));
} catch (error) {
  console.log(JSON.stringify({ error: `${error.name}: ${error.message}` }));
}
"""


def _base_mesh_errors(tmp_path, blobs: list[bytes]) -> list[str | None]:
    """What the viewer's decodeBaseMesh answers for each msgpack level (None: read)."""
    answers = []
    for blob in blobs:
        (tmp_path / "base.msgpack").write_bytes(blob)
        printed = run_node_script(
            tmp_path, _BASE_DRIVER, WEB / "js" / "refine.js", tmp_path / "base.msgpack"
        )
        answers.append(json.loads(printed)["error"])
    return answers


def test_the_viewer_refuses_base_wedge_values_off_their_grid(tmp_path, seamed_pm):
    """As msgpack_mesh.read_msgpack_wedges (tests/unit/test_stream_wedges.py)."""
    n = seamed_pm.n_base
    wedges = quantised_wedges(seamed_pm, n)
    blobs = [
        codecs.encode_mesh(
            *seamed_pm.lod(n), "msgpack", quantize_bits=16, grid_box=seamed_pm.position_bounds,
            wedges=wedges._replace(values=values),
        )  # fmt: skip
        for values in (wedges.values, np.full_like(wedges.values, 255 + 1))  # colours: 8 bits
    ]
    assert _base_mesh_errors(tmp_path, blobs) == [
        None,
        "WireFormatError: base mesh: 'wedges' values lie outside their grid",
    ]


def test_both_decoders_refuse_a_base_mesh_they_could_not_refine(tmp_path, pm):
    """Faces naming a vertex past the level's, integers past its grid: as read_msgpack."""
    n = pm.n_base + 5
    served = msgpack.unpackb(
        codecs.encode_mesh(*pm.lod(n), "msgpack", quantize_bits=16, grid_box=pm.position_bounds)
    )
    indices = bytearray(served["indices"])
    indices[0] = n  # u8 indices on this small level: one past the last vertex
    positions = np.frombuffer(served["positions"], "<u2").copy()
    positions[0] = 1 << 12
    blobs = [
        msgpack.packb({**served, "indices": bytes(indices)}),
        msgpack.packb({**served, "positions": positions.tobytes(), "position_bits": 12}),
    ]
    assert _base_mesh_errors(tmp_path, blobs) == [
        f"WireFormatError: base mesh: 'indices' name a vertex past 'vertex_count' {n}",
        "WireFormatError: base mesh: 'positions' hold values past the 12-bit grid",
    ]
    for blob, python in zip(blobs, ["name vertex", "past the 12-bit grid"], strict=True):
        with pytest.raises(qem_core.MeshFormatError, match=python):
            SplitStreamDecoder.from_msgpack(blob)


def test_both_decoders_refuse_a_base_mesh_whose_box_is_no_grid(tmp_path, pm):
    """Fuzz finding r06: a bbox spanning more than float64 steps over (inf positions) or
    with a min above its max (every position moved) was taken as the grid."""
    served = msgpack.unpackb(
        codecs.encode_mesh(*pm.lod(pm.n_base), "msgpack", quantize_bits=16,
                           grid_box=pm.position_bounds)
    )  # fmt: skip
    boxes = [[-1e308, 0, 0, 1e308, 1, 1], [1, 1, 1, 0, 0, 0]]
    blobs = [msgpack.packb({**served, "bbox": box}) for box in boxes]
    assert _base_mesh_errors(tmp_path, blobs) == [
        "WireFormatError: base mesh: 'bbox' [-1e+308,0,0,1e+308,1,1] spans more than "
        "float64 can hold",
        "WireFormatError: base mesh: 'bbox' [1,1,1,0,0,0]: a min is above its max",
    ]
    for blob, python in zip(blobs, ["spans more than float64", "min is above"], strict=True):
        with pytest.raises(qem_core.MeshFormatError, match=python):
            SplitStreamDecoder.from_msgpack(blob)


def test_both_decoders_refuse_a_frame_past_the_work_limit(tmp_path):
    """A frame whose splits split vertex 0 again and again, each adding a face to it:
    4.5 million corners to walk (the encoder's planner never makes such a frame), refused
    by both decoders once they pass FRAME_WORK_LIMIT."""
    pm = qem_core.build(*_disc(3000))
    vertices, faces = pm.lod(pm.n_base)
    payload = one_vertex_frame(vertices, faces, grid_for(pm), k=pm.n_full - pm.n_base, per=1)
    answer, python = _refusals(tmp_path, pm, payload)
    message = "split frame: the splits walk more than 2097152 corners of their split vertices"
    assert answer == {"error": f"WireFormatError: {message}", "held": pm.n_base}
    assert python is not None and python.startswith(message), python


def test_both_decoders_refuse_a_base_mesh_with_fractional_counts(tmp_path, pm):
    """Regression: the viewer read 44.5 vertices as a RangeError, and 84.3 faces as 84."""
    n = pm.n_base + 5
    served = msgpack.unpackb(
        codecs.encode_mesh(*pm.lod(n), "msgpack", quantize_bits=16, grid_box=pm.position_bounds)
    )
    blobs = [
        msgpack.packb({**served, "vertex_count": n + 0.5}),
        msgpack.packb({**served, "face_count": served["face_count"] + 1 / 3}),
    ]
    assert _base_mesh_errors(tmp_path, blobs) == [
        f"WireFormatError: base mesh: 'vertex_count' must be a non-negative integer, got {n + 0.5}",
        "WireFormatError: base mesh: 'face_count' must be a non-negative integer, got "
        f"{served['face_count'] + 1 / 3}",
    ]
    for blob in blobs:
        with pytest.raises(qem_core.MeshFormatError, match="non-negative integer"):
            SplitStreamDecoder.from_msgpack(blob)


_CUTTER_DRIVER = """
import { readFileSync } from "node:fs";
import { pathToFileURL } from "node:url";
const [refinePath, streamPath] = process.argv.slice(2);
const { FrameCutter } = await import(pathToFileURL(refinePath).href);
const cutter = new FrameCutter();
const out = { payloads: [] };
try {
  for (const payload of cutter.push(readFileSync(streamPath))) out.payloads.push(payload.length);
  cutter.finish();
} catch (error) {
  out.error = `${error.name}: ${error.message}`;
}
console.log(JSON.stringify(out));
"""


def test_frames_before_a_bad_length_are_cut_in_any_chunking(tmp_path, pm):
    """Regression: in one chunk with a frame length past the limit, the good frames
    before it were lost with the error (one frame a chunk, they were refined): the
    viewer's level depended on how the bytes arrived. iter_frames yields them first too."""
    good = list(iter_frames(encode_split_frames(pm, pm.n_base, pm.n_base + 20,
                                                splits_per_frame=10)))[:2]
    stream = b"".join(_frame(payload) for payload in good) + struct.pack("<I", 1 << 30)
    (tmp_path / "splits.bin").write_bytes(stream)
    answer = json.loads(
        run_node_script(tmp_path, _CUTTER_DRIVER, WEB / "js" / "refine.js", tmp_path / "splits.bin")
    )
    assert answer["payloads"] == [len(payload) for payload in good]
    assert answer["error"].startswith("WireFormatError: split frame declares 1073741824 bytes")
    python = []
    with pytest.raises(qem_core.CorruptFileError):
        for payload in iter_frames([stream]):
            python.append(payload)
    assert python == good


@pytest.fixture(scope="module")
def spot_pm():
    """Spot (the repository's demo copy) with its UVs: levels enough for a long frame."""
    return qem_core.build_mesh(qem_core.load_mesh(SPOT))


def test_both_decoders_refuse_a_frame_past_the_wedge_work_limit(tmp_path, spot_pm):
    """A frame whose new faces all hold one vertex, whose corners the wedge side reads
    for each of them (tests/unit/test_stream_wedges.py): refused by both decoders once
    they pass twice WEDGE_WORK_LIMIT (this one would read 31 million corners)."""
    payload = hub_wedge_frame(spot_pm, 350, 16)  # within the viewer's full face count
    answer, python = _refusals(tmp_path, spot_pm, payload)
    message = "split frame: the wedges of its new faces read more than 8388608 corners"
    assert answer["error"].startswith(f"WireFormatError: {message}"), answer
    assert answer["held"] == spot_pm.n_base
    assert python is not None and python.startswith(message), python

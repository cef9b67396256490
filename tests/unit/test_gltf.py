""".gltf (JSON) with its .bin and images: beside it on disk, in a zip, or as data: URIs;
and what is missing said by name."""

from __future__ import annotations

import base64
import json
import struct

import numpy as np
import pytest

import qem_core
from qem_core.codecs.archive import write_archive
from tests.unit.conftest import SPOT

SPOT_GLB = SPOT.with_suffix(".glb")


def split_glb(glb: bytes) -> tuple[dict, bytes]:
    """The JSON document and the binary chunk of a GLB."""
    json_length = struct.unpack_from("<I", glb, 12)[0]
    gltf = json.loads(glb[20 : 20 + json_length])
    bin_length = struct.unpack_from("<I", glb, 20 + json_length)[0]
    return gltf, glb[28 + json_length : 28 + json_length + bin_length]


def spot_gltf(external: bool) -> dict[str, bytes]:
    """Spot as a .gltf: with ``external``, the buffer as spot.bin and the image as
    textures/spot%20skin.png beside it (as exporters write them); else both as data: URIs."""
    gltf, binary = split_glb(SPOT_GLB.read_bytes())
    image_view = gltf["bufferViews"][gltf["images"][0]["bufferView"]]
    start = image_view.get("byteOffset", 0)
    image = binary[start : start + image_view["byteLength"]]
    if external:
        gltf["buffers"][0]["uri"] = "spot.bin"
        gltf["images"][0] = {"uri": "textures/spot%20skin.png"}
        files = {"spot.bin": binary, "textures/spot skin.png": image}
    else:
        gltf["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(
            binary
        ).decode()
        files = {}
    return {"spot.gltf": json.dumps(gltf).encode(), **files, "_image": image}


@pytest.fixture(scope="module")
def spot() -> qem_core.Mesh:
    return qem_core.load_mesh(SPOT_GLB)


def _same_mesh(mesh: qem_core.Mesh, spot: qem_core.Mesh) -> None:
    assert mesh.n_vertices == spot.n_vertices and mesh.n_faces == spot.n_faces
    np.testing.assert_array_equal(mesh.vertices, spot.vertices)
    np.testing.assert_array_equal(mesh.corner_uvs, spot.corner_uvs)


def test_a_gltf_with_its_bin_and_image_beside_it(tmp_path, spot):
    files = spot_gltf(external=True)
    image = files.pop("_image")
    for name, data in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_bytes(data)
    mesh = qem_core.load_mesh(tmp_path / "spot.gltf")
    _same_mesh(mesh, spot)
    assert mesh.texture == image


def test_a_gltf_in_a_zip_with_its_files(spot):
    files = spot_gltf(external=True)
    image = files.pop("_image")
    mesh = qem_core.load_mesh(write_archive({f"model/{n}": d for n, d in files.items()}))
    _same_mesh(mesh, spot)
    assert mesh.texture == image


def test_a_gltf_of_data_uris_needs_nothing_beside_it(spot):
    files = spot_gltf(external=False)
    mesh = qem_core.load_mesh(files["spot.gltf"], format="gltf")
    _same_mesh(mesh, spot)


def test_a_gltf_whose_bin_is_missing_says_which_file(tmp_path):
    files = spot_gltf(external=True)
    (tmp_path / "spot.gltf").write_bytes(files["spot.gltf"])
    with pytest.raises(qem_core.MeshFormatError, match="'spot.bin', which is not there"):
        qem_core.load_mesh(tmp_path / "spot.gltf")
    with pytest.raises(qem_core.MeshFormatError, match="not there: send the .gltf with its"):
        qem_core.load_mesh(files["spot.gltf"], format="gltf")  # bytes: nothing beside


@pytest.mark.parametrize("text", [b"[1, 2]", b"{not json", b'{"asset": 1, "buffers": 5}'])
def test_a_gltf_that_is_no_gltf_is_refused(text):
    with pytest.raises(qem_core.MeshFormatError, match="glTF"):
        qem_core.load_mesh(text, format="gltf")


def test_node_transforms_place_each_instance_of_a_mesh():
    """A mesh used by two nodes comes twice, each where its node's world transform (a
    parent's matrix times the child's translation, rotation and scale) puts it; normals
    turn with it."""
    from tests.unit.test_fuzz_findings import POSITIONS, _glb

    normals = np.array([[0, 0, 1]] * 3, "<f4").tobytes()
    binary = POSITIONS + normals
    quarter = [0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)]  # 90 degrees about z
    gltf = {
        "asset": {"version": "2.0"}, "buffers": [{"byteLength": len(binary)}],
        "bufferViews": [{"buffer": 0, "byteLength": 36},
                        {"buffer": 0, "byteOffset": 36, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"},
                      {"bufferView": 1, "componentType": 5126, "count": 3, "type": "VEC3"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0, "NORMAL": 1}}]}],
        "scene": 0, "scenes": [{"nodes": [0, 2]}],
        "nodes": [
            {"matrix": [2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 2, 0, 10, 0, 0, 1], "children": [1]},
            {"mesh": 0, "rotation": quarter},
            {"mesh": 0, "translation": [0, 0, 5]},
        ],
    }  # fmt: skip
    mesh = qem_core.load_mesh(_glb(gltf, binary), format="glb")
    assert mesh.n_vertices == 6 and mesh.n_faces == 2
    # First instance: rotated a quarter turn, then scaled by 2 and moved by 10 along x.
    np.testing.assert_allclose(mesh.vertices[:3], [[10, 0, 0], [10, 2, 0], [8, 0, 0]],
                               atol=1e-12)  # fmt: skip
    np.testing.assert_allclose(mesh.vertices[3:], [[0, 0, 5], [1, 0, 5], [0, 1, 5]])
    np.testing.assert_allclose(mesh.vertex_attributes["normal"], [[0, 0, 1]] * 6, atol=1e-6)


def test_a_node_cycle_is_refused():
    from tests.unit.test_fuzz_findings import POSITIONS, _glb

    gltf = {
        "asset": {"version": "2.0"}, "buffers": [{"byteLength": 36}],
        "bufferViews": [{"buffer": 0, "byteLength": 36}],
        "accessors": [{"bufferView": 0, "componentType": 5126, "count": 3, "type": "VEC3"}],
        "meshes": [{"primitives": [{"attributes": {"POSITION": 0}}]}],
        "scenes": [{"nodes": [0]}], "nodes": [{"mesh": 0, "children": [1]}, {"children": [0]}],
    }  # fmt: skip
    with pytest.raises(qem_core.MeshFormatError, match="nest deeper|cycle|more vertices"):
        qem_core.load_mesh(_glb(gltf, POSITIONS), format="glb")


# -- compressed GLBs: Draco (gltf-transform draco) and meshopt (gltfpack -cc) ----------------


def _arrays(gltf: dict, binary: bytes) -> dict[str, np.ndarray]:
    """POSITION, TEXCOORD_0 and the indices of the one primitive of a GLB we wrote."""
    primitive = gltf["meshes"][0]["primitives"][0]
    kinds = {5126: "<f4", 5125: "<u4", 5123: "<u2"}
    widths = {"SCALAR": 1, "VEC2": 2, "VEC3": 3}
    out = {}
    for name, index in (*primitive["attributes"].items(), ("indices", primitive["indices"])):
        accessor = gltf["accessors"][index]
        view = gltf["bufferViews"][accessor["bufferView"]]
        start = view.get("byteOffset", 0) + accessor.get("byteOffset", 0)
        count, width = accessor["count"], widths[accessor["type"]]
        dtype = np.dtype(kinds[accessor["componentType"]])
        out[name] = np.frombuffer(binary, dtype, count * width, start).reshape(count, width)
    return out


def _with_views(gltf: dict, chunks: list[bytes]) -> tuple[dict, bytes]:
    """``gltf`` with one new bufferView per chunk, appended to a new binary chunk."""
    binary = b""
    gltf["bufferViews"] = []
    for chunk in chunks:
        gltf["bufferViews"].append({"buffer": 0, "byteOffset": len(binary),
                                    "byteLength": len(chunk)})  # fmt: skip
        binary += chunk + b"\0" * (-len(chunk) % 4)
    gltf["buffers"] = [{"byteLength": len(binary)}]
    return gltf, binary


def _plain_spot() -> tuple[dict, dict[str, np.ndarray]]:
    """Spot's GLB without its image (the texture is no part of what is compressed)."""
    gltf, binary = split_glb(SPOT_GLB.read_bytes())
    arrays = _arrays(gltf, binary)
    for key in ("images", "textures", "materials", "samplers"):
        gltf.pop(key, None)
    gltf["meshes"][0]["primitives"][0].pop("material", None)
    # Another tool's file: no record of qem-lod's seam split (its bufferView is gone);
    # the reader welds the seams by position as for any exporter's file.
    gltf["meshes"][0]["primitives"][0].pop("extras", None)
    gltf["asset"]["generator"] = "a compressor"
    return gltf, arrays


def draco_spot() -> bytes:
    from tests.unit.test_fuzz_findings import _glb

    DracoPy = pytest.importorskip("DracoPy")
    gltf, arrays = _plain_spot()
    encoded = DracoPy.encode(arrays["POSITION"], arrays["indices"], quantization_bits=16,
                             tex_coord=arrays["TEXCOORD_0"].astype(np.float64))  # fmt: skip
    ids = {a["attribute_type"]: a["unique_id"] for a in DracoPy.decode(encoded).attributes}
    gltf, binary = _with_views(gltf, [encoded])
    primitive = gltf["meshes"][0]["primitives"][0]
    for name in ("POSITION", "TEXCOORD_0"):
        gltf["accessors"][primitive["attributes"][name]].pop("bufferView")
    gltf["accessors"][primitive["indices"]].pop("bufferView")
    primitive["extensions"] = {"KHR_draco_mesh_compression": {
        "bufferView": 0, "attributes": {"POSITION": ids[0], "TEXCOORD_0": ids[3]}}}  # fmt: skip
    gltf["extensionsUsed"] = gltf["extensionsRequired"] = ["KHR_draco_mesh_compression"]
    return _glb(gltf, binary)


def meshopt_spot() -> bytes:
    from tests.unit.test_fuzz_findings import _glb

    meshoptimizer = pytest.importorskip("meshoptimizer")
    gltf, arrays = _plain_spot()
    primitive = gltf["meshes"][0]["primitives"][0]
    order = [("POSITION", primitive["attributes"]["POSITION"]),
             ("TEXCOORD_0", primitive["attributes"]["TEXCOORD_0"]),
             ("indices", primitive["indices"])]  # fmt: skip
    chunks, fallback = [], 0
    for name, _ in order:
        values = np.ascontiguousarray(arrays[name])
        if name == "indices":
            indices = values.reshape(-1).astype(np.uint32)
            chunks.append(meshoptimizer.encode_index_buffer(indices, len(indices),
                                                            len(arrays["POSITION"])))  # fmt: skip
        else:
            chunks.append(meshoptimizer.encode_vertex_buffer(values))
    gltf["accessors"][primitive["indices"]]["componentType"] = 5125  # encoded as uint32
    gltf, binary = _with_views(gltf, chunks)
    for view, (name, accessor) in zip(gltf["bufferViews"], order, strict=True):
        count = gltf["accessors"][accessor]["count"]
        stride = 4 if name == "indices" else arrays[name].shape[1] * 4
        view["extensions"] = {"EXT_meshopt_compression": {
            "buffer": 0, "byteOffset": view["byteOffset"], "byteLength": view["byteLength"],
            "byteStride": stride, "count": count,
            "mode": "TRIANGLES" if name == "indices" else "ATTRIBUTES"}}  # fmt: skip
        view.update(buffer=1, byteOffset=fallback, byteLength=count * stride)
        if name != "indices":
            view["byteStride"] = stride
        fallback += count * stride
        gltf["accessors"][accessor]["bufferView"] = gltf["bufferViews"].index(view)
    fallback_buffer = {"EXT_meshopt_compression": {"fallback": True}}
    gltf["buffers"].append({"byteLength": fallback, "extensions": fallback_buffer})
    gltf["extensionsUsed"] = gltf["extensionsRequired"] = ["EXT_meshopt_compression"]
    return _glb(gltf, binary)


def test_a_draco_glb_reads_as_the_plain_one_within_its_quantisation_step(spot):
    mesh = qem_core.load_mesh(draco_spot(), format="glb")
    assert mesh.n_vertices == spot.n_vertices and mesh.n_faces == spot.n_faces
    step = (spot.vertices.max(0) - spot.vertices.min(0)) / (2**16 - 1)
    order = np.lexsort(spot.vertices.T)
    near = np.abs(np.sort(mesh.vertices, axis=0) - np.sort(spot.vertices, axis=0))
    assert (near <= step + 1e-7).all(), near.max(0)
    assert np.unique(mesh.faces).size == spot.n_vertices and order.size == spot.n_vertices


def _rotated_to_lowest(faces: np.ndarray, corner_uvs: np.ndarray):
    """Each triangle (and its corners' UVs) rotated to start at its lowest vertex."""
    shift = np.argmin(faces, axis=1)
    turn = (shift[:, None] + np.arange(3)) % 3
    rows = np.arange(len(faces))[:, None]
    return faces[rows, turn], corner_uvs[rows, turn]


def test_a_meshopt_glb_reads_as_the_plain_one(spot):
    mesh = qem_core.load_mesh(meshopt_spot(), format="glb")
    # The codecs are lossless; the index codec may rotate a triangle's corners.
    np.testing.assert_array_equal(mesh.vertices, spot.vertices)
    faces, uvs = _rotated_to_lowest(mesh.faces, mesh.corner_uvs)
    expected_faces, expected_uvs = _rotated_to_lowest(spot.faces, spot.corner_uvs)
    np.testing.assert_array_equal(faces, expected_faces)
    np.testing.assert_array_equal(uvs, expected_uvs)


def test_meshopt_indices_read_at_another_size_than_decoded_are_refused():
    glb = meshopt_spot()
    gltf, binary = split_glb(glb)
    gltf["accessors"][gltf["meshes"][0]["primitives"][0]["indices"]]["componentType"] = 5123
    from tests.unit.test_fuzz_findings import _glb

    with pytest.raises(qem_core.MeshFormatError, match="decoded as 4-byte indices"):
        qem_core.load_mesh(_glb(gltf, binary), format="glb")


def test_a_draco_primitive_that_holds_no_draco_is_refused():
    from tests.unit.test_fuzz_findings import _glb

    gltf, binary = split_glb(draco_spot())
    gltf["bufferViews"][0]["byteLength"] = 16  # the first bytes of the Draco data only
    with pytest.raises(qem_core.MeshFormatError, match="KHR_draco_mesh_compression .* does not"):
        qem_core.load_mesh(_glb(gltf, binary), format="glb")


def test_a_texture_transform_moves_the_uvs_as_the_extension_says(spot):
    """KHR_texture_transform on the base colour: offset, a quarter turn, scale (glTF's
    UV space, origin top-left); the mesh's UVs (origin bottom-left) follow."""
    from tests.unit.test_fuzz_findings import _glb

    gltf, binary = split_glb(SPOT_GLB.read_bytes())
    info = gltf["materials"][0]["pbrMetallicRoughness"]["baseColorTexture"]
    info["extensions"] = {"KHR_texture_transform": {
        "offset": [0.5, 0.25], "rotation": np.pi / 2, "scale": [2.0, 3.0]}}  # fmt: skip
    gltf["extensionsUsed"] = gltf["extensionsRequired"] = ["KHR_texture_transform"]
    mesh = qem_core.load_mesh(_glb(gltf, binary), format="glb")
    u, v = spot.corner_uvs[..., 0].astype(np.float64), 1.0 - spot.corner_uvs[..., 1]
    su, sv = 2.0 * u, 3.0 * v  # scale, then a quarter turn: (x, y) -> (y, -x), then offset
    expected = np.stack([sv + 0.5, 1.0 - (-su + 0.25)], axis=-1)
    np.testing.assert_allclose(mesh.corner_uvs, expected, atol=1e-6)

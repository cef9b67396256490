"""Meshes of several materials: read from glTF scenes and OBJ + MTL, kept apart through
the build (a material border is a seam: no wedge, so no face, mixes two), in the .qpm,
the levels, the split stream and the msgpack form, and written back with every material
and its image (GLB: a primitive each; OBJ: a ``usemtl`` run each, the .mtl, the images).

The two-texture scene is written by trimesh, not by qem-lod, so the reader is tested
against another writer: spot cut in two halves, the second with its image inverted.
"""

import functools
import io
import json
import struct
import zlib

import msgpack
import numpy as np
import pytest

import qem_core
from qem_core.codecs import obj_companions, write_mesh
from qem_core.errors import CorruptFileError, MeshFormatError
from qem_core.levels import encode_level
from qem_core.stream import (
    SplitStreamDecoder,
    encode_split_frames,
    grid_for,
    iter_frames,
    quantised_wedges,
)
from tests.unit.conftest import SPOT
from tests.unit.test_codec_attributes import _glb_json, _with_glb_json

PIL = pytest.importorskip("PIL", reason="Pillow makes the second texture")
trimesh = pytest.importorskip("trimesh", reason="trimesh writes the scene")
from PIL import Image, ImageOps  # noqa: E402

SPOT_GLB = SPOT.with_suffix(".glb")


def _png(image) -> bytes:
    out = io.BytesIO()
    image.save(out, format="PNG")
    return out.getvalue()


@functools.cache
def two_texture_scene_glb() -> bytes:
    """Spot's two halves (by x) as two meshes of a scene, each with its own image (the
    second inverted), as trimesh writes it."""
    spot = qem_core.load_mesh(SPOT_GLB)
    image = Image.open(io.BytesIO(spot.texture)).convert("RGB")
    images = [image, ImageOps.invert(image)]
    left = spot.vertices[spot.faces].mean(axis=1)[:, 0] < 0
    scene = trimesh.Scene()
    for k, chosen in enumerate([left, ~left]):
        corners = spot.vertices[spot.faces[chosen]].reshape(-1, 3)
        half = trimesh.Trimesh(
            corners, np.arange(len(corners)).reshape(-1, 3), process=False,
            visual=trimesh.visual.TextureVisuals(uv=spot.corner_uvs[chosen].reshape(-1, 2),
                                                 image=images[k]),
        )  # fmt: skip
        scene.add_geometry(half, geom_name=f"half{k}")
    return scene.export(file_type="glb")


@pytest.fixture(scope="module")
def scene_glb() -> bytes:
    return two_texture_scene_glb()


@pytest.fixture(scope="module")
def scene(scene_glb):
    return qem_core.load_mesh(scene_glb, format="glb")


@pytest.fixture(scope="module")
def scene_pm(scene):
    return qem_core.build_mesh(scene)


def _corner_materials(pm, n):
    """The material value of every face corner of lod(n), unweighted: (F, 3)."""
    face_wedges, values = pm.wedge_level(n)
    layout = pm.attribute_layout
    column = layout.offset("material")
    return values[face_wedges][:, :, column] / np.float32(layout.scales[column])


def test_a_scene_of_two_textures_reads_as_one_mesh_of_two_materials(scene):
    spot = qem_core.load_mesh(SPOT_GLB)
    assert scene.n_faces == spot.n_faces
    assert scene.n_vertices == spot.n_vertices  # the halves welded where they meet
    assert scene.texture is None and len(scene.materials) == 2
    first, second = (m.texture for m in scene.materials)
    assert first and second and first != second
    assert Image.open(io.BytesIO(second)).size == Image.open(io.BytesIO(first)).size
    assert np.bincount(scene.face_materials).tolist() == [
        int((spot.vertices[spot.faces].mean(axis=1)[:, 0] < 0).sum()),
        int((spot.vertices[spot.faces].mean(axis=1)[:, 0] >= 0).sum()),
    ]


def test_no_level_has_a_face_whose_corners_mix_materials(scene, scene_pm):
    assert scene_pm.attribute_layout.names[-1] == "material"
    for n in np.linspace(scene_pm.n_base, scene_pm.n_full, 9).astype(int):
        corners = _corner_materials(scene_pm, int(n))
        assert np.all(corners == corners[:, :1]), n
        assert np.all(np.abs(corners - np.rint(corners)) < 1e-3)
        level = scene_pm.lod_mesh(int(n))
        assert np.array_equal(level.face_materials, np.rint(corners[:, 0]))
        assert level.materials is scene_pm.materials and level.texture is None
    full = scene_pm.lod_mesh(scene_pm.n_full)
    assert np.array_equal(np.bincount(full.face_materials), np.bincount(scene.face_materials))


def test_materials_survive_the_qpm(scene_pm, tmp_path):
    scene_pm.save(tmp_path / "scene.qpm")
    blob = (tmp_path / "scene.qpm").read_bytes()
    assert struct.unpack_from("<I", blob, 8)[0] == 3  # version 3: materials
    loaded = qem_core.load(tmp_path / "scene.qpm")
    assert [(m.name, m.texture, m.color) for m in loaded.materials] == [
        (m.name, m.texture, m.color) for m in scene_pm.materials
    ]
    n = (scene_pm.n_base + scene_pm.n_full) // 2
    assert np.array_equal(loaded.lod_mesh(n).face_materials, scene_pm.lod_mesh(n).face_materials)


def _rewritten(path, tmp_path, change):
    """The .qpm at ``path`` with its metadata's material list changed by ``change``:
    the header packed again, the arrays after it, a fresh CRC (a lie that is CRC-valid)."""
    raw = path.read_bytes()
    header_length = struct.unpack_from("<I", raw, 12)[0]
    header = msgpack.unpackb(raw[16 : 16 + header_length])
    change(header["metadata"]["materials"])
    packed = msgpack.packb(header)
    body = raw[:12] + struct.pack("<I", len(packed)) + packed + raw[16 + header_length : -4]
    out = tmp_path / "lying.qpm"
    out.write_bytes(body + struct.pack("<I", zlib.crc32(body)))
    return out


def test_a_qpm_whose_material_list_lies_is_refused(scene_pm, tmp_path):
    path = tmp_path / "good.qpm"
    scene_pm.save(path)
    qem_core.load(_rewritten(path, tmp_path, lambda entries: None))  # repacked, still good

    def image_outside(entries):
        entries[1]["image"][1] += 10**6

    def bad_colour(entries):
        entries[0]["color"] = [2.0, 0.0, 0.0, 1.0]

    with pytest.raises(CorruptFileError, match="outside the material images"):
        qem_core.load(_rewritten(path, tmp_path, image_outside))
    with pytest.raises(CorruptFileError, match="colour"):
        qem_core.load(_rewritten(path, tmp_path, bad_colour))
    # One material left: the wedges' values name the second, which is gone.
    with pytest.raises(CorruptFileError, match="must list 2 to 256 materials"):
        qem_core.load(_rewritten(path, tmp_path, lambda entries: entries.pop()))


def test_glb_writes_a_textured_primitive_per_material(scene_pm):
    level = scene_pm.lod_mesh(700)
    blob = write_mesh(level, "glb")
    gltf = _glb_json(blob)
    primitives = gltf["meshes"][0]["primitives"]
    assert len(primitives) == 2 and len(gltf["materials"]) == 2 and len(gltf["images"]) == 2
    textures = [m["pbrMetallicRoughness"]["baseColorTexture"]["index"] for m in gltf["materials"]]
    assert sorted(gltf["textures"][t]["source"] for t in textures) == [0, 1]
    assert len({json.dumps(p["attributes"]) for p in primitives}) == 1  # shared vertices
    back = qem_core.load_mesh(blob, format="glb")
    assert back.n_vertices == level.n_vertices and back.n_faces == level.n_faces
    assert np.array_equal(np.bincount(back.face_materials), np.bincount(level.face_materials))
    assert [m.texture for m in back.materials] == [m.texture for m in level.materials]


def test_obj_writes_a_usemtl_run_per_material_and_reads_back(scene_pm, tmp_path):
    level = scene_pm.lod_mesh(700)
    text = qem_core.encode_mesh(
        level.vertices, level.faces, "obj", level.vertex_attributes, None, level.corner_uvs,
        material_library="half", materials=level.materials, face_materials=level.face_materials,
    )  # fmt: skip
    (tmp_path / "half.obj").write_bytes(text)
    companions = obj_companions("half", None, level.materials)
    assert sorted(companions) == ["half.mtl", "half_texture0.png", "half_texture1.png"]
    for name, data in companions.items():
        (tmp_path / name).write_bytes(data)
    assert text.count(b"usemtl ") == 2
    back = qem_core.load_mesh(tmp_path / "half.obj")
    assert back.n_vertices == level.n_vertices and back.n_faces == level.n_faces
    assert np.array_equal(np.bincount(back.face_materials), np.bincount(level.face_materials))
    assert [m.texture for m in back.materials] == [m.texture for m in level.materials]


def test_simplify_cli_writes_the_obj_with_its_mtl_and_both_images(scene_glb, tmp_path):
    from client.cli import main

    (tmp_path / "scene.glb").write_bytes(scene_glb)
    assert main(["simplify", str(tmp_path / "scene.glb"), "-n", "600",
                 "-o", str(tmp_path / "out.obj")]) == 0  # fmt: skip
    assert sorted(p.name for p in tmp_path.iterdir()) == [
        "out.mtl", "out.obj", "out_texture0.png", "out_texture1.png", "scene.glb"]
    back = qem_core.load_mesh(tmp_path / "out.obj")
    assert back.n_vertices == 600 and len(back.materials) == 2


def test_the_split_stream_carries_each_new_face_s_material(scene_pm):
    n1, n2 = scene_pm.n_base + 5, scene_pm.n_full
    vertices, faces = scene_pm.lod(n1)
    decoder = SplitStreamDecoder(grid_for(scene_pm).quantise(vertices), faces,
                                 quantised_wedges(scene_pm, n1))  # fmt: skip
    for payload in iter_frames(encode_split_frames(scene_pm, n1, n2, key_frames=True)):
        decoder.feed(payload)
    expected = quantised_wedges(scene_pm, n2)
    assert np.array_equal(decoder.face_wedges, expected.face_wedges)
    assert np.array_equal(decoder.quantised_values, expected.values)
    scales = scene_pm.attribute_layout.scales
    decoded = scene_pm.as_mesh(*scene_pm.lod(n2), decoder.face_wedges,
                               (decoder.wedge_values * scales).astype(np.float32))  # fmt: skip
    assert np.array_equal(decoded.face_materials, scene_pm.lod_mesh(n2).face_materials)


def test_the_msgpack_level_lists_the_materials(scene_pm):
    level = encode_level(scene_pm, 800, "msgpack")
    message = msgpack.unpackb(level.content)
    assert [m["texture"] for m in message["materials"]] == [m.texture for m in scene_pm.materials]
    assert {m["texture_type"] for m in message["materials"]} == {"image/png"}
    back = qem_core.load_mesh(level.content, format="msgpack")
    assert np.array_equal(back.face_materials, scene_pm.lod_mesh(800).face_materials)
    message["face_materials"] = b"\x07" * len(message["face_materials"])
    with pytest.raises(MeshFormatError, match="beyond the 2"):
        qem_core.load_mesh(msgpack.packb(message), format="msgpack")


def test_obj_with_two_images_reads_two_materials(tmp_path):
    spot = qem_core.load_mesh(SPOT)
    image = Image.open(io.BytesIO(qem_core.load_mesh(SPOT_GLB).texture)).convert("RGB")
    (tmp_path / "a.png").write_bytes(_png(image))
    (tmp_path / "b.png").write_bytes(_png(ImageOps.invert(image)))
    (tmp_path / "two.mtl").write_text(
        "newmtl a\nKd 1 1 1\nmap_Kd a.png\nnewmtl b\nKd 0.5 0.5 0.5\nmap_Kd b.png\n")
    half = spot.n_faces // 2
    body = qem_core.encode_mesh(spot.vertices, spot.faces[:half], "obj",
                                corner_uvs=spot.corner_uvs[:half]).decode()
    rest = qem_core.encode_mesh(spot.vertices, spot.faces[half:], "obj",
                                corner_uvs=spot.corner_uvs[half:]).decode()
    # Two runs over one vertex table: the second's vt lines follow the first's.
    first_vt = body.count("\nvt ")
    rest_faces = []
    for line in rest.splitlines():
        if line.startswith("f "):
            corners = [c.split("/") for c in line[2:].split()]
            rest_faces.append("f " + " ".join(f"{v}/{int(t) + first_vt}" for v, t in corners))
    rest_vt = [line for line in rest.splitlines() if line.startswith("vt ")]
    head, faces_a = body.split("\nf ", 1)
    text = ("mtllib two.mtl\n" + head + "\n" + "\n".join(rest_vt) + "\nusemtl a\nf " + faces_a
            + "usemtl b\n" + "\n".join(rest_faces) + "\n")  # fmt: skip
    (tmp_path / "two.obj").write_text(text)
    mesh = qem_core.load_mesh(tmp_path / "two.obj")
    assert mesh.n_faces == spot.n_faces and len(mesh.materials) == 2
    assert np.bincount(mesh.face_materials).tolist() == [half, spot.n_faces - half]
    assert mesh.materials[1].color == (0.5, 0.5, 0.5, 1.0)
    assert mesh.materials[0].texture == (tmp_path / "a.png").read_bytes()


def test_glb_materials_of_two_colours_are_kept_as_two(scene_glb):
    gltf = _glb_json(scene_glb)
    for material in gltf["materials"]:
        material["pbrMetallicRoughness"].pop("baseColorTexture", None)
    gltf["materials"][1]["pbrMetallicRoughness"]["baseColorFactor"] = [1, 0, 0, 1]
    mesh = qem_core.load_mesh(_with_glb_json(scene_glb, gltf), format="glb")
    assert [m.texture for m in mesh.materials] == [None, None]
    assert mesh.materials[1].color == (1.0, 0.0, 0.0, 1.0)
    level = qem_core.build_mesh(mesh).lod_mesh(300)
    gltf_out = _glb_json(write_mesh(level, "glb"))
    factors = [m["pbrMetallicRoughness"].get("baseColorFactor") for m in gltf_out["materials"]]
    assert [1.0, 0.0, 0.0, 1.0] in factors and "images" not in gltf_out


def test_glb_base_colour_factor_that_is_no_colour_is_refused(scene_glb):
    gltf = _glb_json(scene_glb)
    gltf["materials"][0]["pbrMetallicRoughness"]["baseColorFactor"] = ["red", 0, 0, 1]
    with pytest.raises(MeshFormatError, match="baseColorFactor"):
        qem_core.load_mesh(_with_glb_json(scene_glb, gltf), format="glb")


def test_texture_image_names_each_material_s_image(scene_pm):
    first, second = scene_pm.materials
    assert scene_pm.texture_image(0) == (first.texture, "image/png")
    assert scene_pm.texture_image(1) == (second.texture, "image/png")
    with pytest.raises(LookupError, match=r"2 materials; name one .*\[0, 1\]"):
        scene_pm.texture_image()
    with pytest.raises(LookupError, match="not a material 2"):
        scene_pm.texture_image(2)
    one = qem_core.build_mesh(qem_core.load_mesh(SPOT_GLB))
    assert one.texture_image() == (one.texture, "image/png")
    with pytest.raises(LookupError, match="one material"):
        one.texture_image(0)

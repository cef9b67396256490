"""OBJ materials: an .mtl beside the model gives the texture (map_Kd) or, without an
image, the diffuse colours (Kd); a textured OBJ is written with its .mtl and image."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import qem_core
from qem_core import codecs
from qem_core.codecs.mtl import read_mtl
from tests.tiny_meshes import OCTAHEDRON
from tests.unit.conftest import SPOT


@pytest.fixture(scope="module")
def spot_image() -> bytes:
    """Spot's texture (public domain), as the repository's demo GLB carries it."""
    return qem_core.load_mesh(SPOT.with_suffix(".glb")).texture


def _textured_spot(folder: Path, image: bytes, mtl: str, preamble: str) -> Path:
    (folder / "spot_texture.png").write_bytes(image)
    (folder / "spot.mtl").write_text(mtl)
    path = folder / "spot.obj"
    path.write_bytes(preamble.encode() + SPOT.read_bytes())
    return path


def test_an_obj_with_its_mtl_and_image_loads_textured(tmp_path, spot_image):
    path = _textured_spot(tmp_path, spot_image, "newmtl skin\nKd 1 1 1\nmap_Kd spot_texture.png\n",
                          "mtllib spot.mtl\nusemtl skin\n")  # fmt: skip
    mesh = qem_core.load_mesh(path)
    assert mesh.texture == spot_image
    assert mesh.corner_uvs is not None and mesh.n_vertices == 2930
    # As bytes nothing beside it can be read: the UVs stay, the image cannot come.
    assert qem_core.load_mesh(path.read_bytes(), format="obj").texture is None


def test_map_options_before_the_file_name_are_skipped():
    materials = read_mtl(
        b"newmtl a\nmap_Kd -s 1 1 1 -o 0.5 -clamp on -bm 0.2 my texture.png\n"
        b"newmtl b\nmap_Kd -blendu off b.jpg\nnewmtl c\nKd 0.5 2 -1\n"
    )
    assert materials["a"].texture == "my texture.png"
    assert materials["b"].texture == "b.jpg"
    assert materials["c"].diffuse == (0.5, 1.0, 0.0)  # clamped into [0, 1]


@pytest.mark.parametrize("mtl", [b"Kd 1 1 1\n", b"newmtl a\nKd 1 x 1\n", b"newmtl a\nKd 1 1\n"])
def test_a_malformed_mtl_is_refused(mtl):
    with pytest.raises(qem_core.MeshFormatError, match="MTL line"):
        read_mtl(mtl)


def test_a_missing_library_or_image_leaves_the_mesh_untextured(tmp_path, spot_image):
    path = _textured_spot(tmp_path, spot_image, "newmtl skin\nmap_Kd elsewhere.png\n",
                          "mtllib spot.mtl\nmtllib absent.mtl\nusemtl skin\n")  # fmt: skip
    mesh = qem_core.load_mesh(path)
    assert mesh.texture is None and mesh.corner_uvs is not None


def test_faces_using_two_images_keep_their_uvs_but_no_texture(tmp_path, spot_image):
    lines = SPOT.read_text().splitlines(keepends=True)
    first_face = next(i for i, line in enumerate(lines) if line.startswith("f "))
    lines.insert(first_face + 100, "usemtl b\n")
    lines.insert(first_face, "mtllib two.mtl\nusemtl a\n")
    (tmp_path / "two.mtl").write_text("newmtl a\nmap_Kd a.png\nnewmtl b\nmap_Kd b.png\n")
    (tmp_path / "a.png").write_bytes(spot_image)
    (tmp_path / "b.png").write_bytes(spot_image)
    (tmp_path / "two.obj").write_text("".join(lines))
    mesh = qem_core.load_mesh(tmp_path / "two.obj")
    assert mesh.texture is None and mesh.corner_uvs is not None


def test_materials_of_different_colours_become_vertex_colours(tmp_path):
    vertices, faces = OCTAHEDRON
    text = "mtllib colours.mtl\n" + "".join(f"v {x} {y} {z}\n" for x, y, z in vertices)
    for i, (a, b, c) in enumerate(faces):
        text += f"usemtl {'red' if i < 4 else 'blue'}\nf {a + 1} {b + 1} {c + 1}\n"
    (tmp_path / "colours.mtl").write_text("newmtl red\nKd 1 0 0\nnewmtl blue\nKd 0 0 1\n")
    (tmp_path / "octahedron.obj").write_text(text)
    mesh = qem_core.load_mesh(tmp_path / "octahedron.obj")
    colour = mesh.vertex_attributes["color"]
    # Vertex 5 (the bottom) has blue faces only; vertex 4 (the top) red ones only.
    np.testing.assert_array_equal(colour[5], [0, 0, 1])
    np.testing.assert_array_equal(colour[4], [1, 0, 0])


def test_a_textured_level_written_as_obj_names_its_mtl_and_image(tmp_path, spot_image):
    mesh = qem_core.load_mesh(
        _textured_spot(tmp_path, spot_image, "newmtl skin\nmap_Kd spot_texture.png\n",
                       "mtllib spot.mtl\nusemtl skin\n")
    )  # fmt: skip
    out = tmp_path / "out"
    out.mkdir()
    text = qem_core.encode_mesh(
        mesh.vertices, mesh.faces, "obj", mesh.vertex_attributes, mesh.texture,
        mesh.corner_uvs, material_library="level",
    )  # fmt: skip
    assert text.startswith(b"# qem-lod\nmtllib level.mtl\nusemtl level\n")
    (out / "level.obj").write_bytes(text)
    companions = codecs.obj_companions("level", mesh.texture)
    assert sorted(companions) == ["level.mtl", "level_texture.png"]
    for name, data in companions.items():
        (out / name).write_bytes(data)
    again = qem_core.load_mesh(out / "level.obj")
    assert again.texture == spot_image
    np.testing.assert_array_equal(again.corner_uvs, mesh.corner_uvs)
    with pytest.raises(qem_core.InvalidOptionsError, match="'obj' only"):
        qem_core.encode_mesh(mesh.vertices, mesh.faces, "ply", material_library="level")

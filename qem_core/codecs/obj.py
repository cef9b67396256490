"""Wavefront OBJ: reader and writer.

Reads ``v x y z`` (a 6-number ``v x y z r g b`` on every line gives "color"), ``vt u v``,
``vn x y z`` and ``f`` lines with corners ``v``, ``v/vt``, ``v//vn`` or ``v/vt/vn``,
1-based or negative (relative to the lines read so far); polygons are triangulated
(`_polygons.py`).
Texture coordinates go to `Mesh.corner_uvs` (one per face corner, as OBJ stores them);
when every vertex has a single UV (no seams) they are also the "uv" vertex attribute,
and the same rule turns ``vn`` into the "normal" attribute.

Materials (``mtllib``, ``usemtl``), when the reader is given the files beside the model
(`companions.Companions`: `load_mesh` of a path, or of an archive): the faces' materials
are read from the .mtl files (`mtl.py`). When they use one image (``map_Kd``) and the
faces have UVs, it becomes `Mesh.texture`; without an image, materials of different
diffuse colours (``Kd``) become the "color" attribute (each vertex takes the colour of a
material of its faces). Faces using several images (with UVs) give a mesh of several
materials (`Mesh.materials`, `Mesh.face_materials`), one per look (image and ``Kd``)
used. Everything else (``o``, ``g``, ``s``, ``l``, ``p``, comments) is ignored.

Lines are found with one regular expression and their numbers parsed by numpy in bulk;
a Python loop touches each line once, to sort it by keyword.

Writes ``v`` (``v x y z r g b`` when colours are given: the common extension, alpha
dropped), ``vt`` and ``vn`` lines and ``f`` lines ``v``, ``v/vt``, ``v//vn`` or
``v/vt/vn``. UVs: with `corner_uvs`, one ``vt`` line per distinct (u, v) pair and each
corner names its own (seams are kept as written); else the "uv" attribute, one ``vt``
per vertex. Normals: one ``vn`` per vertex. Values are float32 written with 9
significant digits, so they read back exactly. A textured mesh written with a
``material_library`` name starts with ``mtllib <name>.mtl`` and ``usemtl <name>``; a
mesh of several materials has its faces in runs, a ``usemtl`` each. `obj_companions`
gives that .mtl file and the images, to write beside the OBJ.
"""

from __future__ import annotations

import re

import numpy as np

from ..errors import MeshFormatError
from ..mesh import MAX_MATERIALS, Mesh
from ..mesh import Material as Look
from ._corners import per_vertex
from ._images import IMAGE_SUFFIXES, image_media_type
from ._polygons import polygon_corners
from ._text import count_tokens, parse_lines, parse_numbers
from .archive import write_archive
from .companions import Companions
from .mtl import Material, read_mtl

__all__ = ["obj_companions", "read_obj", "write_obj", "write_obj_zip"]


_LINE = re.compile(rb"^[ \t]*(v|vt|vn|f|usemtl|mtllib)[ \t]+([^\r\n#]*)", re.MULTILINE)
_SPACE = np.zeros(256, dtype=bool)
_SPACE[list(b" \t\n\r\x0b\x0c")] = True
_SLASH = ord("/")


def read_obj(data: bytes, files: Companions | None = None) -> Mesh:
    """Decode an OBJ file into a Mesh, its materials read through ``files`` (see the
    module docstring; None: materials ignored). Raises MeshFormatError."""
    # A UTF-8 byte-order mark (editors on Windows write one) would hide the first line,
    # and with it the first vertex: every index after it would name the wrong vertex.
    data = data.removeprefix(b"\xef\xbb\xbf")
    data = data.replace(b"\\\r\n", b" ").replace(b"\\\n", b" ")  # line continuations
    matches = _LINE.findall(data)
    lines: dict[bytes, list[bytes]] = {b"v": [], b"vt": [], b"vn": [], b"f": [],
                                       b"mtllib": [], b"usemtl": []}  # fmt: skip
    material_starts: list[int] = []  # the 'f' line each usemtl applies from
    for keyword, body in matches:
        if keyword == b"usemtl":
            material_starts.append(len(lines[b"f"]))
        lines[keyword].append(body)
    if lines[b"usemtl"] or lines[b"mtllib"]:  # the counters below see geometry lines only
        matches = [match for match in matches if match[0] not in (b"usemtl", b"mtllib")]
    if not lines[b"v"] and not lines[b"f"]:
        raise MeshFormatError("not an OBJ file: no 'v' or 'f' lines")
    positions = _table(lines[b"v"], 3, "OBJ 'v' line")
    uv_table = _table(lines[b"vt"], 2, "OBJ 'vt' line")[:, :2]
    normal_table = _table(lines[b"vn"], 3, "OBJ 'vn' line")[:, :3]

    corner_counts = count_tokens(lines[b"f"])
    v_index, vt_index, vn_index = _corner_indices(b" ".join(lines[b"f"]), corner_counts)
    counters = _Counters(matches, corner_counts)
    v_index = counters.resolve(v_index, b"v", positions.shape[0])
    triangles = polygon_corners(corner_counts, "OBJ 'f' line", first_number=1)
    faces = v_index[triangles]

    attributes = {}
    if positions.shape[1] == 6:
        attributes["color"] = np.clip(positions[:, 3:6], 0.0, 1.0)
    corner_uvs = None
    if vt_index.size and np.all(vt_index != 0):
        vt_index = counters.resolve(vt_index, b"vt", uv_table.shape[0])
        corner_uvs = uv_table[vt_index[triangles]].astype(np.float32)
        uv = _per_vertex(v_index, vt_index, uv_table, positions.shape[0])
        if uv is not None:
            attributes["uv"] = uv
    if vn_index.size and np.all(vn_index != 0):
        vn_index = counters.resolve(vn_index, b"vn", normal_table.shape[0])
        normal = _per_vertex(v_index, vn_index, normal_table, positions.shape[0])
        if normal is not None:
            attributes["normal"] = normal
    texture = None
    if files is not None and lines[b"usemtl"]:
        polygon_start = np.cumsum(corner_counts) - corner_counts
        polygon = np.searchsorted(polygon_start, triangles[:, 0], side="right") - 1
        texture, colour, looks, face_looks = _material_look(
            lines[b"mtllib"], lines[b"usemtl"], material_starts, polygon, files
        )
        if texture is not None and corner_uvs is None:
            texture = None  # an image without UVs to place it
        if looks is not None and corner_uvs is not None:
            return Mesh(
                vertices=np.ascontiguousarray(positions[:, :3]), faces=faces,
                vertex_attributes={k: v.astype(np.float32) for k, v in attributes.items()},
                corner_uvs=corner_uvs, materials=looks, face_materials=face_looks,
            )  # fmt: skip
        if texture is None and colour is not None and "color" not in attributes:
            per_vertex_colour = np.zeros((positions.shape[0], 3))
            per_vertex_colour[faces.reshape(-1)] = np.repeat(colour, 3, axis=0)
            attributes["color"] = per_vertex_colour
    return Mesh(
        vertices=np.ascontiguousarray(positions[:, :3]),
        faces=faces,
        vertex_attributes={k: v.astype(np.float32) for k, v in attributes.items()},
        corner_uvs=corner_uvs,
        texture=texture,
    )


def _material_look(
    libraries: list[bytes],
    names: list[bytes],
    starts: list[int],
    polygon: np.ndarray,
    files: Companions,
) -> tuple[bytes | None, np.ndarray | None, list[Look] | None, np.ndarray | None]:
    """(texture, per-face colours, looks, per-face look) from the faces' materials: the
    image when the faces use exactly one, else None; with several images, each material
    used as a look (its image, its ``Kd``) and the number of each face's; the (faces, 3)
    diffuse colours when no image is used and the faces' materials have two colours or
    more, else None."""
    materials: dict[str, Material] = {}
    for library in libraries:
        name = library.decode("utf-8", "replace").strip()
        data = files.read(name)
        # "mtllib a.mtl b.mtl" names several files; a single name may hold spaces.
        for part in [name] if data is not None else name.split():
            data = data if part == name else files.read(part)
            if data is not None:
                materials.update(read_mtl(data))
    used = [materials.get(name.decode("utf-8", "replace").strip()) for name in names]
    # The material of each polygon: that of the last usemtl before its 'f' line.
    which = np.searchsorted(np.asarray(starts), polygon, side="right") - 1
    present = [used[i] for i in np.unique(which) if i >= 0]
    images = {m.texture for m in present if m is not None and m.texture}
    if len(images) == 1:  # one image: the texture (if it is there)
        return files.read(images.pop()), None, None, None
    if images:
        return (None, None, *_looks(used, which, files))
    palette = np.array(
        [m.diffuse if m is not None and m.diffuse is not None else (1.0, 1.0, 1.0) for m in used]
        or [(1.0, 1.0, 1.0)]
    )
    colours = np.where((which >= 0)[:, None], palette[np.maximum(which, 0)], 1.0)
    if len(np.unique(colours, axis=0)) < 2:
        return None, None, None, None
    return None, colours, None, None


def _looks(used: list[Material | None], which: np.ndarray,
           files: Companions) -> tuple[list[Look] | None, np.ndarray | None]:
    """The looks of the materials the faces use (each ``usemtl`` of the same material
    one look; a face before any ``usemtl``, or naming a material no .mtl defines, white)
    and each face's number among them; (None, None) when they are more than qem-lod
    keeps apart."""
    looks: dict[tuple, int] = {}
    listed: list[Look] = []
    number_of_use = np.zeros(len(used) + 1, np.int32)  # the last: no material
    for i, material in enumerate([*used, None]):
        if not np.any(which == (i if i < len(used) else -1)):
            continue
        texture = files.read(material.texture) if material and material.texture else None
        colour = material.diffuse if material and material.diffuse is not None else None
        colour = None if colour is None else (*(float(c) for c in colour), 1.0)
        key = (texture, colour)
        if key not in looks:
            looks[key] = len(listed)
            listed.append(Look(material.name if material else "default", texture, colour))
        number_of_use[i] = looks[key]
    if not 2 <= len(listed) <= MAX_MATERIALS:
        return None, None
    return listed, number_of_use[which]


def write_obj(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_attributes: dict[str, np.ndarray],
    texture: bytes | None = None,
    corner_uvs: np.ndarray | None = None,
    material_library: str | None = None,
    materials: list[Look] | None = None,
    face_materials: np.ndarray | None = None,
) -> bytes:
    """Encode as OBJ text: see the module docstring. The texture itself is not in it:
    OBJ names its image in a separate .mtl file (`obj_companions`). A mesh of several
    materials written with a ``material_library`` has its faces in runs, one ``usemtl``
    each (`material_names`)."""
    color = vertex_attributes.get("color")
    normal = vertex_attributes.get("normal")
    columns = [vertices]
    if color is not None:
        columns.append(color[:, :3])
    parts = [b"# qem-lod\n"]
    textured = texture is not None and (corner_uvs is not None or "uv" in vertex_attributes)
    several = material_library is not None and materials is not None and face_materials is not None
    if several:
        order = np.argsort(face_materials, kind="stable")
        faces, face_materials = faces[order], face_materials[order]
        corner_uvs = None if corner_uvs is None else corner_uvs[order]
        parts.append(f"mtllib {material_library}.mtl\n".encode())
    elif material_library is not None and textured:
        parts.append(f"mtllib {material_library}.mtl\nusemtl {material_library}\n".encode())
    parts.append(_format_rows("v", np.hstack(columns)))
    one_based = faces.astype(np.int64) + 1
    # One index per stored table: v, then vt and vn when present.
    slots = [one_based]
    if corner_uvs is not None:
        # Each distinct (u, v) once; a seam is corners of one position naming other vt.
        uv_bits = np.ascontiguousarray(corner_uvs, dtype=np.float32).reshape(-1, 2)
        table, uv_index = np.unique(uv_bits.view(np.uint64).reshape(-1), return_inverse=True)
        parts.append(_format_rows("vt", table.view(np.float32).reshape(-1, 2)))
        slots.append(uv_index.reshape(faces.shape) + 1)
    elif "uv" in vertex_attributes:
        parts.append(_format_rows("vt", vertex_attributes["uv"]))
        slots.append(one_based)
    if normal is not None:
        parts.append(_format_rows("vn", normal))
    corner_format = "%d"
    if len(slots) > 1:
        corner_format += "/%d"
    if normal is not None:
        corner_format += "/%d" if len(slots) > 1 else "//%d"
        slots.append(one_based)
    corners = np.stack(slots, axis=2)
    line = "f " + " ".join([corner_format] * 3) + "\n"
    if not several:
        parts.append(((line * faces.shape[0]) % tuple(corners.ravel().tolist())).encode("ascii"))
        return b"".join(parts)
    names = material_names(material_library, materials)
    used, starts = np.unique(face_materials, return_index=True)
    for k, start, end in zip(used, starts, [*starts[1:], len(faces)], strict=True):
        run = corners[start:end]
        parts.append(f"usemtl {names[int(k)]}\n".encode())
        parts.append(((line * run.shape[0]) % tuple(run.ravel().tolist())).encode("ascii"))
    return b"".join(parts)


def write_obj_zip(
    vertices: np.ndarray,
    faces: np.ndarray,
    vertex_attributes: dict[str, np.ndarray],
    texture: bytes | None = None,
    corner_uvs: np.ndarray | None = None,
    materials: list[Look] | None = None,
    face_materials: np.ndarray | None = None,
) -> bytes:
    """The OBJ in a zip archive with what it names: ``mesh.obj``, and for a textured mesh
    or one of several materials ``mesh.mtl`` and its images (``mesh_texture.png``, or
    .jpg, .webp); one download that keeps the look."""
    textured = texture is not None and (corner_uvs is not None or "uv" in vertex_attributes)
    library = "mesh" if textured or materials is not None else None
    files = {"mesh.obj": write_obj(vertices, faces, vertex_attributes, texture, corner_uvs,
                                   library, materials, face_materials)}  # fmt: skip
    if library is not None:
        files.update(obj_companions(library, texture, materials))
    return write_archive(files)


def material_names(material_library: str, materials: list[Look]) -> list[str]:
    """The ``newmtl`` name of each material: its own, made safe for an MTL line (one
    word) and unique, led by its number."""
    return [f"{material_library}_{k}_{re.sub(r'[^A-Za-z0-9_.-]', '_', look.name)[:40]}"
            for k, look in enumerate(materials)]  # fmt: skip


def obj_companions(material_library: str, texture: bytes | None,
                   materials: list[Look] | None = None) -> dict[str, bytes]:
    """The files an OBJ written with ``material_library`` names: ``<name>.mtl`` and the
    images its ``map_Kd`` lines name, by file name. One texture: one material named
    ``<name>``, its image ``<name>_texture.png`` (or .jpg, .webp). Several materials:
    one ``newmtl`` each (`material_names`), ``Kd`` its colour and ``d`` its opacity,
    its image ``<name>_texture<k>.png``."""
    if materials is None:
        materials, names, suffixes = [Look(material_library, texture)], [material_library], [""]
    else:
        names, suffixes = material_names(material_library, materials), range(len(materials))
    lines, files = [], {}
    for look, name, suffix in zip(materials, names, suffixes, strict=True):
        red, green, blue, alpha = look.color or (1.0, 1.0, 1.0, 1.0)
        lines.append(f"newmtl {name}\nKd {red:.6g} {green:.6g} {blue:.6g}\n")
        if alpha < 1.0:
            lines.append(f"d {alpha:.6g}\n")
        if look.texture is not None:
            kind = IMAGE_SUFFIXES.get(image_media_type(look.texture), ".png")
            image = f"{material_library}_texture{suffix}{kind}"
            lines.append(f"map_Kd {image}\n")
            files[image] = bytes(look.texture)
    return {f"{material_library}.mtl": "".join(lines).encode(), **files}


def _format_rows(keyword: str, values: np.ndarray) -> bytes:
    """Lines ``keyword a b c`` with float32 values, 9 significant digits (exact)."""
    values = values.astype(np.float32).astype(np.float64)
    line = keyword + " %.9g" * values.shape[1] + "\n"
    return ((line * values.shape[0]) % tuple(values.ravel().tolist())).encode("ascii")


def _table(lines: list[bytes], width: int, what: str) -> np.ndarray:
    """(n, w) numbers of lines with at least `width` numbers each: w is their common
    count when all lines have the same, else `width` (extra numbers dropped)."""
    numbers, counts = parse_lines(lines, f"{what}s")
    if not lines:
        return np.zeros((0, width), dtype=np.float64)
    if counts.min() < width:
        bad = int(np.flatnonzero(counts < width)[0])
        raise MeshFormatError(
            f"{what} {bad + 1} of its kind has {int(counts[bad])} numbers; it needs {width}"
        )
    if counts.min() == counts.max():
        return numbers.reshape(len(lines), int(counts[0]))
    first = np.cumsum(counts) - counts
    return numbers[first[:, None] + np.arange(width)]


def _corner_indices(text: bytes, corner_counts: np.ndarray) -> tuple[np.ndarray, ...]:
    """(v, vt, vn) indices of every face corner as written (0 where absent).

    `text` holds the corners (``7``, ``7/3``, ``7//2``, ``7/3/2``) separated by spaces.
    Writing ``//`` as ``/0/`` gives every corner one number more than its slashes; the
    slashes of each corner are counted with numpy on the bytes.
    """
    text = text.replace(b"//", b"/0/")
    chars = np.frombuffer(text, dtype=np.uint8)
    space = _SPACE[chars]
    starts = ~space
    starts[1:] &= space[:-1]
    n_corners = int(corner_counts.sum())
    if int(np.count_nonzero(starts)) != n_corners:
        raise MeshFormatError("OBJ 'f' lines hold characters that are not corners")
    corner_of_char = np.cumsum(starts) - 1
    slashes = np.bincount(corner_of_char[chars == _SLASH], minlength=n_corners)
    numbers = parse_numbers(text.replace(b"/", b" "), np.int64, "OBJ 'f' lines")
    per_corner = slashes + 1
    if n_corners and (slashes.max() > 2 or numbers.size != per_corner.sum()):
        raise MeshFormatError(
            "OBJ 'f' line has a malformed corner; corners are v, v/vt, v//vn or v/vt/vn"
        )
    first = np.cumsum(per_corner) - per_corner
    last = max(numbers.size - 1, 0)
    v_index = numbers[first] if n_corners else numbers
    vt_index = np.where(slashes >= 1, numbers[np.minimum(first + 1, last)], 0)
    vn_index = np.where(slashes == 2, numbers[np.minimum(first + 2, last)], 0)
    return v_index, vt_index, vn_index


class _Counters:
    """Turns OBJ indices (1-based, or negative: -1 is the last line of its kind read
    before the face) into 0-based indices, checking their range."""

    def __init__(self, matches: list[tuple[bytes, bytes]], corner_counts: np.ndarray):
        self._matches = matches
        self._corner_counts = corner_counts
        self._keywords: np.ndarray | None = None

    def resolve(self, index: np.ndarray, keyword: bytes, n_defined: int) -> np.ndarray:
        name = keyword.decode()
        if index.size and index.min() == 0:
            face = self._face_of_corner(int(np.flatnonzero(index == 0)[0]))
            raise MeshFormatError(
                f"OBJ 'f' line {face + 1} has {name} index 0; OBJ indices start at 1 "
                "(or count back from -1)"
            )
        resolved = index - 1
        negative = index < 0
        if negative.any():
            resolved[negative] = index[negative] + self._defined_before(keyword)[negative]
        bad = (resolved < 0) | (resolved >= n_defined)
        if bad.any():
            corner = int(np.flatnonzero(bad)[0])
            raise MeshFormatError(
                f"OBJ 'f' line {self._face_of_corner(corner) + 1} refers to {name} "
                f"{int(index[corner])}, but the file has {n_defined} '{name}' lines; "
                "fix the face or add the missing lines"
            )
        return resolved

    def _defined_before(self, keyword: bytes) -> np.ndarray:
        """For each corner, the number of `keyword` lines before its 'f' line."""
        if self._keywords is None:
            self._keywords = np.array([k for k, _ in self._matches])
        defined = np.cumsum(self._keywords == keyword)
        return np.repeat(defined[self._keywords == b"f"], self._corner_counts)

    def _face_of_corner(self, corner: int) -> int:
        return int(np.searchsorted(np.cumsum(self._corner_counts), corner, side="right"))


def _per_vertex(
    v_index: np.ndarray, value_index: np.ndarray, table: np.ndarray, n_vertices: int
) -> np.ndarray | None:
    """(n, k) values per vertex from per-corner indices into `table`, or None when a
    vertex carries different values at different corners (a seam).

    When every corner uses value i with vertex i (one vt or vn line per v line, as this
    module writes), the table is the answer, unreferenced vertices included; otherwise
    vertices no face uses get zeros.
    """
    if table.shape[0] == n_vertices and np.array_equal(v_index, value_index):
        return table
    return per_vertex(v_index, table[value_index], n_vertices)

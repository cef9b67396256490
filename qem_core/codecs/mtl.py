"""Wavefront MTL (an OBJ's material library): the parts that carry a mesh's look.

Per material (``newmtl``): its diffuse colour ``Kd r g b`` and its diffuse texture
``map_Kd [options] file``. Options before the file name (``-s 1 1 1``, ``-clamp on``,
``-bm 0.5``...) are skipped by their known argument counts; the rest of the line is the
name, spaces included. Other statements (``Ka``, ``Ks``, ``Ns``, ``illum``, other maps)
do not change what qem-lod keeps and are ignored.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from ..errors import MeshFormatError

__all__ = ["Material", "read_mtl"]

# Arguments of map_* options (most numeric options take up to three numbers).
_OPTION_ARGUMENTS = {
    "-blendu": 1, "-blendv": 1, "-boost": 1, "-cc": 1, "-clamp": 1, "-imfchan": 1,
    "-mm": 2, "-o": 3, "-s": 3, "-t": 3, "-texres": 1, "-bm": 1, "-type": 1,
}  # fmt: skip


@dataclass
class Material:
    name: str
    diffuse: tuple[float, float, float] | None = None  # Kd, each in [0, 1]
    texture: str | None = None  # map_Kd's file name, as written


def read_mtl(data: bytes) -> dict[str, Material]:
    """The materials of an MTL file by name. Raises MeshFormatError for a ``Kd`` that is
    not three finite numbers, or a statement before any ``newmtl``."""
    materials: dict[str, Material] = {}
    current: Material | None = None
    text = data.removeprefix(b"\xef\xbb\xbf").decode("utf-8", "replace")
    for number, raw in enumerate(text.splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        keyword, _, rest = line.partition(" ")
        keyword, rest = keyword.strip(), rest.strip()
        if keyword == "newmtl":
            current = materials.setdefault(rest, Material(rest))
        elif keyword in ("Kd", "map_Kd"):
            if current is None:
                raise MeshFormatError(f"MTL line {number}: {keyword} before any newmtl")
            if keyword == "Kd":
                current.diffuse = _colour(rest, number)
            else:
                current.texture = _map_file(rest) or None
    return materials


def _colour(text: str, number: int) -> tuple[float, float, float]:
    words = text.split()
    try:
        values = [float(word) for word in words[:3]]
    except ValueError:
        values = []
    # "Kd spectral file" and "Kd xyz x y z" are valid MTL but not colours qem-lod reads.
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise MeshFormatError(f"MTL line {number}: Kd needs three numbers, got {text!r}")
    return tuple(min(1.0, max(0.0, v)) for v in values)


def _map_file(text: str) -> str:
    """The file name of a map statement, its options skipped."""
    words = text.split()
    at = 0
    while at < len(words) and words[at] in _OPTION_ARGUMENTS:
        arity = _OPTION_ARGUMENTS[words[at]]
        at += 1
        # Numeric options take up to `arity` numbers; on/off and names take exactly one.
        taken = 0
        while at < len(words) - 1 and taken < arity:
            if taken and not _is_number(words[at]):
                break
            at += 1
            taken += 1
    return " ".join(words[at:])


def _is_number(word: str) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True

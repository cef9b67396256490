"""Bytes per vertex split of each split-stream field: deflated byte planes (stream v2)
against the range coder (stream v3), from the same symbol arrays.

    python -m bench.stream_entropy [--meshes spot.ply ...] [--qpm-dir DIR] [--bits 16]

For each mesh (built with default options, or loaded from DIR/<mesh>.qpm when given),
``qem_core.stream.split_frame_symbols`` gives each frame's arrays; each field is then

- deflated as v2 stored it (uint32 / uint16 byte planes, zigzag positions; zlib level 9
  on the field alone), and
- range-coded alone (``range_code_fields`` with that field's flag: every field has its
  own contexts, so its bytes do not depend on the others; each frame's 4 flush bytes
  are counted in every field, so the fields add up to a little more than the frames).

A mesh with attributes adds its wedge fields (``WEDGE_FIELDS``), each range-coded alone
by ``range_code_wedges`` (the other wedge fields left empty; the 4 flush bytes of the
frame's ``wedges`` counted once, in ``wedge_values``).

A measuring script, not a test: it prints a Markdown table and writes nothing.
"""

from __future__ import annotations

import argparse
import time
import zlib
from pathlib import Path

import numpy as np

from .meshes import DEFAULT_MESH_FILES, load_bench_mesh

FIELDS = {  # name: (flag name, how v2 stored it)
    "split_back": ("FIELD_SPLIT_BACK", "<u4"),
    "new_face_counts": ("FIELD_FACE_COUNTS", "<u2"),
    "face_codes": ("FIELD_FACE_CODES", "u1"),
    "third_corners": ("FIELD_THIRD_CORNERS", "u1"),
    "corners_back": ("FIELD_CORNERS_BACK", "<u4"),
    "relabel_masks": ("FIELD_RELABEL_MASKS", "u1"),
    "position_mid": ("FIELD_POSITION_MID", "zigzag"),
    "position_span": ("FIELD_POSITION_SPAN", "zigzag"),
}
# The wedge side (meshes with attributes): name: (field of WedgeArrays, how main's v3
# draft stored it: deflated byte planes, as v2 did its fields).
WEDGE_FIELDS = {
    "wedge_counts": ("counts", "<u2"),
    "wedge_corners": ("symbols", "u1"),
    "wedge_backs": ("backs", "<u4"),
    "wedge_values": ("rows", "zigzag"),
}


_FLUSH_BYTES = 4  # what an empty range-coded field costs (the coder's flush)


def _v2_bytes(values: np.ndarray, layout: str) -> bytes:
    """The field as stream v2 stored it (before deflate)."""
    if layout == "zigzag":  # all x, then all y, then all z
        v = values.T.reshape(-1).astype(np.int64)
        values, layout = ((v << 1) ^ (v >> 63)).astype(np.uint64), "<u4"
    raw = np.ascontiguousarray(values, dtype=layout)
    return raw.view(np.uint8).reshape(-1, raw.dtype.itemsize).T.tobytes()


def measure(pm, bits: int) -> dict:
    from qem_core._kernels import stream_coding
    from qem_core.stream import range_code_fields, range_code_wedges, split_frame_symbols

    names = list(FIELDS) + (list(WEDGE_FIELDS) if pm.attribute_layout is not None else [])
    deflated = dict.fromkeys(names, 0)
    coded = dict.fromkeys(names, 0)
    frames = list(split_frame_symbols(pm, pm.n_base, pm.n_full, bits))
    start = time.perf_counter()
    whole = sum(len(range_code_fields(symbols)) for symbols in frames)
    whole += sum(len(range_code_wedges(s.wedges)) for s in frames if s.wedges is not None)
    code_s = time.perf_counter() - start
    for symbols in frames:
        for name, (flag, layout) in FIELDS.items():
            values = getattr(symbols, name)
            deflated[name] += len(zlib.compress(_v2_bytes(values, layout), 9))
            coded[name] += len(range_code_fields(symbols, getattr(stream_coding, flag)))
        wedges = symbols.wedges
        if wedges is None:
            continue
        empty = wedges._replace(
            counts=wedges.counts[:, :0], symbols=wedges.symbols[:0],
            backs=wedges.backs[:0], rows=wedges.rows[:0],
        )  # fmt: skip
        for name, (field, layout) in WEDGE_FIELDS.items():
            values = getattr(wedges, field)
            flat = values.reshape(-1) if field == "counts" else values
            deflated[name] += len(zlib.compress(_v2_bytes(flat, layout), 9))
            alone = len(range_code_wedges(empty._replace(**{field: values})))
            coded[name] += alone if field == "rows" else alone - _FLUSH_BYTES
    return {
        "splits": pm.n_splits,
        "frames": len(frames),
        "deflate": deflated,
        "range": coded,
        "range_whole": whole,
        "range_code_s": code_s,
    }


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--meshes", nargs="+", default=list(DEFAULT_MESH_FILES))
    parser.add_argument("--qpm-dir", type=Path, default=None)
    parser.add_argument("--bits", type=int, default=16)
    args = parser.parse_args(argv)
    import qem_core

    names = list(FIELDS)
    print("| mesh | coder | " + " | ".join(f"`{n}`" for n in names) + " | sum |")
    print("|---|---|" + "---:|" * (len(names) + 1))
    for mesh_name in args.meshes:
        stem = Path(mesh_name).name
        if args.qpm_dir is not None and (args.qpm_dir / f"{stem}.qpm").is_file():
            pm = qem_core.load(args.qpm_dir / f"{stem}.qpm")
        else:
            mesh = load_bench_mesh(mesh_name)
            pm = qem_core.build(mesh.vertices, mesh.faces)
        result = measure(pm, args.bits)
        n = result["splits"]
        names = list(result["range"])
        for coder in ("deflate", "range"):
            sizes = result[coder]
            cells = " | ".join(f"{sizes[name] / n:.2f}" for name in names)
            print(f"| {stem} | {coder} | {cells} | {sum(sizes.values()) / n:.2f} |")
        print(
            f"| {stem} | range, all fields in one coder | | | | | | | | | "
            f"{result['range_whole'] / n:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()

"""Bytes per vertex split of each split-stream field: deflated byte planes (as stream v2
stored its fields) against the range coder (stream v3), from the same symbol arrays.

    python -m bench.stream_entropy [--meshes spot.ply ...] [--qpm-dir DIR] [--bits 16]

For each mesh (built with default options, or loaded from DIR/<mesh>.qpm when given),
``qem_core.stream.split_frame_symbols`` gives each frame's arrays; each field is then

- deflated as v2 stored such values (uint32 / uint16 byte planes, zigzag signed values;
  zlib level 9 on the field alone; v3's symbols are not v2's for the third corners, the
  relabel masks and the positions, so there this only says what deflate makes of them),
- range-coded alone (``range_code_fields`` with that field's flag, its contexts carried
  from frame to frame as in a stream: every field has its own contexts, so its bytes do
  not depend on the others; each frame's 4 flush bytes are counted in every field, so
  the fields add up to a little more than the frames),

then all fields in one coder, and the whole stream (``encode_split_frames``: frame
headers and CRCs included).

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

from .meshes import DEFAULT_MESH_DIR, DEFAULT_MESH_FILES, load_bench_mesh

FIELDS = {  # name: (flag name, the symbols of it, how v2 stored such values)
    "split_back": ("FIELD_SPLIT_BACK", ("split_back",), "<u4"),
    "new_face_counts": ("FIELD_FACE_COUNTS", ("new_face_counts",), "<u2"),
    "face_codes": ("FIELD_FACE_CODES", ("face_codes",), "u1"),
    "third_corners": ("FIELD_THIRD_CORNERS", ("third_corners", "wing_steps"), "zigzag"),
    "corners_back": ("FIELD_CORNERS_BACK", ("corners_back",), "<u4"),
    "relabel_masks": ("FIELD_RELABEL_MASKS", ("relabel_masks",), "u1"),
    "position_mid": ("FIELD_POSITION_MID", ("positions", 3, 7), "zigzag"),
    "position_span": ("FIELD_POSITION_SPAN", ("positions", 0, 3), "zigzag"),
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


def _values(symbols, what) -> np.ndarray:
    if len(what) == 3:  # columns of a 2-d array
        return getattr(symbols, what[0])[:, what[1] : what[2]]
    return np.concatenate([np.asarray(getattr(symbols, name)).reshape(-1) for name in what])


def _v2_bytes(values: np.ndarray, layout: str) -> bytes:
    """The values laid out as stream v2 stored its fields (before deflate)."""
    if layout == "zigzag":  # signed: column by column
        v = np.atleast_2d(values.T).reshape(-1).astype(np.int64)
        values, layout = ((v << 1) ^ (v >> 63)).astype(np.uint64), "<u4"
    raw = np.ascontiguousarray(values, dtype=layout)
    return raw.view(np.uint8).reshape(-1, raw.dtype.itemsize).T.tobytes()


def measure(pm, bits: int) -> dict:
    from qem_core._kernels import stream_coding
    from qem_core.stream import (
        encode_split_frames,
        new_contexts,
        new_wedge_contexts,
        range_code_fields,
        range_code_wedges,
        split_frame_symbols,
    )

    names = list(FIELDS) + (list(WEDGE_FIELDS) if pm.attribute_layout is not None else [])
    deflated = dict.fromkeys(names, 0)
    coded = dict.fromkeys(names, 0)
    frames = list(split_frame_symbols(pm, pm.n_base, pm.n_full, bits))
    start = time.perf_counter()
    contexts = new_contexts()
    whole = sum(len(range_code_fields(symbols, probs=contexts)) for symbols in frames)
    width = frames[0].wedges.rows.shape[1] if frames and frames[0].wedges is not None else 0
    wedge_contexts = new_wedge_contexts(width)
    whole += sum(len(range_code_wedges(s.wedges, wedge_contexts)) for s in frames if width)
    code_s = time.perf_counter() - start
    stream = sum(map(len, encode_split_frames(pm, pm.n_base, pm.n_full, bits)))
    field_contexts = {name: new_contexts() for name in FIELDS}
    field_contexts |= {name: new_wedge_contexts(width) for name in WEDGE_FIELDS}
    for symbols in frames:
        for name, (flag, what, layout) in FIELDS.items():
            values = _values(symbols, what)
            deflated[name] += len(zlib.compress(_v2_bytes(values, layout), 9))
            fields = getattr(stream_coding, flag)
            coded[name] += len(range_code_fields(symbols, fields, field_contexts[name]))
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
            alone = range_code_wedges(empty._replace(**{field: values}), field_contexts[name])
            coded[name] += len(alone) if field == "rows" else len(alone) - _FLUSH_BYTES
    return {
        "splits": pm.n_splits,
        "frames": len(frames),
        "deflate": deflated,
        "range": coded,
        "range_whole": whole,
        "range_code_s": code_s,
        "stream": stream,
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
            mesh = load_bench_mesh(DEFAULT_MESH_DIR / mesh_name)
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
            f"{result['range_whole'] / n:.2f} |"
        )
        print(
            f"| {stem} | whole stream (frame headers included) | | | | | | | | | "
            f"{result['stream'] / n:.2f} |",
            flush=True,
        )


if __name__ == "__main__":
    main()

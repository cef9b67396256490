"""The ``qem`` subcommands that work on files, without a server.

qem build IN -o OUT.qpm [--option NAME=VALUE ...]   simplify once, save the progressive mesh
qem lod FILE.qpm -n N -o OUT                         one level, as PLY, OBJ, GLB or msgpack
qem simplify IN -n N -o OUT [--option ...]           build and extract in one go
qem info FILE.qpm [--json]                           counts, error curve, sizes, options
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import time
from pathlib import Path

import qem_core
from qem_core import codecs

from .console import (
    EXIT_OK,
    EXIT_USAGE,
    OUTPUT_FORMATS,
    Bar,
    CliError,
    format_of,
    note,
    parse_option_pairs,
    print_json,
    reading,
    write_atomically,
)

__all__ = ["add_build", "add_info", "add_lod", "add_simplify"]

# Fractions of the full vertex count at which `qem info` shows the error curve.
_ERROR_CURVE_FRACTIONS = (1.0, 0.5, 0.1, 0.02, 0.005)


def _parse_options(pairs: list[str]) -> qem_core.BuildOptions:
    """--option NAME=VALUE pairs as BuildOptions (numbers and true/false understood)."""
    values: dict[str, object] = {}
    for name, text in parse_option_pairs(pairs).items():
        if text.lower() in ("true", "false"):
            values[name] = text.lower() == "true"
            continue
        try:
            values[name] = float(text)
        except ValueError:
            values[name] = text
    try:
        return qem_core.BuildOptions.from_mapping(values)
    except qem_core.InvalidOptionsError as exc:
        raise CliError(str(exc), EXIT_USAGE) from None


def _add_build_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("input", help="mesh file: PLY, OBJ, STL, OFF or GLB")
    parser.add_argument(
        "-O",
        "--option",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="a build option, repeatable: "
        + ", ".join(field.name for field in dataclasses.fields(qem_core.BuildOptions)),
    )
    parser.add_argument("--quiet", action="store_true", help="no progress bar")


def _add_level_arguments(parser: argparse.ArgumentParser) -> None:
    suffixes = ", ".join(OUTPUT_FORMATS)
    parser.add_argument("-n", "--vertices", type=int, required=True, help="vertex count")
    parser.add_argument(
        "-o", "--output", required=True, help=f"file to write ({suffixes}; - for stdout)"
    )
    parser.add_argument("--format", choices=sorted(set(OUTPUT_FORMATS.values())))
    parser.add_argument("--json", action="store_true", help="print a JSON summary")


def _build(args: argparse.Namespace) -> tuple[qem_core.ProgressiveMesh, float]:
    """The progressive mesh of args.input and the seconds the build took (kept out of the
    file, so the same input always gives the same bytes)."""
    options = _parse_options(args.option)
    with reading(args.input):
        mesh = qem_core.load_mesh(args.input)
    bar = Bar("build", not args.quiet)
    started = time.perf_counter()
    try:
        with reading(args.input):
            pm = qem_core.build_mesh(mesh, options, progress=bar.show)
    finally:
        bar.done()
    return pm, time.perf_counter() - started


def _load_progressive(path: str) -> qem_core.ProgressiveMesh:
    with reading(path):
        return qem_core.load(path)


def _write_level(pm: qem_core.ProgressiveMesh, n: int, output: str, fmt: str) -> dict:
    """Extract lod(n), write it; returns what was written."""
    if n < 1:
        raise CliError(f"-n {n}: the vertex count must be at least 1", EXIT_USAGE)
    level = pm.lod_mesh(n)  # with the appearance attributes, if any
    vertices, faces = level.vertices, level.faces
    # A textured OBJ names its .mtl and image, written beside it (not beside stdout).
    looked = level.texture or level.materials
    library = Path(output).stem if fmt == "obj" and looked and output != "-" else None
    content = qem_core.encode_mesh(vertices, faces, fmt, level.vertex_attributes,
                                   level.texture, level.corner_uvs, material_library=library,
                                   materials=level.materials,
                                   face_materials=level.face_materials)  # fmt: skip
    write_atomically(output, content)
    if library is not None:
        companions = codecs.obj_companions(library, level.texture, level.materials)
        for name, companion in companions.items():
            write_atomically(str(Path(output).with_name(name)), companion)
    return {
        "path": output,
        "format": fmt,
        "vertices": int(len(vertices)),
        "faces": int(len(faces)),
        "asked": n,
        "error": pm.error(len(vertices)),
        "bytes": len(content),
    }


def _report_level(args: argparse.Namespace, written: dict) -> None:
    if args.json and args.output != "-":
        print_json(written)
        return
    clamped = "" if written["asked"] == written["vertices"] else f" (asked {written['asked']})"
    note(
        f"wrote {written['path']}: {written['vertices']} vertices{clamped}, "
        f"{written['faces']} faces, error {written['error']:.3g} "
        f"({written['bytes']} bytes, {written['format']})"
    )


# -- build ---------------------------------------------------------------------------------


def add_build(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "build", help="simplify a mesh once and save its progressive mesh (.qpm)"
    )
    _add_build_arguments(parser)
    parser.add_argument("-o", "--output", required=True, help="the .qpm file to write")
    parser.add_argument("--json", action="store_true", help="print a JSON summary")
    parser.set_defaults(run=cmd_build)


def cmd_build(args: argparse.Namespace) -> int:
    if args.output == "-":
        raise CliError("-o -: a .qpm file cannot go to stdout; give a file name", EXIT_USAGE)
    pm, seconds = _build(args)
    output = Path(args.output)
    write_atomically(args.output, pm.save)
    summary = _summary(pm, output) | {"build_seconds": round(seconds, 3)}
    if args.json:
        print_json(summary)
    else:
        note(
            f"wrote {output}: {pm.n_base}..{pm.n_full} vertices, "
            f"{summary['faces']} faces at full resolution, {summary['bytes']} bytes, "
            f"built in {seconds:.2f} s"
        )
    return EXIT_OK


# -- lod -----------------------------------------------------------------------------------


def add_lod(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("lod", help="write one level of a .qpm file")
    parser.add_argument("qpm", help="a progressive mesh file from `qem build`")
    _add_level_arguments(parser)
    parser.set_defaults(run=cmd_lod)


def cmd_lod(args: argparse.Namespace) -> int:
    fmt = format_of(args.output, args.format)
    pm = _load_progressive(args.qpm)
    _report_level(args, _write_level(pm, args.vertices, args.output, fmt))
    return EXIT_OK


# -- simplify ------------------------------------------------------------------------------


def add_simplify(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("simplify", help="build and write one level in one go")
    _add_build_arguments(parser)
    _add_level_arguments(parser)
    parser.set_defaults(run=cmd_simplify)


def cmd_simplify(args: argparse.Namespace) -> int:
    fmt = format_of(args.output, args.format)
    if args.vertices < 1:
        raise CliError(f"-n {args.vertices}: the vertex count must be at least 1", EXIT_USAGE)
    pm, _ = _build(args)
    _report_level(args, _write_level(pm, args.vertices, args.output, fmt))
    return EXIT_OK


# -- info ----------------------------------------------------------------------------------


def add_info(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser("info", help="describe a .qpm file")
    parser.add_argument("qpm", help="a progressive mesh file from `qem build`")
    parser.add_argument("--json", action="store_true", help="print JSON")
    parser.set_defaults(run=cmd_info)


def _summary(pm: qem_core.ProgressiveMesh, path: Path) -> dict:
    curve = []
    for fraction in _ERROR_CURVE_FRACTIONS:
        n = pm.clamp(max(1, round(fraction * pm.n_full)))
        curve.append(
            {"fraction": fraction, "vertices": n, "faces": pm.n_faces(n), "error": pm.error(n)}
        )
    metadata = pm.metadata
    return {
        "path": str(path),
        "bytes": os.path.getsize(path),
        "name": metadata.get("name"),
        "vertices": pm.n_full,
        "faces": pm.n_faces_full,
        "min_vertices": pm.n_base,
        "min_faces": pm.n_faces(pm.n_base),
        "bbox": metadata.get("bbox"),
        "options": metadata.get("options"),
        "prepare_report": metadata.get("prepare_report"),
        "error_curve": curve,
    }


def cmd_info(args: argparse.Namespace) -> int:
    pm = _load_progressive(args.qpm)
    summary = _summary(pm, Path(args.qpm))
    if args.json:
        print_json(summary)
        return EXIT_OK
    lines = [
        f"{summary['path']}: {summary['bytes']} bytes"
        + (f", mesh {summary['name']!r}" if summary["name"] else ""),
        f"levels: {pm.n_base} .. {pm.n_full} vertices "
        f"({summary['min_faces']} .. {summary['faces']} faces)",
        "error curve (quadric error of the level):",
    ]
    lines += [
        f"  {point['fraction']:>6.1%}  {point['vertices']:>9} vertices  "
        f"{point['faces']:>9} faces  error {point['error']:.3g}"
        for point in summary["error_curve"]
    ]
    options = summary["options"] or {}
    lines.append("options: " + ", ".join(f"{k}={v}" for k, v in sorted(options.items())))
    report = summary["prepare_report"] or {}
    if report:
        lines.append(
            "input preparation: " + ", ".join(f"{k}={v}" for k, v in sorted(report.items()))
        )
    print("\n".join(lines))
    return EXIT_OK

"""qem-lod as the benchmarks call it: build option variants, the whole-forest build, and
levels extracted from the built progressive mesh.

The functions that take or return a progressive mesh run inside the measuring child
process (`bench.measure.measure_in_child`), so the mesh itself never has to be pickled:
only the extracted levels come back.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from .meshes import warm_up_mesh

__all__ = [
    "OptionValues",
    "add_option_argument",
    "build_progressive_mesh",
    "describe_progressive_mesh",
    "extract_levels",
    "option_values_of",
    "parse_option_assignments",
    "qem_unavailable_reason",
    "validate_option_values",
    "variant_label",
    "warm_up_build",
]

OptionValues = dict[str, Any]  # BuildOptions field name -> value; {} means the defaults


def qem_unavailable_reason() -> str | None:
    """None when `qem_core.build` can be called, else why not (one line)."""
    try:
        import qem_core
    except Exception as error:  # any import failure means: skip qem-lod, say why
        return f"qem_core does not import ({type(error).__name__}: {error})"
    if not callable(getattr(qem_core, "build", None)):
        return "qem_core.build does not exist yet"
    return None


def _parse_value(text: str) -> Any:
    lowered = text.strip().lower()
    if lowered in ("true", "false"):
        return lowered == "true"
    for number_type in (int, float):
        try:
            return number_type(text)
        except ValueError:
            pass
    return text.strip()


def parse_option_assignments(assignments: Iterable[str]) -> OptionValues:
    """Parse ``name=value`` strings into build option values.

    Each item may hold several assignments separated by commas
    ("error_mode=exact,weighting=volume"). Values "true"/"false" become booleans,
    numbers become int or float, anything else stays a string. Raises ValueError on an
    item without "=" or a name given twice; names and values are checked by
    `validate_option_values`.
    """
    values: OptionValues = {}
    for item in assignments:
        for assignment in filter(None, (part.strip() for part in item.split(","))):
            name, sep, value = assignment.partition("=")
            if not sep or not name.strip():
                raise ValueError(f"build option {assignment!r} is not of the form name=value")
            name = name.strip()
            if name in values:
                raise ValueError(f"build option {name!r} is given twice")
            values[name] = _parse_value(value)
    return values


def validate_option_values(values: OptionValues) -> None:
    """Raise qem_core.InvalidOptionsError (a ValueError) if `BuildOptions` refuses them."""
    from qem_core import BuildOptions

    BuildOptions.from_mapping(values)


def add_option_argument(parser: argparse.ArgumentParser, help: str) -> None:
    """A benchmark's repeatable ``--qem-option NAME=VALUE`` (read by `option_values_of`)."""
    parser.add_argument(
        "--qem-option", action="append", default=[], metavar="NAME=VALUE", help=help
    )


def option_values_of(parser: argparse.ArgumentParser, args: argparse.Namespace) -> OptionValues:
    """The build options of ``args.qem_option``; a malformed or refused one is the
    parser's error (exit 2). Checked against `BuildOptions` only where qem_core imports,
    so a benchmark can still measure the peers without it."""
    try:
        values = parse_option_assignments(args.qem_option)
        if qem_unavailable_reason() is None:
            validate_option_values(values)
    except ValueError as error:
        parser.error(str(error))
    return values


def variant_label(values: OptionValues) -> str:
    """Row name of a variant: "qem-lod", or "qem-lod[error_mode=exact,...]"."""
    if not values:
        return "qem-lod"
    return "qem-lod[" + ",".join(f"{name}={values[name]}" for name in sorted(values)) + "]"


def build_progressive_mesh(vertices: np.ndarray, faces: np.ndarray, option_values: OptionValues):
    """`qem_core.build` of the whole forest. vertices (n, 3) float64, faces (m, 3) int32."""
    import qem_core

    options = qem_core.BuildOptions.from_mapping(option_values) if option_values else None
    return qem_core.build(vertices, faces, options=options)


def warm_up_build(option_values: OptionValues) -> None:
    """`qem_core.warm_up()`, then build and extract a tiny mesh with the options, so numba
    has compiled (or loaded from its cache) every kernel before a timed build, those of
    the parallel rounds included, which a small build does not reach. Run it as
    `measure_in_child(..., before=warm_up_build)`."""
    import qem_core

    qem_core.warm_up()
    vertices, faces = warm_up_mesh()
    progressive_mesh = build_progressive_mesh(vertices, faces, option_values)
    progressive_mesh.lod(progressive_mesh.n_base)
    progressive_mesh.lod(progressive_mesh.n_full)


def describe_progressive_mesh(progressive_mesh) -> dict[str, int]:
    """{"n_full": ..., "n_base": ...} of a built progressive mesh."""
    return {"n_full": int(progressive_mesh.n_full), "n_base": int(progressive_mesh.n_base)}


def extract_levels(progressive_mesh, vertex_counts: Sequence[int]) -> dict[str, Any]:
    """Extract `progressive_mesh.lod(n)` for each n and time each extraction.

    Returns {"n_full", "n_base", "levels": {n: {"vertices" (k, 3) float64,
    "faces" (f, 3) int32, "seconds": float}}}; k may differ from n where n is clamped.
    """
    levels = {}
    for n in sorted(set(int(count) for count in vertex_counts)):
        start = time.perf_counter()
        vertices, faces = progressive_mesh.lod(n)
        seconds = time.perf_counter() - start
        levels[n] = {
            "vertices": np.asarray(vertices, dtype=np.float64),
            "faces": np.asarray(faces, dtype=np.int32),
            "seconds": seconds,
        }
    return {**describe_progressive_mesh(progressive_mesh), "levels": levels}

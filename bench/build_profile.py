"""Where a hot build's time goes, kernel by kernel: Linux `perf` samples mapped to numba code.

    python -m bench.build_profile [--mesh dragon.ply] [--frequency 4000]

`perf` sees numba's machine code as anonymous memory: it has no symbols for it. So a child
process builds the mesh once with an empty NUMBA_CACHE_DIR (it compiles every kernel, and
numba then keeps each kernel's object code), writes each object file and the address its
kernel was loaded at, and waits; `perf record` attaches to it and the child builds the
mesh again, the build that is measured. Each sampled instruction address is then looked
up in the objects' symbol tables (`nm`): a kernel's helpers that are not inlined are
functions of their own there. Samples outside numba code keep perf's own symbol (libm's
arccos and cos, the kernel's page clearing, Python).

The shares are of all samples of the build's threads at the sampling frequency, so with
two threads in the parallel rounds a kernel's share is of CPU time, not of wall time.
Needs `perf` and `nm` (binutils), and a kernel that lets a process sample its own child
(/proc/sys/kernel/perf_event_paranoid at most 2): without them it says so and stops.
Results: bench/results/build-profile-<mesh>.md and .json.
"""

from __future__ import annotations

import argparse
import bisect
import collections
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any, NamedTuple

from bench.machine import describe_machine, machine_header_lines
from bench.meshes import DEFAULT_MESH_DIR
from bench.report import markdown_table, write_json

__all__ = ["KernelSymbol", "kernel_name", "main", "read_symbols", "share_by_symbol"]

RESULTS_DIR = Path(__file__).resolve().parent / "results"
# Rows of the table: the kernels and other symbols with the most samples.
TABLE_ROWS = 40
# How long the parent waits for the child's compile and first build.
READY_TIMEOUT_S = 900.0


class KernelSymbol(NamedTuple):
    start: int  # absolute address in the child
    end: int
    name: str  # mangled


def kernel_name(mangled: str) -> str:
    """'module.function' of a numba-mangled qem_core kernel name, or the name itself (cut
    to 80 characters) for anything else (numba's own helpers, the cpython wrappers)."""
    match = re.search(r"qem_core\d+_kernels\d+(\w+?)\d+(_\w+?)B\d", mangled)
    if match is None:
        return mangled[:80]
    prefix = "cpython wrapper of " if "7cpython8qem_core" in mangled else ""
    return f"{prefix}{match.group(1)}.{match.group(2)}"


def read_symbols(nm_output: str, kernel: str, kernel_address: int) -> list[KernelSymbol]:
    """The function symbols of one object file (`nm -S` output), at the addresses they
    were loaded at: the object's code was loaded in one piece, with ``kernel`` (a symbol
    of it) at ``kernel_address``. Empty if ``kernel`` is not among them."""
    offsets = []
    for line in nm_output.splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[2] in "TtWw":
            offsets.append((int(parts[0], 16), int(parts[1], 16), parts[3]))
    base = [offset for offset, _, name in offsets if name == kernel]
    if not base:
        return []
    load = kernel_address - base[0]
    return [KernelSymbol(load + offset, load + offset + size, name)
            for offset, size, name in offsets]


def share_by_symbol(samples: list[tuple[int, str]],
                    symbols: list[KernelSymbol]) -> collections.Counter:
    """Samples per kernel (`kernel_name`), or per perf's own symbol where the address
    lies in no numba object. samples: (address, perf's symbol)."""
    symbols = sorted(symbols)
    starts = [symbol.start for symbol in symbols]
    counts: collections.Counter = collections.Counter()
    for address, perf_symbol in samples:
        i = bisect.bisect_right(starts, address) - 1
        if i >= 0 and address < symbols[i].end:
            counts[kernel_name(symbols[i].name)] += 1
        else:
            counts[perf_symbol or "[unknown]"] += 1
    return counts


def _child(mesh_path: str, work: str) -> None:
    """Build, write the kernels' objects and load addresses, wait for "start", build again."""
    import importlib
    import pkgutil

    import numpy as np
    from numba.core.registry import CPUDispatcher

    import qem_core
    import qem_core._kernels as kernels
    from bench.meshes import load_bench_mesh

    mesh = load_bench_mesh(mesh_path)
    vertices, faces = np.asarray(mesh.vertices), np.asarray(mesh.faces)
    qem_core.build(vertices, faces)
    objects = []
    for module_info in pkgutil.iter_modules(kernels.__path__):
        module = importlib.import_module(f"qem_core._kernels.{module_info.name}")
        for value in vars(module).values():
            if not isinstance(value, CPUDispatcher):
                continue
            for result in value.overloads.values():
                try:
                    _, _, (object_code, _) = result.library.serialize_using_object_code()
                except RuntimeError:
                    continue  # compiled without object caching: nothing to map
                path = Path(work) / f"{len(objects)}.o"
                path.write_bytes(object_code)
                name = result.fndesc.llvm_func_name
                objects.append({"path": str(path), "kernel": name,
                                "address": result.library.get_pointer_to_function(name)})
    (Path(work) / "objects.json").write_text(json.dumps(objects))
    (Path(work) / "ready").touch()
    while not (Path(work) / "start").exists():
        time.sleep(0.01)
    started = time.perf_counter()
    qem_core.build(vertices, faces)
    seconds = time.perf_counter() - started
    (Path(work) / "done").write_text(json.dumps({"build_s": seconds}))
    time.sleep(60.0)  # until the parent has stopped perf and ends this process


def _wait_for(path: Path, child: subprocess.Popen, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while not path.exists():
        if child.poll() is not None:
            raise RuntimeError(f"the child process ended (status {child.returncode}) "
                               f"before writing {path.name}")
        if time.monotonic() > deadline:
            raise RuntimeError(f"no {path.name} from the child after {timeout_s:.0f} s")
        time.sleep(0.05)


def _missing_tools() -> str | None:
    for tool in ("perf", "nm"):
        if shutil.which(tool) is None:
            return f"`{tool}` is not installed"
    try:
        paranoid = int(Path("/proc/sys/kernel/perf_event_paranoid").read_text())
    except (OSError, ValueError):
        return "/proc/sys/kernel/perf_event_paranoid cannot be read"
    if paranoid > 2:
        return f"perf_event_paranoid is {paranoid}: sampling another process needs <= 2"
    return None


def profile_build(mesh_path: Path, frequency: int) -> dict[str, Any]:
    """Samples of one hot build of the mesh, by kernel (module docstring)."""
    with tempfile.TemporaryDirectory(prefix="qem-profile-") as work:
        environment = dict(os.environ, NUMBA_CACHE_DIR=str(Path(work) / "numba-cache"))
        child = subprocess.Popen(
            [sys.executable, "-m", "bench.build_profile", "--child", str(mesh_path), work],
            env=environment, cwd=Path(__file__).resolve().parents[1])
        recorder = None
        try:
            _wait_for(Path(work) / "ready", child, READY_TIMEOUT_S)
            data = Path(work) / "perf.data"
            recorder = subprocess.Popen(
                ["perf", "record", "-q", "-F", str(frequency), "-p", str(child.pid),
                 "-o", str(data)], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            time.sleep(1.0)  # perf attaches to every thread of the child
            (Path(work) / "start").touch()
            _wait_for(Path(work) / "done", child, READY_TIMEOUT_S)
            recorder.send_signal(signal.SIGINT)
            recorder.wait(timeout=60)
            build_s = json.loads((Path(work) / "done").read_text())["build_s"]
        finally:
            if recorder is not None and recorder.poll() is None:
                recorder.kill()
            child.kill()
            child.wait()
        symbols = []
        for entry in json.loads((Path(work) / "objects.json").read_text()):
            nm = subprocess.run(["nm", "-S", entry["path"]], capture_output=True, text=True,
                                check=True).stdout
            symbols += read_symbols(nm, entry["kernel"], entry["address"])
        script = subprocess.run(["perf", "script", "-i", str(data), "-F", "ip,sym"],
                                capture_output=True, text=True, check=True).stdout
    samples = []
    for line in script.splitlines():
        parts = line.split(None, 1)
        if parts:
            samples.append((int(parts[0], 16), parts[1].strip() if len(parts) > 1 else ""))
    counts = share_by_symbol(samples, symbols)
    return {"mesh": mesh_path.name, "frequency_hz": frequency, "build_s": build_s,
            "samples": len(samples), "by_symbol": dict(counts.most_common()),
            "machine": describe_machine()}


def write_report(result: dict[str, Any], out_dir: Path) -> Path:
    stem = f"build-profile-{Path(result['mesh']).stem}"
    write_json(out_dir / f"{stem}.json", result)
    total = max(result["samples"], 1)
    rows = [[name, str(count), f"{100.0 * count / total:.1f} %"]
            for name, count in list(result["by_symbol"].items())[:TABLE_ROWS]]
    lines = [
        f"# Where a hot build of `{result['mesh']}` spends its CPU time, kernel by kernel",
        "",
        f"Measured {time.strftime('%Y-%m-%dT%H:%M:%S%z')}. " + machine_header_lines()[0],
        machine_header_lines()[1],
        "",
        f"`python -m bench.build_profile --mesh {result['mesh']}`: {result['samples']} perf "
        f"samples at {result['frequency_hz']} Hz of every thread of one hot build "
        f"({result['build_s'] * 1000:.0f} ms, the second in its process, with numba's "
        "kernels just compiled). A kernel is `module._function` of qem_core/_kernels; its "
        "inlined helpers count as its own. Other rows are perf's symbols: libm "
        "(`__ieee754_acos_fma`, `__cos_fma`: the eigenvalues of placement.py), the Linux "
        "kernel (`clear_page_erms`: zeroing pages at first touch), numpy, Python; "
        "`[unknown]` is mostly the bodies of numba's parallel loops (`prange`), which are "
        "compiled apart from their kernel. Shares are of CPU time: the parallel rounds "
        f"run two threads. The first {TABLE_ROWS} rows:",
        "",
        *markdown_table(["symbol", "samples", "share"], rows, [False, True, True]),
        "",
    ]
    path = out_dir / f"{stem}.md"
    path.write_text("\n".join(lines), encoding="utf-8")
    return path


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--child"]:
        _child(*argv[1:3])
        return 0
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mesh", default="dragon.ply")
    parser.add_argument("--mesh-dir", type=Path, default=DEFAULT_MESH_DIR)
    parser.add_argument("--frequency", type=int, default=4000, help="samples a second")
    parser.add_argument("--out-dir", type=Path, default=RESULTS_DIR)
    args = parser.parse_args(argv)
    missing = _missing_tools()
    if missing:
        print(f"build_profile: {missing}; nothing measured", file=sys.stderr)
        return 2
    mesh_path = args.mesh_dir / args.mesh
    if not mesh_path.is_file():
        print(f"build_profile: no mesh at {mesh_path}", file=sys.stderr)
        return 2
    result = profile_build(mesh_path, args.frequency)
    path = write_report(result, args.out_dir)
    print(path.read_text(encoding="utf-8"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

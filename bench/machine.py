"""Describe the machine and package versions a result was measured with."""

from __future__ import annotations

import importlib.metadata
import os
import platform
import sys
from functools import cache

__all__ = ["BENCH_PACKAGES", "describe_machine", "machine_header_lines"]

# Distributions whose versions go into every results file.
BENCH_PACKAGES = (
    "qem-lod",
    "numpy",
    "numba",
    "trimesh",
    "meshoptimizer",
    "fast-simplification",
    "pyfqmr",
    "pymeshlab",
    "open3d-cpu",
)


def _cpu_model() -> str:
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as cpuinfo:
            for line in cpuinfo:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _total_ram_gib() -> float | None:
    try:
        with open("/proc/meminfo", encoding="utf-8") as meminfo:
            for line in meminfo:
                if line.startswith("MemTotal:"):
                    return int(line.split()[1]) / 2**20  # kB -> GiB
    except OSError:
        pass
    return None


def _version(distribution: str) -> str:
    try:
        return importlib.metadata.version(distribution)
    except importlib.metadata.PackageNotFoundError:
        return "not installed"


@cache
def describe_machine() -> dict:
    """CPU model, logical cores, RAM (GiB), OS, Python and `BENCH_PACKAGES` versions."""
    ram = _total_ram_gib()
    return {
        "cpu": _cpu_model(),
        "cores": os.cpu_count(),
        "ram_gib": None if ram is None else round(ram, 1),
        "os": f"{platform.system()} {platform.release()}",
        "python": sys.version.split()[0],
        "packages": {name: _version(name) for name in BENCH_PACKAGES},
    }


def machine_header_lines() -> list[str]:
    """Two Markdown lines, "Machine: ..." and "Versions: ...", for a results file."""
    machine = describe_machine()
    ram = "unknown RAM" if machine["ram_gib"] is None else f"{machine['ram_gib']:.0f} GiB RAM"
    versions = ", ".join(f"{name} {version}" for name, version in machine["packages"].items())
    return [
        f"Machine: {machine['cpu']}, {machine['cores']} cores, {ram}, "
        f"Python {machine['python']}, {machine['os']}.",
        f"Versions: {versions}.",
    ]

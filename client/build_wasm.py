"""Build the viewer's WebAssembly split decoder: client/web/wasm/refine.c -> js/refine.wasm.

Standard library only, like viewer_files.py: ``setup.py`` runs it by path when a wheel is
built, and ``make install`` as a script (``python client/build_wasm.py``). The compiler
is clang for wasm32, from the ziglang package on PyPI (``python -m ziglang cc``): no
toolchain outside the package registries, and the same one on every machine.
"""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

__all__ = ["SOURCE", "TARGET", "build"]

WEB = Path(__file__).resolve().parent / "web"
SOURCE = WEB / "wasm" / "refine.c"
TARGET = WEB / "js" / "refine.wasm"


def _exports(source: str) -> list[str]:
    """The functions refine.c gives the page: every `qem_...` defined at top level."""
    return sorted(set(re.findall(r"^\w[\w\s*]*?\b(qem_\w+)\(", source, re.MULTILINE)))


def build(target: Path = TARGET, defines: dict[str, str] | None = None) -> Path:
    """Compile SOURCE into `target`; raises SystemExit with the compiler's words on failure.
    ``defines``: macros of refine.c set otherwise (the tests build a variant that reads
    ahead on any mesh, ``READ_AHEAD_BYTES=0``)."""
    try:
        import ziglang  # noqa: F401  (only whether it is there)
    except ImportError:
        raise SystemExit(
            "building the viewer's WebAssembly decoder needs the ziglang package "
            "(pip install ziglang; `make install` installs it with the dev extra)"
        ) from None
    exports = [f"-Wl,--export={name}" for name in _exports(SOURCE.read_text())]
    command = [
        sys.executable, "-m", "ziglang", "cc", "--target=wasm32-freestanding", "-O3",
        "-mbulk-memory", "-nostdlib", "-Wl,--no-entry", *exports,
        *(f"-D{name}={value}" for name, value in (defines or {}).items()),
        "-o", str(target), str(SOURCE),
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise SystemExit(f"building {target.name} failed:\n{done.stderr.strip()}")
    return target


if __name__ == "__main__":
    print(f"built {build()}")

"""Build hook: the wheel carries the web viewer with its npm packages and its wasm.

Everything else is in pyproject.toml. A wheel (``pip wheel .``) installed on a machine
without npm must still serve a working viewer, so building one needs the viewer's
packages in client/web/node_modules: they are installed from the lockfile (``npm ci``)
when missing, and the build stops with a message when npm is not there either. Only the
files the viewer loads go in (client/viewer_files.py), not all of node_modules. The
WebAssembly split decoder (client/web/js/refine.wasm) is compiled from its C source when
missing (client/build_wasm.py, with the ziglang that the build requires). An editable
install (``make install``) serves client/web from the source tree and needs none of this.
"""

from __future__ import annotations

import runpy
import shutil
import subprocess
from pathlib import Path

from setuptools import setup
from setuptools.command.build_py import build_py

ROOT = Path(__file__).resolve().parent
WEB = ROOT / "client" / "web"
_files = runpy.run_path(str(ROOT / "client" / "viewer_files.py"))
VIEWER_FILES, VIEWER_PACKAGES = _files["VIEWER_FILES"], _files["VIEWER_PACKAGES"]
_wasm = runpy.run_path(str(ROOT / "client" / "build_wasm.py"))


def _missing_packages() -> list[str]:
    return [name for name in VIEWER_PACKAGES if not (WEB / "node_modules" / name).exists()]


def _package_data() -> list[str]:
    patterns = [f"web/{pattern}" for pattern in VIEWER_FILES]
    for name in VIEWER_PACKAGES:
        path = WEB / "node_modules" / name
        patterns.append(f"web/node_modules/{name}" + ("/**/*" if path.is_dir() else ""))
    return patterns


class BuildWithViewer(build_py):
    def run(self) -> None:
        if not getattr(self, "editable_mode", False):
            built = _build_missing_wasm()
            if _install_missing_packages() or built:
                # The globs were expanded before these files were made: expand them again.
                self.package_data["client"] = _package_data()
                self.data_files = self._get_data_files()
        super().run()


def _build_missing_wasm() -> bool:
    """Compile client/web/js/refine.wasm when it is missing; whether it was."""
    if _wasm["TARGET"].exists():
        return False
    _wasm["build"]()
    return True


def _install_missing_packages() -> bool:
    """`npm ci` in client/web when some viewer package is missing; whether it ran."""
    if not _missing_packages():
        return False
    npm = shutil.which("npm")
    if npm is None:
        raise SystemExit(
            "building the wheel needs the web viewer's npm packages "
            f"({', '.join(_missing_packages())}): install Node.js >= 18 with npm, or "
            "run `npm ci` in client/web on a machine that has it, then build again"
        )
    subprocess.run([npm, "ci", "--no-audit", "--no-fund"], cwd=WEB, check=True)
    if _missing_packages():
        raise SystemExit(f"npm ci left out {', '.join(_missing_packages())}")
    return True


setup(
    cmdclass={"build_py": BuildWithViewer},
    # Only package_data: not every file an earlier build listed in the egg-info.
    include_package_data=False,
    package_data={"client": _package_data(), "server": ["demo/*"]},
)

"""The wheel as a user gets it: built by ``pip wheel .``, installed into a fresh virtual
environment, ``qem serve --demo`` started from there with no npm (nor the source tree) in
reach; the viewer page loads its packages from the wheel and refines the demo mesh in
headless Chromium."""

from __future__ import annotations

import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import httpx

from client.viewer_files import VIEWER_PACKAGES

from .conftest import REPO, ServerProcess
from .test_viewer import chromium_page, require_web_packages

READY_TIMEOUT_S = 300  # a fresh install compiles numba's kernels for its first build


def _run(*command: str, cwd: Path) -> str:
    done = subprocess.run(command, cwd=cwd, capture_output=True, text=True, check=False)
    assert done.returncode == 0, f"{' '.join(command)}:\n{done.stdout}\n{done.stderr}"
    return done.stdout


def test_the_wheel_serves_the_viewer_without_npm(tmp_path):
    require_web_packages()
    _run(sys.executable, "-m", "pip", "wheel", str(REPO), "--no-deps",
         "-q", "-w", str(tmp_path / "dist"), cwd=tmp_path)  # fmt: skip
    (wheel,) = (tmp_path / "dist").glob("qem_lod-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for package in VIEWER_PACKAGES:
        assert any(name.startswith(f"client/web/node_modules/{package}") for name in names)
    assert not any("three/src/" in name for name in names)  # what the viewer loads, not all
    assert "client/web/js/refine.wasm" in names  # the WebAssembly split decoder, built

    # A fresh environment; its dependencies (not qem-lod, whose editable install is a
    # .pth this path does not run) from this one's site-packages.
    venv = tmp_path / "venv"
    _run(sys.executable, "-m", "venv", str(venv), cwd=tmp_path)
    python = venv / "bin" / "python"
    site = _run(str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])",
                cwd=tmp_path).strip()  # fmt: skip
    (Path(site) / "deps.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    _run(str(python), "-m", "pip", "install", "-q", "--no-deps", str(wheel), cwd=tmp_path)
    where = _run(str(python), "-c", "import client; print(client.__file__)", cwd=tmp_path)
    assert where.startswith(str(venv)), where  # the wheel's, not the source tree's

    server = ServerProcess(
        tmp_path / "data",
        env={"PATH": str(venv / "bin"), "PYTHONPATH": ""},  # no npm, no source tree
        command=[str(venv / "bin" / "qem"), "serve", "--demo", "--port", "0", "--data-dir",
                 str(tmp_path / "data"), "--log-level", "info"],  # fmt: skip
    ).start()
    try:
        with httpx.Client(base_url=server.url, timeout=60) as http:
            (demo,) = http.get("/v1/meshes").json()["meshes"]
            with chromium_page(tmp_path / "profile") as page:
                page.goto(f"{server.url}/#mesh={demo['id']}")
                page.wait_for_function(
                    "() => { const s = window.qemViewer?.state; return s?.failure ||"
                    " (s?.level !== null && s.level === s.full && !s.streaming); }",
                    timeout=READY_TIMEOUT_S * 1000,
                )
                state = page.evaluate("window.qemViewer.state")
                assert state["failure"] is None and page.errors == [], (state, page.errors)
                info = http.get(f"/v1/meshes/{demo['id']}").json()
                assert state["level"] == info["vertices"] and state["splitBytes"] > 0
                assert state["attributes"] and state["textureShown"]  # spot, textured
    finally:
        server.stop()

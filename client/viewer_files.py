"""The web viewer's files: what a static export copies and what the wheel carries.

Standard library only: ``setup.py`` reads this file (by path, before anything is
installed) to put the viewer and its npm packages into the wheel, so that ``pip install``
of the wheel gives ``qem serve`` a working viewer on a machine without npm.
"""

from __future__ import annotations

__all__ = ["VIEWER_FILES", "VIEWER_PACKAGES"]

# client/web's own files (globs relative to client/web); js/refine.wasm is built from
# wasm/refine.c (build_wasm.py).
VIEWER_FILES = ("index.html", "viewer.css", "js/*.js", "js/*.wasm")

# What the viewer imports from node_modules (index.html's import map, refine.js's
# relative msgpack import), and the licences: a file, or a folder taken whole.
VIEWER_PACKAGES = (
    "three/build/three.module.js",
    "three/build/three.core.js",
    "three/examples/jsm/controls/OrbitControls.js",
    "three/examples/jsm/postprocessing/Pass.js",  # FullScreenQuad: off-screen frames' copy
    "three/LICENSE",
    "@msgpack/msgpack/dist.esm",
    "@msgpack/msgpack/LICENSE",
)

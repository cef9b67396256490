"""A scene of two textured meshes through the real server, in both deployments: built
as one mesh of two materials, each level served with both (GLB: a primitive each; the
OBJ zip: both images), each image at ``/texture?material=k``, and the viewer drawing
both halves, each with its own image, on every level the server serves."""

from __future__ import annotations

import base64
import io
import zipfile

import httpx
import pytest

import qem_core

from .test_viewer import (
    _IMAGE_STATS,
    PNG_PIXELS_JS,
    assert_levels_on_screen_are_served,
    chromium_page,
    open_at_full_detail,
    require_web_packages,
)

pytest.importorskip("trimesh", reason="trimesh writes the two-texture scene")
pytest.importorskip("PIL", reason="Pillow makes the second texture")

from tests.unit.test_materials import two_texture_scene_glb  # noqa: E402

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def scene(server, tmp_path_factory):
    """The scene uploaded and built: (its mesh info, its two images)."""
    path = tmp_path_factory.mktemp("scene") / "two-halves.glb"
    path.write_bytes(two_texture_scene_glb())
    with server.client() as qem:
        info = qem.wait_ready(qem.upload(path), timeout=300)
    images = [m.texture for m in qem_core.load_mesh(path).materials]
    return info, images


@pytest.fixture(scope="module")
def http(server):
    with httpx.Client(base_url=server.url, timeout=60) as client:
        yield client


def test_every_level_keeps_both_materials(http, scene):
    info, images = scene
    url = f"/v1/meshes/{info['id']}"
    for n in (info["min_vertices"], 700, info["vertices"]):
        glb = http.get(f"{url}/lod", params={"vertices": n, "format": "glb"})
        mesh = qem_core.load_mesh(glb.content, format="glb")
        assert mesh.n_vertices >= n  # seams split a position into several vertices
        assert [m.texture for m in mesh.materials] == images
        assert sorted(set(mesh.face_materials.tolist())) == [0, 1]
    level = http.get(f"{url}/lod", params={"vertices": 700, "format": "zip"})
    names = sorted(zipfile.ZipFile(io.BytesIO(level.content)).namelist())
    assert names == ["mesh.mtl", "mesh.obj", "mesh_texture0.png", "mesh_texture1.png"]
    mesh = qem_core.load_mesh(level.content)
    assert [m.texture for m in mesh.materials] == images


def test_each_material_s_image_is_served(http, scene):
    info, images = scene
    url = f"/v1/meshes/{info['id']}/texture"
    for k, image in enumerate(images):
        response = http.get(url, params={"material": k})
        assert response.status_code == 200 and response.content == image
        assert response.headers["content-type"] == "image/png"
        again = http.get(url, params={"material": k},
                         headers={"If-None-Match": response.headers["etag"]})  # fmt: skip
        assert again.status_code == 304
    etags = {http.get(url, params={"material": k}).headers["etag"] for k in (0, 1)}
    assert len(etags) == 2
    for params, words in (({}, "2 materials; name one"), ({"material": 2}, "not a material 2")):
        response = http.get(url, params=params)
        assert response.status_code == 404 and response.headers["content-type"] == PROBLEM
        assert words in response.json()["detail"]
    for bad in ("-1", "256", "one"):
        response = http.get(url, params={"material": bad})
        assert response.status_code == 422 and response.headers["content-type"] == PROBLEM


# The mean brightness of the model's pixels left and right of its middle column (pixels
# away from the background's colour, the top-left pixel's, are the model's).
_HALVES = "async (data) => {" + PNG_PIXELS_JS + """
  const [r0, g0, b0] = pixels;
  const model = [];
  for (let i = 0; i < pixels.length; i += 4) {
    const [r, g, b] = [pixels[i], pixels[i + 1], pixels[i + 2]];
    if (Math.abs(r - r0) + Math.abs(g - g0) + Math.abs(b - b0) > 24) {
      model.push([(i / 4) % width, 0.299 * r + 0.587 * g + 0.114 * b]);
    }
  }
  const xs = model.map(([x]) => x).sort((a, b) => a - b);
  const middle = xs[xs.length >> 1];
  const mean = (side) => {
    const ys = model.filter(([x]) => side(x)).map(([, y]) => y);
    return ys.reduce((a, b) => a + b, 0) / ys.length;
  };
  return { left: mean((x) => x < middle), right: mean((x) => x >= middle) };
}
"""


def test_the_viewer_draws_each_half_with_its_own_image(server, http, scene, tmp_path):
    """Spot's texture is mostly white, the inverted one mostly black: seen from behind,
    one half of the cow is light and the other dark (one image on both would not be)."""
    require_web_packages()
    info, _ = scene
    url = f"{server.url}/v1/meshes/{info['id']}"
    with chromium_page(tmp_path / "profile") as page:
        state = open_at_full_detail(page, server.url, info["id"], texture=True)
        assert state["attributes"] == ["uv", "material"] and state["failure"] is None
        levels = (info["vertices"], 700, info["min_vertices"] + 1, info["vertices"] - 3)
        assert_levels_on_screen_are_served(page, http, url, levels)
        page.evaluate("(n) => window.qemViewer.setLevel(n)", info["vertices"])
        page.evaluate("() => new Promise((done) => requestAnimationFrame(() => done()))")
        for overlay in ("#hud", "#controls"):
            page.eval_on_selector(overlay, "node => { node.style.visibility = 'hidden'; }")
        shot = page.locator("#canvas").screenshot(path=tmp_path / "halves.png")
        data = base64.b64encode(shot).decode()
        halves = page.evaluate(_HALVES, data)
        assert abs(halves["left"] - halves["right"]) > 20, halves
        assert page.evaluate(_IMAGE_STATS, data)["colours"] > 200
        assert page.errors == []

"""The local ``qem`` commands (build, info, lod, simplify) run as a user runs them: a
subprocess, files on disk, exit statuses and messages."""

from __future__ import annotations

import json
import os
import stat
import subprocess
import sys
import threading
from pathlib import Path

import numpy as np
import pytest

import qem_core
from tests.tiny_meshes import icosphere

REPO = Path(__file__).resolve().parents[2]


def qem(*args: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "client.cli", *args],
        cwd=cwd,
        env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        text=True,
        timeout=300,
    )


@pytest.fixture(scope="module")
def sphere_file(tmp_path_factory) -> Path:
    vertices, faces = icosphere(3, jitter=0.05, seed=3)  # 642 vertices
    path = tmp_path_factory.mktemp("cli") / "sphere.ply"
    path.write_bytes(qem_core.encode_mesh(vertices, faces, "ply"))
    return path


@pytest.fixture(scope="module")
def built(sphere_file) -> Path:
    result = qem("build", str(sphere_file), "-o", "sphere.qpm", cwd=sphere_file.parent)
    assert result.returncode == 0, result.stderr
    assert "wrote sphere.qpm" in result.stderr
    return sphere_file.parent / "sphere.qpm"


def test_build_writes_a_loadable_qpm(built, sphere_file):
    pm = qem_core.load(built)
    mesh = qem_core.load_mesh(sphere_file)
    assert pm.n_full == mesh.n_vertices
    assert pm.lod(pm.n_full)[1].shape == mesh.faces.shape


def test_build_is_deterministic(built, sphere_file):
    again = qem("build", str(sphere_file), "-o", "again.qpm", cwd=sphere_file.parent)
    assert again.returncode == 0, again.stderr
    assert (sphere_file.parent / "again.qpm").read_bytes() == built.read_bytes()


def test_info_json(built):
    result = qem("info", str(built), "--json", cwd=built.parent)
    assert result.returncode == 0, result.stderr
    info = json.loads(result.stdout)
    pm = qem_core.load(built)
    assert (info["vertices"], info["min_vertices"]) == (pm.n_full, pm.n_base)
    assert info["bytes"] == built.stat().st_size
    errors = [point["error"] for point in info["error_curve"]]
    assert errors == sorted(errors)  # finer levels never have a larger error
    assert info["options"]["weighting"] == qem_core.BuildOptions().weighting  # the default


@pytest.mark.parametrize("suffix", [".ply", ".obj", ".glb", ".msgpack"])
def test_lod_writes_exactly_n_vertices(built, suffix):
    output = built.parent / f"level{suffix}"
    result = qem("lod", str(built), "-n", "100", "-o", output.name, "--json", cwd=built.parent)
    assert result.returncode == 0, result.stderr
    summary = json.loads(result.stdout)
    mesh = qem_core.load_mesh(output)
    vertices, faces = qem_core.load(built).lod(100)
    assert summary["vertices"] == mesh.n_vertices == 100
    assert np.array_equal(mesh.faces, faces)


def test_lod_reports_clamping(built):
    result = qem("lod", str(built), "-n", "1", "-o", "tiny.obj", cwd=built.parent)
    assert result.returncode == 0, result.stderr
    assert "(asked 1)" in result.stderr


def test_simplify_in_one_go(sphere_file):
    result = qem("simplify", str(sphere_file), "-n", "50", "-o", "s.glb", cwd=sphere_file.parent)
    assert result.returncode == 0, result.stderr
    assert qem_core.load_mesh(sphere_file.parent / "s.glb").n_vertices == 50


@pytest.mark.parametrize(
    ("args", "status", "words"),
    [
        (["lod", "missing.qpm", "-n", "5", "-o", "x.ply"], 2, "no such file"),
        (["lod", "sphere.qpm", "-n", "5", "-o", "x.xyz"], 2, "cannot tell the format"),
        (["lod", "sphere.qpm", "-n", "0", "-o", "x.ply"], 2, "at least 1"),
        (["info", "truncated.qpm"], 1, "damaged or truncated"),
        (["build", "sphere.ply", "-o", "x.qpm", "--option", "weighting=foo"], 2, "weighting"),
        (["build", "sphere.ply", "-o", "x.qpm", "--option", "colour=red"], 2, "unknown build"),
        (["build", "sphere.ply", "-o", "x.qpm", "--option", "weighting=area", "--option",
          "weighting=none"], 2, "given twice"),
        (["build", "garbage.ply", "-o", "x.qpm"], 1, "garbage.ply"),
        # Regression: uvicorn raised OverflowError past 65535; nan waited forever.
        (["serve", "--port", "99999"], 2, "not a port"),
        (["upload", "sphere.ply", "--timeout", "nan"], 2, "positive number of seconds"),
        (["upload", "sphere.ply", "--timeout", "-1"], 2, "positive number of seconds"),
    ],
)
def test_bad_input_gives_a_message_and_a_status(built, args, status, words):
    (built.parent / "truncated.qpm").write_bytes(built.read_bytes()[:200])
    (built.parent / "garbage.ply").write_bytes(b"ply\nformat nonsense\n")
    result = qem(*args, cwd=built.parent)
    assert result.returncode == status, result.stderr
    assert words in result.stderr
    assert "Traceback" not in result.stderr
    assert not (built.parent / "x.qpm").exists() and not (built.parent / "x.ply").exists()


def test_lod_writes_through_a_symlink(built):
    """Regression: the level's file was renamed over the link, which then was a plain
    file, and the file it named kept its old content."""
    folder = built.parent
    (folder / "real.ply").write_bytes(b"old")
    link = folder / "link.ply"
    link.unlink(missing_ok=True)
    link.symlink_to("real.ply")
    result = qem("lod", "sphere.qpm", "-n", "50", "-o", "link.ply", cwd=folder)
    assert result.returncode == 0, result.stderr
    assert link.is_symlink()
    assert qem_core.load_mesh(folder / "real.ply").n_vertices == 50


def test_lod_writes_into_a_fifo(built):
    """Regression: a FIFO was replaced by a plain file, and its reader got nothing."""
    fifo = built.parent / "levels.fifo"
    fifo.unlink(missing_ok=True)
    os.mkfifo(fifo)
    received = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_bytes()))
    reader.start()
    result = qem("lod", "sphere.qpm", "-n", "50", "-o", str(fifo), "--format", "ply",
                 cwd=built.parent)
    reader.join(timeout=60)
    assert result.returncode == 0, result.stderr
    assert stat.S_ISFIFO(fifo.stat().st_mode)
    assert qem_core.load_mesh(received[0], format="ply").n_vertices == 50


def test_a_closed_pipe_ends_the_command_quietly(built):
    """Regression: ``qem lod ... -o - | head -c 1`` ended in a BrokenPipeError traceback."""
    process = subprocess.Popen(
        [sys.executable, "-m", "client.cli", "lod", "sphere.qpm", "-n", "600", "-o", "-",
         "--format", "ply"],
        cwd=built.parent,
        env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    process.stdout.close()  # gone before the level is written
    _, stderr = process.communicate(timeout=300)
    assert process.returncode == 141, stderr
    assert b"Traceback" not in stderr


def test_lod_writes_to_dev_stdout_into_a_pipe(built):
    """Regression: /dev/stdout, a link to the pipe, was resolved to a path that does not
    exist ("No such file or directory")."""
    result = subprocess.run(
        [sys.executable, "-m", "client.cli", "lod", "sphere.qpm", "-n", "50", "-o",
         "/dev/stdout", "--format", "ply"],
        cwd=built.parent,
        env={"PYTHONPATH": str(REPO), "PATH": "/usr/bin:/bin"},
        capture_output=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert qem_core.load_mesh(result.stdout, format="ply").n_vertices == 50


def test_a_loop_of_links_is_a_message(built):
    folder = built.parent
    for name, target in (("loop_a.ply", "loop_b.ply"), ("loop_b.ply", "loop_a.ply")):
        (folder / name).unlink(missing_ok=True)
        (folder / name).symlink_to(target)
    result = qem("lod", "sphere.qpm", "-n", "50", "-o", "loop_a.ply", cwd=folder)
    assert result.returncode != 0
    assert "cannot write loop_a.ply" in result.stderr and "Traceback" not in result.stderr


def test_simplify_keeps_the_texture_of_an_obj_with_its_mtl(tmp_path):
    """`qem simplify spot.obj` with `mtllib spot.mtl` and `map_Kd spot_texture.png`
    beside it: the GLB embeds the image; an OBJ output gets its .mtl and image."""
    spot = REPO / "server" / "demo" / "spot.obj"
    image = qem_core.load_mesh(spot.with_suffix(".glb")).texture
    (tmp_path / "spot_texture.png").write_bytes(image)
    (tmp_path / "spot.mtl").write_text("newmtl spot\nmap_Kd spot_texture.png\n")
    (tmp_path / "spot.obj").write_bytes(b"mtllib spot.mtl\nusemtl spot\n" + spot.read_bytes())
    for output in ("spot.glb", "small.obj"):
        result = qem("simplify", "spot.obj", "-n", "293", "-o", output, cwd=tmp_path)
        assert result.returncode == 0, result.stderr
        level = qem_core.load_mesh(tmp_path / output)
        assert level.n_vertices == 293
        assert level.texture == image
    assert (tmp_path / "small.mtl").is_file() and (tmp_path / "small_texture.png").is_file()

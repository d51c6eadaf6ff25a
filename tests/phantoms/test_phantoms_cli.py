"""Every bundled phantom through the command line: ``render``, ``show --screenshot``, ``mesh``.

Each command must run clean: exit status 0, nothing on stderr but the expected notes (at the
file-descriptor level, so VTK's and numba's messages count too), and a sound result - a finite
image in (0, I0] of the detector's shape that shows the phantom, a screenshot with both panes
drawn, a repaired mesh that is closed, outward and encloses the same volume as the file read.

The commands run in-process through :func:`xray_viz.cli.main` (the console script's entry
point; importing the package for every case would cost ~4 s each); one test runs the installed
``xray-viz`` script itself on the smallest phantom. ``mesh`` runs on the smallest mesh file of every phantom by
default and on every mesh file of every phantom with ``-m slow``.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tomllib
from pathlib import Path

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz import phantoms
from xray_viz.cli import main
from xray_viz.meshes.repair import check_mesh

NAMES = phantoms.names()

#: stderr lines a clean run may print (the one-time note before numba compiles the engine).
EXPECTED_STDERR = ("xray-viz: compiling the fast engine on first use",)


def _unexpected(err: str) -> list[str]:
    return [line for line in err.splitlines()
            if line.strip() and not line.startswith(EXPECTED_STDERR)]


def _run(capfd, argv) -> str:
    """Run ``xray-viz argv`` in-process; assert it ran clean; return its stdout."""
    capfd.readouterr()
    rc = main(argv)
    out, err = capfd.readouterr()
    assert rc == 0, f"xray-viz {' '.join(argv)}: exit {rc}\n{err}"
    assert _unexpected(err) == [], f"xray-viz {' '.join(argv)} wrote to stderr:\n{err}"
    return out


def _mesh_files():
    """``(phantom, mesh file, units)`` of every body of every phantom, from its scene TOML."""
    files = []
    for name in NAMES:
        path = phantoms.scene_path(name)
        for body in tomllib.loads(path.read_text()).get("body", []):
            files.append((name, (path.parent / body["mesh"]).resolve(), body.get("units", "mm")))
    return files


MESH_FILES = _mesh_files()
#: The default sample: the smallest mesh file of each phantom.
SMALLEST = [min((f for f in MESH_FILES if f[0] == name), key=lambda f: f[1].stat().st_size)
            for name in NAMES]


def _id(case):
    return f"{case[0]}/{case[1].name}"


def test_every_phantom_has_mesh_files_on_disk():
    assert NAMES and {f[0] for f in MESH_FILES} == set(NAMES)
    missing = [str(f[1]) for f in MESH_FILES if not f[1].is_file()]
    assert missing == []


@pytest.mark.parametrize("name", NAMES)
def test_render_every_phantom(name, tmp_path, capfd):
    out = tmp_path / "out.npy"
    text = _run(capfd, ["render", name, "-o", str(out)])
    assert f"wrote {out}" in text
    scene = xray_viz.load_scene(name)
    w, h = scene.detector.shape
    image = np.load(out)
    assert image.dtype == np.float64 and image.shape == (h, w)
    assert np.all(np.isfinite(image))
    i0 = scene.detector.i0
    if not scene.detector.noise:
        assert np.all(image > 0) and np.all(image <= i0)
    # the phantom is in view: some rays are attenuated by more than a few per cent
    assert image.min() < 0.97 * image.max()


@pytest.mark.parametrize("name", NAMES)
def test_show_screenshot_of_every_phantom(name, tmp_path, capfd):
    from PIL import Image

    out = tmp_path / "view.png"
    text = _run(capfd, ["show", name, "--screenshot", str(out), "--size", "800", "400",
                        "--resolution", "32"])
    assert "wrote" in text
    with Image.open(out) as im:
        assert im.size == (800, 400)
        rgb = np.asarray(im.convert("RGB"))
    # not blank: the 3D scene (left) and the radiograph with its charts (right) are drawn
    for pane in (rgb[:, :400], rgb[:, 400:]):
        colours = np.unique(pane.reshape(-1, 3), axis=0)
        assert len(colours) >= 20, len(colours)
        grey = pane.mean(axis=2)
        assert np.std(grey) > 10


def _check_mesh_command(capfd, tmp_path, case):
    _, src, units = case
    out = tmp_path / f"{src.stem}_fixed.stl"
    text = _run(capfd, ["mesh", str(src), "-o", str(out), "--units", units])
    assert out.is_file() and str(out) in text
    before = trimesh.load(src, force="mesh")
    after = trimesh.load(out, force="mesh")
    report = check_mesh(after)
    assert report.traceable, report.problems()
    # a bundled mesh is already traceable: repair keeps what it encloses (units unchanged)
    assert after.volume == pytest.approx(check_mesh(before).volume, rel=1e-6)
    np.testing.assert_allclose(after.bounds, before.bounds, rtol=0,
                               atol=1e-6 * np.linalg.norm(np.ptp(before.bounds, axis=0)))


@pytest.mark.parametrize("case", SMALLEST, ids=_id)
def test_mesh_command_on_a_mesh_of_every_phantom(case, tmp_path, capfd):
    _check_mesh_command(capfd, tmp_path, case)


@pytest.mark.slow
@pytest.mark.parametrize("case", MESH_FILES, ids=_id)
def test_mesh_command_on_every_mesh_file(case, tmp_path, capfd):
    _check_mesh_command(capfd, tmp_path, case)


def test_installed_script_renders_clean(tmp_path):
    """The console script itself: a fresh process, its real stderr and exit status."""
    script = Path(sys.executable).with_name("xray-viz")
    assert script.is_file(), f"no console script beside {sys.executable}"
    out = tmp_path / "wedge.npy"
    r = subprocess.run([str(script), "render", "step_wedge", "-o", str(out)],
                       capture_output=True, text=True, env=dict(os.environ), timeout=300)
    assert r.returncode == 0 and _unexpected(r.stderr) == [], r.stderr
    assert f"wrote {out}" in r.stdout
    w, h = xray_viz.load_scene("step_wedge").detector.shape
    image = np.load(out)
    assert image.shape == (h, w) and np.all(np.isfinite(image))

"""The xray-viz command line: writes what the API returns; bad input is one line, exit 2."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.cli import main
from helpers import write_scene
from tests.scene.test_scene_file import GOOD


@pytest.fixture
def scene_path(tmp_path):
    ball = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    ball.apply_translation([8.0, 5.0, 0.0])            # off centre: orientation must survive
    return write_scene(tmp_path, GOOD, {"ball.stl": ball})


@pytest.mark.parametrize("quantity,attr", [("intensity", "intensity"),
                                           ("line-integral", "line_integral"),
                                           ("path-length", "total_path_length")])
def test_cli_writes_what_the_api_returns(tmp_path, scene_path, quantity, attr):
    expected = getattr(xray_viz.render(xray_viz.load_scene(scene_path)), attr)
    out = tmp_path / "a.npy"
    assert main(["render", str(scene_path), "-o", str(out), "--quantity", quantity]) == 0
    got = np.load(out)
    assert got.dtype == np.float64 and got.shape == (24, 32)
    np.testing.assert_array_equal(got, expected)

    tiff = tmp_path / "a.tiff"
    assert main(["render", str(scene_path), "-o", str(tiff), "--quantity", quantity]) == 0
    from PIL import Image

    with Image.open(tiff) as im:
        data = np.asarray(im)
    assert data.dtype == np.float32
    np.testing.assert_array_equal(data, expected.astype(np.float32))

    png = tmp_path / "a.png"
    assert main(["render", str(scene_path), "-o", str(png), "--quantity", quantity]) == 0
    with Image.open(png) as im:
        data = np.asarray(im)
    assert data.dtype == np.uint16
    # Windowed to the data, attenuation bright.
    attenuation = -expected if quantity == "intensity" else expected
    assert data.max() == 65535 and data.min() == 0
    assert np.unravel_index(np.argmax(data), data.shape) == np.unravel_index(
        np.argmax(attenuation), data.shape)
    scaled = (attenuation - attenuation.min()) / np.ptp(attenuation) * 65535
    np.testing.assert_allclose(data, scaled, atol=0.51)


def _run(*args, env=None):
    return subprocess.run([sys.executable, "-m", "xray_viz.cli", *args], capture_output=True,
                          text=True, timeout=120, env=env)


@pytest.mark.parametrize("args,message", [
    (["render", "missing.toml", "-o", "x.png"], "no such scene file"),
    (["render", "SCENE", "-o", "x.jpg"], "unknown output format '.jpg'"),
    (["render", "BADSCENE", "-o", "x.png"], "pitch must be > 0"),
])
def test_cli_bad_input_is_one_line_and_exit_2(tmp_path, scene_path, args, message):
    bad = tmp_path / "bad.toml"
    bad.write_text(scene_path.read_text().replace("pitch = 2.0", "pitch = -2.0"))
    args = [str(scene_path) if a == "SCENE" else str(bad) if a == "BADSCENE" else
            str(tmp_path / a) if a.startswith("x.") else a for a in args]
    # an empty numba cache: the background compile starts, but its notice waits for a
    # kernel to be needed, so a refused input is still one line
    result = _run(*args, env={**os.environ, "NUMBA_CACHE_DIR": str(tmp_path / "cold")})
    assert result.returncode == 2
    assert "Traceback" not in result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and message in lines[0] and lines[0].startswith("xray-viz: error:")
    assert not list(tmp_path.glob("x.*"))                    # nothing half-written


def test_help_explains_itself():
    result = _run("--help")
    assert result.returncode == 0
    for word in ("render", "phantoms", "Moller-Trumbore", "Beer-Lambert", "examples:"):
        assert word in result.stdout
    result = _run("render", "--help")
    for word in ("--quantity", "line-integral", ".npy", ".tiff", ".png"):
        assert word in result.stdout


def test_phantoms_listed_and_default_renders(tmp_path):
    result = _run("phantoms")
    assert result.returncode == 0 and "sphere" in result.stdout
    out = tmp_path / "d.png"
    result = _run("render", "default", "-o", str(out))
    assert result.returncode == 0 and out.exists() and str(out) in result.stdout


def test_walkthrough_subcommand_lists_and_refuses_unknown():
    listed = _run("walkthrough", "--list")
    assert listed.returncode == 0, listed.stderr
    lines = listed.stdout.splitlines()
    assert len(lines) == 12 and lines[0].split()[:2] == ["1", "01_parametric_ray"]
    bad = _run("walkthrough", "99")
    assert bad.returncode == 2
    assert "no walkthrough 99" in bad.stderr and "Traceback" not in bad.stderr
    assert len(bad.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("args,message", [
    (["render"], "the following arguments are required: SCENE, -o/--output"),
    (["render", "sphere", "-o", "x.npy", "--quantity", "foo"], "invalid choice: 'foo'"),
    (["render", "sphere", "-o", "x.npy", "--supersample", "two"], "invalid int value: 'two'"),
    (["show", "sphere", "--screenshot", "x.png", "--size", "abc", "600"], "invalid int value"),
    (["frobnicate"], "invalid choice: 'frobnicate'"),
])
def test_usage_errors_are_one_line_too(tmp_path, args, message):
    result = subprocess.run([sys.executable, "-m", "xray_viz.cli", *args], capture_output=True,
                            text=True, timeout=120, cwd=tmp_path)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert message in lines[0] and "--help" in lines[0] and lines[0].startswith("xray-viz")
    assert not list(tmp_path.iterdir())                     # nothing written

"""Inputs that were tracebacks (issue 42): a document nested 100,000 deep (a gVXR JSON scene, a
TOML scene, a poses file, an image's metadata or embedded scene) and ``median = 1000`` on a
``[[ct]]`` table: one line naming the file or key, exit 2 from the CLI.

Siblings searched: every ``json.loads`` / ``tomllib.loads`` of a file a user gives
(``grep -rn "tomllib.load\\|json.load" xray_viz``): the scene (TOML, gVXR JSON, the JSON-not-TOML
hint), the overrides' re-read of a scene, the poses file, the image metadata (PNG text, TIFF
description) and the embedded scene, the kernel-compilation hint.
"""

from __future__ import annotations


import numpy as np
import pytest

from xray_viz.cli import main
from xray_viz.errors import XrayVizError

DEPTH = 100_000


def _one_line(capsys) -> str:
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in err and "RecursionError" not in err, err[-500:]
    return lines[0]


@pytest.mark.parametrize("name, text", [
    ("deep.json", '{"Source": ' + "[" * DEPTH + "]" * DEPTH + "}"),      # gVXR scene
    ("deep.toml", "a = " + "[" * DEPTH + "]" * DEPTH + "\n"),            # TOML scene
    ("deep2.toml", "[" * DEPTH + "]" * DEPTH + "\n"),                    # JSON where TOML goes
    ("inline.toml", "a = " + "{b = " * DEPTH + "1" + "}" * DEPTH + "\n"),
])
@pytest.mark.parametrize("command", [["render"], ["convert"], ["render", "--energy", "50"]])
def test_deeply_nested_scene_is_one_line(tmp_path, capsys, name, text, command):
    if command == ["convert"] and not name.endswith(".json"):
        return
    scene = tmp_path / name
    scene.write_text(text)
    out = tmp_path / ("out.toml" if command == ["convert"] else "out.png")
    assert main([command[0], str(scene), "-o", str(out), *command[1:]]) == 2
    line = _one_line(capsys)
    assert str(scene) in line and ("nested too deeply" in line or "malformed" in line
                                   or "not TOML" in line), line
    assert not out.exists()


def test_deep_poses_file_is_one_line(tmp_path):
    from xray_viz.orbit import read_poses

    poses = tmp_path / "poses.json"
    poses.write_text("[" * DEPTH + "]" * DEPTH)
    with pytest.raises(XrayVizError, match="poses file .* nested too deeply"):
        read_poses(poses)


def test_deep_image_metadata_and_embedded_scene(tmp_path):
    """An image whose metadata JSON is nested too deep is refused in one line as damaged
    (its metadata cannot be read, so the file cannot be trusted); an embedded scene nested too
    deep is refused in one line."""
    from PIL import Image, PngImagePlugin

    from xray_viz.output import ImageMetadata, OutputError, load_image

    info = PngImagePlugin.PngInfo()
    info.add_text("xray_viz", "[" * DEPTH + "]" * DEPTH)
    Image.fromarray(np.zeros((4, 4), np.uint16)).save(tmp_path / "deep.png", pnginfo=info)
    with pytest.raises(OutputError, match="metadata are damaged") as info:
        load_image(tmp_path / "deep.png", with_metadata=True)
    assert "\n" not in str(info.value)
    meta = ImageMetadata(".png", scene_toml="a = " + "[" * DEPTH + "]" * DEPTH)
    with pytest.raises(OutputError, match="embedded scene is nested too deeply"):
        meta.scene()


@pytest.fixture
def ct_file(tmp_path):
    nib = pytest.importorskip("nibabel")
    hu = np.full((12, 12, 12), -1000.0)
    hu[3:9, 3:9, 3:9] = 40.0
    path = tmp_path / "ct.nii.gz"
    nib.save(nib.Nifti1Image(hu.astype(np.int16), np.eye(4)), path)
    return path


SCENE = ('[source]\nposition = [0.0, 0.0, 1000.0]\nenergy = 60.0\n[detector]\n'
         'center = [0.0, 0.0, -500.0]\nshape = [8, 8]\npitch = [4.0, 4.0]\n')


@pytest.mark.parametrize("median", [1000, 10, 2**40])
def test_ct_median_too_large_is_one_line(tmp_path, capsys, ct_file, median):
    scene = tmp_path / "scene.toml"
    scene.write_text(SCENE + f'[[ct]]\nfile = "{ct_file.as_posix()}"\ntrace = "meshes"\n'
                     f'median = {median}\n')
    assert main(["render", str(scene), "-o", str(tmp_path / "out.npy")]) == 2
    line = _one_line(capsys)
    assert f"median = {median} is too large" in line and "[[ct]]" in line, line


def test_ct_median_api_is_bounded_too():
    from xray_viz.meshes.volumes import MAX_MEDIAN, classify_hu

    hu = np.zeros((6, 6, 6))
    assert classify_hu(hu, median=3, min_voxels=0).shape == hu.shape
    with pytest.raises(XrayVizError, match="too large"):
        classify_hu(hu, median=MAX_MEDIAN + 1)

"""The memory check counts voxel volumes (issue 40): the copy of a volume's grid in the
detector's axis order that tracing makes, and the path lengths' columns of its classes; a
volume whose tracing cannot fit is refused in one line (exit 2 from the CLI, no file)."""

from __future__ import annotations

import importlib

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import SceneError
from xray_viz.render import memory_needed

render_mod = importlib.import_module("xray_viz.render")    # (xray_viz.render is the function)

SCENE = """
[source]
position = [0.0, 0.0, 600.0]
kind = "point"
energy = 60.0

[detector]
center = [0.0, 0.0, -200.0]
up = [1.0, 0.0, 0.0]
shape = [24, 20]
pitch = 12.0

[[ct]]
file = "ct.nii.gz"
"""


def write_scene(tmp_path):
    import nibabel as nib

    hu = np.full((120, 100, 80), -1000, np.int16)
    hu[20:100, 15:85, 10:70] = 40       # soft tissue
    hu[50:70, 40:60, 20:60] = 900       # bone
    a = np.diag([1.5, 1.5, 2.0, 1.0])
    a[:3, 3] = -a[:3, :3] @ ((np.array(hu.shape) - 1) / 2)
    nib.save(nib.Nifti1Image(hu, a), tmp_path / "ct.nii.gz")
    (tmp_path / "s.toml").write_text(SCENE)
    return tmp_path / "s.toml"


def test_memory_needed_counts_the_volumes_copy_and_columns(tmp_path):
    scene = xray_viz.load_scene(write_scene(tmp_path))
    vol = scene.volumes[0]
    need = memory_needed(scene)
    # the detector's rows run along y, not the kept grid's contiguous axis (x): one copy
    assert need["volumes"] == vol.classes.nbytes + vol.weights.nbytes == 120 * 100 * 80 * 5
    assert need["total"] == sum(v for k, v in need.items() if k != "total")
    w, h = scene.detector.shape
    with_columns = memory_needed(scene, path_lengths=True)
    assert with_columns["path_lengths"] == w * h * len(vol.names) * 8
    # once traced, the copy is kept on the volume: nothing more to allocate
    xray_viz.render(scene)
    assert memory_needed(scene)["volumes"] == 0


def test_a_volume_that_cannot_fit_is_refused_in_one_line(tmp_path, monkeypatch, capsys):
    path = write_scene(tmp_path)
    scene = xray_viz.load_scene(path)
    need = memory_needed(scene)
    assert need["volumes"] > need["images"]
    # enough for everything but the volume's copy
    monkeypatch.setattr(render_mod, "available_memory", lambda: need["total"] - need["volumes"])
    with pytest.raises(SceneError) as info:
        xray_viz.render(scene)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("the voxel volume 'ct.nii.gz' need about ")
    assert "crop or downsample the CT" in msg
    from xray_viz.cli import main

    out = tmp_path / "x.png"
    assert main(["render", str(path), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "voxel volume 'ct.nii.gz'" in err[0]
    assert not out.exists()
    # with the memory it needs, it renders
    monkeypatch.setattr(render_mod, "available_memory", lambda: need["total"])
    assert xray_viz.render(scene).intensity.shape == (20, 24)

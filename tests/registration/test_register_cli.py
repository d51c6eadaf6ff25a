"""``xray-viz register`` (issue 41): a body's pose from its X-ray images, on the command line."""

from __future__ import annotations

import numpy as np
import pytest

import xray_viz
from xray_viz import registration as R
from xray_viz.cli import main

SCENE = """\
[source]
position = [0.0, 0.0, 600.0]
energy = 60.0

[detector]
center = [0.0, 0.0, -300.0]
shape = [{n}, {n}]
pitch = [{p}, {p}]

[[body]]
name = "stem"
mesh = "stem.ply"
mu = 2.0
position = [{x}, {y}, {z}]
rotation = [{rx}, {ry}, {rz}]
"""


def _write(tmp_path, name, *, n=32, p=4.8, pose=(0, 0, 0, 0, 0, 0)):
    text = SCENE.format(n=n, p=p, x=pose[0], y=pose[1], z=pose[2], rx=pose[3], ry=pose[4],
                        rz=pose[5])
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.fixture()
def files(tmp_path):
    R.demo_stem(3).export(tmp_path / "stem.ply")
    truth = _write(tmp_path, "truth.toml")
    start = _write(tmp_path, "start.toml", pose=(2.0, -1.5, 1.0, 2.0, -1.0, 1.5))
    from xray_viz.scene_options import turn_acquisition

    scene = xray_viz.load_scene(truth)
    for angle, out in ((0.0, "front.npy"), (90.0, "side.tiff")):   # as `render --angle` turns
        view = turn_acquisition(scene, angle) if angle else scene
        xray_viz.save_image(tmp_path / out, xray_viz.render(view, engine="numpy").line_integral,
                            scene=view, quantity="line-integral")
    return tmp_path, truth, start


def test_register_biplane_writes_the_fitted_scene(files, capsys):
    tmp, truth, start = files
    out = tmp / "fitted.toml"
    # the TIFF records the view it was taken with; the .npy is the scene's own view
    code = main(["register", str(start), str(tmp / "front.npy"), str(tmp / "side.tiff"),
                 "--body", "stem", "-o", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "stem: translation" in text and "mean squared difference" in text
    fitted = xray_viz.load_scene(out)
    v_fit = fitted.bodies[0].vertices
    v_true = xray_viz.load_scene(truth).bodies[0].vertices
    assert np.linalg.norm(v_fit - v_true, axis=1).mean() < 0.05     # float32 TIFF, no noise
    # the printed change is the move from the start to the truth, about the start's centroid
    from scipy.spatial.transform import Rotation

    from xray_viz.gradients import centroid

    begin = xray_viz.load_scene(start).bodies[0]
    c = centroid(begin)
    m, *_ = np.linalg.lstsq(np.c_[begin.vertices, np.ones(len(v_true))], v_true, rcond=None)
    move = np.r_[m.T @ [*c, 1.0] - c, np.degrees(Rotation.from_matrix(m[:3].T).as_rotvec())]
    line = text.split("translation [")[1]
    shown = [float(a) for a in line.split("]")[0].split(",")]
    shown += [float(a) for a in line.split("rotation [")[1].split("]")[0].split(",")]
    np.testing.assert_allclose(shown, move, atol=0.02)


def test_register_bad_input_is_one_line_exit_2(files, capsys):
    tmp, truth, start = files
    out = tmp / "fitted.toml"
    out.write_text("previous")
    small = tmp / "small.toml"
    small.write_text(start.read_text().replace("shape = [32, 32]", "shape = [16, 16]"))
    away = _write(tmp, "away.toml", pose=(600.0, 0, 0, 0, 0, 0))
    cases = [
        ([str(small), str(tmp / "front.npy"), "--body", "stem"], "does not match the detector"),
        ([str(start), str(tmp / "front.npy"), "--body", "femur"], "--body 'femur'"),
        ([str(away), str(tmp / "front.npy"), "--body", "stem"], "does not cross the beam"),
        ([str(start), str(tmp / "front.npy"), str(tmp / "front.npy"), "--body", "stem"],
         "give --angles"),
        ([str(start), str(tmp / "front.npy"), "--angles", "0", "90", "--body", "stem"],
         "one per such image"),
    ]
    for argv, message in cases:
        code = main(["register", *argv, "-o", str(out)])
        err = capsys.readouterr().err
        assert code == 2, (argv, err)
        assert message in err and len(err.strip().splitlines()) == 1, err
        assert out.read_text() == "previous"

"""The viewer's transport window (issue 38: "the viewer shows the four detector images and the
dose per body as a table when a transport exists"): ``xray-viz show SCENE --dose N``."""

from __future__ import annotations

import dataclasses
from types import SimpleNamespace

import numpy as np
import pytest

pytest.importorskip("pyvista")

import xray_viz  # noqa: E402
from xray_viz.viz.dose_view import IMAGE_TITLES, plot_transport, transport_table_text  # noqa: E402


def small_limb():
    scene = xray_viz.load_scene("limb")
    d = scene.detector
    size = np.array(d.size, float)
    shape = (12, 24)
    pitch = tuple(float(v) for v in size / (np.array(shape) - 1))
    return scene.replace(detector=dataclasses.replace(d, shape=shape, pitch=pitch))


def test_the_window_shows_the_four_images_and_the_table(tmp_path):
    scene = small_limb()
    result = xray_viz.transport(scene, 4000, seed=3)
    view = plot_transport(result, window_size=(900, 600), off_screen=True, title="limb")
    assert set(view.grids) == set(IMAGE_TITLES) == set(result.images)
    for key, grid in view.grids.items():
        drawn = np.asarray(grid.cell_data[f"{key} eV/history"]).reshape(24, 12)
        np.testing.assert_array_equal(drawn[::-1], result.images[key])   # row 0 at the top
    assert result.images["primary"].sum() > 0 and result.images["multiple"].sum() > 0
    for name in result.energy:
        assert name in view.table
    shot = view.plotter.screenshot(str(tmp_path / "t.png"))
    assert shot.std() > 10
    view.plotter.close()


def test_the_table_gives_energy_error_and_dose():
    t = SimpleNamespace(histories=10**6, energy={"skin": 734.8, "bone": 912.04},
                        energy_error={"skin": 9.81, "bone": 0.153},
                        dose={"skin": 1.234e-5, "bone": 2.5e-6},
                        dose_error={"skin": 1.6e-7, "bone": 4e-9})
    lines = transport_table_text(t).splitlines()
    assert lines[0].split()[:2] == ["body", "eV/history"] and lines[0].endswith("Gy")
    assert lines[1].split() == ["skin", "734.8", "+-", "9.8", "1.234e-05", "+-", "1.6e-07"]
    assert lines[2].split() == ["bone", "912.04", "+-", "0.15", "2.500e-06", "+-", "4.0e-09"]


def test_show_dose_bad_histories_is_one_line(tmp_path, capsys):
    from xray_viz.cli import main

    out = tmp_path / "d.png"
    assert main(["show", "limb", "--dose", "0", "--screenshot", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "histories must be > 0" in err[0] and not out.exists()

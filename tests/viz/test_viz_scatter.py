"""The viewer's primary / scatter / total / SPR views of a radiograph rendered with scatter
(issue 39), off-screen."""

import numpy as np
import pytest
import trimesh
from PIL import Image

pv = pytest.importorskip("pyvista")
pv.OFF_SCREEN = True

from xray_viz.errors import SceneError  # noqa: E402
from xray_viz.scene import Body, Detector, Scene, Source  # noqa: E402
from xray_viz.viz import Viewer  # noqa: E402

SIZE = (1200, 600)


def water_scene():
    """A water box with a bone ball, on a small detector."""
    slab = trimesh.creation.box(extents=[200, 200, 80])
    ball = trimesh.creation.icosphere(subdivisions=2, radius=30)
    det = Detector(center=[0, 0, -400], shape=(40, 32), pitch=(6.0, 6.0))
    return Scene(source=Source(position=[0, 0, 600], energy=60.0), detector=det,
                 bodies=(Body(name="water", mesh=slab, material="Water, Liquid"),
                         Body(name="bone", mesh=ball, material="Bone, Cortical (ICRP)")))


def _shown(vw):
    grid = vw.view.datasets["radiograph"]
    h, w = vw.radiograph.intensity.shape
    return grid.cell_data[grid.cell_data.keys()[0]].reshape(h, w)[::-1]


def test_scatter_views_show_the_radiographs_parts(tmp_path):
    vw = Viewer(water_scene(), resolution=40, window_size=SIZE, scatter="mc",
                histories=40_000)
    try:
        rg = vw.radiograph
        assert rg.scatter is not None and vw.quantities == ("total", "primary", "scatter", "spr")
        assert vw.view.quantity == "total"
        np.testing.assert_array_equal(_shown(vw), rg.intensity)
        shots = {}
        for q, expected in (("primary", rg.primary), ("scatter", rg.scatter),
                            ("spr", rg.spr)):
            vw.set_quantity(q)
            np.testing.assert_array_equal(_shown(vw), expected)
            assert list(vw.plotter.scalar_bars.keys()) == [vw.view.quantity_title]
            # the colours span the new image's range (window and level follow it)
            actor = vw.plotter.renderers[1].actors["radiograph"]
            assert actor.mapper.scalar_range == pytest.approx(
                (float(expected.min()), float(expected.max())))
            shots[q] = np.asarray(Image.open(vw.screenshot(tmp_path / f"{q}.png")))
        assert vw.view.quantity_title == "scatter / primary"
        assert not np.array_equal(shots["primary"], shots["scatter"])
        vw._next_quantity()                              # the k key: back to the total
        assert vw.view.quantity == "total"
        # a new acquisition renders the scatter again, and the view stays
        vw.set_quantity("spr")
        vw.set_source_distance(800.0)
        assert vw.radiograph.scatter is not None and vw.view.quantity == "spr"
        np.testing.assert_array_equal(_shown(vw), vw.radiograph.spr)
        with pytest.raises(SceneError, match="choose one of"):
            vw.set_quantity("dose")
    finally:
        vw.close()


def test_without_scatter_the_scatter_views_are_refused_in_one_line():
    vw = Viewer(water_scene(), resolution=24, window_size=SIZE)
    try:
        assert vw.quantities == ("intensity",)
        with pytest.raises(SceneError, match="scatter='mc' or 'kernel'") as info:
            vw.set_quantity("scatter")
        assert "\n" not in str(info.value)
    finally:
        vw.close()
    with pytest.raises(SceneError, match="needs histories"):
        Viewer(water_scene(), resolution=24, window_size=SIZE, scatter="mc")


SLAB_TOML = """\
[source]
position = [0, 0, 600]
energy = 60.0
[detector]
center = [0, 0, -400]
shape = [24, 24]
pitch = 8.0
[[body]]
name = "water"
mesh = "slab.stl"
material = "Water, Liquid"
"""


def test_show_command_starts_with_the_scatter_view_asked_for(tmp_path, capsys):
    from xray_viz.cli import main

    trimesh.creation.box(extents=[300, 300, 100]).export(tmp_path / "slab.stl")
    scene_file = tmp_path / "slab.toml"
    scene_file.write_text(SLAB_TOML)
    out = tmp_path / "spr.png"
    assert main(["show", str(scene_file), "--screenshot", str(out), "--size", "1200", "600",
                 "--scatter", "mc", "--histories", "30000", "--radiograph", "spr",
                 "--scatter-smoothing", "16"]) == 0
    with Image.open(out) as im:
        assert im.size == (1200, 600)
    assert "wrote" in capsys.readouterr().out
    for args, match in ((["--scatter", "mc"], "--scatter mc needs --histories"),
                        (["--radiograph", "spr"], "needs --scatter mc or kernel"),
                        (["--scatter", "mc", "--histories", "0"], "--histories must be > 0"),
                        (["--scatter-smoothing", "5"], "is for --scatter mc only")):
        assert main(["show", str(scene_file), "--screenshot", str(tmp_path / "x.png"),
                     *args]) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and match in err
        assert not (tmp_path / "x.png").exists()


def test_web_viewer_shares_the_scatter_views():
    pytest.importorskip("trame")
    from xray_viz.viz.web import WebViewer

    web = WebViewer(water_scene(), resolution=24, scatter="mc", histories=20_000,
                    scatter_smoothing=12.0)
    try:
        seen = []
        web.viewer.add_listener(lambda v: seen.append(v.view.quantity))
        web.viewer.set_quantity("spr")                # the page's view is the viewer's
        assert seen == ["spr"]
        np.testing.assert_array_equal(_shown(web.viewer), web.viewer.radiograph.spr)
        assert web.viewer.radiograph.scatter_details["smoothing_mm"] == 12.0
        web.state["rotation"] = 30.0                  # a slider of the page: a new render
        web._on_slider("rotation")
        assert web.viewer.view.quantity == "spr" and web.viewer.radiograph.scatter is not None
    finally:
        web.close()

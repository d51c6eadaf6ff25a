"""The viewer's anti-scatter grid on or off (issue 39), off-screen: the key ``a`` /
``Viewer.set_anti_scatter_grid`` renders again with the grid in front of the detector (the
scene's own, or the default one), which lowers the primary by its transmission and the SPR
more; off again gives back the first radiograph bit for bit."""

import numpy as np
import pytest
import trimesh

pv = pytest.importorskip("pyvista")
pv.OFF_SCREEN = True

from xray_viz.physics.grid import Grid  # noqa: E402
from xray_viz.scene import Body, Detector, Scene, Source  # noqa: E402
from xray_viz.viz import Viewer  # noqa: E402

SIZE = (1200, 600)


def water_scene(**detector):
    slab = trimesh.creation.box(extents=[200, 200, 80])
    ball = trimesh.creation.icosphere(subdivisions=2, radius=30)
    det = Detector(center=[0, 0, -400], shape=(40, 32), pitch=(6.0, 6.0), **detector)
    return Scene(source=Source(position=[0, 0, 600], energy=60.0), detector=det,
                 bodies=(Body(name="water", mesh=slab, material="Water, Liquid"),
                         Body(name="bone", mesh=ball, material="Bone, Cortical (ICRP)")))


def _spr(rg):
    return rg.scatter.sum() / rg.primary.sum()


def test_the_a_key_puts_the_default_grid_in_front_and_takes_it_away():
    vw = Viewer(water_scene(), resolution=40, window_size=SIZE, scatter="kernel")
    try:
        assert vw.anti_scatter_grid is False and vw.scene.detector.grid is None
        assert vw.grid == Grid()
        before = vw.radiograph
        assert "grid" not in vw.view.status
        iren = vw.plotter.iren                   # off-screen plotters may have none
        if iren is not None:
            assert iren._key_press_event_callbacks["a"]          # the key a is bound
        vw.set_anti_scatter_grid()                              # what the key a does: on
        assert vw.anti_scatter_grid is True and vw.scene.detector.grid == Grid()
        after = vw.radiograph
        assert vw.view.status.endswith(", grid 10:1")
        # the primary falls by the grid's transmission, the same over the field ...
        ratio = after.primary / before.primary
        assert 0.5 < ratio.mean() < 0.95 and ratio.std() < 0.01 * ratio.mean()
        # ... the scatter by more: the SPR drops
        assert _spr(after) < 0.6 * _spr(before)
        vw.set_quantity("spr")
        np.testing.assert_array_equal(vw.radiograph.quantity("spr"), after.spr)
        vw.set_anti_scatter_grid()                                  # off again
        assert vw.anti_scatter_grid is False and vw.scene.detector.grid is None
        np.testing.assert_array_equal(vw.radiograph.intensity, before.intensity)
        np.testing.assert_array_equal(vw.radiograph.scatter, before.scatter)
        vw.set_anti_scatter_grid(False)                             # already off: nothing
        assert vw.radiograph.scatter is not None and vw.view.quantity == "spr"
    finally:
        vw.close()


def test_a_scene_with_its_own_grid_starts_with_it_and_can_take_it_away():
    grid = {"ratio": 6, "frequency": 40}
    vw = Viewer(water_scene(grid=grid), resolution=40, window_size=SIZE, widgets=False)
    try:
        assert vw.anti_scatter_grid is True and vw.grid == Grid.of(grid)
        assert vw.scene.detector.grid == Grid.of(grid)
        with_grid = vw.radiograph.intensity
        vw.set_anti_scatter_grid(False)
        assert vw.scene.detector.grid is None
        assert np.all(vw.radiograph.intensity > with_grid)           # the grid absorbs
        vw.set_anti_scatter_grid(True)
        assert vw.scene.detector.grid == Grid.of(grid)
        np.testing.assert_array_equal(vw.radiograph.intensity, with_grid)
    finally:
        vw.close()

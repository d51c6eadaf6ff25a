"""Screenshots of the main views against tests/image_cache/ (pytest-pyvista).

The camera is pinned by SceneView.reset_camera and the window size is fixed, so an image
changes only when what is drawn changes. Regenerate with ``--reset_image_cache`` after a
deliberate change, and look at the images before committing them.
"""

import pytest

pv = pytest.importorskip("pyvista")
pv.OFF_SCREEN = True

import xray_viz  # noqa: E402
from xray_viz.viz import Viewer, plot_scene  # noqa: E402

SIZE = (1200, 600)


@pytest.fixture(autouse=True)
def _testing_theme():
    pv.set_plot_theme("testing")
    yield
    pv.set_plot_theme("default")


def test_scene_view(verify_image_cache):
    view = plot_scene(xray_viz.load_scene("sphere"), rays="grid 5", radiograph=True,
                      frustum=True, window_size=SIZE)
    view.show_pixel(200, 60)
    view.plotter.show()


def test_scene_view_texture(verify_image_cache):
    view = plot_scene(xray_viz.load_scene("sphere"), rays="row 128", radiograph=True,
                      texture=True, show_vectors=False, window_size=SIZE)
    # the "b" view: from behind the source, the ball in front of its shadow on the detector
    view.view_bodies()
    view.plotter.show()


def test_viewer_picked(verify_image_cache):
    viewer = Viewer(xray_viz.load_scene("sphere"), resolution=96, window_size=SIZE)
    viewer.set_source_distance(1100.0)
    viewer.pick_pixel(60, 30)
    viewer.plotter.show()


def test_viewer_bodies_view(verify_image_cache):
    viewer = Viewer(xray_viz.load_scene("sphere"), resolution=64, rays="row 40",
                    window_size=SIZE)
    viewer.view_bodies()
    viewer.pick_pixel(40, 20)
    viewer.plotter.show()


def test_scene_view_materials(verify_image_cache):
    # three materials (water around bone around air), each in its own colour, none of them a
    # marker's; the rays of the middle row darken inside the balls without hiding them
    view = plot_scene(xray_viz.load_scene("nested_spheres"), rays="row 128", radiograph=True,
                      window_size=SIZE)
    view.view_bodies()
    view.plotter.show()


def test_viewer_frog_bodies_view(verify_image_cache):
    # seven materials; the arrows thin, their labels in view, the rays clear of the check boxes
    viewer = Viewer(xray_viz.load_scene("frog"), resolution=64, window_size=SIZE)
    viewer.view_bodies()
    viewer.plotter.show()

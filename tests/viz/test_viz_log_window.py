"""The radiograph pane shows an intensity image as its PNG is written: on a log scale when it
spans more than LOG_WINDOW_RATIO (the chest), as before otherwise (output.png_window is the
one rule). Grey levels are measured in off-screen screenshots (Mesa / EGL) at the pixels of
the anatomy, found from the render's own path lengths per body.

The helpers (:func:`pane_points`, :func:`chest_regions`, :func:`grey_at`) are also used by
``test_web_viewer.py``, on the page's screenshot.
"""

from __future__ import annotations

import numpy as np
import pytest

pv = pytest.importorskip("pyvista")
pv.OFF_SCREEN = True

import xray_viz  # noqa: E402
from xray_viz.output import LOG_WINDOW_RATIO, png_window  # noqa: E402
from xray_viz.viz.scene_view import display_window, window_level_limits  # noqa: E402

SIZE = (1200, 600)


def pane_points(view, rows, cols) -> tuple[np.ndarray, np.ndarray]:
    """Screenshot coordinates (x from the left, y from the top) of the centres of the image
    pixels (row, column) in the radiograph pane of ``view`` (a SceneView) as drawn now."""
    pl = view.plotter
    renderer = pl.renderers[1]                      # the right subplot
    h = view.radiograph.line_integral.shape[0]
    height = pl.render_window.GetSize()[1]
    xs, ys = [], []
    for r, c in zip(np.ravel(rows), np.ravel(cols)):
        renderer.SetWorldPoint(float(c), float(h - 1 - r), 0.0, 1.0)   # see image_to_grid
        renderer.WorldToDisplay()
        x, y, _ = renderer.GetDisplayPoint()
        xs.append(x)
        ys.append(height - 1 - y)
    return np.round(xs).astype(int), np.round(ys).astype(int)


def chest_regions(radiograph) -> dict:
    """Boolean masks (H, W) of the chest's implant (more than 4 mm of titanium), the spine
    beside it (same rows and columns, no metal, the most bone), the lungs (the rays with the
    longest paths in lung) and the heart (the mediastinum: between the lungs' columns, in the
    lower half of their rows, little lung, no cortical bone), from the radiograph's path
    lengths per body."""
    names = list(radiograph.body_names)

    def path(*bodies):
        return sum(radiograph.path_length[..., names.index(b)] for b in bodies)

    metal = path("rods", "screws")
    bone = path("ct_cancellous_bone", "ct_cortical_bone")
    lung = path("ct_lung")
    implant = metal > 4.0
    rows, cols = np.nonzero(metal > 0)
    near = np.zeros_like(implant)
    near[rows.min():rows.max() + 1, cols.min() - 3:cols.max() + 4] = True
    beside = near & (metal == 0)
    spine = beside & (bone >= np.percentile(bone[beside], 75))
    lungs = lung > np.percentile(lung, 85)
    rows, cols = np.nonzero(lungs)
    middle = np.median(cols)
    left, right = np.median(cols[cols < middle]), np.median(cols[cols > middle])
    top, bottom = np.percentile(rows, 10), np.percentile(rows, 90)
    r, c = np.indices(lung.shape)
    band = (r > (top + bottom) / 2) & (r < bottom) & (c > left) & (c < right)
    heart = band & (lung < np.percentile(lung[band], 30)) \
        & (path("ct_cortical_bone") < 5.0) & (metal == 0)
    return {"implant": implant, "spine": spine, "lungs": lungs, "heart": heart}


def grey_at(shot, points) -> np.ndarray:
    """Grey levels (0 to 255, the mean of R, G, B) of a screenshot at (x, y) points."""
    x, y = points
    return np.asarray(shot, dtype=float)[y, x, :3].mean(axis=1)


def region_greys(view, shot, regions) -> dict:
    """Median grey level of each region in the pane's screenshot."""
    out = {}
    for name, mask in regions.items():
        rows, cols = np.nonzero(mask)
        out[name] = float(np.median(grey_at(shot, pane_points(view, rows, cols))))
    return out


@pytest.fixture(scope="module")
def chest_viewer():
    from xray_viz.viz import Viewer

    viewer = Viewer(xray_viz.load_scene("chest"), resolution=128, window_size=SIZE,
                    off_screen=True)
    yield viewer
    viewer.close()


def test_the_chest_pane_shows_the_implant_and_the_heart_against_the_lungs(chest_viewer, tmp_path):
    """The chest (I spans a factor ~2700): the implant is brighter than the spine beside it,
    the heart than the lungs, by a tenth and a fifth of the grey range; each pixel's grey is the PNG's
    log window's (255 (1 - ln(I / lo) / ln(hi / lo)), attenuation bright)."""
    viewer = chest_viewer
    view = viewer.view
    image = viewer.radiograph.intensity
    lo, hi, log = png_window(image, bright="low")
    assert log and hi / lo > 10 * LOG_WINDOW_RATIO
    viewer.plotter.render()
    shot = viewer.plotter.screenshot(str(tmp_path / "chest-pane.png"), return_img=True)
    regions = chest_regions(viewer.radiograph)
    for name, mask in regions.items():
        assert mask.sum() >= 10, name
    grey = region_greys(view, shot, regions)
    assert grey["implant"] > grey["spine"] + 25, grey
    assert grey["heart"] > grey["lungs"] + 50, grey
    assert view.display_window == (lo, hi, True)
    assert "log scale" in view.window_level_text
    # the picture is the log window's, pixel by pixel (the LUT's 256 levels: +-1.5)
    body = ~regions["implant"] & (image > 0)
    rows, cols = np.nonzero(body)
    expected = 255 * (1 - np.clip(np.log(image[body] / lo) / np.log(hi / lo), 0, 1))
    got = grey_at(shot, pane_points(view, rows, cols))
    assert np.median(np.abs(got - expected)) < 1.5
    # the colour bar's ticks are decades
    assert view.colorbar_labels == ["0.001", "0.01", "0.1", "1"]


def test_a_window_set_on_the_chest_is_linear_and_unset_the_log_scale_again(chest_viewer):
    viewer = chest_viewer
    viewer.set_window_level(0.2, 0.1)
    try:
        assert viewer.view.display_window == pytest.approx((0.0, 0.2, False))
        assert viewer.view.window_level_text == "W=0.2, L=0.1"
    finally:
        viewer.set_window_level()
    assert viewer.view.display_window[2]


@pytest.mark.parametrize("name", ["default", "limb", "sphere", "step_wedge"])
def test_phantoms_whose_pngs_are_linear_show_as_before(name):
    """Their intensity PNGs stay linear: the pane's window is the image's whole range, as
    before (window_level_limits), and its title says W and L."""
    scene = xray_viz.load_scene(name)
    w, h = scene.detector.shape
    n = 64
    det = scene.detector
    scene = scene.replace(detector=det.from_size(det.center, det.up,
                                                 (max(2, round(w * n / max(w, h))),
                                                  max(2, round(h * n / max(w, h)))), det.size))
    image = xray_viz.render(scene).intensity
    assert not png_window(image, bright="low")[2]
    lo, hi, log = display_window(image, bright="low")
    assert not log and (lo, hi) == window_level_limits(image)

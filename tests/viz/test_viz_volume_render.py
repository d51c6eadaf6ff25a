"""The viewer's volume rendering of a voxel volume (issue 40): the CT's HU on a grid placed by
its affine, a CT transfer function, and the switch between slices and the rendering
(off-screen)."""

from __future__ import annotations

import argparse
import dataclasses

import numpy as np
import pytest

pv = pytest.importorskip("pyvista")

from xray_viz.errors import SceneError  # noqa: E402
from xray_viz.scene import Body, Detector, Scene, Source  # noqa: E402
from xray_viz.viz.scene_view import (  # noqa: E402
    CT_OPACITY,
    VOLUME_RENDER_VOXELS,
    plot_scene,
    volume_grid,
    voxel_hu,
)
from xray_viz.volume import ct_volume  # noqa: E402


def ct(shape=(18, 14, 10)):
    """A CT on a rotated, anisotropic grid: air at one end, soft tissue, and a bone block."""
    i, j, k = np.meshgrid(*(np.arange(n, dtype=float) for n in shape), indexing="ij")
    hu = -50.0 + 7.0 * i + 3.0 * j + 11.0 * k
    hu[:2] = -1000.0
    hu[shape[0] // 2:, shape[1] // 3: 2 * shape[1] // 3, shape[2] // 3: 2 * shape[2] // 3] = 1200.0
    angle = np.radians(20.0)
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                    [0, 0, 1]])
    a = np.eye(4)
    a[:3, :3] = rot * [1.5, 2.0, 2.5]
    a[:3, 3] = -a[:3, :3] @ ((np.array(shape) - 1) / 2)
    return hu, a


@pytest.mark.parametrize("max_voxels", [VOLUME_RENDER_VOXELS, 500])
def test_the_grid_lands_on_the_voxel_centres_with_their_hu(max_voxels):
    hu, a = ct()
    vol = ct_volume(hu, a, name="ct")
    grid, matrix = volume_grid(vol, max_voxels=max_voxels)
    assert grid.n_points <= max_voxels
    step = 1 if max_voxels > hu.size else 2          # 18 x 14 x 10 = 2520 > 500 >= 9 x 7 x 5
    assert grid.dimensions == tuple(-(-np.array(hu.shape) // step))
    # every grid point, placed by the actor's matrix, is the affine's voxel centre
    pts = np.asarray(grid.points)
    placed = pts @ matrix[:3, :3].T + matrix[:3, 3]
    idx = np.stack(np.meshgrid(*(np.arange(0, n, step) for n in hu.shape), indexing="ij"),
                   axis=-1).reshape(-1, 3, order="F")          # VTK's order: i fastest
    np.testing.assert_allclose(placed, idx @ a[:3, :3].T + a[:3, 3], atol=1e-9)
    expect = voxel_hu(vol.weights, vol.classes)[tuple(idx.T)]
    np.testing.assert_array_equal(grid.point_data["hu"], expect.astype(np.float32))
    # (the CT's own HU back below 120 HU, to float32 rounding of the density)
    soft = (hu[tuple(idx.T)] < 120) & (hu[tuple(idx.T)] > -1000)
    np.testing.assert_allclose(grid.point_data["hu"][soft], hu[tuple(idx.T)][soft], atol=1e-3)


def scene_with_a_pin(shape=(40, 32, 24)):
    import trimesh

    hu, a = ct(shape)
    vol = ct_volume(hu, a, name="ct")
    pin = Body(name="pin", mesh=trimesh.creation.box(bounds=[[-3, -3, -8], [3, 3, 8]]),
               material="Ti", density=4.5)
    scene = Scene(source=Source(position=(0.0, 0.0, 400.0), energy=60.0),
                  detector=Detector(center=(0.0, 0.0, -150.0), up=(0.0, 1.0, 0.0),
                                    shape=(48, 40), pitch=2.0),
                  bodies=[pin], volumes=(vol,))
    return scene, vol


def test_the_volume_style_switches_between_slices_and_the_rendering(tmp_path):
    scene, vol = scene_with_a_pin()
    view = plot_scene(scene, rays=None, window_size=(480, 360), off_screen=True)
    slices = [f"volume:ct:slice:{a}" for a in "ijk"]
    render = "volume:ct:render"

    def actor(name):
        return view.plotter.actors[name]

    assert view.volume_style == "slices"
    assert render not in view.plotter.actors                       # drawn when asked
    slices_shot = view.plotter.screenshot(str(tmp_path / "slices.png"))
    view.set_volume_style("volume")
    assert render in view.plotter.actors
    # the rendering's data: the volume's HU, their whole range
    data = actor(render).GetMapper().GetInput()
    hu = voxel_hu(vol.weights, vol.classes)
    assert data.GetPointData().GetArray("hu").GetRange() == pytest.approx(
        (hu.min(), hu.max()))
    assert hu.min() == -1000.0 and hu.max() > 400      # the bone block (water-line HU)
    # and it spans the volume's voxel centres in the scene (its box less half a voxel)
    ends = np.array([[i, j, k] for i in (0, vol.shape[0] - 1) for j in (0, vol.shape[1] - 1)
                     for k in (0, vol.shape[2] - 1)]) @ vol.affine[:3, :3].T + vol.affine[:3, 3]
    np.testing.assert_allclose(np.reshape(actor(render).GetBounds(), (3, 2)).T,
                               [ends.min(axis=0), ends.max(axis=0)], atol=1e-4)
    # the CT transfer function: air transparent, soft tissue faint, bone opaque
    opacity = actor(render).GetProperty().GetScalarOpacity()
    assert opacity.GetValue(-1000.0) == 0.0 and opacity.GetValue(-600.0) == 0.0
    assert 0 < opacity.GetValue(40.0) < 0.01
    assert opacity.GetValue(hu.max()) > 0.5 and opacity.GetValue(1200.0) > 0.8
    assert [opacity.GetValue(x) for x, _ in CT_OPACITY] == pytest.approx(
        [y for _, y in CT_OPACITY])
    visible = {n: actor(n).GetVisibility()
               for n in slices + [render, "volume:ct:box", "body:pin"]}
    assert visible == {**dict.fromkeys(slices, False), render: True, "volume:ct:box": True,
                       "body:pin": True}
    view.plotter.render()                    # off-screen, a screenshot alone shows the last
    volume_shot = view.plotter.screenshot(str(tmp_path / "volume.png"))
    assert volume_shot.std() > 10
    assert np.abs(volume_shot.astype(float) - slices_shot).mean() > 1      # another picture
    # hiding the bodies hides the rendering; showing them again leaves the slices hidden
    view.set_visible("bodies", False)
    assert not actor(render).GetVisibility() and not actor("body:pin").GetVisibility()
    view.set_visible("bodies", True)
    assert actor(render).GetVisibility()
    assert not any(actor(n).GetVisibility() for n in slices)
    # moving the source redraws the scene but keeps the rendering's actor
    before = actor(render)
    view.scene = scene.replace(source=dataclasses.replace(scene.source,
                                                          position=(0.0, 40.0, 400.0)))
    view.draw()
    assert actor(render) is before and actor(render).GetVisibility()
    view.set_volume_style("slices")
    assert all(actor(n).GetVisibility() for n in slices)
    assert not actor(render).GetVisibility()
    # a scene without the volume: none of its actors left
    view.scene = scene.replace(volumes=())
    view.draw()
    assert not [n for n in view.plotter.actors if n.startswith("volume:")]
    assert "body:pin" in view.plotter.actors
    with pytest.raises(SceneError, match="volume style must be one of slices, volume"):
        view.set_volume_style("mip")
    view.plotter.close()


def test_show_volume_style_volume_on_the_chest(tmp_path, capsys):
    import xray_viz
    from xray_viz.viz.command import add_show_parser
    from xray_viz.viz.viewer import Viewer, help_text

    assert "x volume" in help_text(volumes=True) and "x volume" not in help_text()
    parser = argparse.ArgumentParser(prog="xray-viz")
    add_show_parser(parser.add_subparsers())
    out = tmp_path / "chest.png"
    args = parser.parse_args(["show", "chest", "--volume-style", "volume", "--view", "bodies",
                              "--screenshot", str(out), "--size", "800", "400",
                              "--resolution", "32", "--rays", "none"])
    assert args.func(args) == 0
    assert "wrote" in capsys.readouterr().out
    from PIL import Image

    with Image.open(out) as im:
        assert np.asarray(im).std() > 10
    with pytest.raises(SystemExit):                                # argparse's choices
        parser.parse_args(["show", "chest", "--volume-style", "mip"])
    # the key x switches the viewer's volumes between slices and the rendering
    viewer = Viewer(xray_viz.load_scene("chest"), resolution=32, rays=None,
                    window_size=(800, 400), off_screen=True)
    try:
        viewer.set_volume_style()
        assert viewer.view.volume_style == "volume"
        assert viewer.plotter.actors["volume:ct:render"].GetVisibility()
        viewer.set_volume_style()
        assert viewer.view.volume_style == "slices"
        assert not viewer.plotter.actors["volume:ct:render"].GetVisibility()
        assert viewer.plotter.actors["volume:ct:slice:k"].GetVisibility()
    finally:
        viewer.close()


def test_a_label_map_is_rendered_by_class_with_its_empty_voxels_transparent():
    import matplotlib

    from xray_viz.viz.scene_view import LABEL_OPACITY
    from xray_viz.volume import label_volume

    labels = np.zeros((20, 16, 12), np.int64)
    labels[3:17, 3:13, 2:10] = 5                  # soft tissue
    labels[8:12, 6:10, 4:8] = 9                   # bone inside it
    vol = label_volume(labels, np.diag([2.0, 2.0, 3.0, 1.0]),
                       {5: {"material": "Water, Liquid", "density": 1.0},
                        9: {"material": "Bone, Cortical (ICRP)", "density": 1.92}})
    scene = Scene(source=Source(position=(0.0, 0.0, 400.0), energy=60.0),
                  detector=Detector(center=(20.0, 15.0, -150.0), up=(0.0, 1.0, 0.0),
                                    shape=(32, 32), pitch=2.0),
                  bodies=[], volumes=(vol,))
    view = plot_scene(scene, rays=None, window_size=(400, 300), off_screen=True)
    view.set_volume_style("volume")
    actor = view.plotter.actors["volume:labels:render"]
    data = actor.GetMapper().GetInput().GetPointData().GetArray("class")
    assert data.GetRange() == (0.0, 2.0)                          # empty, then the two classes
    prop = actor.GetProperty()
    opacity, color = prop.GetScalarOpacity(), prop.GetRGBTransferFunction()
    assert opacity.GetValue(0.0) == 0.0
    assert opacity.GetValue(1.0) == opacity.GetValue(2.0) == LABEL_OPACITY
    tab10 = matplotlib.colormaps["tab10"]
    for k in (1, 2):                                 # the slices' colours: tab10 at k / n
        assert color.GetColor(float(k)) == pytest.approx(tab10(k / 2)[:3])
    assert prop.GetInterpolationType() == 0           # nearest: classes are not blended
    view.plotter.close()


def test_volume_style_on_a_scene_without_a_volume_is_one_line(tmp_path, capsys):
    from xray_viz.cli import main

    out = tmp_path / "never.png"
    assert main(["show", "sphere", "--volume-style", "volume", "--screenshot", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--volume-style volume: sphere has no voxel volume" in err[0]
    assert not out.exists()


def _reddish(shot: np.ndarray) -> float:
    """Fraction of the 3D pane's pixels in the CT transfer function's flesh tones (red well
    above blue): the volume rendering's; the slices are grey."""
    from tests.viz.test_web_viewer import view_region

    r, b = view_region(shot, "3d")[..., 0], view_region(shot, "3d")[..., 2]
    return float(((r - b > 40) & (r > 120)).mean())


def test_the_web_viewer_shows_the_volume_rendering_with_volume_style_volume(tmp_path):
    """``xray-viz show chest --web --volume-style volume`` in headless Chromium: the page's
    picture of the 3D scene is the CT's volume rendering beside the implant, as the viewer
    draws it off-screen in this process with the same options (the flesh-toned share of the
    3D pane within a quarter of the off-screen rendering's, and the picture nearer to it than
    to the off-screen slices); nothing leaves 127.0.0.1, no console error, Ctrl-C stops the
    server cleanly."""
    import signal

    from PIL import Image
    from tests.viz.test_web_viewer import (CHROMIUM, browser_page, non_background, view_region,
                                 wait_for_shot, web_server)

    import xray_viz
    from xray_viz.viz.viewer import Viewer

    if CHROMIUM is None:
        pytest.skip("needs Debian's chromium (installed by .ci/system-deps when root)")
    size = (1000, 500)
    with web_server("chest", "--volume-style", "volume", "--view", "bodies", "--port", "0",
                    "--resolution", "32", "--rays", "none", "--size", *map(str, size)) \
            as (proc, url):
        with browser_page(viewport=(size[0], size[1] + 200)) as page:
            errors = []
            page.on("console", lambda m: m.type == "error" and errors.append(m.text))
            page.goto(url)
            view = page.locator("#xray-viz-view")
            view.locator("img").first.wait_for(timeout=60_000)
            web = wait_for_shot(view, tmp_path, "web-volume",
                                lambda shot: non_background(view_region(shot, "3d")) > 0.02)
            remote = list(page.remote)
            # stopped with the page open: the server closes the connection (closing the tab
            # first races an RPC answer on its way, which wslink logs with a traceback)
            proc.send_signal(signal.SIGINT)
            out, err = proc.communicate(timeout=60)
    assert proc.returncode == 0, err[-3000:]
    assert "stopped" in out and "Traceback" not in err, (out[-1000:], err[-3000:])
    assert not remote and not errors, (remote, errors)
    local = {}
    viewer = Viewer(xray_viz.load_scene("chest"), resolution=32, rays=None, window_size=size,
                    off_screen=True)
    try:
        viewer.view_bodies()
        for style in ("slices", "volume"):
            viewer.set_volume_style(style)
            viewer.plotter.render()
            pixels = viewer.plotter.screenshot(None, return_img=True)
            image = Image.fromarray(pixels).convert("RGB").resize(web.shape[1::-1],
                                                                  Image.BILINEAR)
            local[style] = np.asarray(image, dtype=float)
    finally:
        viewer.close()
    assert _reddish(local["slices"]) < 0.01 < 0.03 < _reddish(local["volume"])
    assert _reddish(web) == pytest.approx(_reddish(local["volume"]), rel=0.25)

    def distance(a, b):
        return np.abs(view_region(a, "3d") - view_region(b, "3d")).mean()

    assert distance(web, local["volume"]) < 0.75 * distance(web, local["slices"])

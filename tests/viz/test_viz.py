"""What the viewer draws is what the geometry and the tracer computed; widgets update it."""

import argparse

import numpy as np
import pytest
import trimesh

pv = pytest.importorskip("pyvista")
pv.OFF_SCREEN = True

import xray_viz  # noqa: E402
from xray_viz.errors import OutputError, SceneFileNotFoundError, XrayVizError  # noqa: E402
from xray_viz.geometry import detector_rays, viewport  # noqa: E402
from xray_viz.scene import Body, Detector, Scene, Source  # noqa: E402
from xray_viz.tracing import trace_rays  # noqa: E402
from xray_viz.viz import Viewer, plot_scene, select_pixels  # noqa: E402
from xray_viz.viz.command import add_show_parser  # noqa: E402
from xray_viz.viz.rays import attenuation_profile, inside_segments, pixel_ray_index  # noqa: E402

SIZE = (1200, 600)


def small_scene(*, shape=(48, 40), mesh=None, position=(0.0, 0.0, 1000.0)):
    """The sphere phantom's ball on a small detector (fast)."""
    base = xray_viz.load_scene("sphere")
    ball = base.bodies[0] if mesh is None else Body(name="thing", mesh=mesh, mu=0.2)
    det = Detector.from_size([0, 0, -500], [0, 1, 0], shape, base.detector.size)
    return Scene(source=Source(position=position, energy=60.0), detector=det, bodies=(ball,))


@pytest.fixture
def view():
    v = plot_scene(small_scene(), rays="every 8", radiograph=True, window_size=SIZE)
    yield v
    v.plotter.close()


def test_ray_segments_end_at_the_tracers_hit_points(view):
    scene = view.scene
    i, j = select_pixels(scene.detector.shape, "every 8")
    rays = detector_rays(scene)
    k = (scene.detector.shape[1] - 1 - j) * scene.detector.shape[0] + i
    hits = trace_rays(scene, rays.origins[k], rays.directions[k], t_min=0.0, t_max=rays.t_max[k])
    assert len(hits) > 0 and hits.entering.sum() == (~hits.entering).sum()
    inside = view.datasets["rays-inside"].points.reshape(-1, 2, 3)
    starts, ends, _ = inside_segments(hits)
    np.testing.assert_allclose(inside[:, 0], starts, atol=1e-4)     # float32 points
    np.testing.assert_allclose(inside[:, 1], ends, atol=1e-4)
    np.testing.assert_allclose(view.datasets["hits-entry"].bounds,
                               pv.PolyData(hits.point[hits.entering]).bounds, atol=0.1 * view.size_scale + 1e-3)
    # the full rays run from the source to their pixels on the detector
    full = view.datasets["rays"].points.reshape(-1, 2, 3)
    np.testing.assert_allclose(full[:, 0], np.broadcast_to(scene.source.position, full[:, 0].shape),
                               atol=1e-3)
    np.testing.assert_allclose(full[:, 1], rays.ends[k], atol=1e-3)


def test_grid_points_are_the_pixel_positions(view):
    scene = view.scene
    vp = viewport(scene.source.position, scene.detector)
    w, h = scene.detector.shape
    ii, jj = view.grid_ij
    assert ii[0] == 0 and ii[-1] == w - 1 and jj[0] == 0 and jj[-1] == h - 1
    expected = (vp.LHC + (ii[:, None, None] / (w - 1)) * vp.HO
                + (jj[None, :, None] / (h - 1)) * vp.VE)
    pts = view.datasets["grid"].points
    np.testing.assert_allclose(pts, expected.reshape(-1, 3, order="F"), atol=1e-3)


def test_large_detector_grid_is_subsampled_and_says_so():
    v = plot_scene(xray_viz.load_scene("sphere"), rays=None, window_size=SIZE)
    assert len(v.grid_ij[0]) <= 33 and "of 256 x 256" in v.grid_label
    v.plotter.close()


def test_radiograph_subplot_has_row_0_at_the_top():
    # a ball moved right (+HO) and up (+VE): its shadow is in the right columns, top rows
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=15.0)
    mesh.apply_translation([25.0, 25.0, 0.0])
    scene = small_scene(mesh=mesh)
    v = plot_scene(scene, rays=None, radiograph=True, quantity="path-length", window_size=SIZE)
    img = v.radiograph.total_path_length
    h, w = img.shape
    rows, cols = np.nonzero(img > 0)
    assert cols.mean() > w / 2 and rows.mean() < h / 2
    grid = v.datasets["radiograph"]
    values = grid.cell_data[grid.cell_data.keys()[0]].reshape(h, w)   # y (= j) then x (= i)
    np.testing.assert_array_equal(values, img[::-1])                   # cell (i, j) = img[H-1-j, i]
    v.plotter.close()


@pytest.fixture
def viewer():
    vw = Viewer(small_scene(), resolution=48, window_size=SIZE)
    yield vw
    vw.close()


def test_picking_pixel_selects_its_ray(viewer):
    w, h = viewer.scene.detector.shape
    viewer.on_pick((30.2, 10.9, 0.0))                 # a click in the radiograph subplot
    assert viewer.picked_pixel == (30, 11)
    sel = viewer.view.picked
    assert sel.index[0] == pixel_ray_index((w, h), 30, 11) == (h - 1 - 11) * w + 30
    vp = viewport(viewer.scene.source.position, viewer.scene.detector)
    np.testing.assert_allclose(sel.ends[0], vp.point(30 / (w - 1), 11 / (h - 1)), atol=1e-9)
    line = viewer.view.datasets["picked-ray"].points
    np.testing.assert_allclose(line[1], sel.ends[0], atol=1e-3)
    # the chart's line integral is the image's
    assert viewer.profile.line_integral == pytest.approx(
        viewer.radiograph.line_integral[h - 1 - 11, 30], rel=1e-9, abs=1e-12)


def test_profile_steps_match_the_path_length(viewer):
    w, h = viewer.scene.detector.shape
    prof = viewer.pick_pixel(w // 2, h // 2)
    x, y = prof.steps()
    assert len(x) == len(y) and np.all(np.diff(x) >= 0)
    inside = np.sum(np.diff(prof.t)[prof.body >= 0])
    assert inside == pytest.approx(viewer.radiograph.path_length[h - 1 - h // 2, w // 2, 0])


def test_source_slider_changes_magnification_as_predicted(viewer):
    r, pitch = 40.0, viewer.scene.detector.pitch[0]
    for distance in (1500.0, 900.0):
        viewer.set_source_distance(distance)
        np.testing.assert_allclose(viewer.scene.source.position, [0, 0, distance - 500])
        sod = distance - 500.0                          # source to the ball's centre
        predicted = 2 * distance * r / np.sqrt(sod**2 - r**2)   # tangent cone on the detector
        L = viewer.radiograph.path_length[:, :, 0]
        h = L.shape[0]
        width = np.count_nonzero(L[h // 2] > 0) * pitch
        if predicted < viewer.scene.detector.size[0]:
            assert abs(width - predicted) <= 2 * pitch
        # the source marker moved with it
        src = viewer.view.datasets["source"]
        np.testing.assert_allclose(src.center, viewer.scene.source.position, atol=1e-3)


def test_rotation_energy_resolution_and_toggles():
    box = trimesh.creation.box(extents=(60.0, 20.0, 20.0))
    vw = Viewer(small_scene(mesh=box), resolution=48, window_size=SIZE)
    pitch = vw.scene.detector.pitch[0]
    L = vw.radiograph.path_length[:, :, 0]
    wide = np.count_nonzero(L[L.shape[0] // 2] > 0) * pitch
    vw.set_body_rotation(90)
    L = vw.radiograph.path_length[:, :, 0]
    narrow = np.count_nonzero(L[L.shape[0] // 2] > 0) * pitch
    assert wide == pytest.approx(60 * 1.5, abs=3 * pitch)
    assert narrow == pytest.approx(20 * 1.5, abs=3 * pitch)
    turned = vw.scene.bodies[0].mesh
    vw.set_energy(80)
    assert vw.scene.source.energy == 80
    assert vw.scene.bodies[0].mesh is turned            # still turned, not turned again
    L = vw.radiograph.path_length[:, :, 0]
    assert np.count_nonzero(L[L.shape[0] // 2] > 0) * pitch == pytest.approx(narrow)
    vw.set_resolution(24)
    assert max(vw.scene.detector.shape) == 24 and vw.radiograph.intensity.shape[1] == 24
    assert vw.scene.detector.size == pytest.approx(vw.base_scene.detector.size)
    for group in ("rays", "grid", "hits", "vectors"):
        vw.toggle(group)
        names = {"rays": "rays", "grid": "grid", "hits": "hits-entry", "vectors": "vec:HO"}
        assert not vw.plotter.actors[names[group]].GetVisibility()
        vw.toggle(group)
        assert vw.plotter.actors[names[group]].GetVisibility()
    vw.close()


def test_show_command_screenshot(tmp_path, capsys):
    parser = argparse.ArgumentParser(prog="xray-viz")
    add_show_parser(parser.add_subparsers())
    out = tmp_path / "view.png"
    args = parser.parse_args(["show", "sphere", "--screenshot", str(out), "--size", "1200", "600",
                              "--resolution", "64"])
    assert args.func(args) == 0
    from PIL import Image

    with Image.open(out) as im:
        assert im.size == (1200, 600)
    out_text = capsys.readouterr().out
    assert "wrote" in out_text and "64x64 radiograph right" in out_text     # the preview's
    for argv, err in ((["show", "sphere", "--screenshot", str(tmp_path / "a.gif")], OutputError),
                      (["show", "nosuch", "--screenshot", str(out)], SceneFileNotFoundError),
                      (["show", "sphere", "--screenshot", str(out), "--size", "10", "10"],
                       OutputError),
                      (["show", "sphere", "--screenshot", str(out), "--rays", "most"],
                       XrayVizError)):
        args = parser.parse_args(argv)
        with pytest.raises(err):
            args.func(args)


def test_show_command_view_bodies_starts_with_the_close_up(tmp_path):
    from PIL import Image

    parser = argparse.ArgumentParser(prog="xray-viz")
    add_show_parser(parser.add_subparsers())
    left = {}
    for view in ("side", "bodies"):
        out = tmp_path / f"{view}.png"
        args = parser.parse_args(["show", "sphere", "--screenshot", str(out), "--size", "800",
                                  "400", "--resolution", "32", "--view", view])
        assert args.func(args) == 0
        with Image.open(out) as im:
            left[view] = np.asarray(im.convert("L"), dtype=float)[:, :400]
    # the close-up fills far more of the 3D pane with the (blue-grey) sphere than the side view
    changed = np.mean(np.abs(left["side"] - left["bodies"]) > 30)
    assert changed > 0.05
    with pytest.raises(SystemExit):
        parser.parse_args(["show", "sphere", "--view", "top"])


def test_attenuation_profile_of_nested_bodies_uses_the_inner_material():
    outer = trimesh.creation.icosphere(subdivisions=2, radius=30.0)
    inner = trimesh.creation.icosphere(subdivisions=2, radius=10.0)
    scene = Scene(source=Source(position=[0, 0, 1000.0]),
                  detector=Detector(center=[0, 0, -500], shape=(5, 5), pitch=1.0),
                  bodies=(Body("outer", outer, mu=0.1), Body("inner", inner, mu=1.0)))
    hits = trace_rays(scene, [0, 0, 1000.0], [[0, 0, -1.0]])
    prof = attenuation_profile(scene, hits, 1500.0)
    assert prof.mu.tolist() == [0.0, 0.1, 1.0, 0.1, 0.0]
    assert prof.body.tolist() == [-1, 0, 1, 0, -1]


# --------------------------------------------------------------------------------------------
# window/level, spectra, sizes, palette, camera, colour bar, labels


def _slider_moved(widget, value):
    """Move a slider widget's knob as the mouse does: its value, then the end event."""
    from vtkmodules.vtkCommonCore import vtkCommand

    widget.GetRepresentation().SetValue(value)
    widget.InvokeEvent(vtkCommand.EndInteractionEvent)


def _pane(plotter, loc):
    """The actors of one subplot (``plotter.actors`` are those of the current one)."""
    return plotter.renderers[plotter.renderers.loc_to_index(loc)].actors


def test_window_level_sliders_set_the_image_range_and_the_text(viewer):
    image = viewer.radiograph.intensity
    actor = _pane(viewer.plotter, (0, 1))["radiograph"]
    title = _pane(viewer.plotter, (0, 1))["radiograph-title"]
    lo, hi = float(image.min()), float(image.max())
    assert actor.mapper.scalar_range == pytest.approx((lo, hi))        # default: image range
    assert f"W={hi - lo:.3g}, L={(hi + lo) / 2:.3g} (image range)" in title.GetInput()
    assert viewer.sliders["window"].GetRepresentation().GetValue() == pytest.approx(hi - lo)
    _slider_moved(viewer.sliders["window"], 0.2)
    _slider_moved(viewer.sliders["level"], 0.7)
    actor = _pane(viewer.plotter, (0, 1))["radiograph"]
    assert actor.mapper.scalar_range == pytest.approx((0.6, 0.8))
    text = _pane(viewer.plotter, (0, 1))["radiograph-title"].GetInput()
    assert "W=0.2, L=0.7" in text and "image range" not in text
    assert viewer.view.colorbar_labels == ["0.60", "0.65", "0.70", "0.75", "0.80"]
    # kept while the source moves and the image is rendered again
    viewer.set_source_distance(1200.0)
    assert _pane(viewer.plotter, (0, 1))["radiograph"].mapper.scalar_range == pytest.approx(
        (0.6, 0.8))
    assert viewer.sliders["level"].GetRepresentation().GetValue() == pytest.approx(0.7)
    viewer.set_window_level()                                           # back to the range
    image = viewer.radiograph.intensity
    assert _pane(viewer.plotter, (0, 1))["radiograph"].mapper.scalar_range == pytest.approx(
        (float(image.min()), float(image.max())))
    with pytest.raises(ValueError):
        viewer.set_window(0.0)


def test_pick_chart_of_a_spectrum_scene_names_its_energy_and_the_images_meaning():
    pytest.importorskip("spekpy")
    from xray_viz.physics.spectra import source_spectrum

    base = xray_viz.load_scene("nested_spheres")
    det = Detector.from_size([0, 0, -500], [0, 1, 0], (40, 40), base.detector.size)
    scene = base.replace(source=Source(position=[0.0, 0.0, 1000.0], spectrum={"kvp": 80.0}),
                         detector=det)
    vw = Viewer(scene, resolution=40, window_size=SIZE)
    try:
        spectrum = source_spectrum(vw.scene.source)
        prof = vw.pick_pixel(20, 20)                       # through water, bone and air
        image_li = float(vw.radiograph.line_integral[40 - 1 - 20, 20])
        title = vw.chart.title
        # mu at the ray's effective energy: its integral is the image's -ln(I / I0) ...
        assert spectrum.energies[0] < prof.energy < spectrum.energies[-1]
        assert f"E_eff = {prof.energy:.1f} keV" in title and "80 kVp" in title
        assert prof.line_integral == pytest.approx(image_li, rel=1e-6)
        assert "-ln(I/I0) of the whole spectrum" in title
        assert f"{prof.energy:.3g} keV" in vw.chart.y_label
        # ... while the mean energy's differs (beam hardening), and the title says by how much
        at_mean = attenuation_profile(vw.scene, vw.view.picked.hits,
                                      float(vw.view.picked.t_max[0]),
                                      energy=spectrum.mean_energy)
        assert abs(at_mean.line_integral - image_li) > 0.05 * image_li
        assert f"mean {spectrum.mean_energy:.1f} keV gives {at_mean.line_integral:.4g}" in title
        # a ray that misses the bodies: mu at the mean energy, said so
        prof = vw.pick_pixel(0, 0)
        assert prof.energy == pytest.approx(spectrum.mean_energy)
        assert "mu at the mean" in vw.chart.title and prof.line_integral == 0
    finally:
        vw.close()


def test_monochromatic_pick_chart_names_its_energy(viewer):
    viewer.pick_pixel(24, 20)
    assert viewer.chart.title.startswith("pixel (24, 20) at 60 keV: integral mu dt = ")
    assert viewer.profile.energy == 60.0


def test_show_command_rejects_huge_sizes_in_one_line(tmp_path, capsys):
    from xray_viz.cli import main

    out = tmp_path / "big.png"
    assert main(["show", "sphere", "--screenshot", str(out), "--size", "100000",
                 "100000"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "100000" in err and "8192" in err, err
    assert "Traceback" not in err and not out.exists()
    parser = argparse.ArgumentParser(prog="xray-viz")
    add_show_parser(parser.add_subparsers())
    args = parser.parse_args(["show", "sphere", "--screenshot", str(out), "--size", "1400",
                              "9000"])
    with pytest.raises(OutputError, match="9000"):
        args.func(args)


def test_material_colours_are_not_marker_colours():
    from matplotlib.colors import to_rgb

    from xray_viz.viz.scene_view import COLORS, PALETTE

    view = plot_scene(xray_viz.load_scene("nested_spheres"), rays="center", window_size=SIZE)
    try:
        used = list(view.material_colors.values())
    finally:
        view.plotter.close()
    assert len(set(used)) == 3
    markers = [COLORS[k] for k in ("source", "ray", "inside", "entry", "exit", "picked", "HO",
                                   "VE", "FL", "LHC")]
    for colour in PALETTE:
        for marker in markers:
            distance = np.linalg.norm(np.subtract(to_rgb(colour), to_rgb(marker)))
            assert distance > 0.2, (colour, marker)           # not the same colour


def _box_fraction(view, points):
    xy = view._world_to_box(points)
    bx0, by0, bx1, by1 = view.view_box
    return np.mean((xy[:, 0] >= bx0) & (xy[:, 0] <= bx1) & (xy[:, 1] >= by0)
                   & (xy[:, 1] <= by1))


def test_side_view_shows_the_detector_face_and_frames_the_whole_set_up():
    view = plot_scene(xray_viz.load_scene("nested_spheres"), rays="grid 3", window_size=SIZE)
    try:
        vp = viewport(view.scene.source.position, view.scene.detector)
        corners = np.array([vp.LHC, vp.LHC + vp.HO, vp.LHC + vp.HO + vp.VE, vp.LHC + vp.VE])
        lo, hi = view.bodies_bounds
        points = np.vstack([corners, vp.r0[None], lo[None], hi[None]])
        assert _box_fraction(view, points) == 1.0                  # everything in view
        xy = view._world_to_box(points)
        bx0, by0, bx1, by1 = view.view_box
        span = np.ptp(xy, axis=0) / [bx1 - bx0, by1 - by0]
        assert span.max() > 0.9                                    # ... and filling the box
        # the detector is seen face on enough that its pixel grid shows: the projected
        # parallelogram is well over a sliver (edge on, its area was ~0)
        c = view._world_to_box(corners) * view.plotter.window_size / [2, 1]   # pixels
        d1, d2 = c[2] - c[0], c[3] - c[1]
        area = 0.5 * abs(d1[0] * d2[1] - d1[1] * d2[0])
        w, h = np.ptp(c, axis=0)
        assert area > 0.4 * w * h and min(w, h) > 30
        # all the labels of the arrows are in the pane
        labels = np.array(list(view.vector_label_points.values()))
        assert _box_fraction(view, labels) == 1.0
    finally:
        view.plotter.close()


def test_bodies_view_keeps_the_arrow_labels_in_view_and_thin_shafts():
    vw = Viewer(xray_viz.load_scene("sphere"), resolution=48, window_size=SIZE)
    try:
        vw.view_bodies()
        xy = vw.view._world_to_box(np.array(list(vw.view.vector_label_points.values())[:4]))
        assert np.all((xy > 0) & (xy < 1)), xy                  # HO, VE, FL, LHC labels
        # the shafts are lines of ARROW_WIDTH pixels, the tips sized by the detector
        from xray_viz.viz.scene_view import ARROW_WIDTH

        fl = vw.view.datasets["vec:FL"]
        assert fl.n_lines == 1
        assert vw.plotter.actors["vec:FL"].GetProperty().GetLineWidth() == ARROW_WIDTH
        det = min(vw.scene.detector.size)
        tips = {k: vw.view.datasets[f"vec:{k}"] for k in ("HO", "FL")}
        sizes = [np.ptp(t.extract_cells(range(1, t.n_cells)).points, axis=0).max()
                 for t in tips.values()]
        assert sizes == pytest.approx([0.1 * det] * 2, rel=0.05)   # the same on HO and FL
    finally:
        vw.close()


def test_colour_bar_has_round_ticks_and_legible_corner_labels(view):
    from xray_viz.viz.scene_view import CORNER_FONT

    bar = view.plotter.scalar_bars["I / I0"]
    assert bar.GetUseCustomLabels() and bar.GetVerticalTitleSeparation() > 0
    labels = view.colorbar_labels
    assert 3 <= len(labels) <= 7
    assert all(len(x.split(".")[-1]) <= 2 for x in labels), labels
    steps = np.diff([float(x) for x in labels])
    assert np.allclose(steps, steps[0])
    for name in ("radiograph-corner-00", "radiograph-corner-wh"):
        prop = _pane(view.plotter, (0, 1))[name].GetTextProperty()
        assert prop.GetFontSize() == CORNER_FONT >= 12


def test_vector_labels_toggle_with_the_arrows(view):
    view.set_visible("vectors", False)
    assert not view.plotter.actors["vec-labels-labels"].GetVisibility()
    view.set_visible("vectors", True)
    assert view.plotter.actors["vec-labels-labels"].GetVisibility()


# --------------------------------------------------------------------------------------------
# I0 != 1, preview resolution, grid steps


def photon_scene(*, shape=(48, 40), i0=1000.0):
    """:func:`small_scene`'s ball made of water, ``[detector] I0 = i0`` photons per pixel and
    fall-off."""
    scene = small_scene(shape=shape)
    det = Detector.from_size([0, 0, -500], [0, 1, 0], shape, scene.detector.size, i0=i0,
                             falloff=True)
    ball = Body(name="ball", mesh=scene.bodies[0].mesh, material="Water, Liquid")
    return scene.replace(detector=det, bodies=(ball,))


def test_photon_image_is_labelled_in_photons_and_the_sliders_cover_it():
    from xray_viz.viz.viewer import window_level_ranges

    vw = Viewer(photon_scene(), resolution=48, window_size=SIZE)
    try:
        image = vw.radiograph.intensity
        lo, hi = float(image.min()), float(image.max())
        assert hi > 500                                        # photons, not I / I0
        # the colour bar says what it shows: I in photons, with ticks across the image's range
        assert list(vw.plotter.scalar_bars.keys()) == ["I (photons)"]
        ticks = [float(t) for t in vw.view.colorbar_labels]
        assert lo <= ticks[0] and ticks[-1] <= hi and ticks[-1] - ticks[0] > 0.5 * (hi - lo)
        reps = {k: vw.sliders[k].GetRepresentation() for k in ("window", "level")}
        assert "photons" in reps["window"].GetTitleText()
        assert "photons" in reps["level"].GetTitleText()
        # the level slider spans the image, the window slider from narrow to wider than it,
        # and the knobs (the image range by default) sit inside, not pinned at an end
        r = vw.slider_ranges
        assert r["level"] == pytest.approx((lo, hi))
        assert r["window"][0] < 0.05 * (hi - lo) and r["window"][1] >= hi - lo
        assert r["window"][0] < reps["window"].GetValue() < r["window"][1]
        assert r["level"][0] < reps["level"].GetValue() < r["level"][1]
        _slider_moved(vw.sliders["window"], 200.0)
        _slider_moved(vw.sliders["level"], 700.0)
        actor = _pane(vw.plotter, (0, 1))["radiograph"]
        assert actor.mapper.scalar_range == pytest.approx((600.0, 800.0))
        # a re-render that changes the image's range moves the sliders' ranges with it
        vw.set_energy(25.0)
        image = vw.radiograph.intensity
        assert float(image.min()) < 0.5 * lo
        w_rng, l_rng, _ = window_level_ranges(image)
        assert vw.slider_ranges["level"] == pytest.approx(l_rng)
        assert vw.slider_ranges["window"] == pytest.approx(w_rng)
        assert reps["level"].GetValue() == pytest.approx(700.0)       # the window/level kept
    finally:
        vw.close()


def test_unit_i0_keeps_the_transmitted_fraction():
    vw = Viewer(photon_scene(i0=1.0), resolution=48, window_size=SIZE)
    try:
        assert list(vw.plotter.scalar_bars.keys()) == ["I / I0"]
        assert "(I / I0)" in vw.sliders["window"].GetRepresentation().GetTitleText()
    finally:
        vw.close()


def test_show_command_caps_the_preview_resolution(tmp_path, capsys):
    from xray_viz.cli import main

    out = tmp_path / "big.png"
    assert main(["show", "sphere", "--screenshot", str(out), "--resolution", "5000"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "5000" in err and "2048" in err, err
    assert "Traceback" not in err and not out.exists()


def test_grid_label_gives_both_steps_when_they_differ():
    v = plot_scene(small_scene(shape=(192, 384)), rays=None, window_size=SIZE)
    try:
        ii, jj = v.grid_ij
        assert (ii[1] - ii[0], jj[1] - jj[0]) == (6, 12)
        assert v.grid_label == ("pixel grid: 33 x 33 of 192 x 384 rays drawn "
                                "(column step 6, row step 12)")
    finally:
        v.plotter.close()
    v = plot_scene(small_scene(shape=(256, 256)), rays=None, window_size=SIZE)
    assert v.grid_label.endswith("(step 8)")
    v.plotter.close()

"""The scene view's camera framing (xray_viz.viz.camera), tested against geometry, without VTK.

Every framing is checked by projecting points (Framing.project, itself checked against VTK's
own camera at the end): what is framed is in front of the camera and inside the box with the
margin asked for, tight and centred; the views look where they say (along the beam, across
it, from above), mirror-symmetric set-ups give mirror-symmetric cameras, rotating everything
rotates the camera, and zoom scales what it should.
"""

from __future__ import annotations

import math
import subprocess
import sys

import numpy as np
import pytest

from tests.project.test_architecture import MODULES, THIRD_PARTY, _reaches
from xray_viz.geometry import viewport
from xray_viz.scene import Detector
from xray_viz.viz import camera
from xray_viz.viz.camera import (FULL_PANE, SIDE_VIEW_BOX, Framing, bodies_view, box_corners,
                                 frame, image_view, label_fraction, side_points, side_view,
                                 view_axes)

HEAVY = {"vtk", "vtkmodules", "pyvista"}


# ------------------------------------------------------------------------------ no VTK
@pytest.mark.parametrize("module", ["xray_viz.viz.camera", "xray_viz.viz.style"])
def test_camera_and_style_import_no_vtk(module):
    """The framing maths (and the style constants) reach no VTK or PyVista import."""
    reached = {module} | _reaches(module)
    heavy = {p for m in reached for p in THIRD_PARTY[m]} & HEAVY
    assert not heavy, f"{module} reaches {sorted(heavy)}"


def test_the_import_check_sees_pyvista_where_it_is():
    """The check above can fail: it finds PyVista in the shapes and the scene view."""
    for module in ("xray_viz.viz.shapes", "xray_viz.viz.scene_view"):
        assert "pyvista" in {p for m in {module} | _reaches(module) for p in THIRD_PARTY[m]}


def test_camera_runs_with_vtk_absent():
    """Loaded on its own in a fresh interpreter (not through ``xray_viz.viz``, whose
    ``__init__`` imports the scene view), the module frames a scene and loads no VTK."""
    code = f"""
import importlib.util, sys
sys.modules["vtk"] = sys.modules["vtkmodules"] = sys.modules["pyvista"] = None   # unimportable
import numpy as np
from xray_viz.geometry import viewport
from xray_viz.scene import Detector
spec = importlib.util.spec_from_file_location("camera_alone", {str(MODULES['xray_viz.viz.camera'])!r})
cam = sys.modules["camera_alone"] = importlib.util.module_from_spec(spec)
spec.loader.exec_module(cam)
vp = viewport([0, 0, 1000.0], Detector(center=[0, 0, -500.0], up=[0, 1, 0], shape=(8, 8), pitch=2.0))
f = cam.side_view(vp, (np.full(3, -40.0), np.full(3, 40.0)), aspect=1.5)
assert np.all(np.isfinite(f.position))
print("ok", sorted(k for k in sys.modules if k.startswith(("vtk", "pyvista")) and sys.modules[k] is not None))
"""
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["ok", "[]"]


# ------------------------------------------------------------------------------ helpers
def _setup(source=(0.0, 0.0, 1000.0), center=(0.0, 0.0, -500.0), up=(0.0, 1.0, 0.0),
           shape=(64, 48), pitch=4.0, lo=(-40.0, -30.0, -50.0), hi=(40.0, 30.0, 50.0)):
    det = Detector(center=list(center), up=list(up), shape=shape, pitch=pitch)
    return viewport(list(source), det), (np.asarray(lo, float), np.asarray(hi, float))


def _box_coords(f: Framing, points, aspect):
    """Points' offsets from the centre of the framed box over its half-size (u across, v up)."""
    xy = f.project(points, aspect=aspect)
    bx0, by0, bx1, by1 = f.box
    u = (xy[:, 0] - (bx0 + bx1) / 2) / ((bx1 - bx0) / 2)
    v = (xy[:, 1] - (by0 + by1) / 2) / ((by1 - by0) / 2)
    return u, v


def _depths(f: Framing, points):
    return (np.asarray(points, float) - f.position) @ f.direction


def _assert_framed(f, points, aspect, margin, *, tol=1e-9):
    """In front, inside the box shrunk by margin, touching it, centred."""
    assert np.all(_depths(f, points) > 0)
    u, v = _box_coords(f, points, aspect)
    reach = max(np.abs(u).max(), np.abs(v).max())
    assert reach <= 1 / margin + tol
    assert reach == pytest.approx(1 / margin, rel=1e-6)            # tight
    assert (u.max() + u.min()) / 2 == pytest.approx(0, abs=1e-4)    # centred across
    assert (v.max() + v.min()) / 2 == pytest.approx(0, abs=1e-4)    # and up


def _random_rotation(rng, *, reflect=False):
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    if reflect:
        q = q @ np.diag([-1.0, 1.0, 1.0])
    return q


# ------------------------------------------------------------------------------ frame
CLOUDS = {
    "cube": box_corners([-1, -1, -1], [1, 1, 1]),
    "slab": box_corners([-300, -20, -5], [300, 20, 5]),
    "random": np.random.default_rng(3).normal(size=(40, 3)) * [50, 10, 80] + [5, -7, 30],
}


@pytest.mark.parametrize("cloud", sorted(CLOUDS))
@pytest.mark.parametrize("margin", [0.8, 1.0, 1.06, 1.5])
@pytest.mark.parametrize("box, aspect", [(FULL_PANE, 1.0), (SIDE_VIEW_BOX, 2.0),
                                         ((0.3, 0.1, 0.7, 0.9), 0.6)])
def test_frame_puts_every_point_in_the_box_with_the_margin(cloud, margin, box, aspect):
    pts = CLOUDS[cloud]
    rng = np.random.default_rng(len(cloud) + int(10 * margin))
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    f = frame(pts, direction, [0.0, 0.0, 1.0] if abs(direction[2]) < 0.9 else [1.0, 0, 0],
              view_angle=20.0, aspect=aspect, box=box, margin=margin)
    np.testing.assert_allclose(f.direction, direction, atol=1e-12)
    assert abs(f.up @ f.direction) < 1e-12 and f.up @ f.up == pytest.approx(1.0)
    assert f.view_angle == 20.0 and f.box == box
    _assert_framed(f, pts, aspect, margin)


def test_frame_keeps_its_distance_and_narrows_the_view_instead():
    pts = CLOUDS["cube"]
    near = frame(pts, [0, 0, -1.0], [0, 1.0, 0], view_angle=30.0, aspect=1.0, margin=1.1)
    far = frame(pts, [0, 0, -1.0], [0, 1.0, 0], view_angle=30.0, aspect=1.0, margin=1.1,
                min_distance=50.0, anchor=[0, 0, 0])
    assert near.distance < 50.0
    # the anchor (the cube's centre) in the focal plane: the camera 50 from it
    assert (np.zeros(3) - far.position) @ far.direction == pytest.approx(50.0)
    assert far.view_angle < near.view_angle
    _assert_framed(far, pts, 1.0, 1.1)


def test_frame_turns_with_the_scene():
    """Rotating (or mirroring) the points, the line of sight and up rotates the camera."""
    rng = np.random.default_rng(7)
    pts = CLOUDS["random"]
    d, up = np.array([0.3, -0.9, 0.2]), np.array([0.0, 0.0, 1.0])
    d /= np.linalg.norm(d)
    f = frame(pts, d, up, view_angle=25.0, aspect=1.6, box=SIDE_VIEW_BOX)
    for reflect in (False, True):
        rot = _random_rotation(rng, reflect=reflect)
        shift = rng.normal(size=3) * 100
        g = frame(pts @ rot.T + shift, rot @ d, rot @ up, view_angle=25.0, aspect=1.6,
                  box=SIDE_VIEW_BOX)
        np.testing.assert_allclose(g.position, rot @ f.position + shift, atol=1e-7)
        np.testing.assert_allclose(g.focal_point, rot @ f.focal_point + shift, atol=1e-7)
        np.testing.assert_allclose(g.up, rot @ f.up, atol=1e-12)
        assert g.view_angle == pytest.approx(f.view_angle)


# ------------------------------------------------------------------------------ the views
SETUPS = {
    "on axis": _setup(),
    "oblique": _setup(source=(300.0, -200.0, 900.0), center=(-50.0, 40.0, -600.0),
                      up=(0.2, 1.0, 0.1), lo=(-80, -10, -60), hi=(30, 70, 20)),
    "short and wide": _setup(source=(0.0, -250.0, 0.0), center=(0.0, 250.0, 0.0),
                             up=(0.0, 0.0, 1.0), shape=(300, 100), pitch=1.0,
                             lo=(-60, -40, -20), hi=(60, 40, 20)),
}


@pytest.mark.parametrize("name", sorted(SETUPS))
@pytest.mark.parametrize("aspect", [0.7, 1.3, 2.4])
def test_side_view_frames_the_whole_set_up_source_left_detector_face_on(name, aspect):
    vp, bounds = SETUPS[name]
    f = side_view(vp, bounds, aspect=aspect)
    _assert_framed(f, side_points(vp, bounds), aspect, 1.04)
    forward, up, side = view_axes(vp)
    centre = vp.LHC + vp.HO / 2 + vp.VE / 2
    # the source on the left, the detector on the right
    xy = f.project(np.array([vp.r0, centre]), aspect=aspect)
    assert xy[0, 0] < xy[1, 0]
    # the camera on the source's side of the detector plane: the pixel grid faces it
    assert (f.position - centre) @ forward < 0
    # the detector's up stays up on screen, the view from above
    assert f.up @ up > 0 and f.direction @ up < 0
    assert 4 <= f.elevation <= 32
    assert f.direction @ up == pytest.approx(-math.sin(math.radians(f.elevation)))


@pytest.mark.parametrize("azimuth, elevation", [(0.0, 0.0), (90.0, 0.0), (35.0, 10.0),
                                                (60.0, -12.0)])
def test_side_view_looks_where_its_angles_say(azimuth, elevation):
    vp, bounds = SETUPS["oblique"]
    forward, up, side = view_axes(vp)
    f = side_view(vp, bounds, aspect=1.5, azimuth=azimuth, elevation=elevation)
    a, e = math.radians(azimuth), math.radians(elevation)
    np.testing.assert_allclose(f.direction @ np.array([side, forward, up]).T,
                               [math.cos(e) * math.cos(a), math.cos(e) * math.sin(a),
                                -math.sin(e)], atol=1e-12)
    if azimuth == 90.0 and elevation == 0.0:         # down the beam, from behind the source
        np.testing.assert_allclose(f.direction, forward, atol=1e-12)
    if azimuth == 0.0 and elevation == 0.0:          # across the beam: the detector edge-on
        assert abs(f.direction @ forward) < 1e-12
    _assert_framed(f, side_points(vp, bounds), 1.5, 1.04)


def test_view_axes_are_the_beam_the_detector_up_and_the_side():
    vp, _ = SETUPS["oblique"]
    forward, up, side = view_axes(vp)
    np.testing.assert_allclose(forward, vp.forward, atol=1e-15)
    np.testing.assert_allclose(np.array([forward, up, side]) @ np.array([forward, up, side]).T,
                               np.eye(3), atol=1e-12)
    np.testing.assert_allclose(np.cross(up, forward), side, atol=1e-15)
    np.testing.assert_allclose(up, vp.VE / np.linalg.norm(vp.VE), atol=1e-12)


@pytest.mark.parametrize("name", sorted(SETUPS))
def test_source_side_view_looks_along_the_beam_held_back(name):
    vp, (lo, hi) = SETUPS[name]
    forward, up, side = view_axes(vp)
    f = bodies_view(vp, (lo, hi), aspect=1.4, azimuth=0.0, elevation=0.0)
    np.testing.assert_allclose(f.direction, forward, atol=1e-12)
    centre = (lo + hi) / 2
    pts = np.vstack([[vp.LHC, vp.LHC + vp.HO, vp.LHC + vp.VE, vp.LHC + vp.HO + vp.VE],
                     box_corners(lo, hi)])
    # on the source's side of the bodies, held back as frame() documents it: the distance
    # to the focal point is at least 1.15 |source - centre| + (centre - mean) . forward, and
    # where the camera is held at (about: the last re-centring may step back a hair) that
    # floor it narrowed its view angle (from 30 degrees)
    assert np.all((pts - f.position) @ forward > 0)
    floor = 1.15 * (centre - vp.r0) @ forward + (centre - pts.mean(axis=0)) @ forward
    assert f.distance >= floor * (1 - 1e-12)
    assert (f.view_angle < 30.0) == (f.distance == pytest.approx(floor, rel=1e-3))
    _assert_framed(f, pts, 1.4, 1.06)


def test_bodies_view_turns_aside_and_from_above():
    vp, bounds = SETUPS["on axis"]
    forward, up, side = view_axes(vp)
    f = bodies_view(vp, bounds, aspect=1.4)                     # azimuth -14, elevation 4
    a, e = math.radians(-14.0), math.radians(4.0)
    np.testing.assert_allclose(f.direction @ np.array([forward, side, up]).T,
                               [math.cos(e) * math.cos(a), math.cos(e) * math.sin(a),
                                -math.sin(e)], atol=1e-12)


def test_a_mirror_symmetric_set_up_gives_a_mirror_symmetric_camera():
    """Source and detector on the z axis, the bodies symmetric in x: the views that look in
    the (beam, up) plane have their camera in that plane, and mirroring the line of sight
    mirrors the camera."""
    vp, bounds = _setup(lo=(-40, -10, -50), hi=(40, 30, 50))
    mirror = np.diag([-1.0, 1.0, 1.0])
    for f in (bodies_view(vp, bounds, aspect=1.3, azimuth=0.0, elevation=7.0),
              side_view(vp, bounds, aspect=1.3, azimuth=90.0, elevation=12.0)):
        assert abs(f.position[0]) < 1e-9 * f.distance
        assert abs(f.focal_point[0]) < 1e-9 * f.distance
        assert abs(f.up[0]) < 1e-12
    left = side_view(vp, bounds, aspect=1.3, azimuth=60.0, elevation=10.0)
    right = side_view(vp, bounds, aspect=1.3, azimuth=120.0, elevation=10.0)
    # azimuth 60 and 120 see the set-up from mirror positions (x -> -x, the side axis is -x)
    np.testing.assert_allclose(right.position, mirror @ left.position, atol=1e-6)
    np.testing.assert_allclose(right.focal_point, mirror @ left.focal_point, atol=1e-6)
    np.testing.assert_allclose(right.up, mirror @ left.up, atol=1e-12)


@pytest.mark.parametrize("zoom", [0.5, 1.5, 2.0, 3.0])
def test_zoom_scales_the_distance(zoom):
    """A nearly parallel camera (0.5 degrees) comes ``zoom`` times closer and the picture
    grows ``zoom`` times beyond the margin; a camera held behind the source keeps its place
    and narrows its view angle ``zoom`` times (its tangent)."""
    vp, bounds = SETUPS["oblique"]
    pts = side_points(vp, bounds)
    one = side_view(vp, bounds, aspect=1.5, elevation=10.0, view_angle=0.5)
    z = side_view(vp, bounds, aspect=1.5, elevation=10.0, view_angle=0.5, zoom=zoom)
    assert one.distance / z.distance == pytest.approx(zoom, rel=0.01)
    u, v = _box_coords(z, pts, 1.5)
    assert max(np.abs(u).max(), np.abs(v).max()) == pytest.approx(zoom / 1.04, rel=1e-6)
    if zoom > 1.04:
        assert max(np.abs(u).max(), np.abs(v).max()) > 1       # beyond the box: zoomed in
    b1 = bodies_view(vp, bounds, aspect=1.5)
    bz = bodies_view(vp, bounds, aspect=1.5, zoom=zoom)
    np.testing.assert_allclose(bz.position, b1.position, rtol=1e-9)
    assert (math.tan(math.radians(b1.view_angle) / 2)
            / math.tan(math.radians(bz.view_angle) / 2)) == pytest.approx(zoom, rel=1e-9)


def test_the_chosen_elevation_is_low_in_a_wide_box_and_fills_best():
    vp, bounds = SETUPS["on axis"]
    axes = view_axes(vp)
    pts = side_points(vp, bounds)
    wide = camera.best_elevation(pts, axes, azimuth=60.0, aspect=3.0)
    square = camera.best_elevation(pts, axes, azimuth=60.0, aspect=0.9)
    assert wide <= square

    def fill(e, aspect):               # area of the picture / area of the box, measured
        f = side_view(vp, bounds, aspect=aspect, elevation=e, view_angle=0.5)
        u, v = _box_coords(f, pts, aspect)
        return np.ptp(u) * np.ptp(v) / 4

    for aspect, best in ((3.0, wide), (0.9, square)):
        assert fill(best, aspect) >= max(fill(e, aspect) for e in range(4, 33, 2)) - 2e-3


def test_image_view_shows_the_whole_image_centred_in_its_box():
    for (h, w), aspect, box in [((100, 200), 1.0, (0.06, 0.07, 0.76, 0.86)),
                                ((512, 128), 1.8, (0.1, 0.2, 0.9, 0.8)),
                                ((64, 64), 0.5, FULL_PANE)]:
        f = image_view((h, w), aspect=aspect, box=box)
        assert f.parallel and f.view_angle is None
        np.testing.assert_allclose(f.direction, [0, 0, -1])
        np.testing.assert_allclose(f.up, [0, 1, 0])
        frame_pts = np.array([[-0.5, -0.5, 0], [w - 0.5, -0.5, 0], [w - 0.5, h - 0.5, 0],
                              [-0.5, h - 0.5, 0]])
        u, v = _box_coords(f, frame_pts, aspect)
        assert max(np.abs(u).max(), np.abs(v).max()) == pytest.approx(1.0)   # as large as fits
        assert min(np.abs(u).max(), np.abs(v).max()) <= 1.0 + 1e-12
        assert u.max() + u.min() == pytest.approx(0, abs=1e-12)            # centred
        assert v.max() + v.min() == pytest.approx(0, abs=1e-12)


def test_label_fraction_takes_the_nearest_place_in_view():
    frac = np.linspace(0.05, 0.95, 19)
    xy = np.column_stack([frac, np.full(len(frac), 0.5)])       # across the pane at mid-height
    # in the box: its usual place
    assert label_fraction(xy, frac, 0.5, [FULL_PANE]) == pytest.approx(0.5)
    # beyond the right edge of the box (x < 0.6 - 0.06): the nearest place inside
    assert label_fraction(xy, frac, 0.9, [(0.0, 0.0, 0.6, 1.0)]) == pytest.approx(0.5)
    # no place in the first box: the second one
    assert label_fraction(xy, frac, 0.9, [(0.0, 0.8, 1.0, 1.0), FULL_PANE]) == \
        pytest.approx(frac[frac < 0.94].max())
    # nowhere in view: where it was
    assert label_fraction(xy, frac, 0.3, [(0.0, 0.8, 1.0, 1.0)]) == 0.3


# ------------------------------------------------------------------------------ against VTK
def test_project_is_what_vtk_cameras_draw():
    """Framing.project against VTK's own camera matrices (perspective, window centre shifted;
    and parallel)."""
    pytest.importorskip("vtkmodules")
    from vtkmodules.vtkRenderingCore import vtkCamera

    vp, bounds = SETUPS["oblique"]
    pts = np.vstack([side_points(vp, bounds), np.random.default_rng(1).normal(size=(30, 3))
                     * 200])
    for f, aspect in [(side_view(vp, bounds, aspect=1.7), 1.7),
                      (bodies_view(vp, bounds, aspect=0.8, box=(0.3, 0.1, 0.95, 0.9)), 0.8),
                      (image_view((60, 90), aspect=1.2, box=(0.06, 0.1, 0.76, 0.86)), 1.2)]:
        cam = vtkCamera()
        cam.SetPosition(*f.position)
        cam.SetFocalPoint(*f.focal_point)
        cam.SetViewUp(*f.up)
        if f.parallel:
            cam.SetParallelProjection(True)
            cam.SetParallelScale(f.parallel_scale)
        else:
            cam.SetViewAngle(f.view_angle)
        cam.SetWindowCenter(*f.window_center)
        cam.SetClippingRange(1e-3, 1e7)
        m = cam.GetCompositeProjectionTransformMatrix(aspect, -1, 1)
        mat = np.array([[m.GetElement(r, c) for c in range(4)] for r in range(4)])
        hom = np.c_[pts, np.ones(len(pts))] @ mat.T
        expected = (hom[:, :2] / hom[:, 3:4] + 1) / 2
        expected[hom[:, 3] <= 0] = np.nan
        np.testing.assert_allclose(f.project(pts, aspect=aspect), expected, rtol=1e-9,
                                   atol=1e-9)


def test_scene_view_puts_its_camera_where_the_framing_says():
    """SceneView.view_side / view_bodies apply camera.side_view / bodies_view exactly, and what
    the VTK camera shows is where Framing.project puts it."""
    pv = pytest.importorskip("pyvista")
    import xray_viz
    from xray_viz.viz import plot_scene

    view = plot_scene(xray_viz.load_scene("sphere"), rays="center", window_size=(900, 500),
                      off_screen=True)
    try:
        for show, compute in [
                (view.view_side, lambda a: side_view(view.viewport, view.bodies_bounds,
                                                     aspect=a, box=view.view_box,
                                                     source_radius=0.6 * view.size_scale)),
                (view.view_bodies, lambda a: bodies_view(view.viewport, view.bodies_bounds,
                                                         aspect=a, box=view.view_box))]:
            show()
            aspect = view._pane_aspect()
            f = compute(aspect)
            cam = view.plotter.camera
            assert tuple(cam.position) == tuple(f.position)
            assert tuple(cam.focal_point) == tuple(f.focal_point)
            assert cam.view_angle == f.view_angle
            assert tuple(cam.GetWindowCenter()) == f.window_center
            pts = side_points(view.viewport, view.bodies_bounds)
            np.testing.assert_allclose(view._world_to_box(pts), f.project(pts, aspect=aspect),
                                       atol=1e-9)
        assert view.camera_is_pinned()
    finally:
        view.plotter.close()
    assert pv is not None

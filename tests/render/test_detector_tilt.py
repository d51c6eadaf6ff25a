"""Tilted and offset detectors (issue 14, geometry): the detector's own u/v axes and an in-plane
offset, in both engines, the projection matrix, poses, ASTRA vectors and RTK's geometry."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import trimesh

from xray_viz.errors import SceneError
from xray_viz.geometry import Acquisition
from xray_viz.scene import Body, Detector, Scene, Source, load_scene
from xray_viz.tracing.fast import trace_once
from xray_viz.tracing.reference import numpy_path_lengths


def _tilt(angle_deg, axis=(0.0, 1.0, 0.0), u=(1.0, 0.0, 0.0), v=(0.0, 1.0, 0.0)):
    """The detector axes ``u``, ``v`` turned by ``angle_deg`` about ``axis`` (Rodrigues)."""
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = math.radians(angle_deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    rot = np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * (k @ k)
    return (rot @ np.asarray(u, float)).tolist(), (rot @ np.asarray(v, float)).tolist()


def _with(scene, *, kind="point", shape=(48, 40), pitch=4.0, **det):
    return scene.replace(source=dataclasses.replace(scene.source, kind=kind),
                         detector=dataclasses.replace(scene.detector, shape=shape,
                                                      pitch=(pitch, pitch), **det))


U30, V30 = _tilt(30.0, axis=(0.3, 1.0, -0.2))
GEOMETRIES = {
    "offset": {"offset": (13.25, -9.5)},
    "tilt": {"u": U30, "v": V30},
    "tilt+offset": {"u": U30, "v": V30, "offset": (-11.0, 7.5)},
}


# ------------------------------------------------------------------------ the scene keys

def test_a_scene_without_the_keys_is_todays_plain_detector(tmp_path):
    scene = load_scene("sphere")
    f = scene.acquisition.frame
    assert f.plain and f.normal is f.forward and f.middle is f.center and f.distance == f.sid
    assert f.principal == (0.0, 0.0) and f.grid(2).bx == 2 * 255 / 2 + 0.5
    doc = scene.to_dict()["detector"]
    assert not {"offset", "u", "v"} & set(doc) and "up" in doc


def test_the_keys_round_trip_through_toml(tmp_path):
    scene = _with(load_scene("sphere"), **GEOMETRIES["tilt+offset"])
    path = tmp_path / "tilted.toml"
    text = scene.to_toml(base=tmp_path)
    assert "offset = " in text and "\nu = " in text and "\nup = " not in text
    path.write_text(text)
    back = load_scene(path)
    np.testing.assert_array_equal(back.detector.u, scene.detector.u)
    np.testing.assert_array_equal(back.detector.v, scene.detector.v)
    assert back.detector.offset == scene.detector.offset
    np.testing.assert_array_equal(trace_once(back), trace_once(scene))


@pytest.mark.parametrize("lines, message", [
    ("u = [1.0, 0.0, 0.0]", "gives 'u' without 'v'"),
    ("u = [1.0, 0.0, 0.0]\nv = [0.1, 1.0, 0.0]", "must be perpendicular"),
    ("up = [0.0, 1.0, 0.0]\nu = [1.0, 0.0, 0.0]\nv = [0.0, 1.0, 0.0]", "gives 'up' and"),
    ("offset = [1.0, \"2\"]", "offset must be a list of 2 numbers"),
    ("offset = [1.0, 2.0, 3.0]", "offset must be a list of 2 numbers"),
    ("u = [1.0, 0.0, 0.0]\nv = [0.0, 0.0, 1.0]", "parallel to the beam"),
    ("u = [-1.0, 0.0, 0.0]\nv = [0.0, 1.0, 0.0]", "faces away from the source"),
    ("u = [0.0, 0.0, 0.0]\nv = [0.0, 1.0, 0.0]", "u must be a non-zero vector"),
])
def test_bad_tilt_keys_are_one_line_errors(tmp_path, lines, message):
    path = tmp_path / "bad.toml"
    path.write_text("[source]\nposition = [0.0, 0.0, 1000.0]\n[detector]\ncenter = [0.0, 0.0, "
                    f"-500.0]\nshape = [8, 8]\npitch = 1.0\n{lines}\n")
    with pytest.raises(SceneError, match=message) as info:
        load_scene(path)
    assert "\n" not in str(info.value) and "[detector]" in str(info.value)


def test_u_and_v_are_orthonormalised_and_set_up():
    det = Detector(center=[0, 0, -500.0], u=[2.0, 0, 0], v=[1e-10, 3.0, 0], shape=(4, 4))
    assert det.tilted and not det.shifted
    np.testing.assert_array_equal(det.u, [1.0, 0.0, 0.0])
    assert det.v @ det.u == 0.0 and abs(np.linalg.norm(det.v) - 1) < 1e-15
    np.testing.assert_array_equal(det.up, det.v)


# ------------------------------------------------------------------------ both engines

@pytest.mark.parametrize("name", ["sphere", "nested_spheres", "limb"])
@pytest.mark.parametrize("kind", ["point", "parallel"])
@pytest.mark.parametrize("geometry", sorted(GEOMETRIES))
def test_fast_engine_equals_the_reference_on_tilted_and_offset_detectors(name, kind, geometry):
    scene = _with(load_scene(name), kind=kind, **GEOMETRIES[geometry])
    fast, ref = trace_once(scene), numpy_path_lengths(scene)[0]
    assert (fast.sum(axis=1) > 0).sum() > 100                  # the bodies are in the beam
    np.testing.assert_allclose(fast, ref, rtol=0, atol=1e-9)


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_supersampled_windows_on_a_tilted_detector(kind):
    from xray_viz.tracing.fast import trace_rows

    scene = _with(load_scene("nested_spheres"), kind=kind, shape=(24, 20), pitch=8.0,
                  **GEOMETRIES["tilt+offset"])
    ref = numpy_path_lengths(scene, supersample=2)[0]
    whole = trace_once(scene, supersample=2)
    np.testing.assert_allclose(whole, ref, rtol=0, atol=1e-9)
    parts = np.concatenate([L for *_, L in trace_rows(scene, supersample=2, rows=7)])
    np.testing.assert_array_equal(parts, whole)


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_given_axes_equal_to_the_derived_ones_render_as_the_plain_detector(kind):
    """The general (tilted) path with u, v = unit(HO), unit(VE) agrees with the thesis' path."""
    plain = _with(load_scene("limb"), kind=kind)
    f = plain.acquisition.frame
    tilted = _with(load_scene("limb"), kind=kind, u=f.ho, v=f.ve)
    assert not tilted.acquisition.frame.plain
    for scene in (plain, tilted):
        assert scene.acquisition.rays().directions.shape == (48 * 40, 3)
    np.testing.assert_allclose(trace_once(tilted), trace_once(plain), rtol=0, atol=1e-9)
    np.testing.assert_allclose(tilted.acquisition.projection_matrix(),
                               plain.acquisition.projection_matrix(), rtol=0, atol=1e-9)


# ------------------------------------------------------------------------ analytic checks

def test_an_offset_moves_the_shadow_centre_to_the_predicted_pixel():
    """A ball on the beam axis casts a round shadow centred where the axis meets the detector:
    offset by (du, dv) mm, that is pixel column cx - du / pu and row-from-bottom cy - dv / pv,
    here a pixel centre (10.5 and 6.5 pixels off the middle, a pixel corner), so the image is exactly mirror symmetric
    about it."""
    scene = _with(load_scene("sphere"), shape=(128, 96), pitch=1.0, offset=(10.5, -6.5))
    image = trace_once(scene)[:, 0].reshape(96, 128)
    col = (128 - 1) / 2 - 10.5 / 1.0                   # 53: a pixel centre
    row = (96 - 1) / 2 - (-6.5) / 1.0                  # from the bottom: 54, a pixel centre
    c, r = int(col), 96 - 1 - int(row)                 # image row 41
    assert image[r, c] == pytest.approx(image.max())
    k = np.arange(1, 40)
    np.testing.assert_allclose(image[r, c + k], image[r, c - k], rtol=0, atol=1e-9)
    np.testing.assert_allclose(image[r + k, c], image[r - k, c], rtol=0, atol=1e-9)
    p = scene.acquisition.projection_matrix() @ [0.0, 0.0, 0.0, 1.0]
    assert (p[:2] / p[2]).tolist() == pytest.approx([col, row], abs=1e-9)


def _box_scene(kind):
    box = trimesh.creation.box(extents=[40.0, 29.0, 20.0])
    return Scene(source=Source(position=[0, 0, 1000.0], kind=kind),
                 detector=Detector(center=[0, 0, -400.0], shape=(160, 81), pitch=(1.0, 1.0)),
                 bodies=[Body(name="box", mesh=box, mu=0.1)])


@pytest.mark.parametrize("angle", [25.0, 50.0])
def test_a_tilt_stretches_a_parallel_shadow_by_one_over_cos(angle):
    """A parallel beam along -z through a 40 mm box onto a detector tilted by a about v: the
    shadow is 40 / cos(a) mm wide along u (and still 29 mm along v), the path length 20 mm."""
    u, v = _tilt(angle)
    scene = _box_scene("parallel")
    scene = scene.replace(detector=dataclasses.replace(scene.detector, u=u, v=v))
    image = trace_once(scene)[:, 0].reshape(81, 160)
    x = (np.arange(160) - 79.5) * 1.0                  # pixel positions along u (mm)
    y = (np.arange(81) - 40.0)[::-1] * 1.0             # along v, image rows top down
    inside = (np.abs(x) < 20.0 / math.cos(math.radians(angle)))[None, :] \
        & (np.abs(y) < 14.5)[:, None]
    assert np.all(np.abs(np.abs(x) - 20.0 / math.cos(math.radians(angle))) > 1e-3)
    np.testing.assert_allclose(image[inside], 20.0, rtol=1e-12)
    assert not image[~inside].any()
    np.testing.assert_allclose(numpy_path_lengths(scene)[0][:, 0].reshape(81, 160), image,
                               rtol=0, atol=1e-9)


@pytest.mark.parametrize("angle", [20.0, -35.0])
def test_a_tilt_stretches_a_cone_beam_shadow_as_the_rays_predict(angle):
    """Point source: the box's corners projected by hand (ray from the source through each
    corner, cut with the tilted plane) bound the shadow, so its width along u is
    D cos(a) (tan(phi+ + a) - tan(phi- + a)) with phi the corners' angles from the axis - not
    the untilted width; and the projection matrix sends each corner to the same pixel."""
    from scipy.spatial import ConvexHull

    u, v = _tilt(angle)
    scene = _box_scene("point")
    scene = scene.replace(detector=dataclasses.replace(scene.detector, u=u, v=v))
    f = scene.acquisition.frame
    corners = scene.bodies[0].vertices
    rel = corners - f.source
    t = f.distance / (rel @ f.normal)
    hit = f.source + t[:, None] * rel - f.middle
    a, b = hit @ f.ho, hit @ f.ve                      # mm on the tilted plane
    cols, rows_up = a / 1.0 + 79.5, b / 1.0 + 40.0
    p = scene.acquisition.projection_matrix() @ np.c_[corners, np.ones(8)].T
    np.testing.assert_allclose(p[0] / p[2], cols, rtol=0, atol=1e-9)
    np.testing.assert_allclose(p[1] / p[2], rows_up, rtol=0, atol=1e-9)
    # the central row (v = 0): the shadow's edges at the extreme corner rays, stretched
    phi = np.arctan2(rel @ [1.0, 0, 0], rel @ [0, 0, -1.0])
    tilt = math.radians(angle)
    width = 1400.0 * math.cos(tilt) * (math.tan(phi.max() + tilt) - math.tan(phi.min() + tilt))
    assert width == pytest.approx(a.max() - a.min(), rel=1e-12)
    assert abs(width - 1400.0 * (math.tan(phi.max()) - math.tan(phi.min()))) > 3.0
    image = trace_once(scene)[:, 0].reshape(81, 160)
    hull = ConvexHull(np.c_[cols, 80 - rows_up])
    rr, cc = np.mgrid[0:81, 0:160]
    dist = (np.c_[cc.ravel(), rr.ravel()] @ hull.equations[:, :2].T
            + hull.equations[:, 2]).max(axis=1).reshape(81, 160)
    hitpix = image > 0
    assert hitpix[dist < -1e-6].all() and not hitpix[dist > 1e-6].any()


def test_falloff_uses_the_angle_to_the_detector_normal():
    """On a tilted, offset detector the fall-off is the inverse square from the source (1 at
    SID) times the cosine of the angle between each ray and the detector's normal: cos of the
    tilt at ``center``; an offset alone keeps cos^3 about the beam axis."""
    from xray_viz.physics.imaging import falloff_factor

    scene = _with(load_scene("sphere"), shape=(49, 41), **GEOMETRIES["tilt+offset"])
    f = scene.acquisition.frame
    rays = scene.acquisition.rays()
    r = np.linalg.norm(rays.ends - f.source, axis=1)
    cos = rays.directions @ f.normal
    np.testing.assert_allclose(falloff_factor(scene).ravel(), (1500.0 / r) ** 2 * cos,
                               rtol=1e-12)
    centred = _with(load_scene("sphere"), shape=(49, 41), u=U30, v=V30, offset=(0.0, 0.0))
    assert falloff_factor(centred)[20, 24] == pytest.approx(float(f.forward @ f.normal),
                                                            rel=1e-12)
    shifted = _with(load_scene("sphere"), shape=(49, 41), offset=(40.0, 0.0))
    cos_axis = shifted.acquisition.rays().directions @ [0.0, 0.0, -1.0]
    np.testing.assert_allclose(falloff_factor(shifted).ravel(), cos_axis ** 3, rtol=1e-12)


# ------------------------------------------------------------------------ projection matrices

def _random_acquisitions(kind, n=6, seed=5):
    rng = np.random.default_rng(seed)
    scene = _box_scene(kind)
    for _ in range(n):
        u, v = _tilt(rng.uniform(-50, 50), axis=rng.normal(size=3))
        if kind == "parallel" and np.dot(u, [0, 0, -1.0]) < 0:
            u, v = [-x for x in u], [-x for x in v]      # u . forward >= 0: of the two mirror
            #                                              tilts, from_projection_matrix's
        det = dataclasses.replace(scene.detector, u=u, v=v,
                                  offset=tuple(rng.uniform(-30, 30, size=2)))
        yield Acquisition(source=scene.source, detector=det).rotated(
            rng.uniform(0, 360), axis=rng.normal(size=3), center=rng.normal(size=3) * 20)


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_projection_matrix_sends_every_pixel_point_to_its_pixel(kind):
    for acq in _random_acquisitions(kind):
        w, h = acq.detector.shape
        ends = acq.rays().ends
        p = acq.projection_matrix() @ np.c_[ends, np.ones(len(ends))].T
        rows, cols = np.divmod(np.arange(w * h), w)
        np.testing.assert_allclose(p[0] / p[2], cols, rtol=0, atol=1e-8)
        np.testing.assert_allclose(p[1] / p[2], h - 1 - rows, rtol=0, atol=1e-8)
        if kind == "parallel":       # and every point of a ray to the ray's pixel
            back = acq.rays().origins
            q = acq.projection_matrix() @ np.c_[back, np.ones(len(back))].T
            np.testing.assert_allclose(q[0], cols, rtol=0, atol=1e-8)


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_from_projection_matrix_round_trips_tilted_and_offset_detectors(kind):
    """RQ decomposition of a general camera: the same rays (source, directions, pixel points)
    and the same matrix back. A point source's tilted detector comes back as the untilted one
    through the foot of the perpendicular, offset to the same pixels (the same camera)."""
    for acq in _random_acquisitions(kind):
        f = acq.frame
        kw = {"sid": f.sid, "depth": float(f.forward @ f.middle)} if kind == "parallel" else {}
        back = Acquisition.from_projection_matrix(-0.7 * acq.projection_matrix(),
                                                  shape=f.shape, pitch=f.pitch,
                                                  parallel=kind == "parallel", like=acq, **kw)
        np.testing.assert_allclose(back.projection_matrix(), acq.projection_matrix(),
                                   rtol=0, atol=1e-8)
        a, b = acq.rays(), back.rays()
        np.testing.assert_allclose(b.directions, a.directions, rtol=0, atol=1e-9)
        np.testing.assert_allclose(b.ends, a.ends, rtol=0, atol=1e-8)
        if kind == "point":
            np.testing.assert_allclose(back.frame.source, f.source, rtol=0, atol=1e-8)
            assert not back.detector.tilted
            assert back.frame.distance == pytest.approx(f.distance, rel=1e-12)


def test_from_projection_matrix_still_refuses_skewed_pixels():
    acq = next(_random_acquisitions("point"))
    skew = acq.projection_matrix()
    skew[0, :3] += 0.01 * skew[1, :3]
    with pytest.raises(SceneError, match="skewed") as info:
        Acquisition.from_projection_matrix(skew, shape=(160, 81), pitch=(1.0, 1.0), like=acq)
    assert "\n" not in str(info.value)
    with pytest.raises(SceneError, match="different source-to-detector distances"):
        Acquisition.from_projection_matrix(acq.projection_matrix(), shape=(160, 81),
                                           pitch=(1.0, 1.1), like=acq)


# ------------------------------------------------------------------------ poses, ASTRA, RTK

def _pose_orbit(kind):
    from xray_viz.orbit import Orbit
    from xray_viz.poses import acquisition_pose as _pose

    acqs = list(_random_acquisitions(kind, n=3, seed=9))
    return acqs, Orbit("poses", poses=[_pose(a) for a in acqs])


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_tilted_offset_poses_render_their_acquisitions(kind):
    from xray_viz.orbit import check_pose

    acqs, orbit = _pose_orbit(kind)
    scene = _box_scene(kind)
    for k, acq in enumerate(acqs):
        s, c, u, v = check_pose(orbit.poses[k])
        np.testing.assert_allclose(c, acq.frame.middle, atol=1e-12)
        again = orbit.acquisition(scene.acquisition, k)
        assert again.detector.tilted and not again.detector.shifted
        np.testing.assert_allclose(again.rays().ends, acq.rays().ends, rtol=0, atol=1e-9)
        np.testing.assert_allclose(again.rays().directions, acq.rays().directions, atol=1e-12)
        np.testing.assert_allclose(trace_once(scene.replace(acquisition=again)),
                                   trace_once(scene.replace(acquisition=acq)), atol=1e-9)
    with pytest.raises(SceneError, match="must be perpendicular"):
        check_pose({**orbit.poses[0], "v": orbit.poses[0]["u"]}, where="pose 0: ")
    bad = {**orbit.poses[0], "u": [-x for x in orbit.poses[0]["u"]]}
    with pytest.raises(SceneError, match="pose 0: u .* faces away"):
        check_pose(bad, where="pose 0: ")


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_astra_vectors_of_tilted_offset_poses_put_pixels_where_the_rays_end(kind):
    from xray_viz.scan import astra_vectors, poses_from_astra, scan_geometry

    acqs, orbit = _pose_orbit(kind)
    scene = _box_scene(kind)
    g = scan_geometry(scene, orbit)
    vec = astra_vectors(g)
    W, H = scene.detector.shape
    r, c = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    for k, acq in enumerate(acqs):
        d, u, v = vec[k, 3:6], vec[k, 6:9], vec[k, 9:12]
        astra = d + (c - (W - 1) / 2)[..., None] * u + (r - (H - 1) / 2)[..., None] * v
        np.testing.assert_allclose(astra, acq.rays().ends.reshape(H, W, 3), rtol=0, atol=1e-9)
        if kind == "parallel":
            np.testing.assert_allclose(vec[k, :3], acq.frame.forward, atol=1e-12)
        else:
            np.testing.assert_allclose(vec[k, :3], acq.frame.source, atol=1e-12)
    back = poses_from_astra(vec, beam=g["beam"], sid=g["sid_mm"])
    for k, (a, b) in enumerate(zip(back, g["poses"])):
        for key in ("detector_center", "u", "v"):
            np.testing.assert_allclose(a[key], b[key], rtol=0, atol=1e-9)
        again = orbit.acquisition(scene.acquisition, k)
        from xray_viz.orbit import pose_acquisition

        from_astra = pose_acquisition(scene.acquisition, a)
        np.testing.assert_allclose(from_astra.rays().ends, again.rays().ends, atol=1e-9)
        np.testing.assert_allclose(from_astra.rays().directions, again.rays().directions,
                                   atol=1e-12)


def _rtk_pixel_matrix(geo, k):
    """RTK's projection matrix k, from its fixed frame and detector mm to xray_viz's world
    and pixels (rtk_frame; pixel = mm / pitch + (n - 1) / 2)."""
    from xray_viz.reconstruct import _rtk, rtk_frame, rtk_geometry

    itk, _ = _rtk()
    g = rtk_geometry(geo)
    R, center = rtk_frame(geo)
    m = np.array(itk.array_from_matrix(g.GetMatrix(k)))
    (w, h), (pu, pv) = geo["detector"]["shape"], geo["detector"]["pitch_mm"]
    to_pixels = np.array([[1 / pu, 0, (w - 1) / 2], [0, 1 / pv, (h - 1) / 2], [0, 0, 1]])
    to_rtk = np.vstack([np.hstack([R, -(R @ center)[:, None]]), [0, 0, 0, 1]])
    return to_pixels @ m @ to_rtk


SWIG_WARNING = "ignore:builtin type swigvarlink has no __module__ attribute:DeprecationWarning"


@pytest.mark.filterwarnings(SWIG_WARNING)
def test_rtk_geometry_of_tilted_offset_poses_has_our_projection_matrices():
    from xray_viz.scan import scan_geometry

    acqs, orbit = _pose_orbit("point")
    geo = scan_geometry(_box_scene("point"), orbit)
    geo["axis"], geo["center"] = [0.2, 1.0, 0.1], [1.0, 2.0, -3.0]    # any RTK frame will do
    for k, acq in enumerate(acqs):
        ours = acq.projection_matrix()
        theirs = _rtk_pixel_matrix(geo, k)
        scale = ours[2, :3] @ theirs[2, :3]
        np.testing.assert_allclose(theirs / scale, ours, rtol=0, atol=1e-7)


@pytest.mark.filterwarnings(SWIG_WARNING)
def test_rtk_geometry_refuses_a_parallel_beam_onto_a_tilted_detector():
    from xray_viz.reconstruct import ReconstructionError, rtk_geometry
    from xray_viz.scan import scan_geometry

    acqs, orbit = _pose_orbit("parallel")
    geo = scan_geometry(_box_scene("parallel"), orbit)
    geo["axis"], geo["center"] = [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]
    with pytest.raises(ReconstructionError, match="tilted detector") as info:
        rtk_geometry(geo)
    assert "\n" not in str(info.value)


def test_heel_directions_follow_the_rays_of_an_offset_or_tilted_detector():
    """SpekPy's pixel directions (tangents in the tube's frame, the beam axis) come from each
    pixel's own ray: the derived axes given as u, v change nothing, and an offset of 20 mm
    along u moves every pixel's across-tangent by 20 / SID."""
    from xray_viz.physics.heel import pixel_directions

    scene = Scene(source=Source(position=[0, 0, 1000.0], energy=None, heel=True,
                                spectrum={"kvp": 80.0, "filters": {"Al": 2.5}}),
                  detector=Detector(center=[0, 0, -500.0], shape=(9, 7), pitch=(10.0, 10.0)),
                  bodies=[])
    f = scene.acquisition.frame
    plain = pixel_directions(scene.acquisition)
    same = pixel_directions(scene.replace(detector=dataclasses.replace(
        scene.detector, u=f.ho, v=f.ve)).acquisition)
    np.testing.assert_allclose(same, plain, rtol=0, atol=1e-15)
    moved = pixel_directions(scene.replace(detector=dataclasses.replace(
        scene.detector, offset=(20.0, 0.0))).acquisition)
    np.testing.assert_allclose(moved[0], plain[0], rtol=0, atol=1e-15)   # along: anode-cathode
    np.testing.assert_allclose(moved[1], plain[1] + 20.0 / 1500.0, rtol=0, atol=1e-15)

"""The thesis' viewport geometry (Eq. 1.2-1.5) and image orientation."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.geometry import detector_rays, pixel_coordinates, viewport
from xray_viz.scene import Detector
from helpers import make_scene


def test_viewport_vectors_follow_the_thesis():
    det = Detector(center=[0, 0, -500], up=[0, 1, 0], shape=(512, 384), pitch=0.25)
    vp = viewport([0, 0, 1000], det)
    np.testing.assert_allclose(vp.HO, [511 * 0.25, 0, 0])         # |HO| = (W - 1) pitch, +x
    np.testing.assert_allclose(vp.VE, [0, 383 * 0.25, 0])
    np.testing.assert_allclose(vp.FL, [0, 0, 1500])
    np.testing.assert_allclose(vp.LHC, vp.r0 - vp.HO / 2 - vp.VE / 2 - vp.FL)   # Eq. 1.2
    np.testing.assert_allclose(vp.LHC, [-511 * 0.125, -383 * 0.125, -500])


def test_tilted_up_and_camera_anywhere():
    rng = np.random.default_rng(0)
    for _ in range(5):
        r0 = rng.normal(size=3) * 500
        center = rng.normal(size=3) * 500
        up = rng.normal(size=3)
        det = Detector(center=center, up=up, shape=(9, 7), pitch=(0.5, 0.75))
        vp = viewport(r0, det)
        forward = (center - r0) / np.linalg.norm(center - r0)
        assert abs(vp.HO @ forward) < 1e-9 and abs(vp.VE @ forward) < 1e-9 and abs(vp.HO @ vp.VE) < 1e-9
        assert np.linalg.norm(vp.HO) == pytest.approx(8 * 0.5)
        assert np.linalg.norm(vp.VE) == pytest.approx(6 * 0.75)
        assert vp.VE @ up > 0                                       # VE is up's part across the beam
        # HO x VE points back at the source (HO left-to-right, VE bottom-to-top, seen from r0).
        assert np.cross(vp.HO, vp.VE) @ forward < 0
        np.testing.assert_allclose(vp.LHC + vp.HO / 2 + vp.VE / 2, center, atol=1e-9)


def test_pixel_rays_pass_through_their_viewport_points():
    scene = make_scene(trimesh.creation.icosphere(radius=5.0), source=(100, -50, 300),
                       center=(-20, 10, -200), up=(0.1, 1, 0.3), shape=(5, 4), pitch=2.0)
    vp = viewport(scene.source.position, scene.detector)
    rays = detector_rays(scene)
    u, v = pixel_coordinates((5, 4))
    targets = vp.LHC + u.ravel()[:, None] * vp.HO + v.ravel()[:, None] * vp.VE
    np.testing.assert_allclose(rays.ends, targets, atol=1e-9)
    # Row 0 is the top (v = 1), column 0 the left (u = 0): ray 0 ends at LHC + VE.
    np.testing.assert_allclose(rays.ends[0], vp.LHC + vp.VE, atol=1e-9)
    np.testing.assert_allclose(rays.ends[-1], vp.LHC + vp.HO, atol=1e-9)
    # The printed Eq. 1.5 (direction LHC + u HO + v VE, without - r0) misses the pixel.
    printed = vp.LHC + u.ravel()[:, None] * vp.HO + v.ravel()[:, None] * vp.VE
    cos = np.sum(printed / np.linalg.norm(printed, axis=1)[:, None] * rays.directions, axis=1)
    assert np.all(cos < 0.999)


def test_parallel_beam_rays():
    scene = make_scene(trimesh.creation.icosphere(radius=5.0), kind="parallel", shape=(3, 3),
                       pitch=1.0, source=(0, 0, 100), center=(0, 0, -100))
    rays = detector_rays(scene)
    np.testing.assert_allclose(rays.directions, np.tile([0, 0, -1.0], (9, 1)))
    np.testing.assert_allclose(rays.origins[0], [-1, 1, 100])
    np.testing.assert_allclose(rays.t_max, 200.0)


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_off_centre_object_appears_where_it_should(kind):
    """A ball at +x (right) and +y (up) shows up in the top-right of the image."""
    ball = trimesh.creation.icosphere(subdivisions=2, radius=8.0)
    ball.apply_translation([30.0, 20.0, 0.0])
    scene = make_scene(ball, kind=kind, shape=(101, 81), pitch=1.5)
    L = xray_viz.render(scene).total_path_length
    rows, cols = np.nonzero(L)
    h, w = L.shape
    assert cols.min() > w // 2 and rows.max() < h // 2
    # The centre of the shadow is where the centre of the ball projects.
    mag = 1.0 if kind == "parallel" else 1500.0 / 1000.0
    col_c = (w - 1) / 2 + 30.0 * mag / 1.5
    row_c = (h - 1) / 2 - 20.0 * mag / 1.5
    weights = L[rows, cols]
    assert np.average(cols, weights=weights) == pytest.approx(col_c, abs=0.5)
    assert np.average(rows, weights=weights) == pytest.approx(row_c, abs=0.5)

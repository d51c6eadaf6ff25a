"""mbirjax as a second back-end (issue 14): its geometry decomposition of xray_viz's poses
(default, no JAX), and MBIR reconstructions of a circular and a helical scan that put the
object where it is (slow: JAX compiles for minutes on the first call on this CPU)."""

from __future__ import annotations

import math

import numpy as np
import pytest

import xray_viz
from xray_viz.orbit import Orbit
from xray_viz.reconstruct import ReconstructionError, mbirjax_geometry, reconstruct

from tests.reconstruct.test_reconstruct import CENTER, ellipsoid_scene
from tests.reconstruct.test_reconstruct_iterative import check_ellipsoid


def helical_scan(axis, pitch, n=24, *, shape=(40, 24), det_pitch=3.0, render=True):
    scene, _ = ellipsoid_scene(axis, subdivisions=3, shape=shape, pitch=det_pitch)
    orbit = Orbit("helical" if pitch else "circular", projections=n,
                  arc=720.0 if pitch else 360.0, axis=np.asarray(axis, float), center=CENTER,
                  pitch=pitch, start=7.0)
    if render:
        return scene, xray_viz.scan(scene, orbit)
    from xray_viz.scan import scan_geometry

    return scene, scan_geometry(scene, orbit)


@pytest.mark.parametrize("axis, pitch", [([0, 0, 1], 0.0), ([1, 0, 0], 30.0),
                                         ([0, 1, 1], 30.0)])
def test_mbirjax_geometry_rebuilds_every_pose(axis, pitch):
    """mbirjax's parameters (its documented convention: source at SID (sin t e_x + cos t e_y)
    + shift along the axis, channels along cos t e_x - sin t e_y, rows along the axis) give
    back each pose's source, detector centre and u/v vectors; the angles step by the orbit's
    step and the shifts by pitch per turn."""
    scene, geo = helical_scan(axis, pitch, render=False)
    g = mbirjax_geometry(geo)
    ex, ey, a = g["frame"]
    assert np.allclose(g["frame"] @ g["frame"].T, np.eye(3))
    assert np.isclose(g["source_iso_dist"], geo["sod_mm"])
    assert np.isclose(g["source_detector_dist"], geo["sid_mm"])
    assert abs(g["det_channel_offset"]) < 1e-9 and abs(g["det_row_offset"]) < 1e-9
    step = np.diff(g["angles"])
    assert np.allclose(np.abs(step), math.radians((720.0 if pitch else 360.0) / 24))
    assert np.allclose(np.diff(g["helical_z_shifts"]), pitch * np.abs(step) / (2 * math.pi))
    su = -1.0 if g["flip_channels"] else 1.0
    sv = 1.0 if g["flip_rows"] else -1.0
    for t, z, p in zip(g["angles"], g["helical_z_shifts"], geo["poses"]):
        radial = math.sin(t) * ex + math.cos(t) * ey
        chan = math.cos(t) * ex - math.sin(t) * ey
        src = CENTER + g["source_iso_dist"] * radial + z * a
        det = src - g["source_detector_dist"] * radial
        assert np.allclose(p["source"], src, atol=1e-9)
        assert np.allclose(p["detector_center"], det, atol=1e-9)
        assert np.allclose(p["u"], su * chan, atol=1e-12)
        assert np.allclose(p["v"], sv * a, atol=1e-12)


def test_mbirjax_geometry_refuses_what_it_cannot_hold():
    _, geo = helical_scan([0, 0, 1], 0.0, render=False)
    tilted = [dict(p, u=(np.asarray(p["u"]) * math.cos(0.1)
                         + np.asarray(p["v"]) * math.sin(0.1)).tolist()) for p in geo["poses"]]
    with pytest.raises(ReconstructionError, match="untilted detector") as info:
        mbirjax_geometry(dict(geo, poses=tilted))
    assert "\n" not in str(info.value) and "method='sart'" in str(info.value)
    moved = [dict(p, source=(CENTER + (np.asarray(p["source"]) - CENTER) * (1 + 0.01 * k)
                             ).tolist())
             for k, p in enumerate(geo["poses"])]
    with pytest.raises(ReconstructionError, match="one sid for every view"):
        mbirjax_geometry(dict(geo, poses=moved))
    with pytest.raises(ReconstructionError, match="iterations must be a whole number >= 1"):
        reconstruct(np.zeros((24, 24, 40), np.float32), geo, method="mbirjax", iterations=0)


@pytest.mark.slow
@pytest.mark.parametrize("pitch", [0.0, 40.0])
def test_mbirjax_puts_the_object_where_it_is(pitch):
    """A circular and a helical (2 turns, 40 mm per turn) scan of the off-centre ellipsoid:
    mbirjax's MBIR, resampled onto the world grid, has mean mu inside within 3 % and the
    centroid within a quarter voxel. Minutes the first time (JAX compiles), seconds after."""
    pytest.importorskip("mbirjax")
    _, result = helical_scan([0, 0, 1], pitch, n=40 if pitch else 20, shape=(32, 24),
                             det_pitch=4.0)
    vol = reconstruct(result.projections, result.geometry, voxel=5.0, shape=(16, 16, 16),
                      method="mbirjax", iterations=5)
    assert vol.method == "mbirjax" and vol.mu.dtype == np.float32
    check_ellipsoid(vol, tol=0.03)

"""The viewer draws a voxel volume as three orthogonal slices through its middle (issue 40),
a CT's in an HU window, beside the bodies (off-screen)."""

from __future__ import annotations

import numpy as np
import pytest

pv = pytest.importorskip("pyvista")

from xray_viz.scene import Body, Detector, Scene, Source  # noqa: E402
from xray_viz.viz.scene_view import (  # noqa: E402
    VOLUME_WINDOW,
    hu_window_limits,
    plot_scene,
    volume_slices,
)
from xray_viz.volume import ct_volume  # noqa: E402


def ct(shape=(18, 14, 10)):
    """A CT on a rotated, anisotropic grid: HU varying along every axis (each voxel its own)."""
    i, j, k = np.meshgrid(*(np.arange(n, dtype=float) for n in shape), indexing="ij")
    hu = -50.0 + 7.0 * i + 3.0 * j + 11.0 * k
    hu[:2] = -1000.0                       # air at one end
    angle = np.radians(20.0)
    rot = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                    [0, 0, 1]])
    a = np.eye(4)
    a[:3, :3] = rot * [1.5, 2.0, 2.5]
    a[:3, 3] = -a[:3, :3] @ ((np.array(shape) - 1) / 2)
    return hu, a


def test_the_three_slices_are_the_volumes_own_voxels():
    hu, a = ct()
    vol = ct_volume(hu, a, name="ct")
    slices = volume_slices(vol)
    inv = np.linalg.inv(vol.affine)
    centre = [n // 2 for n in vol.shape]
    for axis, name in enumerate("ijk"):
        grid = slices[name]
        idx = np.asarray(grid.points) @ inv[:3, :3].T + inv[:3, 3]
        np.testing.assert_allclose(idx[:, axis], centre[axis], atol=1e-9)   # one plane
        whole = np.round(idx).astype(int)
        np.testing.assert_allclose(idx, whole, atol=1e-9)                   # voxel centres
        assert grid.n_points == np.prod([vol.shape[m] for m in range(3) if m != axis])
        w = np.asarray(vol.weights, dtype=np.float64)[tuple(whole.T)]
        np.testing.assert_array_equal(grid.point_data["weight"], w)
        # the HU shown: 1000 (rho - 1) where rho = 1 + HU / 1000 (below 120 HU), air -1000
        c = vol.classes[tuple(whole.T)]
        expect = np.where(c > 0, np.round(1000 * (w - 1), 6), -1000.0)
        np.testing.assert_allclose(grid.point_data["hu"], expect)
        soft = (c > 0) & (hu[tuple(whole.T)] < 120)
        assert soft.any()
        # (the CT's own HU back, to float32 rounding of the density)
        np.testing.assert_allclose(grid.point_data["hu"][soft], hu[tuple(whole.T)][soft],
                                   atol=1e-3)


def test_the_viewer_shows_the_slices_in_the_hu_window_beside_the_bodies(tmp_path):
    import trimesh

    hu, a = ct((40, 32, 24))
    vol = ct_volume(hu, a, name="ct")
    pin = Body(name="pin", mesh=trimesh.creation.box(bounds=[[-3, -3, -8], [3, 3, 8]]),
               material="Ti", density=4.5)
    scene = Scene(source=Source(position=(0.0, 0.0, 400.0), energy=60.0),
                  detector=Detector(center=(0.0, 0.0, -150.0), up=(0.0, 1.0, 0.0),
                                    shape=(48, 40), pitch=2.0),
                  bodies=[pin], volumes=(vol,))
    view = plot_scene(scene, rays=None, window_size=(480, 360), off_screen=True)
    names = [f"volume:ct:slice:{a}" for a in "ijk"]
    for name in names + ["volume:ct:box", "body:pin"]:
        assert name in view.plotter.actors, name
    lo, hi = hu_window_limits(*VOLUME_WINDOW)
    for name in names:
        assert view.plotter.actors[name].GetMapper().GetScalarRange() == pytest.approx((lo, hi))
    view.set_volume_window(1500.0, 300.0)                        # a bone window
    for name in names:
        assert view.plotter.actors[name].GetMapper().GetScalarRange() == pytest.approx(
            (-450.0, 1050.0))
    shot = view.plotter.screenshot(str(tmp_path / "v.png"))
    assert shot.std() > 10                                        # something drawn
    view.set_visible("bodies", False)
    assert not any(view.plotter.actors[n].GetVisibility() for n in names)
    with pytest.raises(Exception, match="volume window must be a width > 0"):
        view.set_volume_window(0.0, 40.0)
    view.plotter.close()

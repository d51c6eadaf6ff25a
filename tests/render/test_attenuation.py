"""Path lengths and Beer-Lambert: nesting, overlaps, clipping at the detector."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.geometry import detector_rays
from helpers import box_chord, make_scene


def _box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    box = trimesh.creation.box(extents=hi - lo)
    box.apply_translation((lo + hi) / 2)
    return box


def test_nested_boxes_innermost_wins():
    outer, inner = _box([-30] * 3, [30] * 3), _box([-10, -12, -8], [14, 10, 9])
    mu_out, mu_in = 0.2, 1.5
    # Listed inner first: nesting, not list order, decides.
    scene = make_scene([inner, outer], mu=[mu_in, mu_out], shape=(41, 41), pitch=2.0,
                       names=["inner", "outer"])
    image = xray_viz.render(scene)
    rays = detector_rays(scene)
    Lo, _, _ = box_chord(rays.origins, rays.directions, [-30] * 3, [30] * 3)
    Li, _, _ = box_chord(rays.origins, rays.directions, [-10, -12, -8], [14, 10, 9])
    np.testing.assert_allclose(image.path_length[..., 0].ravel(), Li, atol=1e-6)
    np.testing.assert_allclose(image.path_length[..., 1].ravel(), Lo - Li, atol=1e-6)
    expected = (mu_out * (Lo - Li) + mu_in * Li) / 10.0
    np.testing.assert_allclose(image.line_integral.ravel(), expected, atol=1e-9)
    np.testing.assert_allclose(image.intensity, np.exp(-image.line_integral), rtol=1e-12)
    assert np.count_nonzero(Li) > 50


@pytest.mark.parametrize("order", [(0, 1), (1, 0)])
def test_partial_overlap_later_listed_wins(order):
    boxes = [_box([-20, -20, -20], [10, 20, 20]), _box([-5, -25, -10], [25, 15, 10])]
    mus = [0.3, 0.9]
    scene = make_scene([boxes[k] for k in order], mu=[mus[k] for k in order], shape=(41, 41),
                       pitch=2.0)
    image = xray_viz.render(scene)
    rays = detector_rays(scene)
    _, a0, b0 = box_chord(rays.origins, rays.directions, [-20, -20, -20], [10, 20, 20])
    _, a1, b1 = box_chord(rays.origins, rays.directions, [-5, -25, -10], [25, 15, 10])
    L0 = np.maximum(b0 - a0, 0)
    L1 = np.maximum(b1 - a1, 0)
    overlap = np.maximum(np.minimum(b0, b1) - np.maximum(a0, a1), 0)
    assert np.count_nonzero(overlap) > 50
    later = order[1]
    L = {later: [L0, L1][later], 1 - later: [L0, L1][1 - later] - overlap}
    for slot, k in enumerate(order):
        np.testing.assert_allclose(image.path_length[..., slot].ravel(), L[k], atol=1e-6)


def test_body_reaching_past_the_detector_is_counted_up_to_it():
    box = _box([-10, -10, -60], [10, 10, 10])          # the detector plane is z = -50
    scene = make_scene(box, source=(0, 0, 200), center=(0, 0, -50), shape=(21, 21), pitch=1.0)
    L = xray_viz.render(scene).total_path_length
    rays = detector_rays(scene)
    ref, _, _ = box_chord(rays.origins, rays.directions, [-10, -10, -60], [10, 10, 10], rays.t_max)
    np.testing.assert_allclose(L.ravel(), ref, atol=1e-6)
    assert L[10, 10] == pytest.approx(60.0)


def test_hits_kept_on_request_and_consistent_with_lengths():
    scene = make_scene(trimesh.creation.icosphere(subdivisions=3, radius=20.0), shape=(31, 31),
                       pitch=2.0)
    image = xray_viz.render(scene, keep_hits=True)
    hits = image.hits
    signed = np.where(hits.entering, -hits.t, hits.t)
    L = np.bincount(hits.ray, weights=signed, minlength=31 * 31).reshape(31, 31)
    np.testing.assert_allclose(L, image.total_path_length, atol=1e-9)
    assert xray_viz.render(scene).hits is None


def test_inside_out_body_built_in_code_is_repaired_with_a_warning_not_rendered_wrong():
    from xray_viz.meshes.repair import MeshRepairWarning

    good = trimesh.creation.icosphere(subdivisions=3, radius=20.0)
    flipped = trimesh.Trimesh(good.vertices, good.faces[:, ::-1], process=False)
    holed = trimesh.Trimesh(good.vertices, good.faces[5:], process=False)
    reference = xray_viz.render(make_scene(good, shape=(31, 31), pitch=2.0)).total_path_length
    for broken in (flipped, holed):
        with pytest.warns(MeshRepairWarning, match="body 'b0'"):
            scene = make_scene(broken, shape=(31, 31), pitch=2.0)
        L = xray_viz.render(scene).total_path_length
        np.testing.assert_allclose(L, reference, atol=0.5)      # hole closed: not exact, but close
        assert L.min() >= 0


def test_cli_prints_a_repair_warning_as_one_line(tmp_path):
    import subprocess
    import sys

    from helpers import write_scene
    from tests.scene.test_scene_file import GOOD

    good = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    flipped = trimesh.Trimesh(good.vertices, good.faces[:, ::-1], process=False)
    path = write_scene(tmp_path, GOOD, {"ball.stl": flipped})
    out = tmp_path / "a.npy"
    result = subprocess.run([sys.executable, "-m", "xray_viz.cli", "render", str(path), "-o",
                             str(out)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    warning = [l for l in result.stderr.splitlines() if l.startswith("xray-viz: warning:")]
    assert len(warning) == 1 and "'ball'" in warning[0] and "repaired" in warning[0]
    assert np.load(out).min() < 0.6                            # the ball attenuates


def test_transform_bodies_moves_every_body_and_keeps_nesting():
    from xray_viz.attenuation import _body_precedence
    from xray_viz.scene import Scene

    outer, inner = _box([-30] * 3, [30] * 3), _box([-10, -12, -8], [14, 10, 9])
    scene = make_scene([inner, outer], mu=[1.5, 0.2], shape=(41, 41), pitch=2.0,
                       names=["inner", "outer"])
    turn = trimesh.transformations.rotation_matrix(np.radians(35.0), [0, 1, 0.5], [3, -2, 1])
    turn[:3, 3] += [4.0, -3.0, 2.0]
    moved = scene.transform_bodies(turn)
    for a, b in zip(scene.bodies, moved.bodies):
        np.testing.assert_allclose(b.vertices, trimesh.transform_points(a.vertices, turn))
        assert a.vertices is not b.vertices
    # the carried-over precedence is what testing the moved bodies gives
    np.testing.assert_array_equal(moved.precedence, _body_precedence(moved.bodies))
    np.testing.assert_array_equal(moved.precedence, scene.precedence)
    # and the render equals that of a scene built from scratch with the moved meshes
    fresh = Scene(source=scene.source, detector=scene.detector,
                  bodies=tuple(dataclasses.replace(b, mesh=b.mesh.copy()) for b in moved.bodies))
    np.testing.assert_allclose(xray_viz.render(moved).path_length,
                               xray_viz.render(fresh, engine="numpy").path_length, atol=1e-9)
    mirror = np.diag([-1.0, 1.0, 1.0, 1.0])
    with pytest.raises(xray_viz.errors.SceneError, match="determinant"):
        scene.transform_bodies(mirror)
    with pytest.raises(xray_viz.errors.SceneError, match="4 x 4"):
        scene.transform_bodies(np.eye(3))


def test_body_precedence_is_remembered_per_mesh_data():
    from xray_viz.attenuation import body_precedence

    outer, inner = _box([-30] * 3, [30] * 3), _box([-10, -12, -8], [14, 10, 9])
    scene = make_scene([inner, outer], mu=[1.5, 0.2], shape=(5, 5), pitch=2.0)
    rank = body_precedence(scene)
    rank[:] = -7                                   # the caller's copy, not the cache
    np.testing.assert_array_equal(body_precedence(scene), [1, 0])
    inner.apply_translation([100.0, 0, 0])         # in place: no longer nested
    np.testing.assert_array_equal(body_precedence(scene), [0, 1])

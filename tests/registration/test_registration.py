"""2D/3D registration (issue 41): poses found from noisy synthetic X-ray images.

The target images are line integrals of :func:`xray_viz.registration.demo_stem` (an
asymmetric, implant-like stem) rendered by the fast engine at the true pose with Poisson
noise (``I0`` photons per pixel); the registration starts 5 mm / 5 degrees off and is
judged by the mean target registration error over the body's vertices (mTRE).
"""

from __future__ import annotations

import numpy as np
import pytest

import xray_viz
from xray_viz import gradients as G
from xray_viz import registration as R
from xray_viz.errors import SceneError
from xray_viz.scene import Body, Detector, Scene, Source


def _scene(shape=64, pitch=2.4, subdivisions=3):
    return Scene(source=Source(position=[0, 0, 600.0]),
                 detector=Detector(center=[0, 0, -300.0], shape=(shape, shape),
                                   pitch=(pitch, pitch)),
                 bodies=(Body(name="stem", mesh=R.demo_stem(subdivisions), mu=2.0),))


def _views(scene, rng, *, i0=1e5, angles=(0.0, 90.0)):
    out = []
    for angle in angles:
        acq = scene.acquisition.rotated(angle, axis=(0, 1, 0)) if angle else scene.acquisition
        li = xray_viz.render(scene.replace(acquisition=acq)).line_integral
        counts = rng.poisson(i0 * np.exp(-li))
        out.append((acq, -np.log(np.maximum(counts, 1) / i0)))
    return out


def _start(scene, rng, mm=5.0, degrees=5.0):
    d = rng.normal(size=3)
    a = rng.normal(size=3)
    p = np.r_[d * mm / np.linalg.norm(d), a * np.radians(degrees) / np.linalg.norm(a)]
    return G.pose_matrix(p, G.centroid(scene.bodies[0]))


def _errors(scene, reg, start):
    """mTRE and the mean in-plane (x, y) and out-of-plane (z, along the first view's beam)
    errors of the vertices, from the true pose."""
    total = reg.transforms["stem"] @ start
    v = np.c_[scene.bodies[0].vertices, np.ones(len(scene.bodies[0].vertices))]
    err = (v @ total.T - v)[:, :3]
    return (R.target_registration_error(scene.bodies[0], total),
            float(np.linalg.norm(err[:, :2], axis=1).mean()), float(np.abs(err[:, 2]).mean()))


def test_biplane_registration_from_5_mm_5_degrees_with_noise():
    rng = np.random.default_rng(0)
    scene = _scene()
    pairs = _views(scene, rng)
    start = _start(scene, rng)
    off = G.move_bodies(scene, {"stem": start})
    assert R.target_registration_error(scene.bodies[0], start) > 4.0
    reg = xray_viz.register(off, pairs, bodies=["stem"])
    mtre, _, _ = _errors(scene, reg, start)
    assert mtre < 0.1
    assert reg.loss < reg.initial_loss / 100
    assert reg.iterations > 0 and len(reg.history) > reg.iterations // 2
    assert set(reg.transforms) == {"stem"}
    # the fitted scene has the fitted body placement
    np.testing.assert_allclose(reg.scene.bodies[0].vertices,
                               off.bodies[0].vertices @ reg.transforms["stem"][:3, :3].T
                               + reg.transforms["stem"][:3, 3], atol=1e-9)


def test_single_view_registration_in_plane():
    rng = np.random.default_rng(1)
    scene = _scene()
    pairs = _views(scene, rng, angles=(0.0,))
    start = _start(scene, rng)
    off = G.move_bodies(scene, {"stem": start})
    reg = xray_viz.register(off, pairs[0][1], bodies="stem")     # the scene's own acquisition
    _, in_plane, out_of_plane = _errors(scene, reg, start)
    assert in_plane < 0.2
    assert out_of_plane < 2.0         # reported in BENCHMARKS.md; bounded here loosely


@pytest.mark.parametrize("similarity", ["ncc", "gc"])
def test_other_similarities_converge(similarity):
    rng = np.random.default_rng(2)
    scene = _scene(shape=32, pitch=4.8)
    pairs = _views(scene, rng)
    start = _start(scene, rng, mm=2.0, degrees=2.0)
    off = G.move_bodies(scene, {"stem": start})
    reg = xray_viz.register(off, pairs, bodies=["stem"], similarity=similarity, levels=(2, 1),
                            max_iterations=30)
    mtre, _, _ = _errors(scene, reg, start)
    assert mtre < 0.2
    assert reg.loss < reg.initial_loss


@pytest.mark.parametrize("similarity", ["ssd", "ncc", "gc"])
def test_similarity_gradients_are_exact(similarity):
    """The loss's gradient w.r.t. the (scaled) pose vector against central differences."""
    rng = np.random.default_rng(3)
    scene = _scene(shape=24, pitch=6.4)
    pairs = _views(scene, rng)
    problem = R._Problem(G.move_bodies(scene, {"stem": _start(scene, rng)}), ["stem"], pairs,
                         similarity)
    x = rng.normal(size=6) * 0.3
    if similarity == "ssd":
        r, jac = problem.residuals(x), problem.jacobian(x)
        value, grad = float(r @ r), 2 * jac.T @ r
    else:
        value, grad = problem.loss_and_grad(x)
    assert value > 0
    for j in range(6):
        e = np.zeros(6)
        e[j] = 1e-5
        fd = (problem.loss(x + e) - problem.loss(x - e)) / 2e-5
        assert abs(fd - grad[j]) <= 1e-4 * np.abs(grad).sum(), (j, fd, grad[j])


def test_bad_input_is_refused_in_one_line():
    scene = _scene(shape=16, pitch=9.6)
    image = np.zeros((16, 16))
    with pytest.raises(SceneError, match=r"image 0 has shape \(15, 16\)"):
        R.register(scene, np.zeros((15, 16)), bodies=["stem"])
    with pytest.raises(SceneError, match="no body named 'nope'"):
        R.register(scene, image, bodies=["nope"])
    with pytest.raises(SceneError, match="unknown similarity"):
        R.register(scene, image, bodies=["stem"], similarity="mi")
    away = G.move_bodies(scene, {"stem": G.pose_matrix([500.0, 0, 0, 0, 0, 0], [0, 0, 0])})
    with pytest.raises(SceneError, match="does not cross the beam"):
        R.register(away, image, bodies=["stem"])


@pytest.mark.slow
def test_biplane_success_rate_from_20_random_starts():
    """20 starts 5 mm / 5 degrees off, fresh noise each: mTRE < 0.1 mm in at least 95 %."""
    rng = np.random.default_rng(20)
    scene = _scene()
    ok = 0
    for _ in range(20):
        pairs = _views(scene, rng)
        start = _start(scene, rng)
        reg = xray_viz.register(G.move_bodies(scene, {"stem": start}), pairs, bodies=["stem"])
        ok += _errors(scene, reg, start)[0] < 0.1
    assert ok >= 19


def test_two_bodies_at_once():
    """Two bodies moved independently (a stem and a turned ellipsoid beside it), both found."""
    import trimesh
    from scipy.spatial.transform import Rotation

    ell = trimesh.creation.icosphere(subdivisions=3, radius=1.0)
    m = np.eye(4)
    m[:3, :3] = Rotation.from_rotvec([0.4, -0.3, 0.6]).as_matrix() @ np.diag([6.0, 11.0, 8.0])
    m[:3, 3] = [32.0, 12.0, 4.0]
    ell.apply_transform(m)
    base = _scene(shape=32, pitch=4.8)
    scene = base.replace(bodies=[base.bodies[0], Body(name="knob", mesh=ell, mu=1.5)])
    pairs = _views(scene, np.random.default_rng(4))
    starts = {"stem": G.pose_matrix([2, -1, 1, 0.03, 0.02, -0.02],
                                    G.centroid(scene.bodies[0])),
              "knob": G.pose_matrix([-1, 2, 0.5, -0.02, 0.04, 0.01],
                                    G.centroid(scene.bodies[1]))}
    reg = xray_viz.register(G.move_bodies(scene, starts), pairs, bodies=["stem", "knob"])
    for k, name in enumerate(("stem", "knob")):
        assert R.target_registration_error(scene.bodies[k],
                                           reg.transforms[name] @ starts[name]) < 0.1, name

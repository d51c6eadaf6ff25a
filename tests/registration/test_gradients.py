"""Exact pose gradients of line integrals (issue 41) against central finite differences.

Each check compares the exact derivative of ``sum(W * line_integral)`` (random weights ``W``)
with the central difference of renders of the moved scene. Meshes are smooth (icospheres) or
boxes turned off every axis, and steps are small (1e-4 mm, 2e-6 rad: displacements of ~1e-4
mm), so that no ray crosses a triangle edge within a step. The agreement asked for is 1e-4 of
``sum |W * gradient|`` (the size of the sum's terms: a component that cancels to ~0 by
symmetry is then compared with what it cancels from).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

import xray_viz
from xray_viz import gradients as G
from xray_viz.errors import SceneError
from xray_viz.scene import Body, Detector, Scene, Source

STEPS = (1e-4, 1e-4, 1e-4, 2e-6, 2e-6, 2e-6)


def _turned_box(extents, rotvec, shift):
    box = trimesh.creation.box(extents=extents)
    m = np.eye(4)
    m[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    m[:3, 3] = shift
    box.apply_transform(m)
    return box


def _scene(kind="point", *, spectrum=None, materials=False, shape=(40, 36), pitch=1.9,
           far=False):
    outer = trimesh.creation.icosphere(subdivisions=3, radius=28.0)
    outer.apply_translation([2.0, -1.0, 3.0])
    inner = _turned_box([12, 18, 10], [0.3, 0.5, 0.2], [3.0, -2.0, 1.0])
    if materials:
        bodies = [Body(name="outer", mesh=outer, material="H2O", density=1.0),
                  Body(name="inner", mesh=inner, material="Al", density=2.7)]
    else:
        bodies = [Body(name="outer", mesh=outer, mu=0.3), Body(name="inner", mesh=inner, mu=1.5)]
    if far:
        bodies.append(Body(name="far", mesh=trimesh.creation.icosphere(radius=5.0)
                           .apply_translation([400.0, 0, 0]), mu=1.0))
    source = Source(position=[10.0, 5.0, 600.0], kind=kind,
                    **({"spectrum": spectrum} if spectrum else {}))
    detector = Detector(center=[0.0, 0.0, -300.0], up=[0.1, 1.0, 0.0], shape=shape,
                        pitch=(pitch, pitch))
    return Scene(source=source, detector=detector, bodies=tuple(bodies))


def _fd_pose(scene, name, center, weights, j):
    def f(s):
        p = np.zeros(6)
        p[j] = s
        moved = G.move_bodies(scene, {name: G.pose_matrix(p, center)})
        return float((weights * xray_viz.render(moved, engine="numpy").line_integral).sum())
    h = STEPS[j]
    return (f(h) - f(-h)) / (2 * h)


def _check_all(scene, names, seed=0):
    res = G.line_integral_gradient(scene, names)
    rng = np.random.default_rng(seed)
    weights = rng.standard_normal(res.line_integral.shape)
    for k, name in enumerate(res.names):
        scale = np.abs(weights * res.pose[k]).sum()
        assert scale > 0
        for j in range(6):
            exact = float((weights * res.pose[k, j]).sum())
            fd = _fd_pose(scene, name, res.centers[k], weights, j)
            assert abs(fd - exact) <= 1e-4 * scale, (name, j, fd, exact, scale)
    return res


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_nested_bodies_translations_and_rotations_match_finite_differences(kind):
    scene = _scene(kind)
    res = _check_all(scene, None)
    assert res.names == ["outer", "inner"]
    # the line integral is render's, before the detector model
    np.testing.assert_allclose(res.line_integral, xray_viz.render(scene).line_integral,
                               rtol=0, atol=1e-11)


def test_nested_inner_chord_is_taken_from_the_outer_body():
    """Moving the outer sphere along x while the inner box stays: the rays through the box
    lose nothing of the outer material inside it; the inner body's gradient moves the box's
    chord from (mu_in - mu_out) only."""
    scene = _scene("parallel")
    g = G.pose_gradient(scene, ["inner"])[0]
    # moving the box changes each ray's line integral by (mu_in - mu_out) times its chord's
    # change: compare with a scene where the outer body is air (mu -> tiny): scaled exactly
    thin = scene.replace(bodies=[dataclasses.replace(scene.bodies[0], mu=1e-9),
                                 scene.bodies[1]])
    g_alone = G.pose_gradient(thin, ["inner"])[0]
    ratio = (1.5 - 0.3) / (1.5 - 1e-9 / 1.0)
    np.testing.assert_allclose(g, g_alone * ratio, rtol=1e-12, atol=1e-15)
    assert np.abs(g).max() > 0


def test_polychromatic_beam_by_the_chain_rule():
    from xray_viz.physics.spectra import Spectrum

    spectrum = Spectrum([30.0, 50.0, 70.0, 90.0], [0.2, 0.4, 0.3, 0.1])
    scene = _scene("point", spectrum=spectrum, materials=True, shape=(28, 24), pitch=2.6)
    res = _check_all(scene, ["inner", "outer"])
    np.testing.assert_allclose(res.line_integral, xray_viz.render(scene).line_integral,
                               rtol=1e-12, atol=1e-12)


def test_supersampled_pixels():
    scene = _scene("point", shape=(20, 18), pitch=3.8)
    scene = scene.replace(detector=dataclasses.replace(scene.detector, supersample=2))
    res = _check_all(scene, ["inner"])
    np.testing.assert_allclose(res.line_integral, xray_viz.render(scene).line_integral,
                               rtol=0, atol=1e-11)


def test_a_body_outside_the_beam_has_exact_zeros():
    scene = _scene("point", far=True, shape=(24, 24), pitch=3.0)
    g = G.pose_gradient(scene)
    assert g.shape == (3, 6, 24, 24)
    assert not np.any(g[2])
    assert np.any(g[0]) and np.any(g[1])
    # bodies in the order asked for
    np.testing.assert_array_equal(G.pose_gradient(scene, ["inner", "outer"])[0], g[1])


def test_unknown_body_is_refused_in_one_line():
    with pytest.raises(SceneError, match="no body named 'nope'"):
        G.pose_gradient(_scene("point", shape=(8, 8), pitch=10.0), ["nope"])


def _moved_acquisition(scene, params, center):
    m = G.pose_matrix(params, center)
    r = m[:3, :3]
    src = dataclasses.replace(scene.source, position=(m @ [*scene.source.position, 1.0])[:3])
    det = dataclasses.replace(scene.detector, center=(m @ [*scene.detector.center, 1.0])[:3],
                              up=r @ scene.detector.up)
    return scene.replace(source=src, detector=det)


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_acquisition_pose_gradient(kind):
    """The source and detector moved together (a rigid C-arm) about a centre off the axis."""
    scene = _scene(kind, shape=(30, 28), pitch=2.5)
    center = np.array([5.0, -3.0, 20.0])
    res = G.line_integral_gradient(scene, [], acquisition=True, center=center)
    assert res.pose.shape == (0, 6, 28, 30)
    rng = np.random.default_rng(1)
    weights = rng.standard_normal(res.line_integral.shape)
    scale = np.abs(weights * res.acquisition).sum()
    for j in range(6):
        def f(s):
            p = np.zeros(6)
            p[j] = s
            return float((weights * xray_viz.render(_moved_acquisition(scene, p, center),
                                                    engine="numpy").line_integral).sum())
        fd = (f(STEPS[j]) - f(-STEPS[j])) / (2 * STEPS[j])
        exact = float((weights * res.acquisition[j]).sum())
        assert abs(fd - exact) <= 1e-4 * scale, (j, fd, exact, scale)
    np.testing.assert_array_equal(G.acquisition_gradient(scene, center=center), res.acquisition)


def test_plane_formula_is_moller_trumbore_chained_with_the_vertex_velocities():
    """dt = n.(tau + omega x (p - c)) / n.d equals the derivative of t = n.(v0 - o)/(n.d)
    with respect to the three vertices, chained with their rigid velocities."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        v = rng.normal(size=(3, 3)) * 10
        o = np.array([0.3, -0.2, 50.0])
        bary = rng.dirichlet([1, 1, 1])
        target = bary @ v
        d = (target - o) / np.linalg.norm(target - o)
        c = rng.normal(size=3)
        tau, omega = rng.normal(size=3), rng.normal(size=3)

        def t_of(verts):
            n = np.cross(verts[1] - verts[0], verts[2] - verts[0])
            return n @ (verts[0] - o) / (n @ d)
        vel = tau + np.cross(omega, v - c)                # (3, 3): each vertex's velocity
        h = 1e-6
        chained = (t_of(v + h * vel) - t_of(v - h * vel)) / (2 * h)
        n = np.cross(v[1] - v[0], v[2] - v[0])
        p = o + t_of(v) * d
        formula = (n @ tau + omega @ np.cross(p - c, n)) / (n @ d)
        assert abs(chained - formula) <= 1e-7 * (1 + abs(formula))


def test_centroid_and_pose_matrix():
    box = _turned_box([10, 20, 30], [0.2, -0.4, 0.7], [5.0, 6.0, 7.0])
    np.testing.assert_allclose(G.centroid(Body(name="b", mesh=box, mu=1.0)), [5, 6, 7],
                               atol=1e-12)
    m = G.pose_matrix([1, 2, 3, 0.1, 0.2, 0.3], [5.0, 6.0, 7.0])
    np.testing.assert_allclose(m[:3, :3] @ m[:3, :3].T, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(m @ [5, 6, 7, 1], [6, 8, 10, 1], atol=1e-12)


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_fast_kernel_matches_the_reference(kind):
    """Bodies apart: the numba kernel over the fast engine's path lengths gives the reference's
    numbers (a tilted detector, a spectrum, the acquisition's gradient too)."""
    from xray_viz.physics.spectra import Spectrum

    outer = trimesh.creation.icosphere(subdivisions=3, radius=20.0)
    box = _turned_box([12, 18, 10], [0.3, 0.5, 0.2], [40.0, -2.0, 1.0])
    scene = Scene(source=Source(position=[10.0, 5.0, 600.0], kind=kind,
                                spectrum=Spectrum([30.0, 60.0, 90.0], [0.3, 0.5, 0.2])),
                  detector=Detector(center=[0.0, 0.0, -300.0], shape=(48, 40), pitch=(2.0, 2.0),
                                    u=[1.0, 0.0, 0.1], v=[0.0, 1.0, 0.0]),
                  bodies=(Body(name="ball", mesh=outer, material="H2O", density=1.0),
                          Body(name="box", mesh=box, material="Al", density=2.7)))
    assert G._apart(scene, [0, 1])
    fast = G.line_integral_gradient(scene, acquisition=True, engine="fast")
    ref = G.line_integral_gradient(scene, acquisition=True, engine="numpy")
    scale = np.abs(ref.pose).max()
    assert scale > 0
    np.testing.assert_allclose(fast.line_integral, ref.line_integral, rtol=0, atol=1e-10)
    np.testing.assert_allclose(fast.pose, ref.pose, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(fast.acquisition, ref.acquisition, rtol=0, atol=1e-10 * scale)
    # through the one compile manager: its one explicit signature, nothing else compiled
    from xray_viz import _gradient_kernels as K

    kernel = K.KERNELS.kernel("body_pose_gradient")
    assert kernel.signatures == [K.SIGNATURES["body_pose_gradient"]]
    assert not kernel._can_compile


def test_nested_bodies_through_the_kernel_match_the_reference():
    """A box inside a sphere: the kernel gives the box's hits the slope g(box) - g(sphere) and
    the sphere's g(sphere) - 0 (its parent's material outside it)."""
    scene = _scene("point", shape=(40, 36), pitch=1.9)
    assert not G._apart(scene, [0]) and G.nesting(scene) == [[], [0]]
    fast = G.line_integral_gradient(scene, acquisition=True, engine="fast")
    ref = G.line_integral_gradient(scene, acquisition=True, engine="numpy")
    scale = np.abs(ref.pose).max()
    np.testing.assert_allclose(fast.pose, ref.pose, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(fast.acquisition, ref.acquisition, rtol=0, atol=1e-10 * scale)


def test_partly_overlapping_bodies_take_the_reference():
    outer = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    poking = _turned_box([12, 18, 10], [0.3, 0.5, 0.2], [18.0, 0.0, 0.0])
    scene = Scene(source=Source(position=[0.0, 0.0, 600.0]),
                  detector=Detector(center=[0.0, 0.0, -300.0], shape=(24, 20), pitch=(3.0, 3.0)),
                  bodies=(Body(name="a", mesh=outer, mu=0.3), Body(name="b", mesh=poking, mu=1.0)))
    assert G._parents(scene, [0, 1], G.nesting(scene)) is None
    np.testing.assert_array_equal(G.pose_gradient(scene, engine="fast"),
                                  G.pose_gradient(scene, engine="numpy"))


def test_unknown_gradient_engine():
    with pytest.raises(SceneError, match="unknown gradient engine 'gpu'"):
        G.pose_gradient(_scene("point", shape=(8, 8), pitch=10.0), engine="gpu")

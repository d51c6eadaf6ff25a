"""The compiled self-intersection test selects the same faces as pymeshlab (issue 18).

:mod:`xray_viz.meshes._check_kernels` reproduces pymeshlab's
``compute_selection_by_self_intersections_per_face`` (vcglib's arithmetic, in its order): the
selected faces must be the same set, face for face, on every bundled phantom, on the
deliberately self-intersecting meshes of the tests, on perturbed and overlapping meshes (many
pairs near the decision: coplanar faces, shared vertices, touching boxes) and on triangle
soups with repeated corners; and, per piece, the same as pymeshlab run on each group of pieces
(:func:`xray_viz.meshes.repair._self_crossing_pymeshlab`).
"""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

import xray_viz
from tests.helpers import random_rotation
from tests.test_self_intersection import CROSSING, square_tube
from xray_viz import phantoms
from xray_viz.meshes import _check_kernels as K
from xray_viz.meshes import repair


def _both(vertices, faces, pieces=None):
    kernel = K.self_intersections(vertices, faces, pieces)
    if pieces is None:
        reference = repair._pymeshlab_self_intersections(vertices, np.asarray(faces, np.int64))
    else:
        reference = repair._self_crossing_pymeshlab(np.asarray(vertices, float),
                                                     np.asarray(faces, np.int64),
                                                     np.asarray(pieces, np.int64))
    return kernel, reference


def _assert_same(vertices, faces, pieces=None):
    kernel, reference = _both(vertices, faces, pieces)
    assert kernel.dtype == bool and kernel.shape == (len(faces),)
    np.testing.assert_array_equal(kernel, reference)
    return int(kernel.sum())


@pytest.mark.parametrize("name", phantoms.names())
def test_same_faces_as_pymeshlab_on_every_phantom(name):
    scene = xray_viz.load_scene(name)
    meshes = [b.mesh for b in scene.bodies]
    for m in meshes:
        _assert_same(m.vertices, m.faces)
    # all bodies as one triangle set: the bodies that overlap or nest cross each other
    both = trimesh.util.concatenate(meshes) if len(meshes) > 1 else meshes[0]
    pieces = np.repeat(np.arange(len(meshes)), [len(m.faces) for m in meshes])
    _assert_same(both.vertices, both.faces)
    _assert_same(both.vertices, both.faces, pieces)


def test_same_faces_on_the_self_intersecting_test_meshes():
    tube = square_tube(CROSSING)
    assert _assert_same(tube.vertices, tube.faces) > 0
    ball = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    v = ball.vertices.copy()
    v[v[:, 2] > 6.0, 2] -= 14.0                 # the folded cap of test_self_intersection
    assert _assert_same(v, ball.faces) > 0
    a = trimesh.creation.box(extents=[2, 2, 2])
    for shift in ([1, 0.5, 0.25], [1, 0, 0], [0.5, 0.5, 0], [2, 0, 0], [0, 0, 0]):
        b = a.copy()
        b.apply_translation(shift)                # crossing, coplanar overlaps, touching
        both = trimesh.util.concatenate([a, b])
        _assert_same(both.vertices, both.faces)
        assert _assert_same(both.vertices, both.faces, np.repeat([0, 1], 12)) == 0


@pytest.mark.parametrize("seed", range(4))
def test_same_faces_on_perturbed_and_overlapping_spheres(seed):
    rng = np.random.default_rng(seed)
    counts = []
    for sub, noise in [(2, 0.05), (3, 0.02), (3, 0.1), (3, 0.4), (4, 0.01), (4, 0.05)]:
        s = trimesh.creation.icosphere(subdivisions=sub)
        v = s.vertices + rng.normal(scale=noise, size=s.vertices.shape)
        counts.append(_assert_same(v, s.faces))
    assert min(counts) == 0 < max(counts)
    # overlapping copies of a sphere, some on a grid of 1/8 (exactly coplanar faces, shared
    # coordinates), some rotated at random, as one set and by piece
    s = trimesh.creation.icosphere(subdivisions=2)
    parts = []
    for k in range(4):
        v = s.vertices @ random_rotation(rng).T
        if k % 2:
            v = np.round(v * 8) / 8
        parts.append(trimesh.Trimesh(v + rng.uniform(-0.8, 0.8, 3), s.faces, process=False))
    union = trimesh.util.concatenate(parts)
    pieces = np.repeat(np.arange(4), len(s.faces))
    assert _assert_same(union.vertices, union.faces) > 0
    _assert_same(union.vertices, union.faces, pieces)


@pytest.mark.parametrize("seed", range(3))
def test_same_faces_on_triangle_soups(seed):
    """Random faces on a coarse lattice: repeated corners, duplicate faces, faces sharing one
    or two vertices, coplanar and collinear corners."""
    rng = np.random.default_rng(100 + seed)
    v = rng.uniform(size=(300, 3))
    _assert_same(v, rng.integers(0, 300, size=(200, 3)))
    lattice = rng.integers(0, 4, size=(60, 3)) / 3.0
    _assert_same(lattice, rng.integers(0, 60, size=(300, 3)))
    flat = lattice.copy()
    flat[:, 2] = 0.0                              # every face in one plane
    _assert_same(flat, rng.integers(0, 60, size=(100, 3)))


def test_degenerate_inputs():
    assert K.self_intersections(np.zeros((0, 3)), np.zeros((0, 3), int)).shape == (0,)
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    assert not K.self_intersections(tri, [[0, 1, 2]]).any()
    # the same three vertices twice: pymeshlab counts a pair of coincident faces
    _assert_same(tri, [[0, 1, 2], [0, 1, 2]])
    _assert_same(np.zeros((3, 3)), [[0, 1, 2], [0, 1, 2], [0, 0, 1]])    # all in one point


def test_check_mesh_is_the_same_with_the_kernel_and_with_pymeshlab(monkeypatch):
    tube = square_tube(CROSSING)
    b = tube.copy()
    b.apply_translation([0, 0, 30])
    two = trimesh.util.concatenate([tube, b])     # two self-crossing pieces, apart
    reports = []
    for ready in (True, False):
        monkeypatch.setattr(K, "is_ready", lambda r=ready: r)
        reports.append([repair.check_mesh(m, cache=False) for m in (tube, two)])
    assert reports[0] == reports[1]
    assert reports[0][1].self_intersections == 2 * reports[0][0].self_intersections > 0


def test_each_kernel_has_its_one_specialisation():
    """Explicit signatures: compiled (or loaded) once, then nothing else compiles."""
    assert K.compile_kernels() == list(K.SIGNATURES) and K.is_ready()
    K.self_intersections(np.zeros((3, 3), np.float32), np.zeros((2, 3), np.int32))
    K.edge_facts(np.zeros((1, 3), np.int32), 3)
    for name, sig in K.SIGNATURES.items():
        assert getattr(K, name).signatures == [sig], name


def test_vertices_that_are_not_finite_are_left_to_pymeshlab():
    tube = square_tube(CROSSING)
    v = tube.vertices.copy()
    v[0] = np.nan
    with pytest.raises(ValueError):
        K.self_intersections(v, tube.faces)
    np.testing.assert_array_equal(repair.self_intersecting_faces(v, tube.faces),
                                  repair._pymeshlab_self_intersections(v, tube.faces))

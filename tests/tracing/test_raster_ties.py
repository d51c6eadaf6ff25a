"""The fast engine's tie rule on GIANT triangles (projected boxes wider than 256 fine-grid steps:
the exact limb-arithmetic copies of the edge test): fine-grid samples placed exactly on the
shared edges and the shared vertex of a fan of such triangles are each covered exactly once by
a surface sheet, so that every ray through the body has its whole chord, in the one-body raster,
the banded one-body raster and the several-bodies raster, with a point and a parallel beam.

The tie rule is written once (``xray_viz.tracing._primitives.tie_positive``); its other callers
meet the same fan: the watertight intersection (the NumPy engine), the Monte Carlo's crossing
test and the pose gradients' pixel coverage each take every sample on a shared edge exactly
once, so that a broken rule fails here in each of them."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from xray_viz import _gradient_kernels as GK
from xray_viz.geometry import detector_rays
from xray_viz.montecarlo import geometry as MG
from xray_viz.tracing import _raster as R
from xray_viz.tracing import fast
from xray_viz.tracing.intersect import watertight_intersect
from helpers import make_scene

SOURCE_Z = 1000.0
DETECTOR_Z = -500.0
FRONT_Z, BACK_Z = 30.0, -40.0
HALF = 300.5          # the square's half width on the detector (mm = samples): between samples
SHAPE = (641, 641)    # pitch 1 mm: samples at the integers -320 .. 320


def _on_plane(xd, yd, z, kind):
    """The point of plane ``z`` that projects onto the detector point ``(xd, yd)``."""
    if kind == "parallel":
        return [xd, yd, z]
    s = (SOURCE_Z - z) / (SOURCE_Z - DETECTOR_Z)
    return [xd * s, yd * s, z]


#: The back face's fan centre (detector mm): no sample lies on the back face's inner edges, so
#: that a sample covered twice (or never) by the front face shows in every raster, the
#: several-bodies sweep included (there a sheet covered twice on both faces would not show).
BACK_CENTRE = (0.25, 0.375)
RING = [(-HALF, -HALF), (0.0, -HALF), (HALF, -HALF), (HALF, 0.0),
        (HALF, HALF), (0.0, HALF), (-HALF, HALF), (-HALF, 0.0)]


def _fan_frustum(kind):
    """A closed body whose front and back faces both project onto the square
    ``|x|, |y| <= HALF`` of the detector, each as 8 triangles fanned around a centre. The
    front's centre is a sample: its shared edges lie on the sample rows ``x = 0``, ``y = 0``
    and the diagonals ``x = +-y``, through 301 samples each. The sides lie in planes through
    the source (point beam) or along the beam (parallel): projected, they have no area."""
    front = [(0.0, 0.0)] + RING
    back = [BACK_CENTRE] + RING
    V = np.array([_on_plane(x, y, FRONT_Z, kind) for x, y in front]
                 + [_on_plane(x, y, BACK_Z, kind) for x, y in back])
    n = len(front)
    faces = []
    for k in range(8):
        a, b = 1 + k, 1 + (k + 1) % 8
        # front, facing the source (+z); vertices rotated so that each edge of the triangle
        # (a->b, b->c, c->a: each its own tie bias) is an inner one for some triangles
        faces.append(list(np.roll([0, a, b], k % 3)))
        faces.append([n, n + b, n + a])                  # back
        faces += [[a, a + n, b], [b, a + n, b + n]]      # side
    mesh = trimesh.Trimesh(V, np.array(faces), process=False)
    assert mesh.is_watertight and mesh.is_volume
    return mesh


def test_no_sample_lies_on_the_back_faces_inner_edges():
    """Exact in eighths of a millimetre: the cross product of each inner edge of the back
    face with every sample of its box is not zero."""
    X, Y = np.meshgrid(np.arange(-320, 321), np.arange(-320, 321))
    cx, cy = (int(8 * c) for c in BACK_CENTRE)
    for rx, ry in RING:
        rx, ry = int(8 * rx), int(8 * ry)
        box = ((8 * X >= min(cx, rx)) & (8 * X <= max(cx, rx))
               & (8 * Y >= min(cy, ry)) & (8 * Y <= max(cy, ry)))
        cross = (rx - cx) * (8 * Y - cy) - (ry - cy) * (8 * X - cx)
        assert box.sum() > 0 and not np.any(box & (cross == 0))


def _far_box(kind):
    """A small second body beside the square (no ray meets both): several bodies."""
    box = trimesh.creation.box(extents=[8.0, 8.0, 8.0])
    box.apply_translation(_on_plane(-312.0, 312.0, 0.0, kind))
    return box


def _scene(kind, several):
    meshes = [_fan_frustum(kind)] + ([_far_box(kind)] if several else [])
    return make_scene(meshes, kind=kind, source=(0.0, 0.0, SOURCE_Z),
                      center=(0.0, 0.0, DETECTOR_Z), shape=SHAPE, pitch=1.0)


def _chords(scene):
    """The frustum's exact chord of every ray: the slab between its two planes, inside the
    square."""
    rays = detector_rays(scene)
    hit = rays.origins + rays.directions * np.asarray(rays.t_max).reshape(-1, 1)
    inside = (np.abs(hit[:, 0]) < HALF) & (np.abs(hit[:, 1]) < HALF)
    on_shared = inside & ((np.abs(hit[:, 0]) < 1e-9) | (np.abs(hit[:, 1]) < 1e-9)
                          | (np.abs(np.abs(hit[:, 0]) - np.abs(hit[:, 1])) < 1e-9))
    return np.where(inside, (FRONT_Z - BACK_Z) / np.abs(rays.directions[:, 2]), 0.0), on_shared


@pytest.mark.parametrize("path", ["direct", "banded", "several"])
@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_samples_on_shared_edges_of_giant_triangles_are_covered_once(kind, path, monkeypatch):
    scene = _scene(kind, several=path == "several")
    # The fan's triangles take the GIANT path: their projected boxes are wider than the limit.
    assert 2 * HALF / 2 * (1 << R.FRAC_BITS) > R.SAFE_EXTENT
    if path == "banded":
        monkeypatch.setattr(fast, "_DIRECT_MAX_SAMPLES", 0)
    L = fast.trace_once(scene)
    want, on_shared = _chords(scene)
    assert on_shared.sum() == 4 * 601 - 3           # rows, columns and diagonals; centre once
    np.testing.assert_allclose(L[:, 0], want, rtol=1e-12, atol=1e-9)
    # Each sample on a shared edge: its whole chord (not 0 nor 2 chords).
    assert np.all(np.abs(L[on_shared, 0] - want[on_shared]) < 1e-9 * want[on_shared])
    if path == "several":
        assert (L[:, 1] > 0).sum() > 20 and not np.any((L[:, 0] > 0) & (L[:, 1] > 0))


def _front_fan():
    """The parallel frustum's front face: its 8 triangles, ``(8, 3, 3)``, in the plane
    ``z = FRONT_Z`` (the fan of :func:`_fan_frustum`, vertices in its order)."""
    mesh = _fan_frustum("parallel")
    return mesh.vertices[np.asarray(mesh.faces)[0::4]]


def _fan_samples(every):
    """Samples ``(x, y)`` (mm) inside the square: each one on a shared edge of the front fan
    (the rows ``x = 0``, ``y = 0``, the diagonals) and every ``every``-th of the others; and
    which are on an edge."""
    X, Y = np.meshgrid(np.arange(-300, 301), np.arange(-300, 301))
    on = (X == 0) | (Y == 0) | (np.abs(X) == np.abs(Y))
    keep = on | ((X % every == 0) & (Y % every == 0))
    assert on.sum() == 4 * 601 - 3
    return X[keep].astype(float), Y[keep].astype(float), on[keep]


def test_rays_on_shared_edges_hit_one_triangle_of_the_watertight_intersection():
    """The NumPy engine's test (:func:`watertight_intersect`): each ray down ``-z`` through a
    sample hits exactly one triangle of the fan, on its edges and at its centre too."""
    x, y, on = _fan_samples(7)
    n = len(x)
    origins = np.c_[x, y, np.full(n, 100.0)]
    dirs = np.tile([0.0, 0.0, -1.0], (n, 1))
    hits = np.zeros(n, int)
    for tri in _front_fan():
        hit, t, _, entering = watertight_intersect(origins, dirs, *(np.tile(v, (n, 1))
                                                                    for v in tri))
        assert np.all(t[hit] == 100.0 - FRONT_Z) and np.all(entering[hit])
        hits += hit
    assert on.sum() == 4 * 601 - 3 and np.all(hits == 1)


def test_photons_on_shared_edges_cross_one_triangle_in_the_monte_carlo():
    """The Monte Carlo's crossing test of one triangle (``montecarlo.geometry._triangle``,
    numba): a photon down ``-z`` through a sample crosses exactly one triangle of the fan."""
    x, y, on = _fan_samples(20)
    d = np.array([0.0, 0.0, -1.0])
    frame = MG.ray_frame(d)
    fan = _front_fan()
    hits = np.zeros(len(x), int)
    for k in range(len(x)):
        o = np.array([x[k], y[k], 100.0])
        for tri in fan:
            t, entering = MG._triangle(o, d, tri[0], tri[1], tri[2], *frame)
            if np.isfinite(t):
                assert t == 100.0 - FRONT_Z and entering
                hits[k] += 1
    assert on.sum() == 4 * 601 - 3 and np.all(hits == 1)


def test_pixels_on_shared_edges_count_once_in_the_pose_gradients():
    """The pose gradients' kernel (``_gradient_kernels.body_pose_gradient``, pixel centres on
    an edge by the tie rule): with the fan alone (a sheet facing the beam) the derivative along
    ``z`` of every pixel inside the square is one hit's, on the shared edges and at the centre
    too (a pixel taken twice has twice, one taken by none has 0)."""
    w = h = SHAPE[0]
    pixels = GK.pixel_grid(np.array([-320.0, -320.0, DETECTOR_Z]), np.array([1.0, 0.0, 0.0]),
                           np.array([0.0, 1.0, 0.0]), np.eye(2), np.zeros(3),
                           np.array([0.0, 0.0, -1.0]), 2000.0, True, w, h)
    mesh = _fan_frustum("parallel")
    out = np.zeros((6, w * h))
    GK.KERNELS.kernel("body_pose_gradient")(
        np.ascontiguousarray(mesh.vertices, dtype=np.float64),
        np.ascontiguousarray(np.asarray(mesh.faces)[0::4], dtype=np.int64), np.zeros(3), pixels,
        np.ones(w * h), out)
    dz = out[2].reshape(h, w)
    X, Y = np.meshgrid(np.arange(-320, 321), np.arange(-320, 321))
    inside = (np.abs(X) < HALF) & (np.abs(Y) < HALF)
    one = dz[320, 320]                 # the centre: the vertex of all 8 triangles
    assert one != 0.0
    assert np.all(dz[inside] == one) and np.all(dz[~inside] == 0.0)

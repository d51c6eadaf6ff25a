"""Trilinear interpolation of voxel volumes (issue 40: an option, not the default).

What is checked: a field linear in x, y, z on a rotated, anisotropic grid is integrated
exactly along rays inside the voxel centres' hull (the trapezoid of its end values, 1e-12);
the product x y z (a cubic along a ray) exactly against its polynomial integral; whole rays
through the box, several classes and mesh intervals against SciPy (map_coordinates order 1,
mode "nearest", integrated by quad between the cell planes); the classes' columns add up to
the interpolation of the weights; the default (no key, "nearest") is the exact voxel traversal
bit for bit; the scene key; a bad value is one line and exit 2.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import integrate, ndimage

import xray_viz
from xray_viz.errors import SceneError
from xray_viz.tracing.voxels import voxel_sums

SHAPE = (7, 5, 6)
SPACING = np.array([1.5, 2.0, 2.5])


def _rotation(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = math.radians(deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * (k @ k)


def affine():
    a = np.eye(4)
    a[:3, :3] = _rotation((0.3, 1.0, -0.4), 23.0) * SPACING
    a[:3, 3] = [1.0, -2.0, 0.5]
    return a


def index_grid():
    return np.meshgrid(*(np.arange(n, dtype=float) for n in SHAPE), indexing="ij")


def rays_inside(rng, n):
    """Rays (origin, unit direction, length) whose both ends lie in [0, n - 1]^3 in index
    space: inside the voxel centres' hull, where the interpolation is that of the field."""
    a = affine()
    hi = np.array(SHAPE) - 1.0
    p0 = rng.uniform(0.0, 1.0, (n, 3)) * hi
    p1 = rng.uniform(0.0, 1.0, (n, 3)) * hi
    w0 = p0 @ a[:3, :3].T + a[:3, 3]
    w1 = p1 @ a[:3, :3].T + a[:3, 3]
    length = np.linalg.norm(w1 - w0, axis=1)
    return w0, (w1 - w0) / length[:, None], length, p0, p1


def test_a_linear_field_is_integrated_exactly():
    i, j, k = index_grid()
    coef = np.array([0.7, -0.3, 0.45])
    field = 2.0 + coef[0] * i + coef[1] * j + coef[2] * k
    classes = np.ones(SHAPE, np.uint8)
    o, d, length, p0, p1 = rays_inside(np.random.default_rng(1), 300)
    got = voxel_sums(o, d, length, affine(), classes, field, n_classes=1,
                     interpolation="trilinear")[:, 0]
    f0, f1 = 2.0 + p0 @ coef, 2.0 + p1 @ coef
    expect = length * (f0 + f1) / 2     # a linear function's integral: the trapezoid
    np.testing.assert_allclose(got, expect, rtol=1e-12)
    # the nearest voxels are not the field: the option changes the result
    nearest = voxel_sums(o, d, length, affine(), classes, field, n_classes=1)[:, 0]
    assert np.max(np.abs(nearest - expect) / expect) > 1e-3


def test_a_trilinear_product_is_integrated_exactly():
    """x y z is its own trilinear interpolant; along a ray it is a cubic in t."""
    i, j, k = index_grid()
    field = 1.0 + i * j * k
    classes = np.ones(SHAPE, np.uint8)
    o, d, length, p0, p1 = rays_inside(np.random.default_rng(2), 200)
    got = voxel_sums(o, d, length, affine(), classes, field, n_classes=1,
                     interpolation="trilinear")[:, 0]
    expect = []
    for a, b, L in zip(p0, p1, length):
        # f(s) = 1 + prod(a + s (b - a)), s in [0, 1]; the integral over t is L x that over s
        poly = np.polynomial.Polynomial([1.0])
        for m in range(3):
            poly = poly * np.polynomial.Polynomial([a[m], b[m] - a[m]])
        poly = poly + 1.0
        anti = poly.integ()
        expect.append(L * (anti(1.0) - anti(0.0)))
    np.testing.assert_allclose(got, expect, rtol=1e-12)


def _reference(o, d, t_max, field, skip=()):
    """SciPy: quad of map_coordinates(order=1, mode='nearest') between the cell planes, over
    the part of the ray inside the grid's box; ``skip``: intervals of t left out."""
    a = affine()
    inv = np.linalg.inv(a)
    p = inv[:3, :3] @ o + inv[:3, 3]
    e = inv[:3, :3] @ d
    n = np.array(SHAPE)
    t0, t1 = 0.0, t_max
    for m in range(3):
        ta, tb = (-0.5 - p[m]) / e[m], (n[m] - 0.5 - p[m]) / e[m]
        t0, t1 = max(t0, min(ta, tb)), min(t1, max(ta, tb))
    if t1 <= t0:
        return 0.0
    breaks = [t0, t1]
    for m in range(3):
        breaks += [(c - p[m]) / e[m] for c in range(n[m])]
    for s0, s1 in skip:
        breaks += [s0, s1]
    breaks = np.unique(np.clip(breaks, t0, t1))

    def f(t):
        q = (p + t * e)[:, None]
        return ndimage.map_coordinates(field, q, order=1, mode="nearest")[0]

    total = 0.0
    for lo, hi in zip(breaks[:-1], breaks[1:]):
        mid = 0.5 * (lo + hi)
        if any(s0 <= mid < s1 for s0, s1 in skip):
            continue
        total += integrate.quad(f, lo, hi, epsabs=1e-13, epsrel=1e-13)[0]
    return total


def test_whole_rays_classes_and_intervals_against_scipy():
    rng = np.random.default_rng(3)
    classes = rng.integers(0, 3, SHAPE).astype(np.uint8)     # 0 empty, classes 1 and 2
    weights = rng.uniform(0.5, 2.0, SHAPE)
    centre = affine()[:3, :3] @ ((np.array(SHAPE) - 1) / 2) + affine()[:3, 3]
    n = 12
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    o = centre - 40.0 * d + rng.uniform(-3, 3, (n, 3))
    t_max = np.full(n, 80.0)
    # each ray leaves out one stretch (a mesh body inside the volume)
    start = np.arange(n + 1, dtype=np.int64)
    iv0 = np.full(n, 38.0)
    iv1 = np.full(n, 41.5)
    full = voxel_sums(o, d, t_max, affine(), classes, weights, n_classes=2,
                      interpolation="trilinear")
    cut = voxel_sums(o, d, t_max, affine(), classes, weights, n_classes=2,
                     interpolation="trilinear", intervals=(start, iv0, iv1))
    for r in range(n):
        for c in (1, 2):
            per_class = np.where(classes == c, weights, 0.0)
            ref = _reference(o[r], d[r], t_max[r], per_class)
            assert full[r, c - 1] == pytest.approx(ref, rel=1e-9, abs=1e-12)
            ref_cut = _reference(o[r], d[r], t_max[r], per_class, skip=[(iv0[r], iv1[r])])
            assert cut[r, c - 1] == pytest.approx(ref_cut, rel=1e-9, abs=1e-12)
        # the classes' columns add up to the interpolation of all the weights
        total = _reference(o[r], d[r], t_max[r], np.where(classes > 0, weights, 0.0))
        assert full[r].sum() == pytest.approx(total, rel=1e-9)
    assert np.all(cut <= full + 1e-12) and np.any(cut < full - 1e-3)


def test_bad_interpolation_in_the_kernel_is_one_line():
    with pytest.raises(SceneError, match="interpolation must be one of") as info:
        voxel_sums(np.zeros((1, 3)), np.array([[1.0, 0, 0]]), np.ones(1), np.eye(4),
                   np.ones((2, 2, 2), np.uint8), np.ones((2, 2, 2)), n_classes=1,
                   interpolation="cubic")
    assert "\n" not in str(info.value)


SCENE = """
[source]
position = [0.0, 0.0, 300.0]
kind = "point"
energy = 60.0

[detector]
center = [0.0, 0.0, -100.0]
up = [0.0, 1.0, 0.0]
shape = [24, 20]
pitch = 2.0

[[ct]]
file = "ct.nii.gz"
{extra}
"""


def write_ct(tmp_path):
    import nibabel as nib

    rng = np.random.default_rng(4)
    hu = np.full((16, 14, 10), -1000.0)
    hu[2:14, 2:12, 2:8] = rng.uniform(-100.0, 80.0, (12, 10, 6))    # fat and soft tissue
    hu[6:10, 5:9, 3:7] = 900.0                                       # bone
    a = np.diag([2.0, 2.0, 3.0, 1.0])
    a[:3, 3] = -a[:3, :3] @ ((np.array(hu.shape) - 1) / 2)
    nib.save(nib.Nifti1Image(hu.astype(np.int16), a), tmp_path / "ct.nii.gz")


def _render(tmp_path, extra):
    (tmp_path / "s.toml").write_text(SCENE.format(extra=extra))
    scene = xray_viz.load_scene(tmp_path / "s.toml")
    return scene, xray_viz.render(scene, path_lengths=True)


def test_the_default_is_the_exact_voxels_bit_for_bit(tmp_path):
    write_ct(tmp_path)
    scene, default = _render(tmp_path, "")
    assert scene.volumes[0].interpolation == "nearest"
    _, nearest = _render(tmp_path, 'interpolation = "nearest"')
    np.testing.assert_array_equal(default.path_length, nearest.path_length)
    np.testing.assert_array_equal(default.intensity, nearest.intensity)
    scene_t, tri = _render(tmp_path, 'interpolation = "trilinear"')
    assert scene_t.volumes[0].interpolation == "trilinear"
    assert not np.array_equal(tri.path_length, default.path_length)
    assert np.all(np.isfinite(tri.intensity)) and np.all(tri.path_length >= 0)


def test_a_bad_interpolation_is_one_line_and_exit_2(tmp_path, capsys):
    write_ct(tmp_path)
    (tmp_path / "s.toml").write_text(SCENE.format(extra='interpolation = "cubic"'))
    with pytest.raises(SceneError, match="interpolation must be \"nearest\"") as info:
        xray_viz.load_scene(tmp_path / "s.toml")
    assert "\n" not in str(info.value) and "[[ct]] #1" in str(info.value)
    from xray_viz.cli import main

    out = tmp_path / "x.png"
    assert main(["render", str(tmp_path / "s.toml"), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "interpolation" in err[0] and not out.exists()
    (tmp_path / "m.toml").write_text(SCENE.format(
        extra='trace = "meshes"\ninterpolation = "trilinear"'))
    with pytest.raises(SceneError, match="only applies to trace = \"voxels\""):
        xray_viz.load_scene(tmp_path / "m.toml")


def test_the_interpolation_survives_writing_the_scene(tmp_path):
    write_ct(tmp_path)
    scene, image = _render(tmp_path, 'interpolation = "trilinear"')
    text = scene.to_toml(tmp_path / "back.toml")
    assert 'interpolation = "trilinear"' in text
    back = xray_viz.load_scene(tmp_path / "back.toml")
    assert back.volumes[0].interpolation == "trilinear"
    np.testing.assert_array_equal(xray_viz.render(back).intensity, image.intensity)

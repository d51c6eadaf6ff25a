"""Volumes traced as voxels (issue 40): the exact voxel traversal (xray_viz.tracing.voxels),
the VoxelVolume (xray_viz.volume), meshes inside volumes, and [[ct]] / [[labels]] with
``trace = "voxels"``.

What is checked: constant blocks against their analytic chords (1e-9 relative) on a rotated,
anisotropic grid with point and parallel beams and tilted / offset detectors; the kernel
against a NumPy reference of every (ray, voxel) chord; the same blocks as meshes through both
mesh engines; an implant in a uniform block and in a CT (the implant's path exact, the
volume's reduced by exactly the displaced chords); a render through the scene file; one-line
errors for a NaN voxel, a singular affine and a bad ``trace``; the overlap warning.
"""

from __future__ import annotations

import dataclasses
import math
import warnings

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import SceneError
from xray_viz.geometry import detector_rays
from xray_viz.scene import Body, Detector, Scene, Source
from xray_viz.tracing.engines import ENGINES
from xray_viz.tracing.voxels import grid_chords, voxel_sums
from xray_viz.volume import (
    VolumeOverlapWarning,
    VoxelVolume,
    ct_volume,
    label_volume,
    mesh_intervals,
    volume_path_lengths,
)

SHAPE = (20, 16, 12)
SPACING = np.array([1.5, 2.0, 2.5])


def _rotation(axis, deg):
    a = np.asarray(axis, float) / np.linalg.norm(axis)
    t = math.radians(deg)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * (k @ k)


def grid_affine(rotated=True):
    a = np.eye(4)
    rot = _rotation((0.3, 1.0, -0.4), 23.0) if rotated else np.eye(3)
    a[:3, :3] = rot * SPACING
    a[:3, 3] = -a[:3, :3] @ ((np.array(SHAPE) - 1) / 2) + [1.0, -2.0, 0.5]
    return a


#: Blocks of voxels: (class, index ranges [lo, hi) per axis, weight)
BLOCKS = [
    (1, (2, 9), (3, 12), (1, 10), 1.0),
    (2, (11, 18), (1, 7), (2, 11), 1.7),
    (3, (11, 18), (8, 15), (3, 9), 0.4),
]


def block_volume(affine, *, dtype=np.float64):
    classes = np.zeros(SHAPE, np.uint8)
    weights = np.zeros(SHAPE, dtype)
    for c, (i0, i1), (j0, j1), (k0, k1), w in BLOCKS:
        classes[i0:i1, j0:j1, k0:k1] = c
        weights[i0:i1, j0:j1, k0:k1] = w
    return classes, weights


def analytic(origins, directions, t_max, affine):
    """Per ray and block: weight x the chord through the block's parallelepiped (slabs)."""
    inv = np.linalg.inv(affine)
    n = len(t_max)
    origins = np.broadcast_to(origins, (n, 3))
    directions = np.broadcast_to(directions, (n, 3))
    p = origins @ inv[:3, :3].T + inv[:3, 3]
    d = directions @ inv[:3, :3].T
    out = np.zeros((n, len(BLOCKS)))
    for b, (c, *ranges, w) in enumerate(BLOCKS):
        t0, t1 = np.zeros(n), np.array(t_max, float)
        for a, (lo, hi) in enumerate(ranges):
            with np.errstate(divide="ignore", invalid="ignore"):
                ta = (lo - 0.5 - p[:, a]) / d[:, a]
                tb = (hi - 0.5 - p[:, a]) / d[:, a]
            lo_t, hi_t = np.minimum(ta, tb), np.maximum(ta, tb)
            flat = d[:, a] == 0
            inside = (p[:, a] >= lo - 0.5) & (p[:, a] <= hi - 0.5)
            lo_t = np.where(flat, np.where(inside, -np.inf, np.inf), lo_t)
            hi_t = np.where(flat, np.where(inside, np.inf, -np.inf), hi_t)
            t0, t1 = np.maximum(t0, lo_t), np.minimum(t1, hi_t)
        out[:, c - 1] = w * np.maximum(t1 - t0, 0.0)
    return out


def _scene(kind="point", detector=None, bodies=(), volumes=(), shape=(40, 32), pitch=1.5,
           source=(3.0, -2.0, 400.0)):
    det = dict(center=[0.0, 0.0, -150.0], up=[0.0, 1.0, 0.0], shape=shape,
               pitch=(pitch, pitch))
    det.update(detector or {})
    return Scene(source=Source(position=list(source), kind=kind, energy=60.0),
                 detector=Detector(**det), bodies=bodies, volumes=volumes)


U30 = _rotation((0.3, 1.0, -0.2), 30.0)
GEOMETRIES = {
    "plain": {},
    "tilt+offset": {"u": (U30 @ [1.0, 0, 0]).tolist(), "v": (U30 @ [0, 1.0, 0]).tolist(),
                    "offset": (-7.0, 5.5)},
}


# --------------------------------------------------------------------------------------------
# the kernel


@pytest.mark.parametrize("kind", ["point", "parallel"])
@pytest.mark.parametrize("geometry", sorted(GEOMETRIES))
def test_constant_blocks_match_their_analytic_chords(kind, geometry):
    affine = grid_affine()
    classes, weights = block_volume(affine)
    scene = _scene(kind, GEOMETRIES[geometry])
    rays = detector_rays(scene)
    got = voxel_sums(rays.origins, rays.directions, rays.t_max, affine, classes, weights,
                     n_classes=3)
    want = analytic(rays.origins, rays.directions, rays.t_max, affine)
    assert (want > 0).any(axis=0).all() and (want.sum(1) > 0).sum() > 200
    np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-9 * 40.0)


def test_kernel_matches_every_voxel_chord_of_a_numpy_reference():
    rng = np.random.default_rng(5)
    affine = grid_affine()
    shape = (7, 9, 6)
    classes = rng.integers(0, 4, shape).astype(np.uint8)
    weights = rng.uniform(0.5, 2.0, shape)
    n = 300
    middle = affine[:3, :3] @ ((np.array(shape) - 1) / 2) + affine[:3, 3]
    origins = rng.normal(0, 10, (n, 3)) + middle + [0, 0, -60]
    target = rng.normal(0, 4, (n, 3)) + middle
    directions = target - origins
    directions /= np.linalg.norm(directions, axis=1)[:, None]
    t_max = rng.uniform(60, 150, n)                     # some rays end inside the grid
    got = voxel_sums(origins, directions, t_max, affine, classes, weights, n_classes=3,
                     threads=3)
    ray, vox, chord = grid_chords(origins, directions, t_max, affine, shape)
    want = np.zeros((n, 3))
    c = classes[vox[:, 0], vox[:, 1], vox[:, 2]].astype(int)
    k = c > 0
    np.add.at(want, (ray[k], c[k] - 1), weights[tuple(vox[k].T)] * chord[k])
    assert (want > 0).sum() > 100
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)


def test_the_axis_order_copy_gives_the_same_sums_to_rounding():
    affine = grid_affine()
    classes, weights = block_volume(affine)
    rng = np.random.default_rng(2)
    weights = weights * rng.uniform(0.5, 1.5, weights.shape)
    vol = VoxelVolume(name="v", affine=affine, classes=classes, weights=weights,
                      materials=tuple(xray_viz.volume.VoxelMaterial(f"c{c}", mu=1.0)
                                      for c in (1, 2, 3)))
    rays = detector_rays(_scene("point", GEOMETRIES["tilt+offset"]))
    plain = vol.trace(rays.origins, rays.directions, rays.t_max)
    for across in ([1.0, 0, 0], [0, 1.0, 0], [0.2, 0.3, 1.0]):
        got = vol.trace(rays.origins, rays.directions, rays.t_max, across=across)
        np.testing.assert_allclose(got, plain, rtol=1e-12, atol=1e-12)
    assert len(vol._layouts) <= 1


def test_float32_weights_round_within_their_stated_error():
    affine = grid_affine()
    classes, w64 = block_volume(affine)
    w64 = w64 * 1.0123456789
    scene = _scene("point")
    rays = detector_rays(scene)
    a = voxel_sums(rays.origins, rays.directions, rays.t_max, affine, classes, w64, n_classes=3)
    b = voxel_sums(rays.origins, rays.directions, rays.t_max, affine, classes,
                   w64.astype(np.float32), n_classes=3)
    np.testing.assert_allclose(b, a, rtol=6e-8, atol=0)


# --------------------------------------------------------------------------------------------
# against the meshes of the same blocks


def block_meshes(affine):
    import trimesh

    out = []
    for c, *ranges, w in BLOCKS:
        lo = np.array([r[0] for r in ranges]) - 0.5
        hi = np.array([r[1] for r in ranges]) - 0.5
        box = trimesh.creation.box(bounds=[lo, hi])
        box.apply_transform(affine)                     # index space -> world
        out.append(Body(name=f"block{c}", mesh=box, mu=0.1 * c))
    return out


@pytest.mark.parametrize("kind", ["point", "parallel"])
@pytest.mark.parametrize("geometry", sorted(GEOMETRIES))
def test_voxels_agree_with_the_meshes_of_the_same_blocks_in_both_engines(kind, geometry):
    affine = grid_affine()
    classes, weights = block_volume(affine)
    weights = (classes > 0).astype(np.float64)          # mesh bodies have one density
    vol = VoxelVolume(name="blocks", affine=affine, classes=classes, weights=weights,
                      materials=tuple(xray_viz.volume.VoxelMaterial(f"v{c}", mu=0.1 * c)
                                      for c in (1, 2, 3)))
    meshed = _scene(kind, GEOMETRIES[geometry], bodies=block_meshes(affine))
    voxels = _scene(kind, GEOMETRIES[geometry], volumes=(vol,))
    V = volume_path_lengths(voxels)
    assert (V.sum(1) > 0).sum() > 200
    for engine in ("numpy", "fast"):
        L = ENGINES[engine].path_lengths(meshed.bodies, meshed.acquisition)
        np.testing.assert_allclose(V, L, rtol=1e-9, atol=1e-9)
    # and the images: the same line integrals through render
    a = xray_viz.render(meshed).line_integral
    b = xray_viz.render(voxels).line_integral
    np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-12)


# --------------------------------------------------------------------------------------------
# meshes in volumes


def test_a_ball_in_a_uniform_block_displaces_exactly_its_chords():
    import trimesh

    affine = np.eye(4)
    affine[:3, 3] = -19.5                                # 40 mm cube of 1 mm voxels at 0
    vol = label_volume(np.ones((40, 40, 40), int), affine, {1: {"mu": 0.2}}, name="block")
    ball = Body(name="ball", mesh=trimesh.creation.icosphere(subdivisions=4, radius=8.0),
                material="Ti", density=4.5)
    for kind in ("point", "parallel"):
        scene = _scene(kind, bodies=[ball], volumes=(vol,), shape=(48, 48), pitch=0.5)
        rays = detector_rays(scene)
        block = analytic_box(rays, -20.0, 20.0)
        V = volume_path_lengths(scene)[:, 0]
        for engine in ("numpy", "fast"):
            L = ENGINES[engine].path_lengths(scene.bodies, scene.acquisition)[:, 0]
            assert L.max() > 15.9
            np.testing.assert_allclose(V + L, block, rtol=1e-12, atol=1e-9)
        image = xray_viz.render(scene, path_lengths=True)
        per = image.path_length.reshape(-1, 2)
        np.testing.assert_allclose(per[:, 1] + per[:, 0], block, atol=1e-9)


def test_meshes_around_and_apart_from_a_volume_add_to_it():
    """A water tank around the whole block of voxels and a ball apart from it (inside the
    tank): neither displaces a voxel. The block's column is its analytic chord, the tank's its
    own whole chord (the block does not take it), and the line integral is their sum with
    the ball's (which wins over the tank it is nested in, as between meshes)."""
    import trimesh

    affine = np.eye(4)
    affine[:3, 3] = -19.5                                # 40 mm cube of 1 mm voxels at 0
    vol = label_volume(np.ones((40, 40, 40), int), affine, {1: {"mu": 0.2}}, name="block")
    tank = Body(name="tank", mu=0.02,
                mesh=trimesh.creation.box(bounds=[[-60, -60, -30], [60, 60, 30]]))
    ball = trimesh.creation.icosphere(subdivisions=4, radius=8.0)
    ball.apply_translation([38.0, 0.0, 0.0])             # beside the block
    ball = Body(name="ball", mesh=ball, mu=0.5)
    scene = _scene("parallel", bodies=[tank, ball], volumes=(vol,), shape=(64, 32), pitch=2.0,
                   source=(0.0, 0.0, 400.0))
    rays = detector_rays(scene)
    image = xray_viz.render(scene, path_lengths=True)
    assert image.body_names == ["tank", "ball", "block_1"]
    per = image.path_length.reshape(-1, 3)
    block = analytic_box(rays, -20.0, 20.0)
    np.testing.assert_allclose(per[:, 2], block, rtol=1e-12, atol=1e-9)
    on_ball = per[:, 1] > 0
    assert on_ball.sum() > 10 and (block > 0).sum() > 100 and not (on_ball & (block > 0)).any()
    np.testing.assert_allclose(per[:, 0] + per[:, 1], np.where(per[:, 0] > 0, 60.0, 0.0),
                               atol=1e-9)                 # the tank less the ball's chord
    assert (per[:, 0][block > 0] == 60.0).all()          # the block takes nothing of the tank
    np.testing.assert_allclose(image.line_integral.ravel(),
                               (per[:, 0] * 0.02 + per[:, 1] * 0.5 + per[:, 2] * 0.2) / 10.0,
                               rtol=1e-12)


def analytic_box(rays, lo, hi):
    t0, t1 = np.zeros(len(rays)), rays.t_max.copy()
    for a in range(3):
        d = rays.directions[:, a]
        o = rays.origins[:, a]
        with np.errstate(divide="ignore"):
            ta, tb = (lo - o) / d, (hi - o) / d
        t0 = np.maximum(t0, np.where(d == 0, np.where((o > lo) & (o < hi), 0, np.inf),
                                     np.minimum(ta, tb)))
        t1 = np.minimum(t1, np.where(d == 0, np.inf, np.maximum(ta, tb)))
    return np.maximum(t1 - t0, 0.0)


def test_intervals_are_the_union_of_overlapping_and_nested_meshes():
    import trimesh

    from xray_viz.bodies import Bodies

    a = trimesh.creation.box(bounds=[[-5, -5, -10], [5, 5, 0]])
    b = trimesh.creation.box(bounds=[[-5, -5, -4], [5, 5, 6]])        # overlaps a
    c = trimesh.creation.box(bounds=[[-1, -1, 8], [1, 1, 9]])         # apart
    d = trimesh.creation.box(bounds=[[-1, -1, 8.2], [1, 1, 8.5]])     # inside c
    bodies = Bodies([Body(name=n, mesh=m, mu=1.0) for n, m in zip("abcd", (a, b, c, d))])
    o = np.array([[0.0, 0.0, -50.0], [3.0, 3.0, -50.0]])
    start, t0, t1 = mesh_intervals(bodies, [0, 1, 2, 3], o, np.array([[0, 0, 1.0]]),
                                   np.array([100.0, 100.0]))
    assert start.tolist() == [0, 2, 3]
    np.testing.assert_allclose(np.c_[t0, t1], [[40, 56], [58, 59], [40, 56]])


def ct_hu(n=48):
    """A ball of soft tissue (HU varying linearly with z: contrast inside the organ) around a
    ball of cortical bone, in air; 1 mm voxels centred on the origin."""
    idx = np.indices((n, n, n)) - (n - 1) / 2
    r = np.sqrt((idx ** 2).sum(0))
    hu = np.where(r <= 20, 30.0 + 2.0 * idx[2], -1000.0)
    hu[r <= 8] = 1200.0
    affine = np.eye(4)
    affine[:3, 3] = -(n - 1) / 2
    return hu, affine


def test_an_implant_in_a_ct_keeps_its_path_and_takes_exactly_its_chords_from_the_ct():
    import trimesh

    hu, affine = ct_hu()
    vol = ct_volume(hu, affine, name="ct", dtype=np.float64)
    rod = trimesh.creation.cylinder(radius=2.5, height=16.0, sections=48)
    rod.apply_translation([0.0, 0.0, 3.0])              # half in the bone, half in tissue
    implant = Body(name="rod", mesh=rod, material="Ti", density=4.5)
    axial = dict(shape=(40, 40), pitch=0.5, source=(0.0, 0.0, 400.0))
    scene = _scene("parallel", bodies=[implant], volumes=(vol,), **axial)
    bare = _scene("parallel", volumes=(vol,), **axial)
    rays = detector_rays(scene)
    with_rod = volume_path_lengths(scene)
    without = volume_path_lengths(bare)
    for engine in ("numpy", "fast"):
        L = ENGINES[engine].path_lengths(scene.bodies, scene.acquisition)[:, 0]
        on = np.hypot(rays.origins[:, 0], rays.origins[:, 1]) < 2.0
        np.testing.assert_allclose(L[on], 16.0, atol=1e-9)   # the whole rod, bone or not
        # what the rod took from the CT: its stretches' voxel chords x density, exactly
        start, t0, t1 = mesh_intervals(scene.bodies, [0], rays.origins, rays.directions,
                                       rays.t_max)
        inside_only = np.zeros_like(without)
        for r in np.flatnonzero(np.diff(start)):
            for q in range(start[r], start[r + 1]):
                o = rays.origins[r] + t0[q] * rays.directions[r]
                sub = voxel_sums(o[None], rays.directions[r][None], np.array([t1[q] - t0[q]]),
                                 affine, vol.classes, vol.weights, n_classes=5)
                inside_only[r] += sub[0]
        np.testing.assert_allclose(without - with_rod, inside_only, rtol=1e-9, atol=1e-9)
    # density varies voxel by voxel: soft tissue at 30 + 2 z HU
    soft = vol.classes == 3
    np.testing.assert_allclose(vol.weights[soft], 1.0 + hu[soft] / 1000.0, rtol=1e-15)
    assert np.ptp(vol.weights[soft]) > 0.04
    bone = vol.classes == 5
    np.testing.assert_allclose(vol.weights[bone], 1.017 + 0.592e-3 * 1200.0, rtol=1e-15)


# --------------------------------------------------------------------------------------------
# the scene file


def write_ct(tmp_path, hu, affine, name="ct.nii.gz"):
    import nibabel as nib

    nib.save(nib.Nifti1Image(hu.astype(np.float32), affine), str(tmp_path / name))


SCENE = """
[source]
position = [0, 0, 400]
kind = "point"
spectrum = {{ kvp = 80.0, filters = {{ Al = 2.5 }} }}
[detector]
center = [0, 0, -150]
up = [0.0, 1.0, 0.0]
shape = [64, 64]
pitch = 1.0
{body}
[[ct]]
file = "ct.nii.gz"
{extra}
"""

IMPLANT = """
[[body]]
name = "screw"
mesh = "screw.stl"
material = "Ti"
density = 4.5
"""


def test_a_ct_scene_renders_as_voxels_by_default_with_the_implant(tmp_path):
    import trimesh

    hu, affine = ct_hu()
    write_ct(tmp_path, hu, affine)
    screw = trimesh.creation.cylinder(radius=1.5, height=14.0)
    screw.apply_transform(trimesh.transformations.rotation_matrix(1.2, [0, 1, 0]))
    screw.apply_translation([6.0, 4.0, 0.0])
    screw.export(tmp_path / "screw.stl")
    (tmp_path / "s.toml").write_text(SCENE.format(body=IMPLANT, extra=""))
    scene = xray_viz.load_scene(tmp_path / "s.toml")
    assert scene.bodies.names == ["screw"] and len(scene.volumes) == 1
    image = xray_viz.render(scene, path_lengths=True)
    names = image.body_names
    assert names[0] == "screw" and "ct_soft_tissue" in names and "ct_cortical_bone" in names
    alone = ENGINES["numpy"].path_lengths(scene.bodies, scene.acquisition)
    assert alone.max() > 2.9
    np.testing.assert_allclose(image.path_length[..., 0].ravel(), alone[:, 0], atol=1e-9)
    fast, ref = image.line_integral, xray_viz.render(scene, engine="numpy").line_integral
    np.testing.assert_allclose(fast, ref, rtol=1e-12, atol=1e-12)
    tissue = image.path_length[..., names.index("ct_soft_tissue")]
    assert tissue.max() > 20.0


def test_nrrd_mha_and_a_dicom_series_give_the_niftis_voxel_volume(tmp_path):
    """The same CT (whole HU, a rotated grid of unequal spacings) as NIfTI, NRRD, MetaImage
    and a DICOM series (slices in shuffled files, stored + 1024 with its rescale): ``[[ct]]``
    (voxels by default) reads one volume from each - the same voxels at the same places, to
    the float32 of the files - and one image (to the float32 of the affines: 1e-5)."""
    pytest.importorskip("SimpleITK")
    pytest.importorskip("pydicom")
    from tests.meshes.test_volumes import write_dicom_series, write_itk

    hu, _ = ct_hu(32)
    hu = np.round(hu)
    affine = np.eye(4)
    affine[:3, :3] = _rotation((0.3, 1.0, -0.4), 23.0) * [1.1, 1.3, 1.6]
    affine[:3, 3] = -affine[:3, :3] @ ((np.array(hu.shape) - 1) / 2)
    files = {"nifti": "ct.nii.gz", "nrrd": "nrrd/ct.nrrd", "mha": "mha/ct.mha",
             "dicom": "dicom/ct"}
    write_ct(tmp_path, hu, affine)
    for kind in ("nrrd", "mha"):
        (tmp_path / kind).mkdir()
        write_itk(tmp_path / files[kind], hu.astype(np.float32), affine)
    (tmp_path / "dicom").mkdir()
    write_dicom_series(tmp_path / files["dicom"], hu, affine)
    volumes, images = {}, {}
    for kind, name in files.items():
        text = SCENE.format(body="", extra="").replace('file = "ct.nii.gz"', f'file = "{name}"')
        (tmp_path / f"{kind}.toml").write_text(text)
        scene = xray_viz.load_scene(tmp_path / f"{kind}.toml")
        (volumes[kind],) = scene.volumes
        images[kind] = xray_viz.render(scene).line_integral
    ref = volumes["nifti"]
    assert images["nifti"].max() > 1.0 and len(np.unique(ref.classes)) == 4
    inverse = np.linalg.inv(ref.affine)
    for kind in ("nrrd", "mha", "dicom"):
        vol = volumes[kind]          # its axes maybe in another order (each reader's layout)
        assert vol.names == ref.names and sorted(vol.shape) == sorted(ref.shape)
        idx = np.indices(vol.shape).reshape(3, -1).T
        centres = idx @ vol.affine[:3, :3].T + vol.affine[:3, 3]
        at = centres @ inverse[:3, :3].T + inverse[:3, 3]       # the NIfTI's voxel indices
        assert np.abs(at - np.rint(at)).max() < 1e-4, kind
        at = tuple(np.rint(at).astype(int).T)
        np.testing.assert_array_equal(vol.classes.reshape(-1), ref.classes[at])
        np.testing.assert_allclose(vol.weights.reshape(-1), ref.weights[at], rtol=1e-7)
        np.testing.assert_allclose(images[kind], images["nifti"], rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("response", ["energy", "counting"])
def test_a_ct_and_its_implant_under_a_spectrum_are_the_explicit_sum_over_energies(tmp_path,
                                                                                  response):
    """mu(E) per voxel for any spectrum: the CT's columns are its classes' g/cm2 (density x
    chord, voxel by voxel), the implant's its mm; the image is the sum over the spectrum's
    bins of exp(-sum of mass attenuation x column), computed here by hand from xraylib."""
    import trimesh
    import xraylib

    hu, affine = ct_hu(32)
    write_ct(tmp_path, hu, affine)
    screw = trimesh.creation.cylinder(radius=1.5, height=14.0)
    screw.apply_transform(trimesh.transformations.rotation_matrix(1.2, [0, 1, 0]))
    screw.apply_translation([6.0, 4.0, 0.0])
    screw.export(tmp_path / "screw.stl")
    (tmp_path / "spec.csv").write_text("keV,fluence\n30,2\n45,5\n60,4\n75,1\n")
    text = SCENE.format(body=IMPLANT, extra="").replace(
        "spectrum = { kvp = 80.0, filters = { Al = 2.5 } }", 'spectrum = { file = "spec.csv" }'
    ).replace("pitch = 1.0", f'pitch = 1.0\nresponse = "{response}"')
    (tmp_path / "s.toml").write_text(text)
    scene = xray_viz.load_scene(tmp_path / "s.toml")
    (vol,) = scene.volumes
    image = xray_viz.render(scene, path_lengths=True)
    names = image.body_names
    assert names == ["screw", *vol.names]
    energies, fluence = [30, 45, 60, 75], np.array([2, 5, 4, 1], float)
    weights = fluence * energies if response == "energy" else fluence
    expected = np.zeros(image.intensity.shape)
    for e, w in zip(energies, weights):
        total = xraylib.CS_Total_CP("Ti", e) * 4.5 * image.path_length[..., 0] / 10.0
        for c, m in enumerate(vol.materials, start=1):     # g/cm3 x mm -> g/cm2
            total = total + xraylib.CS_Total_CP(m.material, e) * image.path_length[..., c] / 10.0
        expected += w * np.exp(-total)
    expected /= weights.sum()
    soft = image.path_length[..., names.index("ct_soft_tissue")]
    bone = image.path_length[..., names.index("ct_cortical_bone")]
    assert soft.max() > 20.0 and bone.max() > 10.0 and image.path_length[..., 0].max() > 2.9
    np.testing.assert_allclose(image.intensity, expected, rtol=1e-12)


@pytest.mark.parametrize("extra, expect", [
    ('trace = "pixels"', 'trace must be "voxels"'),
    ('trace = "voxels"\nmax_error = 0.2', "'max_error' only applies to trace"),
])
def test_bad_trace_keys_are_one_line(tmp_path, extra, expect):
    hu, affine = ct_hu(8)
    write_ct(tmp_path, hu, affine)
    (tmp_path / "s.toml").write_text(SCENE.format(body="", extra=extra))
    with pytest.raises(SceneError, match=expect) as info:
        xray_viz.load_scene(tmp_path / "s.toml")
    assert "\n" not in str(info.value) and "[[ct]] #1" in str(info.value)


def test_nan_voxels_and_singular_affines_are_one_line(tmp_path):
    from xray_viz.errors import MeshError

    hu, affine = ct_hu(8)
    hu[2, 3, 4] = np.nan
    with pytest.raises(SceneError, match=r"1 voxel\(s\) are NaN .* index \[2, 3, 4\]"):
        ct_volume(hu, affine)
    write_ct(tmp_path, hu, affine)
    (tmp_path / "s.toml").write_text(SCENE.format(body="", extra=""))
    with pytest.raises(MeshError, match="NaN or infinite") as info:
        xray_viz.load_scene(tmp_path / "s.toml")
    assert "[[ct]] #1" in str(info.value) and "\n" not in str(info.value)
    hu, _ = ct_hu(8)
    for bad, expect in ((np.diag([1.0, 0.0, 1.0, 1.0]), "singular"),
                        (np.diag([1.0, np.nan, 1.0, 1.0]), "NaN or infinite")):
        with pytest.raises(SceneError, match=expect):
            ct_volume(hu, bad)


def test_a_mesh_overlapping_the_volume_edge_is_warned_about_once(tmp_path):
    import trimesh

    hu, affine = ct_hu(16)
    vol = ct_volume(hu, affine)
    poking = trimesh.creation.box(bounds=[[-2, -2, 5], [2, 2, 12]])   # grid ends at z = 8
    with pytest.warns(VolumeOverlapWarning, match="body 'pin' reaches out of volume 'ct'"):
        _scene(bodies=[Body(name="pin", mesh=poking, mu=1.0)], volumes=(vol,))
    tank = trimesh.creation.box(bounds=[[-30, -30, -30], [30, 30, 30]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _scene(bodies=[Body(name="tank", mesh=tank, mu=0.01)], volumes=(vol,))


def _nifti_with_sform(path, values, sform):
    """A NIfTI whose sform is ``sform`` as given (nibabel refuses to build one from a
    singular or non-finite affine, but a file can hold it)."""
    import nibabel as nib

    hdr = nib.Nifti1Header()
    hdr.set_data_shape(values.shape)
    hdr.set_data_dtype(np.float32)
    hdr["srow_x"], hdr["srow_y"], hdr["srow_z"] = sform[0], sform[1], sform[2]
    hdr["sform_code"], hdr["qform_code"] = 1, 0
    nib.save(nib.Nifti1Image(values.astype(np.float32), None, header=hdr), str(path))


@pytest.mark.parametrize("case, expect", [
    ("NaN voxel", "the CT holds NaN or infinite values"),
    ("singular affine", "its voxel-to-world affine is degenerate or not finite"),
    ("NaN affine", "its voxel-to-world affine is degenerate or not finite"),
])
def test_bad_volume_files_are_one_line_and_exit_2_on_the_command_line(tmp_path, capsys,
                                                                     case, expect):
    """``xray-viz render`` of a scene whose CT file is bad: exit 2, one line on stderr that
    names the table and the file, no traceback, no image."""
    from xray_viz.cli import main

    hu, affine = ct_hu(32)
    if case == "NaN voxel":
        hu[2, 3, 4] = np.nan
        write_ct(tmp_path, hu, affine)
    else:
        bad = affine.copy()
        if case == "singular affine":
            bad[2, 2] = 0.0                          # the third axis has no length
        else:
            bad[0, 0] = np.nan
        _nifti_with_sform(tmp_path / "ct.nii.gz", hu, bad)
    (tmp_path / "s.toml").write_text(SCENE.format(body="", extra=""))
    out = tmp_path / "out.png"
    assert main(["render", str(tmp_path / "s.toml"), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert expect in err[0] and "[[ct]] #1" in err[0] and "ct.nii.gz" in err[0]
    assert "Traceback" not in err[0] and not out.exists()


def test_a_mesh_overlapping_the_volume_edge_is_one_warning_line_on_the_command_line(
        tmp_path, capsys):
    import trimesh

    from xray_viz.cli import main

    hu, affine = ct_hu(32)                           # the grid ends at z = 16
    write_ct(tmp_path, hu, affine)
    trimesh.creation.box(bounds=[[-2, -2, 10], [2, 2, 22]]).export(tmp_path / "screw.stl")
    (tmp_path / "s.toml").write_text(SCENE.format(body=IMPLANT, extra=""))
    out = tmp_path / "out.npy"
    with warnings.catch_warnings():
        warnings.simplefilter("always", VolumeOverlapWarning)   # (the suite makes it an error)
        assert main(["render", str(tmp_path / "s.toml"), "-o", str(out)]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert "warning" in err[0] and "body 'screw' reaches out of volume 'ct'" in err[0]
    assert np.isfinite(np.load(out)).all()


def test_names_of_bodies_and_classes_must_be_unique():
    import trimesh

    hu, affine = ct_hu(8)
    vol = ct_volume(hu, affine)
    ball = Body(name="ct_lung", mesh=trimesh.creation.icosphere(radius=1.0), mu=1.0)
    ball = dataclasses.replace(ball, mesh=ball.mesh.apply_translation([0, 0, 100]))
    with pytest.raises(SceneError, match="repeated: \\['ct_lung'\\]"):
        _scene(bodies=[ball], volumes=(vol,))


# --------------------------------------------------------------------------------------------
# against RTK's forward projector


@pytest.mark.slow      # ~50 s: loading RTK's Joseph filter (the default suite checks the
@pytest.mark.parametrize("kind", ["point", "parallel"])   # kernel against grid_chords)
def test_the_projection_agrees_with_rtk_joseph_within_its_interpolation(kind):
    """RTK's CPU Joseph projector on the same grid (rotated 20 degrees, anisotropic voxels,
    an off-centre Gaussian blob) and geometry. Joseph interpolates the voxel values bilinearly
    between planes of voxel centres; the exact traversal integrates them as constant cubes.
    Measured here: the two images' centroids agree to 0.02 pixel (0.01 mm), their sums to
    0.13 %, pixel by pixel to 1.2 % RMS and 7 % at most of the peak (the blob's variation
    across a voxel): the tolerances below are those, rounded up."""
    pytest.importorskip("itk")
    from scipy.spatial.transform import Rotation

    from xray_viz.orbit import Orbit
    from xray_viz.reconstruct import rtk_forward_project
    from xray_viz.scan import scan_geometry

    n = (40, 36, 30)
    affine = np.eye(4)
    affine[:3, :3] = Rotation.from_euler("z", 20, degrees=True).as_matrix() * [1.1, 1.2, 1.3]
    affine[:3, 3] = -affine[:3, :3] @ ((np.array(n) - 1) / 2)
    pts = np.einsum("ij,jklm->iklm", affine[:3, :3], np.indices(n).astype(float)) \
        + affine[:3, 3][:, None, None, None]
    centre, sigma = np.array([2.0, -3.0, 1.0]), np.array([7.0, 6.0, 5.0])
    values = 0.02 * np.exp(-((((pts.T - centre) / sigma) ** 2).sum(-1).T) / 2)
    scene = Scene(source=Source(position=[0, -300, 0], kind=kind, energy=60.0),
                  detector=Detector(center=[0, 200, 0], up=[0, 0, 1], shape=(120, 100),
                                    pitch=(0.5, 0.5)))
    geometry = scan_geometry(scene, Orbit(projections=1, axis=[0, 0, 1], center=[0, 0, 0]))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)    # ITK's SWIG modules
        theirs = rtk_forward_project(values, affine, geometry)[0].astype(float)
    rays = detector_rays(scene)
    ours = voxel_sums(rays.origins, rays.directions, rays.t_max, affine,
                      np.ones(n, np.uint8), values, n_classes=1)[:, 0].reshape(100, 120)
    yy, xx = np.indices(ours.shape)

    def centroid(im):
        return np.array([(im * yy).sum(), (im * xx).sum()]) / im.sum()

    peak = ours.max()
    assert abs(theirs.max() / peak - 1) < 0.01
    np.testing.assert_allclose(centroid(theirs), centroid(ours), atol=0.05)
    assert abs(theirs.sum() / ours.sum() - 1) < 3e-3
    assert np.sqrt(((theirs - ours) ** 2).mean()) < 0.02 * peak
    assert np.abs(theirs - ours).max() < 0.1 * peak


# --------------------------------------------------------------------------------------------
# scans and label maps


@pytest.mark.parametrize("geometry", sorted(GEOMETRIES))
def test_a_helical_scan_of_a_volume_equals_the_scan_of_its_meshed_blocks(geometry):
    """Both detectors: square to the beam, and tilted 30 degrees and offset (the orbit
    turns the tilted detector with the source)."""
    from xray_viz.orbit import Orbit

    affine = grid_affine()
    classes, _ = block_volume(affine)
    vol = VoxelVolume(name="blocks", affine=affine, classes=classes,
                      weights=(classes > 0).astype(np.float64),
                      materials=tuple(xray_viz.volume.VoxelMaterial(f"v{c}", mu=0.1 * c)
                                      for c in (1, 2, 3)))
    orbit = Orbit("helical", projections=4, axis=[0, 1, 0], center=[1.0, -2.0, 0.5],
                  pitch=20.0)
    det = GEOMETRIES[geometry]
    voxels = xray_viz.scan(_scene(detector=det, volumes=(vol,)), orbit).projections
    meshes = xray_viz.scan(_scene(detector=det, bodies=block_meshes(affine)), orbit).projections
    assert voxels.shape == (4, 32, 40) and float(voxels.max()) > 0.4
    np.testing.assert_allclose(voxels, meshes, rtol=1e-6, atol=1e-6)    # float32 stacks


def test_a_scan_store_refuses_to_resume_with_a_changed_ct_file(tmp_path, capsys):
    """The scene file names its CT by path: a store scanned with one CT and resumed after the
    file changed would mix two patients' projections. The store's digest of the scene's
    bodies counts the volumes' voxels too (exit 2, one line); the same file resumes."""
    from xray_viz.cli import main

    hu, affine = ct_hu(32)
    write_ct(tmp_path, hu, affine)
    (tmp_path / "s.toml").write_text(SCENE.format(body="", extra="").replace(
        "shape = [64, 64]", "shape = [16, 12]").replace("pitch = 1.0", "pitch = 4.0"))
    store = tmp_path / "s.zarr"
    args = ["scan", str(tmp_path / "s.toml"), "-o", str(store), "--projections", "4",
            "--axis", "0", "1", "0"]
    assert main(args) == 0
    import zarr

    g = zarr.open_group(str(store), mode="r+")
    g["done"][2] = g["done"][3] = False                 # an interrupted run
    assert main(args) == 0                              # the same CT: resumed
    g["done"][2] = g["done"][3] = False
    hu[hu > 0] += 300.0                                 # another CT at the same path
    write_ct(tmp_path, hu, affine)
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "holds another scan" in err and "voxel volumes" in err


def test_the_level_of_detail_reduces_the_bodies_and_leaves_the_volumes_as_they_are():
    """``render(max_error=...)`` decimates the mesh bodies only: a voxel volume has nothing to
    decimate. The report lists the ball alone, the scene rendered keeps the volume object,
    the volume's columns are those of the full render wherever the ball's full and reduced
    meshes both miss the ray, and the line integral stays within max_error."""
    import trimesh

    hu, affine = ct_hu(48)
    vol = ct_volume(hu, affine, name="ct")
    ball = trimesh.creation.icosphere(subdivisions=4, radius=5.0)
    ball.apply_translation([6.0, 4.0, 0.0])
    scene = _scene(bodies=[Body(name="ball", mesh=ball, material="Ti", density=4.5)],
                   volumes=(vol,), shape=(64, 64), pitch=1.0)
    full = xray_viz.render(scene, path_lengths=True)
    reduced = xray_viz.render(scene, path_lengths=True, max_error=0.5)
    assert [b.name for b in reduced.lod.bodies] == ["ball"]
    assert reduced.lod.faces < reduced.lod.faces_full == len(ball.faces)
    assert reduced.scene.volumes[0] is vol and len(reduced.scene.bodies[0].mesh.faces) < len(ball.faces)
    names = full.body_names
    assert names == reduced.body_names and names[0] == "ball"
    missed = (full.path_length[..., 0] == 0) & (reduced.path_length[..., 0] == 0)
    assert missed.sum() > 1000 and (~missed).sum() > 50
    np.testing.assert_array_equal(reduced.path_length[..., 1:][missed],
                                  full.path_length[..., 1:][missed])
    assert np.abs(reduced.line_integral - full.line_integral).max() <= 0.5


def test_a_label_map_traced_as_voxels(tmp_path):
    import nibabel as nib

    labels = np.zeros(SHAPE, np.int16)
    for c, (i0, i1), (j0, j1), (k0, k1), _ in BLOCKS:
        labels[i0:i1, j0:j1, k0:k1] = c
    labels[0, 0, 0] = 9                                   # not listed: skipped, warned
    affine = grid_affine()
    nib.save(nib.Nifti1Image(labels, affine), str(tmp_path / "seg.nii.gz"))
    (tmp_path / "s.toml").write_text("""
[source]
position = [3.0, -2.0, 400.0]
energy = 60.0
[detector]
center = [0.0, 0.0, -150.0]
up = [0.0, 1.0, 0.0]
shape = [40, 32]
pitch = 1.5
[[labels]]
file = "seg.nii.gz"
trace = "voxels"
materials = { 1 = { mu = 0.1 }, 2 = { mu = 0.2, name = "two" }, 3 = { mu = 0.3 } }
""")
    from xray_viz.meshes.volumes import LabelSkippedWarning

    with pytest.warns(LabelSkippedWarning, match="label 9"):
        scene = xray_viz.load_scene(tmp_path / "s.toml")
    assert [m.name for m in scene.volumes[0].materials] == ["seg_1", "two", "seg_3"]
    rays = detector_rays(scene)
    stored = nib.load(str(tmp_path / "seg.nii.gz")).affine    # NIfTI keeps float32
    want = analytic(rays.origins, rays.directions, rays.t_max, stored)
    want = want / np.array([1.0, 1.7, 0.4])                # labels weigh 1
    image = xray_viz.render(scene)
    np.testing.assert_allclose(image.line_integral.ravel(), want @ [0.01, 0.02, 0.03],
                               rtol=1e-9, atol=1e-12)


def test_a_scene_with_a_ct_volume_writes_its_table_and_loads_back(tmp_path):
    hu, affine = ct_hu(32)                      # air in the corners: a CT in HU, as read
    write_ct(tmp_path, hu, affine)
    (tmp_path / "s.toml").write_text(SCENE.format(body="", extra=""))
    scene = xray_viz.load_scene(tmp_path / "s.toml")
    text = scene.to_toml(base=tmp_path)
    assert "[[ct]]" in text and 'trace = "voxels"' in text
    (tmp_path / "back.toml").write_text(text)
    back = xray_viz.load_scene(tmp_path / "back.toml")
    assert [v.names for v in back.volumes] == [v.names for v in scene.volumes]
    np.testing.assert_array_equal(xray_viz.render(back).line_integral,
                                  xray_viz.render(scene).line_integral)
    built = dataclasses.replace(scene, volumes=(ct_volume(hu, affine, name="py"),))
    with pytest.raises(SceneError, match="voxel volume 'py' was built in Python"):
        built.to_toml()


def test_the_viewer_draws_a_voxel_volume_as_its_box_and_slices():
    pytest.importorskip("pyvista")
    import trimesh

    from xray_viz.viz.scene_view import plot_scene

    hu, affine = ct_hu(24)
    vol = ct_volume(hu, affine, name="ct")
    pin = Body(name="pin", mesh=trimesh.creation.box(bounds=[[-1, -1, -3], [1, 1, 3]]), mu=1.0)
    view = plot_scene(_scene(bodies=[pin], volumes=(vol,)), rays=None, window_size=(320, 240))
    box = view.datasets["volume:ct:box"]
    np.testing.assert_allclose(np.sort(box.points, axis=0), np.sort(vol.corners, axis=0))
    assert box.n_lines == 12
    assert float(view.datasets["volume:ct:slice:k"].point_data["weight"].max()) > 1.7   # bone
    lo, hi = view.bodies_bounds
    np.testing.assert_allclose([lo, hi], vol.bounds)          # the volume is around the pin
    view.set_visible("bodies", False)
    assert not view.plotter.actors["volume:ct:slice:k"].GetVisibility()
    view.plotter.close()

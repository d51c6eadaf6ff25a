"""Large random datasets (issue 14, "Dataset generation"): random poses built over all
projections at once (bit for bit the per-projection draws), and stores that keep the
per-projection poses and projection matrices as Zarr arrays, the JSON attributes small."""

from __future__ import annotations

import dataclasses
import importlib
import json

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import OutputError
from xray_viz.orbit import POSE_STREAM, Orbit, RandomPoses, orbit_from_dict

S = importlib.import_module("xray_viz.scan")
zarr = pytest.importorskip("zarr")

SPEC = {"seed": 7, "angle": [-90.0, 90.0], "tilt": [-15.0, 15.0], "roll": [-5.0, 5.0],
        "sod": [800.0, 1100.0], "sid": [1300.0, 1600.0], "shift": [2.0, 0.0, 3.0]}


@pytest.fixture(scope="module")
def sphere():
    scene = xray_viz.load_scene("sphere")
    return scene.replace(detector=dataclasses.replace(scene.detector, shape=(12, 10),
                                                      pitch=(20.0, 20.0)))


def _orbit(n, **changes):
    return orbit_from_dict({"axis": [0.0, 1.0, 0.0], "center": [0.0, 0.0, 0.0],
                            "poses": {"random": n, **SPEC, **changes}})


def _zarr_json(store):
    return (store / "zarr.json").stat().st_size


def test_draws_many_are_the_per_projection_draws_bit_for_bit():
    rng = np.random.default_rng(3)
    ks = np.r_[0, 1, 2, rng.integers(0, 2**32, 200), 2**32 - 1]
    for seed in (0, 7, 2**32 + 1, 2**70 + 11, 2**140 + 9):       # 1 to 5 seed words
        r = RandomPoses(count=2**32, seed=seed)
        got = r.draws_many(ks)
        ref = np.array([r.draws(k) for k in ks])                 # NumPy's SeedSequence + PCG64
        assert got.dtype == np.float64 and np.array_equal(got, ref)
    big = [2**32, 2**40 + 5]                                      # keys beyond 32 bits
    r = RandomPoses(count=2**41, seed=7)
    assert np.array_equal(r.draws_many(big), np.array([r.draws(k) for k in big]))
    assert r.draws_many([]).shape == (0, 8)
    assert POSE_STREAM == 0x706F7365                              # the stream stays the same


def test_poses_have_the_same_bits_in_any_batch_and_match_each_acquisition(sphere):
    orbit = _orbit(300)
    base = sphere.acquisition
    r = orbit.random
    whole = r.pose_arrays(base, axis=orbit.axis, center=orbit.center)
    order = np.random.default_rng(1).permutation(300)[:50]
    part = r.pose_arrays(base, order, axis=orbit.axis, center=orbit.center)
    for a, b in zip(whole, part):
        assert np.array_equal(a[order], b)
    poses, mats = S.pose_table(sphere, orbit)
    assert poses.shape == (300, 4, 3) and mats.shape == (300, 3, 4)
    for k in range(0, 300, 7):
        acq = orbit.acquisition(base, k)                          # what a worker renders
        f = acq.frame
        assert np.array_equal(poses[k, 0], f.source) and np.array_equal(poses[k, 1], f.center)
        assert np.array_equal(whole[2][k], acq.detector.up)
        assert np.abs(poses[k, 2] - f.ho).max() < 1e-14 and np.abs(poses[k, 3] - f.ve).max() < 1e-14
        p = acq.projection_matrix()
        assert np.abs(mats[k] - p).max() < 1e-12 * np.abs(p).max()
    # the matrices put every pose's detector centre at the image centre and its source at w=0
    homog = np.einsum("nij,nj->ni", mats, np.c_[poses[:, 1], np.ones(300)])
    assert np.allclose(homog[:, :2] / homog[:, 2:], [(12 - 1) / 2, (10 - 1) / 2], atol=1e-9)
    assert np.abs(np.einsum("nj,nj->n", mats[:, 2], np.c_[poses[:, 0], np.ones(300)])).max() \
        < 1e-9
    # a parallel beam's matrices too (affine)
    par = sphere.replace(source=dataclasses.replace(sphere.source, kind="parallel"))
    poses, mats = S.pose_table(par, _orbit(20))
    for k in (0, 13):
        p = _orbit(20).acquisition(par.acquisition, k).projection_matrix()
        assert np.abs(mats[k] - p).max() < 1e-12 * np.abs(p).max()


def test_a_small_scan_reads_back_the_same_geometry_either_way(sphere, tmp_path):
    orbit = _orbit(6)
    serial = xray_viz.scan(sphere, orbit)
    out = {}
    for arrays in (False, True):
        store = tmp_path / f"s{int(arrays)}.zarr"
        group = S.open_store(store, scene=sphere, geometry=serial.geometry, pose_arrays=arrays)
        for k in range(6):
            S._write_projection(group, k, serial.projections[k])
        out[arrays] = S.read_zarr(store)
        meta = dict(zarr.open_group(str(store), mode="r").attrs)["xray_viz"]
        assert meta["version"] == (S.ARRAYS_LAYOUT_VERSION if arrays else S.LAYOUT_VERSION)
        assert ("per_projection_arrays" in meta["geometry"]) == arrays
        assert ("poses" in meta["geometry"]) != arrays
        S.open_store(store, scene=sphere, geometry=serial.geometry)       # resumes: the same
        with pytest.raises(OutputError, match="holds another scan"):
            S.open_store(store, scene=sphere, geometry=S.scan_geometry(sphere, _orbit(6, seed=8)))
    for arrays in (False, True):
        g = out[arrays].geometry
        assert g == serial.geometry and list(g) == list(serial.geometry)   # keys in order too
        assert json.dumps(g) == json.dumps(serial.geometry)
        assert np.array_equal(out[arrays].projections, serial.projections)
        assert np.array_equal(S.astra_vectors(g), S.astra_vectors(serial.geometry))
    # a circular orbit's store with arrays: the same geometry back as well
    circ = Orbit(projections=5, axis=[0, 1, 0])
    g = S.scan_geometry(sphere, circ)
    S.open_store(tmp_path / "c.zarr", scene=sphere, geometry=g, pose_arrays=True)
    assert S.read_zarr(tmp_path / "c.zarr", require_complete=False).geometry == g


def test_a_store_with_missing_arrays_or_a_newer_layout_is_refused(sphere, tmp_path):
    g = S.scan_geometry(sphere, _orbit(3))
    store = tmp_path / "a.zarr"
    S.open_store(store, scene=sphere, geometry=g, pose_arrays=True)
    group = zarr.open_group(str(store), mode="r+")
    meta = dict(group.attrs)["xray_viz"]
    group.attrs["xray_viz"] = {**meta, "version": 3}
    with pytest.raises(OutputError, match="layout version 3 is newer") as info:
        S.read_zarr(store, require_complete=False)
    assert "\n" not in str(info.value)
    group.attrs["xray_viz"] = meta
    del group["projection_matrices"]
    with pytest.raises(OutputError, match="per-projection arrays .* missing"):
        S.read_zarr(store, require_complete=False)


def test_done_flags_from_the_listing_are_zarrs_flags(sphere, tmp_path):
    g = S.scan_geometry(sphere, _orbit(40))
    group = S.open_store(tmp_path / "d.zarr", scene=sphere, geometry=g)
    assert not S.done_flags(group).any()
    image = np.zeros((10, 12), np.float32)
    for k in (0, 3, 17, 39):
        S._write_projection(group, k, image)
    flags = S.done_flags(group)
    assert flags.dtype == bool and np.array_equal(flags, group["done"][:])
    assert np.flatnonzero(flags).tolist() == [0, 3, 17, 39]


def _check_large(sphere, tmp_path, n):
    orbit = _orbit(n)
    g = S.scan_geometry(sphere, orbit)
    assert len(g["poses"]) == n and len(g["projection_matrices"]) == n
    store = tmp_path / f"n{n}.zarr"
    S.open_store(store, scene=sphere, geometry=g)                 # n > INLINE_POSES_MAX: arrays
    group = zarr.open_group(str(store), mode="r")
    assert group["poses"].shape == (n, 4, 3) and group["poses"].dtype == np.float64
    assert group["projection_matrices"].shape == (n, 3, 4)
    for k in (0, n // 2, n - 1):                                  # the arrays hold the poses
        assert group["poses"][k].tolist() == [g["poses"][k][r] for r in S.POSE_ROWS]
        assert group["projection_matrices"][k].tolist() == g["projection_matrices"][k]
    back = S.read_zarr(store, require_complete=False, lazy=True)
    assert back.geometry == g
    return _zarr_json(store)


def test_a_large_random_dataset_keeps_its_json_small(sphere, tmp_path):
    # bounded default case: the attributes of 1,001 and 5,000 poses are the same size
    # (the count's digits aside): they do not grow with the number of poses
    small, large = (_check_large(sphere, tmp_path, n) for n in (S.INLINE_POSES_MAX + 1, 5000))
    assert large < 100_000 and abs(large - small) < 16


@pytest.mark.slow
def test_a_100000_pose_random_dataset_is_built_in_a_bounded_way(sphere, tmp_path):
    assert _check_large(sphere, tmp_path, 100_000) < 100_000

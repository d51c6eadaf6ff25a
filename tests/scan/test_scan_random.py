"""Randomised poses for DRR training sets (issue 14, "Dataset generation"): ``[scan] poses =
{ random = N, seed = 7, ... }``, each projection's pose a function of (seed, k) only."""

from __future__ import annotations

import dataclasses
import hashlib
import importlib

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import SceneError
from xray_viz.orbit import Orbit, RandomPoses, check_pose, orbit_from_dict

S = importlib.import_module("xray_viz.scan")

SPEC = {"random": 40, "seed": 7, "angle": [-90.0, 90.0], "tilt": [-15.0, 15.0],
        "roll": [-5.0, 5.0], "sod": [800.0, 1100.0], "sid": [1300.0, 1600.0]}


@pytest.fixture(scope="module")
def sphere():
    scene = xray_viz.load_scene("sphere")
    return scene.replace(detector=dataclasses.replace(scene.detector, shape=(24, 20),
                                                      pitch=(10.0, 10.0)))


def _orbit(**changes):
    return orbit_from_dict({"axis": [0.0, 1.0, 0.0], "center": [0.0, 0.0, 0.0],
                            "poses": {**SPEC, **changes}})


def _poses(orbit, base, order):
    return {k: orbit.acquisition(base, k).frame for k in order}


def test_the_same_seed_gives_the_same_poses_in_any_order(sphere):
    orbit = _orbit()
    assert orbit.kind == "poses" and orbit.projections == 40
    base = sphere.acquisition
    order = np.random.default_rng(1).permutation(40)
    fwd, shuffled = _poses(orbit, base, range(40)), _poses(orbit, base, order)
    longer = _orbit(random=1000)                         # more poses: the first 40 unchanged
    for k in range(40):
        for name in ("source", "center", "ho", "ve"):
            a = getattr(fwd[k], name)
            assert np.array_equal(a, getattr(shuffled[k], name))
            assert np.array_equal(a, getattr(longer.acquisition(base, k).frame, name))
    other = _orbit(seed=8)
    moved = [np.abs(other.acquisition(base, k).frame.source - fwd[k].source).max()
             for k in range(40)]
    assert min(moved) > 1e-6                             # every pose differs with the seed
    # fixing one range changes no other draw: the same angles about the axis
    flat = _orbit(tilt=[0.0, 0.0], roll=[0.0, 0.0])
    for k in range(5):
        f = flat.acquisition(base, k).frame
        a = np.degrees(np.arctan2(f.source[0], f.source[2]))    # source azimuth about y
        u = RandomPoses.from_dict(SPEC).draws(k)
        assert a == pytest.approx(-90.0 + 180.0 * u[4], abs=1e-9)


def test_every_random_pose_is_valid_and_within_its_ranges(sphere):
    orbit = _orbit(random=200)
    g = S.scan_geometry(sphere, orbit)
    assert g["orbit"] == "poses" and len(g["poses"]) == 200
    assert g["random"]["seed"] == 7 and g["random"]["axis"] == [0.0, 1.0, 0.0]
    axis = np.array([0.0, 1.0, 0.0])
    tilts, sods, sids = [], [], []
    for k, pose in enumerate(g["poses"]):
        s, c, u, v = check_pose(pose, where=f"pose {k}: ")    # the frame of source -> centre
        f = (c - s) / np.linalg.norm(c - s)
        assert abs(u @ v) < 1e-12 and abs(u @ f) < 1e-12 and abs(v @ f) < 1e-12
        assert np.linalg.norm(np.cross(-s, f)) < 1e-9       # no shift: the centre on the beam
        sods.append(-s @ f)
        sids.append(np.linalg.norm(c - s))
        tilts.append(np.degrees(np.arcsin(f @ axis)))
    sods, sids, tilts = map(np.asarray, (sods, sids, tilts))
    assert sods.min() >= 800 and sods.max() <= 1100 and sods.max() - sods.min() > 250
    assert sids.min() >= 1300 and sids.max() <= 1600 and sids.max() - sids.min() > 250
    assert np.abs(tilts).max() <= 15 + 1e-9 and np.abs(tilts).max() > 12
    # shift: source and detector move together, by at most the given mm per axis
    base = _orbit(random=200, seed=7)
    shifted = _orbit(random=200, seed=7, shift=[3.0, 0.0, 5.0])
    d = np.array([shifted.acquisition(sphere.acquisition, k).frame.source
                  - base.acquisition(sphere.acquisition, k).frame.source for k in range(200)])
    assert np.abs(d[:, 0]).max() <= 3 and np.abs(d[:, 0]).max() > 2.5
    assert np.abs(d[:, 1]).max() == 0 and np.abs(d[:, 2]).max() <= 5


def test_random_scan_is_reproducible_in_any_batching(sphere, tmp_path):
    orbit = _orbit(random=6)
    serial = xray_viz.scan(sphere, orbit)
    assert np.all(np.isfinite(serial.projections)) and serial.projections.max() > 0
    assert not np.array_equal(serial.projections[0], serial.projections[1])
    store = tmp_path / "r.zarr"
    S.open_store(store, scene=sphere, geometry=serial.geometry)
    text = sphere.to_toml()
    digest = hashlib.sha256(text.encode()).hexdigest()
    for batch in ([5, 2], [0, 4], [3, 1]):              # other batches, other order
        S.render_batch(text, digest, orbit, batch, store=str(store))
    assert np.array_equal(S.read_zarr(store).projections[:], serial.projections)


def test_a_scene_file_with_random_poses_and_its_errors(sphere, tmp_path):
    text = sphere.to_toml() + ('\n[scan]\naxis = [0.0, 1.0, 0.0]\nposes = { random = 5, '
                               'seed = 3, tilt = [-5.0, 5.0] }\n')
    (tmp_path / "a.toml").write_text(text)
    orbit = xray_viz.load_scene(tmp_path / "a.toml").orbit
    assert orbit.projections == 5 and orbit.random.tilt == (-5.0, 5.0)
    assert orbit_from_dict(orbit.to_dict()).random == orbit.random       # round trip
    for bad, match in ((" tilt = [5.0, -5.0]", r"poses\.tilt must be \[low, high\].*\[5\.0, -5\.0\]"),
                       (" tilted = [1.0, 2.0]", r"unknown key.*'tilted'"),
                       (" seed = -1", r"poses\.seed must be a whole number >= 0, got -1"),
                       (" sod = [0.0, 10.0]", r"poses\.sod must be > 0 mm"),
                       (" sod = [900.0, 1000.0], sid = [950.0, 1200.0]", r"poses\.sid .* beyond"),
                       (" shift = [1.0, -1.0, 0.0]", r"poses\.shift must be 3 numbers >= 0")):
        (tmp_path / "b.toml").write_text(sphere.to_toml() + f"\n[scan]\nposes = {{ random = 5,"
                                         f"{bad} }}\n")
        with pytest.raises(SceneError, match=match) as info:
            xray_viz.load_scene(tmp_path / "b.toml")
        assert "\n" not in str(info.value) and "b.toml" in str(info.value)
    with pytest.raises(SceneError, match=r"poses\.random must be a whole number >= 1"):
        Orbit("poses", random={"random": 0})
    with pytest.raises(SceneError, match=r"projections = 4 but poses\.random = 5"):
        orbit_from_dict({"projections": 4, "poses": {"random": 5}})
    with pytest.raises(SceneError, match="axis across the beam"):
        Orbit("poses", random={"random": 2, "tilt": [1.0, 2.0]}).acquisition(
            sphere.acquisition, 0)                   # z axis: along the sphere scene's beam

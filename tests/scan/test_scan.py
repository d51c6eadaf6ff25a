"""CT scans (issue 14): orbits, the projection stack, its files, the scene's [scan] table."""

from __future__ import annotations

import dataclasses
import importlib
import json

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.errors import OutputError, SceneError
from xray_viz.geometry import Acquisition
from xray_viz.orbit import Orbit
from xray_viz.scene import Body, Detector, Scene, Source

S = importlib.import_module("xray_viz.scan")      # the module (xray_viz.scan is the function)


def _small(scene, shape=(32, 24), pitch=8.0):
    return scene.replace(detector=dataclasses.replace(scene.detector, shape=shape,
                                                      pitch=(pitch, pitch)))


@pytest.fixture(scope="module")
def sphere():
    return _small(xray_viz.load_scene("sphere"))


def test_every_projection_uses_the_scenes_one_bodies(monkeypatch):
    import xray_viz.tracing.fast as fast

    calls = []
    real = fast._spatial_order
    monkeypatch.setattr(fast, "_spatial_order", lambda v, f: calls.append(1) or real(v, f))
    scene = _small(xray_viz.load_scene("nested_spheres"))
    result = xray_viz.scan(scene, Orbit(projections=8, axis=[0, 1, 0]))
    assert len(calls) == len(scene.bodies)             # once per mesh, not once per projection
    assert np.all(np.isfinite(result.projections)) and result.projections.max() > 0


def test_circular_projection_is_the_rotated_acquisitions_render(sphere):
    orbit = Orbit(projections=5, arc=200.0, axis=[0, 1, 0], center=[0, 0, 0])
    result = xray_viz.scan(sphere, orbit)
    for k, angle in enumerate(orbit.angles()):
        image = xray_viz.render(sphere.replace(
            acquisition=sphere.acquisition.rotated(angle, axis=[0, 1, 0])))
        assert np.array_equal(result.projections[k], image.line_integral.astype(np.float32))
    assert np.allclose(orbit.angles(), 40.0 * np.arange(5))
    g = result.geometry
    json.dumps(g)                                        # serialisable
    assert g["sod_mm"] == pytest.approx(1000.0) and g["sid_mm"] == pytest.approx(1500.0)
    assert len(g["poses"]) == len(g["projection_matrices"]) == 5


def test_helical_orbit_moves_along_the_axis_by_the_pitch(sphere):
    orbit = Orbit("helical", projections=6, axis=[0, 1, 0], pitch=12.0)
    acqs = list(orbit.acquisitions(sphere.acquisition))
    for acq, angle in zip(acqs, orbit.angles()):
        assert acq.frame.source[1] == pytest.approx(12.0 * angle / 360.0, abs=1e-12)
        assert acq.frame.center[1] == pytest.approx(12.0 * angle / 360.0, abs=1e-12)
        rel = acq.frame.source - [0, acq.frame.source[1], 0]
        assert np.linalg.norm(rel) == pytest.approx(1000.0)
    with pytest.raises(SceneError, match="helical"):
        Orbit("circular", projections=3, pitch=1.0)


def test_poses_orbit_reproduces_the_circular_scan(sphere, tmp_path):
    circ = xray_viz.scan(sphere, Orbit(projections=4, axis=[0, 1, 0]))
    poses = circ.geometry["poses"]
    again = xray_viz.scan(sphere, Orbit("poses", poses=poses))
    assert np.array_equal(again.projections, circ.projections)
    tilted = dict(poses[1], u=(np.array(poses[1]["u"]) + [0, 0.1, 0]).tolist())
    # (tilted poses are supported now, tests/render/test_detector_tilt.py; skewed u/v are not)
    with pytest.raises(SceneError, match="pose 1: .*must be perpendicular"):
        S.orbit_from_dict({"poses": [poses[0], tilted]})


def test_scan_table_in_a_scene_file(tmp_path, sphere):
    poses = xray_viz.scan(sphere, Orbit(projections=3)).geometry["poses"]
    (tmp_path / "poses.json").write_text(json.dumps(poses))
    text = sphere.to_toml()
    (tmp_path / "a.toml").write_text(text + '\n[scan]\norbit = "circular"\nprojections = 7\n'
                                     'arc = 190.0\naxis = [0.0, 1.0, 0.0]\n'
                                     'center = [0.0, 0.0, 0.0]\npitch = 0.0\n')
    orbit = xray_viz.load_scene(tmp_path / "a.toml").orbit
    assert (orbit.kind, orbit.projections, orbit.arc) == ("circular", 7, 190.0)
    (tmp_path / "b.toml").write_text(text + '\n[scan]\nposes = "poses.json"\n')
    orbit = xray_viz.load_scene(tmp_path / "b.toml").orbit
    assert orbit.kind == "poses" and orbit.projections == 3
    (tmp_path / "c.toml").write_text(text + '\n[scan]\nprojection = 7\n')
    with pytest.raises(SceneError, match=r"c\.toml: \[scan\] unknown key.*projection"):
        xray_viz.load_scene(tmp_path / "c.toml")
    assert xray_viz.load_scene("sphere").orbit is None


def test_noise_seeds_differ_per_projection_and_repeat(sphere):
    noisy = sphere.replace(detector=dataclasses.replace(sphere.detector, noise=True, seed=7,
                                                        i0=1e4))
    orbit = Orbit(projections=3, axis=[0, 0, 1])       # about the beam: the same sphere image
    a = xray_viz.scan(noisy, orbit, quantity="intensity").projections
    b = xray_viz.scan(noisy, orbit, quantity="intensity").projections
    clean = xray_viz.scan(noisy.replace(detector=dataclasses.replace(noisy.detector,
                                                                     noise=False)),
                          orbit, quantity="intensity").projections
    assert np.array_equal(a, b)
    r0, r1 = (a[0] - clean[0]).ravel(), (a[1] - clean[1]).ravel()
    assert np.corrcoef(r0, r1)[0, 1] < 0.3               # not the same noise in every view
    assert S.projection_seed(7, 0) != S.projection_seed(7, 1)


# ------------------------------------------------------------------------ projection matrices

def _box_scene():
    box = trimesh.creation.box(extents=[30.0, 20.0, 25.0])
    box.apply_translation([25.0, -15.0, 10.0])
    return Scene(source=Source(position=[0, 0, 1000.0]),
                 detector=Detector(center=[0, 0, -400.0], up=[0, 1, 0], shape=(96, 80),
                                   pitch=(1.5, 1.5)),
                 bodies=[Body(name="box", mesh=box, mu=0.1)])


@pytest.mark.parametrize("angle", [0.0, 33.0, 121.0])
@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_projection_matrix_lands_on_the_silhouette(angle, kind):
    scene = _box_scene()
    scene = scene.replace(source=dataclasses.replace(scene.source, kind=kind))
    acq = scene.acquisition.rotated(angle, axis=[0.3, 1.0, 0.2])
    image = xray_viz.render(scene.replace(acquisition=acq)).total_path_length
    from scipy.spatial import ConvexHull

    h, w = image.shape
    p = acq.projection_matrix() @ np.c_[scene.bodies[0].vertices, np.ones(8)].T
    hull = ConvexHull(np.c_[p[0] / p[2], h - 1 - p[1] / p[2]])     # (column, row) in pixels
    rows, cols = np.mgrid[0:h, 0:w]
    # signed distance (pixels) of each pixel centre from the hull (> 0 outside)
    dist = (np.c_[cols.ravel(), rows.ravel()] @ hull.equations[:, :2].T
            + hull.equations[:, 2]).max(axis=1).reshape(h, w)
    hit = image > 0
    assert hit[dist < -1e-6].all() and not hit[dist > 1e-6].any()
    assert (dist < -1e-6).sum() > 50                    # the box covers many pixels


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_from_projection_matrix_round_trip(kind):
    scene = _box_scene()
    rng = np.random.default_rng(3)
    for _ in range(5):
        acq = Acquisition(source=dataclasses.replace(scene.source, kind=kind),
                          detector=scene.detector).rotated(
            rng.uniform(0, 360), axis=rng.normal(size=3), center=rng.normal(size=3) * 20)
        f = acq.frame
        kw = {"sid": f.sid, "depth": float(f.forward @ f.center)} if kind == "parallel" else {}
        back = Acquisition.from_projection_matrix(
            -2.5 * acq.projection_matrix(), shape=f.shape, pitch=f.pitch,
            parallel=kind == "parallel", like=acq, **kw)
        for name in ("source", "center", "ho", "ve", "forward"):
            assert np.allclose(getattr(back.frame, name), getattr(f, name), atol=1e-9)
        assert np.allclose(back.projection_matrix(), acq.projection_matrix(), atol=1e-9)
    skew = acq.projection_matrix()
    skew[0, :3] += 0.01 * skew[1, :3]
    with pytest.raises(SceneError, match="not supported yet"):
        Acquisition.from_projection_matrix(skew, shape=f.shape, pitch=f.pitch, like=acq,
                                           parallel=kind == "parallel", **kw)


# ------------------------------------------------------------------------ files

def test_zarr_store_round_trip_and_resume(sphere, tmp_path, monkeypatch):
    orbit = Orbit(projections=6, axis=[0, 1, 0])
    mem = xray_viz.scan(sphere, orbit)
    store = tmp_path / "s.zarr"
    got = xray_viz.scan(sphere, orbit, store=store)
    assert np.array_equal(got.projections, mem.projections)
    assert [p.name for p in tmp_path.iterdir()] == ["s.zarr"]          # no partial left
    import zarr

    g = zarr.open_group(str(store), mode="r+")
    assert g["projections"].chunks == (1, 24, 32) and g["done"][:].all()
    meta = dict(g.attrs)["xray_viz"]
    assert meta["geometry"] == json.loads(json.dumps(mem.geometry)) and meta["units"] == "1"
    # an interrupted writer: chunks 1 and 4 written wrong, flags unset -> re-rendered only
    g["projections"][1] = 0.0
    g["projections"][4] = np.nan
    g["done"][1] = g["done"][4] = False
    with pytest.raises(OutputError, match="2 of 6 projections are missing"):
        S.read_zarr(store)
    calls = []
    real = S.Projections.__call__
    monkeypatch.setattr(S.Projections, "__call__", lambda self, k: calls.append(k) or real(self, k))
    again = xray_viz.scan(sphere, orbit, store=store)
    assert sorted(calls) == [1, 4]
    assert np.array_equal(again.projections, mem.projections)
    with pytest.raises(OutputError, match="holds another scan"):
        xray_viz.scan(sphere, Orbit(projections=6, axis=[1, 0, 0]), store=store)


def test_tiff_stack_and_nexus(sphere, tmp_path):
    import h5py
    import tifffile

    result = xray_viz.scan(sphere, Orbit(projections=3, arc=90.0, axis=[0, 1, 0]))
    folder = S.write_tiff_stack(result, tmp_path / "stack")
    files = sorted(folder.glob("proj_*.tif"))
    assert len(files) == 3
    assert np.array_equal(np.stack([tifffile.imread(f) for f in files]), result.projections)
    meta = json.loads((folder / "geometry.json").read_text())
    assert meta["geometry"]["angles_deg"] == [0.0, 30.0, 60.0]
    with pytest.raises(OutputError, match="exists"):
        S.write_tiff_stack(result, folder)
    path = S.write_nexus(result, tmp_path / "scan.nxs")
    with h5py.File(path, "r") as f:
        assert f["entry/definition"][()] == b"NXtomo"
        assert np.array_equal(f["entry/instrument/detector/data"][:], result.projections)
        assert np.array_equal(f["entry/data/data"][:], result.projections)
        assert f["entry/sample/rotation_angle"][:].tolist() == [0.0, 30.0, 60.0]
        assert f["entry/instrument/detector/image_key"][:].tolist() == [0, 0, 0]
        assert json.loads(f["entry/xray_viz_geometry"][()])["geometry"]["sid_mm"] == 1500.0


def test_cli_scan_writes_and_resumes(tmp_path, capsys):
    from xray_viz.cli import main

    scene = _small(xray_viz.load_scene("sphere"))
    (tmp_path / "s.toml").write_text(scene.to_toml())
    out = tmp_path / "s.zarr"
    args = ["scan", str(tmp_path / "s.toml"), "-o", str(out), "--projections", "4",
            "--axis", "0", "1", "0"]
    assert main(args) == 0
    assert "4 projections (4 rendered now)" in capsys.readouterr().out
    ref = xray_viz.scan(scene, Orbit(projections=4, axis=[0, 1, 0]))
    assert np.array_equal(S.read_zarr(out).projections, ref.projections)
    assert main(args) == 0
    assert "(0 rendered now)" in capsys.readouterr().out
    assert main(args[:3] + [str(tmp_path / "s.png")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("xray-viz: error: -o") and "\n" not in err


@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_astra_vectors_put_every_pixel_where_the_rays_end(kind):
    """ASTRA's pixel (row r, column c) of projection k lies at d + (c - (W-1)/2) u +
    (r - (H-1)/2) v: for every pixel of every view that is where xray_viz's ray of image pixel
    (r, c) meets the detector, so the stack is ASTRA's data as projections.transpose(1, 0, 2).
    And the poses come back from the vectors."""
    import dataclasses

    import xray_viz
    from xray_viz.scan import Orbit, astra_vectors, poses_from_astra, scan_geometry

    scene = xray_viz.load_scene("sphere")
    scene = scene.replace(source=dataclasses.replace(scene.source, kind=kind),
                          detector=dataclasses.replace(scene.detector, shape=(7, 5)))
    orbit = Orbit(projections=5, arc=200.0, axis=[0.2, 1.0, 0.3], center=[3.0, -2.0, 1.0])
    g = scan_geometry(scene, orbit)
    vec = astra_vectors(g)
    W, H = g["detector"]["shape"]
    r, c = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    for k, acq in enumerate(orbit.acquisitions(scene.acquisition)):
        d, u, v = vec[k, 3:6], vec[k, 6:9], vec[k, 9:12]
        astra = d + (c - (W - 1) / 2)[..., None] * u + (r - (H - 1) / 2)[..., None] * v
        ends = acq.rays().ends.reshape(H, W, 3)
        np.testing.assert_allclose(astra, ends, rtol=0, atol=1e-9)
        if kind == "parallel":
            np.testing.assert_allclose(vec[k, :3], acq.frame.forward, atol=1e-12)
    back = poses_from_astra(vec, beam=g["beam"], sid=g["sid_mm"])
    for a, b in zip(back, g["poses"]):
        for key in ("source", "detector_center", "u", "v"):
            np.testing.assert_allclose(a[key], b[key], rtol=0, atol=1e-9)
    with pytest.raises(xray_viz.errors.SceneError, match="12 numbers"):
        poses_from_astra(vec[:, :11])


def test_a_scene_without_a_scan_table_orbits_its_bodies(tmp_path, capsys):
    """No [scan] table: the source goes round the bodies about the detector's up axis (not
    about the beam, which would show the same view every time), and the CLI's store
    reconstructs; a degenerate orbit about the beam axis is refused in one line."""
    import xray_viz
    from xray_viz import cli
    from xray_viz.scan import default_orbit

    scene = xray_viz.load_scene("sphere")
    orbit = default_orbit(scene, projections=4)
    sources = [a.frame.source for a in orbit.acquisitions(scene.acquisition)]
    np.testing.assert_allclose(sources[1], [1000.0, 0.0, 0.0], atol=1e-9)   # 90 deg about y
    out = tmp_path / "s.zarr"
    assert cli.main(["scan", "sphere", "-o", str(out), "--projections", "4"]) == 0
    geometry = S.read_zarr(out).geometry
    assert geometry["axis"] == [0.0, 1.0, 0.0] and geometry["projections"] == 4
    capsys.readouterr()
    beam = tmp_path / "beam.zarr"
    assert cli.main(["scan", "sphere", "-o", str(beam), "--projections", "4",
                     "--axis", "0", "0", "1"]) == 0
    capsys.readouterr()
    assert cli.main(["reconstruct", str(beam), "-o", str(tmp_path / "v.nii.gz"),
                     "--voxel", "8"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "axis must cross the beam" in err, err


def test_fan_beam_is_one_detector_row_of_the_cone_beam():
    """A fan beam is a detector of one row: its scan is, bit for bit, the middle row of the
    cone-beam scan of the same orbit on a detector of an odd number of rows."""
    base = xray_viz.load_scene("sphere")
    cone = base.replace(detector=dataclasses.replace(base.detector, shape=(64, 5),
                                                     pitch=(2.0, 2.0)))
    fan = base.replace(detector=dataclasses.replace(base.detector, shape=(64, 1),
                                                    pitch=(2.0, 2.0)))
    a = S.scan(cone, S.default_orbit(cone, projections=8))
    b = S.scan(fan, S.default_orbit(fan, projections=8))
    assert b.projections.shape == (8, 1, 64)
    assert a.projections[:, 2].max() > 1.0                 # the sphere is in the fan
    np.testing.assert_array_equal(a.projections[:, 2], b.projections[:, 0])

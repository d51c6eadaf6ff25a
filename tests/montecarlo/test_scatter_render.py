"""Scatter in the rendered images (issue 39): ``render(scene, scatter=None | "mc" | "kernel",
histories=)``, ``Radiograph.primary/.scatter/.spr``, the detector reading primary plus
scatter, the command line's ``--scatter``."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest
import trimesh
from scipy.ndimage import gaussian_filter

import xray_viz
from xray_viz.errors import SceneError
from xray_viz.scene import Body, Detector, Scene, Source


def _slab(thickness=50.0, shape=(16, 16), pitch=(8.0, 8.0), energy=60.0, **detector):
    """A water slab (300 x 300 mm, ``thickness`` mm) between a point source at 600 mm and a
    detector at -400 mm: the field the detector sees is inside the slab."""
    slab = trimesh.creation.box(extents=[300, 300, thickness])
    return Scene(source=Source(position=[0, 0, 600], energy=energy),
                 detector=Detector(center=[0, 0, -400], shape=shape, pitch=pitch, **detector),
                 bodies=(Body(name="water", mesh=slab, material="Water, Liquid"),))


def _central_spr(image, k=4):
    """SPR of the central ``k x k`` pixels together, and its standard error."""
    h, w = image.scatter.shape
    box = (slice(h // 2 - k // 2, h // 2 + k // 2), slice(w // 2 - k // 2, w // 2 + k // 2))
    s = image.scatter[box].sum()
    err = np.sqrt((image.scatter_details["error"][box] ** 2).sum())
    p = image.primary[box].sum()
    return s / p, err / p


def test_scatter_off_is_the_primary_render_bit_for_bit():
    scene = xray_viz.load_scene("sphere")
    a, b = xray_viz.render(scene), xray_viz.render(scene, scatter=None)
    assert np.array_equal(a.intensity, b.intensity)
    assert np.array_equal(a.line_integral, b.line_integral)
    assert b.primary is None and b.scatter is None and b.spr is None
    assert b.scope.startswith("primary radiation only")
    c = xray_viz.render(scene, scatter="none")
    assert np.array_equal(a.intensity, c.intensity) and c.scatter is None


def test_mc_scatter_is_the_transports_and_the_total_is_primary_plus_scatter():
    from xray_viz.render import stages
    from xray_viz.transport import flat_signal

    scene = _slab(50.0)
    image = xray_viz.render(scene, scatter="mc", histories=40_000)
    primary_only = xray_viz.render(scene)
    # the seed is the detector's (none here): 0
    t = xray_viz.transport(scene, 40_000, seed=0)
    s = (t.images["incoherent"] + t.images["coherent"] + t.images["multiple"]) / \
        flat_signal(scene)
    beam, model = stages(scene)
    flat = model.flat_field(beam=beam.at(scene.acquisition), acquisition=scene.acquisition)
    assert np.allclose(image.scatter, flat * s, rtol=1e-12, atol=0)
    assert image.scatter_details["mode"] == "mc" and image.scatter_details["seed"] == 0
    assert image.scatter_details["histories"] == 40_000
    # the primary part is today's image (noise-free, no blur here)
    assert np.allclose(image.primary, primary_only.intensity, rtol=1e-13, atol=0)
    # the detector reads the sum; the line integral is the total's: lower where scatter is
    assert np.allclose(image.intensity, image.primary + image.scatter, rtol=1e-12, atol=0)
    assert np.allclose(image.line_integral, -np.log((image.primary + image.scatter) / flat),
                       rtol=1e-12, atol=1e-14)
    has = image.scatter > 0
    assert has.mean() > 0.5
    assert np.all(image.line_integral[has] < primary_only.line_integral[has])
    assert np.allclose(image.spr, image.scatter / image.primary)
    assert "Monte Carlo" in image.scope


def test_mc_scatter_is_non_negative_finite_and_smooth():
    image = xray_viz.render(_slab(100.0, shape=(32, 32), pitch=(6.0, 6.0)), scatter="mc",
                            histories=300_000)
    s, err = image.scatter, image.scatter_details["error"]
    assert np.all(np.isfinite(s)) and s.min() >= 0 and np.all(np.isfinite(image.spr))
    # its high-frequency part is its statistical noise alone: the residual of a 3-pixel
    # Gaussian smoothing has the variance of the standard errors (1 - 2 k0 + sum k^2 = 0.95
    # of it for that kernel), where the primary's edges would give far more
    residual = s - gaussian_filter(s, 3.0, mode="nearest")
    inner = (slice(4, -4), slice(4, -4))
    ratio = residual[inner].var() / (err[inner] ** 2).mean()
    assert 0.7 < ratio < 1.3
    # and it is smooth on the scale of the field: the smoothed scatter varies slowly
    smooth = gaussian_filter(s, 3.0, mode="nearest")[inner]
    assert smooth.max() / smooth.min() < 2.0


def test_thicker_water_and_larger_field_give_larger_spr():
    thin, se_thin = _central_spr(xray_viz.render(_slab(20.0), scatter="mc", histories=60_000))
    thick, se_thick = _central_spr(xray_viz.render(_slab(100.0), scatter="mc",
                                                   histories=60_000))
    assert thick - thin > 4 * np.hypot(se_thin, se_thick)
    small, se_small = _central_spr(xray_viz.render(_slab(100.0, pitch=(2.0, 2.0)),
                                                   scatter="mc", histories=60_000))
    assert thick - small > 4 * np.hypot(se_small, se_thick)


def test_noise_of_the_total_is_poisson_of_primary_plus_scatter():
    scene = _slab(100.0, shape=(48, 48), pitch=(4.0, 4.0), response="counting", noise=True,
                  seed=5, i0=2000.0)
    image = xray_viz.render(scene, scatter="mc", histories=60_000)
    mean = image.primary + image.scatter
    z = (image.intensity - mean) / np.sqrt(mean)          # counts: variance = mean
    n = z.size
    assert abs(z.mean()) < 4 / np.sqrt(n)
    assert abs(z.var() - 1.0) < 4 * np.sqrt(2.0 / n)
    # the detector's seed seeds the Monte Carlo too: the same image again, bit for bit
    again = xray_viz.render(scene, scatter="mc", histories=60_000)
    assert image.scatter_details["seed"] == 5
    assert np.array_equal(image.intensity, again.intensity)


@pytest.mark.parametrize("kwargs, match", [
    ({"scatter": "monte-carlo"}, "unknown scatter"),
    ({"scatter": "mc"}, "needs histories"),
    ({"scatter": "mc", "histories": 0}, "histories must be > 0"),
    ({"scatter": "mc", "histories": -5}, "histories must be > 0"),
    ({"scatter": "mc", "histories": 2.5}, "whole number"),
    ({"histories": 1000}, "for scatter='mc'"),
    ({"scatter": 1}, "scatter must be"),
])
def test_bad_scatter_options_are_one_line(kwargs, match):
    with pytest.raises(SceneError, match=match) as info:
        xray_viz.render(_slab(), **kwargs)
    assert "\n" not in str(info.value)


def test_mc_scatter_refuses_bodies_without_material():
    scene = xray_viz.load_scene("sphere")                  # mu only
    with pytest.raises(SceneError, match="material"):
        xray_viz.render(scene, scatter="mc", histories=100)


# --- the kernel model (xray_viz.scatter_kernel, written by another branch of issue 39) ----


def test_kernel_scatter_goes_through_the_detector_like_the_mc():
    pytest.importorskip("xray_viz.scatter_kernel")       # the kernel branch of issue 39
    import warnings

    from xray_viz import errors
    from xray_viz.render import stages
    from xray_viz.scatter_kernel import KernelModel

    scene = _slab(100.0, shape=(32, 32), pitch=(6.0, 6.0), energy=60.0)
    with warnings.catch_warnings():     # this test is about the plumbing, not the model's range
        warnings.simplefilter("ignore", errors.ScatterModelWarning)
        image = xray_viz.render(scene, scatter="kernel")
        primary_only = xray_viz.render(scene)
        beam, model = stages(scene)
        flat = model.flat_field(beam=beam.at(scene.acquisition), acquisition=scene.acquisition)
        log_t = np.log(primary_only.intensity / flat)
        # the render passes each pixel's path lengths per body (the materials' scattering)
        s = KernelModel.of(scene).scatter(log_t, scene.acquisition, scene.bodies,
                                          path_lengths=primary_only.path_length)
    assert np.allclose(image.scatter, flat * s, rtol=1e-9)
    assert np.all(np.isfinite(image.scatter)) and image.scatter.min() >= 0
    assert np.allclose(image.intensity, image.primary + image.scatter, rtol=1e-12)
    assert image.scatter_details == {"mode": "kernel"} and "kernel" in image.scope


# --- the command line ------------------------------------------------------------------------

SLAB_TOML = """\
[source]
position = [0, 0, 600]
energy = 60.0
[detector]
center = [0, 0, -400]
shape = [16, 16]
pitch = 8.0
seed = 3
[[body]]
name = "water"
mesh = "slab.stl"
material = "Water, Liquid"
"""


def _slab_file(tmp_path):
    trimesh.creation.box(extents=[300, 300, 80]).export(tmp_path / "slab.stl")
    path = tmp_path / "slab.toml"
    path.write_text(SLAB_TOML)
    return path


def test_cli_render_with_mc_scatter_writes_the_total_and_says_so(tmp_path, capsys):
    import pydicom

    from xray_viz.cli import main
    from xray_viz.output import load_image

    scene_file = _slab_file(tmp_path)
    out = tmp_path / "total.tiff"
    assert main(["render", str(scene_file), "-o", str(out), "--scatter", "mc",
                 "--histories", "20000"]) == 0
    said = capsys.readouterr().out
    assert "scatter mc: SPR " in said and " over the field" in said
    api = xray_viz.render(xray_viz.load_scene(scene_file), scatter="mc", histories=20_000)
    data, meta = load_image(out, with_metadata=True)
    assert np.array_equal(data, api.intensity.astype(np.float32))
    assert meta.scatter["mode"] == "mc" and meta.scatter["histories"] == 20_000
    assert meta.scatter["seed"] == 3 and "Monte Carlo" in meta.scatter["scope"]
    # the line integral written is the total's, below the primary's
    li = tmp_path / "li.npy"
    assert main(["render", str(scene_file), "-o", str(li), "--quantity", "line-integral",
                 "--scatter", "mc", "--histories", "20000", "-q"]) == 0
    primary = xray_viz.render(xray_viz.load_scene(scene_file))
    assert np.array_equal(np.load(li), api.line_integral)
    assert np.all(np.load(li) <= primary.line_integral)
    # DICOM's comments say what was modelled, with and without scatter
    dcm = tmp_path / "x.dcm"
    assert main(["render", str(scene_file), "-o", str(dcm), "--scatter", "mc",
                 "--histories", "20000", "-q"]) == 0
    assert "scatter mc, histories 20000, seed 3" in pydicom.dcmread(dcm).ImageComments
    assert main(["render", str(scene_file), "-o", str(dcm), "-q"]) == 0
    assert "primary radiation only" in pydicom.dcmread(dcm).ImageComments
    # without --scatter: no scatter key, today's file
    plain = tmp_path / "plain.tiff"
    assert main(["render", str(scene_file), "-o", str(plain), "-q"]) == 0
    assert load_image(plain, with_metadata=True)[1].scatter is None


@pytest.mark.parametrize("args, match", [
    (["--scatter", "mc"], "--scatter mc needs --histories"),
    (["--scatter", "mc", "--histories", "0"], "--histories must be > 0"),
    (["--scatter", "mc", "--histories", "-4"], "--histories must be > 0"),
    (["--scatter", "mc", "--histories", "1e5"], "invalid int value"),
    (["--scatter", "monte"], "invalid choice"),
    (["--histories", "100"], "--histories is for --scatter mc only"),
    (["--scatter", "kernel", "--histories", "100"], "--histories is for --scatter mc only"),
])
def test_cli_bad_scatter_input_is_one_line_and_exit_2(tmp_path, capsys, args, match):
    from xray_viz.cli import main

    scene_file = _slab_file(tmp_path)
    keep = tmp_path / "previous.npy"
    np.save(keep, np.zeros(2))
    before = keep.read_bytes()
    try:
        code = main(["render", str(scene_file), "-o", str(keep), *args])
    except SystemExit as exc:                     # argparse's own errors
        code = exc.code
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and match in err and "Traceback" not in err
    assert keep.read_bytes() == before               # nothing written, nothing lost


def test_cli_shows_the_monte_carlos_progress_on_a_terminal(tmp_path):
    import sys
    from pathlib import Path

    from helpers import run_on_a_terminal

    scene_file = _slab_file(tmp_path)
    out = tmp_path / "s.npy"
    script = Path(sys.executable).parent / "xray-viz"
    status, text = run_on_a_terminal([str(script), "render", str(scene_file), "-o", str(out),
                                      "--scatter", "mc", "--histories", "300000"],
                                     env={"XRAY_VIZ_PROGRESS_DELAY": "0"})
    assert status == 0, text
    done = {int(n) for n in re.findall(r"scatter \(Monte Carlo\):.*?(\d+)/300000", text)}
    assert done - {0} and max(done) <= 300_000, text          # it moved, by groups
    assert f"wrote {out}" in text


# --- scans (and the random-poses datasets, which are scans) ---------------------------------


def _small_slab_with_ball(seed=11):
    ball = trimesh.creation.icosphere(subdivisions=2, radius=30)
    slab = trimesh.creation.box(extents=[200, 200, 60])
    return Scene(source=Source(position=[0, 0, 600], energy=60.0),
                 detector=Detector(center=[0, 0, -400], shape=(16, 12), pitch=(10.0, 10.0),
                                   seed=seed, noise=True, i0=5000.0),
                 bodies=(Body(name="water", mesh=slab, material="Water, Liquid"),
                         Body(name="bone", mesh=ball, material="Bone, Cortical (ICRP)")))


def test_a_scan_with_mc_scatter_is_renders_with_the_same_seeds():
    import dataclasses

    from xray_viz.orbit import Orbit
    from xray_viz.scan import projection_seed

    scene = _small_slab_with_ball()
    orbit = Orbit(projections=4, axis=[0, 1, 0])
    result = xray_viz.scan(scene, orbit, quantity="intensity", scatter="mc",
                           histories=20_000)
    assert result.physics["scatter"] == {"mode": "mc", "histories": 20_000}
    plain = xray_viz.scan(scene, orbit, quantity="intensity")
    for k in range(4):
        acq = orbit.acquisition(scene.acquisition, k)
        det = dataclasses.replace(acq.detector, seed=projection_seed(acq.detector.seed, k))
        r = xray_viz.render(scene.replace(source=acq.source, detector=det), scatter="mc",
                            histories=20_000)
        assert r.scatter_details["seed"] == projection_seed(11, k)
        assert np.array_equal(result.projections[k], r.intensity.astype(np.float32))
        # scatter off: today's scan
        r0 = xray_viz.render(scene.replace(source=acq.source, detector=det))
        assert np.array_equal(plain.projections[k], r0.intensity.astype(np.float32))
    assert "scatter" not in plain.physics
    # the projections differ by their scatter: each its own Monte Carlo
    assert not np.array_equal(result.projections[0], plain.projections[0])


def test_a_stored_scan_with_scatter_records_it_and_resumes_only_the_same(tmp_path):
    from xray_viz.errors import OutputError
    from xray_viz.orbit import Orbit

    scene = _small_slab_with_ball()
    orbit = Orbit(projections=2, axis=[0, 1, 0])
    store = tmp_path / "s.zarr"
    stored = xray_viz.scan(scene, orbit, scatter="mc", histories=10_000, store=store)
    memory = xray_viz.scan(scene, orbit, scatter="mc", histories=10_000)
    assert np.array_equal(stored.projections[:], memory.projections)
    with pytest.raises(OutputError, match="another scan"):
        xray_viz.scan(scene, orbit, store=store)            # primary only: not the same scan
    with pytest.raises(SceneError, match="needs histories"):
        xray_viz.scan(scene, orbit, scatter="mc", store=tmp_path / "t.zarr")
    assert not (tmp_path / "t.zarr").exists()


def test_random_poses_dataset_takes_scatter_through_the_cli(tmp_path, capsys):
    from xray_viz.cli import main
    from xray_viz.scan import read_zarr

    scene_file = _slab_file(tmp_path)
    text = scene_file.read_text() + '[scan]\naxis = [0, 1, 0]\nposes = { random = 3, seed = 2 }\n'
    scene_file.write_text(text)
    out = tmp_path / "random.zarr"
    assert main(["scan", str(scene_file), "-o", str(out), "--scatter", "mc",
                 "--histories", "5000"]) == 0
    result = read_zarr(out)
    assert result.physics["scatter"] == {"mode": "mc", "histories": 5000}
    assert result.projections.shape[0] == 3
    plain = tmp_path / "plain.zarr"
    assert main(["scan", str(scene_file), "-o", str(plain)]) == 0
    # scatter lowers every line integral where it lands
    assert np.all(result.projections[:] <= read_zarr(plain).projections[:] + 1e-6)
    capsys.readouterr()
    assert main(["scan", str(scene_file), "-o", str(tmp_path / "x.zarr"), "--scatter",
                 "mc"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--scatter mc needs --histories" in err
    assert not (tmp_path / "x.zarr").exists()


# --- smoothing the Monte Carlo's scatter ----------------------------------------------------


def test_smoothing_keeps_the_scatter_and_lowers_its_error():
    scene = _slab(100.0, shape=(32, 32), pitch=(6.0, 6.0))
    raw = xray_viz.render(scene, scatter="mc", histories=100_000)
    smooth = xray_viz.render(scene, scatter="mc", histories=100_000, scatter_smoothing=12.0)
    assert smooth.scatter_details["smoothing_mm"] == 12.0
    # the same photons (same seed), blurred: the total is kept (mirrored borders) ...
    assert smooth.scatter.sum() == pytest.approx(raw.scatter.sum(), rel=1e-9)
    assert np.array_equal(smooth.primary, raw.primary)
    # ... the central mean agrees within the errors, and each pixel's error is far smaller
    box = (slice(12, 20), slice(12, 20))
    err = np.sqrt((raw.scatter_details["error"][box] ** 2).sum()) / 64
    assert abs(smooth.scatter[box].mean() - raw.scatter[box].mean()) < 4 * err
    e_raw, e_smooth = raw.scatter_details["error"], smooth.scatter_details["error"]
    assert np.median(e_smooth) < 0.3 * np.median(e_raw)
    # the error of a weighted mean: sigma_2 = 2 px, sum k^2 = 1 / (4 pi sigma^2) per pixel
    ratio = np.median(e_smooth[box] / np.sqrt(gaussian_filter(e_raw ** 2, 2.0)[box]))
    assert ratio == pytest.approx(1.0 / np.sqrt(4 * np.pi * 2.0 ** 2), rel=0.1)
    # and the detector reads the smoothed scatter
    assert np.allclose(smooth.intensity, smooth.primary + smooth.scatter, rtol=1e-12)


@pytest.mark.parametrize("kwargs, match", [
    ({"scatter": "mc", "histories": 100, "scatter_smoothing": -1.0}, "mm >= 0"),
    ({"scatter": "mc", "histories": 100, "scatter_smoothing": float("nan")}, "mm >= 0"),
    ({"scatter_smoothing": 5.0}, "for scatter='mc' only"),
])
def test_bad_smoothing_is_one_line(kwargs, match):
    with pytest.raises(SceneError, match=match):
        xray_viz.render(_slab(), **kwargs)


def test_cli_records_the_smoothing_and_scan_takes_it(tmp_path, capsys):
    from xray_viz.cli import main
    from xray_viz.orbit import Orbit
    from xray_viz.output import load_image

    scene_file = _slab_file(tmp_path)
    out = tmp_path / "s.tiff"
    assert main(["render", str(scene_file), "-o", str(out), "--scatter", "mc", "--histories",
                 "20000", "--scatter-smoothing", "16", "-q"]) == 0
    data, meta = load_image(out, with_metadata=True)
    assert meta.scatter["smoothing_mm"] == 16.0
    api = xray_viz.render(xray_viz.load_scene(scene_file), scatter="mc", histories=20_000,
                          scatter_smoothing=16.0)
    assert np.array_equal(data, api.intensity.astype(np.float32))
    assert main(["render", str(scene_file), "-o", str(tmp_path / "x.tiff"),
                 "--scatter-smoothing", "16"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--scatter-smoothing is for --scatter mc" in err
    assert not (tmp_path / "x.tiff").exists()
    result = xray_viz.scan(_small_slab_with_ball(), Orbit(projections=2, axis=[0, 1, 0]),
                           scatter="mc", histories=5_000, scatter_smoothing=20.0)
    assert result.physics["scatter"] == {"mode": "mc", "histories": 5_000, "smoothing_mm": 20.0}


def test_kernel_scatter_in_a_scan_and_through_the_cli(tmp_path):
    pytest.importorskip("xray_viz.scatter_kernel")       # the kernel branch of issue 39
    import dataclasses
    import warnings

    from xray_viz import errors
    from xray_viz.cli import main
    from xray_viz.orbit import Orbit
    from xray_viz.output import load_image
    from xray_viz.scan import projection_seed

    scene = _small_slab_with_ball()
    orbit = Orbit(projections=3, axis=[0, 1, 0])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", errors.ScatterModelWarning)
        result = xray_viz.scan(scene, orbit, quantity="intensity", scatter="kernel")
        assert result.physics["scatter"] == {"mode": "kernel"}
        for k in range(3):
            acq = orbit.acquisition(scene.acquisition, k)
            det = dataclasses.replace(acq.detector, seed=projection_seed(acq.detector.seed, k))
            r = xray_viz.render(scene.replace(source=acq.source, detector=det),
                                scatter="kernel")
            assert np.array_equal(result.projections[k], r.intensity.astype(np.float32))
        scene_file = _slab_file(tmp_path)
        out = tmp_path / "k.tiff"
        assert main(["render", str(scene_file), "-o", str(out), "--scatter", "kernel",
                     "-q"]) == 0
    assert load_image(out, with_metadata=True)[1].scatter["mode"] == "kernel"


def test_radiograph_views_of_its_scatter():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    image = xray_viz.render(_slab(50.0), scatter="mc", histories=20_000)
    for name, expected in (("total", image.intensity), ("primary", image.primary),
                           ("scatter", image.scatter), ("spr", image.spr)):
        assert np.array_equal(image.quantity(name), expected)
        _, ax = plt.subplots()
        shown = image.plot(name, ax=ax)
        assert np.array_equal(shown.get_array(), expected)
        plt.close(ax.figure)
    plain = xray_viz.render(_slab(50.0))
    with pytest.raises(SceneError, match="rendered with scatter"):
        plain.quantity("spr")


def test_mc_scatter_of_a_water_slab_as_voxels_is_the_meshed_slabs():
    """The transport crosses voxel volumes: the slab as a label volume scatters as its mesh
    (same photons' statistics, different seeds, within the combined errors)."""
    from xray_viz.volume import label_volume

    mesh = _slab(thickness=60.0, shape=(8, 8), pitch=(16.0, 16.0))
    # the same 300 x 300 x 60 mm box as 5 mm voxels
    affine = np.diag([5.0, 5.0, 5.0, 1.0])
    affine[:3, 3] = [-147.5, -147.5, -27.5]
    vol = label_volume(np.ones((60, 60, 12), np.int64), affine,
                       {1: {"material": "Water, Liquid"}}, name="slab")
    voxels = mesh.replace(bodies=(), volumes=(vol,))
    a = xray_viz.render(mesh, scatter="mc", histories=60_000)
    b = xray_viz.render(voxels.replace(detector=dataclasses.replace(voxels.detector, seed=9)),
                        scatter="mc", histories=60_000)
    assert np.allclose(a.primary, b.primary, rtol=1e-9)
    sa, sb = a.scatter.sum(), b.scatter.sum()
    err = np.hypot(np.sqrt((a.scatter_details["error"] ** 2).sum()),
                   np.sqrt((b.scatter_details["error"] ** 2).sum()))
    assert sa > 0 and abs(sa - sb) < 4 * err

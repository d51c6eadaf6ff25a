"""Line integrals stay finite and exact however thick or dense the bodies (issue 12): ln(I/I0)
is computed in the log domain, checked against high-precision sums (decimal) and analytic
bounds; the focal-spot blur in the log domain against the direct blur; noise at huge I0."""

from __future__ import annotations

import dataclasses
from decimal import Decimal, getcontext

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.cli import main
from xray_viz.physics import imaging
from xray_viz.physics.spectra import Spectrum
from xray_viz.scene import Body, Detector, Scene, Source


def _ball_scene(mu, *, spectrum=None, material=None, density=None, **detector):
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=40.0)
    body = Body(name="ball", mesh=mesh, mu=None if material else mu, material=material,
                density=density)
    options = dict(center=[0, 0, -500], up=[0, 1, 0], shape=(33, 31), pitch=2.0)
    options.update(detector)
    return Scene(source=Source(position=[0, 0, 1000], energy=None if spectrum else 60.0,
                               spectrum=spectrum),
                 detector=Detector(**options), bodies=(body,))


@pytest.mark.parametrize("engine", ["fast", "numpy"])
def test_monochromatic_line_integral_is_mu_times_length_past_underflow(engine):
    # mu L up to 200/cm * 8 cm = 1600: exp(-1600) is 0 in float64
    image = xray_viz.render(_ball_scene(200.0), engine=engine)
    li, L = image.line_integral, image.total_path_length
    assert np.all(np.isfinite(li)) and np.all(np.isfinite(image.intensity))
    assert li.max() > 1500
    np.testing.assert_allclose(li, 20.0 * L, rtol=1e-12, atol=1e-12)
    assert np.all(image.intensity >= 0) and np.all(image.intensity <= 1.0)


def _decimal_line_integral(L, mu, weights):
    """-ln sum_k w_k exp(-sum_b mu_kb L_b), in 60-digit decimal arithmetic."""
    getcontext().prec = 60
    total = sum(Decimal(float(w)) * (-(Decimal(float(m)) * Decimal(float(L)))).exp()
                for w, m in zip(weights, mu))
    return float(-total.ln())


def test_polychromatic_line_integral_against_high_precision_sums():
    spectrum = Spectrum([20.0, 40.0, 60.0, 80.0], [0.1, 0.4, 0.3, 0.2])
    scene = _ball_scene(None, spectrum=spectrum, material="Water, Liquid")
    mu = imaging.body_mu(scene, spectrum.energies)[:, 0] / imaging.MM_PER_CM   # 1/mm
    weights = imaging.detector_weights(spectrum, "energy")
    lengths = np.array([0.0, 1.0, 50.0, 1e3, 1e4, 1e5])       # up to 100 m of water
    got = -imaging.log_transmission(lengths[:, None], scene)
    want = [_decimal_line_integral(x, mu, weights) for x in lengths]
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13)
    assert np.all(np.isfinite(got))
    # far past underflow the hardest bin dominates: min_k(mu_k L - ln w_k) - ln K <= LI <= that
    x = lengths[-1]
    hard = np.min(mu * x - np.log(weights))
    assert hard - np.log(len(weights)) <= got[-1] <= hard


def test_log_transmission_agrees_with_transmission_where_it_does_not_underflow():
    spectrum = Spectrum(np.linspace(20, 100, 41), np.linspace(1, 2, 41))
    scene = _ball_scene(None, spectrum=spectrum, material="Bone, Cortical (ICRP)")
    L = np.linspace(0, 120, 200)[:, None]
    np.testing.assert_allclose(np.exp(imaging.log_transmission(L, scene)),
                               imaging.transmission(L, scene), rtol=1e-13)


def test_supersampled_pixel_mean_in_the_log_domain():
    # a pixel whose rays all underflow: the log of their mean is still exact
    log_t = np.array([-3000.0, -3001.0, -3002.0, -3003.0])
    want = -3000.0 + np.log(np.exp(-np.arange(4.0)).mean())
    assert imaging.pixel_log_mean(log_t, 4)[0] == pytest.approx(want, rel=1e-15)
    small = np.log(np.array([0.2, 0.4, 0.6, 0.8]))
    assert imaging.pixel_log_mean(small, 2) == pytest.approx(np.log([0.3, 0.7]), rel=1e-14)


@pytest.mark.parametrize("engine", ["fast", "numpy"])
def test_polychromatic_render_of_a_dense_thick_body_is_finite(engine):
    spectrum = {"kvp": 80.0, "filters": {"Al": 2.5}}
    from xray_viz.physics.spectra import spectrum_from_dict

    scene = _ball_scene(None, spectrum=spectrum_from_dict(spectrum), material="Pb",
                        density=60.0)       # a lead ball of 5x lead's density: mu L ~ 1000
    image = xray_viz.render(scene, engine=engine, supersample=2)
    li = image.line_integral
    assert np.all(np.isfinite(li)) and li.max() > 745       # lead: beyond exp underflow
    assert np.all(li >= 0)


def test_log_blur_is_the_blur_shifted():
    """ln blur(exp(g)) is shift-equivariant: the log-domain blur of g - 2000 (every value
    underflows) is the direct blur of g, minus 2000."""
    scene = _ball_scene(1.0, focal_spot=1.2, pitch=0.25)
    rng = np.random.default_rng(3)
    g = -rng.uniform(0, 20, size=(31, 33))
    from xray_viz.physics.detector_model import DetectorModel

    model = DetectorModel.of(scene.detector)
    kernels = model.focal_kernels(scene.acquisition, scene.bodies)
    direct = np.log(imaging._convolve(np.exp(g), kernels))
    shifted = imaging._log_convolve(g - 2000.0, kernels) + 2000.0
    np.testing.assert_allclose(shifted, direct, rtol=0, atol=1e-11)
    # the blur is not negligible
    assert model.blur_sigmas(scene.acquisition, scene.bodies)[0] > 0.9


def test_focal_spot_render_of_an_opaque_body_is_finite():
    image = xray_viz.render(_ball_scene(500.0, focal_spot=0.8))
    li = image.line_integral
    assert np.all(np.isfinite(li)) and li.max() > 3000
    # the blur only mixes values: the line integral stays within the unblurred range
    sharp = xray_viz.render(_ball_scene(500.0)).line_integral
    assert li.max() <= sharp.max() + 1e-9 and li.min() >= sharp.min() - 1e-9


def test_noise_with_a_huge_photon_count():
    scene = _ball_scene(0.2, i0=1e19, noise=True, seed=4)
    image = xray_viz.render(scene)
    clean = xray_viz.render(dataclasses.replace(scene, detector=dataclasses.replace(
        scene.detector, noise=False)))
    assert np.all(np.isfinite(image.intensity))
    rel = np.abs(image.intensity - clean.intensity) / clean.intensity
    assert 0 < rel.max() < 1e-7                        # sqrt(1e19 T) / (1e19 T): ~1e-9 .. 1e-8
    # the noise is there and has the Poisson variance (normal limit): z-scores of unit spread
    z = (image.intensity - clean.intensity) / np.sqrt(clean.intensity)
    assert 0.7 < z.std() < 1.3


def test_focal_spot_larger_than_the_detector_is_one_line(tmp_path, capsys):
    ball = tmp_path / "ball.stl"
    trimesh.creation.icosphere(subdivisions=2, radius=40.0).export(ball)
    scene = tmp_path / "s.toml"
    scene.write_text(
        '[source]\nposition = [0.0, 0.0, 1000.0]\n'
        '[detector]\ncenter = [0.0, 0.0, -500.0]\nshape = [32, 32]\npitch = 1.0\n'
        'focal_spot = 1e9\n'
        f'[[body]]\nmesh = "{ball}"\nmu = 0.2\n')
    out = tmp_path / "x.npy"
    assert main(["render", str(scene), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "focal_spot" in err and "mm" in err
    assert not out.exists()


def test_cli_line_integral_of_an_opaque_body_is_finite(tmp_path):
    ball = tmp_path / "ball.stl"
    trimesh.creation.icosphere(subdivisions=2, radius=40.0).export(ball)
    scene = tmp_path / "s.toml"
    scene.write_text(
        '[source]\nposition = [0.0, 0.0, 1000.0]\n'
        '[detector]\ncenter = [0.0, 0.0, -500.0]\nshape = [32, 32]\npitch = 1.0\n'
        f'[[body]]\nmesh = "{ball}"\nmu = 300.0\n')
    out = tmp_path / "li.npy"
    assert main(["render", str(scene), "-o", str(out), "--quantity", "line-integral"]) == 0
    li = np.load(out)
    assert np.all(np.isfinite(li)) and li.max() > 2000


# --------------------------------------------------------------------------------------------
# invariants checked on every engine's output: never a silent wrong image


def _faulty_windows(value):
    def windows(projector, acquisition, n, keep_hits=False):
        w, h = acquisition.detector.shape
        L = np.full((w * h * n * n, len(projector.bodies)), 3.0)
        L[7, 0] = value
        yield 0, h, L, None
    return windows


@pytest.mark.parametrize("value", [-1.0, np.nan, np.inf])
def test_a_negative_or_non_finite_path_length_is_refused(monkeypatch, tmp_path, capsys, value):
    import importlib

    render_module = importlib.import_module("xray_viz.render")
    from xray_viz.errors import EngineError

    monkeypatch.setattr(render_module, "_windows", _faulty_windows(value))
    scene = _ball_scene(0.2)
    with pytest.raises(EngineError, match="internal error.*'ball'.*row 0"):
        xray_viz.render(scene)
    out = tmp_path / "x.npy"
    np.save(out, np.zeros(3))                              # a previous good file
    assert main(["render", "sphere", "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("xray-viz: error: internal error") and "\n" not in err
    assert np.load(out).tolist() == [0.0, 0.0, 0.0]


def test_rounding_level_negatives_read_as_zero(monkeypatch):
    import importlib

    render_module = importlib.import_module("xray_viz.render")

    monkeypatch.setattr(render_module, "_windows", _faulty_windows(-1e-12))
    image = xray_viz.render(_ball_scene(0.2), path_lengths=True)
    assert image.path_length.min() == 0.0 and image.intensity.max() <= 1.0

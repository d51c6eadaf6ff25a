"""A detector, not an ideal counter: scintillator absorption, blur (the edge method's presampled
MTF), electronic noise and gain, the exact variance of energy-integrating detectors, and the heel
effect. Every expected number is computed here from xraylib / SpekPy, not copied."""

from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
import xraylib

import xray_viz
from physics_scenes import box, load, parallel_detector, pixel_centres, write_scene
from xray_viz.errors import SceneError, SceneFileNotFoundError
from xray_viz.physics import imaging
from xray_viz.physics.detector import absorption_efficiency, mtf_kernel
from xray_viz.physics.detector_model import DetectorModel
from xray_viz.physics.spectra import source_spectrum

PARALLEL = {"position": [0.0, 0.0, 1000.0], "kind": "parallel"}
TUBE = {"kvp": 80.0, "filters": {"Al": 2.5}}
CSI = {"material": "CsI", "thickness": 0.6, "fill": 0.8}


pytestmark = pytest.mark.filterwarnings(
    "ignore::xray_viz.physics.spectra.UnfilteredSpectrumWarning")   # bare spectra on purpose


def _mu(material, energies, density):
    """Linear attenuation (1/cm) straight from xraylib."""
    return np.array([xraylib.CS_Total_CP(material, float(e)) for e in energies]) * density


def _water_slab(thickness_mm):
    return ("water", box([400, 400, thickness_mm]), {"material": "Water, Liquid"})


# --------------------------------------------------------------------------------------------
# scintillator


@pytest.mark.parametrize("material, density, thickness, fill", [("CsI", 4.51, 0.6, 0.8),
                                                                 ("Gd2O2S", 7.32, 0.2, 1.0)])
def test_absorption_efficiency_is_one_minus_exp_of_xraylib_mu(material, density, thickness, fill):
    from xray_viz.physics.detector import scintillator_from_dict

    sc = scintillator_from_dict({"material": material, "thickness": thickness, "fill": fill})
    assert sc["density"] == density                                 # the documented defaults
    e = np.array([15.0, 33.0, 34.0, 50.0, 51.0, 80.0, 120.0])      # across the K edges
    expected = fill * (1 - np.exp(-_mu(material, e, density) * thickness / 10))
    np.testing.assert_allclose(absorption_efficiency(sc, e), expected, rtol=1e-14)
    # Cs/I K edges (36.0/33.2 keV) and Gd's (50.2 keV) show as jumps
    eta = absorption_efficiency(sc, e)
    jump = (2, 1) if material == "CsI" else (4, 3)
    assert eta[jump[0]] > eta[jump[1]]


#: The documented difference (physics/__init__.py): line integral of 20 cm of water at 80 kVp
#: (W anode, 12 degrees) with a 0.6 mm CsI converter against an ideal detector, in %.
DOCUMENTED_CSI_EXCESS = {("none", "energy"): 1.38, ("none", "counting"): 1.28,
                         ("Al", "energy"): 1.07, ("Al", "counting"): 0.95}


@pytest.mark.parametrize("filters", ["none", "Al"])
@pytest.mark.parametrize("response", ["energy", "counting"])
def test_csi_line_integral_behind_20_cm_of_water(tmp_path, filters, response):
    spectrum = {"kvp": 80.0} | ({"filters": {"Al": 2.5}} if filters == "Al" else {})
    kw = dict(source={**PARALLEL, "spectrum": spectrum}, bodies=[_water_slab(200.0)])
    ideal = load(tmp_path, detector=parallel_detector(shape=(3, 2), response=response), **kw)
    real = load(tmp_path, detector=parallel_detector(shape=(3, 2), response=response,
                                                     scintillator=CSI), **kw)
    li_ideal = xray_viz.render(ideal).line_integral
    li_real = xray_viz.render(real).line_integral
    # independent sums over the spectrum's bins
    s = source_spectrum(real.source)
    e, phi = s.energies, s.weights
    q = e if response == "energy" else np.ones_like(e)
    eta = 0.8 * (1 - np.exp(-_mu("CsI", e, 4.51) * 0.06))
    t = np.exp(-_mu("Water, Liquid", e, 1.0) * 20.0)
    want_ideal = -np.log((phi * q * t).sum() / (phi * q).sum())
    want_real = -np.log((phi * q * eta * t).sum() / (phi * q * eta).sum())
    np.testing.assert_allclose(li_ideal, want_ideal, rtol=1e-12)
    np.testing.assert_allclose(li_real, want_real, rtol=1e-12)
    excess = 100 * (want_real / want_ideal - 1)
    assert round(excess, 2) == DOCUMENTED_CSI_EXCESS[filters, response]
    # the converter hardens the detected beam: its line integral is larger, and the fill
    # factor does not change it (it scales every energy alike)
    half = load(tmp_path, detector=parallel_detector(shape=(3, 2), response=response,
                                                     scintillator={**CSI, "fill": 0.4}), **kw)
    np.testing.assert_allclose(xray_viz.render(half).line_integral, want_real, rtol=1e-12)


def test_scintillator_flat_field_reads_the_absorbed_fraction(tmp_path):
    i0 = 1000.0
    for source in ({"energy": 60.0}, {"spectrum": TUBE}):
        scene = load(tmp_path, source={**PARALLEL, **source},
                     detector=parallel_detector(shape=(4, 3), I0=i0, scintillator=CSI))
        s = source_spectrum(scene.source)
        eta = 0.8 * (1 - np.exp(-_mu("CsI", s.energies, 4.51) * 0.06))
        want = i0 * (s.weights * s.energies * eta).sum() / (s.weights * s.energies).sum()
        image = xray_viz.render(scene)
        np.testing.assert_allclose(image.intensity, want, rtol=1e-12)
        np.testing.assert_allclose(imaging.flat_field(scene), want, rtol=1e-12)
        np.testing.assert_allclose(image.line_integral, 0.0, atol=1e-12)
        assert 0.5 * i0 < want < 0.8 * i0


def test_counting_scintillator_noise_is_poisson_of_the_absorbed_photons(tmp_path):
    i0 = 400.0
    scene = load(tmp_path, source={**PARALLEL, "spectrum": TUBE},
                 detector=parallel_detector(shape=(128, 128), I0=i0, noise=True, seed=11,
                                            response="counting", scintillator=CSI))
    image = xray_viz.render(scene).intensity
    s = source_spectrum(scene.source)
    lam = i0 * (s.weights * 0.8 * (1 - np.exp(-_mu("CsI", s.energies, 4.51) * 0.06))).sum()
    n = image.size
    assert np.all(image == np.round(image))                         # whole photons
    assert abs(image.mean() - lam) < 5 * np.sqrt(lam / n)
    assert abs(image.var(ddof=1) - lam) < 5 * lam * np.sqrt(2 / n)


@pytest.mark.parametrize("scintillator, message", [
    ({"material": "CsI"}, "thickness"),
    ({"thickness": 0.5}, "material"),
    ({"material": "CsI", "thickness": -0.5}, "thickness must be a number > 0 mm, got -0.5"),
    ({"material": "CsI", "thickness": 0.5, "fill": 1.2}, "fill must be a number > 0 and <= 1"),
    ({"material": "CsI", "thickness": 0.5, "thick": 1}, "did you mean 'thickness'"),
    ({"material": "NaI", "thickness": 0.5}, "NaI.*density"),
    ({"material": "Csl", "thickness": 0.5}, "unknown material 'Csl'"),
    ("CsI", "must be a table"),
])
def test_scintillator_errors_are_one_line(tmp_path, scintillator, message):
    with pytest.raises(SceneError, match=message) as info:
        load(tmp_path, source={**PARALLEL, "energy": 60.0},
             detector=parallel_detector(shape=(2, 2), scintillator=scintillator))
    assert "\n" not in str(info.value) and "[detector] scintillator" in str(info.value)


# --------------------------------------------------------------------------------------------
# blur: the presampled MTF by the edge method

EDGE_DEG, EDGE_PITCH, EDGE_SHAPE, EDGE_N = 3.0, 0.1, (64, 128), 8


def _edge_image(tmp_path, mtf=None, *, mu=1000.0, name="edge"):
    """A 3-degree slanted edge of an opaque slab (10 mm of mu 1000/cm: a line integral of
    1000, far past exp underflow), parallel beam, 8 x 8 rays per pixel (the pixel aperture)."""
    det = parallel_detector(shape=EDGE_SHAPE, pitch=EDGE_PITCH, supersample=EDGE_N)
    if mtf is not None:
        det["mtf"] = mtf
    scene = load(tmp_path, source={**PARALLEL, "energy": 60.0}, detector=det,
                 bodies=[(name, box([20, 60, 10], center=[10, 0, 0], angle_z=EDGE_DEG),
                          {"mu": mu})])
    return xray_viz.render(scene).intensity


def _presampled_mtf(image, f):
    """The edge method: pixel centres projected onto the edge normal give an oversampled ESF
    (bins of a tenth of the pitch, at their mean position), its finite differences the LSF, and
    its Fourier transform the MTF, corrected for the bins' and the differences' sinc(f dx)."""
    th = np.radians(EDGE_DEG)
    x, y = pixel_centres(EDGE_SHAPE, EDGE_PITCH)
    # the slab's left face: through (10 - 10 cos, -10 sin), normal (cos, sin)
    d = ((x - (10 - 10 * np.cos(th))) * np.cos(th) + (y + 10 * np.sin(th)) * np.sin(th)).ravel()
    v = image.ravel()
    near = np.abs(d) < 2.5                                          # 25 pixels either side
    dx = EDGE_PITCH / 10
    b = np.floor(d[near] / dx).astype(int)
    b -= b.min()
    count = np.bincount(b)
    assert np.all(count > 0)                                        # every bin sampled
    esf = np.bincount(b, v[near]) / count
    pos = np.bincount(b, d[near]) / count
    lsf = np.diff(esf)
    mid = (pos[1:] + pos[:-1]) / 2
    m = np.abs(np.exp(-2j * np.pi * f[:, None] * mid[None, :]) @ lsf) / abs(lsf.sum())
    return m / np.sinc(f * dx) ** 2


NYQUIST = 0.5 / EDGE_PITCH
FREQ = np.linspace(0.0, NYQUIST, 26)


def test_edge_method_without_blur_measures_the_pixel_aperture(tmp_path):
    m = _presampled_mtf(_edge_image(tmp_path), FREQ)
    np.testing.assert_allclose(m, np.abs(np.sinc(FREQ * EDGE_PITCH)), rtol=0.01)


@pytest.mark.parametrize("mtf, sigma", [({"sigma": 0.1}, 0.1),
                                        ({"fwhm": 0.15 * 2 * np.sqrt(2 * np.log(2))}, 0.15)])
def test_presampled_mtf_of_a_gaussian_blur_from_a_slanted_edge(tmp_path, mtf, sigma):
    m = _presampled_mtf(_edge_image(tmp_path, mtf), FREQ)
    want = np.exp(-2 * np.pi**2 * sigma**2 * FREQ**2) * np.abs(np.sinc(FREQ * EDGE_PITCH))
    assert np.abs(m - want).max() < 0.005
    big = want > 0.05
    assert big.sum() >= 10
    np.testing.assert_allclose(m[big], want[big], rtol=0.03)
    # the blur moved the MTF: at half the Nyquist frequency it is well below the aperture's
    assert m[13] < 0.8 * np.sinc(FREQ[13] * EDGE_PITCH)


def test_opaque_edge_blurs_the_same_in_the_log_domain(tmp_path):
    # mu 50/cm: a line integral of 50, blurred directly; mu 1000/cm: 1000, through log-sum-exp
    direct = _edge_image(tmp_path, {"sigma": 0.1}, mu=50.0)
    logged = _edge_image(tmp_path, {"sigma": 0.1}, mu=1000.0)
    np.testing.assert_allclose(logged, direct, atol=1e-15)
    assert np.abs(direct - _edge_image(tmp_path, mu=50.0)).max() > 0.05


def test_sub_pixel_blur_is_the_kernel_that_the_grid_can_carry(tmp_path):
    # sigma = half a pixel: no non-negative kernel on the pixel grid has exactly the Gaussian's
    # MTF; the edge measures the applied kernel's, which is within its reported error
    sigma = 0.05
    kernel, err = mtf_kernel({"sigma": sigma}, EDGE_PITCH)
    assert np.all(kernel >= 0) and kernel.sum() == pytest.approx(1.0, abs=1e-14)
    assert 0.01 < err < 0.065                                        # documented: ~0.06
    m = _presampled_mtf(_edge_image(tmp_path, {"sigma": sigma}), FREQ)
    r = np.arange(len(kernel)) - len(kernel) // 2
    nu = FREQ * EDGE_PITCH
    applied = np.abs(np.cos(2 * np.pi * nu[:, None] * r[None, :]) @ kernel)
    np.testing.assert_allclose(m, applied * np.abs(np.sinc(nu)), atol=0.004)
    gauss = np.exp(-2 * np.pi**2 * sigma**2 * FREQ**2)
    assert np.abs(applied - gauss).max() <= err + 1e-6


@pytest.mark.parametrize("sigma_px, bound", [(1.0, 0.002), (0.7, 0.012), (0.5, 0.065),
                                             (0.2, 0.03), (2.0, 1e-4)])
def test_mtf_kernel_error_is_as_documented(sigma_px, bound):
    pitch = 0.14
    kernel, err = mtf_kernel({"sigma": sigma_px * pitch}, pitch)
    nu = np.linspace(0, 0.5, 1001)                                  # finer than the fit's grid
    r = np.arange(len(kernel)) - len(kernel) // 2
    response = np.cos(2 * np.pi * nu[:, None] * r[None, :]) @ kernel
    gauss = np.exp(-2 * np.pi**2 * sigma_px**2 * nu**2)
    assert np.abs(response - gauss).max() < bound
    assert err == pytest.approx(np.abs(response - gauss).max(), abs=2e-3)
    assert np.all(kernel >= 0) and np.allclose(kernel, kernel[::-1])


def test_mtf_and_lsf_tables_give_the_gaussian_kernel(tmp_path):
    sigma, pitch = 0.12, 0.1
    f = np.linspace(0, 6.0, 121)
    presampled = np.exp(-2 * np.pi**2 * sigma**2 * f**2) * np.abs(np.sinc(f * pitch))
    (tmp_path / "mtf.csv").write_text("cycles/mm, MTF\n" + "".join(
        f"{float(a)!r}, {float(b)!r}\n" for a, b in zip(f, presampled)))
    x = np.arange(-1.0, 1.0 + 1e-9, 0.005)
    (tmp_path / "lsf.csv").write_text("# a Gaussian LSF\n" + "".join(
        f"{float(a)!r} {float(b)!r}\n" for a, b in zip(x, np.exp(-x**2 / (2 * sigma**2)))))
    want = mtf_kernel({"sigma": sigma}, pitch)[0]
    images = []
    for mtf in ({"sigma": sigma}, {"file": "mtf.csv"}, {"lsf": "lsf.csv", "presampled": False}):
        scene = load(tmp_path, source={**PARALLEL, "energy": 60.0},
                     detector=parallel_detector(shape=(24, 20), pitch=pitch, mtf=mtf),
                     bodies=[("cube", box([1, 1, 4]), {"mu": 3.0})])
        k = mtf_kernel(scene.detector.mtf, pitch)[0]
        pad = (len(k) - len(want)) // 2
        k, w = (k, np.pad(want, pad)) if pad >= 0 else (np.pad(k, -pad), want)
        assert np.abs(k - w).max() < 2e-3
        images.append(xray_viz.render(scene).intensity)
    np.testing.assert_allclose(images[1], images[0], atol=2e-3)
    np.testing.assert_allclose(images[2], images[0], atol=2e-3)


def test_mtf_blur_conserves_signal_and_is_shift_equivariant_in_the_log_domain(tmp_path):
    kw = dict(source={**PARALLEL, "energy": 60.0},
              bodies=[("cube", box([3, 3, 8], center=[1.0, 0.5, 0]), {"mu": 2.0})])
    sharp = load(tmp_path, detector=parallel_detector(shape=(20, 24), pitch=0.25), **kw)
    blurred = load(tmp_path, detector=parallel_detector(shape=(20, 24), pitch=0.25,
                                                        mtf={"sigma": 0.4}), **kw)
    a, b = xray_viz.render(sharp).intensity, xray_viz.render(blurred).intensity
    assert np.abs(a - b).max() > 0.05
    assert b.sum() == pytest.approx(a.sum(), rel=1e-12)
    kernels = DetectorModel.of(blurred.detector).mtf_kernels
    g = np.log(a)
    np.testing.assert_allclose(imaging._log_convolve(g - 3000.0, kernels) + 3000.0,
                               np.log(imaging._convolve(a, kernels)), rtol=1e-12, atol=1e-11)


@pytest.mark.parametrize("mtf, message", [
    ({"sigma": -0.1}, "sigma must be a number > 0 mm"),
    ({"sigma": 0.1, "fwhm": 0.2}, "exactly one of"),
    ({}, "exactly one of"),
    ({"sigma": 0.1, "presampled": True}, "presampled goes with"),
    ({"sigam": 0.1}, "did you mean 'sigma'"),
    ({"sigma": 50.0}, "blurs more than the detector"),
    ({"file": "short.csv"}, "ends at 2 cycles/mm, below the detector's Nyquist frequency 5"),
    ({"file": "offset.csv"}, "must start at 0 cycles/mm"),
    ({"lsf": "coarse.csv"}, "not finer than the detector pitch"),
    ({"file": "bad.csv"}, "line 2, field 2 of 2 is not a number"),
])
def test_mtf_errors_are_one_line(tmp_path, mtf, message):
    (tmp_path / "short.csv").write_text("0, 1\n1, 0.8\n2, 0.5\n")
    (tmp_path / "offset.csv").write_text("0.5, 1\n6, 0.5\n")
    (tmp_path / "coarse.csv").write_text("-1, 0\n-0.5, 0.2\n0, 1\n0.5, 0.2\n1, 0\n")
    (tmp_path / "bad.csv").write_text("0, 1\n1, x\n")
    with pytest.raises(SceneError, match=message) as info:
        load(tmp_path, source={**PARALLEL, "energy": 60.0},
             detector=parallel_detector(shape=(8, 8), pitch=0.1, mtf=mtf))
    assert "\n" not in str(info.value) and "[detector]" in str(info.value)


def test_missing_mtf_file_is_not_found(tmp_path):
    with pytest.raises(SceneFileNotFoundError, match=r"\[detector\] mtf: .*nope.csv"):
        load(tmp_path, source={**PARALLEL, "energy": 60.0},
             detector=parallel_detector(shape=(8, 8), pitch=0.1, mtf={"file": "nope.csv"}))


# --------------------------------------------------------------------------------------------
# electronic noise and gain


def test_gain_scales_intensity_and_keeps_the_line_integral(tmp_path):
    kw = dict(source={**PARALLEL, "spectrum": TUBE},
              bodies=[("cube", box([3, 3, 8]), {"material": "Al", "density": 2.7})])
    one = xray_viz.render(load(tmp_path, detector=parallel_detector(shape=(8, 8), I0=50.0), **kw))
    two = xray_viz.render(load(tmp_path, detector=parallel_detector(shape=(8, 8), I0=50.0,
                                                                   gain=2.5), **kw))
    np.testing.assert_allclose(two.intensity, 2.5 * one.intensity, rtol=1e-14)
    np.testing.assert_array_equal(two.line_integral, one.line_integral)


def test_electronic_noise_and_gain_flat_field_statistics(tmp_path):
    i0, sigma_e, gain = 100.0, 5.0, 2.5
    scene = load(tmp_path, source={**PARALLEL, "energy": 60.0},
                 detector=parallel_detector(shape=(256, 256), I0=i0, noise=True, seed=5,
                                            response="counting", electronic_noise=sigma_e,
                                            gain=gain))
    image = xray_viz.render(scene).intensity
    n = image.size
    mean, var = gain * i0, gain**2 * (i0 + sigma_e**2)             # Poisson + Gaussian, then gain
    assert abs(image.mean() - mean) < 5 * np.sqrt(var / n)
    assert abs(image.var(ddof=1) - var) < 5 * var * np.sqrt(2 / n)
    assert not np.all(image == np.round(image))                     # no longer whole photons


def test_order_quantum_noise_then_blur_then_electronic_noise(tmp_path):
    # the MTF blurs the quantum noise (variance times sum k^2 per axis), not the electronic
    # noise, which is added per pixel after it
    i0, sigma_e = 400.0, 3.0
    scene = load(tmp_path, source={**PARALLEL, "energy": 60.0},
                 detector=parallel_detector(shape=(256, 256), pitch=0.1, I0=i0, noise=True,
                                            seed=8, response="counting", electronic_noise=sigma_e,
                                            mtf={"sigma": 0.1}))
    image = xray_viz.render(scene).intensity[8:-8, 8:-8]               # away from the mirror
    k_rows, k_cols = DetectorModel.of(scene.detector).mtf_kernels
    var = i0 * (k_rows @ k_rows) * (k_cols @ k_cols) + sigma_e**2
    n = image.size
    assert abs(image.mean() - i0) < 5 * np.sqrt(var / n)
    # neighbouring pixels are correlated, so the sample variance scatters more than 2/n; a
    # quarter of the pixels (every other row and column) are nearly independent
    assert abs(image.var(ddof=1) - var) < 5 * var * np.sqrt(2 / (n / 4))
    assert var < 0.5 * (i0 + sigma_e**2)                              # the blur matters


@pytest.mark.parametrize("detector, message", [
    ({"electronic_noise": 2.0}, "electronic_noise = 2 needs noise = true"),
    ({"electronic_noise": -1.0, "noise": True, "I0": 10.0}, "electronic_noise must be >= 0"),
    ({"gain": 0.0}, "gain must be > 0"),
    ({"gain": "high"}, "gain must be a number"),
])
def test_noise_and_gain_errors(tmp_path, detector, message):
    with pytest.raises(SceneError, match=message) as info:
        load(tmp_path, source={**PARALLEL, "energy": 60.0},
             detector=parallel_detector(shape=(2, 2), **detector))
    assert "\n" not in str(info.value)


# --------------------------------------------------------------------------------------------
# exact noise of an energy-integrating detector


def _transmitted_moments(scene, thickness_cm, scintillator=None):
    """Mean and variance of the signal (photon-equivalents per incident photon), by hand."""
    s = source_spectrum(scene.source)
    e, phi = s.energies, s.weights
    eta = np.ones_like(e) if scintillator is None else \
        scintillator["fill"] * (1 - np.exp(-_mu("CsI", e, 4.51) * scintillator["thickness"] / 10))
    t = np.exp(-_mu("Water, Liquid", e, 1.0) * thickness_cm)
    e_ref = phi @ e                                                  # the photon-equivalent
    return (phi * e * eta * t).sum() / e_ref, (phi * e**2 * eta * t).sum() / e_ref**2


@pytest.mark.parametrize("thickness_mm", [10.0, 200.0])
@pytest.mark.parametrize("scintillator", [None, CSI])
def test_energy_integrating_variance_is_the_transmitted_spectrums(tmp_path, thickness_mm,
                                                                   scintillator):
    i0 = 20000.0
    det = parallel_detector(shape=(128, 128), I0=i0, noise=True, seed=3)
    if scintillator:
        det["scintillator"] = scintillator
    scene = load(tmp_path, source={**PARALLEL, "spectrum": TUBE}, detector=det,
                 bodies=[_water_slab(thickness_mm)])
    image = xray_viz.render(scene).intensity
    m1, m2 = _transmitted_moments(scene, thickness_mm / 10, scintillator)
    mean, var = i0 * m1, i0 * m2
    n = image.size
    assert abs(image.mean() - mean) < 5 * np.sqrt(var / n)
    assert abs(image.var(ddof=1) - var) < 5 * var * np.sqrt(2 / n)
    # the unattenuated beam's Swank factor would be 18 % low behind 20 cm of water
    s = source_spectrum(scene.source)
    old = mean * (s.weights @ s.energies**2) / (s.weights @ s.energies)**2
    if scintillator is None:
        old_error = 1 - old / var
        assert (0.17 < old_error < 0.19) if thickness_mm == 200 else (0.01 < old_error < 0.03)
    if thickness_mm == 200:
        assert abs(image.var(ddof=1) - old) > 10 * var * np.sqrt(2 / n)


def test_variance_sum_in_the_log_domain_is_exact(tmp_path):
    scene = load(tmp_path, source={**PARALLEL, "spectrum": TUBE},
                 detector=parallel_detector(shape=(2, 2)),
                 bodies=[("water", box([1, 1, 1]), {"material": "Water, Liquid"})])
    s = source_spectrum(scene.source)
    e, phi = s.energies, s.weights
    mu = _mu("Water, Liquid", e, 1.0) / 10                           # 1/mm
    lengths = np.array([0.0, 10.0, 200.0, 5e3, 1e5])                 # to far past underflow
    got = imaging.log_variance_transmission(lengths[:, None], scene)
    w = phi * e**2
    want = np.array([np.logaddexp.reduce(np.log(w) - mu * L) - np.log(w.sum()) for L in lengths])
    np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-14)
    assert np.all(np.isfinite(got)) and np.all(np.diff(got) < 0)
    # the variance-to-mean ratio grows with thickness (the transmitted beam is harder)
    mean = imaging.log_transmission(lengths[:, None], scene)
    assert np.all(np.diff(got - mean) > 0)


def test_pixel_log_transmission_gives_the_variance_only_when_needed(tmp_path):
    kw = dict(source={**PARALLEL, "spectrum": TUBE}, bodies=[_water_slab(50.0)])
    L = np.full((16 * 4, 1), 50.0)
    for det, needed in (({}, False), ({"noise": True, "I0": 10.0}, True),
                        ({"noise": True, "I0": 10.0, "response": "counting"}, False)):
        scene = load(tmp_path, detector=parallel_detector(shape=(4, 4), **det), **kw)
        log_t, log_v = imaging.pixel_log_transmission(L, scene, supersample=2)
        assert log_t.shape == (4, 4) and (log_v is not None) == needed
        if needed:
            assert np.all(log_v > log_t)                             # hardened: V/M grew


# --------------------------------------------------------------------------------------------
# heel effect

SID_MM = 1000.0


@lru_cache(maxsize=4)
def _spek(kvp, angle, al_mm):
    import spekpy

    s = spekpy.Spek(kvp=kvp, th=angle, dk=1.0)
    s.filter("Al", al_mm)
    return s


def _heel_scene(tmp_path, heel=True, *, shape=(9, 9), size=300.0, angle=12.0, extra=None,
                al_mm=20.0):
    pitch = size / (shape[0] - 1)
    bodies = [("al", box([600, 600, al_mm], center=[0, 0, 100]), {"material": "Al",
                                                                  "density": 2.699})]
    return load(tmp_path, source={"position": [0, 0, SID_MM], "kind": "point", "heel": heel,
                                  "spectrum": {"kvp": 80.0, "anode_angle": angle,
                                               "filters": {"Al": 2.5}}},
                detector={"center": [0, 0, 0.0], "up": [0, 1, 0], "shape": list(shape),
                          "pitch": pitch, "I0": 1000.0, **(extra or {})},
                bodies=bodies if al_mm else [])


def _spekpy_reading(x_mm, y_mm, *, angle=12.0, al_mm=20.0):
    """SpekPy's spectrum towards a pixel (x towards the cathode), per solid angle, relative to
    the central axis: (detected intensity, transmitted fraction behind the Al) for an ideal
    energy-integrating detector."""
    s = _spek(80.0, angle, 0.0)
    z = SID_MM / 10
    k, centre = s.get_spectrum()
    _, here = s.get_spectrum(x=x_mm / 10, y=y_mm / 10, z=z)
    here = here * ((x_mm / 10) ** 2 + (y_mm / 10) ** 2 + z**2) / z**2      # no inverse square
    oblique = np.sqrt(1 + (x_mm / SID_MM) ** 2 + (y_mm / SID_MM) ** 2)   # path through the slab
    # the tube's 2.5 mm Al, crossed obliquely off axis, with xraylib's Al (as the bodies)
    mu_filter = _mu("Al", np.maximum(k, 1.0), 2.699) / 10
    centre = centre * np.exp(-mu_filter * 2.5)
    here = here * np.exp(-mu_filter * 2.5 * oblique)
    t = np.exp(-_mu("Al", np.maximum(k, 1.0), 2.699) * al_mm * oblique / 10)
    detected = (here * k * t).sum() / (centre * k).sum()
    return detected, (here * k * t).sum() / (here * k).sum()


def test_heel_anode_side_is_darker_and_harder_as_spekpy_says(tmp_path):
    scene = _heel_scene(tmp_path)
    image = xray_viz.render(scene)
    # rows 0 and 8 (the top, the anode side, and the bottom) at the centre column are 150 mm
    # from the axis; the pitch is 37.5 mm, the source 1000 mm away; no fall-off
    anode, cathode = image.intensity[0, 4], image.intensity[8, 4]
    # (2e-5: the tube filter's oblique path is interpolated with the heel's grid)
    want_anode = _spekpy_reading(-150.0, 0.0)
    want_cathode = _spekpy_reading(150.0, 0.0)
    assert anode == pytest.approx(1000.0 * want_anode[0], rel=2e-5)
    assert cathode == pytest.approx(1000.0 * want_cathode[0], rel=2e-5)
    assert np.exp(-image.line_integral[0, 4]) == pytest.approx(want_anode[1], rel=2e-5)
    assert np.exp(-image.line_integral[8, 4]) == pytest.approx(want_cathode[1], rel=2e-5)
    # darker and harder on the anode side, by SpekPy's amounts (here ~14 % less signal behind
    # the aluminium, and ~14 % more of the beam through it)
    assert anode < 0.95 * cathode
    assert want_anode[1] > 1.03 * want_cathode[1]
    column = image.intensity[:, 4]
    assert np.all(column[:4] < column[::-1][:4])                   # than the mirror pixel
    # across the axis it is symmetric
    np.testing.assert_allclose(image.intensity[:, 0], image.intensity[:, 8], rtol=1e-12)


def test_heel_spectra_between_grid_nodes_are_close_to_spekpys(tmp_path):
    scene = _heel_scene(tmp_path, shape=(13, 13))
    image = xray_viz.render(scene)
    pitch = 300.0 / 12
    for row, col in ((1, 3), (5, 11), (10, 7)):                     # not grid nodes
        x = -(6 - row) * pitch                                       # top = anode = -x
        y = (col - 6) * pitch
        detected, through = _spekpy_reading(x, y)
        assert image.intensity[row, col] == pytest.approx(1000.0 * detected, rel=1e-3)
        assert np.exp(-image.line_integral[row, col]) == pytest.approx(through, rel=1e-3)


def test_heel_sides_turn_the_image(tmp_path):
    top = xray_viz.render(_heel_scene(tmp_path, True, shape=(5, 5))).intensity
    for side, turned in (("bottom", top[::-1]), ("left", top.T), ("right", top.T[:, ::-1])):
        image = xray_viz.render(_heel_scene(tmp_path, side, shape=(5, 5))).intensity
        np.testing.assert_allclose(image, turned, rtol=1e-9)


def test_heel_in_bands_of_rows_equals_the_whole_detector(tmp_path):
    scene = _heel_scene(tmp_path, shape=(5, 6), extra={"noise": True, "seed": 1})   # W 5, H 6
    n = 2
    rng = np.random.default_rng(0)
    L = rng.uniform(0, 30, (6 * 5 * n * n, 1))
    full_t, full_v = imaging.pixel_log_transmission(L, scene, supersample=n)
    per_row = 5 * n * n
    for rows in ((0, 2), (2, 5), (5, 6)):
        band = L[rows[0] * per_row:rows[1] * per_row]
        t, v = imaging.pixel_log_transmission(band, scene, supersample=n, rows=rows)
        np.testing.assert_allclose(t, full_t[rows[0]:rows[1]], rtol=1e-14)
        np.testing.assert_allclose(v, full_v[rows[0]:rows[1]], rtol=1e-14)
        # the same from the explicit per-ray weights
        w = imaging.ray_weights(scene, rows, supersample=n)
        s = source_spectrum(scene.source)
        mu = imaging.body_mu(scene, s.energies)[:, 0] / 10
        by_hand = np.log((w * np.exp(-band * mu[None, :])).sum(axis=1))
        np.testing.assert_allclose(imaging.log_transmission(band, scene, rows=rows), by_hand,
                                   rtol=1e-12)
    with pytest.raises(ValueError, match="do not cover image rows 0:2"):
        imaging.log_transmission(L[:7], scene, rows=(0, 2))


@pytest.mark.parametrize("source, message", [
    ({"kind": "parallel"}, "needs a point source"),
    ({"spectrum": None, "energy": 60.0}, "needs a SpekPy tube spectrum.*monochromatic"),
    ({"spectrum": {"file": "s.csv"}}, "needs a SpekPy tube spectrum.*file"),
    ({"heel": "up"}, "heel must be true, false or the anode's side"),
    ({"heel": 1}, "heel must be true, false or the anode's side"),
    ({"spectrum": {"kvp": 80.0, "anode_angle": 6.0}}, "behind the anode surface"),
])
def test_heel_errors_are_one_line(tmp_path, source, message):
    (tmp_path / "s.csv").write_text("50, 1\n60, 1\n")
    src = {"position": [0, 0, SID_MM], "kind": "point", "heel": True,
           "spectrum": {"kvp": 80.0}, **source}
    src = {k: v for k, v in src.items() if v is not None}
    with pytest.raises(SceneError, match=message) as info:
        xray_viz.load_scene(write_scene(tmp_path, source=src, detector={
            "center": [0, 0, 0.0], "shape": [5, 5], "pitch": 60.0}))
    assert "\n" not in str(info.value) and "[source] heel" in str(info.value)

"""Image formation: polychromatic sums, beam hardening, noise statistics, supersampling, fall-off,
focal-spot blur. Mathematics and physics, not snapshots."""

import numpy as np
import pytest
import xraylib

import xray_viz
from physics_scenes import box, load, parallel_detector, pixel_centres
from xray_viz.errors import SceneError
from xray_viz.physics.imaging import (focal_spot_blur_mm, magnification, source_object_distance,
                                      transmission)
from xray_viz.physics.spectra import source_spectrum

PARALLEL = {"position": [0.0, 0.0, 1000.0], "kind": "parallel"}
POINT = {"position": [0.0, 0.0, 1000.0], "kind": "point"}


def _sphere(radius=20.0):
    import trimesh

    return trimesh.creation.icosphere(subdivisions=3, radius=radius)


def test_monochromatic_box_line_integral(tmp_path):
    scene = load(tmp_path, source={**PARALLEL, "energy": 60.0}, detector=parallel_detector(),
                 bodies=[("slab", box([40, 40, 10]), {"material": "Al", "density": 2.699})])
    image = xray_viz.render(scene)
    mu = xraylib.CS_Total_CP("Al", 60.0) * 2.699
    np.testing.assert_allclose(image.line_integral, mu * 1.0, rtol=1e-9)


@pytest.mark.parametrize("response", ["energy", "counting"])
def test_polychromatic_equals_explicit_sum_over_spectrum(tmp_path, response):
    (tmp_path / "spec.csv").write_text("keV,fluence\n30,2\n45,5\n60,4\n75,1\n")
    scene = load(tmp_path, source={**POINT, "spectrum": {"file": "spec.csv"}},
                 detector=parallel_detector(shape=(24, 20), pitch=2.0, response=response),
                 bodies=[("ball", _sphere(), {"material": "Water, Liquid"}),
                         ("core", _sphere(8.0), {"material": "Ca5(PO4)3OH", "density": 3.0})])
    image = xray_viz.render(scene)
    L = image.path_length / 10.0                                    # cm, (H, W, 2)
    energies, fluence = [30, 45, 60, 75], np.array([2, 5, 4, 1], float)
    weights = fluence * energies if response == "energy" else fluence
    expected = np.zeros(L.shape[:2])
    for e, w in zip(energies, weights):                            # independent sum, by hand
        mu_water = xraylib.CS_Total_CP("Water, Liquid", e) * 1.0
        mu_hap = xraylib.CS_Total_CP("Ca5(PO4)3OH", e) * 3.0
        expected += w * np.exp(-(mu_water * L[..., 0] + mu_hap * L[..., 1]))
    expected /= weights.sum()
    assert L[..., 1].max() > 10 / 10                               # the core is seen
    np.testing.assert_allclose(image.intensity, expected, rtol=1e-12)
    np.testing.assert_allclose(image.line_integral, -np.log(expected), rtol=1e-12)


def test_transmission_chunks_agree():
    scene = xray_viz.load_scene("sphere").replace()
    scene = scene.replace(source=type(scene.source)(position=[0, 0, 1000],
                                                    spectrum={"kvp": 80.0}, energy=None))
    L = np.random.default_rng(0).uniform(0, 80, (5000, 1))
    full = transmission(L, scene)
    from xray_viz.physics import beam as beam_module

    old = beam_module.CHUNK_BYTES
    try:
        beam_module.CHUNK_BYTES = 8 * 79 * 7                          # 7 rays per chunk
        np.testing.assert_allclose(transmission(L, scene), full, rtol=1e-14)
    finally:
        beam_module.CHUNK_BYTES = old
    assert np.all(np.diff(full[np.argsort(L[:, 0])]) <= 0)        # more material, less signal


@pytest.mark.parametrize("material, density", [("Al", 2.699), ("Water, Liquid", None)])
def test_beam_hardening_effective_mu_falls_with_thickness(tmp_path, material, density):
    thicknesses = [0.2, 2.0, 5.0, 10.0, 20.0, 40.0]                # mm, side by side
    keys = {"material": material} | ({"density": density} if density else {})
    bodies = [(f"slab{i}", box([10, 10, t], center=[-31.25 + 12.5 * i, 0, 0]), keys)
              for i, t in enumerate(thicknesses)]
    scene = load(tmp_path, source={**PARALLEL, "spectrum": {"kvp": 80.0, "filters": {"Al": 2.5}}},
                 detector=parallel_detector(shape=(6, 1), pitch=12.5), bodies=bodies)
    image = xray_viz.render(scene)
    mu_eff = image.line_integral[0] / (np.array(thicknesses) / 10)  # 1/cm
    assert np.all(np.diff(mu_eff) < 0), mu_eff
    spectrum = source_spectrum(scene.source)
    from xray_viz.physics.materials import linear_attenuation

    mu = linear_attenuation(material, spectrum.energies, density=density)
    # Jensen: -ln(sum w exp(-mu t)) / t < sum w mu, with equality in the thin-slab limit;
    # thick slabs tend to the smallest mu of the spectrum (the hardest photons)
    w = spectrum.weights * spectrum.energies
    mean_mu = (w @ mu) / w.sum()
    assert np.all(mu_eff < mean_mu)
    assert mu_eff[0] == pytest.approx(mean_mu, rel=0.02)
    assert mu_eff[-1] > mu.min()


def _flat_scene(tmp_path, *, shape=(128, 128), **detector):
    return load(tmp_path, source={**PARALLEL, **detector.pop("source", {"energy": 60.0})},
                detector=parallel_detector(shape=shape, **detector))


@pytest.mark.parametrize("source, response", [({"energy": 60.0}, "counting"),
                                              ({"energy": 60.0}, "energy"),
                                              ({"spectrum": {"kvp": 100.0,
                                                             "filters": {"Al": 2.5}}}, "energy"),
                                              ({"spectrum": {"kvp": 100.0,
                                                             "filters": {"Al": 2.5}}}, "counting")])
def test_poisson_flat_field_mean_and_variance(tmp_path, source, response):
    i0 = 400.0
    scene = _flat_scene(tmp_path, source=source, I0=i0, noise=True, seed=7, response=response)
    image = xray_viz.render(scene).intensity
    n = image.size
    s = source_spectrum(scene.source).swank_factor if response == "energy" else 1.0
    var = i0 / s
    assert abs(image.mean() - i0) < 5 * np.sqrt(var / n)
    # the sample variance has a standard deviation of about var * sqrt(2 / n)
    assert abs(image.var(ddof=1) - var) < 5 * var * np.sqrt(2 / n)
    if response == "counting":
        assert np.all(image == np.round(image))                    # photon counts


def test_noise_seed_reproducible(tmp_path):
    a = xray_viz.render(_flat_scene(tmp_path, shape=(16, 16), I0=100.0, noise=True, seed=3))
    b = xray_viz.render(_flat_scene(tmp_path, shape=(16, 16), I0=100.0, noise=True, seed=3))
    c = xray_viz.render(_flat_scene(tmp_path, shape=(16, 16), I0=100.0, noise=True, seed=4))
    assert np.array_equal(a.intensity, b.intensity)
    assert not np.array_equal(a.intensity, c.intensity)
    assert np.all(np.isfinite(a.line_integral))


def test_noise_needs_i0(tmp_path):
    with pytest.raises(SceneError, match="I0"):
        _flat_scene(tmp_path, shape=(4, 4), noise=True)


@pytest.mark.parametrize("detector, message", [({"response": "charge"}, "response"),
                                               ({"supersample": 0}, "supersample"),
                                               ({"noise": "yes"}, "true or false"),
                                               ({"focal_spot": -1.0}, "focal_spot"),
                                               ({"I0": 0.0}, "I0"),
                                               ({"seeed": 1}, "did you mean 'seed'")])
def test_detector_key_errors(tmp_path, detector, message):
    with pytest.raises(SceneError, match=message):
        _flat_scene(tmp_path, shape=(4, 4), **detector)


def test_supersampling_converges_to_pixel_average(tmp_path):
    # a slab rotated 30 degrees about the beam: its edges cut pixels obliquely
    shape, pitch, mu, t = (24, 24), 2.0, 0.5, 10.0
    scene = load(tmp_path, source={**PARALLEL, "energy": 60.0},
                 detector=parallel_detector(shape=shape, pitch=pitch),
                 bodies=[("slab", box([30, 30, t], angle_z=30.0), {"mu": mu})])
    # analytic pixel average: exp(-mu t) over the part of the pixel inside the slab, fine grid
    x, y = pixel_centres(shape, pitch)
    k = 200
    off = ((np.arange(k) + 0.5) / k - 0.5) * pitch
    px = x[..., None, None] + off[None, None, None, :]
    py = y[..., None, None] + off[None, None, :, None]
    c, s = np.cos(np.radians(30.0)), np.sin(np.radians(30.0))
    inside = (np.abs(c * px + s * py) < 15) & (np.abs(-s * px + c * py) < 15)
    expected = 1 + inside.mean(axis=(-2, -1)) * (np.exp(-mu * t / 10) - 1)
    edge = (expected > np.exp(-mu * t / 10) + 1e-9) & (expected < 1 - 1e-9)
    assert edge.sum() > 20
    errors = []
    for n in (1, 2, 4, 8, 16):
        image = xray_viz.render(scene, supersample=n)
        errors.append(np.abs(image.intensity - expected)[edge].mean())
    interior = ~edge
    np.testing.assert_allclose(image.intensity[interior], expected[interior], rtol=1e-12)
    assert errors[-1] < errors[0] / 8, errors
    assert errors[-1] < 2e-3, errors
    # the scene's supersample is read from [detector] (the renderer's default comes from it)
    assert load(tmp_path, source={**PARALLEL, "energy": 60.0},
                detector=parallel_detector(supersample=4)).detector.supersample == 4


def test_falloff_inverse_square_and_obliquity(tmp_path):
    shape, pitch = (33, 21), 10.0
    scene = load(tmp_path, source={**POINT, "energy": 60.0},
                 detector=parallel_detector(shape=shape, pitch=pitch, falloff=True, I0=50.0))
    image = xray_viz.render(scene)
    x, y = pixel_centres(shape, pitch)
    sid = 1500.0
    r2 = x**2 + y**2 + sid**2
    expected = 50.0 * (sid**2 / r2) * (sid / np.sqrt(r2))           # 1/r^2 times cos(theta)
    np.testing.assert_allclose(image.intensity, expected, rtol=1e-12)
    np.testing.assert_allclose(image.line_integral, 0.0, atol=1e-12)  # flat-field corrected
    assert image.intensity[10, 16] == pytest.approx(50.0)             # detector centre


def test_focal_spot_blur_conserves_signal(tmp_path):
    kw = dict(source={**POINT, "energy": 60.0},
              bodies=[("cube", box([8, 8, 8]), {"mu": 2.0})])
    sharp = load(tmp_path, detector=parallel_detector(shape=(64, 64), pitch=0.25), **kw)
    blurred = load(tmp_path, detector=parallel_detector(shape=(64, 64), pitch=0.25,
                                                        focal_spot=1.2), **kw)
    # object plane through the cube's centre, 1000 mm from the source: M = 1.5, penumbra 0.6 mm
    # (FWHM 2.4 pixels)
    assert source_object_distance(blurred) == pytest.approx(1000.0)
    assert magnification(blurred) == pytest.approx(1.5)
    assert focal_spot_blur_mm(blurred) == pytest.approx(0.6)
    a, b = xray_viz.render(sharp).intensity, xray_viz.render(blurred).intensity
    assert np.abs(a - b).max() > 0.1                                # edges are blurred
    assert b.sum() == pytest.approx(a.sum(), rel=1e-12)            # total signal conserved


def test_gaussian_kernel_has_exact_variance_below_a_pixel():
    from xray_viz.physics.imaging import gaussian_kernel

    for sigma in (0.01, 0.05, 0.2, 0.7, 2.5):
        k = gaussian_kernel(sigma)
        n = np.arange(len(k)) - (len(k) - 1) / 2
        assert k.sum() == pytest.approx(1.0, abs=1e-14) and np.allclose(k, k[::-1])
        assert k @ n**2 == pytest.approx(sigma**2, rel=1e-3)
    # a few pixels wide, it is the sampled Gaussian
    k = gaussian_kernel(3.0)
    n = np.arange(len(k)) - (len(k) - 1) / 2
    g = np.exp(-n**2 / 18.0)
    assert np.abs(k - g / g.sum()).max() < 2e-3


def test_sub_pixel_focal_spot_blurs_an_edge_and_conserves_signal(tmp_path):
    # point source 1000 mm above the object plane, detector 500 mm below it: M = 1.5; a 0.03 mm
    # focal spot gives a 0.015 mm (0.06 pixel) FWHM penumbra, sigma = 0.0255 pixel, for which
    # a sampled Gaussian kernel (scipy's gaussian_filter, truncate=4) is the identity
    kw = dict(source={**POINT, "energy": 60.0},
              bodies=[("slab", box([40, 40, 8], center=[20.0, 0, 0]), {"mu": 2.0})])
    sharp = load(tmp_path, detector=parallel_detector(shape=(32, 32), pitch=0.25), **kw)
    blurred = load(tmp_path, detector=parallel_detector(shape=(32, 32), pitch=0.25,
                                                        focal_spot=0.03), **kw)
    fwhm_px = focal_spot_blur_mm(blurred) / 0.25
    sigma_px = fwhm_px / (2 * np.sqrt(2 * np.log(2)))
    assert fwhm_px == pytest.approx(0.06)
    a, b = xray_viz.render(sharp).intensity, xray_viz.render(blurred).intensity
    # the slab's side x = 0 projects between columns 15 and 16
    step = np.abs(np.diff(a, axis=1)).max(axis=0)
    col = int(np.argmax(step))
    assert col == 15 and step[col] > 0.3
    # across a step of height d the neighbour pixels change by d * T(1) / sum(T) ~ d sigma^2 / 2
    from scipy.ndimage import gaussian_filter
    from scipy.special import ive

    assert np.array_equal(gaussian_filter(a, sigma_px, truncate=4.0), a)   # the old, no-op blur
    w1 = ive(1, sigma_px**2) / sum(ive(n, sigma_px**2) for n in range(-5, 6))
    d = a[:, col + 1] - a[:, col]
    np.testing.assert_allclose(b[:, col] - a[:, col], w1 * d, rtol=1e-3, atol=1e-12)
    assert np.abs(b - a).max() > 1e-4                                # measurable
    assert b.sum() == pytest.approx(a.sum(), rel=1e-12)             # total signal conserved


def test_focal_spot_blur_conserves_signal_at_the_border(tmp_path):
    # an edge that runs off the detector: the mirrored border keeps the sum exactly
    kw = dict(source={**POINT, "energy": 60.0},
              bodies=[("cube", box([8, 8, 8], center=[3.0, 2.0, 0]), {"mu": 2.0})])
    sharp = load(tmp_path, detector=parallel_detector(shape=(24, 20), pitch=0.5), **kw)
    blurred = load(tmp_path, detector=parallel_detector(shape=(24, 20), pitch=0.5,
                                                        focal_spot=2.0), **kw)
    a, b = xray_viz.render(sharp).intensity, xray_viz.render(blurred).intensity
    assert a[:, -1].std() > 0.1 or a[0].std() > 0.1          # the cube reaches a border
    assert np.abs(a - b).max() > 0.05
    assert b.sum() == pytest.approx(a.sum(), rel=1e-12)


def test_tube_spectrum_with_noise_renders_without_warnings(tmp_path):
    """A filtered tube spectrum's faintest bins have second-moment weights that underflow to
    0 (log -inf): the noisy render is finite, warns nothing (warnings are errors here) and
    scatters about the noiseless image."""
    import dataclasses

    scene = load(tmp_path, source={"position": [0.0, 0.0, 1000.0],
                                   "spectrum": {"kvp": 80.0, "filters": {"Al": 2.5}, "bin": 2.0}},
                 detector=parallel_detector(shape=(24, 24), pitch=4.0, I0=1000.0, noise=True,
                                            seed=3),
                 bodies=[("ball", box([40.0, 40.0, 40.0]),
                          {"material": "Bone, Cortical (ICRP)"})])
    noisy = xray_viz.render(scene).intensity
    clean = xray_viz.render(scene.replace(detector=dataclasses.replace(
        scene.detector, noise=False))).intensity
    assert np.isfinite(noisy).all() and not np.array_equal(noisy, clean)
    assert abs(noisy.mean() / clean.mean() - 1) < 0.05

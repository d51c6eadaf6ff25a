"""The image step's cheap paths (issue 18) against the plain formulas they replace: per-pixel
distances, fall-off applied in place, line integrals and ray sums without BLAS, the heel
effect's per-ray mix, the in-place detector reading."""

import dataclasses
import importlib

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.physics import imaging
from xray_viz.scene import Body, Detector, Scene, Source

render_module = importlib.import_module("xray_viz.render")

TUBE = {"kvp": 80.0, "filters": {"Al": 2.5}}


def _scene(*, shape=(37, 29), kind="point", **detector):
    det = Detector(center=[3.0, -2.0, -500.0], shape=shape, pitch=(1.7, 2.3), **detector)
    return Scene(source=Source(position=[10.0, 5.0, 1000.0], kind=kind), detector=det,
                 bodies=(Body(name="a", mesh=trimesh.creation.icosphere(radius=15.0), mu=0.3),
                         Body(name="b", mesh=trimesh.creation.box(extents=[8, 9, 10]),
                              material="Al", density=2.699)))


GEOMETRIES = {
    "plain": {},
    "offset": {"offset": (12.0, -7.0)},
    "tilted": {"u": [np.cos(0.4), 0.0, np.sin(0.4)], "v": [0.0, 1.0, 0.0]},
    "tilted+offset": {"u": [np.cos(0.3), 0.1 * np.sin(0.3), np.sin(0.3)],
                      "v": [0.0, 1.0, -0.1 * np.sin(0.3) / np.cos(0.3)], "offset": (5.0, 9.0)},
}


def _unit_v(g):
    if "v" not in g:
        return g
    u = np.asarray(g["u"], float)
    v = np.asarray(g["v"], float)
    v = v - (v @ u) / (u @ u) * u                      # exactly perpendicular (the rule)
    return dict(g, v=list(v))


@pytest.mark.parametrize("geometry", list(GEOMETRIES))
@pytest.mark.parametrize("kind", ["point", "parallel"])
def test_pixel_distances_are_the_rays_lengths(geometry, kind):
    """The separable r^2 = |m|^2 + column term + row term equals the length of every pixel's
    ray from detector_rays (the 3-vector norm), on plain, offset and tilted detectors."""
    scene = _scene(kind=kind, **_unit_v(GEOMETRIES[geometry]))
    rays = scene.acquisition.rays()
    w, h = scene.detector.shape
    r = scene.acquisition.pixel_distances
    assert r.shape == (h, w) and not r.flags.writeable
    np.testing.assert_allclose(r, rays.t_max.reshape(h, w), rtol=1e-13)
    assert scene.acquisition.pixel_distances is r          # kept by the acquisition


@pytest.mark.parametrize("geometry", list(GEOMETRIES))
def test_falloff_in_place_equals_the_factor(geometry):
    """_apply_falloff (in place, by the kept distances) multiplies by falloff_factor, whose
    plain case is cos^3 of each ray's angle to the beam axis."""
    scene = _scene(**_unit_v(GEOMETRIES[geometry]))
    image = np.random.default_rng(1).uniform(0.5, 2.0, scene.detector.shape[::-1])
    expected = image * imaging.falloff_factor(scene)
    from xray_viz.physics.detector_model import _apply_falloff

    _apply_falloff(image, scene.acquisition)
    np.testing.assert_allclose(image, expected, rtol=1e-13)
    if geometry == "plain":
        cos = scene.acquisition.rays().directions @ scene.acquisition.frame.forward
        np.testing.assert_allclose(imaging.falloff_factor(scene).ravel(), cos ** 3, rtol=1e-13)


@pytest.mark.parametrize("n_bodies", [0, 1, 2, 16])
def test_line_integrals_and_ray_sums_equal_the_plain_products(n_bodies):
    """-sum_b mu_b L_b per ray (einsum, or a product for one body) equals NumPy's matmul to
    rounding, sum_b L_b is NumPy's sum bit for bit, and each ray's value is the same whatever the number
    of rays of the call (bit for bit: a band's image does not depend on the band size)."""
    rng = np.random.default_rng(2)
    L = rng.uniform(0, 50, (3001, n_bodies)) * (rng.random((3001, n_bodies)) < 0.3)
    mu = rng.uniform(0.001, 0.1, n_bodies)
    line = imaging._line_integrals(L, mu, out=np.empty(len(L)))
    sums = render_module._row_sums(L, out=np.empty(len(L)))
    np.testing.assert_allclose(line, -(L @ mu), rtol=1e-14, atol=1e-300)
    assert np.array_equal(sums, L.sum(axis=1))          # Radiograph.path_length's sums
    if n_bodies == 1:                                   # one product: exactly -(L @ mu)
        assert np.array_equal(line, -(L @ mu)) and np.array_equal(sums, L[:, 0])
    for size in (1, 7, 1000):
        part = L[size:2 * size]
        assert np.array_equal(imaging._line_integrals(part, mu, out=np.empty(size)),
                              line[size:2 * size])
        assert np.array_equal(render_module._row_sums(part, out=np.empty(size)),
                              sums[size:2 * size])


def test_inside_finds_every_ray_with_a_path_length():
    L = np.zeros((50, 3))
    L[[3, 17, 40], [0, 2, 1]] = [1e-300, 2.0, 5.0]
    assert imaging._inside(L).tolist() == [3, 17, 40]
    L[8, 1] = -1.0                                      # a negative: not summed away
    L[8, 2] = 1.0
    assert imaging._inside(L).tolist() == [3, 8, 17, 40]
    assert imaging._inside(np.zeros((4, 0))).tolist() == []


@pytest.mark.parametrize("heel", [False, True])
def test_polychromatic_log_sums_equal_the_explicit_sum_over_bins(heel):
    """ln sum_k w_k exp(-sum_b mu_b(E_k) L_b) per ray, bodies that no ray of a chunk crosses
    left out of its product, equals the sum written out bin by bin (each pixel's own
    spectrum with the heel effect: ray_weights)."""
    scene = _scene(shape=(24, 20))
    scene = scene.replace(source=dataclasses.replace(scene.source, spectrum=TUBE, heel=heel))
    rng = np.random.default_rng(3)
    L = rng.uniform(0, 30, (24 * 20, 2)) * (rng.random((24 * 20, 2)) < 0.5)
    L[:100, 1] = 0.0                                    # whole chunks without body b
    from xray_viz.physics.beam import Beam

    beam = Beam.of(scene.source, scene.bodies, scene.detector)
    mu = imaging.body_mu(scene, beam.spectrum.energies[beam.keep]) / 10.0
    w = imaging.ray_weights(scene)
    expected = np.log((w * np.exp(-(L @ mu.T))).sum(axis=1))
    from xray_viz.physics import beam as beam_module

    old = beam_module.CHUNK_BYTES
    try:
        for chunk_rays in (7, 1000):
            beam_module.CHUNK_BYTES = 8 * len(mu) * chunk_rays
            got = imaging.log_transmission(L, scene)
            np.testing.assert_allclose(got, expected, rtol=1e-13, atol=1e-15)
    finally:
        beam_module.CHUNK_BYTES = old


@pytest.mark.parametrize("detector", [{}, {"falloff": True, "i0": 1e4, "gain": 2.5}])
def test_detect_log_overwrite_gives_the_same_reading(detector):
    """render's in-place reading (the line integral written over ln T) equals detect_log's."""
    scene = _scene(**detector)
    log_t = -np.random.default_rng(4).uniform(0, 5, scene.detector.shape[::-1])
    want_i, want_li = imaging.detect_log(log_t, scene)
    mine = log_t.copy()
    from xray_viz.render import stages

    beam, model = stages(scene)
    got_i, got_li = model.read(mine, beam=beam.at(scene.acquisition),
                               acquisition=scene.acquisition, bodies=scene.bodies,
                               seed=scene.detector.seed, overwrite=True)
    assert got_li is mine
    np.testing.assert_array_equal(got_i, want_i)
    np.testing.assert_array_equal(got_li, want_li)


def test_render_of_two_bodies_matches_beer_lambert_of_its_path_lengths():
    """The whole image step: intensity = i0 exp(-sum mu L) and the total path length from the
    per-body path lengths render returns, for one frame and for the source moved."""
    scene = _scene(shape=(64, 48))
    for dx in (0.0, 3.0):
        s = scene.replace(source=dataclasses.replace(scene.source,
                                                     position=[10.0 + dx, 5.0, 1000.0]))
        image = xray_viz.render(s, path_lengths=True)
        P = image.path_length
        mu = imaging.body_mu(s, [60.0])[0] / 10.0
        np.testing.assert_allclose(image.line_integral, P @ mu, rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(image.intensity, np.exp(-(P @ mu)), rtol=1e-13)
        assert np.array_equal(image.total_path_length, P.sum(axis=2))
        assert image.intensity.dtype == image.line_integral.dtype == np.float64


def _faulty_windows(value, n_bodies, first=3.0):
    def windows(projector, acquisition, n, keep_hits=False):
        w, h = acquisition.detector.shape
        L = np.full((w * h * n * n, n_bodies), 3.0)
        L[7, 0] = first
        L[7, n_bodies - 1] = value
        yield 0, h, L, None
    return windows


@pytest.mark.parametrize("value, first", [(np.inf, 3.0), (np.nan, 3.0), (-1.0, 3.0),
                                          (np.inf, -np.inf)])
def test_a_bad_path_length_of_any_body_is_refused(monkeypatch, value, first):
    """The finiteness check reads the rays' sums: an infinite path length in the second body
    is refused as one in the first is (also when the sum is inf - inf)."""
    from xray_viz.errors import EngineError

    monkeypatch.setattr(render_module, "_windows", _faulty_windows(value, 2, first))
    with pytest.raises(EngineError, match="internal error.*row 0"):
        xray_viz.render(_scene(shape=(16, 12)))


def test_rounding_negatives_read_as_zero_in_the_total_too(monkeypatch):
    monkeypatch.setattr(render_module, "_windows", _faulty_windows(-1e-12, 2))
    image = xray_viz.render(_scene(shape=(16, 12)), path_lengths=True)
    assert image.path_length.min() == 0.0
    np.testing.assert_array_equal(image.total_path_length, image.path_length.sum(axis=2))
    assert image.total_path_length.ravel()[7] == 3.0


@pytest.mark.parametrize("n", [4, 9, 16])
def test_pixel_log_mean_is_the_log_of_the_mean_transmission(n):
    """ln of the mean of each pixel's n transmissions: the plain formula where exp does not
    underflow, the same shifted by 2000 where it does (log-sum-exp), -inf for a pixel whose
    rays are all at -inf."""
    rng = np.random.default_rng(5)
    a = -rng.uniform(0, 8, 300 * n)
    a[::5] = 0.0
    want = np.log(np.exp(a).reshape(-1, n).mean(axis=1))
    np.testing.assert_allclose(imaging.pixel_log_mean(a, n), want, rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(imaging.pixel_log_mean(a - 2000.0, n), want - 2000.0,
                               rtol=1e-14)
    a[:n] = -np.inf
    a[n] = -np.inf                                       # one ray of the next pixel
    got = imaging.pixel_log_mean(a, n)
    assert got[0] == -np.inf and np.isfinite(got[1:]).all()
    np.testing.assert_allclose(got[1], np.log(np.exp(a[n:2 * n]).mean()), rtol=1e-14)

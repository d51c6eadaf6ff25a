"""The pipeline's stages as values (issue 37): Projector -> Beam -> DetectorModel.

Each value, built once, gives bit for bit what the scene functions gave (they are now its
adapters), and a scan builds them once for all of its projections and no scene per projection.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import SceneError
from xray_viz.geometry import Acquisition
from xray_viz.orbit import Orbit
from xray_viz.physics import imaging
from xray_viz.physics.beam import Beam
from xray_viz.physics.detector import mtf_from_dict, scintillator_from_dict
from xray_viz.physics.detector_model import DetectorModel
from xray_viz.render import image, stages
from xray_viz.scene import Scene
from xray_viz.tracing.engines import ENGINES, Projector

SPECTRUM = {"kvp": 80.0, "filters": {"Al": 2.0}}


def _small(name="frog", shape=(40, 32), **det):
    scene = xray_viz.load_scene(name)
    d = scene.detector
    pitch = (d.pitch[0] * d.shape[0] / shape[0], d.pitch[1] * d.shape[1] / shape[1])
    return scene.replace(detector=dataclasses.replace(d, shape=shape, pitch=pitch, **det))


def _full(name="frog", **det):
    """A scene with every option of the beam and the detector model on."""
    scene = _small(name, noise=True, seed=7, falloff=True, focal_spot=0.4, i0=500.0,
                   scintillator=scintillator_from_dict({"material": "CsI", "thickness": 0.5}),
                   mtf=mtf_from_dict({"sigma": 0.4}), electronic_noise=1.5, gain=2.0, **det)
    return scene.replace(source=dataclasses.replace(scene.source, spectrum=SPECTRUM,
                                                    heel=True))


@pytest.mark.parametrize("heel", [False, True])
def test_a_beam_built_once_gives_the_adapters_numbers(heel):
    scene = _full()
    if not heel:
        scene = scene.replace(source=dataclasses.replace(scene.source, heel=False))
    beam = Beam.of(scene.source, scene.bodies, scene.detector).at(scene.acquisition)
    w, h = scene.detector.shape
    L = np.random.default_rng(1).uniform(0.0, 30.0, (w * 3 * 4, len(scene.bodies)))
    L[::5] = 0.0                                                  # rays through no body
    rows = (10, 13)                                               # 3 rows, 2 x 2 rays a pixel
    got = beam.log_transmission(L, rows=rows)
    assert np.array_equal(got, imaging.log_transmission(L, scene, rows=rows))
    assert np.array_equal(beam.log_sums(L, rows=rows, variance=True)[1],
                          imaging.log_variance_transmission(L, scene, rows=rows))
    assert np.array_equal(beam.ray_weights(rows, supersample=2),
                          imaging.ray_weights(scene, rows, supersample=2))
    # a second library's number: the weighted sum over the bins, written out
    w_k = beam.ray_weights(rows, supersample=2)
    explicit = np.log((w_k * np.exp(-(L @ beam.mu.T))).sum(axis=1))
    np.testing.assert_allclose(got, explicit, rtol=1e-12, atol=1e-14)
    assert (beam.heel is not None) == heel and np.ndim(beam.levels()[0]) == (2 if heel else 0)


def test_a_beam_without_heel_is_the_same_value_at_every_pose():
    scene = _small()
    beam = Beam.of(scene.source, scene.bodies, scene.detector)
    moved = scene.acquisition.rotated(40.0, axis=[0, 1, 0], center=[0, 0, 0])
    assert beam.at(moved) is beam
    assert beam.mu.shape == (1, len(scene.bodies)) and beam.counts_photons   # one energy


@pytest.mark.parametrize("response", ["energy", "counting"])
def test_detector_model_read_with_a_seed_equals_detect_log(response):
    scene = _full(response=response)
    beam = Beam.of(scene.source, scene.bodies, scene.detector).at(scene.acquisition)
    model = DetectorModel.of(scene.detector)
    w, h = scene.detector.shape
    log_t = -np.random.default_rng(2).uniform(0.0, 3.0, (h, w))
    log_v = log_t * 1.1
    got = model.read(log_t, beam=beam, acquisition=scene.acquisition, bodies=scene.bodies,
                     seed=7, log_variance=log_v)
    want = imaging.detect_log(log_t, scene, log_variance=log_v)         # the scene's seed, 7
    for a, b in zip(got, want):
        assert np.array_equal(a, b)
    other = model.read(log_t, beam=beam, acquisition=scene.acquisition, bodies=scene.bodies,
                       seed=8, log_variance=log_v)
    assert not np.array_equal(other[0], got[0])                          # the seed is used
    # without noise or blur the reading of T = 1 is the flat field, the adapter's
    quiet = dataclasses.replace(model, noise=False, focal_spot=0.0, mtf_kernels=None)
    flat = quiet.flat_field(beam=beam, acquisition=scene.acquisition)
    assert np.array_equal(flat, dataclasses.replace(model).flat_field(beam=beam,
                                                                       acquisition=scene.acquisition))
    assert np.array_equal(flat, imaging.flat_field(scene))
    mean, li = quiet.read(np.zeros((h, w)), beam=beam, acquisition=scene.acquisition,
                          bodies=scene.bodies)
    np.testing.assert_allclose(mean, flat, rtol=1e-12)
    np.testing.assert_allclose(li, 0.0, atol=1e-12)


def test_detector_model_refuses_a_focal_spot_wider_than_the_detector():
    scene = _small(focal_spot=5000.0)
    with pytest.raises(SceneError, match=r"\[detector\] focal_spot = 5000 mm"):
        DetectorModel.of(scene.detector).blur_sigmas(scene.acquisition, scene.bodies)


@pytest.mark.parametrize("engine", sorted(ENGINES))
def test_a_projector_gives_its_engines_path_lengths(engine):
    scene = _small("nested_spheres")
    projector = Projector(scene.bodies, engine)
    L = projector.path_lengths(scene.acquisition, supersample=2)
    assert np.array_equal(L, ENGINES[engine].path_lengths(scene.bodies, scene.acquisition,
                                                          supersample=2))
    windows = list(projector.windows(scene.acquisition, supersample=2, rows=5))
    assert np.array_equal(np.concatenate([part for _, _, part in windows]), L)
    hits_L, hits = projector.hits(scene.acquisition, supersample=2)       # the NumPy engine's
    np.testing.assert_allclose(hits_L, L, atol=1e-9)
    assert len(hits.t) > 0
    assert projector.name == engine and projector.fallback != engine
    assert projector.returns_hits == (engine == "numpy") == (not projector.compiled)


def test_a_projector_refuses_an_unknown_engine():
    with pytest.raises(SceneError, match="unknown engine 'gpu'; choose one of fast, numpy"):
        Projector(xray_viz.load_scene("sphere").bodies, "gpu")


@pytest.mark.parametrize("engine", sorted(ENGINES))
def test_image_of_the_stages_is_the_render(engine):
    scene = _full("limb")
    projector = Projector(scene.bodies, engine)
    beam, model = stages(scene)
    got = image(projector, beam, model, scene.acquisition, seed=scene.detector.seed)
    r = xray_viz.render(scene, engine=engine)
    assert np.array_equal(got[0], r.intensity) and np.array_equal(got[1], r.line_integral)


def _count(monkeypatch, cls, name):
    counts = {"n": 0}
    original = getattr(cls, name).__func__ if name == "of" else getattr(cls, name)

    if name == "of":
        def wrapped(klass, *a, **k):
            counts["n"] += 1
            return original(klass, *a, **k)
        monkeypatch.setattr(cls, name, classmethod(wrapped))
    else:
        def wrapped(self, *a, **k):
            counts["n"] += 1
            return original(self, *a, **k)
        monkeypatch.setattr(cls, name, wrapped)
    return counts


@pytest.mark.parametrize("store", [False, True])
def test_a_scan_builds_its_stages_once_and_no_scene_per_projection(monkeypatch, tmp_path,
                                                                   store):
    scene = _full("frog", shape=(24, 16))
    counts = {}
    for projections in (2, 6):
        monkeypatch.undo()
        made = {"scene": _count(monkeypatch, Scene, "__post_init__"),
                "acquisition": _count(monkeypatch, Acquisition, "__post_init__"),
                "beam": _count(monkeypatch, Beam, "of"),
                "model": _count(monkeypatch, DetectorModel, "of"),
                "projector": _count(monkeypatch, Projector, "__init__")}
        orbit = Orbit(projections=projections, axis=[0, 1, 0])
        target = tmp_path / f"s{projections}.zarr" if store else None
        xray_viz.scan(scene, orbit, store=target)
        counts[projections] = {k: v["n"] for k, v in made.items()}
    monkeypatch.undo()
    few, many = counts[2], counts[6]
    assert many["scene"] == few["scene"] == 0, counts
    assert many["beam"] == few["beam"] == 1, counts
    # the memory check (once per scan) builds its own projector and detector model
    assert many["projector"] == few["projector"] <= 2, counts
    assert many["model"] == few["model"] <= 2, counts
    # per projection one acquisition for its image (the orbit's, nothing rebuilt around it);
    # the geometry export's poses are computed for the whole orbit at once
    assert many["acquisition"] - few["acquisition"] == 1 * 4, counts


def test_scan_projections_are_renders_of_the_moved_scene():
    """The loop over acquisitions gives what rendering each moved scene gives (seeds too)."""
    from xray_viz.scan import projection_seed

    scene = _full("frog", shape=(24, 16))
    orbit = Orbit(projections=3, axis=[0, 1, 0])
    stack = xray_viz.scan(scene, orbit, quantity="intensity").projections
    for k in range(3):
        acq = orbit.acquisition(scene.acquisition, k)
        det = dataclasses.replace(acq.detector, seed=projection_seed(acq.detector.seed, k))
        r = xray_viz.render(scene.replace(source=acq.source, detector=det))
        assert np.array_equal(stack[k], r.intensity.astype(np.float32))

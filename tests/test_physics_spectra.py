"""Spectra: monochromatic, SpekPy tube spectra, CSV files, and their validation in scene files."""

import time

import numpy as np
import pytest

from physics_scenes import load, parallel_detector
from xray_viz.errors import SceneError, SceneFileNotFoundError, SpectrumError
from xray_viz.physics.spectra import (Spectrum, read_spectrum_csv, source_spectrum,
                                      spectrum_from_dict, tube_spectrum)


def test_monochromatic():
    s = Spectrum.monochromatic(60.0)
    assert s.energies.tolist() == [60.0] and s.weights.tolist() == [1.0]
    assert s.swank_factor == 1.0 and s.mean_energy == 60.0


def test_weights_are_normalised_and_moments():
    s = Spectrum([20.0, 40.0], [1.0, 3.0])
    assert s.weights.tolist() == [0.25, 0.75]
    assert s.mean_energy == pytest.approx(35.0)
    assert s.swank_factor == pytest.approx(35.0**2 / (0.25 * 400 + 0.75 * 1600))


@pytest.mark.parametrize("energies, weights", [([20.0, 10.0], [1, 1]), ([0.0, 10.0], [1, 1]),
                                               ([10.0, 20.0], [1, -1]), ([10.0], [0.0])])
def test_invalid_spectra(energies, weights):
    with pytest.raises(SpectrumError):
        Spectrum(energies, weights)


def test_csv_with_header_and_comments(tmp_path):
    p = tmp_path / "spec.csv"
    p.write_text("# measured\nenergy_keV, fluence\n30, 1\n50, 2  # peak\n\n70, 1\n")
    s = read_spectrum_csv(p)
    assert s.energies.tolist() == [30.0, 50.0, 70.0]
    np.testing.assert_allclose(s.weights, [0.25, 0.5, 0.25])
    assert s.kvp == 70.0


def test_csv_errors(tmp_path):
    p = tmp_path / "bad.csv"
    p.write_text("30, 1\n20, 1\n")
    with pytest.raises(SpectrumError, match="increasing"):
        read_spectrum_csv(p)
    p.write_text("30, 1, 2\n")
    with pytest.raises(SpectrumError, match="two columns"):
        read_spectrum_csv(p)
    with pytest.raises(SceneFileNotFoundError):
        read_spectrum_csv(tmp_path / "missing.csv")


def test_tube_spectrum_spekpy_and_cache():
    s = tube_spectrum(80.0, filters={"Al": 2.5})
    assert s.energies.max() < 80.0 and s.kvp == 80.0
    assert abs(s.weights.sum() - 1) < 1e-12
    assert 35.0 < s.mean_energy < 55.0
    t = time.perf_counter()
    assert tube_spectrum(80.0, filters={"Al": 2.5}) is s          # cached
    assert time.perf_counter() - t < 0.05
    # more filtration hardens the beam
    assert tube_spectrum(80.0, filters={"Al": 6.0}).mean_energy > s.mean_energy
    with pytest.raises(SpectrumError, match="unknown filter material 'Alu'"):
        tube_spectrum(80.0, filters={"Alu": 1.0})


def test_spectrum_dict_validation():
    d = spectrum_from_dict({"kvp": 90, "filters": {"Al": 2, "Cu": 0}})
    assert d == {"kvp": 90.0, "anode_angle": 12.0, "filters": {"Al": 2.0}, "bin": 1.0,
                 "anode": "W"}
    with pytest.raises(SpectrumError, match="'kpv' \\(did you mean 'kvp'\\?\\)"):
        spectrum_from_dict({"kpv": 80})
    with pytest.raises(SpectrumError, match="filter Al"):
        spectrum_from_dict({"kvp": 80, "filters": {"Al": -1}})
    with pytest.raises(SpectrumError, match="needs 'kvp'"):
        spectrum_from_dict({"anode_angle": 10})


def test_scene_spectrum_table(tmp_path):
    (tmp_path / "spec.csv").write_text("40,1\n60,1\n")
    scene = load(tmp_path, source={"position": [0, 0, 1000], "spectrum": {"file": "spec.csv"}},
                 detector=parallel_detector())
    assert scene.source.spectrum == {"file": str((tmp_path / "spec.csv").resolve())}
    assert source_spectrum(scene.source).energies.tolist() == [40.0, 60.0]


@pytest.mark.parametrize("source, message", [
    ({"spectrum": {"kpv": 80.0}}, r"\[source\] spectrum has unknown key 'kpv'"),
    ({"spectrum": {"kvp": 80.0}, "energy": 60.0}, "both 'energy' and 'spectrum'"),
    ({"spectrum": {"kvp": 80.0, "anode": "Cu"}}, "anode"),
    ({"spectrum": 80.0}, "must be a table"),
])
def test_scene_spectrum_errors(tmp_path, source, message):
    with pytest.raises(SceneError, match=message):
        load(tmp_path, source={"position": [0, 0, 1000], **source}, detector=parallel_detector())


def test_scene_spectrum_missing_file(tmp_path):
    with pytest.raises(SceneFileNotFoundError, match="nope.csv"):
        load(tmp_path, source={"position": [0, 0, 1000], "spectrum": {"file": "nope.csv"}},
             detector=parallel_detector())

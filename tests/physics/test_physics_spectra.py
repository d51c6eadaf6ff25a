"""Spectra: monochromatic, SpekPy tube spectra, CSV files, and their validation in scene files."""

import time

import numpy as np
import pytest

from physics_scenes import box, load, parallel_detector
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


# --------------------------------------------------------------------------------------------
# CSV files: encodings, headers, malformed rows


def test_csv_not_utf8_is_a_spectrum_error(tmp_path):
    p = tmp_path / "latin1.csv"
    p.write_bytes("énergie,fluence\n30,1\n".encode("latin-1"))
    with pytest.raises(SpectrumError, match=r"latin1\.csv: not a UTF-8 text file"):
        read_spectrum_csv(p)
    p = tmp_path / "utf16.csv"
    p.write_text("30,1\n50,2\n", encoding="utf-16")
    with pytest.raises(SpectrumError, match=r"utf16\.csv: not a UTF-8"):
        read_spectrum_csv(p)


def test_csv_unreadable_is_a_spectrum_error(tmp_path, monkeypatch):
    from xray_viz.physics import spectra

    p = tmp_path / "locked.csv"
    p.write_text("30,1\n")

    def refuse(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(p))

    monkeypatch.setattr(spectra, "open", refuse, raising=False)   # also when run as root
    with pytest.raises(SpectrumError, match=r"locked\.csv: cannot read the spectrum file: "
                                            "Permission denied"):
        read_spectrum_csv(p)


def test_csv_byte_order_mark_keeps_the_first_row(tmp_path):
    p = tmp_path / "bom.csv"
    p.write_bytes(b"\xef\xbb\xbf30,1\n50,3\n")
    assert read_spectrum_csv(p).energies.tolist() == [30.0, 50.0]
    p.write_bytes(b"\xef\xbb\xbfkeV,fluence\n30,1\n50,3\n")       # a BOM before a header too
    np.testing.assert_allclose(read_spectrum_csv(p).weights, [0.25, 0.75])


@pytest.mark.parametrize("text, line, value, field", [
    ("30,abc\n50,2\n", 1, "abc", 2),                        # malformed first row, not a header
    ("keV,fluence\n30,abc\n50,2\n", 2, "abc", 2),
    ("x,30\n50,2\n", 1, "x", 1),                            # a header has no number at all
    ("keV,fluence\nunits,relative\n30,1\n", 2, "units", 1),  # at most one header line
    ("# c\n\nkeV,fluence\n# c\n30,1\nkeV,fluence\n", 6, "keV", 1),  # a header after the data
    ("30;1\n50;\n", 2, "", 2),                              # an empty field
])
def test_csv_malformed_rows_name_file_line_and_field(tmp_path, text, line, value, field):
    """The file, line and field are named; the file's text is never quoted (the file may be
    any file a scene names: issue 42)."""
    p = tmp_path / "bad.csv"
    p.write_text(text)
    with pytest.raises(SpectrumError) as info:
        read_spectrum_csv(p)
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith(str(p.resolve()))
    assert f"line {line}, field {field} of 2 is not a number" in msg
    assert not value or repr(value) not in msg


def test_csv_one_header_comments_and_separators(tmp_path):
    p = tmp_path / "ok.csv"
    p.write_text("# from a spreadsheet\nenergy (keV); fluence\n30; 1\n# mid comment\n50 2\n")
    assert read_spectrum_csv(p).energies.tolist() == [30.0, 50.0]


def test_cli_malformed_csv_is_one_line_exit_2(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    from physics_scenes import write_scene

    (tmp_path / "spec.csv").write_text("30,abc\n50,2\n")
    scene = write_scene(tmp_path, source={"position": [0, 0, 1000],
                                          "spectrum": {"file": "spec.csv"}},
                        detector=parallel_detector(),
                        bodies=[("cube", box([4, 4, 4]), {"mu": 0.2})])
    script = Path(sys.executable).parent / "xray-viz"
    cmd = [str(script)] if script.exists() else [sys.executable, "-m", "xray_viz.cli"]
    out = tmp_path / "out.npy"
    run = subprocess.run(cmd + ["render", str(scene), "-o", str(out)], capture_output=True,
                         text=True, timeout=120, cwd=tmp_path)
    assert run.returncode == 2, run.stderr
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in run.stderr
    assert lines[0].startswith(f"xray-viz: error: {scene}: [source] ")
    assert "spec.csv: line 1, field 2 of 2 is not a number" in lines[0]
    assert "abc" not in lines[0]
    assert not out.exists() and not list(tmp_path.glob("*.npy")) and not run.stdout


# --------------------------------------------------------------------------------------------
# tube spectra: parameters checked when the scene is loaded, without computing the spectrum


@pytest.mark.parametrize("spec, message", [
    ({"kvp": 800.0}, r"kvp = 800 is outside the 10-500 kV that SpekPy models for the W anode"),
    ({"kvp": 5.0}, "kvp = 5 is outside"),
    ({"kvp": 60.0, "anode": "Mo"}, "kvp = 60 is outside the 10-50 kV .* Mo anode"),
    ({"kvp": 80.0, "anode_angle": 95.0}, "anode_angle must be between 0 and 90"),
    ({"kvp": 80.0, "anode_angle": 0.0}, "anode_angle must be a number > 0"),
    ({"kvp": 80.0, "filters": {"Alu": 1.0}}, "unknown filter material 'Alu': did you mean 'Al'"),
    ({"kvp": 80.0, "filters": {"al": 1.0}}, "unknown filter material 'al': did you mean 'Al'\\?"),
    ({"kvp": 80.0, "filters": {"Cuu": 0.0}}, "did you mean 'Cu'"),   # checked even at 0 mm
])
def test_tube_parameters_validated_without_spekpy(spec, message):
    with pytest.raises(SpectrumError, match=message):
        spectrum_from_dict(spec)


def test_scene_load_names_file_and_key_and_stays_fast(tmp_path):
    import subprocess
    import sys

    from physics_scenes import write_scene

    bad = write_scene(tmp_path, source={"position": [0, 0, 1000],
                                        "spectrum": {"kvp": 80.0, "filters": {"Alu": 2.5}}},
                      detector=parallel_detector(), name="bad")
    with pytest.raises(SceneError, match=rf"^{bad}: \[source\] spectrum has an unknown filter "
                                         r"material 'Alu': did you mean 'Al'"):
        import xray_viz

        xray_viz.load_scene(bad)
    good = write_scene(tmp_path, source={"position": [0, 0, 1000],
                                         "spectrum": {"kvp": 80.0, "filters": {"Al": 2.5}}},
                       detector=parallel_detector(), name="good")
    # a fresh process: loading the scene neither imports SpekPy nor computes the spectrum
    # (what that saves in time is a benchmark's business, not a timed assertion's)
    code = ("import sys, xray_viz; "
            f"xray_viz.load_scene({str(good)!r}); "
            "print('spekpy' in sys.modules)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120, check=True)
    assert run.stdout.split() == ["False"]

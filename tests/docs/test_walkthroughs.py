"""The walkthroughs: every script runs off-screen, writes non-blank PNGs and prints right numbers.

All twelve scripts run once per session, two at a time (subprocesses with
``PYVISTA_OFF_SCREEN=true`` and ``XRAY_VIZ_OUTPUT`` in a temporary folder); the tests below then
check each one's output.
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from xray_viz.errors import XrayVizError
from xray_viz.walkthroughs import (WalkthroughNotFoundError, add_walkthrough_parser,
                                   list_walkthroughs, run_walkthrough, walkthrough_path)
from helpers import doctest_examples

#: PNGs each walkthrough must write.
EXPECTED_PNGS = {
    1: ["ray_t2", "ray_t7"],
    2: ["forward_vs_backward"],
    3: ["ho_ve_fl_lhc"],
    4: ["pixel_rays"],
    5: ["m3_positive", "m3_zero", "m3_negative"],
    6: ["moller_trumbore"],
    7: ["mu_and_intensity_along_ray", "hits_3d"],
    8: ["nested_spheres", "limb"],
    9: ["beam_hardening"],
    10: ["wrong_rays", "wrong_rays_3d"],
    11: ["repair", "error_and_time", "decimation_levels"],
    12: ["scene_3d", "tracks_3d", "four_images"],
}


@dataclass
class Run:
    returncode: int
    stdout: str
    stderr: str
    out: Path

    def number(self, pattern: str, group: int = 1) -> float:
        """The float captured by ``pattern`` in stdout (the first match)."""
        m = re.search(pattern, self.stdout)
        assert m, f"{pattern!r} not found in:\n{self.stdout}"
        return float(m.group(group))


#: Seconds a walkthrough may take (about 50 s for the slowest, 11, on a quiet 2-core machine).
WALKTHROUGH_TIMEOUT = 300


def _run(n: int, out: Path, path: Path | None = None) -> Run:
    env = dict(os.environ, PYVISTA_OFF_SCREEN="true", XRAY_VIZ_OUTPUT=str(out),
               MPLBACKEND="Agg")
    path = walkthrough_path(n) if path is None else path
    try:
        proc = subprocess.run([sys.executable, str(path)], env=env, cwd=out,
                              capture_output=True, text=True, timeout=WALKTHROUGH_TIMEOUT)
    except subprocess.TimeoutExpired as exc:
        def text(b):                      # TimeoutExpired keeps bytes, even with text=True
            return b.decode(errors="replace") if isinstance(b, bytes) else (b or "")

        return Run(-1, text(exc.stdout), f"timed out after {WALKTHROUGH_TIMEOUT} s\n"
                   f"{text(exc.stderr)}", out)
    return Run(proc.returncode, proc.stdout, proc.stderr, out)


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> dict[int, Run]:
    numbers = [n for n, _, _ in list_walkthroughs()]
    folders = {n: tmp_path_factory.mktemp(f"walkthrough{n:02d}") for n in numbers}
    # The slowest first, so that the two workers finish together.
    order = sorted(numbers, key=lambda n: n != 11)
    # paths found here, not in the threads (ast.parse from two threads at once has failed
    # under load with "AST constructor recursion depth mismatch")
    paths = {n: walkthrough_path(n) for n in numbers}
    with ThreadPoolExecutor(max_workers=2) as pool:
        results = dict(zip(order, pool.map(lambda n: _run(n, folders[n], paths[n]), order)))
    return results


def test_walkthroughs_are_listed_in_order():
    found = list_walkthroughs()
    assert [n for n, _, _ in found] == list(range(1, 13))
    assert all(title and not title.startswith("=") for _, _, title in found)
    assert set(EXPECTED_PNGS) == {n for n, _, _ in found}


@pytest.mark.parametrize("n", range(1, 13))
def test_walkthrough_runs_off_screen_and_writes_pngs(runs, n):
    run = runs[n]
    assert run.returncode == 0, f"walkthrough {n} failed:\n{run.stderr[-3000:]}"
    assert "Warning" not in run.stderr, run.stderr
    for name in EXPECTED_PNGS[n]:
        path = run.out / f"{name}.png"
        assert path.is_file(), f"walkthrough {n} did not write {path.name}"
        grey = np.asarray(Image.open(path).convert("L"), dtype=float)
        assert min(grey.shape) >= 300
        assert grey.std() > 8.0, f"{path.name} looks blank (std {grey.std():.1f})"
    assert sorted(p.stem for p in run.out.glob("*.png")) == sorted(EXPECTED_PNGS[n])


def test_01_t_is_the_distance_along_the_ray(runs):
    rows = re.findall(r"t = +([\d.]+) .*\|r\(t\) - r0\| = ([\d.]+)", runs[1].stdout)
    assert len(rows) == 4
    for t, dist in rows:
        assert float(t) == pytest.approx(float(dist), abs=1e-4)


def test_02_forward_fraction_is_the_solid_angle(runs):
    run = runs[2]
    fraction = run.number(r"\(fraction ([\d.]+);")
    omega = run.number(r"Omega/4pi = ([\d.]+)\)")
    assert fraction == pytest.approx(omega, rel=0.1)
    # Rectangle 160 x 120 mm at 450 mm: the analytic solid angle.
    a, b, d = 80.0, 60.0, 450.0
    exact = 4 * np.arcsin(a * b / np.sqrt((a * a + d * d) * (b * b + d * d))) / (4 * np.pi)
    assert omega == pytest.approx(exact, abs=1e-4)
    assert "63 rays" in run.stdout


def test_03_eq_1_2_and_orthogonality(runs):
    run = runs[3]
    assert "(= LHC: True)" in run.stdout
    assert "LHC = [80. 60. 20.]" in run.stdout
    assert "HO.VE = 0.0, HO.FL = 0.0, VE.FL = 0.0" in run.stdout


def test_04_printed_eq_1_5_fails_away_from_the_origin(runs):
    out = runs[4].stdout
    blocks = out.split("camera ")[1:]
    assert len(blocks) == 3
    origin, away, axis = blocks
    for block in blocks:
        assert "detector_rays: max difference 0.0e+00" in block
    assert "max angle to the correct ray 0.0 deg, 0 of 20 rays" in origin
    assert "max miss distance 0.0 mm" in origin
    assert "20 of 20 rays never reach the detector, so there is no miss distance" in away
    assert "miss distance -" not in out
    miss = float(re.search(r"max miss distance ([\d.]+) mm", axis).group(1))
    # The printed form aims at the pixel positions seen from the origin: 3x magnified, so the
    # corner pixel (80, 60) lands at (240, 180), 200 mm away.
    assert miss == pytest.approx(200.0, abs=0.1)


def test_05_barycentric_rows(runs):
    rows = re.findall(r"\|\s*([-\d.]+)\s+([-\d.]+)\s+([-\d.]+)\s+([\d.]+) \|.*\| (True|False)",
                      runs[5].stdout)
    assert len(rows) == 5
    for a, b, g, s, inside in rows:
        assert float(s) == pytest.approx(1.0)
        assert float(a) + float(b) + float(g) == pytest.approx(1.0, abs=2e-3)
        assert (inside == "True") == (min(float(a), float(b), float(g)) >= 0)
    assert [r[-1] for r in rows] == ["True", "True", "True", "True", "False"]


def test_06_moller_trumbore_t_is_analytic(runs):
    run = runs[6]
    v0, v1, v2 = np.array([-2.0, -1, 6]), np.array([3.0, -1, 4]), np.array([0.0, 4, 5])
    r0 = np.array([0.5, 0.5, 0.0])
    d = np.array([0.1, 0.05, 1.0])
    d /= np.linalg.norm(d)
    n = np.cross(v1 - v0, v2 - v0)
    t_exact = n @ (v0 - r0) / (n @ d)
    assert run.number(r"t = e2 \. q / C = ([\d.]+)") == pytest.approx(t_exact, abs=1e-6)
    assert run.number(r"t from the plane equation = ([\d.]+)") == pytest.approx(t_exact, abs=1e-6)
    C = run.number(r"C = e1 \. p = ([-\d.]+)")
    assert C == pytest.approx((v1 - v0) @ np.cross(d, v2 - v0), abs=1e-5)
    assert run.number(r"Listing 1 \(\* C\): .* t = ([\d.]+)") == pytest.approx(
        t_exact * C * C, rel=1e-5)
    assert "Listing 1 (* C): hit False" in run.stdout
    assert "xray_viz moller_trumbore: hit True" in run.stdout
    assert "unit triangle: C = 1.0; correct t = 2.000, Listing 1 t = 2.000" in run.stdout


def test_07_path_lengths_and_beer_lambert(runs):
    run = runs[7]
    tissue_chord = run.number(r"tissue: chord \(sum of \+-t\) = ([\d.]+)")
    tissue_ideal = run.number(r"tissue: .*ideal sphere ([\d.]+)")
    bone_chord = run.number(r"bone: chord \(sum of \+-t\) = ([\d.]+)")
    bone_ideal = run.number(r"bone: .*ideal sphere ([\d.]+)")
    tissue_L = run.number(r"tissue: .*effective path length L = ([\d.]+)")
    bone_L = run.number(r"bone: .*effective path length L = ([\d.]+)")
    # An icosphere is inscribed in its sphere: chords are a little shorter, never longer.
    assert 0 <= tissue_ideal - tissue_chord < 0.2
    assert 0 <= bone_ideal - bone_chord < 0.2
    assert bone_L == pytest.approx(bone_chord, abs=1e-9)
    assert tissue_L == pytest.approx(tissue_chord - bone_chord, abs=1e-3)
    li = run.number(r"line integral = sum mu L = ([\d.]+)")
    assert li == pytest.approx((0.2 * tissue_L + 0.5 * bone_L) / 10, abs=1e-4)
    ratio = run.number(r"I/I0 = exp\(-line integral\) = ([\d.]+)")
    assert ratio == pytest.approx(np.exp(-li), abs=1e-5)
    assert run.number(r"transmission: ([\d.]+)") == pytest.approx(ratio, abs=1e-5)


def test_08_centre_ray_matches_pencil_and_paper(runs):
    run = runs[8]
    traced = run.number(r"line integral: traced ([\d.]+)")
    analytic = run.number(r"analytic ([\d.]+)")
    assert traced == pytest.approx(analytic, rel=1e-3)
    mu_water = run.number(r"water: .*mu\(60 keV\) = ([\d.]+)")
    assert mu_water == pytest.approx(0.2059, abs=5e-4)          # NIST XCOM, 60 keV
    assert run.number(r"max path length in bone ([\d.]+) mm") > 0


def test_09_beam_hardening(runs):
    run = runs[9]
    by_hand = run.number(r"by hand ([\d.]+)")
    assert run.number(r"xray_viz ([\d.]+)") == pytest.approx(by_hand, rel=1e-9)
    mu_eff = [float(x) for x in re.findall(r"^\s+\d+\s+[\d.]+\s+([\d.]+)\s+[\d.]+$",
                                             run.stdout, flags=re.M)]
    assert len(mu_eff) == 5 and all(np.diff(mu_eff) < 0)
    per_mm = run.number(r"60 keV: line integral / mm of Al = ([\d.]+)")
    assert per_mm == pytest.approx(run.number(r"mu\(60 keV\) = ([\d.]+) /mm"), rel=1e-3)
    thin = run.number(r"slope ([\d.]+) /mm below")
    thick = run.number(r"mm of Al, ([\d.]+) /mm above")
    assert thick < 0.9 * thin


def test_10_textbook_double_counts_and_watertight_does_not(runs):
    out = runs[10].stdout
    counts = dict(((beam, test), int(n)) for beam, test, n in re.findall(
        r"(parallel|point source) beam, +(textbook|watertight) test: (\d+) of", out))
    assert len(counts) == 4
    assert counts["parallel", "textbook"] > 0
    assert counts["point source", "textbook"] > 0
    assert counts["parallel", "watertight"] == 0
    assert counts["point source", "watertight"] == 0
    assert "centre ray,   textbook: 4 hits, L = 80.0 mm (exact 40.0 mm)" in out
    assert "centre ray, watertight: 2 hits, L = 40.0 mm (exact 40.0 mm)" in out
    # every wrong ray goes through a shared edge (crossing or grazing the cube) ...
    edges = re.findall(r"(parallel|point source) beam: (\d+) wrong rays, (\d+) of them through "
                       r"a shared edge \((\d+) crossing the cube, (\d+) grazing it\)", out)
    assert len(edges) == 2
    for beam, wrong, on_edge, crossing, grazing in edges:
        assert int(wrong) == counts[beam, "textbook"] == int(on_edge)
        assert int(crossing) + int(grazing) == int(on_edge)
    # ... but not every ray through one goes wrong: rounding takes some off their edge
    saved = re.findall(r"of the (\d+) rays that cross the cube through a shared edge, (\d+) "
                       r"come out right, e.g. the ray to the pixel at \(([-\d.e]+), ([-\d.e]+)\)",
                       out)
    assert len(saved) == 2
    for (_, _, _, crossing, _), (total, right, _, _) in zip(edges, saved):
        assert 0 < int(right) < int(total) and int(total) - int(right) == int(crossing)
    total, right, x, y = saved[0]                   # the parallel beam's: a diagonal pixel,
    assert abs(float(x)) != abs(float(y))           # a rounding error off its diagonal
    assert abs(float(x)) == pytest.approx(abs(float(y)), abs=1e-12)
    # a strict edge test rounds the ties the other way: other counts, still not zero
    strict = dict(re.findall(r"(parallel|point source) beam, strict edges: (\d+) of \d+ rays "
                             r"wrong \(inclusive: \d+\)", out))
    assert len(strict) == 2
    for beam, n in strict.items():
        assert 0 < int(n) != counts[beam, "textbook"]


def test_walkthrough_without_a_display_says_use_off_screen(tmp_path):
    env = {k: v for k, v in os.environ.items()
           if k not in ("DISPLAY", "WAYLAND_DISPLAY", "PYVISTA_OFF_SCREEN")}
    env["XRAY_VIZ_OUTPUT"] = str(tmp_path / "pngs")
    exe = Path(sys.executable).with_name("xray-viz")
    proc = subprocess.run([str(exe), "walkthrough", "1"], env=env, cwd=tmp_path,
                          capture_output=True, text=True, timeout=WALKTHROUGH_TIMEOUT)
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip()
    assert err.count("\n") == 0 and "no display" in err and "--off-screen" in err, err
    assert "\x1b" not in proc.stderr and "WARN" not in proc.stderr and proc.stdout == ""
    assert not (tmp_path / "pngs").exists()


def test_11_repair_and_decimation(runs):
    run = runs[11]
    assert run.number(r"broken mesh: (\d+) of") > 0
    assert run.number(r"broken mesh: .*worst by (\d+) mm") > 100
    assert run.number(r"repaired in [\d.]+ s: (\d+) rays") == 0
    rows = re.findall(r"^\s*(\d+)\s+([\d.]+)\s+([\d.]+) / ([\d.]+)\s+(\d+) / (\d+)$",
                      run.stdout, flags=re.M)
    assert [int(r[0]) for r in rows] == [81920, 5120, 1280, 320]
    hausdorff = [float(r[1]) for r in rows]
    rms = [float(r[3]) for r in rows]
    assert hausdorff[0] == 0 and all(np.diff(hausdorff) > 0)
    assert all(np.diff(rms) > 0)


# --------------------------------------------------------------------------------------------
# The helpers and the command


def test_12_energy_balance_dose_and_four_images(runs):
    run = runs[12]
    emitted = run.number(r"mean energy emitted ([\d.]+) eV")
    parts = [run.number(rf"{what} +([\d.]+) eV/history")
             for what in ("deposited in the bodies", "absorbed in the air", "escaped",
                          "reached the detector")]
    assert sum(parts) == pytest.approx(emitted, abs=1.0)        # the balance, as printed
    assert abs(run.number(r"emitted - all the others = ([-\d.e+]+) eV")) < 1e-6 * emitted
    # 80 kVp with 2.5 mm Al: the mean energy emitted lies between 35 and 50 keV
    assert 35_000 < emitted < 50_000
    water = re.search(r"water +([\d.]+) +([\d.]+) +([\d.]+)", run.stdout)
    bone = re.search(r"bone +([\d.]+) +([\d.]+) +([\d.]+)", run.stdout)
    assert water and bone
    # the bodies' energies add up to the deposited total (to the printed rounding)
    assert float(water[1]) + float(bone[1]) == pytest.approx(parts[0], abs=0.1)
    assert float(bone[3]) > float(water[3]) > 0                 # dose: bone in the beam
    images = dict(re.findall(r"(primary|incoherent|coherent|multiple) ([\d.]+)", run.stdout))
    assert set(images) == {"primary", "incoherent", "coherent", "multiple"}
    total = sum(float(v) for v in images.values())
    assert total == pytest.approx(parts[3], rel=2e-3)           # the images hold the detector's
    spr = run.number(r"scatter-to-primary ratio on this detector: ([\d.]+)")
    assert 0.05 < spr < 1.0
    # the 300 tracks drawn: every way a photon ends, adding up to 300
    tracks = dict(re.findall(r"(primary|scattered|escaped|absorbed) (\d+)",
                             run.stdout.split("tracks: ")[1].splitlines()[0]))
    assert set(tracks) == {"primary", "scattered", "escaped", "absorbed"}
    assert sum(int(v) for v in tracks.values()) == 300


def test_unknown_walkthrough_is_a_one_line_error():
    with pytest.raises(WalkthroughNotFoundError) as info:
        walkthrough_path(99)
    assert isinstance(info.value, XrayVizError) and isinstance(info.value, LookupError)
    message = str(info.value)
    assert "\n" not in message
    assert "99" in message and "1, 2, 3" in message and "11" in message


def _parser():
    parser = argparse.ArgumentParser(prog="xray-viz")
    add_walkthrough_parser(parser.add_subparsers(dest="command"))
    return parser


def test_walkthrough_command_lists(capsys):
    args = _parser().parse_args(["walkthrough", "--list"])
    assert args.func(args) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 12
    assert lines[0].split()[:2] == ["1", "01_parametric_ray"]
    assert "Moller-Trumbore" in lines[5]


def test_walkthrough_command_unknown_number():
    args = _parser().parse_args(["walkthrough", "42"])
    with pytest.raises(WalkthroughNotFoundError, match="no walkthrough 42; choose one of 1, "):
        args.func(args)
    args = _parser().parse_args(["walkthrough"])
    with pytest.raises(WalkthroughNotFoundError, match="--list"):
        args.func(args)


def test_run_walkthrough_in_process(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("XRAY_VIZ_OUTPUT", str(tmp_path))
    monkeypatch.delenv("PYVISTA_OFF_SCREEN", raising=False)
    namespace = run_walkthrough(6, off_screen=True)
    assert namespace["t"] == pytest.approx(namespace["t_plane"])
    assert (tmp_path / "moller_trumbore.png").is_file()
    assert "PYVISTA_OFF_SCREEN" not in os.environ          # restored after the run
    assert "C = e1 . p" in capsys.readouterr().out


def test_docstring_examples():
    import xray_viz.walkthroughs

    assert doctest_examples(xray_viz.walkthroughs) > 0     # pytest runs them, once

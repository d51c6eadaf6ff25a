"""The command line behaves like its neighbours (issue 17): progress bars on a terminal only,
-v/-q through logging, scene overrides checked like the file, ``python -m xray_viz``, a
version report for bug reports, and an sdist that carries what its tests import.

The console script runs in subprocesses (a pseudo-terminal where the terminal matters); the
per-option comparisons also run in-process through :func:`xray_viz.cli.main`, the function
the console script calls, to keep the default suite quick.
"""

from __future__ import annotations

import ast
import copy
import json
import logging
import os
import re
import subprocess
import sys
import tarfile
import tomllib
import warnings
from importlib.metadata import version
from pathlib import Path

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz import cli, progress
from helpers import REPO, doctest_examples, run_on_a_terminal

ROOT = REPO
SCRIPT = Path(sys.executable).parent / "xray-viz"

#: A bone ball (a material: the image depends on the energy), noise-ready (I0 given).
BASE = {
    "source": {"position": [0.0, 0.0, 1000.0], "kind": "point", "energy": 60.0},
    "detector": {"center": [0.0, 0.0, -500.0], "up": [0.0, 1.0, 0.0], "shape": [32, 24],
                 "pitch": 2.0, "I0": 1000.0},
    "body": [{"name": "ball", "mesh": "ball.stl", "material": "Bone, Cortical (ICRP)"}],
}


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(v)


def to_toml(doc: dict) -> str:
    """A scene document as TOML text (tables of scalars, arrays and inline tables)."""
    lines = []
    for table in ("source", "detector"):
        lines.append(f"[{table}]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in doc[table].items()]
        lines.append("")
    for body in doc["body"]:
        lines.append("[[body]]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in body.items()]
        lines.append("")
    return "\n".join(lines)


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """``write(doc, name) -> path``: scene files beside one ball mesh."""
    folder = tmp_path_factory.mktemp("scenes")
    trimesh.creation.icosphere(subdivisions=2, radius=20.0).export(folder / "ball.stl")

    def write(doc, name):
        path = folder / f"{name}.toml"
        path.write_text(to_toml(doc))
        assert tomllib.loads(path.read_text()) == doc          # the writer round-trips
        return path

    return write


def _render(args, out, capsys):
    assert cli.main(["render", *map(str, args), "-o", str(out)]) == 0, capsys.readouterr().err
    capsys.readouterr()
    return np.load(out)


def _tube(doc, kvp=100.0):
    doc = copy.deepcopy(doc)
    del doc["source"]["energy"]
    doc["source"]["spectrum"] = {"kvp": kvp, "filters": {"Al": 2.5}, "bin": 2.0}
    return doc


def _noisy(doc, seed=1):
    doc = copy.deepcopy(doc)
    doc["detector"].update(noise=True, seed=seed)
    return doc


def _edit(doc, table, **changes):
    doc = copy.deepcopy(doc)
    for key, value in changes.items():
        if value is None:
            doc[table].pop(key, None)
        else:
            doc[table][key] = value
    return doc


# (base document, override options, the same change written in the file)
CASES = {
    "energy": (BASE, ["--energy", "40"], _edit(BASE, "source", energy=40.0)),
    "energy-over-spectrum": (_tube(BASE), ["--energy", "40"],
                             _edit(_tube(BASE), "source", spectrum=None, energy=40.0)),
    "kvp": (_tube(BASE), ["--kvp", "70"],
            _edit(_tube(BASE), "source", spectrum={"kvp": 70.0, "filters": {"Al": 2.5},
                                                   "bin": 2.0})),
    "seed": (_noisy(BASE), ["--seed", "7"], _noisy(BASE, seed=7)),
    "noise": (BASE, ["--noise", "--seed", "3"], _noisy(BASE, seed=3)),
    "no-noise": (_noisy(BASE), ["--no-noise"], _edit(_noisy(BASE), "detector", noise=False)),
    "shape": (BASE, ["--shape", "40", "30"], _edit(BASE, "detector", shape=[40, 30])),
    "pitch": (BASE, ["--pitch", "1.5"], _edit(BASE, "detector", pitch=1.5)),
    "pitch-pair": (BASE, ["--pitch", "1.5", "1.25"],
                   _edit(BASE, "detector", pitch=[1.5, 1.25])),
    "detector-size": (BASE, ["--detector-size", "60", "40"],
                      _edit(BASE, "detector", pitch=None, size=[60.0, 40.0])),
    # the source moved along the beam axis to 1200 mm from the detector centre (-500 on z)
    "source-distance": (BASE, ["--source-distance", "1200"],
                        _edit(BASE, "source", position=[0.0, 0.0, 700.0])),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_an_override_renders_what_the_edited_file_renders(case, scenes, tmp_path, capsys):
    base, options, edited = CASES[case]
    base_path, edited_path = scenes(base, f"base-{case}"), scenes(edited, f"edited-{case}")
    overridden = _render([base_path, *options], tmp_path / "o.npy", capsys)
    from_file = _render([edited_path], tmp_path / "f.npy", capsys)
    unchanged = _render([base_path], tmp_path / "b.npy", capsys)
    assert overridden.dtype == from_file.dtype == np.float64
    assert overridden.shape == from_file.shape
    assert overridden.tobytes() == from_file.tobytes()          # the same image, bit for bit
    assert unchanged.shape != overridden.shape or not np.array_equal(unchanged, overridden)


def test_source_distance_keeps_the_beam_axis_of_an_oblique_source(scenes, tmp_path, capsys):
    doc = _edit(BASE, "source", position=[300.0, -200.0, 900.0])
    p, c = np.array([300.0, -200.0, 900.0]), np.array([0.0, 0.0, -500.0])
    moved = c + 800.0 * (p - c) / np.linalg.norm(p - c)
    assert np.isclose(np.linalg.norm(moved - c), 800.0)
    a = _render([scenes(doc, "oblique"), "--source-distance", "800"], tmp_path / "a.npy", capsys)
    b = _render([scenes(_edit(doc, "source", position=moved.tolist()), "oblique-moved")],
                tmp_path / "b.npy", capsys)
    assert a.tobytes() == b.tobytes()


def test_angle_turns_the_acquisition_about_the_bodies(scenes, tmp_path, capsys):
    """--angle renders what the turned acquisition renders, and equals the bodies turned the
    other way about the same axis (to rounding: two different computations)."""
    import trimesh as tm

    path = scenes(BASE, "angle")
    turned = _render([path, "--angle", "35"], tmp_path / "a.npy", capsys)
    scene = xray_viz.load_scene(path)
    expected = xray_viz.render(cli.turn_acquisition(scene, 35.0)).intensity
    assert turned.tobytes() == expected.tobytes()
    box = scene.bodies.bounds
    centre = (box[:, 0].min(axis=0) + box[:, 1].max(axis=0)) / 2
    m = tm.transformations.rotation_matrix(np.radians(-35.0), scene.detector.up, centre)
    bodies_turned = xray_viz.render(scene.transform_bodies(m)).intensity
    np.testing.assert_allclose(turned, bodies_turned, rtol=0, atol=1e-6)
    assert not np.array_equal(turned, _render([path], tmp_path / "b.npy", capsys))
    assert cli.main(["render", str(path), "-o", str(tmp_path / "c.npy"), "--angle", "nan"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--angle nan" in err[0] and not (tmp_path / "c.npy").exists()


def test_overrides_together_through_the_console_script(scenes, tmp_path):
    base = scenes(BASE, "together")
    edited = _edit(BASE, "source", energy=45.0, position=[0.0, 0.0, 400.0])
    edited["detector"].update(shape=[36, 20], noise=True, seed=5)
    out = tmp_path / "o.npy"
    r = subprocess.run([str(SCRIPT), "render", str(base), "-o", str(out), "--energy", "45",
                        "--shape", "36", "20", "--noise", "--seed", "5",
                        "--source-distance", "900"], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert "wrote" in r.stdout and "36x20" in r.stdout
    expected = xray_viz.render(xray_viz.load_scene(scenes(edited, "together-edited"))).intensity
    assert np.load(out).tobytes() == expected.tobytes()


BAD = [
    (["--energy", "-5"], "--energy -5", "energy must be > 0"),
    (["--energy", "nan"], "--energy nan", "finite"),
    (["--energy", "900"], "--energy 900", "outside"),             # beyond xraylib's tables
    (["--kvp", "5"], "--kvp 5", "kvp"),
    (["--seed", "-1"], "--seed -1", "seed"),
    (["--shape", "0", "10"], "--shape 0 10", "shape"),
    (["--pitch", "1", "2", "3"], "--pitch 1 2 3", "one number"),
    (["--pitch", "-1"], "--pitch -1", "pitch"),
    (["--detector-size", "0", "10"], "--detector-size 0 10", "size"),
    (["--source-distance", "-1"], "--source-distance -1", "> 0"),
    (["--source-distance", "500"], "--source-distance 500", "inside"),  # into the ball
    (["--energy", "abc"], "--energy", "invalid float"),
    (["--pitch", "1", "--detector-size", "3", "4"], "--detector-size", "not allowed"),
    (["--energy", "50", "--kvp", "80"], "--kvp", "not allowed"),
]


@pytest.mark.parametrize("options, named, says", BAD, ids=[b[1] for b in BAD])
def test_a_bad_override_is_one_line_naming_the_option(options, named, says, scenes, tmp_path,
                                                      capsys):
    out = tmp_path / "x.npy"
    try:
        rc = cli.main(["render", str(scenes(BASE, "bad")), "-o", str(out), *options])
    except SystemExit as exc:             # argparse's usage errors
        rc = exc.code
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "Traceback" not in err, err
    assert err.startswith("xray-viz") and "error:" in err and named in err and says in err, err
    assert not out.exists()


def test_noise_without_photons_is_refused_as_in_the_file(scenes, tmp_path, capsys):
    doc = _edit(BASE, "detector", I0=None)
    rc = cli.main(["render", str(scenes(doc, "no-i0")), "-o", str(tmp_path / "x.npy"),
                   "--noise"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err
    assert err.startswith("xray-viz: error: --noise: ") and "without 'I0'" in err


def test_the_files_own_error_is_not_blamed_on_an_override(scenes, tmp_path, capsys):
    path = scenes(_edit(BASE, "source", energy=-1.0), "broken")
    rc = cli.main(["render", str(path), "-o", str(tmp_path / "x.npy"), "--seed", "3"])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "--seed" not in err
    assert err.startswith(f"xray-viz: error: {path}: [source] energy must be > 0"), err


def test_a_bad_override_through_the_console_script(scenes, tmp_path):
    out = tmp_path / "x.npy"
    r = subprocess.run([str(SCRIPT), "render", str(scenes(BASE, "bad-script")), "-o", str(out),
                        "--energy", "-5"], capture_output=True, text=True, timeout=300)
    assert r.returncode == 2 and r.stdout == "" and not out.exists()
    assert len(r.stderr.splitlines()) == 1 and "--energy -5" in r.stderr, r.stderr


def test_show_takes_the_overrides_and_keeps_its_window_size(scenes):
    parser = cli.build_parser()
    args = parser.parse_args(["show", str(scenes(BASE, "show")), "--size", "800", "400",
                              "--detector-size", "60", "40", "--shape", "40", "30",
                              "--energy", "45"])
    assert args.size == [800, 400] and args.detector_size == [60.0, 40.0]
    scene = cli.load_scene_with_overrides(args)
    assert scene.detector.shape == (40, 30) and scene.source.energy == 45.0
    assert np.allclose(scene.detector.size, (60.0, 40.0))


@pytest.mark.parametrize("argv", [
    ["render", "default", "-o", "x.png"],
    ["-vv", "render", "-o", "x.png", "default", "--shape", "3", "4", "--pitch", "1", "2",
     "--no-noise", "-q", "--engine", "numpy"],
    ["-q", "render", "x.toml", "-o", "y.tiff", "--quantity", "line-integral", "--bogus"],
])
def test_the_render_sub_parser_alone_parses_as_the_whole_parser(argv):
    """``xray-viz render`` builds its own sub-parser only (the other commands' modules are not
    imported): the same arguments, the same leftovers."""
    assert cli._only_command(argv) == "render"
    whole, alone = cli.build_parser().parse_known_args(argv), \
        cli.build_parser(only="render").parse_known_args(argv)
    assert vars(whole[0]) == vars(alone[0]) and whole[1] == alone[1]


@pytest.mark.parametrize("argv", [["-h", "render"], ["--version", "render"], ["show", "x"],
                                  ["mesh", "render"], [], ["-vq", "render"]])
def test_anything_else_gets_the_whole_parser(argv):
    assert cli._only_command(argv) is None


def test_render_errors_and_help_are_the_whole_parser_s(capsys):
    for argv in (["render", "--help"], ["render"], ["render", "x", "-o", "y", "--shape", "1"],
                 ["render", "x", "-o", "y", "--engine", "bogus"]):
        said = []
        for only in (None, "render"):
            with pytest.raises(SystemExit) as exc:
                cli.build_parser(only=only).parse_known_args(argv)
            said.append((exc.value.code, capsys.readouterr()))
        assert said[0] == said[1], argv


# -- progress ------------------------------------------------------------------------------


NOW = {"XRAY_VIZ_PROGRESS_DELAY": "0"}       # draw bars at once, however quick the job


def test_a_render_shows_its_bands_on_a_terminal(tmp_path):
    out = tmp_path / "s.npy"
    status, text = run_on_a_terminal([str(SCRIPT), "render", "sphere", "-o", str(out),
                                      "--engine", "numpy"], env=NOW)
    assert status == 0, text
    from xray_viz.render import _band_rows
    from xray_viz.tracing.engines import Projector

    scene = xray_viz.load_scene("sphere")
    h, step = scene.detector.shape[1], _band_rows(Projector(scene.bodies, "numpy"),
                                                  scene.acquisition, 1)
    assert step < h                                              # several bands
    counts = {int(n) for n in re.findall(rf"rendering:.*?(\d+)/{h} ", text)}
    assert 0 in counts and counts - {0}, text                   # it moved
    assert all(n % step == 0 or n == h for n in counts), (counts, step)
    assert f"wrote {out}" in text and np.load(out).shape == (256, 256)


def test_no_progress_when_piped_or_quiet(tmp_path):
    out = tmp_path / "s.npy"
    r = subprocess.run([str(SCRIPT), "render", "sphere", "-o", str(out), "--engine", "numpy"],
                       capture_output=True, text=True, timeout=300, env={**os.environ, **NOW})
    assert r.returncode == 0 and "rendering" not in r.stderr and "\r" not in r.stderr
    for quiet in (["-q"], ["--quiet"]):
        status, text = run_on_a_terminal([str(SCRIPT), *quiet, "render", "sphere", "-o",
                                          str(out), "--engine", "numpy"], env=NOW)
        assert status == 0 and "rendering" not in text and f"wrote {out}" not in text, text
    status, text = run_on_a_terminal([str(SCRIPT), "render", "sphere", "-o", str(out),
                                      "--engine", "numpy", "-q"], env=NOW)   # after the command
    assert status == 0 and "rendering" not in text, text


def test_mesh_repair_and_a_walkthrough_show_progress_on_a_terminal(tmp_path):
    holed = trimesh.creation.icosphere(subdivisions=3, radius=20.0)
    holed.update_faces(np.arange(len(holed.faces)) != 0)
    holed.export(tmp_path / "holed.stl")
    status, text = run_on_a_terminal([str(SCRIPT), "mesh", str(tmp_path / "holed.stl"), "-o",
                                      str(tmp_path / "fixed.stl")], env=NOW)
    assert status == 0, text
    assert "repairing the mesh" in text and trimesh.load(tmp_path / "fixed.stl").is_watertight

    env = {**NOW, "XRAY_VIZ_OUTPUT": str(tmp_path / "w1")}
    status, text = run_on_a_terminal([str(SCRIPT), "walkthrough", "1", "--off-screen"], env=env)
    assert status == 0, text
    written = sorted((tmp_path / "w1").glob("*.png"))
    assert written and "walkthrough 1:" in text
    assert max(int(n) for n in re.findall(r"walkthrough 1: (\d+) figures", text)) >= 1
    assert all(f"wrote {p}" in text for p in written)


def test_progress_is_silent_unless_the_command_line_turns_it_on(capsys):
    assert not progress.is_enabled()
    with progress.task("quiet", total=2) as t:
        progress.rows(1, 2)
        progress.advance()
        progress.status("compiling")
    assert t.n == 2 and t.total == 2
    assert capsys.readouterr() == ("", "")


# -- messages -------------------------------------------------------------------------------


def _debug(stderr):
    return [line for line in stderr.splitlines() if line.startswith("xray-viz: debug:")]


def test_verbose_shows_debug_lines_and_the_default_does_not(tmp_path):
    out = tmp_path / "s.npy"
    quiet = subprocess.run([str(SCRIPT), "render", "sphere", "-o", str(out)],
                           capture_output=True, text=True, timeout=300)
    loud = subprocess.run([str(SCRIPT), "render", "sphere", "-o", str(out), "-v"],
                          capture_output=True, text=True, timeout=300)
    first = subprocess.run([str(SCRIPT), "--verbose", "render", "sphere", "-o", str(out)],
                           capture_output=True, text=True, timeout=300)
    assert quiet.returncode == loud.returncode == first.returncode == 0
    assert _debug(quiet.stderr) == []
    for r in (loud, first):
        lines = _debug(r.stderr)
        assert any("scene" in line and "sphere.toml" in line for line in lines), r.stderr
        assert any("timing" in line for line in lines), r.stderr


def _flipped_ball_scene(folder):
    good = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    trimesh.Trimesh(good.vertices, good.faces[:, ::-1], process=False).export(folder / "ball.stl")
    doc = _edit(BASE, "detector", I0=None)
    path = folder / "flipped.toml"
    path.write_text(to_toml(doc))
    return path


def test_warnings_are_one_line_and_only_minus_qq_hides_them(tmp_path):
    path = _flipped_ball_scene(tmp_path)
    out = tmp_path / "a.npy"
    seen = {}
    for flags in ([], ["-q"], ["-qq"]):
        r = subprocess.run([str(SCRIPT), *flags, "render", str(path), "-o", str(out)],
                           capture_output=True, text=True, timeout=300)
        assert r.returncode == 0, r.stderr
        seen[" ".join(flags)] = [l for l in r.stderr.splitlines() if "repaired" in l]
    assert len(seen[""]) == 1 and seen[""][0].startswith("xray-viz: warning: ")
    assert seen["-q"] == seen[""] and seen["-qq"] == []


def test_the_api_still_warns_and_main_restores_the_warning_machinery(tmp_path, capsys):
    from xray_viz.meshes.repair import MeshRepairWarning

    path = _flipped_ball_scene(tmp_path)
    shown, logger = warnings.showwarning, logging.getLogger("xray_viz")
    handlers, level = list(logger.handlers), logger.level
    assert cli.main(["phantoms"]) == 0
    capsys.readouterr()
    assert warnings.showwarning is shown and logger.handlers == handlers
    assert logger.level == level
    with pytest.warns(MeshRepairWarning, match="repaired"):
        xray_viz.load_scene(path)


def test_messages_print_one_line_each_on_stderr(capsys):
    with progress.setup_logging(logging.DEBUG):
        warnings.simplefilter("always")     # (the suite turns warnings into errors)
        logging.getLogger("xray_viz.test").info("two\nlines")
        logging.getLogger("xray_viz.test").debug("detail")
        warnings.warn("careful", UserWarning)
    err = capsys.readouterr().err.splitlines()
    assert err == ["xray-viz: two lines", "xray-viz: debug: xray_viz.test: detail",
                   "xray-viz: warning: careful"]


# -- python -m, versions ---------------------------------------------------------------------


def test_python_minus_m_xray_viz():
    r = subprocess.run([sys.executable, "-m", "xray_viz", "--help"], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.startswith("usage: xray-viz")
    assert "render" in r.stdout and "--verbose" in r.stdout and "--quiet" in r.stdout
    r = subprocess.run([sys.executable, "-m", "xray_viz", "--version"], capture_output=True,
                       text=True, timeout=300)
    assert r.returncode == 0 and r.stdout.strip() == f"xray-viz {version('xray_viz')}"


#: Distribution name -> the name the report gives it.
REPORTED = {"numba": "numba", "vtk": "vtk", "pyvista": "pyvista", "pymeshlab": "pymeshlab",
            "xraylib": "xraylib", "spekpy": "spekpy", "numpy": "numpy", "xray_viz": "xray_viz"}


@pytest.mark.parametrize("argv", [["--version", "--verbose"], ["report"]])
def test_the_version_report_lists_the_packages_and_the_render_window(argv):
    r = subprocess.run([str(SCRIPT), *argv], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    table = dict(re.findall(r"^\s*(\S[^:\n]*?) : (.+?)\s*$", r.stdout, flags=re.M))
    for dist, name in REPORTED.items():
        assert table.get(name) == version(dist), (name, r.stdout)
    assert re.fullmatch(r"vtk\w*RenderWindow", table["Render Window"]), r.stdout
    assert f"Python {sys.version.split()[0]}" in r.stdout


def test_doctests_of_the_progress_and_cli_modules():
    for module in (progress, cli):
        assert doctest_examples(module) > 0      # pytest runs them (--doctest-modules), once


# -- packaging -------------------------------------------------------------------------------


def _local_imports(test_file: Path) -> set[str]:
    """Files in tests/ that a test file imports (helpers in tests/_support/, other test
    modules as ``tests.<folder>.test_x``), relative to the repository's root."""
    names = set()
    for node in ast.walk(ast.parse(test_file.read_text())):
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module)
    files = {f"tests/_support/{n.split('.')[0]}.py" for n in names}
    files |= {n.replace(".", "/") + ".py" for n in names if n.startswith("tests.")}
    return {f for f in files if (ROOT / f).is_file()}


@pytest.fixture(scope="module")
def sdist(tmp_path_factory):
    """The source distribution built from this checkout, unpacked: its root folder."""
    dist = tmp_path_factory.mktemp("dist")
    r = subprocess.run([sys.executable, "-m", "build", "--sdist", "--no-isolation",
                        "--skip-dependency-check", "--outdir", str(dist), str(ROOT)],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    (archive,) = dist.glob("xray_viz-*.tar.gz")
    with tarfile.open(archive) as tar:
        tar.extractall(dist, filter="data")
    (root,) = [p for p in dist.iterdir() if p.is_dir()]
    return root


def test_the_sdist_carries_what_its_tests_import(sdist):
    tests = sorted((ROOT / "tests").rglob("*.py"))
    assert ({str(p.relative_to(ROOT)) for p in tests}
            <= {str(p.relative_to(sdist)) for p in (sdist / "tests").rglob("*.py")})
    for test in tests:
        for rel in _local_imports(test):
            assert (sdist / rel).is_file(), (test.name, rel)
    # the files the tests read from the checkout
    for rel in ("pyproject.toml", "BENCHMARKS.md", "benchmarks/suites.py", "LICENSE",
                "CITATION.cff", "tests/conftest.py", "docs/conf.py", "Makefile",
                *(str(p.relative_to(ROOT)) for p in (ROOT / "tests" / "image_cache").glob("*"))):
        assert (sdist / rel).is_file(), rel
        assert (sdist / rel).read_bytes() == (ROOT / rel).read_bytes(), rel
    assert not list(sdist.rglob("__pycache__")) and not list(sdist.rglob("*.nbc"))
    meta = (sdist / "PKG-INFO").read_text()
    assert "License-Expression: MIT" in meta and "License-File: LICENSE" in meta
    assert "Classifier: Topic :: Scientific/Engineering :: Physics" in meta


def test_license_and_citation():
    text = (ROOT / "LICENSE").read_text()
    assert text.startswith("MIT License") and "Permission is hereby granted" in text
    assert tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["license"] == "MIT"
    cff = (ROOT / "CITATION.cff").read_text()
    assert "cff-version: 1.2.0" in cff and "preferred-citation:" in cff
    assert "Computational Modeling of X-ray Attenuation and Simulation of Medical Imaging" in cff
    assert "family-names: Meneghini" in cff and f"version: {version('xray_viz')}" in cff


def test_bench_from_a_wheel_says_how_to_get_the_benchmark_extra(monkeypatch, capsys):
    monkeypatch.setattr(cli, "bench_suites", lambda: None)
    assert cli.main(["bench"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "benchmark extra" in err and "pip install -e '.[bench]'" in err
    assert f"xray_viz-{version('xray_viz')}.tar.gz" in err        # where the suites are

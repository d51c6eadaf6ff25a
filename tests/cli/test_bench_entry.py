"""`xray-viz bench` is a thin entry: the suites live in the repository's benchmarks/ folder (not
in the installed package); from a checkout it runs them, elsewhere it says how to get them."""

from __future__ import annotations

import subprocess
import sys

import xray_viz.cli as cli


def test_bench_help_comes_from_the_suites_in_a_checkout():
    assert cli.bench_suites() is not None and cli.bench_suites().name == "suites.py"
    result = subprocess.run([sys.executable, "-m", "xray_viz.cli", "bench", "--help"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    assert "--suite" in result.stdout and "pareto" in result.stdout


def test_bench_without_the_repository_says_how_to_get_it(monkeypatch, capsys):
    monkeypatch.setattr(cli, "bench_suites", lambda: None)
    assert cli.main(["bench", "--quick"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "pip install -e '.[bench]'" in err and "benchmarks/" in err


def test_the_package_does_not_ship_the_benchmarks():
    import importlib.util

    assert importlib.util.find_spec("xray_viz.bench") is None


def test_unknown_arguments_of_other_commands_are_still_errors(capsys):
    try:
        cli.main(["phantoms", "--bogus"])
    except SystemExit as exc:
        assert exc.code == 2
    else:  # pragma: no cover
        raise AssertionError("no usage error")
    assert "unrecognized arguments: --bogus" in capsys.readouterr().err

"""ruff with the project's docstring rules (pyproject.toml, [tool.ruff]) finds nothing."""

from __future__ import annotations

import subprocess
import sys

from helpers import REPO



def test_ruff_finds_nothing():
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--output-format", "concise",
                             "--no-cache", str(REPO)], capture_output=True, text=True, cwd=REPO)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr[-2000:]


def test_ruff_would_catch_an_undocumented_public_function(tmp_path):
    """The rules are live: an undocumented public function in the package is reported."""
    bad = tmp_path / "xray_viz" / "probe.py"
    bad.parent.mkdir()
    bad.write_text('"""A module."""\n\n\ndef public(x):\n    return x\n')
    result = subprocess.run([sys.executable, "-m", "ruff", "check", "--no-cache", "--config",
                             str(REPO / "pyproject.toml"), "--output-format", "concise",
                             str(bad)], capture_output=True, text=True, cwd=tmp_path)
    assert result.returncode == 1 and "D103" in result.stdout, result.stdout + result.stderr

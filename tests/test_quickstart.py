"""The README's Quick start: `make demo` installs the core package only and shows pip's progress,
`make test` everything the tests need; either may run first in the same clone.

The Makefile runs for real, with the interpreter and ``.ci/system-deps`` replaced by scripts
that record how they were called (and a venv whose ``python`` is that script), so the test sees
every install and apt step each target takes, in either order, in seconds.
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

FAKE_PYTHON = r"""#!/usr/bin/env bash
# records its arguments; `-m venv DIR` makes DIR/bin/python (this script) and DIR/bin/xray-viz
echo "python $*" >> "$LOG"
if [ "$1" = -m ] && [ "$2" = venv ]; then
  mkdir -p "$3/bin"; cp "$0" "$3/bin/python"
  printf '#!/usr/bin/env bash\necho "xray-viz $*" >> "$LOG"\n' > "$3/bin/xray-viz"
  chmod +x "$3/bin/xray-viz"
fi
"""


@pytest.fixture
def clone(tmp_path):
    if shutil.which("make") is None:
        pytest.skip("needs make")
    for name in ("Makefile", "pyproject.toml"):
        shutil.copy(ROOT / name, tmp_path / name)
    (tmp_path / ".ci").mkdir()
    (tmp_path / ".ci" / "system-deps").write_text('echo "system-deps $*" >> "$LOG"\n')
    fake = tmp_path / "fake-python"
    fake.write_text(FAKE_PYTHON)
    fake.chmod(fake.stat().st_mode | stat.S_IXUSR)
    return tmp_path


def make(clone, target):
    log = clone / "log.txt"
    log.write_text("")
    env = dict(os.environ, LOG=str(log))
    done = subprocess.run(["make", "-s", target, f"PYTHON={clone / 'fake-python'}"], cwd=clone,
                          env=env, capture_output=True, text=True, timeout=60)
    assert done.returncode == 0, done.stderr
    return log.read_text().splitlines()


def installs(lines):
    return [line for line in lines if " pip install" in line and "--upgrade pip" not in line]


def test_demo_installs_the_core_only_with_progress(clone):
    lines = make(clone, "demo")
    assert installs(lines) == ["python -m pip install -e ."], lines
    assert "system-deps core" in lines                      # the GL libraries pymeshlab needs
    assert not any("--quiet" in line or " -q" in line for line in lines)
    assert lines[-1] == "xray-viz render default -o out/default.png"
    assert installs(make(clone, "demo")) == []              # done once


def test_test_installs_the_extras_and_then_demo_installs_nothing(clone):
    lines = make(clone, "test")
    assert installs(lines) == ["python -m pip install -e .[test,docs,ct]"], lines
    assert "system-deps " in lines                          # every Debian package, not `core`
    assert lines[-1] == "python -m pytest -q"
    demo = make(clone, "demo")
    assert installs(demo) == [] and demo[-1].startswith("xray-viz render default")


def test_demo_then_test_installs_the_extras(clone):
    make(clone, "demo")
    lines = make(clone, "test")
    assert installs(lines) == ["python -m pip install -e .[test,docs,ct]"], lines
    assert not any("-m venv" in line for line in lines)     # the same .venv
    assert installs(make(clone, "test")) == [] and installs(make(clone, "demo")) == []

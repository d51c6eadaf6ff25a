"""Writing HDF5 where there is no room (issue 42): ``scan -o x.nxs`` on a full disk printed the
error, then HDF5 crashed the process closing the file (a segmentation fault). Now the room is
checked before any work: one line, exit 2, nothing written.

The full disk is played by the file-size limit (``ulimit -f``, RLIMIT_FSIZE: writes past it
fail as on a full disk, EFBIG instead of ENOSPC), set in the child process only; a small tmpfs
showed the same before and after (``mount -t tmpfs -o size=512k``: needs root, not done here).
"""

from __future__ import annotations

import resource
import subprocess
import sys

import pytest

pytest.importorskip("h5py")

LIMIT = 1_000_000          # bytes: a 256 x 256 float32 stack of 8 is 2 MiB


def _limited():
    resource.setrlimit(resource.RLIMIT_FSIZE, (LIMIT, LIMIT))


@pytest.mark.parametrize("argv, out", [
    (["scan", "sphere", "--projections", "8", "-o", "{d}/x.nxs"], "x.nxs"),
    (["render", "sphere", "-o", "{d}/x.h5", "--shape", "512", "512"], "x.h5"),
])
def test_hdf5_where_there_is_no_room(tmp_path, argv, out):
    argv = [a.format(d=tmp_path) for a in argv]
    run = subprocess.run([sys.executable, "-m", "xray_viz", *argv], capture_output=True,
                         text=True, timeout=300, preexec_fn=_limited)
    assert run.returncode == 2, (run.returncode, run.stderr[-2000:])
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and "ulimit -f" in lines[0] and "needs about" in lines[0], lines
    assert str(tmp_path / out) in lines[0]
    assert list(tmp_path.iterdir()) == []              # no partial file left


def test_check_room_figures(tmp_path):
    from xray_viz.output import OutputError, check_room

    check_room(tmp_path / "small.h5", 1000)             # fits
    with pytest.raises(OutputError, match=r"needs about .* free on that disk"):
        check_room(tmp_path / "huge.h5", 1 << 62)

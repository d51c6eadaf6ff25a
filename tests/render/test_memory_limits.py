"""One memory check that reads the real limit (issue 42): the machine's available memory, the
process's RLIMIT_AS and its control group's memory.max (v2) or memory.limit_in_bytes (v1),
the least of them, used by every up-front check (a render's images, a scan's stack, a label
map's or CT's voxels)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import xray_viz
from xray_viz import _memory
from xray_viz.errors import MeshError, OutputError, SceneError

LINUX = sys.platform.startswith("linux")
pytestmark = pytest.mark.skipif(not LINUX, reason="/proc, RLIMIT_AS and cgroups are Linux's")


def _run(code: str, *args, timeout=300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)}
    return subprocess.run([sys.executable, "-c", code, *map(str, args)], env=env,
                          capture_output=True, text=True, timeout=timeout)


def _fake_root(tmp_path, *, meminfo_kb=None, v2=None, v1=None, rel="/job/task"):
    """A /proc and /sys tree: ``v2``/``v1`` are {level: (limit, used)} under the group."""
    root = tmp_path / "root"
    (root / "proc/self").mkdir(parents=True)
    if meminfo_kb is not None:
        (root / "proc/meminfo").write_text(f"MemTotal: 99999999 kB\nMemAvailable: "
                                           f"{meminfo_kb} kB\n")
    lines = []
    if v2 is not None:
        lines.append(f"0::{rel}")
        for level, (limit, used) in v2.items():
            d = root / "sys/fs/cgroup" / level
            d.mkdir(parents=True, exist_ok=True)
            (d / "memory.max").write_text(f"{limit}\n")
            (d / "memory.current").write_text(f"{used}\n")
    if v1 is not None:
        lines.append(f"4:memory:{rel}")
        for level, (limit, used) in v1.items():
            d = root / "sys/fs/cgroup/memory" / level
            d.mkdir(parents=True, exist_ok=True)
            (d / "memory.limit_in_bytes").write_text(f"{limit}\n")
            (d / "memory.usage_in_bytes").write_text(f"{used}\n")
    (root / "proc/self/cgroup").write_text("\n".join(lines) + "\n")
    return root


def test_cgroup_v2_memory_max_at_any_level_limits(tmp_path):
    gib = 1 << 30
    root = _fake_root(tmp_path, meminfo_kb=20 * gib // 1024,
                      v2={"job/task": ("max", 0), "job": (3 * gib, gib)})
    got, what = _memory.memory_limit(root=root)
    assert got == 2 * gib and "memory.max of 3.0 GiB" in what
    root = _fake_root(tmp_path / "b", meminfo_kb=gib // 1024, v2={"job": (3 * gib, 0)})
    assert _memory.memory_limit(root=root) == (gib, "this machine has 1.0 GiB available")
    # reclaimable page cache (inactive_file) is not counted as used
    got, what = _memory.memory_limit(root=_fake_root(tmp_path / "c", meminfo_kb=9 * gib // 1024,
                                                     v2={"job": (3 * gib, int(2.5 * gib))}))
    assert got == gib // 2
    (tmp_path / "c/root/sys/fs/cgroup/job/memory.stat").write_text(f"inactive_file {gib}\n")
    assert _memory.available_memory(root=tmp_path / "c/root") == gib + gib // 2


def test_cgroup_v1_limit_in_bytes_and_its_unlimited_value(tmp_path):
    gib = 1 << 30
    root = _fake_root(tmp_path, meminfo_kb=20 * gib // 1024,
                      v1={"job/task": (6 * gib, 5 * gib), "": (9223372036854771712, 0)})
    got, what = _memory.memory_limit(root=root)
    assert got == gib and "memory.limit_in_bytes of 6.0 GiB" in what
    root = _fake_root(tmp_path / "b", meminfo_kb=4 * gib // 1024,
                      v1={"job/task": (9223372036854771712, 5 * gib)})
    assert _memory.available_memory(root=root) == 4 * gib


def test_rlimit_as_limits_what_is_left_of_the_address_space():
    code = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (3 << 30, resource.RLIM_INFINITY))
from xray_viz import _memory
size = next(int(l.split()[1]) * 1024 for l in open("/proc/self/status")
            if l.startswith("VmSize"))
got, what = _memory.memory_limit()
print(got, size, what)
"""
    r = _run(code)
    assert r.returncode == 0, r.stderr
    got, size, what = r.stdout.split(maxsplit=2)
    assert 0 < int(got) <= (3 << 30) - int(size) + (64 << 20)    # VmSize read a moment later
    assert "address-space limit (ulimit -v) of 3.0 GiB" in what


def test_the_frog_at_16384_under_a_6_gib_address_space_limit_is_refused_up_front(tmp_path):
    """The issue's example: refused in one line naming the limit, before any image exists
    (on main: a MemoryError traceback after minutes of work)."""
    code = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (6 << 30, resource.RLIM_INFINITY))
from xray_viz.cli import main
sys.exit(main(["render", "frog", "--shape", "16384", "16384", "-o", sys.argv[1]]))
"""
    r = _run(code, tmp_path / "frog.tif")
    err = r.stderr.strip()
    assert r.returncode == 2, err[-2000:]
    assert "\n" not in err and "Traceback" not in err
    assert err.startswith("xray-viz: error: [detector] shape 16384 x 16384 needs about")
    assert "address-space limit (ulimit -v) of 6.0 GiB" in err and "smaller shape" in err
    assert not (tmp_path / "frog.tif").exists()


def test_a_768_cubed_label_map_is_not_widened_to_int64(tmp_path):
    """A uint8 label map of 768^3 voxels (0.4 GiB) under a 2.5 GiB address-space limit: read
    in its own type (as int64 it would need 3.4 GiB)."""
    nib = pytest.importorskip("nibabel")
    data = np.zeros((768, 768, 768), np.uint8)
    data[300:400, 300:420, 310:400] = 3
    path = tmp_path / "big.nii"
    nib.save(nib.Nifti1Image(data, np.eye(4)), str(path))
    del data
    code = """
import resource, sys
resource.setrlimit(resource.RLIMIT_AS, (2560 << 20, resource.RLIM_INFINITY))
import numpy as np
from xray_viz.meshes.volumes import read_volume
vol = read_volume(sys.argv[1])
print(vol.data.dtype, int(np.count_nonzero(vol.data == 3)))
"""
    r = _run(code, path)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["uint8", str(100 * 120 * 90)]


def test_widening_that_cannot_fit_is_refused_in_one_line(tmp_path, monkeypatch):
    """Whole floats to int64, a CT to float64: refused up front against the real limit."""
    nib = pytest.importorskip("nibabel")
    from xray_viz.meshes import volumes as V

    path = tmp_path / "f.nii.gz"
    nib.save(nib.Nifti1Image(np.ones((20, 20, 20), np.float32), np.eye(4)), str(path))
    monkeypatch.setattr(_memory, "available_memory", lambda **kw: 20 ** 3 * 8 - 1)
    for hu, kind in ((False, "int64"), (True, "float64")):
        with pytest.raises(MeshError) as info:
            V.read_volume(path, hu=hu)
        msg = str(info.value)
        assert "\n" not in msg and f"20 x 20 x 20 voxels as {kind}" in msg
        assert "crop or downsample" in msg
    monkeypatch.setattr(_memory, "available_memory", lambda **kw: 20 ** 3 * 8)
    assert V.read_volume(path).data.dtype == np.int64


def test_a_scan_stack_that_cannot_fit_is_refused_before_any_work(tmp_path, monkeypatch):
    import importlib

    S = importlib.import_module("xray_viz.scan")
    from xray_viz.orbit import Orbit

    scene = xray_viz.load_scene("sphere")          # 256 x 256
    monkeypatch.setattr(_memory, "available_memory", lambda **kw: 100 * 256 * 256 * 4 - 1)
    monkeypatch.setattr(S.Projections, "__call__", lambda *a, **k: pytest.fail("rendered"))
    with pytest.raises(SceneError) as info:
        xray_viz.scan(scene, Orbit(projections=100, axis=[0, 1, 0]))
    msg = str(info.value)
    assert "\n" not in msg and "a stack of 100 projections of 256 x 256" in msg
    assert "store=" in msg


def test_reading_a_store_whole_that_cannot_fit_is_refused(tmp_path, monkeypatch):
    import dataclasses
    import importlib

    S = importlib.import_module("xray_viz.scan")
    from xray_viz.orbit import Orbit

    scene = xray_viz.load_scene("sphere")
    scene = scene.replace(detector=dataclasses.replace(scene.detector, shape=(16, 8),
                                                       pitch=(16.0, 16.0)))
    store = tmp_path / "s.zarr"
    xray_viz.scan(scene, Orbit(projections=3, axis=[0, 1, 0]), store=store)
    monkeypatch.setattr(_memory, "available_memory", lambda **kw: 3 * 16 * 8 * 4 - 1)
    with pytest.raises(OutputError, match=r"s\.zarr: a stack of 3 projections .* lazy=True"):
        S.read_zarr(store)
    assert S.read_zarr(store, lazy=True).projections.shape == (3, 8, 16)


def test_every_up_front_check_goes_through_the_one_reading():
    """render's available_memory is the shared one (no second reading of /proc/meminfo)."""
    import importlib

    render_mod = importlib.import_module("xray_viz.render")
    src = Path(render_mod.__file__).read_text()
    assert "/proc/meminfo" not in src
    got = _memory.memory_limit()
    assert got is not None and render_mod.available_memory() <= got[0] + (64 << 20)


def test_a_dicom_series_that_cannot_fit_as_float64_is_refused_before_decoding(tmp_path,
                                                                             monkeypatch):
    pytest.importorskip("pydicom")
    pytest.importorskip("nibabel")
    pytest.importorskip("SimpleITK")
    from tests.meshes.test_volumes import grid_affine, write_dicom_series

    from xray_viz.meshes import volumes as V

    hu = np.full((40, 36, 5), 40.0)
    write_dicom_series(tmp_path / "series", hu, grid_affine())
    monkeypatch.setattr(_memory, "available_memory", lambda **kw: 2 * 8 * hu.size - 1)
    with pytest.raises(MeshError, match=r"series: the series' 40 x 36 x 5 voxels as float64 "
                                        r"needs about .* crop or downsample") as info:
        V.read_volume(tmp_path / "series", hu=True)
    assert "\n" not in str(info.value)
    monkeypatch.setattr(_memory, "available_memory", lambda **kw: 2 * 8 * hu.size)
    assert V.read_volume(tmp_path / "series", hu=True).data.shape == (40, 36, 5)

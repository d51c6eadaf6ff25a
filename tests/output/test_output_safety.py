"""No lost file, no half-written file, no message that dumps a user's file (issue 12).

Outputs (``xray-viz render -o``, ``xray-viz mesh -o``, :func:`xray_viz.output.save_image`) go
through one atomic writer: a temporary file beside the target, read back, renamed into place.
These tests break each step for real (a suffix in capitals, a read-only target, SIGTERM
mid-write, a full disk, a file that does not read back) and check that the previous file
survives, nothing is left behind, and the user reads one line. Messages about a user's files
(a scene can name any file as a mesh or spectrum) quote only short escaped excerpts.
"""

from __future__ import annotations

import builtins
import errno
import io
import os
import select
import signal
import stat
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh

import xray_viz
import xray_viz.errors
from xray_viz.cli import main
from xray_viz.errors import MeshError, OutputError, SpectrumError, excerpt, one_line
from xray_viz.meshes import load_mesh
from xray_viz.physics.spectra import read_spectrum_csv
from xray_viz.output import _write_protected, save_image, to_uint16
from helpers import doctest_examples, write_scene
from tests.scene.test_scene_file import GOOD

IS_ROOT = hasattr(os, "geteuid") and os.geteuid() == 0
#: A scene big enough that its outputs are written in many chunks (npy 512 KiB).
BIG = GOOD.replace("shape = [32, 24]", "shape = [256, 256]").replace("pitch = 2.0", "pitch = 0.25")


@pytest.fixture
def scene_path(tmp_path):
    folder = tmp_path / "scene"
    folder.mkdir()
    ball = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    ball.apply_translation([8.0, 5.0, 0.0])
    return write_scene(folder, GOOD, {"ball.stl": ball})


@pytest.fixture
def out_dir(tmp_path):
    folder = tmp_path / "out"
    folder.mkdir()
    return folder


def hidden(folder: Path) -> list[str]:
    """Names of hidden files (the writer's temporaries are ``.NAME.xxxx``) in ``folder``."""
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def one_error_line(captured) -> str:
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    assert "Traceback" not in captured.err
    return lines[0]


def check_values(path: Path, expected: np.ndarray, *, bright: str) -> None:
    """The file at ``path`` holds ``expected`` as its format stores it (an independent read)."""
    suffix = path.suffix.lower()
    if suffix == ".npy":
        got = np.load(path)          # np.load does not care about the suffix's case
        assert got.dtype == np.float64 and got.shape == expected.shape
        np.testing.assert_array_equal(got, expected)
        return
    if suffix == ".dcm":
        import pydicom

        from xray_viz.output import dicom_values

        got = dicom_values(pydicom.dcmread(path))
        np.testing.assert_allclose(got, expected, rtol=0,
                                   atol=np.ptp(expected) / 65535 / 2 * 1.0001)
        return
    from PIL import Image

    with Image.open(path) as im:
        got = np.asarray(im)
    if suffix in (".tif", ".tiff"):
        np.testing.assert_array_equal(got, expected.astype(np.float32))
    else:
        lo, hi = expected.min(), expected.max()
        scaled = (expected - lo) / (hi - lo) if bright == "high" else (hi - expected) / (hi - lo)
        np.testing.assert_allclose(got, scaled * 65535, atol=0.51)


# -- 1. any suffix case, and every written file is read back ---------------------------------

@pytest.mark.parametrize("suffix", [".npy", ".NPY", ".Npy", ".TIFF", ".Tif", ".PNG", ".DCM"])
def test_any_suffix_case_replaces_the_previous_file_with_the_new_image(scene_path, out_dir,
                                                                       suffix):
    scene = xray_viz.load_scene(scene_path)
    out = out_dir / f"result{suffix}"
    previous = np.linspace(1.0, 2.0, 24 * 32).reshape(24, 32)
    save_image(out, previous, scene=scene)                       # the previous good file
    before = out.read_bytes()
    assert main(["render", str(scene_path), "-o", str(out), "--engine", "numpy",
                 "--quantity", "line-integral"]) == 0
    expected = xray_viz.render(scene, engine="numpy").line_integral
    assert out.read_bytes() != before
    check_values(out, expected, bright="high")
    assert sorted(os.listdir(out_dir)) == [out.name]             # no stray temporary file

    # the API, over the CLI's file
    image = xray_viz.render(scene, engine="numpy").intensity
    assert save_image(out, image, bright="low", scene=scene) == out
    check_values(out, image, bright="low")
    assert sorted(os.listdir(out_dir)) == [out.name]


def _truncate_after(real):
    def write(obj, fp, *args, **kwargs):
        real(obj, fp, *args, **kwargs)
        os.truncate(fp, os.path.getsize(fp) // 2)
    return write


@pytest.mark.parametrize("suffix", [".npy", ".NPY", ".tiff", ".png", ".dcm"])
def test_a_file_that_does_not_read_back_is_refused_and_the_previous_kept(scene_path, out_dir,
                                                                         monkeypatch, suffix):
    import PIL.Image
    import pydicom

    scene = xray_viz.load_scene(scene_path)
    out = out_dir / f"a{suffix}"
    save_image(out, np.eye(24, 32), scene=scene)
    before = out.read_bytes()
    if suffix.lower() == ".npy":
        # the old failure: np.save put the data elsewhere and the target stayed empty
        monkeypatch.setattr(np, "save", lambda file, arr, *a, **k: None)
    elif suffix == ".dcm":
        real = pydicom.dcmwrite
        monkeypatch.setattr(pydicom, "dcmwrite", lambda fp, ds, **k: _truncate_after(
            lambda d, f: real(f, d, **k))(ds, fp))
    elif suffix == ".tiff":                     # written by tifffile
        import tifffile

        real = tifffile.imwrite

        def truncated(fh, data, **kwargs):
            real(fh, data, **kwargs)
            fh.flush()
            os.truncate(fh.name, os.path.getsize(fh.name) // 2)
        monkeypatch.setattr(tifffile, "imwrite", truncated)
    else:
        monkeypatch.setattr(PIL.Image.Image, "save", _truncate_after(PIL.Image.Image.save))
    with pytest.raises(OutputError) as info:
        save_image(out, np.ones((24, 32)), scene=scene)
    text = str(info.value)
    assert text.startswith(f"{out}: cannot write: the written file does not read back")
    assert "\n" not in text and len(text) < 400
    assert out.read_bytes() == before
    assert sorted(os.listdir(out_dir)) == [out.name]


# -- 2. permissions ---------------------------------------------------------------------------

@pytest.mark.parametrize("mode", [0o600, 0o640, 0o604, 0o660])
def test_overwriting_keeps_the_files_permission_bits(scene_path, out_dir, mode):
    out = out_dir / "a.npy"
    out.write_bytes(b"previous")
    os.chmod(out, mode)
    assert main(["render", str(scene_path), "-o", str(out), "--engine", "numpy"]) == 0
    assert stat.S_IMODE(out.stat().st_mode) == mode
    assert np.load(out).shape == (24, 32)
    mesh_out = out_dir / "b.stl"
    mesh_out.write_bytes(b"previous")
    os.chmod(mesh_out, mode)
    assert main(["mesh", str(scene_path.parent / "ball.stl"), "-o", str(mesh_out)]) == 0
    assert stat.S_IMODE(mesh_out.stat().st_mode) == mode
    assert len(trimesh.load(mesh_out).faces) == 320


def test_a_new_file_gets_the_usual_mode(out_dir):
    mask = os.umask(0o027)
    try:
        out = save_image(out_dir / "a.tiff", np.eye(3))
    finally:
        os.umask(mask)
    assert stat.S_IMODE(out.stat().st_mode) == 0o640


@pytest.mark.parametrize("mode", [0o444, 0o400, 0o555, 0o000])
def test_a_read_only_target_is_refused_in_one_line_and_kept(scene_path, out_dir, capsys, mode):
    # as root (CI) too: the kernel would let root replace it, cp -i / rm call it write-protected
    out = out_dir / "a.png"
    out.write_bytes(b"previous")
    os.chmod(out, mode)
    try:
        assert main(["render", str(scene_path), "-o", str(out), "--engine", "numpy"]) == 2
        line = one_error_line(capsys.readouterr())
        assert line == (f"xray-viz: error: {out}: is read-only (mode {mode:04o}); "
                        "remove it or choose another output")
        with pytest.raises(OutputError, match="is read-only"):
            save_image(out, np.eye(3))
        mesh_out = out_dir / "a.stl"
        mesh_out.write_bytes(b"previous")
        os.chmod(mesh_out, mode)
        assert main(["mesh", str(scene_path.parent / "ball.stl"), "-o", str(mesh_out)]) == 2
        captured = capsys.readouterr()
        assert one_error_line(captured).startswith(f"xray-viz: error: {mesh_out}: is read-only")
        assert captured.out == ""            # refused before the repair and its report
        for path in (out, mesh_out):
            assert stat.S_IMODE(path.stat().st_mode) == mode
            os.chmod(path, 0o600)
            assert path.read_bytes() == b"previous"
        assert hidden(out_dir) == []
    finally:
        for path in out_dir.iterdir():
            os.chmod(path, 0o600)


def _stat(mode, uid, gid):
    return os.stat_result((stat.S_IFREG | mode, 1, 1, 1, uid, gid, 0, 0, 0, 0))


@pytest.mark.parametrize("euid,groups,mode,uid,gid,protected", [
    (1000, [1000], 0o466, 1000, 1000, True),    # the owner: only the owner's bit counts
    (1000, [1000], 0o200, 1000, 1000, False),
    (1000, [50], 0o646, 0, 50, True),           # a member of the group: the group's bit
    (1000, [50], 0o020, 0, 50, False),
    (1000, [1000], 0o664, 0, 0, True),          # anyone else: the others' bit
    (1000, [1000], 0o002, 0, 0, False),
    (0, [0], 0o444, 1000, 1000, True),          # root: no write bit at all
    (0, [0], 0o020, 1000, 1000, False),
    (0, [0], 0o002, 0, 0, False),
])
def test_write_protection_rule_of_each_class(monkeypatch, euid, groups, mode, uid, gid,
                                             protected):
    monkeypatch.setattr(os, "geteuid", lambda: euid)
    monkeypatch.setattr(os, "getegid", lambda: groups[0])
    monkeypatch.setattr(os, "getgroups", lambda: list(groups))
    assert _write_protected(Path("x.npy"), _stat(mode, uid, gid)) is protected


@pytest.mark.skipif(not IS_ROOT, reason="only root can give a file to another user")
def test_root_overwriting_another_users_file_keeps_its_owner(out_dir):
    out = out_dir / "a.npy"
    out.write_bytes(b"previous")
    os.chown(out, 1234, 4321)
    os.chmod(out, 0o640)
    save_image(out, np.eye(3))
    st = out.stat()
    assert (st.st_uid, st.st_gid, stat.S_IMODE(st.st_mode)) == (1234, 4321, 0o640)
    np.testing.assert_array_equal(np.load(out), np.eye(3))


def test_a_symbolic_link_is_followed_and_kept(out_dir):
    real = out_dir / "real.npy"
    save_image(real, np.zeros((2, 2)))
    os.chmod(real, 0o600)
    link = out_dir / "link.npy"
    link.symlink_to(real.name)
    save_image(link, np.eye(2))
    assert link.is_symlink() and os.readlink(link) == real.name
    np.testing.assert_array_equal(np.load(real), np.eye(2))
    assert stat.S_IMODE(real.stat().st_mode) == 0o600
    assert hidden(out_dir) == []


def test_a_folder_as_target_is_refused_in_one_line(scene_path, out_dir, capsys):
    folder = out_dir / "a.png"
    folder.mkdir()
    assert main(["render", str(scene_path), "-o", str(folder), "--engine", "numpy"]) == 2
    assert one_error_line(capsys.readouterr()) == (
        f"xray-viz: error: {folder}: is a folder; give a file name to write")
    assert list(folder.iterdir()) == [] and sorted(os.listdir(out_dir)) == ["a.png"]


# -- 3. signals while writing -----------------------------------------------------------------

SLOW_WRITER = textwrap.dedent('''
    """Run the CLI with writers that report, through a pipe, once the data are in the
    temporary file, and then take their time: a signal sent then arrives mid-write."""
    import os
    import sys
    import time

    import numpy as np
    import PIL.Image
    import tifffile

    ready = int(sys.argv[1])

    def slowly(real):
        def write(*args, **kwargs):
            result = real(*args, **kwargs)
            os.write(ready, b"w")
            time.sleep(600)
            return result
        return write

    np.save = slowly(np.save)
    PIL.Image.Image.save = slowly(PIL.Image.Image.save)
    tifffile.imwrite = slowly(tifffile.imwrite)
    from xray_viz.cli import main
    sys.exit(main(sys.argv[2:]))
''')


@pytest.mark.parametrize("suffix,signum", [
    (".npy", signal.SIGTERM), (".tiff", signal.SIGINT),    # a process each: ~3 s (idle)
    pytest.param(".tiff", signal.SIGTERM, marks=pytest.mark.slow),
    pytest.param(".npy", signal.SIGINT, marks=pytest.mark.slow),
    pytest.param(".npy", signal.SIGHUP, marks=pytest.mark.slow),
])
def test_a_signal_during_the_write_removes_the_temporary_and_keeps_the_previous(
        tmp_path, out_dir, suffix, signum):
    ball = trimesh.creation.icosphere(subdivisions=2, radius=20.0)
    scene = write_scene(tmp_path, BIG, {"ball.stl": ball})
    out = out_dir / f"result{suffix}"
    save_image(out, np.eye(256))
    before = out.read_bytes()
    script = tmp_path / "slow_writer.py"
    script.write_text(SLOW_WRITER)
    r, w = os.pipe()
    proc = subprocess.Popen(
        [sys.executable, str(script), str(w), "render", str(scene), "-o", str(out),
         "--engine", "numpy"], pass_fds=(w,), stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)
    os.close(w)
    try:
        readable, _, _ = select.select([r], [], [], 300)      # a guard against a hang only
        assert readable and os.read(r, 1) == b"w", proc.stderr.read() if proc.poll() else ""
        temporary = hidden(out_dir)
        assert len(temporary) == 1                             # the write is under way
        assert (out_dir / temporary[0]).stat().st_size > 100_000
        os.kill(proc.pid, signum)
        stdout, stderr = proc.communicate(timeout=300)
    finally:
        os.close(r)
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + signum
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in stderr, stderr
    name = signal.Signals(signum).name
    expected = ("xray-viz: interrupted: " if signum == signal.SIGINT
                else f"xray-viz: error: interrupted by {name}: ")
    assert lines[0] == f"{expected}{out} not written; nothing was changed there"
    assert stdout == ""
    assert hidden(out_dir) == [] and sorted(os.listdir(out_dir)) == [out.name]
    assert out.read_bytes() == before


# -- 4. operating-system errors: one line -----------------------------------------------------

class _FullDisk:
    """A file object whose writes fail as on a full disk (or another errno)."""

    def __init__(self, fh, code):
        self._fh, self._code = fh, code

    def write(self, data):
        raise OSError(self._code, os.strerror(self._code))

    def fileno(self):   # encoders that would write to the descriptor use write() instead
        raise io.UnsupportedOperation("fileno")

    def __getattr__(self, name):
        return getattr(self._fh, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()


@pytest.fixture
def failing_writes(monkeypatch):
    """Make every write into a hidden temporary file of a folder fail with an errno."""
    def install(folder: Path, code: int):
        real_open = builtins.open

        def fake_open(file, mode="r", *args, **kwargs):
            fh = real_open(file, mode, *args, **kwargs)
            name = Path(os.fsdecode(file)) if isinstance(file, (str, bytes, os.PathLike)) else None
            if (name is not None and name.parent == folder and name.name.startswith(".")
                    and any(c in mode for c in "wa+")):
                return _FullDisk(fh, code)
            return fh
        monkeypatch.setattr(builtins, "open", fake_open)
    return install


@pytest.mark.parametrize("command,suffix,code", [
    ("render", ".npy", errno.ENOSPC), ("render", ".NPY", errno.ENOSPC),
    ("render", ".tiff", errno.ENOSPC), ("render", ".png", errno.ENOSPC),
    ("render", ".dcm", errno.ENOSPC), ("render", ".dcm", errno.EDQUOT),
    ("render", ".dcm", errno.EIO), ("render", ".npy", errno.EIO),
    ("mesh", ".stl", errno.ENOSPC), ("mesh", ".ply", errno.ENOSPC),
    ("mesh", ".obj", errno.ENOSPC), ("mesh", ".off", errno.EDQUOT),
])
def test_a_failing_disk_is_one_line_and_keeps_the_previous_file(scene_path, out_dir, capsys,
                                                                failing_writes, command,
                                                                suffix, code):
    out = out_dir / f"result{suffix}"
    out.write_bytes(b"previous")
    args = (["render", str(scene_path), "--engine", "numpy"] if command == "render" else
            ["mesh", str(scene_path.parent / "ball.stl")])
    failing_writes(out_dir, code)
    assert main([*args, "-o", str(out)]) == 2
    line = one_error_line(capsys.readouterr())
    assert line == f"xray-viz: error: {out}: cannot write: {os.strerror(code)}"
    assert out.read_bytes() == b"previous"
    assert sorted(os.listdir(out_dir)) == [out.name]


FILE_SIZE_LIMIT = textwrap.dedent('''
    """Run the CLI with a 20 kB file size limit: the kernel fails the writes (EFBIG)."""
    import resource
    import signal
    import sys

    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
    resource.setrlimit(resource.RLIMIT_FSIZE, (20_000, 20_000))
    from xray_viz.cli import main
    sys.exit(main(sys.argv[1:]))
''')


@pytest.mark.parametrize("command,suffix", [
    ("render", ".dcm"),                       # pydicom wraps the error with a traceback
    pytest.param("render", ".npy", marks=pytest.mark.slow),
    pytest.param("mesh", ".stl", marks=pytest.mark.slow),
])
def test_a_real_write_error_from_the_kernel_is_one_line(tmp_path, out_dir, command, suffix):
    pytest.importorskip("resource")
    ball = trimesh.creation.icosphere(subdivisions=3, radius=20.0)       # 64 kB as STL
    scene = write_scene(tmp_path, BIG, {"ball.stl": ball})
    script = tmp_path / "limit.py"
    script.write_text(FILE_SIZE_LIMIT)
    out = out_dir / f"result{suffix}"
    out.write_bytes(b"previous")
    args = (["render", str(scene), "--engine", "numpy"] if command == "render" else
            ["mesh", str(tmp_path / "ball.stl")])
    result = subprocess.run([sys.executable, str(script), *args, "-o", str(out)],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
    assert lines[0] == f"xray-viz: error: {out}: cannot write: {os.strerror(errno.EFBIG)}"
    assert out.read_bytes() == b"previous"
    assert sorted(os.listdir(out_dir)) == [out.name]


# -- 5. messages quote short escaped excerpts of user files -----------------------------------

#: 5000 characters with control characters (a terminal escape, a bell) and non-ASCII text.
LONG_LINE = "7" * 2400 + "\x01\x1b[2J\x07\x00é€\u202e" + "A" * 2590


def assert_safe(line: str, folder=None) -> None:
    """One short line, nothing unprintable, no long run of the file's contents; ``folder``
    (a scene's absolute paths to its files) does not count towards the length."""
    assert "\n" not in line
    assert len(line.replace(str(folder), "") if folder else line) < 300, line
    assert all(c.isprintable() for c in line), repr(line)
    assert "A" * 50 not in line and "7" * 50 not in line


def test_excerpt_and_one_line_helpers():
    assert doctest_examples(xray_viz.errors) >= 4     # pytest runs them (--doctest-modules)
    text = excerpt(LONG_LINE)
    assert text.startswith("'" + "7" * 40 + "'...") and f"({len(LONG_LINE)} characters)" in text
    assert_safe(text)
    assert_safe(excerpt(LONG_LINE.encode("utf-8")))
    assert eval(excerpt("a\x1bb\n")) == "a\x1bb\n"          # repr escaping: reversible
    said = one_line("reader says:\n" + LONG_LINE)
    assert said.startswith("reader says: 777") and said.endswith("...") and len(said) == 200
    assert all(c.isprintable() for c in said)


@pytest.mark.parametrize("row", [f"{LONG_LINE},3", f"60,{LONG_LINE}", LONG_LINE])
def test_a_spectrum_csv_error_quotes_nothing_of_the_file(tmp_path, capsys, monkeypatch, row):
    """Named by line and field; the file's text is not quoted at all (issue 42: a spectrum
    file may be any private file)."""
    monkeypatch.chdir(tmp_path)
    Path("spectrum.csv").write_text(f"keV,fluence\n50,1\n{row}\n70,2\n", encoding="utf-8")
    with pytest.raises(SpectrumError) as info:
        read_spectrum_csv("spectrum.csv")
    assert "line 3" in str(info.value)
    assert_safe(str(info.value))
    ball = trimesh.creation.icosphere(subdivisions=1, radius=10.0)
    scene = write_scene(tmp_path, GOOD.replace("energy = 60.0",
                                               'spectrum = { file = "spectrum.csv" }'),
                        {"ball.stl": ball})
    assert main(["render", scene.name, "-o", "x.npy", "--engine", "numpy"]) == 2
    line = one_error_line(capsys.readouterr())
    assert line.startswith("xray-viz: error: ") and "spectrum.csv: line 3, field " in line
    assert_safe(line)
    assert "7777" not in line and "7777" not in str(info.value)
    assert not Path("x.npy").exists()


def _long_line_meshes() -> dict[str, bytes]:
    """Mesh files whose readers quote a 5000-character line of the file in their errors."""
    long = LONG_LINE.encode("utf-8")
    return {
        "header.ply": (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty " + long
                       + b" x\nend_header\n"),
        "header.vtk": long + b"\nrest\n",
        "format.vtk": b"# vtk DataFile Version 3.0\ntitle\n" + long + b"\nDATASET POLYDATA\n",
        "attribute.vtp": b'<?xml version="1.0"?>\n<VTKFile type="' + long + b'"></VTKFile>\n',
        "bad.off": b"OFF\n3 1 0\n0 0 0\n1 0 0\n" + long + b"\n3 0 1 2\n",
        "bad.obj": b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nv " + long + b"\n",
    }


@pytest.mark.parametrize("name", sorted(_long_line_meshes()))
def test_a_mesh_reader_error_quotes_a_short_escaped_excerpt(tmp_path, capsys, monkeypatch,
                                                            name):
    monkeypatch.chdir(tmp_path)
    Path(name).write_bytes(_long_line_meshes()[name])
    with pytest.raises(MeshError) as info:
        load_mesh(name)
    assert str(info.value).startswith(f"{name}: ")
    assert_safe(str(info.value))
    assert main(["mesh", name, "-o", "x.stl"]) == 2
    line = one_error_line(capsys.readouterr())
    assert line.startswith(f"xray-viz: error: {name}: ")
    assert_safe(line)
    scene = write_scene(tmp_path, GOOD.replace('mesh = "ball.stl"', f'mesh = "{name}"'))
    assert main(["render", scene.name, "-o", "x.npy", "--engine", "numpy"]) == 2
    line = one_error_line(capsys.readouterr())
    assert name in line
    assert_safe(line, tmp_path)
    assert not Path("x.stl").exists() and not Path("x.npy").exists()


# -- 6. corrupt VTK files ----------------------------------------------------------------------

def _corrupt_vtk_files(folder: Path) -> dict[str, str]:
    """name -> a word the one-line error must contain."""
    import pyvista as pv

    rng = np.random.default_rng(12)
    ball = pv.Sphere(theta_resolution=16, phi_resolution=16)
    ball.save(folder / "good_binary.vtk", binary=True)
    whole = (folder / "good_binary.vtk").read_bytes()
    files = {
        # not UTF-8 in the header: VTK's message about it comes back as bytes
        "latin1_header.vtk": b"\xff\xfe vtk DataFile Version 3.0\nt\xe9te\nASCII\n",
        "junk.vtk": b"\xff\xfe" + rng.integers(0, 256, 3000, dtype=np.uint8).tobytes(),
        "truncated.vtk": whole[: len(whole) // 2],
        "junk.vtp": rng.integers(0, 256, 3000, dtype=np.uint8).tobytes(),
        "junk.vtu": rng.integers(0, 256, 3000, dtype=np.uint8).tobytes(),
        "bad_dataset.vtk": b"# vtk DataFile Version 3.0\nt\nASCII\nDATASET \xe9POLYDATA\n",
    }
    for name, data in files.items():
        (folder / name).write_bytes(data)
    return {"latin1_header.vtk": "legacy VTK", "junk.vtk": "legacy VTK",
            "truncated.vtk": "binary data", "junk.vtp": "XML", "junk.vtu": "cannot read mesh",
            "bad_dataset.vtk": "DATASET"}


def test_corrupt_vtk_files_are_one_line_errors_through_the_cli(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name, word in _corrupt_vtk_files(tmp_path).items():
        assert main(["mesh", name, "-o", "x.stl"]) == 2, name
        line = one_error_line(capsys.readouterr())
        assert line.startswith(f"xray-viz: error: {name}: ") and word in line, line
        assert_safe(line)
        scene = write_scene(tmp_path, GOOD.replace('mesh = "ball.stl"', f'mesh = "{name}"'))
        assert main(["render", scene.name, "-o", "x.npy", "--engine", "numpy"]) == 2, name
        line = one_error_line(capsys.readouterr())
        assert name in line and word in line, line
        assert_safe(line, tmp_path)
    assert not Path("x.stl").exists() and not Path("x.npy").exists()
    # and as a separate process: no traceback on stderr, exit status 2
    result = subprocess.run([sys.executable, "-m", "xray_viz.cli", "mesh", "junk.vtk",
                             "-o", "x.stl"], capture_output=True, text=True, timeout=120)
    assert result.returncode == 2 and "Traceback" not in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


# -- 7. PNG windowing with non-finite values --------------------------------------------------

@pytest.mark.parametrize("bright", ["high", "low"])
def test_png_windows_the_finite_values_and_draws_infinities_at_their_end(out_dir, bright):
    finite = np.array([[0.5, 1.0, 1.5], [2.0, 2.5, 3.0]])
    image = np.vstack([finite, [[np.inf, -np.inf, np.nan]]])
    out = out_dir / "a.PNG"
    with pytest.warns(RuntimeWarning, match=r"a\.PNG: 3 of 9 pixels are not finite"):
        save_image(out, image, bright=bright)
    from PIL import Image

    with Image.open(out) as im:
        got = np.asarray(im).astype(np.float64)
    scaled = (finite - 0.5) / (3.0 - 0.5)                      # the window of the finite values
    top, bottom = (65535, 0) if bright == "high" else (0, 65535)
    expected_finite = scaled if bright == "high" else 1 - scaled
    np.testing.assert_allclose(got[:2], expected_finite * 65535, atol=0.51)
    assert got[2].tolist() == [top, bottom, bottom]             # +inf, -inf, NaN
    with pytest.warns(RuntimeWarning, match="3 of 9 pixels are not finite"):
        np.testing.assert_array_equal(to_uint16(image, bright=bright), got)


def test_png_of_finite_values_does_not_warn(out_dir):
    import warnings

    with warnings.catch_warnings():
        warnings.simplefilter("error")
        save_image(out_dir / "a.png", np.eye(3))

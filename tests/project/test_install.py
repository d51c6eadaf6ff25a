"""Installs that are not yours: a read-only install, an unwritable home, a broken kernel cache.

The fast engine's numba kernels are cached on disk where numba and
:mod:`xray_viz.tracing._numba_cache` decide. These tests install xray_viz into a fresh directory
owned by root (a copy of what its wheel holds, laid out by ``pyproject.toml``) and run it in a
subprocess as the unprivileged user nobody (uid 65534), with HOME a directory that nobody cannot
write: the tests run as root, and root ignores permission bits, so a chmod alone would prove
nothing. When nobody cannot reach this Python (its interpreter under a private /root, say), the
subprocess gets a private mount namespace (``unshare --mount``) in which the blocking
directories are covered by an empty tmpfs with the needed entries bound back; nothing of the
machine is changed. The tests skip, saying why, only when no unprivileged run is possible.

A cold compile of every kernel a render needs takes 15-60 s, so the default cases compile one
small kernel (``finish``; ``first_use_rank`` in the probes) and load the others from cache
files copied from this process's own warm cache (same source, same machine: numba accepts
them); the full cold runs are marked slow.
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import pickle
import shutil
import stat
import subprocess
import sys
import tempfile
import types
from pathlib import Path

import numpy as np
import pytest

#: The repository's root (not helpers.REPO: this file also runs as a script, the launcher).
ROOT = Path(__file__).resolve().parents[2]
NOBODY = 65534
#: The small kernel the probes compile (well under 10 s cold).
SMALL = "first_use_rank"
#: The small kernel the default render cases compile: one a render of the sphere waits for
#: (a cold render orders the meshes in NumPy rather than wait for ``first_use_rank``).
RENDERED = "finish"
#: Prints where each kernel is cached, then runs the small kernel on faces whose first-use
#: ranks are known, and says whether it came from the cache.
PROBE = """
import json, sys
import numpy as np
import xray_viz
from xray_viz.tracing import _numba_cache as C, _raster as R, _raster_calls as RC
faces = np.array([3, 1, 3, 0, 4], np.int64)
rank = RC.first_use_rank(faces, 6)
print(json.dumps(dict(uid=__import__("os").getuid(), version=sys.version, base=sys.base_prefix,
                      package=xray_viz.__file__, numba=__import__("numba").__file__,
                      where=C.cache_path(R._first_use_rank), where_direct=C.cache_path(R._raster_direct),
                      rank=rank.tolist(), hits=sum(R._first_use_rank.stats.cache_hits.values()),
                      misses=sum(R._first_use_rank.stats.cache_misses.values()))))
"""
#: What nobody must be able to reach: this interpreter and its packages.
NEEDED = sorted({os.path.realpath(sys.base_prefix), os.path.realpath(sys.prefix),
                 os.path.dirname(os.path.realpath(sys.executable))})


# -- running as nobody ---------------------------------------------------------------------------

def _may_enter(st, uid, gid) -> bool:
    if st.st_uid == uid:
        return bool(st.st_mode & stat.S_IXUSR)
    if st.st_gid == gid:
        return bool(st.st_mode & stat.S_IXGRP)
    return bool(st.st_mode & stat.S_IXOTH)


def _blocked(paths, uid, gid):
    """(directory, entry) pairs: a directory that uid cannot enter on the way to one of
    ``paths``, and the entry under it on that way. ``None`` as entry: the path itself."""
    out = []
    for p in paths:
        parts = Path(os.path.realpath(p)).parts
        for i in range(1, len(parts) + 1):
            d = os.path.join(*parts[:i])
            if not _may_enter(os.stat(d), uid, gid):
                out.append((d, parts[i] if i < len(parts) else None))
                break
    return out


def _launch(spec):
    """Run as root, in a private mount namespace when directories must be opened: cover each
    directory that blocks nobody's way to ``spec['expose']`` with a tmpfs (mode 755) holding
    only the entries on the way, bound back; then become nobody and exec ``spec['argv']``."""
    uid, gid = spec["uid"], spec["gid"]
    stash = tempfile.mkdtemp(prefix="xray_viz-stash-")
    for _ in range(32):
        blocked = _blocked(spec["expose"], uid, gid)
        if not blocked:
            break
        d = blocked[0][0]
        entries = sorted({e for dd, e in blocked if dd == d})
        if None in entries:
            sys.exit(f"launcher: {d} itself is closed to uid {uid}")
        held = []
        for i, e in enumerate(entries):
            os.mkdir(os.path.join(stash, str(i)))
            subprocess.run(["mount", "--bind", os.path.join(d, e), os.path.join(stash, str(i))],
                           check=True)
            held.append((os.path.join(stash, str(i)), os.path.join(d, e)))
        subprocess.run(["mount", "-t", "tmpfs", "-o", "mode=0755", "tmpfs", d], check=True)
        for src, dst in held:
            os.mkdir(dst)
            subprocess.run(["mount", "--move", src, dst], check=True)
            os.rmdir(src)
    else:
        sys.exit("launcher: could not open the way")
    os.rmdir(stash)
    os.setgroups([])
    os.setgid(gid)
    os.setuid(uid)
    os.chdir(spec["cwd"])
    os.execve(spec["argv"][0], spec["argv"], spec["env"])


def _launcher_prefix(expose):
    """The command that runs the launcher for ``expose``: in a new mount namespace if any
    directory blocks nobody, else directly."""
    if _blocked(expose, NOBODY, NOBODY):
        return ["unshare", "--mount", "--propagation", "private", "--",
                sys.executable, __file__]
    return [sys.executable, __file__]


def run_as_nobody(argv, *, env, cwd, expose=(), timeout=600):
    """Run ``argv`` (argv[0] an absolute path) as nobody; see the module docstring."""
    spec = dict(uid=NOBODY, gid=NOBODY, argv=list(map(str, argv)), env=env, cwd=str(cwd),
                expose=[*NEEDED, *map(str, expose)])
    cmd = [*_launcher_prefix(spec["expose"]), json.dumps(spec)]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)


@functools.cache
def _why_nobody_cannot_run():
    """None if nobody can run this Python and import numba here (the launcher works), else
    why not."""
    if not hasattr(os, "getuid") or os.getuid() != 0:
        return "becoming another user needs root (tests and CI run as root)"
    try:
        r = run_as_nobody([sys.executable, "-c", "import os, numba; print(os.getuid())"],
                          env={"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": "/"},
                          cwd="/", timeout=300)
    except (OSError, subprocess.SubprocessError) as exc:
        return f"{type(exc).__name__}: {exc}"
    if r.returncode or r.stdout.strip() != str(NOBODY):
        return f"exit {r.returncode}: {r.stderr.strip()[-500:]}"
    return None


@pytest.fixture(scope="module")
def world():
    """A directory everyone can enter (mkdtemp makes 0700 ones), removed afterwards."""
    import time

    d = Path(tempfile.mkdtemp(prefix="xray_viz-install-"))
    d.chmod(0o755)
    yield d
    # a render leaves background compiles (other scenes' kernels, the mesh checks) filling
    # the installs' caches for a while: removed once they are done writing
    deadline = time.monotonic() + 300
    while True:
        try:
            shutil.rmtree(d)
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            time.sleep(1)


@pytest.fixture(scope="module")
def nobody():
    """Skip (saying why) only when no unprivileged run is possible here."""
    why = _why_nobody_cannot_run()
    if why:
        pytest.skip(f"cannot run a subprocess as the unprivileged user nobody here: {why}")


def _install(dest: Path) -> Path:
    """Copy what xray_viz's wheel holds (packages and package data of pyproject.toml) into
    ``dest``, as ``pip install --target dest`` would lay it out; return ``dest``."""
    import fnmatch
    import tomllib

    conf = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]
    mapping = conf["package-dir"]
    for pkg in conf["packages"]:
        base = max((p for p in mapping if pkg == p or pkg.startswith(p + ".")), key=len)
        src = ROOT / mapping[base] / Path(*pkg[len(base):].split(".")[1:])
        out = dest / Path(*pkg.split("."))
        out.mkdir(parents=True, exist_ok=True)
        patterns = ["*.py", *conf.get("package-data", {}).get(pkg, [])]
        for f in src.iterdir():
            if f.is_file() and any(fnmatch.fnmatch(f.name, pat) for pat in patterns):
                shutil.copy2(f, out / f.name)
    return dest


def _tree(d: Path):
    """Every path under ``d`` with its size and mtime (to see that nothing changed)."""
    return {str(p): (p.stat().st_size, p.stat().st_mtime_ns) for p in d.rglob("*")}


@pytest.fixture(scope="module")
def site(world, nobody):
    """A read-only install: owned by root, every directory 555 and file 444."""
    d = _install(world / "site")
    for p in [d, *d.rglob("*")]:
        p.chmod(0o555 if p.is_dir() else 0o444)
    return d


def _home(world, name="home"):
    """A home directory nobody cannot write (owned by root, 555)."""
    h = world / name
    h.mkdir()
    h.chmod(0o555)
    return h


def _tmp(world, name):
    """A temporary directory like /tmp (1777) of our own, so that runs do not share one."""
    t = world / name
    t.mkdir()
    t.chmod(0o1777)
    return t


def _env(site, home, tmp, **extra):
    env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin"), "HOME": str(home),
           "TMPDIR": str(tmp), "PYTHONPATH": str(site), "PYTHONNOUSERSITE": "1",
           "PYTHONDONTWRITEBYTECODE": "1", "LANG": "C.UTF-8"}
    env.update(extra)
    return env


def _probe(site, home, tmp, **extra):
    r = run_as_nobody([sys.executable, "-c", PROBE], env=_env(site, home, tmp, **extra),
                      cwd=home, expose=[site, home, tmp])
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr, r.stderr
    return json.loads(r.stdout.strip().splitlines()[-1]), r.stderr


def _notices(stderr: str):
    return [line for line in stderr.splitlines() if "KernelCacheWarning" in line
            or line.startswith("xray-viz: warning:")]


@functools.cache
def _expected_rank():
    """First-use ranks of the probe's faces, by an independent route (numpy.unique)."""
    faces = np.array([3, 1, 3, 0, 4])
    used, first = np.unique(faces, return_index=True)
    order = list(used[np.argsort(first)]) + [v for v in range(6) if v not in used]
    rank = np.empty(6, int)
    rank[order] = np.arange(6)
    return rank.tolist()


# -- a read-only install, an unwritable home -----------------------------------------------------

def test_read_only_install_caches_in_a_private_temp_dir(world, site):
    home, tmp = _home(world, "home-ro"), _tmp(world, "tmp-ro")
    before = _tree(site), _tree(home)
    info, err = _probe(site, home, tmp)
    # nobody runs this very interpreter, its packages, and the install under test.
    assert info["uid"] == NOBODY
    assert (info["version"], info["base"]) == (sys.version, sys.base_prefix)
    import numba

    assert info["numba"] == numba.__file__
    assert info["package"] == str(site / "xray_viz" / "__init__.py")
    # The kernel ran right, was compiled (cold), and is cached in <tmp>/xray_viz-numba-65534.
    assert info["rank"] == _expected_rank()
    assert (info["misses"], info["hits"]) == (1, 0)
    root = tmp / f"xray_viz-numba-{NOBODY}"
    assert Path(info["where"]).parent == root and info["where"] == info["where_direct"]
    st = root.stat()
    assert st.st_uid == NOBODY and stat.S_IMODE(st.st_mode) == 0o700
    cached = sorted(p.name for p in Path(info["where"]).iterdir())
    assert any(n.startswith(f"_raster.{SMALL}-") and n.endswith(".nbi") for n in cached)
    assert any(n.startswith(f"_raster.{SMALL}-") and n.endswith(".nbc") for n in cached)
    # One line says where, and why (the install's __pycache__ and the home's cache).
    (line,) = _notices(err)
    assert f"cached in {info['where']}" in line and "NUMBA_CACHE_DIR" in line
    assert str(site / "xray_viz" / "tracing" / "__pycache__") in line and str(home) in line
    # Nothing was written in the install or the home (a second process loading the kernels
    # from there: test_compile_notice_in_the_fallback_location).
    assert (_tree(site), _tree(home)) == before
    # nobody really cannot write either (root could: that is why nobody runs these tests).
    r = run_as_nobody(["/bin/sh", "-c", f"touch {site}/x; a=$?; touch {home}/x; echo $a $?"],
                      env=_env(site, home, tmp), cwd=home, expose=[site, home])
    assert r.stdout.split() == ["1", "1"] and "Permission denied" in r.stderr


def test_unusable_numba_cache_dir_falls_back_and_says_so(world, site):
    home, tmp = _home(world, "home-ncd"), _tmp(world, "tmp-ncd")
    closed = _home(world, "closed")  # exists, but nobody cannot write it
    info, err = _probe(site, home, tmp, NUMBA_CACHE_DIR=str(closed))
    assert info["rank"] == _expected_rank()
    assert Path(info["where"]).parent == tmp / f"xray_viz-numba-{NOBODY}"
    (line,) = _notices(err)
    assert f"NUMBA_CACHE_DIR={closed}" in line and f"cached in {info['where']}" in line
    assert list(closed.iterdir()) == []


@pytest.mark.slow
def test_a_usable_numba_cache_dir_is_used_quietly(world, site):
    home, tmp, ncd = _home(world, "home-ncd2"), _tmp(world, "tmp-ncd2"), _tmp(world, "ncd")
    info, err = _probe(site, home, tmp, NUMBA_CACHE_DIR=str(ncd))
    assert info["rank"] == _expected_rank() and Path(info["where"]).parent == ncd
    assert _notices(err) == [] and list(tmp.iterdir()) == []


def test_no_writable_place_means_no_cache_and_one_line(world, site):
    # The per-user temporary directory exists but belongs to root and is open to all: files in
    # it could be anyone's, so it is refused, and there is nowhere else to write.
    home, tmp = _home(world, "home-none"), _tmp(world, "tmp-none")
    planted = tmp / f"xray_viz-numba-{NOBODY}"
    planted.mkdir()
    planted.chmod(0o777)
    info, err = _probe(site, home, tmp)
    assert info["rank"] == _expected_rank() and info["where"] is None
    assert (info["misses"], info["hits"]) == (1, 0)
    (line,) = _notices(err)
    assert "no writable place" in line and "owned by uid 0" in line and "NUMBA_CACHE_DIR" in line
    assert list(planted.iterdir()) == [] and [p.name for p in tmp.iterdir()] == [planted.name]


@pytest.mark.slow
def test_read_only_install_renders_cold_then_warm(world, site):
    """The whole engine compiled cold as nobody, by the API, then the CLI loads it all."""
    home, tmp = _home(world, "home-cold"), _tmp(world, "tmp-cold")
    env = _env(site, home, tmp)
    code = ("import numpy, sys, xray_viz; "
            "numpy.save(sys.argv[1], xray_viz.render(xray_viz.load_scene('sphere')).intensity)")
    out = _tmp(world, "out-cold")
    r = run_as_nobody([sys.executable, "-c", code, out / "api.npy"], env=env, cwd=home,
                      expose=[site, home, tmp, out])
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    assert len(_notices(r.stderr)) == 1
    r = run_as_nobody([sys.executable, "-m", "xray_viz.cli", "render", "sphere", "-o",
                       out / "cli.npy"], env=env, cwd=home, expose=[site, home, tmp, out])
    assert r.returncode == 0, r.stderr
    # numba's notice, and the data cache's (xray_viz._cache: the read-only home's folder)
    kernels, data = _notices(r.stderr)
    assert "compiling" not in r.stderr and "mesh reports are not cached" in data
    np.testing.assert_array_equal(np.load(out / "api.npy"), np.load(out / "cli.npy"))


# -- the compile notice of the CLI, wherever the cache is ------------------------------------------

@pytest.fixture(scope="module")
def warm():
    """A sphere render in this process, and the cache files of every kernel it used: they
    exist once this process has compiled or loaded the kernels. Asked of numba (each kernel's
    cache object), not guessed."""
    import xray_viz
    from xray_viz.tracing import _numba_cache as C
    from xray_viz.tracing import _raster as R

    image = xray_viz.render(xray_viz.load_scene("sphere"))
    R.KERNELS.kernel("_first_use_rank")    # the probes' kernel: a render orders meshes in NumPy cold
    files = {}
    for name, kernel in vars(R).items():
        cache = getattr(kernel, "_cache", None)
        if isinstance(cache, C.KernelCache) and getattr(kernel, "overloads", None):
            cf = cache._cache_file
            files[name.lstrip("_")] = [Path(cf._index_path),      # the kernel's name
                           *(Path(cf._data_path(n)) for n in cf._load_index().values())]
    assert SMALL in files and RENDERED in files and "raster_direct" in files
    assert all(p.is_file() for paths in files.values() for p in paths)
    return image.intensity, files


def _seed(files, dest: Path, *, skip=(), owner=None):
    """Copy the warm cache files into ``dest`` (the kernels in ``skip`` left out, to be
    compiled), owned by ``owner``."""
    dest.mkdir(parents=True, exist_ok=True)
    # a kernel reached under two names (a thin entry point and its dispatcher) has the same
    # files under both: leave out the files, not only the name
    left_out = {p.name for name in skip for p in files.get(name, ())}
    for name, paths in files.items():
        if name not in skip:
            for p in paths:
                if p.name not in left_out:
                    shutil.copy2(p, dest / p.name)
    if owner is not None:
        for p in [dest, *dest.rglob("*")]:
            os.chown(p, owner, owner)


def _temp_cache_dir(tmp, site):
    """Where numba's cache sub-path scheme puts the kernels of ``site`` under ``tmp``."""
    from numba.core.caching import _CacheLocator

    raster = site / "xray_viz" / "tracing" / "_raster.py"
    return tmp / f"xray_viz-numba-{NOBODY}" / _CacheLocator.get_suitable_cache_subpath(str(raster))


def _cli(out, *, run, **kw):
    r = run([sys.executable, "-m", "xray_viz.cli", "render", "sphere", "-o", out], **kw)
    assert r.returncode == 0 and "Traceback" not in r.stderr, r.stderr
    return r.stderr.splitlines(), np.load(out)


def _run_as_root(argv, *, env, cwd, expose=()):
    return subprocess.run(list(map(str, argv)), env=env, cwd=cwd, capture_output=True,
                          text=True, timeout=600)


def _compiling(lines):
    return [line for line in lines if line.startswith("xray-viz: compiling")]


def test_compile_notice_in_tree(world, warm):
    ref, files = warm
    site = _install(world / "site-rw")  # writable: numba caches beside the module
    pycache = site / "xray_viz" / "tracing" / "__pycache__"
    _seed(files, pycache, skip={RENDERED})
    env = _env(site, _home(world, "home-rw"), _tmp(world, "tmp-rw"))
    lines, image = _cli(world / "rw1.npy", run=_run_as_root, env=env, cwd=world)
    assert _compiling(lines) == [
        f"xray-viz: compiling the fast engine on first use (a few seconds, cached in {pycache} "
        "afterwards)..."]
    assert _notices("\n".join(lines)) == []
    np.testing.assert_array_equal(image, ref)
    lines, image = _cli(world / "rw2.npy", run=_run_as_root, env=env, cwd=world)
    assert _compiling(lines) == [] and _notices("\n".join(lines)) == []
    np.testing.assert_array_equal(image, ref)


def test_compile_notice_in_the_fallback_location(world, site, warm):
    ref, files = warm
    home, tmp, out = _home(world, "home-fb"), _tmp(world, "tmp-fb"), _tmp(world, "out-fb")
    where = _temp_cache_dir(tmp, site)
    where.parent.mkdir(mode=0o700)
    os.chown(where.parent, NOBODY, NOBODY)
    _seed(files, where, skip={RENDERED}, owner=NOBODY)
    kw = dict(env=_env(site, home, tmp), cwd=home, expose=[site, home, tmp, out])
    lines, image = _cli(out / "fb1.npy", run=run_as_nobody, **kw)
    assert _compiling(lines) == [
        f"xray-viz: compiling the fast engine on first use (a few seconds, cached in {where} "
        "afterwards)..."]
    # two notices: numba's kernel cache and the data cache (xray_viz._cache), both of the
    # read-only home, each one line
    line, data = _notices("\n".join(lines))
    assert line.startswith("xray-viz: warning: numba cannot write") and str(where) in line
    assert data.startswith(f"xray-viz: warning: cache folder {home}/.cache/xray_viz/")
    assert "mesh reports are not cached" in data
    np.testing.assert_array_equal(image, ref)
    lines, image = _cli(out / "fb2.npy", run=run_as_nobody, **kw)
    assert _compiling(lines) == [] and len(_notices("\n".join(lines))) == 2
    np.testing.assert_array_equal(image, ref)


@pytest.mark.slow
def test_compile_notice_cold_and_uncached(world, site, warm):
    """Every kernel compiled: in-tree cold then warm, and twice with nowhere to cache."""
    ref, _ = warm
    fresh = _install(world / "site-cold")
    env = _env(fresh, _home(world, "home-c"), _tmp(world, "tmp-c"))
    lines, image = _cli(world / "c1.npy", run=_run_as_root, env=env, cwd=world)
    assert len(_compiling(lines)) == 1
    np.testing.assert_array_equal(image, ref)
    lines, _ = _cli(world / "c2.npy", run=_run_as_root, env=env, cwd=world)
    assert _compiling(lines) == []
    home, tmp, out = _home(world, "home-n"), _tmp(world, "tmp-n"), _tmp(world, "out-n")
    (tmp / f"xray_viz-numba-{NOBODY}").mkdir(mode=0o777)
    kw = dict(env=_env(site, home, tmp), cwd=home, expose=[site, home, tmp, out])
    for k in range(2):
        lines, image = _cli(out / f"n{k}.npy", run=run_as_nobody, **kw)
        assert _compiling(lines) == [
            "xray-viz: compiling the fast engine on first use (a few seconds, not cached: no "
            "writable place)..."]
        np.testing.assert_array_equal(image, ref)


# -- a broken kernel cache ----------------------------------------------------------------------

def _flip(data: bytes, at=None) -> bytes:
    b = bytearray(data)
    b[len(b) // 3 if at is None else at] ^= 0x10  # one bit (in the machine code of an .nbc)
    return bytes(b)


def _flip_stamp(data: bytes) -> bytes:
    """One bit of the index's source stamp (numba's: the SHA-256 of _raster.py) flipped: the
    index then reads as one of another source, which numba itself rebuilds silently."""
    stamp = hashlib.sha256((ROOT / "xray_viz" / "tracing" / "_raster.py").read_bytes()).digest()
    assert data.count(stamp) == 1
    return _flip(data, data.index(stamp) + 5)


#: name -> (file: "nbi" or "nbc", what becomes of its bytes, whether a warning names it)
CORRUPTIONS = {
    "nbi-empty": ("nbi", lambda b: b"", True),
    "nbc-one-bit": ("nbc", _flip, True),
    "nbi-garbage": ("nbi", lambda b: os.urandom(len(b)), True),
    "nbi-half": ("nbi", lambda b: b[:len(b) // 2], True),
    "nbi-other-pickle": ("nbi", lambda b: pickle.dumps({"not": "an index"}), False),
    "nbi-stamp-bit": ("nbi", _flip_stamp, False),
    "nbc-empty": ("nbc", lambda b: b"", True),
    "nbc-garbage": ("nbc", lambda b: os.urandom(len(b)), True),
    "nbc-half": ("nbc", lambda b: b[:len(b) // 2], True),
    "nbc-other-pickle": ("nbc", lambda b: pickle.dumps(("not", "a kernel")), True),
    "nbc-numba-format": ("nbc", lambda b: b[b.index(b"\n") + 1 + 32:], True),  # no header
}
DEFAULT_CORRUPTIONS = ("nbi-empty", "nbc-one-bit")


@pytest.mark.parametrize("kind", [
    k if k in DEFAULT_CORRUPTIONS else pytest.param(k, marks=pytest.mark.slow)
    for k in CORRUPTIONS])
def test_a_corrupt_cache_file_is_rebuilt(world, warm, kind):
    ref, files = warm
    site = _install(world / f"site-{kind}")
    pycache = site / "xray_viz" / "tracing" / "__pycache__"
    _seed(files, pycache)
    suffix, corrupt, named = CORRUPTIONS[kind]
    (victim,) = [pycache / p.name for p in files[RENDERED] if p.suffix == "." + suffix]
    victim.write_bytes(corrupt(victim.read_bytes()))
    env = _env(site, _home(world, f"home-{kind}"), _tmp(world, f"tmp-{kind}"))
    lines, image = _cli(world / f"{kind}.npy", run=_run_as_root, env=env, cwd=world)
    np.testing.assert_array_equal(image, ref)
    assert len(_compiling(lines)) == 1  # that kernel only; the rest came from the cache
    notes = _notices("\n".join(lines))
    if named:
        (line,) = notes
        assert line.startswith(f"xray-viz: warning: kernel cache file {victim} is unusable")
    else:  # numba reads it as the index of another numba version or source: rebuilt quietly
        assert notes == []
    # Rebuilt: the files are whole again (read as the next process would: any fault would
    # warn, and warnings are errors here), and hold the kernel.
    from xray_viz.tracing import _numba_cache as C
    from xray_viz.tracing import _raster as R

    cache = getattr(R, "_" + RENDERED)._cache
    cf = C.CheckedCacheFile(cache_path=str(pycache), filename_base=cache._impl.filename_base,
                            source_stamp=cache._impl.locator.get_source_stamp())
    overloads = cf._load_index()
    assert len(overloads) == 1
    (key,) = overloads
    assert cf.load(key) is not None


# -- the pieces ------------------------------------------------------------------------------------

def test_private_dir_refuses_what_others_could_have_written(tmp_path):
    from xray_viz.tracing._numba_cache import private_dir

    mine = tmp_path / "mine"
    private_dir(str(mine))
    assert stat.S_IMODE(mine.stat().st_mode) == 0o700
    private_dir(str(mine))  # again: fine
    (tmp_path / "open").mkdir()
    (tmp_path / "open").chmod(0o777)
    (tmp_path / "file").write_text("")
    (tmp_path / "link").symlink_to(mine)
    for name, why in [("open", "writable by other users"), ("file", "not a directory"),
                      ("link", "not a directory")]:
        with pytest.raises(PermissionError, match=why):
            private_dir(str(tmp_path / name))
    if os.geteuid() == 0:
        (tmp_path / "theirs").mkdir(mode=0o700)
        os.chown(tmp_path / "theirs", NOBODY, NOBODY)
        with pytest.raises(PermissionError, match=f"owned by uid {NOBODY}"):
            private_dir(str(tmp_path / "theirs"))


def _xray_viz_function(folder: Path):
    """A cached numba function of a (made-up) xray_viz module whose source is in ``folder``:
    it gets the kernel cache, in ``folder/__pycache__``."""
    src = folder / "cache_probe.py"
    src.write_text("from numba import njit\n\n\n@njit(cache=True)\ndef twice(x):\n"
                   "    return 2 * x\n")
    module = types.ModuleType("xray_viz._cache_probe")
    exec(compile(src.read_text(), str(src), "exec"), module.__dict__)
    return module.twice


def test_a_cache_that_cannot_be_written_warns_and_the_kernel_still_runs(tmp_path):
    from xray_viz.tracing._numba_cache import KernelCache, KernelCacheWarning

    twice = _xray_viz_function(tmp_path)
    assert isinstance(twice._cache, KernelCache)
    pycache = tmp_path / "__pycache__"
    assert twice._cache.cache_path == str(pycache) and pycache.is_dir()
    pycache.rmdir()
    pycache.write_text("")  # after numba chose it: no directory there any more
    with pytest.warns(KernelCacheWarning) as record:
        assert twice(21) == 42
    messages = [str(w.message) for w in record]
    assert any(m.startswith(f"cannot write the kernel cache in {pycache}") for m in messages)
    assert all(m.count("\n") == 0 for m in messages)


def test_other_packages_numba_functions_are_left_to_numba():
    from numba import njit
    from numba.core.caching import FunctionCache

    from xray_viz.tracing import _numba_cache as C
    from xray_viz.tracing import _raster as R

    @njit(cache=True)
    def not_ours(x):  # never called: nothing is compiled or written
        return x

    assert type(not_ours._cache) is FunctionCache
    assert isinstance(R._first_use_rank._cache, C.KernelCache)


if __name__ == "__main__":
    _launch(json.loads(sys.argv[1]))

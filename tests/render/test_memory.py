"""Big jobs, predictable memory: banded rendering, lazy per-body path lengths, refusals.

* Rendering by bands of rows gives exactly (bit for bit) the whole-frame results, whatever the
  bands, for every bundled phantom, both beam kinds, both engines, supersampling 1 and 2.
* Per-body path lengths are made only when asked for, and equal the whole-frame ones.
* A job whose output cannot fit is refused up front in one line.
* Peak memory of a render, measured in a fresh subprocess, is O(output + meshes): bounded by
  the estimate of :func:`xray_viz.render.memory_needed` above a trivial render's, and far
  below one (pixels x bodies) float64 array.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

import importlib

import xray_viz
from xray_viz import phantoms
from xray_viz.errors import SceneError, XrayVizError
from xray_viz.geometry import detector_rays
from xray_viz.render import ENGINES, memory_needed, render
from xray_viz.tracing.fast import trace_once, trace_rows

from helpers import make_scene

render_mod = importlib.import_module("xray_viz.render")    # (xray_viz.render is the function)
LINUX = Path("/proc/self/status").exists() and Path("/proc/meminfo").exists()


# ---------------------------------------------------------------------------- scenes


@functools.lru_cache(maxsize=None)
def _phantom(name):
    return xray_viz.load_scene(name)          # scenes are immutable: load each one once


def _shrunk(scene, longest):
    """The scene with its detector resampled to at most ``longest`` pixels a side (same mm),
    and at least 8."""
    det = scene.detector
    w, h = det.shape
    k = max(1, -(-max(w, h) // longest))
    shape = (max(8, w // k), max(8, h // k))
    return scene.replace(detector=det.from_size(det.center, det.up, shape, det.size))


def _beam(scene, kind):
    return scene.replace(source=dataclasses.replace(scene.source, kind=kind))


def _render_with_rows(monkeypatch, scene, rows, **kw):
    """render() with bands of ``rows`` image rows (``None``: the whole frame at once)."""
    monkeypatch.setattr(render_mod, "_band_rows", lambda *a: 10**9 if rows is None else rows)
    return render(scene, **kw)


def _assert_same(a, b):
    for name in ("intensity", "line_integral", "total_path_length", "path_length"):
        x, y = getattr(a, name), getattr(b, name)
        assert x.shape == y.shape and x.dtype == y.dtype == np.float64, name
        assert np.array_equal(x, y), name


def _phantom_cases(fast_px, numpy_px):
    for name in phantoms.names():
        for kind in ("point", "parallel"):
            for engine, px in (("fast", fast_px), ("numpy", numpy_px)):
                for n in (1, 2):
                    yield pytest.param(name, kind, engine, px, n, id=f"{name}-{kind}-{engine}-{n}")


# ---------------------------------------------------------------------------- bands are exact


@pytest.mark.parametrize("name,kind,engine,px,n", list(_phantom_cases(64, 16)))
def test_bands_give_the_whole_frame_bit_for_bit(monkeypatch, name, kind, engine, px, n):
    """Bands of 1 and 3 rows against the whole frame at once (phantoms at <= 64 pixels a side;
    the NumPy engine at <= 16, in bands of 3 rows)."""
    scene = _shrunk(_beam(_phantom(name), kind), px)
    whole = _render_with_rows(monkeypatch, scene, None, engine=engine, supersample=n,
                              path_lengths=True)
    assert whole.total_path_length.max() > 0
    h = scene.detector.shape[1]
    for rows in ((1, 3) if engine == "fast" else (3,)):
        banded = _render_with_rows(monkeypatch, scene, rows, engine=engine, supersample=n,
                                   path_lengths=True)
        _assert_same(banded, whole)
        assert rows < h


@pytest.mark.slow
@pytest.mark.parametrize("name,kind,engine,px,n", list(_phantom_cases(10**6, 96)))
def test_bands_give_the_whole_frame_bit_for_bit_full_size(monkeypatch, name, kind, engine, px,
                                                          n):
    """The bundled phantoms at their own shapes (the NumPy engine at <= 96 pixels a side)."""
    scene = _shrunk(_beam(_phantom(name), kind), px)
    whole = _render_with_rows(monkeypatch, scene, None, engine=engine, supersample=n,
                              path_lengths=True)
    for rows in (1, 37):
        banded = _render_with_rows(monkeypatch, scene, rows, engine=engine, supersample=n,
                                   path_lengths=True)
        _assert_same(banded, whole)


def _ball(r=20.0, at=(0.0, 0.0, 0.0), sub=2):
    m = trimesh.creation.icosphere(subdivisions=sub, radius=r)
    m.apply_translation(at)
    return m


@pytest.mark.parametrize("kind", ["point", "parallel"])
@pytest.mark.parametrize("n", [1, 3])
def test_trace_rows_windows_tile_the_detector(kind, n, monkeypatch):
    """Windows are whole pixel rows from the top down, and together are trace_once exactly:
    several bodies (sorted hits), one body (signed sums: per-thread and banded), none in the
    beam, and no body at all."""
    import xray_viz.tracing.fast as fast

    multi = make_scene([_ball(), _ball(10, (25, 5, 0))], kind=kind, shape=(41, 29), pitch=2.0)
    one = make_scene([_ball(), _ball(5, (0, 0, 5000))], kind=kind, shape=(41, 29), pitch=2.0)
    away = make_scene([_ball(5, (0, 0, 5000))], kind=kind, shape=(41, 29), pitch=2.0)
    empty = multi.replace(bodies=())
    for direct in (True, False):
        if not direct:
            monkeypatch.setattr(fast, "_DIRECT_MAX_SAMPLES", 0)
        for scene in (multi, one, away, empty):
            whole = trace_once(scene, supersample=n)
            assert whole.shape == (41 * 29 * n * n, len(scene.bodies))
            for rows in (1, 4, 28, 29, 1000):
                parts = list(trace_rows(scene, supersample=n, rows=rows))
                starts = [r0 for r0, _, _ in parts]
                assert starts[0] == 0 and parts[-1][1] == 29
                assert all(a[1] == b[0] for a, b in zip(parts, parts[1:]))
                assert all(0 < r1 - r0 <= rows for r0, r1, _ in parts)
                for r0, r1, L in parts:
                    assert L.shape == ((r1 - r0) * 41 * n * n, len(scene.bodies))
                glued = np.concatenate([L for *_, L in parts])
                assert np.array_equal(glued, whole)
            assert whole.max(initial=0) > 0 or scene is away or scene is empty


def test_trace_rows_memory_is_one_window():
    """Each window's array holds only that window's rays."""
    scene = make_scene([_ball(), _ball(10, (25, 5, 0))], shape=(64, 48), pitch=1.5)
    sizes = {L.shape[0] for *_, L in trace_rows(scene, rows=8)}
    assert max(sizes) <= 8 * 64


@pytest.mark.parametrize("kind", ["point", "parallel"])
@pytest.mark.parametrize("n", [1, 3])
def test_detector_rays_rows_are_the_rows_of_the_whole_grid(kind, n):
    scene = _beam(_phantom("limb"), kind)
    scene = _shrunk(scene, 40)
    w, h = scene.detector.shape
    whole = detector_rays(scene, supersample=n)
    per_row = w * n * n
    for rows in [(0, h), (0, 1), (3, 7), (h - 1, h), range(2, 5), slice(4, 9), (5, 5)]:
        part = detector_rays(scene, supersample=n, rows=rows)
        r = range(h)[rows] if isinstance(rows, slice) else range(*rows) if isinstance(
            rows, tuple) else rows
        sl = slice(r.start * per_row, r.stop * per_row)
        for a in ("origins", "directions", "t_max"):
            assert np.array_equal(getattr(part, a), getattr(whole, a)[sl]), (rows, a)
        assert part.shape == whole.shape == (w, h)
    for bad in [(0, h + 1), (-1, 2), (5, 3), slice(0, 4, 2), range(0, 4, 2)]:
        with pytest.raises(ValueError, match="rows"):
            detector_rays(scene, rows=bad)


# ---------------------------------------------------------------------------- path lengths


def test_per_body_path_lengths_only_when_asked():
    scene = _phantom("limb")                                  # 6 bodies
    w, h = scene.detector.shape
    nb = len(scene.bodies)
    image = render(scene)
    held = [v for v in vars(image).values() if isinstance(v, np.ndarray)]
    assert all(a.size < w * h * nb for a in held)            # no pixels x bodies array
    assert image.total_path_length.shape == (h, w) and image.total_path_length.max() > 50
    # On first access: traced again, the same numbers as asked for up front, and kept.
    asked = render(scene, path_lengths=True)
    lazy = image.path_length
    assert lazy.shape == (h, w, nb) and lazy is image.path_length
    assert np.array_equal(lazy, asked.path_length)
    # ... and the whole-frame formula on the engine's path lengths, and the total their sum.
    L, _ = ENGINES["fast"](scene, supersample=1, keep_hits=False)
    assert np.array_equal(lazy, L.reshape(h, w, nb))
    assert np.array_equal(image.total_path_length, lazy.sum(axis=2))
    assert np.array_equal(asked.intensity, image.intensity)


@pytest.mark.parametrize("engine", ["fast", "numpy"])
def test_lazy_path_lengths_use_the_same_engine_and_supersampling(engine):
    scene = _shrunk(_phantom("nested_spheres"), 24)
    image = render(scene, engine=engine, supersample=2)
    assert image.supersample == 2 and image.engine == engine
    L, _ = ENGINES[engine](scene, supersample=2, keep_hits=False)
    w, h = scene.detector.shape
    want = L.reshape(h * w, 4, -1).mean(axis=1).reshape(h, w, -1)
    assert np.array_equal(image.path_length, want)
    assert np.array_equal(image.total_path_length, want.sum(axis=2))


def test_keep_hits_still_returns_every_hit():
    scene = _shrunk(_phantom("sphere"), 16)
    image = render(scene, engine="numpy", keep_hits=True)
    assert len(image.hits) > 0 and image.hits.ray.max() < 16 * 16
    assert np.array_equal(image.path_length, render(scene, engine="numpy").path_length)


# ---------------------------------------------------------------------------- refusals


@pytest.mark.parametrize("bad", [2.7, 2.0, np.float64(2.0), "2", True, np.bool_(True), 0, -1])
def test_supersample_must_be_a_whole_number(bad):
    scene = _shrunk(_phantom("sphere"), 8)
    from xray_viz.tracing.fast import fast_path_lengths

    for call in (lambda: render(scene, supersample=bad),
                 lambda: fast_path_lengths(scene, supersample=bad, cache=False),
                 lambda: detector_rays(scene, supersample=bad)):
        with pytest.raises(SceneError, match="supersample must be a whole number") as info:
            call()
        assert isinstance(info.value, ValueError) and "\n" not in str(info.value)


def test_numpy_integers_are_whole_numbers():
    scene = _shrunk(_phantom("sphere"), 8)
    a = render(scene, supersample=np.int64(2))
    b = render(scene, supersample=2)
    assert a.supersample == 2 and type(a.supersample) is int
    assert np.array_equal(a.intensity, b.intensity)


def test_unknown_engine_is_an_xray_viz_error():
    scene = _shrunk(_phantom("sphere"), 8)
    for engine in ("nope", None, 3):
        with pytest.raises(XrayVizError, match="unknown engine") as info:
            render(scene, engine=engine)
        assert isinstance(info.value, ValueError)


def _huge(scene, shape):
    det = scene.detector
    return scene.replace(detector=det.from_size(det.center, det.up, shape, det.size))


def test_output_that_cannot_fit_is_refused_in_one_line(monkeypatch):
    scene = _phantom("sphere")
    monkeypatch.setattr(render_mod, "available_memory", lambda: 3 << 30)
    big = _huge(scene, (20000, 20000))
    need = memory_needed(big)
    assert need["images"] == 20000 * 20000 * 48 and need["path_lengths"] == 0
    with pytest.raises(SceneError) as info:
        render(big)
    msg = str(info.value)
    assert "\n" not in msg and isinstance(info.value, ValueError)
    assert msg.startswith("[detector] shape 20000 x 20000 needs about 18 GiB for the output "
                          "images (this machine has 3.0 GiB available): use a smaller shape")
    # What fits is rendered; asking for per-body path lengths counts them too.
    fine = _huge(scene, (64, 64))
    assert render(fine).intensity.shape == (64, 64)
    enough = memory_needed(fine)["total"] + 64 * 64 * 8 // 2
    monkeypatch.setattr(render_mod, "available_memory", lambda: enough)
    assert render(fine).intensity.shape == (64, 64)
    with pytest.raises(SceneError, match="for the output images and the path lengths of 1 "
                                         "body .this machine has"):
        render(fine, path_lengths=True)
    # Where the memory is unknown, no check.
    monkeypatch.setattr(render_mod, "available_memory", lambda: None)
    assert render(fine).intensity.shape == (64, 64)


def test_lazy_path_lengths_that_cannot_fit_are_refused(monkeypatch):
    scene = _shrunk(_phantom("limb"), 64)
    image = render(scene)
    w, h = scene.detector.shape
    nb = len(scene.bodies)
    need = memory_needed(scene, path_lengths=True, images=False)
    assert need["path_lengths"] == w * h * nb * 8 and need["images"] == 0
    monkeypatch.setattr(render_mod, "available_memory", lambda: need["total"] - 1)
    with pytest.raises(SceneError, match=f"for the path lengths of {nb} bodies .* use a smaller "
                                         "shape, or do without the per-body path lengths"):
        image.path_length
    monkeypatch.setattr(render_mod, "available_memory", lambda: need["total"])
    assert image.path_length.shape == (h, w, nb)


@pytest.mark.skipif(not LINUX, reason="MemAvailable is read from /proc/meminfo")
def test_available_memory_reads_meminfo():
    avail = render_mod.available_memory()
    total = next(int(l.split()[1]) for l in Path("/proc/meminfo").read_text().splitlines()
                 if l.startswith("MemTotal"))
    assert 0 < avail <= total * 1024


def test_cli_refuses_a_shape_too_big_for_this_machine(tmp_path):
    """``shape = [200000, 200000]``: one line, exit 2, nothing written, no allocation."""
    text = phantoms.scene_path("sphere").read_text()
    src = phantoms.scene_path("sphere").parent
    text = text.replace('mesh = "', f'mesh = "{src.as_posix()}/')
    lines = [("shape = [200000, 200000]" if l.startswith("shape") else l)
             for l in text.splitlines()]
    scene = tmp_path / "big.toml"
    scene.write_text("\n".join(lines) + "\n")
    out = tmp_path / "x.tiff"
    res = subprocess.run([sys.executable, "-m", "xray_viz.cli", "render", str(scene), "-o",
                          str(out)], capture_output=True, text=True, timeout=300)
    assert res.returncode == 2, res.stderr
    # (A cold numba cache adds a "compiling the fast engine" notice before the render.)
    err = [l for l in res.stderr.strip().splitlines() if "compiling the fast engine" not in l]
    assert len(err) == 1 and "Traceback" not in res.stderr
    assert err[0].startswith("xray-viz: error: [detector] shape 200000 x 200000 needs about ")
    assert "TiB for the output images (this machine has" in err[0]
    assert err[0].endswith("available): use a smaller shape")
    assert not out.exists() and list(tmp_path.iterdir()) == [scene]


# ---------------------------------------------------------------------------- peak memory

#: A child process: build a job's scene, render it to a file, print its peak RSS (VmHWM).
CHILD = textwrap.dedent(r'''
    import json, sys
    spec = json.loads(sys.argv[1])
    import numpy as np
    import xray_viz
    if spec["kind"] == "file":
        from xray_viz.cli import main
        rc = main(["render", spec["scene"], "-o", spec["out"]])
        assert rc == 0, rc
    else:
        import trimesh
        from xray_viz.output import save_image
        from xray_viz.scene import Body, Detector, Scene, Source
        n, k, shape = spec["bodies"], int(np.ceil(np.sqrt(spec["bodies"]))), spec["shape"]
        pitch = 100.0 / k
        bodies = []
        for b in range(n):
            m = trimesh.creation.icosphere(subdivisions=1, radius=0.35 * pitch)
            m.apply_translation([(b % k - (k - 1) / 2) * pitch, (b // k - (k - 1) / 2) * pitch, 0])
            bodies.append(Body(name=f"ball{b}", mesh=m, mu=0.2))
        det = Detector.from_size([0, 0, -100.0], [0, 1, 0], (shape, shape), (120.0, 120.0))
        scene = Scene(Source(position=[0, 0, 1000.0], energy=60.0), det, tuple(bodies))
        # Disjoint balls: no body inside another, so the precedence is the list order.
        assert scene.bodies.precedence.tolist() == list(range(n))
        image = xray_viz.render(scene)
        save_image(spec["out"], image.intensity)
        assert image.total_path_length.max() > 0
    hwm = next(int(l.split()[1]) * 1024 for l in open("/proc/self/status")
               if l.startswith("VmHWM:"))
    from xray_viz.render import memory_needed
    need = None if spec["kind"] == "file" else memory_needed(scene)
    print(json.dumps({"peak": hwm, "need": need}))
''')


def _run_child(spec, tmp_path):
    res = subprocess.run([sys.executable, "-c", CHILD, json.dumps(spec)], capture_output=True,
                         text=True, timeout=3600, cwd=tmp_path)
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout.strip().splitlines()[-1])


def _peak(spec, tmp_path):
    return _run_child(spec, tmp_path)["peak"]


def _frog_file(tmp_path, shape):
    """The frog phantom's scene at ``shape x shape`` pixels over the same detector size."""
    src = phantoms.scene_path("frog")
    lines = []
    for line in src.read_text().splitlines():
        key = line.split("=")[0].strip()
        if key == "shape":
            line = f"shape = [{shape}, {shape}]"
        elif key == "pitch":
            line = f"pitch = {0.274 * 511 / (shape - 1)!r}"
        elif key == "mesh":
            line = f'mesh = "{src.parent.as_posix()}/{line.split("=", 1)[1].strip()[1:-1]}"'
        lines.append(line)
    path = tmp_path / f"frog{shape}.toml"
    path.write_text("\n".join(lines) + "\n")
    return path


@pytest.fixture(scope="module")
def baseline(tmp_path_factory):
    """Peak RSS of a trivial job: a 16 x 16 render of one ball (interpreter, libraries,
    compiled kernels)."""
    tmp = tmp_path_factory.mktemp("baseline")
    return _peak({"kind": "balls", "bodies": 1, "shape": 16, "out": str(tmp / "b.tiff")}, tmp)


def _check_frog(tmp_path, baseline, shape, limit=None):
    scene_file = _frog_file(tmp_path, shape)
    out = tmp_path / "frog.tiff"
    peak = _peak({"kind": "file", "scene": str(scene_file), "out": str(out)}, tmp_path)
    scene = _huge(_phantom("frog"), (shape, shape))         # the same meshes and shape
    with Image.open(out) as im:
        assert im.size == (shape, shape)
    pixels, nb = shape * shape, len(scene.bodies)
    need = memory_needed(scene)
    above = peak - baseline
    print(f"frog {shape}^2: peak {peak / 2**20:.0f} MiB, baseline {baseline / 2**20:.0f} MiB, "
          f"{above / pixels:.1f} bytes/pixel above it; estimate {need['total'] / 2**20:.0f} MiB")
    assert above <= need["total"]                            # the estimate is an upper bound
    assert need["images"] <= 64 * pixels                     # ... and O(output)
    assert above < pixels * nb * 8                           # not one pixels x bodies array
    if limit is not None:
        assert peak < limit
    return peak


@pytest.mark.skipif(not LINUX, reason="peak RSS is read from /proc/self/status")
def test_frog_2048_peak_memory_is_o_output(tmp_path, baseline):
    _check_frog(tmp_path, baseline, 2048)


@pytest.mark.slow
@pytest.mark.skipif(not LINUX, reason="peak RSS is read from /proc/self/status")
def test_frog_8192_to_tiff_under_3_gib(tmp_path, baseline):
    _check_frog(tmp_path, baseline, 8192, limit=3 << 30)


def _check_balls(tmp_path, baseline, n, shape):
    out = tmp_path / "balls.tiff"
    res = _run_child({"kind": "balls", "bodies": n, "shape": shape, "out": str(out)}, tmp_path)
    peak, need = res["peak"], res["need"]
    pixels = shape * shape
    with Image.open(out) as im:
        assert im.size == (shape, shape)
    above = peak - baseline
    print(f"{n} balls {shape}^2: peak {peak / 2**20:.0f} MiB, baseline "
          f"{baseline / 2**20:.0f} MiB, above it {above / 2**20:.0f} MiB; estimate "
          f"{need['total'] / 2**20:.0f} MiB")
    assert above <= need["total"]                            # the estimate is an upper bound
    assert need["images"] <= 64 * pixels and need["bands"] <= 4 * render_mod.BAND_BYTES
    assert above < pixels * n * 8 / 4                        # a quarter of pixels x bodies


@pytest.mark.skipif(not LINUX, reason="peak RSS is read from /proc/self/status")
def test_1000_bodies_512_peak_memory_is_bounded(tmp_path, baseline):
    _check_balls(tmp_path, baseline, 1000, 512)


@pytest.mark.slow
@pytest.mark.skipif(not LINUX, reason="peak RSS is read from /proc/self/status")
def test_1000_bodies_1024_succeeds(tmp_path, baseline):
    _check_balls(tmp_path, baseline, 1000, 1024)

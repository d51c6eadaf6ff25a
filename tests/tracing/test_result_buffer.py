"""The fast engine hands a dropped result's memory to the next frame on the same bodies (issue
18: the first touch of a fresh 33 MB result was ~4 ms of the frog's frame), so its kernels
write every ray: a reused buffer left full of NaN must give the same bits as a new one, and
a result anyone still holds (the caller, a view of it, the result cache) is never written."""

import dataclasses
import weakref

import numpy as np
import pytest

import xray_viz
from xray_viz.tracing import fast
from xray_viz.tracing.fast import fast_path_lengths, trace_once, trace_rows

#: Scene, supersampling, and whether the one body is forced onto the banded path.
CASES = [("nested_spheres", 1, False), ("nested_spheres", 2, False), ("sphere", 1, False),
         ("sphere", 2, False), ("sphere", 1, True), ("frog", 1, False)]


def _moved(scene, dx, dy=0.0):
    src = scene.source
    return scene.replace(source=dataclasses.replace(
        src, position=np.asarray(src.position, float) + np.array([dx, dy, 0.0])))


def _small(name):
    """The scene on a 96 x 80 detector of the same width and height (rays that miss every
    body included)."""
    scene = xray_viz.load_scene(name)
    d = scene.detector
    (W, H), (pu, pv) = d.shape, d.pitch
    return scene.replace(detector=dataclasses.replace(d, shape=(96, 80),
                                                      pitch=(pu * W / 96, pv * H / 80)))


@pytest.mark.parametrize("name,n,banded", CASES)
def test_a_dropped_result_is_reused_and_every_ray_written_again(name, n, banded, monkeypatch):
    if banded:
        monkeypatch.setattr(fast, "_DIRECT_MAX_SAMPLES", 0)
    scene = _small(name)
    a, b = _moved(scene, 4.0, 2.5), _moved(scene, -3.0)
    L = trace_once(a, supersample=n)
    address = L.ctypes.data
    L.fill(np.nan)                    # whatever the dropped result held must not show
    del L
    got = trace_once(b, supersample=n)
    assert got.ctypes.data == address                     # the same memory, handed on
    want = trace_once(b, supersample=n)                   # `got` is held: a new array
    assert not np.shares_memory(got, want)
    assert np.isfinite(got).all()
    assert np.array_equal(got, want)
    assert got.max() > 0 and (got == 0).any()        # rays that hit and rays that miss
    assert not np.array_equal(got, trace_once(a, supersample=n))


@pytest.mark.parametrize("name", ["nested_spheres", "sphere"])
def test_a_result_or_a_view_still_held_is_never_written(name):
    scene = _small(name)
    first = trace_once(scene)
    kept = first.copy()
    second = trace_once(_moved(scene, 5.0))
    assert not np.shares_memory(first, second)
    assert np.array_equal(first, kept)
    view = first[:, 0]
    del first                         # only a view of it is left: still not free
    third = trace_once(_moved(scene, -5.0))
    assert not np.shares_memory(view, third)
    assert np.array_equal(view, kept[:, 0])


def test_a_cached_result_is_never_written():
    scene = _small("nested_spheres")
    fast.clear_caches(scene)
    before = fast_path_lengths(scene)[0].copy()         # the cache keeps the only reference
    other = trace_once(_moved(scene, 6.0))
    cached = fast_path_lengths(scene)[0]
    assert not cached.flags.writeable
    assert not np.shares_memory(cached, other)
    assert np.array_equal(cached, before)


@pytest.mark.parametrize("name", ["nested_spheres", "sphere"])
def test_windows_dropped_one_by_one_give_the_whole_trace(name):
    scene = _small(name)
    whole = trace_once(scene)
    parts = []
    for r0, r1, L in trace_rows(scene, rows=17):
        parts.append(L.copy())
        L.fill(np.nan)                # the next window may be given this memory
    assert np.array_equal(np.concatenate(parts), whole)


def test_results_above_the_bound_are_not_kept(monkeypatch):
    monkeypatch.setattr(fast, "_RESULT_ENTRY_BYTES", 1024)
    scene = _small("nested_spheres")
    fast.clear_caches(scene)
    L = trace_once(scene)
    nb = len(scene.bodies)
    assert scene.bodies.lookup(("fast", "result buffer", len(L), nb)) is None
    assert np.array_equal(L, trace_once(scene))


def test_results_pushed_out_of_the_cache_are_reused_but_never_while_held():
    """A render loop through the result cache: each frame's result pushes an older one out,
    whose memory a later frame is given (the same bits as traced afresh); a result the caller
    still holds is never given."""
    name = "nested_spheres"
    scene = _small(name)
    fast.clear_caches(scene)
    shifts = [0.7 * i for i in range(10)]
    fresh = _small(name)                      # other bodies: their own caches and buffers
    want = [trace_once(_moved(fresh, dx)).copy() for dx in shifts]
    held = fast_path_lengths(_moved(scene, shifts[0]))[0]
    earlier = []                              # weak: a freed result's object cannot come back
    reused = 0
    for dx, ref in zip(shifts[1:], want[1:]):
        got = fast_path_lengths(_moved(scene, dx))[0]
        reused += any(r() is got for r in earlier)
        earlier.append(weakref.ref(got))
        assert not np.shares_memory(got, held)
        assert np.array_equal(got, ref)
        del got
    assert reused >= 3                        # 9 frames through a cache of 4 results
    assert np.array_equal(held, want[0])


def test_threads_sharing_bodies_never_get_a_result_someone_holds():
    """Two threads in render loops on the same bodies (frames through the result cache and
    without it), each keeping every other result: none of those is ever written again."""
    import threading

    scene = _small("nested_spheres")
    fast.clear_caches(scene)
    kept, errors = [], []

    def loop(sign):
        try:
            for i in range(8):
                s = _moved(scene, sign * 0.9 * i)
                L = fast_path_lengths(s)[0] if i % 2 else trace_once(s)
                if i % 3 == 0:
                    kept.append((L, L.copy()))
        except Exception as e:            # pragma: no cover - reported below
            errors.append(e)

    threads = [threading.Thread(target=loop, args=(sg,)) for sg in (1.0, -1.0)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors
    assert len(kept) == 6
    for L, copy in kept:
        assert np.array_equal(L, copy)

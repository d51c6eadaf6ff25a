"""The up-front memory check counts the scatter (issue 39): ``memory_needed(scene,
scatter=)``'s ``scatter`` part bounds what a render with scatter allocates beyond the
primary render (measured with tracemalloc), and a render or a scan whose scatter cannot fit
is refused in one line before any work, where the primary alone would fit."""

from __future__ import annotations

import importlib
import tracemalloc
import warnings

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz import errors
from xray_viz.errors import SceneError
from xray_viz.orbit import Orbit
from xray_viz.render import memory_needed
from xray_viz.scene import Body, Detector, Scene, Source

render_mod = importlib.import_module("xray_viz.render")    # (xray_viz.render is the function)


def _cylinder(shape=(96, 64), pitch=4.0):
    """A 20 cm water cylinder along y, 60 keV, a point source at 600 mm, SID 1000 mm."""
    cyl = trimesh.creation.cylinder(radius=100.0, height=300.0, sections=64)
    cyl.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    return Scene(source=Source(position=[0, 0, 600], energy=60.0),
                 detector=Detector(center=[0, 0, -400], shape=shape, pitch=(pitch, pitch)),
                 bodies=(Body(name="water", mesh=cyl, material="Water, Liquid"),))


def test_memory_needed_counts_the_scatter_part_and_its_total():
    scene = _cylinder()
    w, h = scene.detector.shape
    plain = memory_needed(scene)
    assert plain["scatter"] == 0 and memory_needed(scene, scatter="none")["scatter"] == 0
    for mode in ("kernel", "mc"):
        need = memory_needed(scene, scatter=mode)
        assert need["scatter"] > 0 and need["scatter"] % (w * h) == 0    # per pixel
        assert need["total"] == plain["total"] + need["scatter"]
        assert {k: v for k, v in need.items() if k not in ("scatter", "total")} == \
            {k: v for k, v in plain.items() if k not in ("scatter", "total")}
    # the Monte Carlo's tallies weigh more than the kernel model's work
    assert memory_needed(scene, scatter="mc")["scatter"] > \
        memory_needed(scene, scatter="kernel")["scatter"]


@pytest.mark.parametrize("mode, kwargs, grid", [("kernel", {}, False), ("kernel", {}, True),
                                              ("mc", {"histories": 40_000}, False)])
def test_the_scatter_estimate_bounds_what_a_render_allocates(monkeypatch, mode, kwargs, grid):
    """320 x 256 pixels: the kernel model's coarse grid has 5 x 5 pixels a cell there, its
    worst case (no pre-averaging: it works on every pixel); behind a grid, its off-focus
    cut-off too. The Monte Carlo on 2 threads (the estimate counts a batch's tallies per
    thread), with histories for 3 batches: both threads busy, whatever this machine's
    cores."""
    import dataclasses

    from xray_viz import _threads
    from xray_viz.physics.grid import Grid

    monkeypatch.setattr(_threads, "count", lambda: 2)
    scene = _cylinder((320, 256), 1.0)
    if grid:
        scene = scene.replace(detector=dataclasses.replace(scene.detector, grid=Grid()))
    w, h = scene.detector.shape
    xray_viz.render(scene, scatter=mode, **kwargs)            # compiled, tables cached
    peaks = {}
    for key, extra in ((None, {}), (mode, kwargs)):
        tracemalloc.start()
        try:
            image = xray_viz.render(scene, scatter=key, **extra)
            peaks[key] = tracemalloc.get_traced_memory()[1]
        finally:
            tracemalloc.stop()
        del image
    measured = peaks[mode] - peaks[None]
    estimate = memory_needed(scene, scatter=mode)["scatter"]
    # an upper bound, and not a loose one: the scatter costs at least 3 (H, W) float64 arrays
    assert 24 * w * h < measured <= estimate < 2 * measured


@pytest.mark.parametrize("mode, kwargs", [("kernel", {}), ("mc", {"histories": 1_000})])
def test_a_render_or_scan_whose_scatter_cannot_fit_is_refused_in_one_line(monkeypatch, mode,
                                                                         kwargs):
    scene = _cylinder()
    need = memory_needed(scene, scatter=mode)
    enough_for_primary = memory_needed(scene)["total"]
    assert enough_for_primary < need["total"]
    monkeypatch.setattr(render_mod, "available_memory", lambda: enough_for_primary)
    assert xray_viz.render(scene).intensity.shape == (64, 96)        # the primary fits
    with pytest.raises(SceneError) as info:
        xray_viz.render(scene, scatter=mode, **kwargs)
    msg = str(info.value)
    assert "\n" not in msg and isinstance(info.value, ValueError)
    assert f"for the output images and the scatter ({mode})" in msg
    assert "use a smaller shape" in msg
    # a scan checks it once, before its first projection
    calls = []
    monkeypatch.setattr(render_mod, "_image", lambda *a, **k: calls.append(1))
    with pytest.raises(SceneError, match=rf"the scatter \({mode}\)"):
        xray_viz.scan(scene, Orbit(projections=3, axis=[0, 1, 0]), scatter=mode, **kwargs)
    assert calls == []
    monkeypatch.undo()
    # with enough memory for the scatter too, both run
    monkeypatch.setattr(render_mod, "available_memory", lambda: need["total"])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", errors.ScatterModelWarning)
        image = xray_viz.render(scene, scatter=mode, **kwargs)
        stack = xray_viz.scan(scene, Orbit(projections=2, axis=[0, 1, 0]), scatter=mode,
                              **kwargs).projections
    assert image.scatter.shape == (64, 96) and stack.shape == (2, 64, 96)

"""Error-budgeted level of detail (xray_viz.lod, ``render(scene, max_error=...)``): the image
error measured against the full-resolution render stays within the budget, the chosen meshes
are cheaper, the decimations are cached on disk, and ``max_error=None`` changes nothing."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz import lod, phantoms
from xray_viz.cli import main
from xray_viz.errors import SceneError

BUDGETS = (0.05, 0.2)


def _small(name, size=96):
    """A bundled phantom on a detector of about ``size`` pixels across (same field of view)."""
    scene = xray_viz.load_scene(name)
    w, h = scene.detector.shape
    f = size / max(w, h)
    det = dataclasses.replace(scene.detector, shape=(max(8, round(w * f)), max(8, round(h * f))),
                              pitch=tuple(p / f for p in scene.detector.pitch))
    return scene.replace(detector=det)


def _check_budget(scene, budget, **options):
    full = xray_viz.render(scene)
    if options:
        reduced, report = lod.level_of_detail(scene, budget, **options)
        image = dataclasses.replace(xray_viz.render(reduced), lod=report)
    else:
        image = xray_viz.render(scene, max_error=budget)
    err = float(np.abs(image.line_integral - full.line_integral).max())
    assert err <= budget, (scene.path, budget, err, image.lod)
    assert image.lod.estimated_error <= budget
    assert image.lod.faces <= image.lod.faces_full
    assert image.body_names == full.body_names
    return image, err


@pytest.mark.parametrize("name, budget", [
    ("nested_spheres", 0.2), pytest.param("nested_spheres", 0.05, marks=pytest.mark.slow),
    ("step_wedge", 0.05), ("step_wedge", 0.2)])
def test_measured_error_within_budget_default_sample(name, budget):
    # (the sphere at both budgets: test_a_loose_budget_is_cheaper...; the frog:
    # test_frog_organs_within_budget, all 16 bodies behind slow)
    _check_budget(_small(name, 64), budget)


def _frog_organs(names=("heart", "spleen")):
    """Some of the frog's smaller organs (overlapping footprints; 4,000 and 1,500 faces)."""
    from xray_viz.bodies import Bodies

    scene = _small("frog", 32)
    keep = [b for b in scene.bodies if b.name in names]
    assert len(keep) == len(names)
    return scene.replace(bodies=Bodies(keep, check=False))


@pytest.mark.parametrize("spend", [True, pytest.param(False, marks=pytest.mark.slow)])
def test_frog_organs_within_budget(spend):
    """Overlapping bodies of unequal shares, both allocations (the equal shares alone in
    test_overlapping_bodies_share_the_budget)."""
    scene = _frog_organs()
    image, _ = _check_budget(scene, 0.2, spend_leftover=spend)
    assert all(b.share < 0.2 for b in image.lod.bodies)          # they do overlap
    bound = "allowance" if spend else "share"
    assert all(b.estimated_error <= getattr(b, bound) for b in image.lod.bodies)


@pytest.mark.slow
@pytest.mark.parametrize("budget", BUDGETS)
@pytest.mark.parametrize("name", phantoms.names())
def test_measured_error_within_budget_every_phantom(name, budget):
    _check_budget(_small(name, 128), budget)


@pytest.mark.slow
def test_frog_within_budget_and_reduced():
    """16 nested and overlapping bodies (up to 10 footprints on one ray): within the budget
    with equal shares and with the leftover spent, and reduced either way; spending the
    leftover is not coarser than the budget allows and not finer than the equal shares."""
    scene = _small("frog", 32)
    equal, _ = _check_budget(scene, 0.2, spend_leftover=False)
    spent, err = _check_budget(scene, 0.2)
    assert equal.lod.faces < equal.lod.faces_full
    assert spent.lod.faces <= equal.lod.faces
    assert all(b.estimated_error <= b.share for b in equal.lod.bodies)
    assert all(b.estimated_error <= b.allowance for b in spent.lod.bodies)


def test_traced_footprints_are_tighter_than_boxes_and_cover_the_rays():
    """A sphere beside a box in its bounding box's corner region: the boxes overlap, the
    footprints do not, so neither shares; every ray of the full render that meets a body lies
    in that body's traced footprint."""
    from xray_viz.bodies import Bodies
    from xray_viz.scene import Body

    scene = _small("sphere", 64)
    ball = trimesh.creation.icosphere(subdivisions=3, radius=20.0)
    cube = trimesh.creation.box(extents=[8.0, 8.0, 8.0])
    cube.apply_translation([23.0, 23.0, 0.0])          # its corner in the ball's box, not the ball
    two = scene.replace(bodies=Bodies([Body(name="ball", mesh=ball, mu=0.02),
                                       Body(name="cube", mesh=cube, mu=0.02)]))
    boxes = lod._boxes(two)
    assert boxes[0][0] < boxes[1][1] and boxes[1][0] < boxes[0][1]    # the boxes do overlap
    assert boxes[0][2] < boxes[1][3] and boxes[1][2] < boxes[0][3]
    foot = lod._footprints(two, boxes)
    assert lod._sharing(foot) == [1, 1]
    L = xray_viz.render(two, path_lengths=True).path_length      # (H, W, 2); 64 px: s = 1
    assert foot.shape[1:] == L.shape[:2]
    for b in range(2):
        assert np.all(foot[b][L[..., b] > 0])
    # a box narrower than THIN coarse pixels is taken whole
    tiny = lod._box_mask((10, 12, 40, 41), 1, (64, 64), (64, 64))
    assert tiny[64 - 1 - 40, 11] and tiny.sum() >= 2 * 1


def test_a_loose_budget_is_cheaper_and_a_tighter_one_is_not_looser():
    scene = _small("sphere", 64)
    loose, _ = _check_budget(scene, 0.2)
    tight, _ = _check_budget(scene, 0.05)
    assert loose.lod.faces < loose.lod.faces_full          # 20480 faces: decimated
    assert loose.lod.faces <= tight.lod.faces
    # The reduced meshes really are what was traced: closed, and fewer faces.
    (ball,) = loose.scene.bodies
    assert len(ball.faces) == loose.lod.faces and ball.mesh.is_watertight


def test_no_max_error_is_bit_identical():
    scene = _small("nested_spheres", 48)
    a = xray_viz.render(scene)
    b = xray_viz.render(scene, max_error=None)
    for name in ("intensity", "line_integral", "total_path_length"):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))
    assert a.lod is None and b.lod is None and b.scene is scene


def test_overlapping_bodies_share_the_budget():
    scene = _small("nested_spheres", 48)
    report = lod.level_of_detail(scene, 0.1, spend_leftover=False)[1]
    # three concentric spheres: every pixel of the innermost is covered by all three boxes
    assert [round(b.share, 12) for b in report.bodies] == [round(0.1 / 3, 12)] * 3
    assert all(b.estimated_error <= b.share for b in report.bodies)
    assert report.estimated_error <= sum(b.estimated_error for b in report.bodies) + 1e-15
    # render(max_error=) spends what the equal shares leave: never finer, within the budget
    spent = xray_viz.render(scene, max_error=0.1).lod
    assert spent.faces <= report.faces
    assert all(b.estimated_error <= b.allowance for b in spent.bodies)
    assert spent.estimated_error <= 0.1


def test_a_small_footprint_is_decimated_further():
    """The same body, the same budget: seen by few, coarse pixels its measuring lines are as
    coarse as the rays, and it is traced with fewer faces."""
    fine = _small("sphere", 256)
    coarse = _small("sphere", 16)
    a = xray_viz.render(fine, max_error=0.1).lod.bodies[0]
    b = xray_viz.render(coarse, max_error=0.1).lod.bodies[0]
    assert b.pitch_mm > a.pitch_mm
    assert b.faces < a.faces
    assert b.estimated_error <= 0.1


def _box_chords(rays, half):
    """Exact path lengths of lines through the box ``|x_i| <= half_i`` (slab method)."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - rays.origins) / rays.directions
        t2 = (half - rays.origins) / rays.directions
    lo = np.where(np.isnan(t1), -np.inf, np.minimum(t1, t2)).max(axis=1)
    hi = np.where(np.isnan(t2), np.inf, np.maximum(t1, t2)).min(axis=1)
    return np.clip(hi - lo, 0.0, None)


def test_path_length_error_matches_exact_box_chords():
    """Two boxes, one 0.5 mm taller: the largest change along the measuring lines, against the
    exact chords on the same lines. It is not 0.5 mm: lines grazing the moved face run inside
    the 0.5 mm sliver for several mm (the silhouette effect the module docstring describes)."""
    from xray_viz.geometry import detector_rays
    from xray_viz.scene import Scene

    a = trimesh.creation.box(extents=[10, 10, 10])
    b = trimesh.creation.box(extents=[10, 10, 10.5])
    exact = 0.0
    for acq in lod._parallel_views(a, 0.25):
        rays = detector_rays(Scene(source=acq.source, detector=acq.detector))
        exact = max(exact, float(np.abs(_box_chords(rays, np.array([5, 5, 5.25]))
                                        - _box_chords(rays, np.array([5, 5, 5.0]))).max()))
    got = lod.path_length_error(a, b, pitch=0.25)
    assert got == pytest.approx(exact, abs=1e-6)
    assert 0.5 < got <= 10.5
    assert lod.path_length_error(a, a, pitch=0.25) == 0.0


def test_decimations_are_cached_on_disk(tmp_path, monkeypatch):
    monkeypatch.setenv("XRAY_VIZ_CACHE_DIR", str(tmp_path))
    lod.forget()                                   # nothing from the other tests in memory
    scene = _small("nested_spheres", 32)
    first = xray_viz.render(scene, max_error=0.2)
    stored = sorted((tmp_path / "lod").glob("*.npz"))
    assert stored and len(stored) >= 2             # every level tried, the failing one too

    import sys

    decimate = sys.modules["xray_viz.meshes.decimate"]

    def refuse(*args, **kwargs):
        raise AssertionError("decimated again")

    monkeypatch.setattr(decimate, "collapse", refuse)
    monkeypatch.setattr(lod, "path_length_error", refuse)
    again = xray_viz.render(xray_viz.load_scene("nested_spheres").replace(
        detector=scene.detector), max_error=0.2)
    assert again.lod == first.lod
    np.testing.assert_array_equal(again.line_integral, first.line_integral)
    # a corrupt file is ignored (and the work done again), never a wrong mesh
    for path in stored:
        path.write_bytes(b"not an npz")
    lod.forget()
    monkeypatch.undo()
    monkeypatch.setenv("XRAY_VIZ_CACHE_DIR", str(tmp_path))
    third = xray_viz.render(xray_viz.load_scene("nested_spheres").replace(
        detector=scene.detector), max_error=0.2)
    np.testing.assert_array_equal(third.line_integral, first.line_integral)


def test_cache_off_in_tests_writes_nothing(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    assert lod.cache_dir() is None                 # tests/conftest.py: XRAY_VIZ_CACHE_DIR=off
    xray_viz.render(_small("nested_spheres", 32), max_error=0.2)
    assert not list(tmp_path.rglob("*.npz"))


def test_collapse_keeps_float64_vertices():
    """pymeshlab does not round vertices through float32: vertices the collapse leaves alone
    come back bit for bit 1 m from the origin (float32 would move them by ~6e-5 mm)."""
    from scipy.spatial import cKDTree

    from xray_viz.meshes.decimate import collapse

    ball = trimesh.creation.icosphere(subdivisions=4, radius=40.0)
    ball.apply_translation([1000.123456789012, 0.0, 0.0])
    out = collapse(ball, len(ball.faces) - 200)
    assert out.vertices.dtype == np.float64
    d, _ = cKDTree(ball.vertices).query(out.vertices)
    assert (d == 0).sum() >= len(out.vertices) - 150          # ~100 vertices are new
    f32 = ball.vertices.astype(np.float32).astype(np.float64)
    assert np.abs(f32 - ball.vertices).max() > 1e-6          # float32 would have been visible


@pytest.mark.parametrize("bad", [0, -0.1, float("nan"), float("inf"), "0.1", True])
def test_bad_max_error_is_refused_in_one_line(bad):
    with pytest.raises(SceneError, match="max_error must be a number > 0") as info:
        xray_viz.render(_small("sphere", 16), max_error=bad)
    assert "\n" not in str(info.value)


def test_cli_max_error_reports_the_choice(tmp_path, capsys):
    out = tmp_path / "li.npy"
    scene = _small("nested_spheres", 32)
    assert main(["render", "nested_spheres", "-o", str(out), "--quantity", "line-integral", "-v",
                 "--shape", "32", "32", "--detector-size", *(
                     str(p * 31) for p in scene.detector.pitch), "--max-error", "0.2"]) == 0
    text = capsys.readouterr().err
    assert "level of detail for max_error 0.2: 15360 ->" in text
    assert "water: 5120 ->" in text                           # per body (debug, -v)
    expected = xray_viz.render(
        xray_viz.load_scene("nested_spheres").replace(detector=scene.detector), max_error=0.2)
    np.testing.assert_allclose(np.load(out), expected.line_integral, rtol=1e-9, atol=1e-12)


def test_cli_bad_max_error_is_one_line(tmp_path, capsys):
    assert main(["render", "sphere", "-o", str(tmp_path / "x.png"), "--max-error", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("xray-viz: error: --max-error must be")
    assert not list(tmp_path.iterdir())


def test_footprints_kept_per_acquisition(monkeypatch):
    """A second choice for the same bodies and acquisition does not trace the footprints
    again (kept on the bodies); a moved source does, and its choice is still within budget."""
    scene = _small("nested_spheres", 32)
    first = lod.level_of_detail(scene, 0.2)[1]
    calls = []
    real = lod._footprints
    monkeypatch.setattr(lod, "_footprints", lambda *a: calls.append(1) or real(*a))
    again = lod.level_of_detail(scene.replace(acquisition=scene.acquisition), 0.2)[1]
    assert again == first and calls == []
    moved = scene.replace(source=dataclasses.replace(
        scene.source, position=np.asarray(scene.source.position) + [5.0, 0.0, 0.0]))
    _check_budget(moved, 0.2)
    assert calls == [1]


def test_partly_measured_refusals_choose_as_complete_measurements(monkeypatch):
    """A level is refused once part of its measurement exceeds what it may have (a maximum
    over fewer lines is a lower bound of the complete one). The choice is the one made
    measuring every level completely, bit for bit, with the leftover spent and without, and
    fewer views are traced with equal shares (with the leftover spent, these bodies' refused
    levels are all measured to the end: not more); a refused level's partial value is at
    most its complete one."""
    scene = _frog_organs(("heart", "spleen", "lung"))
    calls = []
    real = lod._measure

    def counted(*args, **kwargs):
        before = bin(args[2].done).count("1")
        out = real(*args, **kwargs)
        calls.append(bin(out.done).count("1") - before)
        return out

    def complete(*args, **kwargs):
        return counted(*args, **{**kwargs, "refuse": None})

    for spend in (True, False):
        choices, traced = [], []
        for measure in (counted, complete):
            lod.forget()
            calls.clear()
            monkeypatch.setattr(lod, "_measure", measure)
            choices.append(lod.level_of_detail(scene, 0.2, spend_leftover=spend)[1])
            traced.append(sum(calls))
        assert choices[0] == choices[1]
        assert traced[0] < traced[1] if not spend else traced[0] <= traced[1]
    monkeypatch.setattr(lod, "_measure", real)
    # a partial measurement is a lower bound of the complete one
    a = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    from xray_viz.meshes.decimate import collapse

    b = collapse(a, 80)
    part = lod._measure(a, b, lod._Measurement(), pitch=0.5, refuse=lambda w: w > 0)
    assert 0 < part.worst and not part.complete
    assert part.worst <= lod.path_length_error(a, b, pitch=0.5)


def test_reduced_bodies_carry_the_checks_of_their_meshes(monkeypatch):
    """The chosen levels were checked while they were measured: the reduced bodies keep
    those reports (the render does not check again), and they are what a new check finds."""
    from xray_viz.meshes import repair

    check_mesh = repair.check_mesh
    lod.forget()
    scene = _frog_organs()
    reduced = lod.level_of_detail(scene, 0.2)[0]
    assert any(a.mesh is not b.mesh for a, b in zip(reduced.bodies, scene.bodies))

    def refuse(*args, **kwargs):
        raise AssertionError("checked again")

    monkeypatch.setattr(repair, "check_mesh", refuse)
    kept = reduced.bodies.reports
    xray_viz.render(reduced)
    monkeypatch.undo()
    for body, report in zip(reduced.bodies, kept):
        assert report == check_mesh(body.mesh)

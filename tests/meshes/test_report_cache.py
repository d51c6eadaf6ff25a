"""Mesh reports kept on disk by content hash (xray_viz.meshes._report_cache)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

import xray_viz
from xray_viz.meshes import _report_cache, repair


@pytest.fixture
def cache(tmp_path, monkeypatch):
    folder = tmp_path / "cache"
    monkeypatch.setenv("XRAY_VIZ_CACHE_DIR", str(folder))
    calls = []
    real = repair._check_mesh
    monkeypatch.setattr(repair, "_check_mesh", lambda mesh: calls.append(1) or real(mesh))
    return folder / "mesh-reports", calls


def test_the_same_mesh_is_checked_once_whatever_the_object(cache):
    folder, calls = cache
    ball = trimesh.creation.icosphere(subdivisions=3, radius=10.0)
    first = repair.check_mesh(ball)
    again = repair.check_mesh(trimesh.Trimesh(ball.vertices.copy(), ball.faces.copy(),
                                              process=False))
    assert calls == [1] and again == first and len(list(folder.glob("*.json"))) == 1
    # a different mesh (one vertex moved) is checked
    moved = ball.copy()
    moved.vertices[0] += 0.5
    assert repair.check_mesh(moved).volume != first.volume and calls == [1, 1]


def test_a_report_agrees_with_the_checker_on_a_broken_mesh(cache):
    folder, calls = cache
    box = trimesh.creation.box(extents=[4, 5, 6])
    open_box = trimesh.Trimesh(box.vertices, box.faces[1:], process=False)
    a = repair.check_mesh(open_box)
    b = repair.check_mesh(open_box)
    assert a == b == repair.check_mesh(open_box, cache=False) and not a.watertight
    assert calls == [1, 1]                      # the third was cache=False


def test_a_corrupt_or_foreign_file_is_ignored_and_replaced(cache):
    folder, calls = cache
    ball = trimesh.creation.icosphere(subdivisions=2, radius=5.0)
    good = repair.check_mesh(ball)
    (path,) = folder.glob("*.json")
    for text in ("{not json", json.dumps({"format": 99, "report": {}}),
                 json.dumps({"format": _report_cache.FORMAT, "report": {"faces": 1}})):
        path.write_text(text)
        assert repair.check_mesh(ball) == good
    assert len(calls) == 4
    assert json.loads(path.read_text())["format"] == _report_cache.FORMAT


def test_the_checker_code_is_part_of_the_key(cache, monkeypatch):
    folder, calls = cache
    v, f = np.zeros((3, 3)), np.array([[0, 1, 2]])
    key = _report_cache.mesh_key(v, f)
    _report_cache._checker_digest.cache_clear()
    monkeypatch.setattr(_report_cache, "_checker_digest", lambda: b"another checker")
    assert _report_cache.mesh_key(v, f) != key


def test_off_and_unwritable_places_only_cost_time(tmp_path, monkeypatch):
    ball = trimesh.creation.icosphere(subdivisions=2, radius=5.0)
    monkeypatch.setenv("XRAY_VIZ_CACHE_DIR", "off")
    assert _report_cache.cache_dir() is None and repair.check_mesh(ball).watertight
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    monkeypatch.setenv("XRAY_VIZ_CACHE_DIR", str(blocked))
    from xray_viz._cache import CacheWarning

    with pytest.warns(CacheWarning, match="mesh reports are not cached") as said:
        assert repair.check_mesh(ball).watertight        # nothing written, no error
        assert repair.check_mesh(ball).watertight
    assert len([w for w in said if "mesh reports" in str(w.message)]) == 1     # said once


def test_a_scene_loads_from_stored_reports(cache):
    folder, calls = cache
    first = xray_viz.load_scene("nested_spheres")
    n = len(calls)
    again = xray_viz.load_scene("nested_spheres")
    assert n >= len(first.bodies) and len(calls) == n        # the second load checked nothing
    assert again.bodies.reports == first.bodies.reports
    assert np.array_equal(xray_viz.render(again).intensity, xray_viz.render(first).intensity)


@pytest.mark.parametrize("name", ["default", "nested_spheres", "shepp_logan"])
def test_containment_read_from_disk_is_what_the_tests_give(cache, monkeypatch, name):
    """Whether one body lies inside another is kept per pair of content hashes: a second load
    of the scene tests no pair, and the stored answers (True and False ones) are those of the
    tests themselves."""
    folder, _ = cache
    meshes = [b.mesh for b in xray_viz.load_scene(name).bodies]
    truth = repair.containers(meshes, cache=False)
    assert not (folder.parent / "mesh-pairs").exists()
    assert repair.containers(meshes) == truth              # computed, then stored
    stored = list((folder.parent / "mesh-pairs").glob("*.json"))
    assert stored or not any(truth)
    tested = []
    real = repair._inside_of
    monkeypatch.setattr(repair, "_inside_of", lambda meshes, b, cand, *a: tested.extend(cand)
                        or real(meshes, b, cand, *a))
    copies = [trimesh.Trimesh(m.vertices.copy(), m.faces.copy(), process=False) for m in meshes]
    assert repair.containers(copies) == truth and tested == []      # read, not tested
    if name == "default":
        assert any(truth) and len(stored) > sum(map(len, truth))   # "not inside" kept too
        for path in stored:                                # a corrupt answer is tested again
            path.write_text("{not json")
        assert repair.containers(copies) == truth and tested


def test_a_moved_body_is_tested_again(cache, monkeypatch):
    big = trimesh.creation.box(extents=[20, 20, 20])
    small = trimesh.creation.box(extents=[4, 4, 4])
    assert repair.containers([small, big]) == [[1], []]
    moved = small.copy()
    moved.apply_translation([9, 0, 0])                     # pokes out of big
    assert repair.containers([moved, big]) == [[], []]
    assert repair.containers([small, big]) == [[1], []]


def test_the_bundled_phantoms_load_from_the_shipped_reports(monkeypatch):
    """The reports shipped with the package (phantoms/mesh-reports.json) cover every mesh of
    every bundled phantom under the running checker's keys, with the cache off: a load checks
    nothing. Fails when the checker or a phantom changed without writing the file anew:
    ``python -m xray_viz.meshes._report_cache``."""
    monkeypatch.setenv("XRAY_VIZ_CACHE_DIR", "off")
    monkeypatch.setenv("XRAY_VIZ_SHIPPED_REPORTS", "on")
    calls = []
    real = repair._check_mesh
    monkeypatch.setattr(repair, "_check_mesh", lambda mesh: calls.append(1) or real(mesh))
    from xray_viz import phantoms

    tested = []
    real_inside = repair._inside_of
    monkeypatch.setattr(repair, "_inside_of", lambda meshes, b, cand, *a: tested.extend(cand)
                        or real_inside(meshes, b, cand, *a))
    for name in phantoms.names():
        bodies = xray_viz.load_scene(name).bodies
        bodies.reports
        assert calls == [], f"{name}: a mesh without a shipped report"
        bodies.precedence
        assert tested == [], f"{name}: a pair of meshes without a shipped inside test"
    assert len(_report_cache.shipped()) >= 16 and any(_report_cache.shipped_pairs().values())


def test_the_shipped_reports_are_the_checkers_and_can_be_turned_off(monkeypatch):
    """The frog's shipped reports equal what the checker says of its meshes now, and the
    image rendered from them is the image rendered from checked meshes, bit for bit;
    ``XRAY_VIZ_SHIPPED_REPORTS=off`` checks every mesh."""
    monkeypatch.setenv("XRAY_VIZ_CACHE_DIR", "off")
    monkeypatch.setenv("XRAY_VIZ_SHIPPED_REPORTS", "on")
    shipped = xray_viz.load_scene("default")
    reports = shipped.bodies.reports
    monkeypatch.setenv("XRAY_VIZ_SHIPPED_REPORTS", "off")
    calls = []
    real = repair._check_mesh
    monkeypatch.setattr(repair, "_check_mesh", lambda mesh: calls.append(1) or real(mesh))
    checked = xray_viz.load_scene("default")
    assert checked.bodies.reports == reports and len(calls) == len(checked.bodies) == 16
    meshes = [b.mesh for b in shipped.bodies]
    assert np.array_equal(shipped.bodies.precedence, checked.bodies.precedence)
    assert any(repair.containers(meshes, cache=False))       # the frog has nested bodies
    assert np.array_equal(xray_viz.render(shipped).intensity,
                          xray_viz.render(checked).intensity)

"""The one disk cache rule (xray_viz._cache): where each kind of cached data goes, and when
caching is off."""

from __future__ import annotations

import warnings
from pathlib import Path

import platformdirs
import pytest

from xray_viz import _cache, lod
from xray_viz.meshes import _report_cache, volumes


def _folders():
    """Every user's folder, by kind: the mesh reports, the inside tests, the decimations and
    the meshed volumes."""
    return {"mesh-reports": _report_cache.cache_dir(), "mesh-pairs": _report_cache._pairs_dir(),
            "lod": lod.cache_dir(), "volumes": volumes.cache_dir()}


def test_the_variable_set_puts_every_kind_under_it(tmp_path, monkeypatch):
    monkeypatch.setenv("XRAY_VIZ_CACHE_DIR", str(tmp_path / "mine"))
    folders = _folders()
    assert folders == {kind: tmp_path / "mine" / kind for kind in folders}
    assert all(f.is_dir() for f in folders.values())            # made when first asked


@pytest.mark.parametrize("value", ["off", "OFF", " Off ", "0", "no", "false", "None", ""])
def test_the_variable_off_turns_every_kind_off_silently(value, monkeypatch):
    monkeypatch.setenv("XRAY_VIZ_CACHE_DIR", value)
    with warnings.catch_warnings():
        warnings.simplefilter("error")                          # no notice: a choice
        assert _folders() == dict.fromkeys(_folders())


def test_unset_is_the_user_cache_folder_of_platformdirs(tmp_path, monkeypatch):
    monkeypatch.delenv("XRAY_VIZ_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    user = Path(platformdirs.user_cache_dir("xray_viz", appauthor=False))
    assert user == tmp_path / "xdg" / "xray_viz"                 # Linux: $XDG_CACHE_HOME/xray_viz
    assert _folders() == {kind: user / kind for kind in _folders()}


@pytest.mark.parametrize("where", ["variable", "user"])
def test_an_unwritable_folder_is_off_with_one_notice(where, tmp_path, monkeypatch):
    blocked = tmp_path / "a-file"
    blocked.write_text("not a folder")
    if where == "variable":
        monkeypatch.setenv("XRAY_VIZ_CACHE_DIR", str(blocked))
    else:
        monkeypatch.delenv("XRAY_VIZ_CACHE_DIR", raising=False)
        monkeypatch.setenv("XDG_CACHE_HOME", str(blocked))
    with pytest.warns(_cache.CacheWarning) as said:
        for _ in range(3):
            assert _cache.cache_dir("lod", what="decimations") is None
    (notice,) = [str(w.message) for w in said]                  # once, however often asked
    assert "\n" not in notice and "decimations are not cached" in notice
    assert "XRAY_VIZ_CACHE_DIR" in notice and str(blocked) in notice


"""Scan stores that are damaged, and stores that stream (issue 42).

A Zarr store whose chunk is cut short, bit-flipped or deleted while its ``done`` flag is set:
resuming verifies what it skips and renders such projections again; reading refuses them in
one line (never a codec's traceback, never the fill value NaN handed out as data). NeXus and
TIFF scans write batch by batch, so memory stays bounded by the batch.
"""

from __future__ import annotations

import dataclasses
import importlib

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import OutputError
from xray_viz.orbit import Orbit

S = importlib.import_module("xray_viz.scan")      # the module (xray_viz.scan is the function)
ORBIT = Orbit(projections=5, axis=[0, 1, 0])


def _small(scene, shape=(32, 24), pitch=8.0):
    return scene.replace(detector=dataclasses.replace(scene.detector, shape=shape,
                                                      pitch=(pitch, pitch)))


@pytest.fixture(scope="module")
def sphere():
    return _small(xray_viz.load_scene("sphere"))


@pytest.fixture(scope="module")
def reference(sphere):
    return xray_viz.scan(sphere, ORBIT).projections


def _chunk(store, k):
    """The chunk file of projection ``k`` (chunks of one projection, default key encoding)."""
    return store / "projections" / "c" / str(k) / "0" / "0"


def _damage(path, how):
    data = path.read_bytes()
    if how == "truncate":
        path.write_bytes(data[: len(data) // 2])
    elif how == "flip":
        b = bytearray(data)
        b[len(b) // 2] ^= 0x10
        path.write_bytes(bytes(b))
    else:
        path.unlink()


@pytest.mark.parametrize("how", ["truncate", "flip", "delete"])
def test_a_damaged_chunk_flagged_done_is_rendered_again_on_resume(sphere, reference, tmp_path,
                                                                  how, monkeypatch):
    store = tmp_path / "s.zarr"
    xray_viz.scan(sphere, ORBIT, store=store)
    _damage(_chunk(store, 2), how)
    assert S.done_flags(__import__("zarr").open_group(str(store), mode="r"))[2]  # still flagged
    calls = []
    real = S.projection
    monkeypatch.setattr(S, "projection", lambda *a, **k: calls.append(a[2]) or real(*a, **k))
    again = xray_viz.scan(sphere, ORBIT, store=store)
    assert calls == [2]
    assert np.array_equal(again.projections[:], reference)


@pytest.mark.parametrize("how", ["truncate", "flip", "delete"])
def test_reading_a_damaged_store_is_one_line_naming_the_projection(sphere, tmp_path, how):
    store = tmp_path / "s.zarr"
    xray_viz.scan(sphere, ORBIT, store=store)
    _damage(_chunk(store, 3), how)
    for lazy in (False, True):
        with pytest.raises(OutputError) as info:
            got = S.read_zarr(store, lazy=lazy)
            np.asarray(got.projections[:])
        message = str(info.value)
        assert "\n" not in message and "projection 3" in message and str(store) in message
        assert "run the same scan again" in message


def test_reconstruct_of_a_damaged_store_is_one_line(sphere, tmp_path, capsys):
    from xray_viz.cli import main

    (tmp_path / "s.toml").write_text(sphere.to_toml())
    store = tmp_path / "s.zarr"
    args = ["scan", str(tmp_path / "s.toml"), "-o", str(store), "--projections", "5",
            "--axis", "0", "1", "0"]
    assert main(args) == 0
    capsys.readouterr()
    _damage(_chunk(store, 1), "truncate")
    assert main(["reconstruct", str(store), "-o", str(tmp_path / "v.nii.gz")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("xray-viz: error:") and "\n" not in err and "projection 1" in err
    assert not (tmp_path / "v.nii.gz").exists()
    # the scan run again repairs it, saying so, then it reconstructs
    assert main(args) == 0
    out = capsys.readouterr()
    assert "(1 rendered now)" in out.out
    assert "projection 1" in out.err and "damaged" in out.err

"""Flat and dark fields of a scan store (CT-LAYOUT.md: arrays ``flat``, ``dark``)."""

from __future__ import annotations

import dataclasses
import importlib

import numpy as np

import xray_viz
from xray_viz.orbit import Orbit

S = importlib.import_module("xray_viz.scan")


def test_flat_and_dark_correct_an_intensity_scan_to_its_line_integrals(tmp_path):
    """(proj - dark) / (flat - dark) = exp(-line integral) for a noiseless scan, with a
    detector whose flat is not 1 everywhere (fall-off, gain, I0); and exp(-mu L) with the
    path lengths of an independent render."""
    scene = xray_viz.load_scene("sphere")
    scene = scene.replace(detector=dataclasses.replace(
        scene.detector, shape=(40, 30), pitch=(4.0, 4.0), falloff=True, gain=2.5, i0=1e4))
    orbit = Orbit(projections=3, axis=[0, 1, 0])
    store = tmp_path / "i.zarr"
    got = xray_viz.scan(scene, orbit, quantity="intensity", store=store)
    assert got.flat.shape == got.dark.shape == (30, 40) and not np.any(got.dark)
    assert got.flat.max() / got.flat.min() > 1.005          # the fall-off shows
    empty = scene.replace(bodies=[], acquisition=orbit.acquisition(scene.acquisition, 0))
    np.testing.assert_allclose(got.flat, xray_viz.render(empty).intensity, rtol=1e-7)
    assert got.flat.max() <= 2.5 * 1e4 * (1 + 1e-6)
    li = xray_viz.scan(scene, orbit).projections
    corrected = (np.asarray(got.projections[:], float) - got.dark) / (got.flat - got.dark)
    np.testing.assert_allclose(corrected, np.exp(-li.astype(float)), rtol=2e-6, atol=0)
    mu = scene.bodies[0].mu
    for k, acq in enumerate(orbit.acquisitions(scene.acquisition)):
        L = xray_viz.render(scene.replace(acquisition=acq)).total_path_length
        np.testing.assert_allclose(corrected[k], np.exp(-mu * L / 10.0), rtol=2e-6)
    # the in-memory scan carries the same fields; a line-integral store has none
    mem = xray_viz.scan(scene, orbit, quantity="intensity")
    assert np.array_equal(mem.flat, got.flat) and np.array_equal(mem.dark, got.dark)
    line = xray_viz.scan(scene, orbit, store=tmp_path / "l.zarr")
    assert line.flat is None and line.dark is None
    import zarr

    assert sorted(zarr.open_group(str(store), mode="r").array_keys()) == [
        "dark", "done", "flat", "projections"]


def test_a_scan_to_a_store_keeps_the_stack_on_disk(tmp_path):
    """scan(store=) returns the store's lazy array (memory bounded by the batch), equal to
    the in-memory scan, and the TIFF/NeXus writers take it projection by projection."""
    import h5py
    import tifffile
    import zarr

    scene = xray_viz.load_scene("sphere")
    scene = scene.replace(detector=dataclasses.replace(scene.detector, shape=(20, 16),
                                                       pitch=(10.0, 10.0)))
    orbit = Orbit(projections=4, axis=[0, 1, 0])
    mem = xray_viz.scan(scene, orbit)
    lazy = xray_viz.scan(scene, orbit, store=tmp_path / "s.zarr")
    assert isinstance(lazy.projections, zarr.Array) and not isinstance(lazy.projections,
                                                                       np.ndarray)
    assert np.array_equal(lazy.projections[2], mem.projections[2])
    assert np.array_equal(lazy.projections[:], mem.projections)
    full = S.read_zarr(tmp_path / "s.zarr")
    assert isinstance(full.projections, np.ndarray)
    folder = S.write_tiff_stack(lazy, tmp_path / "t")
    assert np.array_equal(np.stack([tifffile.imread(f) for f in sorted(folder.glob("*.tif"))]),
                          mem.projections)
    with h5py.File(S.write_nexus(lazy, tmp_path / "s.nxs"), "r") as f:
        assert np.array_equal(f["entry/instrument/detector/data"][:], mem.projections)


def test_each_batch_gives_its_memory_back(tmp_path, monkeypatch):
    """render_batch (a Dask task) and the serial store loop call malloc_trim after each batch;
    on glibc Linux the call is made (a bool either way)."""
    import hashlib

    scene = xray_viz.load_scene("sphere")
    scene = scene.replace(detector=dataclasses.replace(scene.detector, shape=(8, 8),
                                                       pitch=(32.0, 32.0)))
    assert isinstance(S.trim_memory(), bool)
    calls = []
    monkeypatch.setattr(S, "trim_memory", lambda: calls.append(1) or True)
    orbit = Orbit(projections=5, axis=[0, 1, 0])
    xray_viz.scan(scene, orbit, store=tmp_path / "a.zarr", batch=2)
    assert len(calls) == 2                               # after projections 2 and 4
    geometry = S.scan_geometry(scene, orbit)
    S.open_store(tmp_path / "b.zarr", scene=scene, geometry=geometry)
    text = scene.to_toml()
    S.render_batch(text, hashlib.sha256(text.encode()).hexdigest(), orbit, [0, 1],
                   store=str(tmp_path / "b.zarr"))
    assert len(calls) == 3

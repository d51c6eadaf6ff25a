"""RTK's files for a scan (issue 14): the ThreeDCircularProjectionGeometry XML and the
projection image RTK's command-line tools read, proven by RTK's own reader and by running
RTK's ``rtkfdk`` on them (the same volume as :func:`xray_viz.reconstruct`)."""

from __future__ import annotations

import json
import sys

import numpy as np
import pytest

import xray_viz
from xray_viz import cli
from xray_viz.orbit import Orbit
from xray_viz.reconstruct import (ReconstructionError, read_rtk_geometry, reconstruct,
                                  rtk_frame, rtk_geometry, rtk_matrices, write_rtk_geometry,
                                  write_rtk_projections)

from tests.reconstruct.test_reconstruct import CENTER, SWIG_WARNING, ellipsoid_scene, write_store

pytestmark = pytest.mark.filterwarnings(SWIG_WARNING)

with __import__("warnings").catch_warnings():
    __import__("warnings").simplefilter("ignore", DeprecationWarning)
    itk = pytest.importorskip("itk")
    from itk import RTK as rtk               # noqa: E402

PARAMETERS = ("GetGantryAngles", "GetSourceToIsocenterDistances",
              "GetSourceToDetectorDistances", "GetSourceOffsetsX", "GetSourceOffsetsY",
              "GetProjectionOffsetsX", "GetProjectionOffsetsY", "GetInPlaneAngles",
              "GetOutOfPlaneAngles")


def small_scan(axis, kind="point", n=24, shape=(40, 32), pitch=3.0):
    """A real :func:`xray_viz.scan` of the test ellipsoid about ``axis`` through CENTER."""
    scene, _ = ellipsoid_scene(axis, kind=kind, subdivisions=3, shape=shape, pitch=pitch)
    orbit = Orbit("circular", projections=n, axis=np.asarray(axis, float), center=CENTER,
                  start=11.0)
    result = xray_viz.scan(scene, orbit)
    return result.projections, result.geometry


@pytest.fixture(scope="module")
def cone():
    return small_scan([0, 1, 1])


@pytest.mark.parametrize("axis, kind", [([0, 1, 1], "point"), ([1, 0, 0], "parallel")])
def test_geometry_xml_round_trip_through_rtks_reader(axis, kind, tmp_path, cone):
    """Written, read back by RTK's XML reader: the same projections, parameters and matrices
    (to the 15 digits the XML holds); a second write of what was read is the same file."""
    projs, geo = cone if kind == "point" else small_scan(axis, kind, n=6)
    ours = rtk_geometry(geo)
    path = write_rtk_geometry(geo, tmp_path / "geometry.xml")
    back = read_rtk_geometry(path)
    text = path.read_text()
    assert text.count("<Projection>") == len(geo["poses"])
    for name in PARAMETERS:
        a, b = (np.asarray(getattr(g, name)(), float) for g in (ours, back))
        assert a.shape == b.shape == (len(geo["poses"]),)
        if "Angles" in name:          # radians in [0, 2 pi): 2 pi - 1e-16 is read back as 0
            a = (a - b + np.pi) % (2 * np.pi) - np.pi + b
        assert np.allclose(a, b, rtol=1e-13, atol=1e-12), name
    m, mb = rtk_matrices(ours), rtk_matrices(back)
    assert np.all(np.abs(m - mb) <= 1e-12 * np.abs(m).max()), np.abs(m - mb).max()
    # RTK's own helper reads the same file to the same matrices
    assert np.array_equal(rtk_matrices(rtk.read_geometry(str(path))), mb)
    # a fixed point: what was read, written and read again by RTK, gives the same matrices
    again = tmp_path / "again.xml"
    rtk.write_geometry(back, str(again))
    assert np.all(np.abs(rtk_matrices(rtk.read_geometry(str(again))) - mb)
                  <= 1e-13 * np.abs(m).max())
    if kind == "parallel":
        assert np.all(np.asarray(back.GetSourceToDetectorDistances()) == 0.0)


def test_rtk_matrices_project_like_xray_viz(cone, tmp_path):
    """RTK's matrix (RTK fixed mm -> projection mm), composed with the world -> RTK frame and
    the projection mm -> pixel maps, sends world points to the pixels of xray_viz's own
    projection matrices (geometry['projection_matrices'], an independent derivation)."""
    projs, geo = cone
    (w, h), (pu, pv) = geo["detector"]["shape"], geo["detector"]["pitch_mm"]
    R, c = rtk_frame(geo)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R, -R @ c
    A = np.array([[1 / pu, 0, (w - 1) / 2], [0, 1 / pv, (h - 1) / 2], [0, 0, 1]])
    pts = np.c_[np.random.default_rng(3).uniform(-40, 40, (50, 3)) + CENTER, np.ones(50)]
    back = rtk_matrices(read_rtk_geometry(write_rtk_geometry(geo, tmp_path / "g.xml")))
    for k, P in enumerate(geo["projection_matrices"]):
        a = (A @ back[k] @ T @ pts.T)
        b = np.asarray(P) @ pts.T
        assert np.allclose(a[:2] / a[2], b[:2] / b[2], atol=1e-9), k


def test_rtkfdk_on_the_written_files_gives_our_volume(cone, tmp_path, monkeypatch, capsys):
    """`xray-viz reconstruct --rtk-geometry --rtk-projections` then RTK's own `rtkfdk` (run
    in-process: `itk.rtkfdk.main`) on those files, asked for our grid (RTK frame origin and
    direction): the volume `xray-viz reconstruct` computes, to float rounding."""
    projs, geo = cone
    store = write_store(tmp_path / "scan.zarr", projs, geo)
    xml, mha = tmp_path / "geometry.xml", tmp_path / "projections.mha"
    assert cli.main(["reconstruct", str(store), "--rtk-geometry", str(xml),
                     "--rtk-projections", str(mha)]) == 0
    said = capsys.readouterr().out
    assert "RTK geometry, 24 projections" in said and "RTK projections" in said
    assert sorted(p.name for p in tmp_path.iterdir()) == ["geometry.xml", "projections.mha",
                                                          "scan.zarr"]
    vol = reconstruct(projs, geo, voxel=3.0, shape=(24, 22, 20))
    R, c = rtk_frame(geo)
    origin = R @ (vol.origin - c)
    out = tmp_path / "rtk.mha"
    from itk import rtkfdk

    # our grid in RTK's frame, as an image for `--like` (rtkfdk's own --direction option fails
    # in itk-rtk 2.7.0's Python script: "'itkMatrixD33' object is not subscriptable")
    like = itk.image_from_array(np.zeros(vol.mu.shape, np.float32))
    like.SetOrigin([float(x) for x in origin])
    like.SetSpacing([3.0, 3.0, 3.0])
    like.SetDirection(itk.GetMatrixFromArray(np.ascontiguousarray(R)))
    itk.imwrite(like, str(tmp_path / "like.mha"))
    monkeypatch.setattr(sys, "argv", [
        "rtkfdk", "-g", str(xml), "-p", str(tmp_path), "-r", "projections.mha",
        "-o", str(out), "--like", str(tmp_path / "like.mha")])
    rtkfdk.main()
    theirs = itk.array_from_image(itk.imread(str(out))) * 10.0        # 1/mm -> 1/cm
    assert theirs.shape == vol.mu.shape
    assert np.abs(vol.mu).max() > 0.1
    assert np.allclose(theirs, vol.mu, atol=1e-5 * np.abs(vol.mu).max()), \
        np.abs(theirs - vol.mu).max()
    # the rows of the projection file are flipped once: unflipped, RTK reconstructs elsewhere
    flipped = tmp_path / "flip"
    flipped.mkdir()
    img = itk.imread(str(mha))
    bad = itk.image_from_array(np.ascontiguousarray(itk.array_from_image(img)[:, ::-1, :]))
    bad.CopyInformation(img)
    itk.imwrite(bad, str(flipped / "p.mha"))
    monkeypatch.setattr(sys, "argv", [
        "rtkfdk", "-g", str(xml), "-p", str(flipped), "-r", "p.mha", "-o", str(out),
        "--like", str(tmp_path / "like.mha")])
    rtkfdk.main()
    wrong = itk.array_from_image(itk.imread(str(out))) * 10.0
    assert np.abs(wrong - vol.mu).max() > 0.3 * np.abs(vol.mu).max()


def test_rtk_file_refusals(cone, tmp_path, capsys):
    projs, geo = cone
    store = write_store(tmp_path / "scan.zarr", projs, geo)
    with pytest.raises(ReconstructionError, match="no such RTK geometry file"):
        read_rtk_geometry(tmp_path / "missing.xml")
    (tmp_path / "other.xml").write_text("<a>not RTK</a>")
    with pytest.raises(ReconstructionError, match="not an RTK geometry file"):
        read_rtk_geometry(tmp_path / "other.xml")
    with pytest.raises(ValueError, match=r"end the name with \.xml"):
        write_rtk_geometry(geo, tmp_path / "g.txt")
    with pytest.raises(ReconstructionError, match=r"shape \(24, 32, 39\)"):
        write_rtk_projections(projs[:, :, :39], geo, tmp_path / "p.mha")
    keep = tmp_path / "keep.xml"
    keep.write_text("previous")
    cases = [([str(store)], "nothing to write"),
             ([str(store), "--rtk-geometry", str(tmp_path / "g.json")], r"end the name with \.xml"),
             ([str(store), "--rtk-projections", str(tmp_path / "p.png")], r"\.mha, \.mhd"),
             ([str(store), "--rtk-geometry", str(keep), "-o", str(tmp_path / "v.nii.gz"),
               "--method", "fbp"], "use method='fdk'")]
    for argv, words in cases:
        assert cli.main(["reconstruct", *argv]) == 2
        err = capsys.readouterr().err
        assert err.startswith("xray-viz: error: ") and err.count("\n") == 1, err
        assert __import__("re").search(words, err), err
    assert keep.read_text() == "previous"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["keep.xml", "other.xml", "scan.zarr"]


def test_scan_geometry_dict_is_unchanged_by_export(cone, tmp_path):
    projs, geo = cone
    text = json.dumps(geo, sort_keys=True)
    write_rtk_geometry(geo, tmp_path / "g.xml")
    write_rtk_projections(projs, geo, tmp_path / "p.mha")
    assert json.dumps(geo, sort_keys=True) == text

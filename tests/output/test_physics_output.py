"""Round trips of every output format, and the DICOM geometry."""

from pathlib import Path

import numpy as np
import pydicom
import pytest

import xray_viz
from physics_scenes import box, load, parallel_detector
from xray_viz.errors import OutputError
from xray_viz.output import load_image, save_image, to_uint16


@pytest.fixture
def image():
    rng = np.random.default_rng(1)
    return rng.uniform(0.1, 3.0, (17, 23))


def test_npy_exact(tmp_path, image):
    save_image(tmp_path / "a.npy", image)
    assert np.array_equal(load_image(tmp_path / "a.npy"), image)


@pytest.mark.parametrize("suffix", [".tiff", ".tif"])
def test_tiff_float32_exact(tmp_path, image, suffix):
    save_image(tmp_path / f"a{suffix}", image)
    back = load_image(tmp_path / f"a{suffix}")
    assert back.dtype == np.float32 and np.array_equal(back, image.astype(np.float32))


@pytest.mark.parametrize("bright", ["high", "low"])
def test_png_16bit_quantisation(tmp_path, image, bright):
    save_image(tmp_path / "a.png", image, bright=bright)
    back = load_image(tmp_path / "a.png").astype(np.uint16)
    assert np.array_equal(back, to_uint16(image, bright=bright))
    lo, hi = image.min(), image.max()
    scaled = back / 65535.0 if bright == "high" else 1 - back / 65535.0
    assert np.abs(lo + scaled * (hi - lo) - image).max() <= (hi - lo) / 65535 / 2 + 1e-12


def _scene(tmp_path, **source):
    return load(tmp_path, source={"position": [0.0, 0.0, 1000.0], **source},
                detector=parallel_detector(shape=(23, 17), pitch=[0.4, 0.6], focal_spot=0.6),
                bodies=[("cube", box([10, 10, 10], center=[0, 0, 100]), {"mu": 0.3})])


def test_dicom_values_and_geometry(tmp_path, image):
    scene = _scene(tmp_path, energy=70.0)
    save_image(tmp_path / "a.dcm", image, scene=scene, bright="low", quantity="intensity")
    back = load_image(tmp_path / "a.dcm")
    step = (image.max() - image.min()) / 65535
    assert np.abs(back - image).max() <= step / 2 * (1 + 1e-6)
    ds = pydicom.dcmread(tmp_path / "a.dcm")
    assert ds.Modality == "DX" and ds.PhotometricInterpretation == "MONOCHROME1"
    assert (ds.Rows, ds.Columns, ds.BitsStored) == (17, 23, 16)
    # cube centre at z = 100: SOD = 900 mm, SID = 1500 mm, magnification 5/3
    assert float(ds.DistanceSourceToDetector) == pytest.approx(1500.0)
    assert float(ds.DistanceSourceToPatient) == pytest.approx(900.0)
    assert float(ds.EstimatedRadiographicMagnificationFactor) == pytest.approx(1500 / 900)
    assert [float(v) for v in ds.ImagerPixelSpacing] == pytest.approx([0.6, 0.4])  # row, column
    assert [float(v) for v in ds.PixelSpacing] == pytest.approx([0.6 * 0.6, 0.4 * 0.6])
    assert "KVP" not in ds                       # a monochromatic beam has no tube potential
    assert "beam: monochromatic 70 keV" in ds.ImageComments
    assert float(ds.FocalSpots) == pytest.approx(0.6)
    rwv = ds.RealWorldValueMappingSequence[0]
    assert np.array_equal(ds.pixel_array.astype(np.float64) * rwv.RealWorldValueSlope
                          + rwv.RealWorldValueIntercept, back)


@pytest.mark.parametrize("quantity, bright, shape, sign, relationship, unit", [
    ("intensity", "low", "INVERSE", 1, "LIN", "1"),
    ("line-integral", "high", "IDENTITY", -1, "LOG", "1"),
    ("path-length", "high", "IDENTITY", -1, "LOG", "mm"),
    (None, "high", "IDENTITY", -1, "LIN", "1"),
])
def test_dicom_dx_conformance(tmp_path, image, quantity, bright, shape, sign, relationship, unit):
    # PS3.3 C.8.11.3 (DX Image Module): Rescale Slope 1 and Intercept 0 (enumerated), Rescale
    # Type US, Presentation LUT Shape for a FOR PRESENTATION image, IDENTITY with MONOCHROME2 and
    # INVERSE with MONOCHROME1; the physical values go in a Real World Value Mapping item.
    scene = _scene(tmp_path, energy=70.0)
    save_image(tmp_path / "a.dcm", image, scene=scene, bright=bright, quantity=quantity)
    ds = pydicom.dcmread(tmp_path / "a.dcm")
    assert ds.SOPClassUID == "1.2.840.10008.5.1.4.1.1.1.1" and ds.Modality == "DX"
    assert ds.PresentationIntentType == "FOR PRESENTATION"
    assert (float(ds.RescaleSlope), float(ds.RescaleIntercept), ds.RescaleType) == (1, 0, "US")
    assert ds.PresentationLUTShape == shape
    assert ds.PhotometricInterpretation == ("MONOCHROME1" if shape == "INVERSE" else
                                            "MONOCHROME2")
    assert ds.PixelIntensityRelationship == relationship
    assert ds.PixelIntensityRelationshipSign == sign
    assert list(ds.ImageType) == ["DERIVED", "SECONDARY", ""]
    assert ds.ImageLaterality == "U" and ds.LossyImageCompression == "00"
    # the window is in stored values (identity Modality LUT) and spans them all
    assert float(ds.WindowCenter) == 32767.5 and float(ds.WindowWidth) == 65536
    assert len(ds.RealWorldValueMappingSequence) == 1
    rwv = ds.RealWorldValueMappingSequence[0]
    assert (rwv.RealWorldValueFirstValueMapped, rwv.RealWorldValueLastValueMapped) == (0, 65535)
    assert rwv["RealWorldValueFirstValueMapped"].VR == "US"
    assert rwv.RealWorldValueIntercept == image.min()
    assert rwv.RealWorldValueSlope == pytest.approx((image.max() - image.min()) / 65535,
                                                    rel=1e-15)
    assert rwv.LUTLabel == (quantity or "value") and rwv.LUTExplanation
    units = rwv.MeasurementUnitsCodeSequence[0]
    assert (units.CodeValue, units.CodingSchemeDesignator) == (unit, "UCUM")
    # geometry tags are kept
    for keyword in ("ImagerPixelSpacing", "PixelSpacing",
                    "EstimatedRadiographicMagnificationFactor", "DistanceSourceToDetector",
                    "DistanceSourceToPatient", "FocalSpots"):
        assert keyword in ds
    assert ds.pixel_array.dtype == np.uint16 and ds.pixel_array.shape == image.shape
    step = (image.max() - image.min()) / 65535
    assert np.abs(load_image(tmp_path / "a.dcm") - image).max() <= step / 2 * (1 + 1e-9)


def test_dicom_reader_falls_back_to_rescale(tmp_path, image):
    # files without a Real World Value Mapping (older xray_viz, other writers) use the rescale
    scene = _scene(tmp_path, energy=70.0)
    save_image(tmp_path / "a.dcm", image, scene=scene)
    ds = pydicom.dcmread(tmp_path / "a.dcm")
    rwv = ds.RealWorldValueMappingSequence[0]
    slope, intercept = rwv.RealWorldValueSlope, rwv.RealWorldValueIntercept
    del ds.RealWorldValueMappingSequence
    ds.RescaleSlope, ds.RescaleIntercept = f"{slope:.10e}", f"{intercept:.10g}"
    ds.save_as(tmp_path / "old.dcm")
    back = load_image(tmp_path / "old.dcm")
    assert np.abs(back - image).max() <= slope * (0.5 + 1e-6)


def test_dicom_tube_spectrum_kvp_and_rendered_line_integral(tmp_path):
    scene = _scene(tmp_path, spectrum={"kvp": 90.0, "filters": {"Al": 2.0}})
    li = xray_viz.render(scene).line_integral
    save_image(tmp_path / "li.dcm", li, scene=scene, quantity="line-integral")
    ds = pydicom.dcmread(tmp_path / "li.dcm")
    assert float(ds.KVP) == 90.0 and ds.PhotometricInterpretation == "MONOCHROME2"
    assert "90 kV" in ds.ImageComments
    np.testing.assert_allclose(load_image(tmp_path / "li.dcm"), li,
                               atol=(li.max() - li.min()) / 65535)


def test_dicom_handles_infinite_and_flat(tmp_path):
    scene = _scene(tmp_path, energy=60.0)
    a = np.ones((17, 23))
    save_image(tmp_path / "flat.dcm", a, scene=scene)
    assert np.allclose(load_image(tmp_path / "flat.dcm"), 1.0)
    a[0, 0] = np.inf
    a[1, 1] = 3.0
    with pytest.warns(RuntimeWarning, match=r"inf\.dcm: 1 of 391 pixels are not finite"):
        save_image(tmp_path / "inf.dcm", a, scene=scene)
    back = load_image(tmp_path / "inf.dcm")
    assert back[0, 0] == pytest.approx(3.0) and back[1, 1] == pytest.approx(3.0)


def test_dicom_needs_scene(tmp_path, image):
    with pytest.raises(OutputError, match="scene"):
        save_image(tmp_path / "a.dcm", image)
    assert not (tmp_path / "a.dcm").exists()


@pytest.mark.parametrize("suffix", [".npy", ".tiff", ".png"])
def test_unwritable_output_names_the_users_path_and_leaves_nothing(tmp_path, suffix):
    blocker = tmp_path / "not_a_folder"
    blocker.write_text("")
    target = blocker / f"x{suffix}"
    with pytest.raises(OutputError, match=r"not_a_folder/x\.\w+: cannot write: .* is a file"):
        save_image(target, np.eye(3))
    missing = Path("/proc/xray_viz_test") / f"x{suffix}"      # /proc refuses new folders
    with pytest.raises(OutputError) as info:
        save_image(missing, np.eye(3))
    assert str(info.value).startswith(f"{missing}: cannot write") and "\n" not in str(info.value)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["not_a_folder"]


def test_written_files_get_the_usual_permissions(tmp_path):
    import os

    mask = os.umask(0o022)
    try:
        out = save_image(tmp_path / "a.png", np.eye(3))
    finally:
        os.umask(mask)
    assert out.stat().st_mode & 0o777 == 0o644          # not mkstemp's private 0600

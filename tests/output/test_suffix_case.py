"""Whatever case a suffix is written in, what is written reads back (issue 42): ``-o image.Nii``
was written, then ``load_image`` said "no such file" (nibabel's suffix lookup); a label map
``labels.MHA`` had no SimpleITK reader. Every image format of ``save_image`` and every volume
format of ``read_volume``, in odd cases, against the lower-case file."""

from __future__ import annotations

import numpy as np
import pytest

import xray_viz
from xray_viz.output import FORMATS, load_image, save_image


def _odd_case(suffix: str) -> str:
    return "".join(c.upper() if k % 2 == 0 else c for k, c in enumerate(suffix))


@pytest.mark.parametrize("suffix", sorted(FORMATS))
def test_save_then_load_any_case(tmp_path, suffix):
    scene = xray_viz.load_scene("sphere")
    image = np.linspace(0.0, 2.0, 6 * 5).reshape(6, 5)
    for name in dict.fromkeys((f"img{suffix}", f"img{_odd_case(suffix)}",
                               f"IMG{suffix.upper()}", f"img{suffix.title()}")):
        folder = tmp_path / name                     # alone: no lower-case twin beside it
        folder.mkdir()
        out = save_image(folder / name, image, scene=scene, quantity="line-integral")
        assert out.name == name and out.exists()
        back, meta = load_image(out, with_metadata=True)
        lower, _ = load_image(tmp_path / f"img{suffix}" / f"img{suffix}", with_metadata=True)
        np.testing.assert_array_equal(back, lower)
        assert meta.format == suffix


@pytest.mark.parametrize("suffix", [".nii", ".nii.gz", ".mha", ".nrrd", ".mhd", ".nhdr"])
def test_read_volume_any_case(tmp_path, suffix):
    sitk = pytest.importorskip("SimpleITK")
    nib = pytest.importorskip("nibabel")
    from xray_viz.meshes.volumes import read_volume

    labels = np.zeros((5, 6, 7), np.uint8)
    labels[1:4, 2:5, 3:6] = 2
    lower = tmp_path / f"lab{suffix}"
    if suffix.startswith(".nii"):
        nib.save(nib.Nifti1Image(labels, np.diag([0.5, 0.5, 2.0, 1.0])), lower)
    else:
        img = sitk.GetImageFromArray(labels.transpose(2, 1, 0).copy())
        img.SetSpacing((0.5, 0.5, 2.0))
        sitk.WriteImage(img, str(lower))
    want = read_volume(lower)
    odd = tmp_path / f"odd{_odd_case(suffix)}"
    odd.write_bytes(lower.read_bytes())                 # a detached header names lab.raw
    got = read_volume(odd)
    np.testing.assert_array_equal(got.data, want.data)
    np.testing.assert_array_equal(got.affine, want.affine)

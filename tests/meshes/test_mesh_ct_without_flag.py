"""``xray-viz mesh`` given a CT without ``--ct`` (issue 42): a DICOM series folder was meshed
as a label map of raw HU values (hundreds of "labels"); now it is refused in one line that
says to use ``--ct``, as are a CT volume file with negative values (air -1000 HU) and one of
thousands of distinct values. With ``--ct`` the same folder meshes its HU classes. (Sibling:
``[[labels]]`` naming a DICOM folder or a CT file goes through the same reader.)"""

from __future__ import annotations

import numpy as np
import pytest

from tests.meshes.test_volumes import write_dicom_series
from xray_viz.cli import main

pytest.importorskip("pydicom")
nib = pytest.importorskip("nibabel")


def _hu():
    hu = np.full((20, 20, 12), -1000.0)
    hu[5:15, 5:15, 3:9] = 40.0
    hu[8:12, 8:12, 4:8] = 900.0
    return hu


def test_ct_folder_without_ct_flag(tmp_path, capsys):
    folder = tmp_path / "series"
    write_dicom_series(folder, _hu(), np.diag([2.0, 2.0, 3.0, 1.0]))
    out = tmp_path / "bodies"
    assert main(["mesh", str(folder), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--ct" in err[0] and "not a label map" in err[0], err
    assert not out.exists()
    assert main(["mesh", str(folder), "--ct", "-o", str(out)]) == 0
    assert len(list(out.glob("*.stl"))) >= 2


@pytest.mark.parametrize("kind", ["hu", "raw"])
def test_ct_file_without_ct_flag(tmp_path, capsys, kind):
    values = _hu().astype(np.int16)
    if kind == "raw":                                  # stored values: 0 .. 4095, no negatives
        values = (values + 1024).astype(np.int16)
        values[values > 0] += np.arange(values[values > 0].size, dtype=np.int16) % 1500
    ct = tmp_path / "ct.nii.gz"
    nib.save(nib.Nifti1Image(values, np.diag([2.0, 2.0, 3.0, 1.0])), ct)
    out = tmp_path / "bodies"
    assert main(["mesh", str(ct), "-o", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--ct" in err[0], err
    assert not out.exists()

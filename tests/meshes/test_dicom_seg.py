"""DICOM-SEG label maps for [[labels]]: a synthetic CT series (pydicom) and its segmentation
(written by highdicom), on a rotated, offset, anisotropic grid."""

import warnings
from pathlib import Path

import numpy as np
import pytest

import xray_viz
from xray_viz.errors import MeshError
from xray_viz.meshes import volumes as V
from xray_viz.meshes.dicom_seg import read_dicom_seg

hd = pytest.importorskip("highdicom")
pydicom = pytest.importorskip("pydicom")

SHAPE = (20, 16, 12)                       # (i: columns, j: rows, k: slices)
SPACING = np.array([0.8, 1.1, 1.5])


def _ras_affine():
    from scipy.spatial.transform import Rotation

    a = np.eye(4)
    a[:3, :3] = Rotation.from_euler("zyx", [25, -15, 10], degrees=True).as_matrix() * SPACING
    a[:3, 3] = [-20.0, 15.0, 40.0]
    return a


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    monkeypatch.delenv("XRAY_VIZ_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg-cache"))


def write_ct_series(folder: Path, affine_ras, shape=SHAPE):
    """Single-frame CT slices (zeros) whose geometry is ``affine_ras`` (voxel -> RAS mm)."""
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian, generate_uid

    folder.mkdir(parents=True, exist_ok=True)
    lps = V.LPS_TO_RAS @ affine_ras
    spacing = np.linalg.norm(lps[:3, :3], axis=0)
    row, col = lps[:3, 0] / spacing[0], lps[:3, 1] / spacing[1]
    study, series, frame = generate_uid(), generate_uid(), generate_uid()
    ni, nj, nk = shape
    slices = []
    for k in range(nk):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = "1.2.840.10008.5.1.4.1.1.2"        # CT Image Storage
        meta.MediaStorageSOPInstanceUID = generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        ds = Dataset()
        ds.file_meta = meta
        ds.SOPClassUID, ds.SOPInstanceUID = meta.MediaStorageSOPClassUID, \
            meta.MediaStorageSOPInstanceUID
        ds.StudyInstanceUID, ds.SeriesInstanceUID, ds.FrameOfReferenceUID = study, series, frame
        ds.Modality, ds.PatientID, ds.PatientName = "CT", "P", "Phantom^Test"
        ds.PatientBirthDate = ds.PatientSex = ds.AccessionNumber = ds.ReferringPhysicianName = ""
        ds.StudyID, ds.StudyDate, ds.StudyTime = "1", "20260101", "000000"
        ds.SeriesNumber, ds.InstanceNumber = 1, k + 1
        ds.ImageType = ["ORIGINAL", "PRIMARY", "AXIAL"]
        ds.ImageOrientationPatient = [*row.tolist(), *col.tolist()]
        ds.ImagePositionPatient = (lps[:3, 3] + k * lps[:3, 2]).tolist()
        ds.PixelSpacing = [float(spacing[1]), float(spacing[0])]   # between rows, columns
        ds.SliceThickness = float(spacing[2])
        ds.Rows, ds.Columns = nj, ni
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 1
        ds.RescaleSlope, ds.RescaleIntercept = 1, 0
        ds.PixelData = np.zeros((nj, ni), np.int16).tobytes()
        pydicom.dcmwrite(folder / f"ct{k:03d}.dcm", ds, enforce_file_format=True)
        slices.append(pydicom.dcmread(folder / f"ct{k:03d}.dcm"))
    return slices


def write_seg(path: Path, slices, labels, names, *, kind="BINARY"):
    """A DICOM-SEG of ``labels`` (i, j, k) over the CT ``slices``, one segment per label."""
    from pydicom.sr.codedict import codes
    from pydicom.uid import generate_uid

    descriptions = [hd.seg.SegmentDescription(
        segment_number=n, segment_label=name, segmented_property_category=codes.SCT.Tissue,
        segmented_property_type=codes.SCT.Bone,
        algorithm_type=hd.seg.SegmentAlgorithmTypeValues.MANUAL) for n, name in names.items()]
    pixels = np.ascontiguousarray(labels.transpose(2, 1, 0)).astype(np.uint8)   # frames, rows, cols
    seg = hd.seg.Segmentation(
        source_images=slices, pixel_array=pixels, segmentation_type=kind,
        segment_descriptions=descriptions, series_instance_uid=generate_uid(), series_number=2,
        sop_instance_uid=generate_uid(), instance_number=1, manufacturer="xray_viz tests",
        manufacturer_model_name="synthetic", software_versions="0", device_serial_number="0")
    seg.save_as(path)
    return path


def nested_boxes():
    labels = np.zeros(SHAPE, np.uint8)
    labels[4:16, 3:13, 2:10] = 1
    labels[8:12, 6:10, 4:8] = 2
    return labels


def test_a_seg_reads_as_the_label_map_at_the_ct_series_positions(tmp_path):
    labels = nested_boxes()
    slices = write_ct_series(tmp_path / "ct", _ras_affine())
    write_seg(tmp_path / "seg.dcm", slices, labels, {1: "bone", 2: "marrow"})
    got, affine, names = read_dicom_seg(tmp_path / "seg.dcm")
    assert names == {1: "bone", 2: "marrow"}
    assert np.bincount(got.ravel(), minlength=3)[1:].tolist() == np.bincount(
        labels.ravel(), minlength=3)[1:].tolist()
    # every labelled voxel lands on the CT voxel of the same label: the CT series read by
    # read_volume (pydicom, its own geometry code) gives the voxel -> world map
    ct = V.read_volume(tmp_path / "ct", hu=True)
    np.testing.assert_allclose(ct.affine, _ras_affine(), atol=1e-6)
    idx = np.argwhere(got > 0)
    world = np.c_[idx, np.ones(len(idx))] @ affine.T
    back = np.linalg.solve(ct.affine, world.T).T[:, :3]
    ijk = np.round(back).astype(int)
    np.testing.assert_allclose(back, ijk, atol=1e-4)
    assert np.array_equal(labels[tuple(ijk.T)], got[tuple(idx.T)])
    vol = V.read_volume(tmp_path / "seg.dcm")               # the [[labels]] reader
    assert np.array_equal(vol.data, got) and np.allclose(vol.affine, affine)


@pytest.mark.parametrize("nested", [False, pytest.param(True, marks=pytest.mark.slow)])
def test_labels_from_a_seg_render_as_the_nifti_of_the_same_map(tmp_path, nested):
    import nibabel as nib

    labels = nested_boxes() if nested else np.minimum(nested_boxes(), 1)
    names = {1: "bone", 2: "marrow"} if nested else {1: "bone"}
    write_seg(tmp_path / "seg.dcm", write_ct_series(tmp_path / "ct", _ras_affine()), labels,
              names)
    nib.save(nib.Nifti1Image(labels, _ras_affine()), str(tmp_path / "seg.nii.gz"))
    centre = _ras_affine() @ [*(np.array(SHAPE) - 1) / 2, 1.0]
    materials = ", ".join(f'{n} = {{ mu = {mu}, name = "{name}" }}'
                          for (n, name), mu in zip(names.items(), (0.1, 0.5)))
    images = []
    for name in ("seg.dcm", "seg.nii.gz"):
        (tmp_path / "scene.toml").write_text(f"""
[source]
position = [{centre[0]}, {centre[1]}, {centre[2] + 500.0}]
kind = "parallel"
energy = 60.0

[detector]
center = [{centre[0]}, {centre[1]}, {centre[2] - 100.0}]
shape = [48, 40]
pitch = 0.6

[[labels]]
file = "{name}"
materials = {{ {materials} }}
""")
        scene = xray_viz.load_scene(tmp_path / "scene.toml")
        assert [b.name for b in scene.bodies] == list(names.values())
        images.append((scene, xray_viz.render(scene, engine="numpy").line_integral))
    (seg_scene, seg), (nii_scene, nii) = images
    for a, b in zip(seg_scene.bodies, nii_scene.bodies):
        assert a.mesh.volume == pytest.approx(b.mesh.volume, rel=0.01)
        np.testing.assert_allclose(a.mesh.center_mass, b.mesh.center_mass, atol=0.05)
    # 8 slices of 1.5 mm of bone (mu 0.1 /cm) along a steep ray, at least; the marrow adds
    assert seg.max() > 0.1 * 8 * 1.5 / 10 * (1 + 0.5 * nested)
    # the same surfaces to the meshing's tolerance: through the bodies the line integrals
    # agree closely (near the boxes' edges the two meshes' decimation may differ a little)
    hit = (seg > 0) | (nii > 0)
    assert hit.sum() > 200
    diff = np.abs(seg - nii)[hit] / seg.max()
    assert np.median(diff) <= 0.02 and diff.mean() <= 0.03     # here: 0.4 % and 0.9 %


def test_overlapping_segments_and_a_non_seg_dcm_are_one_line(tmp_path):
    slices = write_ct_series(tmp_path / "ct", _ras_affine())
    # a CT slice is not a segmentation
    with pytest.raises(MeshError) as info:
        read_dicom_seg(tmp_path / "ct" / "ct000.dcm")
    text = str(info.value)
    assert "not a DICOM Segmentation" in text and "folder" in text and "\n" not in text
    # two segments that share voxels cannot be one label map
    a = np.zeros(SHAPE, bool)
    a[2:10, 2:10, 2:8] = True
    b = np.zeros(SHAPE, bool)
    b[6:14, 6:14, 4:10] = True
    stack = np.stack([a, b], axis=-1).transpose(2, 1, 0, 3).astype(np.uint8)
    from pydicom.sr.codedict import codes
    from pydicom.uid import generate_uid

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        seg = hd.seg.Segmentation(
            source_images=slices, pixel_array=stack, segmentation_type="BINARY",
            segment_descriptions=[hd.seg.SegmentDescription(
                segment_number=n, segment_label=f"s{n}",
                segmented_property_category=codes.SCT.Tissue,
                segmented_property_type=codes.SCT.Bone,
                algorithm_type=hd.seg.SegmentAlgorithmTypeValues.MANUAL) for n in (1, 2)],
            series_instance_uid=generate_uid(), series_number=2, sop_instance_uid=generate_uid(),
            instance_number=1, manufacturer="t", manufacturer_model_name="t",
            software_versions="0", device_serial_number="0")
    seg.save_as(tmp_path / "overlap.dcm")
    with pytest.raises(MeshError, match=r"overlap\.dcm: its segments overlap") as info:
        read_dicom_seg(tmp_path / "overlap.dcm")
    assert "\n" not in str(info.value)
    with pytest.raises(MeshError, match="single .dcm file is read as a DICOM-SEG"):
        V.read_volume(tmp_path / "overlap.dcm", hu=True)

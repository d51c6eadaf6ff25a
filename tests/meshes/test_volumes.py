"""Label maps and CT volumes as bodies (xray_viz.meshes.volumes, the [[labels]] / [[ct]] tables,
``xray-viz mesh VOLUME -o FOLDER``).

The label maps are written here: ellipsoids sampled at the voxel centres of a rotated, offset,
anisotropic grid, so the truth is analytic. What is checked: the rendered chords against the
analytic ellipsoid within the stated surface tolerance, the centre where the affine puts it,
NIfTI (RAS) and NRRD/MHA (LPS) giving the same bodies, the nested label winning, the cache,
the DICOM reader against SimpleITK's, the HU classes, and one-line errors through the CLI.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

nib = pytest.importorskip("nibabel")
sitk = pytest.importorskip("SimpleITK")

import xray_viz  # noqa: E402
from xray_viz import cli  # noqa: E402
from xray_viz.errors import MaterialError, MeshError, SceneError  # noqa: E402
from xray_viz.geometry import detector_rays  # noqa: E402
from xray_viz.meshes import volumes as V  # noqa: E402
from helpers import doctest_examples  # noqa: E402

SHAPE = (40, 36, 32)
SPACING = np.array([0.8, 1.0, 1.3])
OFFSET = np.array([-20.0, 15.0, 40.0])
AXES = np.array([12.0, 9.0, 8.0])       # semi-axes (mm) of the outer ellipsoid
INNER = 0.5                             # the inner ellipsoid: the outer one scaled by this
MAX_ERROR = 0.2


def _rotation(zyx_deg):
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("zyx", zyx_deg, degrees=True).as_matrix()


GRID_ROTATION = _rotation([25, -15, 10])
BODY_ROTATION = _rotation([30, 0, 0])   # the ellipsoid's own axes in the world


def grid_affine():
    a = np.eye(4)
    a[:3, :3] = GRID_ROTATION * SPACING
    a[:3, 3] = OFFSET
    return a


def centre():
    """World centre (mm, RAS) of the ellipsoids: the middle of the grid."""
    a = grid_affine()
    return a[:3, :3] @ ((np.array(SHAPE) - 1) / 2) + a[:3, 3]


def label_map(nested=True):
    """Label 1 = outer ellipsoid, 2 = inner ellipsoid (if nested), sampled at voxel centres."""
    a = grid_affine()
    idx = np.stack(np.indices(SHAPE), -1).reshape(-1, 3)
    local = (idx @ a[:3, :3].T + a[:3, 3] - centre()) @ BODY_ROTATION
    lab = np.zeros(len(idx), np.uint8)
    lab[((local / AXES) ** 2).sum(1) <= 1] = 1
    if nested:
        lab[((local / (AXES * INNER)) ** 2).sum(1) <= 1] = 2
    return lab.reshape(SHAPE)


def write_nifti(path, data, affine=None):
    nib.save(nib.Nifti1Image(data, grid_affine() if affine is None else affine), str(path))
    return path


def write_itk(path, data, affine_ras=None):
    """The same volume for ITK: LPS geometry, array [k, j, i]."""
    lps = V.LPS_TO_RAS @ (grid_affine() if affine_ras is None else affine_ras)
    spacing = np.linalg.norm(lps[:3, :3], axis=0)
    img = sitk.GetImageFromArray(np.ascontiguousarray(data.transpose(2, 1, 0)))
    img.SetSpacing(spacing.tolist())
    img.SetDirection((lps[:3, :3] / spacing).ravel().tolist())
    img.SetOrigin(lps[:3, 3].tolist())
    sitk.WriteImage(img, str(path))
    return path


@pytest.fixture(autouse=True)
def _private_cache(tmp_path, monkeypatch):
    """Every test caches in its own folder (the user cache folder via XDG_CACHE_HOME)."""
    monkeypatch.delenv("XRAY_VIZ_CACHE_DIR", raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg-cache"))


def scene_text(tables: str, *, kind="parallel", shape=(96, 96), pitch=0.5) -> str:
    c = centre()
    return f"""
[source]
position = [{c[0]}, {c[1]}, {c[2] + 500.0}]
kind = "{kind}"
energy = 60.0

[detector]
center = [{c[0]}, {c[1]}, {c[2] - 100.0}]
up = [0.0, 1.0, 0.0]
shape = [{shape[0]}, {shape[1]}]
pitch = {pitch}

{tables}
"""


def write_scene(tmp_path, tables, **kw) -> Path:
    p = tmp_path / "scene.toml"
    p.write_text(scene_text(tables, **kw))
    return p


# --------------------------------------------------------------------------------------------
# analytic chords


def ellipsoid_chords(origins, directions, axes, *, rotation=BODY_ROTATION, at=None):
    """Chord lengths (mm) of rays through the ellipsoid, and the |cos| of the angle between
    the ray and the surface normal at its entry and exit (0 for a miss)."""
    at = centre() if at is None else at
    o = (origins - at) @ rotation / axes
    d = directions @ rotation / axes
    a = (d * d).sum(1)
    b = 2 * (o * d).sum(1)
    c = (o * o).sum(1) - 1
    disc = b * b - 4 * a * c
    hit = disc > 0
    sq = np.sqrt(np.where(hit, disc, 0))
    t0, t1 = (-b - sq) / (2 * a), (-b + sq) / (2 * a)
    chord = np.where(hit, (t1 - t0) * np.linalg.norm(directions, axis=1), 0.0)
    cos = []
    for t in (t0, t1):
        p_local = (origins + t[:, None] * directions - at) @ rotation
        normal = (p_local / axes ** 2) @ rotation.T
        normal /= np.linalg.norm(normal, axis=1)[:, None]
        cos.append(np.where(hit, np.abs((normal * directions).sum(1)), 0.0))
    return chord, cos[0], cos[1]


def surface_tolerance(max_error):
    """How far (mm) a body's surface may lie from the analytic one, as stated: the voxel
    surface (half-way between a voxel centre inside and its neighbour outside) lies within
    half a voxel diagonal of the true surface, smoothing stays within half a voxel diagonal of
    the voxel surface (``smoothing_limit``), and decimation within ``max_error`` of that."""
    return max_error + 2 * V.smoothing_limit(grid_affine())


def analytic_distance(points, axes=AXES):
    """Distance (mm, first order: the surfaces are close) of points to the ellipsoid."""
    local = (points - centre()) @ BODY_ROTATION
    f = ((local / axes) ** 2).sum(1)
    return np.abs(f - 1) / np.linalg.norm(2 * local / axes ** 2, axis=1)


# --------------------------------------------------------------------------------------------
# label maps


def test_nifti_chords_agree_with_the_analytic_ellipsoid(tmp_path):
    write_nifti(tmp_path / "seg.nii.gz", label_map(nested=False))
    scene = xray_viz.load_scene(write_scene(tmp_path, f"""
[[labels]]
file = "seg.nii.gz"
materials = {{ 1 = {{ mu = 0.2 }} }}
max_error = {MAX_ERROR}
"""))
    (body,) = scene.bodies
    assert body.name == "seg_1" and body.mu == 0.2 and body.mesh.is_watertight
    image = xray_viz.render(scene, engine="numpy").quantity("path-length")
    rays = detector_rays(scene)
    chord, cin, cout = ellipsoid_chords(rays.origins, rays.directions, AXES)
    got = image.ravel()
    steep = (cin > 0.5) & (cout > 0.5)
    assert steep.sum() > 500                       # most of the ellipsoid's shadow
    tol = surface_tolerance(MAX_ERROR) * (1 / cin[steep] + 1 / cout[steep])
    err = got[steep] - chord[steep]
    assert np.all(np.abs(err) <= tol)
    # smoothed without shrinking: no bias beyond a tenth of a voxel per surface (a chord
    # crosses two)
    assert abs(np.mean(err)) < 2 * 0.1 * SPACING.min()
    # and the shadow is where the ellipsoid's is (outside it, nothing)
    assert np.all(got[chord == 0] < 2 * surface_tolerance(MAX_ERROR) + 1e-9)


def test_every_vertex_within_the_tolerance_of_the_ellipsoid_and_hausdorff_reported(tmp_path):
    write_nifti(tmp_path / "seg.nii", label_map(nested=False))
    out = V.label_surfaces(tmp_path / "seg.nii", [1], max_error=MAX_ERROR)
    (s,) = out.surfaces
    assert 0 < s.hausdorff <= V.smoothing_limit(grid_affine()) + MAX_ERROR
    assert s.voxels == int((label_map(nested=False) == 1).sum())
    assert analytic_distance(s.mesh.vertices).max() <= surface_tolerance(MAX_ERROR)
    # smoothing takes the voxel staircase off: the body lies closer to the true surface than
    # the voxel surface does (root mean square over points sampled evenly on each)
    raw = V.voxel_surface(label_map(nested=False) == 1, grid_affine())
    rms = [np.sqrt(np.mean(analytic_distance(m.sample(20000, seed=1)) ** 2))
           for m in (s.mesh, raw)]
    assert rms[0] < 0.8 * rms[1]
    # decimated: far fewer faces than the voxel surface
    assert len(s.mesh.faces) < 0.5 * len(raw.faces)


def test_centre_and_volume_land_where_the_affine_says(tmp_path):
    write_nifti(tmp_path / "seg.nii.gz", label_map(nested=False))
    (s,) = V.label_surfaces(tmp_path / "seg.nii.gz", [1], max_error=MAX_ERROR).surfaces
    assert np.allclose(s.mesh.center_mass, centre(), atol=0.1)
    assert s.mesh.volume == pytest.approx(4 / 3 * np.pi * AXES.prod(), rel=0.02)
    # far from the grid's own origin and axes: the affine was applied
    assert np.linalg.norm(centre() - OFFSET) > 20


@pytest.mark.parametrize("suffix", [".nrrd", ".mha"])
def test_itk_formats_give_the_same_bodies_as_nifti(tmp_path, suffix):
    from xray_viz.meshes import hausdorff_distance

    data = label_map()
    nii, itk = write_nifti(tmp_path / "seg.nii.gz", data), write_itk(tmp_path / f"seg{suffix}",
                                                                      data)
    va, vb = V.read_volume(nii), V.read_volume(itk)
    assert np.array_equal(va.data, vb.data)
    assert np.allclose(va.affine, vb.affine, atol=1e-5)   # NIfTI stores float32
    # the same voxel surfaces (to float32) ...
    for label in (1, 2):
        ra = V.voxel_surface(va.data == label, va.affine)
        rb = V.voxel_surface(vb.data == label, vb.affine)
        assert np.allclose(ra.vertices, rb.vertices, atol=1e-4)
    # ... and bodies within the tolerance of each other (decimation may stop elsewhere)
    a = V.label_surfaces(nii, [1, 2], max_error=MAX_ERROR)
    b = V.label_surfaces(itk, [1, 2], max_error=MAX_ERROR)
    for sa, sb in zip(a.surfaces, b.surfaces):
        assert sa.label == sb.label
        assert hausdorff_distance(sa.mesh, sb.mesh) <= 2 * MAX_ERROR
        assert np.allclose(sa.mesh.center_mass, sb.mesh.center_mass, atol=0.05)


def test_convention_ras_matches_itk_reading_the_nifti(tmp_path):
    """SimpleITK reads the same NIfTI in LPS: its physical point of a voxel, x and y negated,
    is the scene's point (an independent check of LPS_TO_RAS and of the NIfTI affine)."""
    path = write_nifti(tmp_path / "seg.nii.gz", label_map())
    vol = V.read_volume(path)
    img = sitk.ReadImage(str(path))
    for ijk in [(0, 0, 0), (39, 0, 0), (3, 30, 7), (39, 35, 31)]:
        lps = np.array(img.TransformIndexToPhysicalPoint(tuple(int(v) for v in ijk)))
        ras = (vol.affine @ [*ijk, 1])[:3]
        assert np.allclose(ras, lps * [-1, -1, 1], atol=1e-4)
    itk = V.read_volume(write_itk(tmp_path / "seg.mha", label_map()))
    assert np.allclose(itk.affine, vol.affine, atol=1e-5)
    assert np.array_equal(itk.data, vol.data)


def test_nested_label_gets_the_inner_material(tmp_path):
    write_nifti(tmp_path / "seg.nii.gz", label_map(nested=True))
    scene = xray_viz.load_scene(write_scene(tmp_path, f"""
[[labels]]
file = "seg.nii.gz"
materials = {{ 1 = {{ mu = 0.1, name = "bone" }}, 2 = {{ mu = 0.5, name = "marrow" }} }}
max_error = {MAX_ERROR}
"""))
    assert [b.name for b in scene.bodies] == ["bone", "marrow"]
    # the bone's body is solid (its hole holds the listed label 2): marrow lies inside it
    assert scene.bodies[0].mesh.volume == pytest.approx(4 / 3 * np.pi * AXES.prod(), rel=0.02)
    image = xray_viz.render(scene, engine="numpy").quantity("line-integral")
    rays = detector_rays(scene)
    outer, cin, cout = ellipsoid_chords(rays.origins, rays.directions, AXES)
    inner, iin, iout = ellipsoid_chords(rays.origins, rays.directions, AXES * INNER)
    # 1/cm * mm / 10: the inner material replaces the outer one inside it
    expected = (0.1 * (outer - inner) + 0.5 * inner) / 10
    steep = (iin > 0.5) & (iout > 0.5) & (cin > 0.5) & (cout > 0.5)
    assert steep.sum() > 100
    cin, cout, iin, iout = cin[steep], cout[steep], iin[steep], iout[steep]
    tol = surface_tolerance(MAX_ERROR) * (0.1 * (1 / cin + 1 / cout)
                                          + 0.4 * (1 / iin + 1 / iout)) / 10
    assert np.all(np.abs(image.ravel()[steep] - expected[steep]) <= tol)
    # the outer material alone would be far below, both summed far above
    centre_ray = np.argmax(inner)
    got = image.ravel()[centre_ray]
    assert got > 0.1 * outer[centre_ray] / 10 + 0.3 * inner[centre_ray] / 10
    assert got < (0.1 * outer[centre_ray] + 0.5 * inner[centre_ray]) / 10 - 0.05 * inner[
        centre_ray] / 10


def test_unlisted_labels_are_skipped_with_a_warning(tmp_path):
    write_nifti(tmp_path / "seg.nii.gz", label_map(nested=True))
    path = write_scene(tmp_path, """
[[labels]]
file = "seg.nii.gz"
materials = { 1 = "Tissue, Soft (ICRP)" }
""")
    with pytest.warns(V.LabelSkippedWarning, match=r"\[\[labels\]\] #1.*label 2 not in"):
        scene = xray_viz.load_scene(path)
    (body,) = scene.bodies
    assert body.material == "Tissue, Soft (ICRP)"
    # not nested any more: label 2 is not listed, so its voxels are a cavity in label 1
    assert body.mesh.volume == pytest.approx(4 / 3 * np.pi * AXES.prod() * (1 - INNER ** 3),
                                             rel=0.05)


def test_second_load_reads_the_cache_file(tmp_path, monkeypatch):
    write_nifti(tmp_path / "seg.nii.gz", label_map(nested=True))
    first = V.label_surfaces(tmp_path / "seg.nii.gz", [1, 2], max_error=MAX_ERROR)
    assert not first.cache_hit and first.cache_file.is_file()
    assert first.cache_file.is_relative_to(tmp_path / "xdg-cache" / "xray_viz")

    def no_meshing(*args, **kw):
        raise AssertionError("meshed again instead of reading the cache")

    monkeypatch.setattr(V, "_mesh_labels", no_meshing)
    second = V.label_surfaces(tmp_path / "seg.nii.gz", [1, 2], max_error=MAX_ERROR)
    assert second.cache_hit and second.cache_file == first.cache_file
    for a, b in zip(first.surfaces, second.surfaces):
        assert np.array_equal(a.mesh.vertices, b.mesh.vertices)
        assert np.array_equal(a.mesh.faces, b.mesh.faces)
        assert (a.name, a.hausdorff, a.voxels) == (b.name, b.hausdorff, b.voxels)
    # another parameter or other file contents: another entry, meshed again
    with pytest.raises(AssertionError, match="meshed again"):
        V.label_surfaces(tmp_path / "seg.nii.gz", [1, 2], max_error=0.3)
    data = label_map(nested=True)
    data[0, 0, 0] = 2
    write_nifti(tmp_path / "seg.nii.gz", data)
    with pytest.raises(AssertionError, match="meshed again"):
        V.label_surfaces(tmp_path / "seg.nii.gz", [1, 2], max_error=MAX_ERROR)


def test_a_corrupt_cache_file_is_ignored_and_rewritten(tmp_path):
    write_nifti(tmp_path / "seg.nii.gz", label_map(nested=False))
    first = V.label_surfaces(tmp_path / "seg.nii.gz", [1], max_error=1.0)
    first.cache_file.write_bytes(b"garbage")
    again = V.label_surfaces(tmp_path / "seg.nii.gz", [1], max_error=1.0)
    assert not again.cache_hit and again.cache_file == first.cache_file
    assert V.label_surfaces(tmp_path / "seg.nii.gz", [1], max_error=1.0).cache_hit


def test_an_unwritable_user_cache_is_off_with_one_warning(tmp_path, monkeypatch):
    """The one rule of :mod:`xray_viz._cache`: a cache folder that cannot be written is off
    (the volume is meshed, not cached), said once."""
    from xray_viz._cache import CacheWarning

    blocked = tmp_path / "not-a-folder"
    blocked.write_text("a file where the cache folder would be")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocked))
    write_nifti(tmp_path / "seg.nii.gz", label_map(nested=False))
    with pytest.warns(CacheWarning, match="cannot be written") as said:
        assert V.cache_dir() is None and V.cache_dir() is None
        first = V.label_surfaces(tmp_path / "seg.nii.gz", [1], max_error=1.0)
    assert first.cache_file is None and not first.cache_hit
    notices = [str(w.message) for w in said if "meshed volumes" in str(w.message)]
    assert len(notices) == 1 and "meshed volumes are not cached" in notices[0]


# --------------------------------------------------------------------------------------------
# CT volumes


def ct_volume():
    """HU: air around soft tissue (40 HU) around cortical bone (1200 HU), with noise."""
    rng = np.random.default_rng(3)
    lab = label_map(nested=True)
    hu = np.choose(lab, [-1000.0, 40.0, 1200.0]) + rng.normal(0, 15, lab.shape)
    return hu


def test_ct_is_segmented_by_the_schneider_table(tmp_path):
    hu = ct_volume()
    write_nifti(tmp_path / "ct.nii.gz", hu.astype(np.float32))
    scene = xray_viz.load_scene(write_scene(tmp_path, """
[[ct]]
file = "ct.nii.gz"
trace = "meshes"
max_error = 0.2
"""))
    names = [b.name for b in scene.bodies]
    assert names == ["ct_soft_tissue", "ct_cortical_bone"]
    soft, bone = scene.bodies
    assert soft.material == "Tissue, Soft (ICRP)" and bone.material == "Bone, Cortical (ICRP)"
    assert soft.mesh.volume == pytest.approx(4 / 3 * np.pi * AXES.prod(), rel=0.03)
    assert bone.mesh.volume == pytest.approx(4 / 3 * np.pi * (AXES * INNER).prod(), rel=0.06)


def test_ct_ranges_override_the_default(tmp_path):
    write_nifti(tmp_path / "ct.nii.gz", ct_volume().astype(np.float32))
    scene = xray_viz.load_scene(write_scene(tmp_path, """
[[ct]]
file = "ct.nii.gz"
trace = "meshes"
max_error = 0.5
ranges = [
  { hu = [-200, 300], mu = 0.2, name = "soft" },
  { hu = [300, 4000], material = "Al", density = 2.7, name = "metal" },
]
"""))
    assert [(b.name, b.mu, b.material) for b in scene.bodies] == [
        ("soft", 0.2, None), ("metal", None, "Al")]


def test_classify_hu_boundaries_and_speckle():
    lows = [r[1] for r in V.SCHNEIDER_2000]
    hu = np.array(lows + [-951.0, 5000.0], dtype=float).reshape(1, 1, -1)
    classes = classify = V.classify_hu(hu, median=1, min_voxels=0)
    assert classify.ravel().tolist() == [1, 2, 3, 4, 5, 0, 5]
    # one voxel of bone in soft tissue is speckle: it takes its neighbours' class
    hu = np.full((7, 7, 7), 40.0)
    hu[3, 3, 3] = 1200.0
    assert np.all(V.classify_hu(hu, median=1, min_voxels=8) == 3)
    assert V.classify_hu(hu, median=1, min_voxels=0)[3, 3, 3] == 5
    assert np.all(V.classify_hu(hu, median=3, min_voxels=0) == 3)
    del classes


def write_dicom_series(folder: Path, hu: np.ndarray, affine_ras: np.ndarray):
    """One CT slice per k, geometry from the affine (LPS in the DICOM tags)."""
    import pydicom
    from pydicom.dataset import Dataset, FileMetaDataset
    from pydicom.uid import CTImageStorage, ExplicitVRLittleEndian, generate_uid

    folder.mkdir()
    lps = V.LPS_TO_RAS @ affine_ras
    col_step, row_step, slice_step = lps[:3, 0], lps[:3, 1], lps[:3, 2]
    dc, dr = np.linalg.norm(col_step), np.linalg.norm(row_step)
    series, study = generate_uid(), generate_uid()
    stored = np.round(hu + 1024).astype(np.uint16)
    order = np.random.default_rng(0).permutation(hu.shape[2])   # files not in slice order
    for n, k in enumerate(order):
        meta = FileMetaDataset()
        meta.MediaStorageSOPClassUID = CTImageStorage
        meta.MediaStorageSOPInstanceUID = generate_uid()
        meta.TransferSyntaxUID = ExplicitVRLittleEndian
        ds = Dataset()
        ds.file_meta = meta
        ds.SOPClassUID, ds.SOPInstanceUID = CTImageStorage, meta.MediaStorageSOPInstanceUID
        ds.Modality = "CT"
        ds.StudyInstanceUID, ds.SeriesInstanceUID = study, series
        ds.Rows, ds.Columns = hu.shape[1], hu.shape[0]
        ds.PixelSpacing = [f"{dr:.10g}", f"{dc:.10g}"]
        ds.ImageOrientationPatient = [f"{v:.10g}" for v in
                                      [*(col_step / dc), *(row_step / dr)]]
        ds.ImagePositionPatient = [f"{v:.10g}" for v in lps[:3, 3] + k * slice_step]
        ds.SliceThickness = f"{np.linalg.norm(slice_step):.10g}"
        ds.RescaleIntercept, ds.RescaleSlope = "-1024", "1"
        ds.SamplesPerPixel, ds.PhotometricInterpretation = 1, "MONOCHROME2"
        ds.BitsAllocated, ds.BitsStored, ds.HighBit, ds.PixelRepresentation = 16, 16, 15, 0
        ds.PixelData = np.ascontiguousarray(stored[:, :, k].T).tobytes()
        ds.InstanceNumber = int(k) + 1
        pydicom.dcmwrite(folder / f"IM{n:04d}.dcm", ds, enforce_file_format=True)


def test_dicom_series_reads_as_simpleitk_reads_it(tmp_path):
    hu = np.clip(np.round(ct_volume()[:, :, :12]), -1024, None)   # stored unsigned
    affine = grid_affine()
    write_dicom_series(tmp_path / "series", hu, affine)
    vol = V.read_volume(tmp_path / "series", hu=True)
    assert np.array_equal(vol.data, hu)
    assert np.allclose(vol.affine, affine, atol=1e-6)
    reader = sitk.ImageSeriesReader()
    reader.SetFileNames(reader.GetGDCMSeriesFileNames(str(tmp_path / "series")))
    img = reader.Execute()
    assert np.array_equal(sitk.GetArrayFromImage(img).transpose(2, 1, 0), hu)
    for ijk in [(0, 0, 0), (39, 35, 11), (5, 20, 3)]:
        lps = np.array(img.TransformIndexToPhysicalPoint(ijk))
        assert np.allclose((vol.affine @ [*ijk, 1])[:3], lps * [-1, -1, 1], atol=1e-4)


# --------------------------------------------------------------------------------------------
# xray-viz mesh VOLUME -o FOLDER


def test_mesh_command_writes_meshes_and_a_scene_snippet(tmp_path, capsys):
    write_nifti(tmp_path / "seg.nii.gz", label_map(nested=True))
    rc = cli.main(["mesh", str(tmp_path / "seg.nii.gz"), "-o", str(tmp_path / "bodies"),
                   "--max-error", str(MAX_ERROR)])
    out = capsys.readouterr().out
    assert rc == 0
    assert sorted(p.name for p in (tmp_path / "bodies").iterdir()) == [
        "seg.toml", "seg_1.stl", "seg_2.stl"]
    assert "seg_1" in out and "Hausdorff" in out
    snippet = (tmp_path / "bodies" / "seg.toml").read_text()
    # the snippet is [[body]] tables with a placeholder material to edit; it loads as is
    scene_file = tmp_path / "bodies" / "scene.toml"
    scene_file.write_text(scene_text(snippet))
    scene = xray_viz.load_scene(scene_file)
    direct = V.label_surfaces(tmp_path / "seg.nii.gz", [1, 2], max_error=MAX_ERROR)
    assert [b.name for b in scene.bodies] == ["seg_1", "seg_2"]
    for body, s in zip(scene.bodies, direct.surfaces):
        assert np.allclose(body.mesh.bounds, s.mesh.bounds, atol=1e-4)  # STL is float32


# --------------------------------------------------------------------------------------------
# bad input: one line through the CLI


def run_cli(args, capsys):
    rc = cli.main(args)
    err = capsys.readouterr().err
    return rc, err


@pytest.mark.parametrize("case, tables, expect", [
    ("missing file", 'file = "nope.nii.gz"\nmaterials = { 1 = { mu = 0.2 } }',
     r"\[\[labels\]\] #1 file 'nope.nii.gz': volume file not found"),
    ("label not an int", 'file = "seg.nii.gz"\nmaterials = { one = { mu = 0.2 } }',
     r"materials: 'one' is not a label"),
    ("label zero", 'file = "seg.nii.gz"\nmaterials = { 0 = { mu = 0.2 } }',
     r"materials: '0' is not a label"),
    ("unknown material", 'file = "seg.nii.gz"\nmaterials = { 1 = "Unobtainium" }',
     r"materials.1 .*Unobtainium"),
    ("no mu nor material", 'file = "seg.nii.gz"\nmaterials = { 1 = { density = 1.0 } }',
     r"materials.1 needs one of 'mu'"),
    ("unknown key", 'file = "seg.nii.gz"\nmaterials = { 1 = { mu = 0.2 } }\nsmooth = 3',
     r"unknown key 'smooth'"),
    ("bad max_error", 'file = "seg.nii.gz"\nmaterials = { 1 = { mu = 0.2 } }\nmax_error = -1',
     r"max_error must be a number > 0"),
    ("empty label", 'file = "seg.nii.gz"\nmaterials = { 1 = { mu = 0.2 }, 9 = { mu = 0.1 } }',
     r"label 9 has no voxels \(labels present: 1\)"),
    ("4D volume", 'file = "four.nii.gz"\nmaterials = { 1 = { mu = 0.2 } }',
     r"four.nii.gz: a 4D volume of shape \[4, 4, 4, 2\]"),
    ("not a label map", 'file = "float.nii.gz"\nmaterials = { 1 = { mu = 0.2 } }',
     r"not a label map: it holds values that are not whole numbers"),
    ("not a volume", 'file = "scene.toml"\nmaterials = { 1 = { mu = 0.2 } }',
     r"not a volume file"),
])
def test_bad_labels_tables_are_one_line(tmp_path, capsys, case, tables, expect):
    small = np.zeros((8, 8, 8), np.uint8)
    small[2:6, 2:6, 2:6] = 1
    write_nifti(tmp_path / "seg.nii.gz", small, np.eye(4))
    nib.save(nib.Nifti1Image(np.ones((4, 4, 4, 2), np.uint8), np.eye(4)),
             str(tmp_path / "four.nii.gz"))
    nib.save(nib.Nifti1Image(np.full((4, 4, 4), 0.5, np.float32), np.eye(4)),
             str(tmp_path / "float.nii.gz"))
    scene = write_scene(tmp_path, f"[[labels]]\n{tables}\n")
    out = tmp_path / "out.npy"
    rc, err = run_cli(["render", str(scene), "-o", str(out)], capsys)
    assert rc == 2, case
    assert err.count("\n") == 1 and err.startswith("xray-viz: error: "), err
    assert "Traceback" not in err
    import re

    assert re.search(expect, err), err
    assert str(scene) in err
    assert not out.exists()


def test_bad_ct_ranges_are_one_line(tmp_path, capsys):
    write_nifti(tmp_path / "ct.nii.gz", np.zeros((4, 4, 4), np.float32), np.eye(4))
    for ranges, expect in [
        ('[{ hu = [100, 0], mu = 0.2 }]', "hu must be [low, high] HU with low < high"),
        ('[{ hu = [0, 100], mu = 0.2 }, { hu = [50, 200], mu = 0.3 }]', "overlap"),
        ('"soft"', "ranges must be an array of tables"),
    ]:
        scene = write_scene(tmp_path, f'[[ct]]\nfile = "ct.nii.gz"\nranges = {ranges}\n')
        rc, err = run_cli(["render", str(scene), "-o", str(tmp_path / "o.npy")], capsys)
        assert rc == 2 and err.count("\n") == 1 and expect in err, err


def test_mesh_command_bad_volume_is_one_line(tmp_path, capsys):
    nib.save(nib.Nifti1Image(np.zeros((4, 4, 4), np.uint8), np.eye(4)),
             str(tmp_path / "empty.nii.gz"))
    rc, err = run_cli(["mesh", str(tmp_path / "empty.nii.gz"), "-o", str(tmp_path / "b")],
                      capsys)
    assert rc == 2 and err.count("\n") == 1 and "no labels" in err, err
    assert not (tmp_path / "b").exists()
    rc, err = run_cli(["mesh", str(tmp_path / "missing.nii"), "-o", str(tmp_path / "b")],
                      capsys)
    assert rc == 2 and "not found" in err and err.count("\n") == 1


def test_errors_subclass_builtins():
    assert issubclass(MeshError, ValueError) and issubclass(SceneError, ValueError)
    assert issubclass(MaterialError, ValueError)


def test_docstring_examples():
    assert doctest_examples(V) > 0           # pytest runs them (--doctest-modules), once


@pytest.mark.slow   # ~10 s of CPU (pymeshlab decimation of two organs); the default suite's
def test_a_real_segmentation_pyvistas_frog(tmp_path):  # synthetic label maps cover the same code
    """pyvista's frog_tissues.vti (shipped in its wheel), written as NIfTI at the frog
    phantom's 0.25 mm per unit: the brain and the eye come out closed, and as large as the frog
    phantom's own meshes of them (made independently: Gaussian-smoothed iso-surfaces)."""
    from pyvista import examples

    from xray_viz import phantoms

    data = examples.load_frog_tissues()
    labels = np.asarray(data.point_data["MetaImage"]).reshape(data.dimensions[::-1])
    affine = np.diag([*(np.asarray(data.spacing) * 0.25), 1.0])
    affine[:3, 3] = np.asarray(data.origin) * 0.25
    write_nifti(tmp_path / "frog.nii.gz", np.ascontiguousarray(labels.transpose(2, 1, 0))
                .astype(np.uint8), affine)
    out = V.label_surfaces(tmp_path / "frog.nii.gz", [2, 5], max_error=0.1)
    assert set(out.skipped) >= set(range(6, 16))
    import trimesh

    for s, name in zip(out.surfaces, ["brain", "eye_white"]):
        shipped = trimesh.load(phantoms._root() / "frog" / f"{name}.stl")
        assert s.mesh.is_watertight and s.mesh.volume > 0
        assert s.hausdorff <= V.smoothing_limit(affine) + 0.1
        assert s.mesh.volume == pytest.approx(s.voxels * np.prod(np.diag(affine)[:3]),
                                              rel=0.05)
        assert s.mesh.volume == pytest.approx(shipped.volume, rel=0.05)


# --------------------------------------------------------------------------------------------
# the cache is keyed by every byte the meshing reads (issue 42: a header's data file changed)


def _data_file(header: Path) -> Path:
    """The data file a detached header (.mhd / .nhdr) names."""
    for line in header.read_text(errors="replace").splitlines():
        key, _, value = line.partition("=" if header.suffix == ".mhd" else ":")
        if key.strip().lower() in ("elementdatafile", "data file", "datafile"):
            return header.with_name(value.strip())
    raise AssertionError(f"{header} names no data file")


@pytest.mark.parametrize("suffix", [".mhd", ".nhdr"])
@pytest.mark.parametrize("kind", ["labels", "ct"])
def test_a_changed_data_file_of_a_detached_header_is_meshed_again(tmp_path, suffix, kind):
    """Only the data file (.raw) of a .mhd / .nhdr changes, its header stays byte for byte:
    the bodies and the render follow the new data, not the cached old bodies."""
    if kind == "labels":
        before = label_map(nested=True)
        after = np.where(before == 2, 1, before).astype(np.uint8)
        half = SHAPE[2] // 2
        after[:, :, :half][before[:, :, :half] == 2] = 2      # half the marrow left
        table = f"""
[[labels]]
file = "seg{suffix}"
materials = {{ 1 = {{ mu = 0.1, name = "bone" }}, 2 = {{ mu = 0.5, name = "marrow" }} }}
max_error = {MAX_ERROR}
"""
    else:
        lab = label_map(nested=True)
        before = np.choose(lab, [-1000.0, 40.0, 1200.0]).astype(np.float32)
        after = np.choose(lab, [-1000.0, 40.0, 40.0]).astype(np.float32)  # no bone any more
        table = f"""
[[ct]]
file = "seg{suffix}"
trace = "meshes"
max_error = {MAX_ERROR}
min_voxels = 0
"""
    header = write_itk(tmp_path / f"seg{suffix}", before)
    data_file = _data_file(header)
    scene_path = write_scene(tmp_path, table, shape=(48, 48), pitch=1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", V.LabelSkippedWarning)
        first = xray_viz.load_scene(scene_path)
        image_before = xray_viz.render(first, engine="numpy").quantity("line-integral")
        (tmp_path / "other").mkdir()
        other = write_itk(tmp_path / "other" / f"seg{suffix}", after)
        header_bytes = header.read_bytes()
        data_file.write_bytes(_data_file(other).read_bytes())
        assert header.read_bytes() == header_bytes
        second = xray_viz.load_scene(scene_path)
        image_after = xray_viz.render(second, engine="numpy").quantity("line-integral")
    assert [b.name for b in first.bodies] != [b.name for b in second.bodies] or not np.allclose(
        image_before, image_after)
    # the render of the changed file is the render of a fresh, uncached meshing of it
    fresh = xray_viz.load_scene(write_scene(tmp_path / "other", table, shape=(48, 48),
                                            pitch=1.0))
    assert [b.name for b in second.bodies] == [b.name for b in fresh.bodies]
    assert np.allclose(image_after, xray_viz.render(fresh, engine="numpy").quantity(
        "line-integral"), atol=1e-12)


def test_ct_volumes_of_equal_voxels_but_other_names_keep_their_own_names(tmp_path):
    """The bodies' names come from the file name: two files with the same voxels do not share
    a cache entry's names."""
    hu = ct_volume().astype(np.float32)
    write_nifti(tmp_path / "knee.nii.gz", hu)
    write_nifti(tmp_path / "wrist.nii.gz", hu)
    a = V.ct_surfaces(tmp_path / "knee.nii.gz", max_error=0.5)
    b = V.ct_surfaces(tmp_path / "wrist.nii.gz", max_error=0.5)
    assert [s.name for s in a.surfaces] == ["knee_soft_tissue", "knee_cortical_bone"]
    assert [s.name for s in b.surfaces] == ["wrist_soft_tissue", "wrist_cortical_bone"]


def test_a_changed_dicom_slice_is_meshed_again(tmp_path):
    import pydicom

    hu = np.clip(np.round(ct_volume()[:, :, :12]), -1024, None)
    write_dicom_series(tmp_path / "series", hu, grid_affine())
    a = V.ct_surfaces(tmp_path / "series", max_error=0.5)
    for f in sorted((tmp_path / "series").iterdir())[:6]:   # soft tissue becomes adipose
        ds = pydicom.dcmread(f)
        px = ds.pixel_array.copy()
        px[(px >= 1024 + 19) & (px < 1024 + 120)] = 1024 - 60
        ds.PixelData = px.tobytes()
        ds.save_as(f, enforce_file_format=True)
    b = V.ct_surfaces(tmp_path / "series", max_error=0.5)
    assert not b.cache_hit
    assert "series_soft_tissue" in [s.name for s in a.surfaces]
    assert "series_adipose" not in [s.name for s in a.surfaces]
    assert "series_adipose" in [s.name for s in b.surfaces]

# precedence: a [[body]] in a meshed CT (issue 40)


def test_an_implant_touching_the_meshed_ct_bone_keeps_its_whole_path(tmp_path):
    """A titanium rod in a meshed CT's soft tissue, two thirds of it inside the bone: it
    displaces tissue and bone alike (both engines). Before the rule, the bone (a CT body,
    listed after the [[body]] tables) won where they overlap and the rod's 20 mm dropped to
    the 5.5 mm outside the bone, silently."""
    import trimesh

    n = 56
    r = np.sqrt(((np.indices((n, n, n)) - (n - 1) / 2) ** 2).sum(0))
    hu = np.where(r <= 25, 40.0, -1000.0)
    hu[r <= 10] = 1200.0
    affine = np.eye(4)
    affine[:3, 3] = -(n - 1) / 2                       # the balls centred on the origin
    write_nifti(tmp_path / "ct.nii.gz", hu.astype(np.float32), affine)
    rod = trimesh.creation.cylinder(radius=3.0, height=20.0, sections=32)
    rod.apply_translation([0.0, 0.0, 4.0])             # z -6 .. 14: bone up to z = 10
    rod.export(tmp_path / "rod.stl")
    (tmp_path / "scene.toml").write_text("""
[source]
position = [0, 0, 500]
kind = "parallel"
energy = 60.0
[detector]
center = [0, 0, -200]
up = [0.0, 1.0, 0.0]
shape = [24, 24]
pitch = 0.5
[[body]]
name = "rod"
mesh = "rod.stl"
material = "Ti"
density = 4.5
[[ct]]
file = "ct.nii.gz"
trace = "meshes"
max_error = 0.3
""")
    scene = xray_viz.load_scene(tmp_path / "scene.toml")
    assert scene.bodies.names == ["rod", "ct_soft_tissue", "ct_cortical_bone"]
    prec = scene.bodies.precedence
    assert prec[0] > prec[2] > prec[1]        # rod over bone over tissue
    from xray_viz.tracing.engines import ENGINES

    rays = detector_rays(scene)
    on_rod = np.hypot(rays.origins[:, 0], rays.origins[:, 1]) < 2.5   # well inside the rod
    assert on_rod.sum() > 50
    for engine in ("numpy", "fast"):
        L = ENGINES[engine].path_lengths(scene.bodies, scene.acquisition)
        np.testing.assert_allclose(L[on_rod, 0], 20.0, rtol=0, atol=1e-9)
        # the CT is what remains of each ray: the rod's 20 mm taken from tissue and bone
        total = L[on_rod].sum(1)
        np.testing.assert_allclose(total, 2 * np.sqrt(25.0 ** 2 - (rays.origins[on_rod, 0] ** 2
                                                                   + rays.origins[on_rod, 1] ** 2)),
                                   atol=1.0)

"""Label maps and CT volumes as bodies: one closed, smoothed, decimated surface per label.

A segmentation (a *label map*: an integer volume, 0 the background) becomes one body per
label listed in the scene; a CT volume in Hounsfield units is first segmented by HU ranges
into material classes (:data:`SCHNEIDER_2000`) and then meshed the same way.

Reading (:func:`read_volume`)
    NIfTI ``.nii`` / ``.nii.gz`` through nibabel; NRRD ``.nrrd`` / ``.nhdr`` and MetaImage
    ``.mha`` / ``.mhd`` through SimpleITK; a DICOM series (a folder of slices of one series)
    through pydicom.

Coordinates
    Scene coordinates are the volume's **world coordinates in mm, RAS+**: +x towards the
    patient's right, +y anterior, +z superior (the convention of NIfTI, nibabel and 3D
    Slicer), so that a body lands where the scanner put it. NIfTI's affine (``sform`` or
    ``qform``, as nibabel resolves them) is used as is. ITK (NRRD, MetaImage) and DICOM give
    world coordinates in LPS+ (+x left, +y posterior, +z superior); they are turned into RAS+
    by negating x and y, :data:`LPS_TO_RAS`::

        RAS = diag(-1, -1, 1) @ LPS

    A point that SimpleITK or a DICOM header puts at ``(x, y, z)`` is therefore at
    ``(-x, -y, z)`` in the scene, and one that nibabel puts at ``(x, y, z)`` is at
    ``(x, y, z)``: the same segmentation saved as NIfTI or as NRRD makes the same bodies at the
    same place (tested). Place the source and the detector around them (a body's ``position``
    does not apply here; the volume's own geometry does).

Meshing (:func:`mesh_mask`)
    The label's voxels are cropped and padded with one voxel of background on every side (so
    that every surface is closed, also where the label touches the edge of the volume), the
    iso-surface at 0.5 is extracted by VTK's flying edges in index space and mapped through
    the affine to mm (faces reversed when the affine mirrors), smoothed by a windowed-sinc
    filter with normalised coordinates (VTK ``vtkWindowedSincPolyDataFilter``, which does not
    shrink the surface as Laplacian smoothing does), repaired if needed, and decimated by
    quadric edge collapse (pymeshlab, :func:`~xray_viz.meshes.decimate`).

    The *voxel surface* is the unsmoothed flying-edges surface of the label's voxels: it
    passes half-way between a voxel inside and its neighbour outside, a staircase whose steps
    are the data's resolution, not anatomy. Smoothing takes the steps off: the strongest
    windowed-sinc filter of :data:`PASS_BANDS` whose Hausdorff distance to the voxel surface
    stays within half a voxel diagonal (:func:`smoothing_limit`, the resolution of the data) is
    used. ``max_error`` (mm) is the decimation's budget: the Hausdorff distance of the body to
    the smoothed surface. Each body's symmetric Hausdorff distance to its voxel surface is
    measured and reported (:attr:`LabelSurface.hausdorff`); it is at most about
    ``smoothing_limit + max_error``.

Nesting
    A label enclosed by another (marrow inside bone) must win inside it. The scene's rule is
    "innermost wins" (:func:`xray_viz.attenuation.body_precedence`), so the outer label's body
    is its voxels *and* the holes in it that other listed labels fill (a hole of background
    stays a cavity): the bone is meshed solid, the marrow inside it, and the marrow wins.

Cache
    Meshing takes seconds to minutes; the result is cached on disk under the SHA-256 of the
    voxels as read (every file of a multi-file format counts: the data file of a ``.mhd`` or
    detached ``.nhdr``, every slice of a DICOM series), the affine and every parameter: a
    second load reads it instead. The cache
    folder is ``volumes/`` in the one cache of ``xray_viz._cache``
    (``$XRAY_VIZ_CACHE_DIR`` if set, ``off`` turns the cache off, else the user cache folder,
    ``platformdirs.user_cache_dir("xray_viz")``: ``$XDG_CACHE_HOME/xray_viz`` or
    ``~/.cache/xray_viz`` on Linux); a folder that cannot be written is off (one warning). Cache files hold arrays only (``.npz``, read with ``allow_pickle=False``); a file
    that cannot be read is ignored and rewritten. Deleting the cache is always safe.

Examples
--------
>>> import numpy as np
>>> from xray_viz.meshes.volumes import mesh_mask
>>> i, j, k = np.indices((24, 24, 24))
>>> ball = (i - 11.5) ** 2 + (j - 11.5) ** 2 + (k - 11.5) ** 2 <= 8.0 ** 2
>>> mesh, hausdorff = mesh_mask(ball, np.eye(4), max_error=0.25)
>>> mesh.is_watertight, bool(hausdorff <= smoothing_limit(np.eye(4)) + 0.25)
(True, True)
>>> bool(abs(mesh.volume / (4 / 3 * np.pi * 8.0 ** 3) - 1) < 0.02)   # the ball of radius 8
True
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import warnings
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from xray_viz.errors import CacheWarning, MaterialError, MeshError, SceneError, \
    SceneFileNotFoundError, XrayVizError, reader_reason
from xray_viz.meshes._volume_files import (  # noqa: F401 (re-exported)
    DICOM_SEG_SUFFIXES,
    ITK_SUFFIXES,
    NIFTI_SUFFIXES,
    VOLUME_SUFFIXES,
    is_volume_path,
)

__all__ = [
    "Volume", "LabelSurface", "VolumeMeshes", "read_volume", "voxel_surface", "mesh_mask",
    "smoothing_limit",
    "label_surfaces",
    "ct_surfaces", "classify_hu", "check_hounsfield", "volume_bodies", "is_volume_path", "cache_dir",
    "SCHNEIDER_2000", "VOLUME_SUFFIXES", "LabelSkippedWarning", "VolumeCacheWarning",
    "LPS_TO_RAS",
]

#: ITK's and DICOM's world coordinates (LPS+) to the scene's (RAS+): x and y negated.
LPS_TO_RAS = np.diag([-1.0, -1.0, 1.0, 1.0])

#: Largest median filter size of a ``[[ct]]`` table (voxels): 3 removes speckle; beyond a few
#: voxels the filter erases bodies and its cost grows with the cube of the size.
MAX_MEDIAN = 9

#: Windowed-sinc pass bands tried, strongest smoothing first (VTK: 0 < pass band < 2).
PASS_BANDS = (0.01, 0.03, 0.1, 0.3)
#: Windowed-sinc iterations.
SMOOTHING_ITERATIONS = 20
#: Bumped whenever the meshing changes what it makes: old cache entries are then not used.
CACHE_VERSION = "volumes-3"

#: Default HU -> material table: a coarse grouping of the HU segments of Schneider, Bortfeld and
#: Schlegel, "Correlation between CT numbers and tissue parameters needed for Monte Carlo
#: simulations of clinical dose distributions", Phys. Med. Biol. 45 (2000) 459-478: air below
#: -950 HU (left empty: vacuum), lung -950 to -120, adipose tissue -120 to 19 (their adipose /
#: adrenal / small-intestine mixtures), soft tissue 19 to 120 (their soft and connective
#: tissue), and their marrow-bone mixtures from 120 HU split in two: cancellous bone 120 to
#: 600 and cortical bone from 600 (a density of their HU-density line, rho = 1.017 +
#: 0.592e-3 HU, at the middle of the cancellous range; cortical bone at the ICRP density).
#: Lung at 0.26 g/cm3 (inflated lung, about -740 HU). Each entry: (name, low HU inclusive,
#: high HU exclusive, material, density or None for the compound's own).
SCHNEIDER_2000 = (
    ("lung", -950.0, -120.0, "Lung (ICRP)", 0.26),
    ("adipose", -120.0, 19.0, "Adipose Tissue (ICRP)", None),
    ("soft_tissue", 19.0, 120.0, "Tissue, Soft (ICRP)", None),
    ("cancellous_bone", 120.0, 600.0, "Bone, Cortical (ICRP)", 1.23),
    ("cortical_bone", 600.0, float("inf"), "Bone, Cortical (ICRP)", None),
)

#: Keys of a ``[[labels]]`` table, of one of its ``materials`` entries, of a ``[[ct]]`` table
#: and of one of its ``ranges``.
LABELS_KEYS = ("file", "materials", "max_error", "trace", "interpolation")
MATERIAL_KEYS = ("mu", "material", "density", "name")
CT_KEYS = ("file", "ranges", "max_error", "median", "min_voxels", "trace", "interpolation")
RANGE_KEYS = ("hu", "mu", "material", "density", "name")


class LabelSkippedWarning(UserWarning):
    """Labels present in a segmentation but not listed in the scene's ``materials`` were
    skipped (no body made)."""


class VolumeCacheWarning(CacheWarning):
    """A meshed volume could not be written to the cache (its folder:
    :class:`xray_viz.errors.CacheWarning`)."""


# --------------------------------------------------------------------------------------------
# reading


@dataclass(frozen=True, eq=False)
class Volume:
    """A 3D volume: ``data[i, j, k]`` and the affine from voxel index to scene mm (RAS+).

    Parameters
    ----------
    data : numpy.ndarray
        3D array indexed (i, j, k).
    affine : numpy.ndarray
        4x4: ``affine @ [i, j, k, 1]`` is the centre of voxel (i, j, k) in mm, RAS+.
    path : Path or None
        Where it was read from, for messages.
    """

    data: np.ndarray
    affine: np.ndarray
    path: Path | None = None

    @property
    def spacing(self) -> np.ndarray:
        """Voxel size along i, j, k (mm): the lengths of the affine's columns."""
        return np.linalg.norm(np.asarray(self.affine)[:3, :3], axis=0)


def _stem(path: Path) -> str:
    name = path.name
    for s in sorted(VOLUME_SUFFIXES, key=len, reverse=True):
        if name.lower().endswith(s):
            return name[: -len(s)] or name
    return name


def _as_3d(data: np.ndarray, path: Path) -> np.ndarray:
    if data.ndim == 4 and data.shape[3] == 1:
        data = data[..., 0]
    if data.ndim != 3:
        raise MeshError(f"{path}: a {data.ndim}D volume of shape {list(data.shape)}; a label map "
                        "or CT must be 3D (one value per voxel): split the volume first")
    if min(data.shape) < 1:
        raise MeshError(f"{path}: the volume is empty (shape {list(data.shape)})")
    return data


def _read_nifti(path: Path, *, hu: bool):
    from xray_viz._files import open_nifti

    try:
        with open_nifti(path) as img:      # CT.NII.GZ as ct.nii.gz
            data = np.asanyarray(img.dataobj)  # scaled by scl_slope/scl_inter when set
            affine = np.asarray(img.affine, dtype=np.float64)
    except Exception as exc:
        raise MeshError(f"{path}: cannot read NIfTI: {reader_reason(exc)}") from None
    return _as_3d(np.asarray(data), path), affine


def _detached_data_names(path: Path) -> list[str]:
    """The data files a MetaImage (``ElementDataFile``) or NRRD (``data file``) header names,
    as written (``LOCAL``/attached data: none; ``LIST``: the names after it; a numbered
    pattern such as ``slice%03d.raw 1 40 1``: the pattern)."""
    import re

    with open(path, "rb") as fh:
        head = fh.read(1 << 16).decode("latin-1")
    lines = head.splitlines()
    mha = path.name.lower().endswith((".mha", ".mhd"))
    key = re.compile(r"^\s*ElementDataFile\s*=\s*(.*)$" if mha
                     else r"^\s*data ?file\s*:\s*(.*)$", re.IGNORECASE)
    for k, line in enumerate(lines):
        if not mha and not line.strip() and k > 0:
            return []                                     # NRRD: the header ends here
        m = key.match(line)
        if not m:
            continue
        value = m.group(1).strip()
        first = value.split()[0] if value.split() else ""
        if first.upper() == "LOCAL" or not value:
            return []
        if first.upper() == "LIST":
            return [t.strip() for t in lines[k + 1:] if t.strip()]
        if "%" in first and len(value.split()) >= 3:      # a pattern, then min max step
            return [first]
        return [value]
    return []


def _refuse_detached_outside(path: Path) -> None:
    """A header whose data file lies outside the header's own folder (an absolute path, or
    ``..`` out of it) is refused: a crafted header would otherwise read any file as voxels."""
    import posixpath

    for name in _detached_data_names(path):
        norm = posixpath.normpath(name.replace("\\", "/"))
        if posixpath.isabs(norm) or norm.startswith("../") or norm == ".." \
                or (len(norm) > 1 and norm[1] == ":"):
            raise MeshError(f"{path}: its data file {name[:120]!r} is outside the header's "
                            "folder: refused; put the data file beside the header (or in a "
                            "folder under it) and name it relative to it")


def _read_itk(path: Path, *, hu: bool):
    import SimpleITK as sitk

    from xray_viz._files import itk_read

    _refuse_detached_outside(path)
    try:
        img = itk_read(path)                # labels.MHA as labels.mha
    except Exception as exc:
        text = str(exc).split("\n")
        reason = next((t.strip() for t in text if "description" in t.lower()), exc)
        raise MeshError(f"{path}: cannot read image: {reader_reason(reason)}") from None
    if img.GetNumberOfComponentsPerPixel() != 1:
        raise MeshError(f"{path}: {img.GetNumberOfComponentsPerPixel()} components per voxel; "
                        "a label map or CT has one")
    if img.GetDimension() != 3:
        raise MeshError(f"{path}: a {img.GetDimension()}D image of size {list(img.GetSize())}; "
                        "a label map or CT must be 3D")
    data = sitk.GetArrayFromImage(img).transpose(2, 1, 0)  # ITK's array is [k, j, i]
    direction = np.asarray(img.GetDirection(), dtype=np.float64).reshape(3, 3)
    lps = np.eye(4)
    lps[:3, :3] = direction * np.asarray(img.GetSpacing(), dtype=np.float64)
    lps[:3, 3] = img.GetOrigin()
    return _as_3d(data, path), LPS_TO_RAS @ lps


def _read_dicom_series(folder: Path, *, hu: bool):
    """A folder of DICOM slices of one series: HU (RescaleSlope/Intercept applied), stacked
    along the slice normal, and its affine (LPS from the DICOM tags, then RAS)."""
    import pydicom

    slices = []
    for f in sorted(folder.iterdir()):
        if not f.is_file():
            continue
        try:
            ds = pydicom.dcmread(f, stop_before_pixels=False)
        except Exception:
            continue   # not a DICOM file (a DICOMDIR, a note): skipped
        if "PixelData" in ds and "ImagePositionPatient" in ds:
            slices.append((f, ds))
    if not slices:
        raise MeshError(f"{folder}: no DICOM image slices (with ImagePositionPatient) in this "
                        "folder; give a folder holding one series")
    series = sorted({str(getattr(ds, "SeriesInstanceUID", "")) for _, ds in slices})
    if len(series) > 1:
        raise MeshError(f"{folder}: holds {len(series)} DICOM series; put each series in its own "
                        "folder")
    first = slices[0][1]
    iop = np.asarray(first.ImageOrientationPatient, dtype=np.float64)
    row, col = iop[:3], iop[3:]          # along a row (column index grows), along a column
    normal = np.cross(row, col)
    dr, dc = (float(x) for x in first.PixelSpacing)   # between rows, between columns
    slices.sort(key=lambda s: float(np.dot(np.asarray(s[1].ImagePositionPatient, float), normal)))
    pos = np.array([np.asarray(ds.ImagePositionPatient, dtype=np.float64) for _, ds in slices])
    from xray_viz._memory import check_allocation

    rows, cols = int(getattr(first, "Rows", 0) or 0), int(getattr(first, "Columns", 0) or 0)
    check_allocation(2 * 8 * len(slices) * rows * cols,   # the float64 slices and their stack
                     f"{folder}: the series' {cols} x {rows} x {len(slices)} voxels as float64",
                     "crop or downsample the series (or give the process more memory)",
                     error=MeshError)
    images = []
    for f, ds in slices:
        if not np.allclose(np.asarray(ds.ImageOrientationPatient, float), iop, atol=1e-4):
            raise MeshError(f"{folder}: slice {f.name} is oriented differently from the others")
        try:
            px = ds.pixel_array.astype(np.float64)
        except Exception as exc:
            raise MeshError(f"{folder}: cannot decode slice {f.name}: "
                            f"{reader_reason(exc, limit=120)}") from None
        slope = float(getattr(ds, "RescaleSlope", 1.0))
        intercept = float(getattr(ds, "RescaleIntercept", 0.0))
        images.append(px * slope + intercept if hu else px)
    if len({im.shape for im in images}) != 1:
        raise MeshError(f"{folder}: the slices differ in size")
    data = np.stack([im.T for im in images], axis=2)   # (column i, row j, slice k)
    if len(slices) > 1:
        steps = np.diff(pos, axis=0)
        step = steps.mean(axis=0)
        if not np.allclose(steps, step, atol=1e-3 * max(1.0, float(np.linalg.norm(step)))):
            raise MeshError(f"{folder}: the slices are not evenly spaced; resample the series")
    else:
        step = normal * float(getattr(first, "SliceThickness", 1.0) or 1.0)
    lps = np.eye(4)
    lps[:3, 0] = row * dc
    lps[:3, 1] = col * dr
    lps[:3, 2] = step
    lps[:3, 3] = pos[0]
    return data, LPS_TO_RAS @ lps


def read_volume(path, *, hu: bool = False, dtype=np.float64) -> Volume:
    """Read a label map or CT volume and its affine (voxel index -> scene mm, RAS+).

    Parameters
    ----------
    path : str or Path
        ``.nii`` / ``.nii.gz`` (nibabel), ``.nrrd`` / ``.nhdr`` / ``.mha`` / ``.mhd``
        (SimpleITK), a DICOM-SEG ``.dcm`` file (highdicom, a label map only:
        :func:`~xray_viz.meshes.dicom_seg.read_dicom_seg`), or a folder holding one DICOM
        series (pydicom).
    hu : bool, optional
        Read a CT in Hounsfield units (``dtype``; DICOM's rescale applied). Otherwise the
        values must be whole numbers (a label map): integer voxels keep their type (booleans
        become uint8), whole floats come back as int64.
    dtype : numpy dtype, optional
        Of a CT's values (float64 by default; the voxel tracer reads float32: HU are whole
        numbers well within its 24 bits, and a 512 x 512 x 133 CT is half the memory).

    Returns
    -------
    Volume

    Raises
    ------
    SceneFileNotFoundError
        The file does not exist.
    MeshError
        Unknown format, unreadable, not 3D, (a label map) values that are not integers, or
        a conversion (to float64 or int64) that cannot fit in the memory this process may
        still take.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np, nibabel as nib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "seg.nii.gz"
    >>> affine = np.diag([0.5, 0.5, 2.0, 1.0]); affine[:3, 3] = [10, 20, 30]
    >>> nib.save(nib.Nifti1Image(np.ones((4, 4, 4), np.uint8), affine), path)
    >>> vol = read_volume(path)
    >>> vol.data.shape, vol.spacing.tolist(), (vol.affine @ [1, 1, 1, 1])[:3].tolist()
    ((4, 4, 4), [0.5, 0.5, 2.0], [10.5, 20.5, 32.0])
    """
    path = Path(path)
    if not path.exists():
        raise SceneFileNotFoundError(f"{path}: volume file not found")
    from xray_viz._files import require_regular

    require_regular(path, MeshError, "volume file")
    name = path.name.lower()
    if path.is_dir():
        if not hu:          # an image series, never labels: read as labels it meshes raw HU
            raise MeshError(f"{path}: a folder of DICOM slices is a CT (an image in HU), not a "
                            "label map: give it as a CT (`xray-viz mesh FOLDER --ct`, a [[ct]] "
                            "table); a DICOM label map is one DICOM-SEG .dcm file")
        data, affine = _read_dicom_series(path, hu=hu)
    elif name.endswith(NIFTI_SUFFIXES):
        data, affine = _read_nifti(path, hu=hu)
    elif name.endswith(ITK_SUFFIXES):
        data, affine = _read_itk(path, hu=hu)
    elif name.endswith(DICOM_SEG_SUFFIXES):
        if hu:
            raise MeshError(f"{path}: a single .dcm file is read as a DICOM-SEG label map (a "
                            "[[labels]] table); give a CT series as the folder of its slices")
        from xray_viz.meshes.dicom_seg import read_dicom_seg

        data, affine, _ = read_dicom_seg(path)
    else:
        raise MeshError(f"{path}: not a volume file; use one of {', '.join(VOLUME_SUFFIXES)} or "
                        "a folder holding a DICOM series")
    if not np.all(np.isfinite(affine)) or abs(np.linalg.det(affine[:3, :3])) < 1e-12:
        raise MeshError(f"{path}: its voxel-to-world affine is degenerate or not finite")
    if hu:
        if data.dtype != np.dtype(dtype):
            _check_widening(path, data, "the CT's", np.dtype(dtype))
        data = np.asarray(data, dtype=dtype)
        if not np.all(np.isfinite(data)):
            raise MeshError(f"{path}: the CT holds NaN or infinite values")
    else:
        if data.dtype.kind == "f":
            if not np.all(np.isfinite(data)) or np.any(data != np.round(data)):
                raise MeshError(f"{path}: not a label map: it holds values that are not whole "
                                "numbers; for a CT in Hounsfield units use a [[ct]] table")
            _check_widening(path, data, "the label map's", np.int64)
            data = np.asarray(data, dtype=np.int64)
        elif data.dtype.kind == "b":
            data = data.view(np.uint8)
        elif data.dtype.kind not in "iu":
            raise MeshError(f"{path}: not a label map: voxels of type {data.dtype}")
        # integer labels keep their own type: a uint8 map of 768^3 voxels stays 0.4 GiB
        # (as int64 it would take 3.4 GiB)
        if data.size and data.dtype.kind == "i" and int(data.min()) < 0:
            raise MeshError(f"{path}: not a label map: negative values (down to "
                            f"{int(data.min())}); labels are whole numbers >= 0. A CT in "
                            "Hounsfield units (air -1000) is given as a CT: `xray-viz mesh IN "
                            "--ct`, a [[ct]] table")
    return Volume(data=data, affine=affine, path=path)


def _check_widening(path, data, whose, dtype) -> None:
    """Refuse in one line a conversion of ``data`` to ``dtype`` that cannot fit in the memory
    this process may still take (:mod:`xray_viz._memory`)."""
    from xray_viz._memory import check_allocation

    shape = " x ".join(str(n) for n in data.shape)
    check_allocation(data.size * np.dtype(dtype).itemsize,
                     f"{path}: {whose} {shape} voxels as {np.dtype(dtype).name}",
                     "crop or downsample the volume (or give the process more memory)",
                     error=MeshError)


# --------------------------------------------------------------------------------------------
# meshing


def _trimesh(poly):
    import trimesh

    if poly.n_cells and not poly.is_all_triangles:
        poly = poly.triangulate()
    faces = np.asarray(poly.regular_faces, dtype=np.int64) if poly.n_cells else \
        np.zeros((0, 3), np.int64)
    return trimesh.Trimesh(np.asarray(poly.points, dtype=np.float64), faces, process=False)


def voxel_surface(values, affine, *, level: float = 0.5, pad: bool = True):
    """Closed iso-surface of a voxel field at ``level``, by VTK's flying edges, in mm.

    The field is cropped to the voxels above ``level`` and padded with one voxel of 0 on every
    side, so that the surface is closed also where it reaches the edge of the volume. Points
    are found in index space and mapped through ``affine``; the faces are reversed when the
    affine mirrors, so that they stay outward.

    Parameters
    ----------
    values : array_like, 3D
        Indexed (i, j, k): a boolean mask, or a smoothed one (the frog phantom's).
    affine : array_like, 4x4
        Voxel index -> mm.
    level : float, optional
        Iso-value.
    pad : bool, optional
        Crop and pad (default). False takes the field as it is: the caller has padded it
        (the surface is open where the field is above ``level`` at its edge).

    Returns
    -------
    trimesh.Trimesh
        Triangles, not repaired.

    Examples
    --------
    >>> cube = np.zeros((6, 6, 6), bool); cube[1:5, 1:5, 1:5] = True
    >>> surf = voxel_surface(cube, np.diag([2.0, 2.0, 2.0, 1.0]))
    >>> surf.is_watertight, round(float(surf.volume), 6)
    (True, 469.333333)

    An 8 mm cube (4 voxels of 2 mm), its 12 edges chamfered by half a voxel (prisms of
    1 x 1 / 2 mm2 x 6 mm) and its 8 corners cut to a tetrahedron (1/6 of 1 mm3 kept):

    >>> round(8.0 ** 3 - 12 * 0.5 * 6 - 8 * (1 - 1 / 6), 6)
    469.333333
    """
    return _trimesh(_voxel_surface(values, affine, level=level, pad=pad))


def _voxel_surface(values, affine, *, level: float = 0.5, pad: bool = True):
    """:func:`voxel_surface` as pyvista PolyData."""
    import pyvista as pv

    values = np.asarray(values)
    affine = np.asarray(affine, dtype=np.float64)
    idx = np.nonzero(values > level)
    if not idx[0].size:
        raise MeshError("no voxel above the iso-level: an empty surface")
    if pad:
        lo = np.array([i.min() for i in idx])
        hi = np.array([i.max() for i in idx]) + 1
        lo, hi = np.maximum(lo - 1, 0), np.minimum(hi + 1, values.shape)  # the cells around
        sub = np.pad(values[lo[0]:hi[0], lo[1]:hi[1], lo[2]:hi[2]].astype(np.float32), 1)
    else:
        lo, sub = np.ones(3, dtype=np.int64), values.astype(np.float32)
    linear = affine[:3, :3]
    axis_aligned = np.all(linear == np.diag(np.diag(linear))) and np.all(np.diag(linear) > 0)
    if axis_aligned:   # VTK places the points itself (as the frog phantom was made)
        spacing = np.diag(linear)
        img = pv.ImageData(dimensions=sub.shape, spacing=tuple(spacing),
                           origin=tuple(affine[:3, 3] + (lo - 1.0) * spacing))
    else:
        img = pv.ImageData(dimensions=sub.shape, spacing=(1.0, 1.0, 1.0),
                           origin=tuple(lo - 1.0))
    img.point_data["m"] = sub.ravel(order="F")   # VTK: i varies fastest
    surf = img.contour([level], scalars="m", method="flying_edges", compute_normals=False)
    surf = surf.triangulate().clean()
    if axis_aligned:
        return surf
    pts = np.asarray(surf.points, dtype=np.float64)
    faces = np.asarray(surf.regular_faces)
    if np.linalg.det(linear) < 0:   # a mirroring affine turns the faces inside out
        faces = faces[:, ::-1]
    return pv.PolyData.from_regular_faces(pts @ linear.T + affine[:3, 3], faces)


def smoothing_limit(affine) -> float:
    """How far (mm) smoothing may move a surface from the voxel surface: half the voxel
    diagonal, the resolution of the data.

    Examples
    --------
    >>> round(smoothing_limit(np.diag([1.0, 1.0, 2.0, 1.0])), 4)
    1.2247
    """
    return 0.5 * float(np.linalg.norm(np.linalg.norm(np.asarray(affine)[:3, :3], axis=0)))


def mesh_mask(mask, affine, *, max_error: float, name: str = "label"):
    """Closed, smoothed, decimated surface of a boolean voxel mask.

    Parameters
    ----------
    mask : array_like of bool, 3D
        The voxels inside, indexed (i, j, k).
    affine : array_like, 4x4
        Voxel index -> mm.
    max_error : float
        Decimation budget: the largest Hausdorff distance (mm) of the result to the smoothed
        surface. (Smoothing itself stays within :func:`smoothing_limit` of the voxel surface.)
    name : str, optional
        For messages.

    Returns
    -------
    mesh : trimesh.Trimesh
        Closed and outward.
    hausdorff : float
        Measured symmetric Hausdorff distance (mm) of ``mesh`` to the voxel surface.

    Raises
    ------
    MeshError
        The mask is empty, or no closed surface could be made.
    """
    from xray_viz.meshes.decimate import decimate, hausdorff_distance
    from xray_viz.meshes.repair import check_mesh, repair_mesh

    mask = np.asarray(mask, dtype=bool)
    affine = np.asarray(affine, dtype=np.float64)
    if not mask.any():
        raise MeshError(f"{name}: no voxels")
    if not (np.isfinite(max_error) and max_error > 0):
        raise MeshError(f"{name}: max_error must be > 0 mm, got {max_error}")
    raw_poly = _voxel_surface(mask, affine)
    raw = _trimesh(raw_poly)
    if not check_mesh(raw).traceable:
        raw, _ = repair_mesh(raw)
    limit = smoothing_limit(affine)
    smooth = raw
    for band in PASS_BANDS:
        cand = _trimesh(raw_poly.smooth_taubin(
            n_iter=SMOOTHING_ITERATIONS, pass_band=band, normalize_coordinates=True,
            boundary_smoothing=False, non_manifold_smoothing=False, feature_smoothing=False))
        if not check_mesh(cand).traceable:
            cand, _ = repair_mesh(cand)
            if not check_mesh(cand).traceable:
                continue
        if hausdorff_distance(cand, raw) <= limit:
            smooth = cand
            break
    if not check_mesh(smooth).traceable:
        raise MeshError(f"{name}: the surface of its voxels could not be closed")
    # the bisection's sampled distances are estimates: the result is measured again against
    # the smoothed surface, and decimated less when it is over
    result, budget = smooth, max_error
    for _ in range(4):
        if len(smooth.faces) <= 64:
            break
        cand, _ = decimate(smooth, max_error=budget, samples=10000)
        if hausdorff_distance(cand, smooth) <= max_error:
            result = cand
            break
        budget *= 0.7
    if result.volume < 0:
        result.invert()
    return result, hausdorff_distance(result, raw)


@dataclass(frozen=True, eq=False)
class LabelSurface:
    """The body made of one label (or one HU class of a CT).

    Attributes
    ----------
    label : int
        The label value (for a CT: the class's index in its table, from 1).
    name : str
        Body name.
    mesh : trimesh.Trimesh
        Closed surface in scene mm.
    hausdorff : float
        Symmetric Hausdorff distance (mm) to the label's voxel surface.
    voxels : int
        Voxels of the label.
    """

    label: int
    name: str
    mesh: object
    hausdorff: float
    voxels: int


@dataclass(frozen=True, eq=False)
class VolumeMeshes:
    """What :func:`label_surfaces` and :func:`ct_surfaces` return.

    Attributes
    ----------
    surfaces : tuple of LabelSurface
        In the order of the labels asked for.
    skipped : tuple of int
        Labels present in the volume but not asked for.
    cache_file : Path or None
        The cache entry read or written (None: no cache).
    cache_hit : bool
        True when the surfaces were read from ``cache_file`` rather than computed.
    """

    surfaces: tuple
    skipped: tuple = ()
    cache_file: Path | None = None
    cache_hit: bool = False
    max_error: float = 0.0
    spacing: tuple = field(default=())


def _nesting_fill(labels: np.ndarray, label: int, listed) -> np.ndarray:
    """The label's voxels and the holes in them that other listed labels fill."""
    from scipy import ndimage

    mask = labels == label
    idx = np.nonzero(mask)
    if not idx[0].size:
        return mask
    box = tuple(slice(i.min(), i.max() + 1) for i in idx)   # holes lie inside the bounding box
    sub = mask[box]
    holes = ndimage.binary_fill_holes(sub) & ~sub
    if holes.any():
        others = np.isin(labels[box], [v for v in listed if v != label])
        mask[box] = sub | (holes & others)
    return mask


def _default_max_error(spacing) -> float:
    return 0.25 * float(np.min(spacing))


def _mesh_labels(labels: np.ndarray, affine, wanted, names, max_error) -> list[LabelSurface]:
    affine = np.asarray(affine, dtype=np.float64)
    out = []
    for label in wanted:
        idx = np.nonzero(labels == label)   # the one pass over the whole volume
        voxels = int(idx[0].size)
        if not voxels:
            raise MeshError(f"{names[label]}: label {label} has no voxels")
        lo = np.array([i.min() for i in idx])
        box = tuple(slice(a, int(i.max()) + 1) for a, i in zip(lo, idx))
        sub_affine = affine.copy()   # the label's bounding box, placed where it is
        sub_affine[:3, 3] = affine[:3, :3] @ lo + affine[:3, 3]
        mask = _nesting_fill(labels[box], label, wanted)
        mesh, h = mesh_mask(mask, sub_affine, max_error=max_error, name=names[label])
        out.append(LabelSurface(label=int(label), name=names[label], mesh=mesh, hausdorff=h,
                                voxels=voxels))
    return out


# --------------------------------------------------------------------------------------------
# cache


def cache_dir() -> Path | None:
    """Where meshed volumes are cached (see the module's docstring), or None
    (``xray_viz._cache.cache_dir``: the one rule).

    Examples
    --------
    >>> import os
    >>> old = os.environ.get("XRAY_VIZ_CACHE_DIR")
    >>> os.environ["XRAY_VIZ_CACHE_DIR"] = d = __import__("tempfile").mkdtemp()
    >>> str(cache_dir()) == os.path.join(d, "volumes")
    True
    >>> os.environ["XRAY_VIZ_CACHE_DIR"] = "off"
    >>> cache_dir() is None
    True
    >>> if old is None: del os.environ["XRAY_VIZ_CACHE_DIR"]
    ... else: os.environ["XRAY_VIZ_CACHE_DIR"] = old
    """
    from xray_viz import _cache

    return _cache.cache_dir("volumes", what="meshed volumes")


_warned: set = set()


def _warn_cache(message: str) -> None:
    if message in _warned:
        return
    _warned.add(message)
    warnings.warn(message, VolumeCacheWarning, stacklevel=4)


def _cache_key(vol: Volume, params: dict) -> str:
    """SHA-256 of what the meshing reads: the decoded voxels (their dtype, shape and bytes), the
    affine and ``params``. Keyed by the data, not by the file named: a header whose data file
    (``.mhd`` -> ``ElementDataFile``, a detached ``.nhdr`` -> ``data file``, however many
    files), one slice of a DICOM series, or any other part of a multi-file format that changes
    changes the key."""
    h = hashlib.sha256()
    h.update(CACHE_VERSION.encode())
    h.update(json.dumps(params, sort_keys=True, default=str).encode())
    for a in (vol.data, vol.affine):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def _cache_read(file: Path):
    import trimesh

    try:
        with np.load(file, allow_pickle=False) as z:
            meta = json.loads(str(z["meta"][()]))
            surfaces = [
                LabelSurface(label=int(m["label"]), name=str(m["name"]),
                             mesh=trimesh.Trimesh(z[f"v{k}"].astype(np.float64),
                                                  z[f"f{k}"].astype(np.int64), process=False),
                             hausdorff=float(m["hausdorff"]), voxels=int(m["voxels"]))
                for k, m in enumerate(meta["surfaces"])]
        return surfaces, tuple(meta.get("skipped", ()))
    except Exception:
        return None


def _cache_write(file: Path, surfaces, skipped) -> None:
    meta = {"surfaces": [dict(label=s.label, name=s.name, hausdorff=s.hausdorff,
                              voxels=s.voxels) for s in surfaces],
            "skipped": [int(v) for v in skipped]}
    arrays = {"meta": np.array(json.dumps(meta))}
    for k, s in enumerate(surfaces):
        arrays[f"v{k}"] = np.asarray(s.mesh.vertices, dtype=np.float64)
        arrays[f"f{k}"] = np.asarray(s.mesh.faces, dtype=np.int64)
    tmp = file.with_name(f".{file.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, **arrays)
        os.replace(tmp, file)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        _warn_cache(f"{file}: cannot write the mesh cache ({exc.strerror}); not cached")


def _cached(vol: Volume, params: dict, cache: bool, compute):
    """``compute()`` -> (surfaces, skipped), through the cache (keyed by :func:`_cache_key`)."""
    folder = cache_dir() if cache else None
    file = None
    if folder is not None:
        file = folder / f"{_cache_key(vol, params)}.npz"
        if file.is_file():
            got = _cache_read(file)
            if got is not None:
                return got[0], got[1], file, True
    surfaces, skipped = compute()
    if file is not None:
        _cache_write(file, surfaces, skipped)
    return surfaces, skipped, file, False


# --------------------------------------------------------------------------------------------
# label maps and CT


def label_surfaces(path, labels=None, *, names=None, max_error: float | None = None,
                   cache: bool = True) -> VolumeMeshes:
    """One closed surface per label of a segmentation, in scene mm (RAS+).

    Parameters
    ----------
    path : str or Path
        The label map (see :func:`read_volume`).
    labels : sequence of int, optional
        Labels to mesh (default: every label but 0). Labels present but not asked for are
        listed in :attr:`VolumeMeshes.skipped`.
    names : mapping of int to str, optional
        Body names (default ``<file stem>_<label>``).
    max_error : float, optional
        Decimation tolerance in mm from the smoothed surface (default: a quarter of the
        smallest voxel spacing); see :func:`mesh_mask`.
    cache : bool, optional
        Use the on-disk cache (:func:`cache_dir`).

    Returns
    -------
    VolumeMeshes

    Raises
    ------
    MeshError
        The volume cannot be read, or a label asked for has no voxels.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np, nibabel as nib
    >>> path = pathlib.Path(tempfile.mkdtemp()) / "cube.nii.gz"
    >>> data = np.zeros((12, 12, 12), np.uint8); data[2:10, 2:10, 2:10] = 1; data[0, 0, 0] = 7
    >>> nib.save(nib.Nifti1Image(data, np.eye(4)), path)
    >>> out = label_surfaces(path, [1], cache=False)
    >>> [s.name for s in out.surfaces], out.skipped, out.surfaces[0].mesh.is_watertight
    (['cube_1'], (7,), True)
    """
    path = Path(path)
    vol = read_volume(path)
    present = [int(v) for v in np.unique(vol.data) if v != 0]
    wanted = present if labels is None else [int(v) for v in labels]
    missing = [v for v in wanted if v not in present]
    if missing:
        raise MeshError(f"{path}: label{'s' if len(missing) > 1 else ''} "
                        f"{', '.join(map(str, missing))} ha{'ve' if len(missing) > 1 else 's'} "
                        f"no voxels (labels present: {', '.join(map(str, present)) or 'none'})")
    stem = _stem(path)
    names = {v: (names or {}).get(v, f"{stem}_{v}") for v in wanted}
    max_error = _default_max_error(vol.spacing) if max_error is None else float(max_error)
    skipped = tuple(v for v in present if v not in wanted)
    params = dict(kind="labels", labels=wanted, names=names, max_error=max_error)
    surfaces, skipped, file, hit = _cached(
        vol, params, cache,
        lambda: (_mesh_labels(vol.data, vol.affine, wanted, names, max_error), skipped))
    return VolumeMeshes(surfaces=tuple(surfaces), skipped=tuple(skipped), cache_file=file,
                        cache_hit=hit, max_error=max_error, spacing=tuple(vol.spacing))


def classify_hu(hu, ranges=SCHNEIDER_2000, *, median: int = 1, min_voxels: int = 27):
    """HU volume -> class index per voxel (0: no class; k: the k-th range, from 1).

    Parameters
    ----------
    hu : numpy.ndarray
        CT values in Hounsfield units.
    ranges : sequence of (name, low, high, ...)
        ``low <= HU < high`` is class k (1-based, in the order given).
    median : int, optional
        Size of a median filter applied to the HU first (default 1: none). 3 removes more
        noise but erodes convex corners (a small ball loses a few % of its volume).
    min_voxels : int, optional
        Connected pieces (face-connected) of a class smaller than this take the class of
        their nearest voxel outside such pieces (0: keep everything): speckle in a noisy CT
        would otherwise become thousands of tiny bodies. Default 27, a 3 x 3 x 3 block.

    Returns
    -------
    numpy.ndarray of int

    Examples
    --------
    >>> hu = np.full((6, 6, 6), -1000.0); hu[1:5, 1:5, 1:5] = 40.0; hu[2:4, 2:4, 2:4] = 1200.0
    >>> classes = classify_hu(hu, median=1, min_voxels=0)
    >>> [SCHNEIDER_2000[c - 1][0] for c in np.unique(classes) if c]
    ['soft_tissue', 'cortical_bone']
    """
    from scipy import ndimage

    hu = np.asarray(hu, dtype=np.float64)
    if median and median > 1:
        if int(median) > MAX_MEDIAN:
            raise MeshError(f"median = {median} is too large: the median filter's size in "
                            f"voxels is 0 or 1 (none) up to {MAX_MEDIAN} (3 removes speckle)")
        hu = ndimage.median_filter(hu, size=int(median), mode="nearest")
    classes = np.zeros(hu.shape, dtype=np.int64)
    for k, r in enumerate(ranges, start=1):
        lo, hi = float(r[1]), float(r[2])
        classes[(hu >= lo) & (hu < hi) & (classes == 0)] = k
    if min_voxels and min_voxels > 1:
        small = np.zeros(hu.shape, dtype=bool)
        for k in range(1, len(ranges) + 1):
            lab, n = ndimage.label(classes == k)
            if n:
                sizes = np.bincount(lab.ravel())
                tiny = np.nonzero(sizes < min_voxels)[0]
                tiny = tiny[tiny > 0]
                if tiny.size:
                    small |= np.isin(lab, tiny)
        if small.any() and not small.all():
            _, nearest = ndimage.distance_transform_edt(small, return_indices=True)
            classes = classes[tuple(nearest)]
    return classes


def check_hounsfield(hu, path) -> None:
    """Refuse a CT whose values cannot be Hounsfield units, before it is classified.

    A CT in HU spans air (-1000) to tissue and bone (0 to 1000s). Two common mistakes
    classify into one body of adipose or soft tissue without a word: a volume of linear
    attenuation coefficients (mu in 1/cm, 0 to about 0.6: a span of a fraction of one HU) and
    stored values without the scanner's rescale (``RescaleIntercept = -1024`` not applied: no
    voxel below 0, air at about 0). Both are refused in one line saying which it looks like.

    Examples
    --------
    >>> import numpy as np
    >>> check_hounsfield(np.array([-1000.0, 0.0, 40.0, 900.0]), "ct.nii")
    >>> check_hounsfield(np.array([0.0, 0.19, 0.5]), "ct.nii")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    xray_viz.errors.MeshError: ct.nii: its values span only 0 .. 0.5: not Hounsfield units ...
    """
    lo, hi = float(np.min(hu)), float(np.max(hu))
    if hi - lo < 100.0 and lo > -500.0:     # (air alone, -1000 HU, is HU: it makes no body)
        raise MeshError(f"{path}: its values span only {lo:.4g} .. {hi:.4g}: not Hounsfield "
                        "units (air -1000, water 0, bone several hundred); a CT of mu (1/cm) or "
                        "of normalised values must be converted to HU first: "
                        "HU = 1000 (mu - mu_water) / mu_water")
    if lo >= 0.0 and hi >= 1000.0:
        raise MeshError(f"{path}: no voxel below 0 (values {lo:.4g} .. {hi:.4g}): air is -1000 "
                        "HU, so these look like stored values without the scanner's rescale "
                        "(RescaleSlope/RescaleIntercept, typically -1024): apply it first")


def ct_surfaces(path, ranges=SCHNEIDER_2000, *, max_error: float | None = None,
                median: int = 1, min_voxels: int = 27, cache: bool = True) -> VolumeMeshes:
    """One closed surface per HU class of a CT (see :func:`classify_hu`), in scene mm.

    Parameters
    ----------
    path : str or Path
        A CT volume in HU (NIfTI, NRRD/MHA, or a DICOM series folder).
    ranges : sequence of (name, low, high, ...), optional
        The HU classes (default :data:`SCHNEIDER_2000`); a class without voxels makes no body.
    max_error, cache
        As for :func:`label_surfaces`.
    median, min_voxels
        As for :func:`classify_hu`.

    Returns
    -------
    VolumeMeshes
        ``label`` of each surface is the class's 1-based index in ``ranges``.
    """
    path = Path(path)
    vol = read_volume(path, hu=True)
    check_hounsfield(vol.data, path)
    stem = _stem(path)
    max_error = _default_max_error(vol.spacing) if max_error is None else float(max_error)
    table = [tuple(r[:3]) for r in ranges]
    params = dict(kind="ct", ranges=table, max_error=max_error, median=median,
                  min_voxels=min_voxels, stem=stem)   # the bodies' names come from the stem

    def compute():
        classes = classify_hu(vol.data, ranges, median=median, min_voxels=min_voxels)
        present = [k for k in range(1, len(ranges) + 1) if np.any(classes == k)]
        names = {k: f"{stem}_{ranges[k - 1][0]}" for k in present}
        return _mesh_labels(classes, vol.affine, present, names, max_error), ()

    surfaces, skipped, file, hit = _cached(vol, params, cache, compute)
    return VolumeMeshes(surfaces=tuple(surfaces), skipped=(), cache_file=file, cache_hit=hit,
                        max_error=max_error, spacing=tuple(vol.spacing))


# --------------------------------------------------------------------------------------------
# the scene's [[labels]] and [[ct]] tables


def _where(file, table: str, k: int) -> str:
    return f"{file}: " * bool(file) + f"[[{table}]] #{k + 1}"


def _fail(where: str, msg: str):
    raise SceneError(f"{where} {msg}")


def _check_keys(raw, keys, where):
    if not isinstance(raw, Mapping):
        _fail(where, f"must be a table, got {type(raw).__name__}")
    unknown = sorted(set(raw) - set(keys))
    if unknown:
        _fail(where, f"has unknown key{'s' * (len(unknown) > 1)} "
                     f"{', '.join(repr(u) for u in unknown)}; allowed: {', '.join(keys)}")


def _material_entry(raw, where: str) -> dict:
    """``"name"`` or ``{ mu = ... }`` / ``{ material = ..., density = ..., name = ... }`` ->
    Body keyword arguments (mu / material / density), checked; plus 'name' if given."""
    from xray_viz.physics.materials import check_material

    if isinstance(raw, str):
        raw = {"material": raw}
    elif not isinstance(raw, Mapping):
        _fail(where, f"must be a material name or a table such as {{ mu = 0.3 }} or "
                     f"{{ material = \"Water, Liquid\", density = 1.0 }}; got {raw!r}")
    _check_keys(raw, MATERIAL_KEYS, where)
    out = {k: raw[k] for k in ("mu", "material", "density", "name") if k in raw}
    if ("mu" in out) == ("material" in out):
        _fail(where, "needs one of 'mu' (1/cm) or 'material'")
    if "mu" in out:
        mu = out["mu"]
        if isinstance(mu, bool) or not isinstance(mu, (int, float)) or not mu >= 0:
            _fail(where, f"mu must be a number >= 0 (1/cm), got {mu!r}")
        if "density" in out:
            _fail(where, "gives 'density' with 'mu'; density goes with 'material'")
    else:
        density = out.get("density")
        if density is not None and (isinstance(density, bool)
                                    or not isinstance(density, (int, float)) or not density > 0):
            _fail(where, f"density must be a number > 0 (g/cm3), got {density!r}")
        if not isinstance(out["material"], (str, Mapping)):
            _fail(where, f"material must be a name or formula, got {out['material']!r}")
        try:
            check_material(out["material"], density=density)
        except MaterialError as exc:
            raise MaterialError(f"{where} {exc}") from None
    if "name" in out and not isinstance(out["name"], str):
        _fail(where, f"name must be a string, got {out['name']!r}")
    return out


def _max_error(raw, where):
    if "max_error" not in raw:
        return None
    v = raw["max_error"]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (np.isfinite(v) and v > 0):
        _fail(where, f"max_error must be a number > 0 (mm), got {v!r}")
    return float(v)


def _volume_file(raw, where, base_dir: Path) -> Path:
    if "file" not in raw:
        _fail(where, "is missing the required key 'file' (a label map: .nii, .nii.gz, .nrrd, "
                     ".mha, ...)")
    name = raw["file"]
    if not isinstance(name, str) or not name.strip():
        _fail(where, f"file must name a volume file, got {name!r}")
    p = Path(name)
    p = p if p.is_absolute() else (base_dir / p)
    if not p.exists():
        raise SceneFileNotFoundError(f"{where} file {name!r}: volume file not found ({p})")
    return p


#: ``trace`` by default: a CT is traced as voxels (what users of DRR tools expect: every
#: voxel's own density), a label map is meshed (a segmentation is a surface model: smooth
#: organ surfaces, shown as bodies by the viewer).
DEFAULT_TRACE = {"ct": "voxels", "labels": "meshes"}

#: Keys that only meshing uses.
MESHING_KEYS = ("max_error", "median", "min_voxels")


def _trace_mode(raw, where, table):
    from xray_viz.volume import TRACE_MODES

    mode = raw.get("trace", DEFAULT_TRACE[table])
    if mode not in TRACE_MODES:
        _fail(where, f"trace must be \"voxels\" (exact voxel traversal) or \"meshes\" (meshed "
                     f"into bodies), got {mode!r}")
    if mode == "voxels":
        extra = [k for k in MESHING_KEYS if k in raw]
        if extra:
            _fail(where, f"{', '.join(repr(k) for k in extra)} only appl"
                         f"{'y' if len(extra) > 1 else 'ies'} to trace = \"meshes\" (the "
                         "default for [[ct]] is \"voxels\"); remove "
                         f"{'them' if len(extra) > 1 else 'it'} or set trace = \"meshes\"")
        interpolation = raw.get("interpolation", "nearest")
        from xray_viz.volume import INTERPOLATIONS

        if interpolation not in INTERPOLATIONS:
            _fail(where, "interpolation must be \"nearest\" (each voxel's value over its "
                         "voxel, the default) or \"trilinear\" (interpolated between voxel "
                         f"centres), got {interpolation!r}")
    elif "interpolation" in raw:
        _fail(where, "'interpolation' only applies to trace = \"voxels\" (meshes have no "
                     "voxels); remove it or set trace = \"voxels\"")
    return mode


def _read_for_voxels(path, where, *, hu):
    try:
        return read_volume(path, hu=hu, dtype=np.float32)
    except XrayVizError as exc:
        raise type(exc)(f"{where}: {exc}") from None


def _make_bodies(meshes: VolumeMeshes, entries: dict, path: Path, where: str, Body):
    bodies = []
    for s in meshes.surfaces:
        kw = {k: v for k, v in entries[s.label].items() if k != "name"}
        name = entries[s.label].get("name", s.name)
        try:
            bodies.append(Body(name=name, mesh=s.mesh, source_file=path, **kw))
        except XrayVizError as exc:
            raise type(exc)(f"{where} label {s.label}: {exc}") from None
    return bodies


def _labels_bodies(raw, k, base_dir, file, cache, body):
    where = _where(file, "labels", k)
    _check_keys(raw, LABELS_KEYS, where)
    path = _volume_file(raw, where, base_dir)
    materials = raw.get("materials")
    if not isinstance(materials, Mapping) or not materials:
        _fail(where, "needs 'materials', a table of label = material, such as "
                     "materials = { 1 = \"Bone, Cortical (ICRP)\", 2 = { mu = 0.3 } }")
    entries = {}
    for key, value in materials.items():
        try:
            label = int(str(key).strip())
        except ValueError:
            label = None
        if label is None or str(label) != str(key).strip().lstrip("+") or label == 0:
            _fail(where, f"materials: {key!r} is not a label; keys are the label values, "
                         "whole numbers other than 0 (the background)")
        entries[label] = _material_entry(value, f"{where} materials.{key}")
    if _trace_mode(raw, where, "labels") == "voxels":
        from xray_viz.volume import label_volume

        vol = _read_for_voxels(path, where, hu=False)
        present = {int(v) for v in np.unique(vol.data) if v != 0}
        missing = sorted(set(entries) - present)
        if missing:
            _fail(where, f"label{'s' * (len(missing) > 1)} {', '.join(map(str, missing))} "
                         f"of 'materials' ha{'ve' if len(missing) > 1 else 's'} no voxels")
        skipped = sorted(present - set(entries))
        if skipped:
            warnings.warn(f"{where}: {path.name}: label{'s' * (len(skipped) > 1)} "
                          f"{', '.join(map(str, skipped))} not in 'materials': skipped (empty)",
                          LabelSkippedWarning, stacklevel=4)
        made = label_volume(vol.data, vol.affine, entries, name=_stem(path), source_file=path,
                            names={v: e["name"] for v, e in entries.items() if "name" in e})
        return [dataclasses.replace(made, table=("labels", dict(raw)),
                                    interpolation=raw.get("interpolation", "nearest"))]
    max_error = _max_error(raw, where)
    try:
        meshes = label_surfaces(path, sorted(entries), max_error=max_error, cache=cache,
                                names={v: e["name"] for v, e in entries.items() if "name" in e})
    except XrayVizError as exc:
        raise type(exc)(f"{where}: {exc}") from None
    if meshes.skipped:
        sk = meshes.skipped
        warnings.warn(f"{where}: {path.name}: label{'s' * (len(sk) > 1)} "
                      f"{', '.join(map(str, sk))} not in 'materials': skipped (no body)",
                      LabelSkippedWarning, stacklevel=4)
    if not meshes.surfaces:
        _fail(where, f"{path.name}: no body: none of the labels {sorted(entries)} given in "
                     "'materials' has voxels in the label map")
    return _make_bodies(meshes, entries, path, where, body)


def _ct_bodies(raw, k, base_dir, file, cache, body):
    where = _where(file, "ct", k)
    _check_keys(raw, CT_KEYS, where)
    path = _volume_file(raw, where, base_dir)
    ranges = []
    entries = {}
    if "ranges" in raw:
        rr = raw["ranges"]
        if not isinstance(rr, list) or not rr:
            _fail(where, "ranges must be an array of tables such as "
                         "[{ hu = [-950, -120], material = \"Lung (ICRP)\", density = 0.26 }]")
        for j, r in enumerate(rr, start=1):
            w = f"{where} ranges #{j}"
            _check_keys(r, RANGE_KEYS, w)
            hu = r.get("hu")
            if (not isinstance(hu, list) or len(hu) != 2
                    or not all(isinstance(x, (int, float)) and not isinstance(x, bool)
                               for x in hu) or not hu[0] < hu[1]):
                _fail(w, f"hu must be [low, high] HU with low < high, got {hu!r}")
            e = _material_entry({x: r[x] for x in r if x != "hu"}, w)
            name = e.get("name", f"class{j}")
            ranges.append((name, float(hu[0]), float(hu[1])))
            entries[j] = e
        spans = sorted(ranges, key=lambda t: t[1])
        for a, b in zip(spans, spans[1:]):
            if b[1] < a[2]:
                _fail(where, f"ranges {a[0]!r} and {b[0]!r} overlap ({a[1]:g}..{a[2]:g} and "
                             f"{b[1]:g}..{b[2]:g} HU)")
    else:
        for j, (name, lo, hi, material, density) in enumerate(SCHNEIDER_2000, start=1):
            ranges.append((name, lo, hi))
            entries[j] = {"material": material, **({"density": density} if density else {})}
    if _trace_mode(raw, where, "ct") == "voxels":
        from xray_viz.volume import HU_DENSITY, ct_volume

        vol = _read_for_voxels(path, where, hu=True)
        try:
            check_hounsfield(vol.data, path)
        except MeshError as exc:
            _fail(where, str(exc).removeprefix(f"{path}: "))
        if "ranges" in raw:
            table = []
            for (name, lo, hi), j in zip(ranges, sorted(entries)):
                e = dict(entries[j])
                if "mu" not in e and e.get("density") is None:   # the density line
                    e["line"] = HU_DENSITY[0][4] if lo < 120.0 else HU_DENSITY[3][4]
                table.append((name, lo, hi, e))
        else:
            table = None
        try:
            made = ct_volume(vol.data, vol.affine, name=_stem(path), ranges=table,
                             source_file=path)
        except SceneError as exc:
            _fail(where, str(exc))
        if not made.classes.any():           # a blank image, exit 0, said nothing
            _fail(where, "gives no body: no voxel falls in any of its HU ranges (all air?); "
                         "check the file, or its ranges")
        return [dataclasses.replace(made, table=("ct", dict(raw)),
                                    interpolation=raw.get("interpolation", "nearest"))]
    median = raw.get("median", 1)
    min_voxels = raw.get("min_voxels", 27)
    for key, v in (("median", median), ("min_voxels", min_voxels)):
        if isinstance(v, bool) or not isinstance(v, int) or v < 0:
            _fail(where, f"{key} must be a whole number >= 0, got {v!r}")
    if median > MAX_MEDIAN:
        _fail(where, f"median = {median} is too large: the median filter's size in voxels is "
                     f"0 or 1 (none) up to {MAX_MEDIAN} (3 removes speckle)")
    try:
        meshes = ct_surfaces(path, ranges, max_error=_max_error(raw, where), median=median,
                             min_voxels=min_voxels, cache=cache)
    except XrayVizError as exc:
        raise type(exc)(f"{where}: {exc}") from None
    if not meshes.surfaces:                  # a blank image, exit 0, said nothing
        _fail(where, f"{path.name}: no body: no HU class holds {min_voxels} connected voxels "
                     f"or more (the ranges: {', '.join(f'{n} {lo:g}..{hi:g}' for n, lo, hi in ranges)}"
                     "); check the CT's values and the ranges, or lower min_voxels")
    return _make_bodies(meshes, entries, path, where, body)


def volume_bodies(tables: Mapping, *, base_dir=".", file=None, cache: bool = True,
                  body=None) -> list:
    """The bodies of a scene's ``[[labels]]`` and ``[[ct]]`` tables (the scene file's hook).

    Parameters
    ----------
    tables : mapping
        ``{"labels": [...] or None, "ct": [...] or None}``, the raw TOML values.
    base_dir : path-like
        Folder that ``file`` entries are relative to.
    file : Path, optional
        The scene file, named in messages.
    body : type
        The body class, :class:`xray_viz.scene.Body` (the scene reader passes it: this module
        sits below the scene model and does not import it).
    cache : bool, optional
        Use the on-disk mesh cache.

    Returns
    -------
    list of Body or VoxelVolume
        In the order of the tables, and of the labels (ascending) within each; a table with
        ``trace = "voxels"`` gives one :class:`xray_viz.volume.VoxelVolume`.

    Raises
    ------
    SceneError, MaterialError, SceneFileNotFoundError, MeshError
        One line naming the file, the table and the key.
    """
    base_dir = Path(base_dir)
    bodies = []
    for key, make in (("labels", _labels_bodies), ("ct", _ct_bodies)):
        raw = tables.get(key)
        if raw is None:
            continue
        if not isinstance(raw, list):
            raise SceneError(f"{file}: " * bool(file) + f"'{key}' must be an array of tables: "
                             f"write [[{key}]]")
        for k, t in enumerate(raw):
            bodies.extend(make(t, k, base_dir, file, cache, body))
    return bodies

"""Writing images: ``.npy`` (float64 as computed), ``.tiff`` (float32), ``.png`` (16-bit) and
DICOM ``.dcm`` (16-bit with rescale slope and intercept, and the geometry of the scene).

Files are written to a temporary name beside the target and renamed into place, so a failed
write never leaves a half-written file.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from xray_viz.errors import OutputError

__all__ = ["save_image", "load_image", "to_uint16", "dicom_dataset", "FORMATS"]

#: Output suffixes and what they hold.
FORMATS = {
    ".npy": "the float64 array exactly as the API returns it",
    ".tiff": "float32 TIFF",
    ".tif": "float32 TIFF",
    ".png": "16-bit grey PNG, attenuation bright, windowed to the data",
    ".dcm": "DICOM DX image, 16-bit with RescaleSlope/Intercept, geometry of the scene",
}


def to_uint16(image, *, bright="high") -> np.ndarray:
    """Window an image to its own range and scale it to 0..65535.

    Parameters
    ----------
    image : (H, W) float
    bright : {"high", "low"}
        ``"high"``: the largest value is white (line integrals, path lengths);
        ``"low"``: the smallest value is white (intensities, so attenuation shows bright).
    """
    a = np.asarray(image, dtype=np.float64)
    lo, hi = np.nanmin(a), np.nanmax(a)
    scaled = np.zeros_like(a) if hi <= lo else (a - lo) / (hi - lo)
    if bright == "low":
        scaled = 1.0 - scaled if hi > lo else scaled
    return np.round(np.clip(scaled, 0, 1) * 65535).astype(np.uint16)


def _atomic_write(path: Path, write) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def save_image(path, image, *, bright="high", scene=None, quantity=None) -> Path:
    """Save an (H, W) image; the format follows the suffix (see :data:`FORMATS`).

    Parameters
    ----------
    path : path-like
    image : (H, W) float
    bright : {"high", "low"}
        Which end of the values is shown white (``.png``, ``.dcm``): ``"low"`` for intensities.
    scene : Scene, optional
        Required for ``.dcm``: gives pixel spacing, distances, kVp or energy
        (see :func:`dicom_dataset`).
    quantity : str, optional
        What the image holds (``"intensity"``, ``"line-integral"``, ``"path-length"``), written
        to the DICOM header.

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "a.npy"
    >>> _ = save_image(out, np.eye(2))
    >>> np.load(out).tolist()
    [[1.0, 0.0], [0.0, 1.0]]
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix not in FORMATS:
        known = ", ".join(FORMATS)
        raise OutputError(f"{path}: unknown output format {suffix or '(none)'!r}; use one of {known}")
    image = np.asarray(image)
    if suffix == ".npy":
        _atomic_write(path, lambda tmp: np.save(tmp, image))
    elif suffix in (".tif", ".tiff"):
        from PIL import Image

        _atomic_write(path, lambda tmp: Image.fromarray(image.astype(np.float32))
                      .save(tmp, format="TIFF"))
    elif suffix == ".png":
        from PIL import Image

        data = to_uint16(image, bright=bright)
        _atomic_write(path, lambda tmp: Image.fromarray(data).save(tmp, format="PNG"))
    elif suffix == ".dcm":
        if scene is None:
            raise OutputError(f"{path}: DICOM output needs the scene for its geometry: "
                              "save_image(path, image, scene=scene)")
        ds = dicom_dataset(image, scene, bright=bright, quantity=quantity)
        _atomic_write(path, lambda tmp: _dcmwrite(tmp, ds))
    return path


def _dcmwrite(path, ds) -> None:
    import pydicom

    try:
        pydicom.dcmwrite(path, ds, enforce_file_format=True)
    except TypeError:  # pragma: no cover - pydicom < 3
        pydicom.dcmwrite(path, ds, write_like_original=False)


def _ds(value: float) -> str:
    """A DICOM decimal string (at most 16 characters)."""
    text = f"{value:.10g}"
    return text if len(text) <= 16 else f"{value:.6e}"


def dicom_dataset(image, scene, *, bright="high", quantity=None):
    """A DICOM Digital X-Ray (for presentation) dataset of an image and its scene's geometry.

    Pixel data are 16-bit unsigned integers windowed to the finite values of the image;
    ``value = stored * RescaleSlope + RescaleIntercept`` recovers them to within half a
    quantisation step, ``(max - min) / 65535 / 2``. Infinite values (a line integral through a
    body that stops every photon) are stored as the window's end.

    Geometry written:

    * ``ImagerPixelSpacing``: the detector pitch (row spacing, column spacing) in mm.
    * ``PixelSpacing``: the pitch divided by the magnification ``SID / SOD``, i.e. mm in the
      object plane, with ``PixelSpacingCalibrationType = "GEOMETRY"`` and
      ``EstimatedRadiographicMagnificationFactor``: viewers that measure use it, so distances
      read in the viewer are object sizes at the object plane.
    * ``DistanceSourceToDetector`` (SID, source to detector centre) and
      ``DistanceSourceToPatient`` (SOD, source to the object plane through the centre of the
      bodies' bounding box, along the beam axis; see
      :func:`xray_viz.physics.imaging.source_object_distance`), in mm.
    * ``KVP``: the tube potential of a tube spectrum, the highest energy (keV) of a CSV spectrum,
      the photon energy of a monochromatic beam (then also in ``ImageComments``).
    * ``FocalSpots`` (mm) when a focal spot is set.

    Photometric interpretation: ``MONOCHROME2`` (high values white) or, with ``bright="low"``,
    ``MONOCHROME1`` (low values white: an intensity image shows attenuation bright, like a
    radiograph).

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> ds = dicom_dataset(np.eye(3), xray_viz.load_scene("sphere"))
    >>> float(ds.DistanceSourceToDetector), float(ds.DistanceSourceToPatient)
    (1500.0, 1000.0)
    """
    import datetime

    import pydicom
    from pydicom.dataset import FileDataset, FileMetaDataset
    from pydicom.uid import ExplicitVRLittleEndian, generate_uid

    from xray_viz.physics import imaging
    from xray_viz.physics.spectra import source_spectrum

    a = np.asarray(image, dtype=np.float64)
    if a.ndim != 2:
        raise OutputError(f"DICOM output needs an (H, W) image, got shape {a.shape}")
    finite = np.isfinite(a)
    lo, hi = (float(a[finite].min()), float(a[finite].max())) if finite.any() else (0.0, 0.0)
    # quantise with the slope and intercept exactly as written (decimal strings)
    intercept = float(_ds(lo))
    slope = float(_ds((hi - lo) / 65535.0)) if hi > lo else 1.0
    filled = np.where(np.isnan(a), lo, np.clip(a, lo, hi))
    stored = np.clip(np.round((filled - intercept) / slope), 0, 65535).astype(np.uint16)

    sop_class = "1.2.840.10008.5.1.4.1.1.1.1"  # Digital X-Ray Image Storage - For Presentation
    meta = FileMetaDataset()
    meta.MediaStorageSOPClassUID = sop_class
    meta.MediaStorageSOPInstanceUID = generate_uid()
    meta.TransferSyntaxUID = ExplicitVRLittleEndian
    meta.ImplementationClassUID = pydicom.uid.PYDICOM_IMPLEMENTATION_UID
    ds = FileDataset(None, {}, file_meta=meta, preamble=b"\0" * 128)
    now = datetime.datetime.now()
    ds.SOPClassUID = sop_class
    ds.SOPInstanceUID = meta.MediaStorageSOPInstanceUID
    ds.StudyInstanceUID = generate_uid()
    ds.SeriesInstanceUID = generate_uid()
    ds.FrameOfReferenceUID = generate_uid()
    ds.Modality = "DX"
    ds.PresentationIntentType = "FOR PRESENTATION"
    ds.ImageType = ["DERIVED", "SECONDARY"]
    ds.ContentDate = now.strftime("%Y%m%d")
    ds.ContentTime = now.strftime("%H%M%S")
    ds.StudyDate, ds.StudyTime = ds.ContentDate, ds.ContentTime
    ds.PatientName = "Phantom^" + (scene.path.stem if getattr(scene, "path", None) else "scene")
    ds.PatientID = "XRAY_VIZ"
    ds.Manufacturer = "xray_viz (simulation)"
    ds.SeriesDescription = f"simulated radiograph: {quantity or 'image'}"
    ds.PatientOrientation = ""
    ds.BodyPartExamined = ""
    ds.ViewPosition = ""

    # pixels
    h, w = a.shape
    ds.Rows, ds.Columns = h, w
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME1" if bright == "low" else "MONOCHROME2"
    ds.BitsAllocated = 16
    ds.BitsStored = 16
    ds.HighBit = 15
    ds.PixelRepresentation = 0
    ds.RescaleIntercept = _ds(intercept)
    ds.RescaleSlope = _ds(slope)
    ds.RescaleType = "US"
    ds.WindowCenter = _ds((lo + hi) / 2)
    ds.WindowWidth = _ds(max(hi - lo, slope))
    if quantity is not None:
        # +1: higher values mean more X-rays (intensity); -1: fewer (line integral, path length)
        ds.PixelIntensityRelationship = "LIN" if quantity == "intensity" else "LOG"
        ds.PixelIntensityRelationshipSign = 1 if quantity == "intensity" else -1
    ds.PixelData = stored.tobytes()

    # geometry
    px, py = scene.detector.pitch
    sid = imaging.source_detector_distance(scene)
    sod = imaging.source_object_distance(scene)
    mag = imaging.magnification(scene)
    ds.ImagerPixelSpacing = [_ds(py), _ds(px)]
    ds.PixelSpacing = [_ds(py / mag), _ds(px / mag)]
    ds.PixelSpacingCalibrationType = "GEOMETRY"
    ds.PixelSpacingCalibrationDescription = "object plane through the centre of the bodies"
    ds.EstimatedRadiographicMagnificationFactor = _ds(mag)
    ds.DistanceSourceToDetector = _ds(sid)
    ds.DistanceSourceToPatient = _ds(sod)
    spectrum = source_spectrum(scene.source)
    ds.KVP = _ds(spectrum.kvp if spectrum.kvp is not None else spectrum.max_energy)
    if scene.detector.focal_spot > 0:
        ds.FocalSpots = _ds(scene.detector.focal_spot)
    ds.ImageComments = (f"{quantity or 'image'}; beam: {spectrum.description}; "
                        f"detector response: {scene.detector.response}; SID {sid:g} mm, "
                        f"SOD {sod:g} mm")[:10240]
    return ds


def load_image(path) -> np.ndarray:
    """Read back an image written by :func:`save_image`.

    ``.npy`` and ``.tiff`` give the saved values, ``.png`` the 16-bit stored values, ``.dcm`` the
    rescaled float64 values (``stored * RescaleSlope + RescaleIntercept``).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return np.load(path)
    if suffix == ".dcm":
        import pydicom

        ds = pydicom.dcmread(path)
        stored = np.frombuffer(ds.PixelData, dtype="<u2").reshape(ds.Rows, ds.Columns)
        return stored * float(ds.RescaleSlope) + float(ds.RescaleIntercept)
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im)

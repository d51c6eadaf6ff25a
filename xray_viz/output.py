"""Writing images: ``.npy`` (float64 as computed), ``.tiff`` (float32), ``.png`` (16-bit) and
DICOM ``.dcm`` (a 16-bit DX image with the geometry of the scene; the physical values through a
Real World Value Mapping).

Files are written to a temporary name beside the target and renamed into place, so a failed
write never leaves a half-written file.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from xray_viz.errors import OutputError

__all__ = ["save_image", "load_image", "to_uint16", "dicom_dataset", "dicom_values",
           "atomic_write", "FORMATS", "UNITS"]

#: Output suffixes and what they hold.
FORMATS = {
    ".npy": "the float64 array exactly as the API returns it",
    ".tiff": "float32 TIFF",
    ".tif": "float32 TIFF",
    ".png": "16-bit grey PNG, attenuation bright, windowed to the data",
    ".dcm": "DICOM DX image, 16-bit, values by Real World Value Mapping, geometry of the scene",
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


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def atomic_write(path: Path, write) -> None:
    """Write through a temporary file beside ``path``, then rename: never a half-written file.

    An operating-system error names ``path`` (not the temporary file) in an :class:`OutputError`.
    """
    tmp = None
    if path.parent.exists() and not path.parent.is_dir():
        raise OutputError(f"{path}: cannot write: {path.parent} is a file, not a folder")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
        os.close(fd)
        write(tmp)
        os.chmod(tmp, 0o666 & ~_umask())    # mkstemp makes 0600; a new file gets the usual mode
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None and os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, OSError):
            raise OutputError(f"{path}: cannot write: {exc.strerror or exc}") from None
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
        atomic_write(path, lambda tmp: np.save(tmp, image))
    elif suffix in (".tif", ".tiff"):
        from PIL import Image

        atomic_write(path, lambda tmp: Image.fromarray(image.astype(np.float32))
                      .save(tmp, format="TIFF"))
    elif suffix == ".png":
        from PIL import Image

        data = to_uint16(image, bright=bright)
        atomic_write(path, lambda tmp: Image.fromarray(data).save(tmp, format="PNG"))
    elif suffix == ".dcm":
        if scene is None:
            raise OutputError(f"{path}: DICOM output needs the scene for its geometry: "
                              "save_image(path, image, scene=scene)")
        ds = dicom_dataset(image, scene, bright=bright, quantity=quantity)
        atomic_write(path, lambda tmp: _dcmwrite(tmp, ds))
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

    Pixel data are 16-bit unsigned integers spanning the finite values of the image. The DX
    Image Module fixes ``RescaleSlope = 1``, ``RescaleIntercept = 0`` (``RescaleType = "US"``),
    so the physical values are carried by one item of the ``RealWorldValueMappingSequence``
    (0040,9096): ``value = stored * RealWorldValueSlope + RealWorldValueIntercept`` (double
    precision) for stored values 0..65535, with ``LUTLabel`` the quantity and
    ``MeasurementUnitsCodeSequence`` its UCUM unit (``"1"``, no units, for intensities in photons
    per pixel and line integrals; ``"mm"`` for path lengths). It recovers the values to within
    half a quantisation step, ``(max - min) / 65535 / 2`` (:func:`load_image`). Infinite values
    (a line integral through a body that stops every photon) are stored as the range's end.
    The window (``WindowCenter``/``WindowWidth``, in stored values) spans the whole range.

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
    * ``KVP``: the tube potential of a tube spectrum, or the highest energy (keV) of a CSV
      spectrum (its end point). A monochromatic beam has no tube potential: it has no ``KVP``,
      and its photon energy is in ``ImageComments`` ("beam: monochromatic 60 keV").
    * ``FocalSpots`` (mm) when a focal spot is set.

    Grey scale: ``PhotometricInterpretation = "MONOCHROME2"`` with
    ``PresentationLUTShape = "IDENTITY"`` (high values white) or, with ``bright="low"``,
    ``"MONOCHROME1"`` with ``"INVERSE"`` (low values white: an intensity image shows attenuation
    bright, like a radiograph). ``PixelIntensityRelationship`` is ``LIN`` for intensities and
    ``LOG`` for line integrals and path lengths; ``PixelIntensityRelationshipSign`` is ``+1``
    for intensities (higher stored values, more X-rays) and ``-1`` for line integrals and path
    lengths; for ``quantity=None`` it follows ``bright`` (``"low"``: ``+1``). With the defaults of
    :func:`save_image` for each quantity, less X-ray intensity is always shown white.

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
    if bright not in ("high", "low"):
        raise OutputError(f"bright must be 'high' or 'low', got {bright!r}")
    finite = np.isfinite(a)
    lo, hi = (float(a[finite].min()), float(a[finite].max())) if finite.any() else (0.0, 0.0)
    intercept = lo
    slope = (hi - lo) / 65535.0 if hi > lo else 1.0
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
    ds.ImageType = ["DERIVED", "SECONDARY", ""]      # DX: value 3 present and empty
    ds.ContentDate = now.strftime("%Y%m%d")
    ds.ContentTime = now.strftime("%H%M%S")
    ds.StudyDate, ds.StudyTime = ds.ContentDate, ds.ContentTime
    ds.PatientName = "Phantom^" + (scene.path.stem if getattr(scene, "path", None) else "scene")
    ds.PatientID = "XRAY_VIZ"
    ds.Manufacturer = "xray_viz (simulation)"
    ds.SeriesDescription = f"simulated radiograph: {quantity or 'image'}"
    ds.PatientBirthDate = ""
    ds.PatientSex = ""
    ds.ReferringPhysicianName = ""
    ds.StudyID = ""
    ds.AccessionNumber = ""
    ds.SeriesNumber = 1
    ds.InstanceNumber = 1
    ds.PatientOrientation = ""
    ds.BodyPartExamined = ""
    ds.ViewPosition = ""
    ds.ImageLaterality = "U"
    ds.AcquisitionContextSequence = []
    ds.BurnedInAnnotation = "NO"
    ds.LossyImageCompression = "00"

    # pixels
    h, w = a.shape
    ds.Rows, ds.Columns = h, w
    ds.SamplesPerPixel = 1
    ds.PhotometricInterpretation = "MONOCHROME1" if bright == "low" else "MONOCHROME2"
    ds.BitsAllocated = 16
    ds.BitsStored = 16
    ds.HighBit = 15
    ds.PixelRepresentation = 0
    # DX Image Module: an identity Modality LUT; Presentation LUT Shape follows the photometric
    # interpretation (PS3.3 C.8.11.3, C.7.6.1.1.6)
    ds.RescaleIntercept = "0"
    ds.RescaleSlope = "1"
    ds.RescaleType = "US"
    ds.PresentationLUTShape = "INVERSE" if bright == "low" else "IDENTITY"
    ds.WindowCenter = "32767.5"
    ds.WindowWidth = "65536"
    ds.VOILUTFunction = "LINEAR"
    # +1: higher values mean more X-rays (intensity); -1: fewer (line integral, path length)
    if quantity is None:
        ds.PixelIntensityRelationship = "LIN"
        ds.PixelIntensityRelationshipSign = 1 if bright == "low" else -1
    else:
        ds.PixelIntensityRelationship = "LIN" if quantity == "intensity" else "LOG"
        ds.PixelIntensityRelationshipSign = 1 if quantity == "intensity" else -1
    ds.RealWorldValueMappingSequence = [_real_world_value_mapping(slope, intercept, quantity)]
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
    if len(spectrum) > 1:                 # a monochromatic beam has no tube potential
        ds.KVP = _ds(spectrum.kvp if spectrum.kvp is not None else spectrum.max_energy)
    if scene.detector.focal_spot > 0:
        ds.FocalSpots = _ds(scene.detector.focal_spot)
    ds.ImageComments = (f"{quantity or 'image'}; beam: {spectrum.description}; "
                        f"detector response: {scene.detector.response}; SID {sid:g} mm, "
                        f"SOD {sod:g} mm")[:10240]
    return ds


#: UCUM units of each quantity: (code, meaning).
UNITS = {"intensity": ("1", "no units"), "line-integral": ("1", "no units"),
         "path-length": ("mm", "millimeter")}


def _real_world_value_mapping(slope: float, intercept: float, quantity):
    """The Real World Value Mapping item: stored 0..65535 -> value, with units (UCUM)."""
    from pydicom.dataset import Dataset

    code, meaning = UNITS.get(quantity, ("1", "no units"))
    item = Dataset()
    item.add_new(0x00409216, "US", 0)           # RealWorldValueFirstValueMapped
    item.add_new(0x00409211, "US", 65535)       # RealWorldValueLastValueMapped
    item.RealWorldValueIntercept = float(intercept)
    item.RealWorldValueSlope = float(slope)
    item.LUTLabel = (quantity or "value")[:16]
    item.LUTExplanation = {
        "intensity": "detected intensity I = I0 F T (photons per pixel)",
        "line-integral": "line integral -ln(I / (I0 F))",
        "path-length": "total path length through the bodies (mm)",
    }.get(quantity, "image value")
    units = Dataset()
    units.CodeValue = code
    units.CodingSchemeDesignator = "UCUM"
    units.CodeMeaning = meaning
    item.MeasurementUnitsCodeSequence = [units]
    return item


def dicom_values(ds) -> np.ndarray:
    """The float64 values of a DICOM image: its first Real World Value Mapping applied to the
    stored pixels (falling back to the Modality LUT's RescaleSlope/RescaleIntercept).

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> image = np.array([[0.5, 1.0], [2.0, 4.0]])
    >>> ds = dicom_dataset(image, xray_viz.load_scene("sphere"), quantity="line-integral")
    >>> bool(np.abs(dicom_values(ds) - image).max() <= 3.5 / 65535 / 2)
    True
    """
    stored = ds.pixel_array.astype(np.float64)
    rwv = ds.get("RealWorldValueMappingSequence")
    if rwv:
        item = rwv[0]
        first = int(item.get("RealWorldValueFirstValueMapped", 0))
        last = int(item.get("RealWorldValueLastValueMapped", 65535))
        if not np.all((stored >= first) & (stored <= last)):
            raise OutputError("DICOM stored values outside the Real World Value Mapping's range")
        return stored * float(item.RealWorldValueSlope) + float(item.RealWorldValueIntercept)
    return stored * float(ds.get("RescaleSlope", 1.0)) + float(ds.get("RescaleIntercept", 0.0))


def load_image(path) -> np.ndarray:
    """Read back an image written by :func:`save_image`.

    ``.npy`` and ``.tiff`` give the saved values, ``.png`` the 16-bit stored values, ``.dcm`` the
    float64 values of its Real World Value Mapping (:func:`dicom_values`).
    """
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return np.load(path)
    if suffix == ".dcm":
        import pydicom

        return dicom_values(pydicom.dcmread(path))
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im)

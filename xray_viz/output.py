"""Writing images: ``.npy`` (float64 as computed), ``.tiff`` (float32), ``.png`` (16-bit) and
DICOM ``.dcm`` (a 16-bit DX image with the geometry of the scene; the physical values through a
Real World Value Mapping).

Files are written to a temporary name beside the target, read back, and renamed into place
(:func:`atomic_write`), so a failed or interrupted write never leaves a half-written file and
never loses the previous one.
"""

from __future__ import annotations

import os
import signal
import stat
import tempfile
import threading
import warnings
from pathlib import Path

import numpy as np

from xray_viz.errors import OutputError, WriteInterrupted, one_line

__all__ = ["save_image", "load_image", "to_uint16", "dicom_dataset", "dicom_values",
           "atomic_write", "check_target", "FORMATS", "UNITS"]

#: Output suffixes and what they hold.
FORMATS = {
    ".npy": "the float64 array exactly as the API returns it",
    ".tiff": "float32 TIFF",
    ".tif": "float32 TIFF",
    ".png": "16-bit grey PNG, attenuation bright, windowed to the data",
    ".dcm": "DICOM DX image, 16-bit, values by Real World Value Mapping, geometry of the scene",
}


def to_uint16(image, *, bright="high") -> np.ndarray:
    """Window an image to the range of its finite values and scale it to 0..65535.

    Non-finite values do not stretch the window: it spans the finite values only, ``+inf`` is
    drawn at its top (the largest value; white with ``bright="high"``, so a line integral
    through a body that stops every photon is white), ``-inf`` and NaN at its bottom (as
    :func:`dicom_dataset` stores them). A ``RuntimeWarning`` says how many pixels were not finite.

    Parameters
    ----------
    image : (H, W) float
    bright : {"high", "low"}
        ``"high"``: the largest value is white (line integrals, path lengths);
        ``"low"``: the smallest value is white (intensities, so attenuation shows bright).

    Examples
    --------
    >>> import warnings
    >>> with warnings.catch_warnings():
    ...     warnings.simplefilter("ignore")
    ...     to_uint16(np.array([[0.0, 1.0], [np.inf, np.nan]])).tolist()
    [[0, 65535], [65535, 0]]
    """
    data, bad = _window(image, bright=bright)
    if bad:
        warnings.warn(_nonfinite_message(bad, data.size), RuntimeWarning, stacklevel=2)
    return data


def _nonfinite_message(bad: int, total: int, where: str = "") -> str:
    return (f"{where}{bad} of {total} pixels are not finite (inf or NaN); the 16-bit window "
            "spans the finite values, +inf is drawn at its top, -inf and NaN at its bottom")


def _window(image, *, bright="high") -> tuple[np.ndarray, int]:
    """(the 16-bit windowed image, the number of non-finite pixels): see :func:`to_uint16`."""
    if bright not in ("high", "low"):
        raise OutputError(f"bright must be 'high' or 'low', got {bright!r}")
    a = np.asarray(image, dtype=np.float64)
    finite = np.isfinite(a)
    bad = int(a.size - np.count_nonzero(finite))
    lo, hi = (float(a[finite].min()), float(a[finite].max())) if bad < a.size else (0.0, 0.0)
    if hi > lo:
        scaled = (np.where(finite, a, lo) - lo) / (hi - lo)
    else:
        scaled = np.zeros_like(a)
    scaled[a == np.inf] = 1.0           # the top of the window; -inf and NaN stay at 0
    if bright == "low":
        scaled = 1.0 - scaled
    return np.round(np.clip(scaled, 0, 1) * 65535).astype(np.uint16), bad


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _write_protected(path: Path, st: os.stat_result) -> bool:
    """Whether the current user may not overwrite ``path`` in place (as ``cp`` would refuse).

    The rule reads the mode bits of the class that applies: the owner's write bit for the
    file's owner, else the group's for a member of its group, else the others'. For root,
    whom the kernel lets write anything (``os.access`` says yes), a file is write-protected
    when it has no write bit at all (GNU ``rm`` and ``mv`` call such a file "write-protected").
    """
    mode = st.st_mode
    if not hasattr(os, "geteuid"):  # pragma: no cover - Windows: the read-only attribute
        return not os.access(path, os.W_OK)
    euid = os.geteuid()
    if euid == 0:
        return not mode & (stat.S_IWUSR | stat.S_IWGRP | stat.S_IWOTH)
    if st.st_uid == euid:
        return not mode & stat.S_IWUSR
    if st.st_gid == os.getegid() or st.st_gid in os.getgroups():
        return not mode & stat.S_IWGRP
    return not mode & stat.S_IWOTH


def check_target(path) -> Path:
    """Check that an output file may be written at ``path``; return the file that will be
    replaced (``path``, or the file a symbolic link ``path`` points to).

    Raises
    ------
    OutputError
        ``path`` is a folder, not a regular file (a device, a pipe), or read-only (see
        :func:`atomic_write`), or its folder is a file.
    """
    path = Path(path)
    target = Path(os.path.realpath(path)) if path.is_symlink() else path
    if target.parent.exists() and not target.parent.is_dir():
        raise OutputError(f"{path}: cannot write: {target.parent} is a file, not a folder")
    try:
        st = target.stat()
    except FileNotFoundError:
        return target
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc.strerror or one_line(exc)}") from None
    if stat.S_ISDIR(st.st_mode):
        raise OutputError(f"{path}: is a folder; give a file name to write")
    if not stat.S_ISREG(st.st_mode):
        raise OutputError(f"{path}: is not a regular file (a device, pipe or socket); "
                          "choose another output")
    if _write_protected(target, st):
        raise OutputError(f"{path}: is read-only (mode {stat.S_IMODE(st.st_mode):04o}); "
                          "remove it or choose another output")
    return target


class _Signalled(BaseException):
    """A termination signal, raised inside :func:`atomic_write` to run its clean-up."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


#: The signals :func:`atomic_write` turns into a clean-up (those whose handler is the default).
_SIGNALS = tuple(getattr(signal, name) for name in ("SIGTERM", "SIGINT", "SIGHUP")
                 if hasattr(signal, name))


class _SignalGuard:
    """Handlers of SIGTERM, SIGINT and SIGHUP for the duration of one write (main thread only).

    Only signals left at their default disposition are taken over (an ignored signal stays
    ignored, an application's own handler stays in charge). While ``armed`` a signal raises
    :class:`_Signalled` at once; otherwise (creating the temporary file, renaming it into
    place) it is remembered and acted on by :meth:`arm` or :meth:`pending`.
    """

    def __init__(self):
        self.signum = None
        self.armed = False
        self.previous = {}

    def _handler(self, signum, frame):
        if self.signum is None:
            self.signum = signum
        if self.armed:
            self.armed = False
            raise _Signalled(signum)

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            for sig in _SIGNALS:
                old = signal.getsignal(sig)
                if old is signal.SIG_DFL or old is signal.default_int_handler:
                    self.previous[sig] = old
                    signal.signal(sig, self._handler)
        return self

    def __exit__(self, *exc):
        self.armed = False
        for sig, old in self.previous.items():
            signal.signal(sig, old)
        return False

    def arm(self):
        if self.signum is not None:
            raise _Signalled(self.signum)
        self.armed = True

    def disarm(self):
        self.armed = False


def _signal_exception(signum: int, text: str) -> BaseException:
    """What a signal becomes once the clean-up is done: ``KeyboardInterrupt`` for SIGINT (as
    Python's default handler), :class:`WriteInterrupted` (exit status 128 + signum) otherwise."""
    name = signal.Signals(signum).name
    if signum == getattr(signal, "SIGINT", None):
        return KeyboardInterrupt(text)
    return WriteInterrupted(f"interrupted by {name}: {text}", signum)


def _os_error(exc: BaseException):
    """The operating-system error behind ``exc``: itself, or one that a writer wrapped (pydicom
    re-raises an ``OSError`` as a new one whose message embeds a traceback)."""
    seen = set()
    found = None
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError):
            found = exc
            if exc.errno is not None:
                return exc
        exc = exc.__cause__ or exc.__context__
    return found


def _strays(tmp: str) -> list[str]:
    """Files that a writer made beside the temporary file by appending to its name (as
    ``np.save`` appends ``.npy``)."""
    folder, name = os.path.split(tmp)
    try:
        return [os.path.join(folder, f) for f in os.listdir(folder or ".")
                if f.startswith(name) and f != name]
    except OSError:
        return []


def _remove(names) -> None:
    for name in names:
        try:
            os.unlink(name)
        except FileNotFoundError:
            pass
        except OSError:  # pragma: no cover - nothing better to do while failing already
            pass


def _fsync(path, *, folder=False) -> None:
    try:
        fd = os.open(path, os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if folder else 0))
    except OSError:
        if folder:
            return
        raise
    try:
        os.fsync(fd)
    except OSError:
        if not folder:
            raise
    finally:
        os.close(fd)


def _copy_owner_and_mode(tmp: str, st: os.stat_result | None) -> None:
    """Give the temporary file the permission bits (and, where allowed, the owner and group)
    of the file it replaces; a new file gets ``0o666 & ~umask`` (mkstemp makes 0600)."""
    if st is None:
        os.chmod(tmp, 0o666 & ~_umask())
        return
    if hasattr(os, "chown") and (st.st_uid, st.st_gid) != (os.geteuid(), os.getegid()):
        try:
            os.chown(tmp, st.st_uid, st.st_gid)
        except OSError:
            pass  # not allowed (not root): the file becomes the writer's, as cp's new files
    os.chmod(tmp, stat.S_IMODE(st.st_mode) & 0o777)


def atomic_write(path, write, *, verify=None) -> None:
    """Write through a temporary file beside ``path``, then rename: never a half-written file.

    ``write(tmp)`` writes the file at ``tmp`` (a path string, in the same folder as the
    target, whose suffix is the lower-case suffix of ``path``). Then ``verify(tmp)``, if given,
    reads it back and raises if it is not what was meant to be written. Only then is the file
    renamed over ``path``; on any failure the temporary file (and anything the writer made by
    appending to its name) is removed and the previous file at ``path`` is untouched.

    * **Permissions**: a replaced file keeps its permission bits (and, for root, its owner and
      group); a new file gets ``0o666 & ~umask``. A symbolic link is followed: the file it
      points to is replaced, the link stays. (A file with several hard links is replaced by a
      new file: the other links keep the old contents.)
    * **Read-only targets are refused**, as ``cp`` refuses them, although the rename could
      replace them: the file's owner is refused when the owner's write bit is clear, a member
      of its group when the group's is, anyone else when the others' is; root (who may write
      anything, ``os.access`` says yes) is refused when the file has no write bit at all, the
      files GNU ``rm``/``mv`` call "write-protected".
    * **Signals**: in the main thread, SIGTERM, SIGINT and SIGHUP (those left at their default
      handling) are caught while writing: the temporary file is removed, then SIGINT raises
      ``KeyboardInterrupt`` and the others :class:`~xray_viz.errors.WriteInterrupted`, a
      ``SystemExit`` with status ``128 + signum``. A signal during the final rename waits until
      the file is in place.
    * **Operating-system errors** (no space left, quota, I/O error), also those a writer
      wraps in another exception, become one line: ``PATH: cannot write: No space left on
      device``.

    Parameters
    ----------
    path : path-like
    write : callable
        ``write(tmp)`` writes the file.
    verify : callable, optional
        ``verify(tmp)`` raises (any exception) if the written file is wrong; its message
        becomes that of an :class:`OutputError`.

    Raises
    ------
    OutputError
        The target is read-only, a folder or not a regular file; the file could not be
        written or failed verification.
    """
    path = Path(path)
    target = check_target(path)
    try:
        st = target.stat()
    except FileNotFoundError:
        st = None
    except OSError as exc:
        raise OutputError(f"{path}: cannot write: {exc.strerror or one_line(exc)}") from None
    tmp = None
    with _SignalGuard() as guard:
        try:
            target.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=target.parent, prefix=f".{target.name}.",
                                       suffix=target.suffix.lower())
            os.close(fd)
            guard.arm()
            write(tmp)
            if verify is not None:
                try:
                    verify(tmp)
                except OutputError:
                    raise
                except Exception as exc:
                    error = _os_error(exc)
                    if error is not None and error.errno is not None:
                        raise               # reading back failed: an operating-system error
                    raise OutputError(f"{path}: cannot write: the written file does not read "
                                      f"back correctly: {one_line(exc)}") from None
            guard.disarm()
            _copy_owner_and_mode(tmp, st)
            _fsync(tmp)
            os.replace(tmp, target)
            tmp_done, tmp = tmp, None
            _remove(_strays(tmp_done))
            _fsync(target.parent, folder=True)
        except BaseException as exc:
            guard.disarm()
            if tmp is not None:
                _remove([tmp, *_strays(tmp)])
            if isinstance(exc, _Signalled):
                raise _signal_exception(exc.signum, f"{path} not written; nothing was "
                                        "changed there") from None
            if isinstance(exc, KeyboardInterrupt):
                raise
            if isinstance(exc, OutputError):
                raise OutputError(str(exc)) from None
            error = _os_error(exc)
            if error is not None:
                reason = error.strerror or one_line(error)
                raise OutputError(f"{path}: cannot write: {reason}") from None
            raise
    if guard.signum is not None:     # arrived while the finished file was renamed into place
        raise _signal_exception(guard.signum, f"{path} was written completely")


def _check_image_file(tmp, *, size, mode, values=None) -> None:
    """Open a written TIFF/PNG with PIL and compare its size, mode and pixels."""
    from PIL import Image

    with Image.open(tmp) as im:
        if im.size != size or im.mode != mode:
            raise OutputError(f"it holds a {im.size[0]}x{im.size[1]} {im.mode} image, "
                              f"not {size[0]}x{size[1]} {mode}")
        got = np.asarray(im)
    if values is not None and not np.array_equal(got, values, equal_nan=True):
        raise OutputError("its pixels differ from the image")


def _check_npy(tmp, image) -> None:
    got = np.load(tmp, mmap_mode=None if image.dtype.hasobject else "r",
                  allow_pickle=image.dtype.hasobject)
    if got.shape != image.shape or got.dtype != image.dtype:
        raise OutputError(f"it holds a {got.shape} {got.dtype} array, not {image.shape} "
                          f"{image.dtype}")
    if not image.dtype.hasobject and not np.array_equal(
            got, image, equal_nan=image.dtype.kind in "fc"):
        raise OutputError("its values differ from the image")


def _write_npy(tmp, image) -> None:
    with open(tmp, "wb") as fh:
        # through write(): an operating-system error keeps its errno (ndarray.tofile, which
        # np.save uses on a real file, reports only "N requested and M written")
        np.save(_Writer(fh), image)


class _Writer:
    """A file seen only through its ``write`` method."""

    def __init__(self, fh):
        self.write = fh.write


def _check_dicom(tmp, ds) -> None:
    import pydicom

    got = pydicom.dcmread(tmp)
    if (int(got.Rows), int(got.Columns)) != (int(ds.Rows), int(ds.Columns)):
        raise OutputError(f"it holds a {got.Columns}x{got.Rows} image, not "
                          f"{ds.Columns}x{ds.Rows}")
    if bytes(got.PixelData) != bytes(ds.PixelData):
        raise OutputError("its pixel data differ from the image")


def save_image(path, image, *, bright="high", scene=None, quantity=None) -> Path:
    """Save an (H, W) image; the format follows the suffix (see :data:`FORMATS`), in any case
    (``.NPY``, ``.Tiff``).

    The file is written by :func:`atomic_write` and read back before it replaces a previous
    file: ``np.load`` for ``.npy`` (shape, dtype, values), PIL for ``.tiff``/``.png`` (size,
    mode, pixels), ``pydicom.dcmread`` for ``.dcm`` (rows, columns, pixel data).

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

    Raises
    ------
    OutputError
        Unknown suffix, a read-only or otherwise unwritable target, a failed write or
        read-back (the previous file is kept).

    Warns
    -----
    RuntimeWarning
        A ``.png`` of an image with non-finite values (see :func:`to_uint16`).

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
        atomic_write(path, lambda tmp: _write_npy(tmp, image),
                     verify=lambda tmp: _check_npy(tmp, image))
        return path
    if image.ndim != 2:
        raise OutputError(f"{path}: {suffix} output needs an (H, W) image, got shape "
                          f"{image.shape}")
    size = (image.shape[1], image.shape[0])
    if suffix in (".tif", ".tiff"):
        from PIL import Image

        data = image.astype(np.float32)
        atomic_write(path, lambda tmp: Image.fromarray(data).save(tmp, format="TIFF"),
                     verify=lambda tmp: _check_image_file(tmp, size=size, mode="F", values=data))
    elif suffix == ".png":
        from PIL import Image

        data, bad = _window(image, bright=bright)
        if bad:
            warnings.warn(_nonfinite_message(bad, data.size, f"{path}: "), RuntimeWarning,
                          stacklevel=2)
        atomic_write(path, lambda tmp: Image.fromarray(data).save(tmp, format="PNG"),
                     verify=lambda tmp: _check_image_file(tmp, size=size, mode="I;16",
                                                          values=data))
    elif suffix == ".dcm":
        if scene is None:
            raise OutputError(f"{path}: DICOM output needs the scene for its geometry: "
                              "save_image(path, image, scene=scene)")
        ds = dicom_dataset(image, scene, bright=bright, quantity=quantity)
        atomic_write(path, lambda tmp: _dcmwrite(tmp, ds), verify=lambda tmp: _check_dicom(tmp, ds))
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
    exposure = ""
    if getattr(scene.source, "mas", None) is not None:
        from xray_viz.physics.dosimetry import air_kerma, hvl

        kerma = air_kerma(scene)
        ds.ExposureInuAs = int(round(kerma.mas * 1000))            # (0018,1153)
        ds.Exposure = int(round(kerma.mas))                         # (0018,1152), mAs
        if kerma.entrance_uGy is not None:
            # Entrance Dose in mGy (0040,8302): incident air kerma, free in air, no backscatter
            ds.EntranceDoseInmGy = _ds(kerma.entrance_uGy / 1000.0)
            ds.DistanceSourceToEntrance = _ds(kerma.entrance_distance_mm)
        ds.HalfValueLayer = _ds(hvl(spectrum).hvl1)               # mm Al, on air kerma
        exposure = (f"; {kerma.mas:g} mAs: incident air kerma (free in air, no backscatter) "
                    + (f"{kerma.entrance_uGy:.4g} uGy at the nearest body surface, "
                       if kerma.entrance_uGy is not None else "")
                    + f"{kerma.detector_uGy:.4g} uGy at the detector")
    from xray_viz.physics.dosimetry import SCATTER_NOT_MODELLED

    ds.ImageComments = (f"{quantity or 'image'}; beam: {spectrum.description}; "
                        f"detector response: {scene.detector.response}; SID {sid:g} mm, "
                        f"SOD {sod:g} mm{exposure}; {SCATTER_NOT_MODELLED}")[:10240]
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

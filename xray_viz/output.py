"""Writing and reading images: ``.npy`` (float64 as computed), ``.tiff`` (float32), ``.png``
(16-bit), NIfTI ``.nii``/``.nii.gz`` and HDF5 ``.h5`` (float64), and DICOM ``.dcm`` (a 16-bit DX
image; the physical values through a Real World Value Mapping). Every format but ``.npy`` keeps
the pixel pitch in its own fields and the scene's geometry and scene file in its metadata
(:func:`save_image`); :func:`load_image` reads them back (:class:`ImageMetadata`).

Files are written to a temporary name beside the target, read back, and renamed into place
(:func:`atomic_write`), so a failed or interrupted write never leaves a half-written file and
never loses the previous one.
"""

from __future__ import annotations

import json
import os
import signal
import stat
import tempfile
import threading
import warnings
import dataclasses
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from xray_viz.errors import OutputError, WriteInterrupted, one_line, reader_reason

__all__ = ["save_image", "load_image", "ImageMetadata", "image_metadata", "to_uint16",
           "dicom_dataset", "dicom_values", "atomic_write", "check_target", "check_format",
           "format_of", "FORMATS", "SUFFIX_FORMATS", "Format", "suffixes", "UNITS", "window_range", "OUTLIER_FRACTION",
           "LOG_WINDOW_RATIO", "png_window"]

@dataclasses.dataclass(frozen=True)
class Format:
    """One file format of :data:`FORMATS`: what a file of its suffix is and holds."""

    #: The format (``"npy"``, ``"tiff"``, ``"png"``, ``"dicom"``, ``"nifti"``, ``"hdf5"``,
    #: ``"zarr"``, ``"nexus"``, ``"tiff-folder"``): what the writers and readers dispatch on.
    name: str
    #: What a file holds (the command line's help).
    holds: str
    #: An image format (:func:`save_image`, :func:`load_image`).
    image: bool = False
    #: The projection stack ``xray-viz scan -o`` writes for this suffix (``"zarr"``,
    #: ``"nexus"``, ``"tiff"``: a folder of TIFF files), or None.
    stack: str | None = None
    #: ``(module, how to install it)`` when the format needs an optional library.
    library: tuple | None = None

    def __str__(self) -> str:
        return self.holds


_TIFF = ("tifffile", "pip install tifffile")
_NIFTI = ("nibabel", "pip install 'xray_viz[volumes]'")
_HDF5 = ("h5py", "pip install 'xray_viz[ct]'")
#: The one table from a file's suffix (:func:`format_of`) to its format: images (what
#: :func:`save_image` writes and :func:`load_image` reads) and projection stacks (what
#: ``xray-viz scan -o`` writes; no suffix: a folder of TIFF files).
SUFFIX_FORMATS = {
    ".npy": Format("npy", "the float64 array exactly as the API returns it", image=True),
    ".tiff": Format("tiff", "float32 TIFF, pixel pitch and scene geometry in its tags",
                    image=True, library=_TIFF),
    ".tif": Format("tiff", "float32 TIFF, pixel pitch and scene geometry in its tags",
                   image=True, library=_TIFF),
    ".png": Format("png", "16-bit grey PNG, attenuation bright, windowed to the data; pitch "
                   "(pHYs), window and geometry in its chunks", image=True),
    ".dcm": Format("dicom", "DICOM DX image, 16-bit, values by Real World Value Mapping, "
                   "geometry of the scene", image=True),
    ".nii": Format("nifti", "NIfTI-1, float64, the detector's pixel positions (mm) as its "
                   "affine, geometry", image=True, library=_NIFTI),
    ".nii.gz": Format("nifti", "gzipped NIfTI-1, as .nii", image=True, library=_NIFTI),
    ".h5": Format("hdf5", "HDF5 (NeXus-style), float64, pixel size and geometry", image=True,
                  stack="nexus", library=_HDF5),
    ".hdf5": Format("hdf5", "HDF5, as .h5", image=True, stack="nexus", library=_HDF5),
    ".zarr": Format("zarr", "Zarr store of a projection stack", stack="zarr"),
    ".nxs": Format("nexus", "HDF5 NeXus NXtomo projection stack", stack="nexus"),
    "": Format("tiff-folder", "a folder of TIFF files, one per projection", stack="tiff"),
}
#: The image formats of :data:`SUFFIX_FORMATS` (a view of it): suffix -> :class:`Format`.
FORMATS = {k: f for k, f in SUFFIX_FORMATS.items() if f.image}


def suffixes(*, image: bool = False, stack: bool = False) -> list:
    """The suffixes of :data:`SUFFIX_FORMATS` of images (``image=True``) or projection
    stacks.

    Examples
    --------
    >>> suffixes(image=True)[:3], suffixes(stack=True)
    (['.npy', '.tiff', '.tif'], ['.h5', '.hdf5', '.zarr', '.nxs', ''])
    """
    return [k for k, f in SUFFIX_FORMATS.items() if (image and f.image) or (stack and f.stack)]


def to_uint16(image, *, bright="high") -> np.ndarray:
    """Window an image to the range of its finite values and scale it to 0..65535.

    A few pixels far beyond the others at the attenuating end (a metal implant's: see
    :func:`window_range`) are drawn saturated at the window's end instead of taking the window.
    Intensities (``bright="low"``) that span more than a factor :data:`LOG_WINDOW_RATIO` (a
    body that stops nearly every photon: a chest, an abdomen) are stored on a logarithmic
    scale, as a radiograph is shown: the picture of their line integral ``-ln I`` (see
    :func:`window_range`); zero and negative intensities (noise) are drawn at the attenuating
    end.
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
    data, bad, _ = _window(image, bright=bright)
    if bad:
        warnings.warn(_nonfinite_message(bad, data.size), RuntimeWarning, stacklevel=2)
    return data


def _nonfinite_message(bad: int, total: int, where: str = "") -> str:
    return (f"{where}{bad} of {total} pixels are not finite (inf or NaN); the 16-bit window "
            "spans the finite values, +inf is drawn at its top, -inf and NaN at its bottom")


def _window(image, *, bright="high") -> tuple[np.ndarray, int, dict]:
    """(the 16-bit windowed image, the number of non-finite pixels, the window): see
    :func:`to_uint16`. The window is what a PNG records: the values mapped to stored 0 and
    65535, ``bright``, its ``scale`` when logarithmic, the quantisation ``step``, and how many
    finite pixels lie beyond it (``clipped``: an implant's, see :func:`window_range`; zero and
    negative intensities on a log scale)."""
    if bright not in ("high", "low"):
        raise OutputError(f"bright must be 'high' or 'low', got {bright!r}")
    a = np.asarray(image, dtype=np.float64)
    finite = np.isfinite(a)
    bad = int(a.size - np.count_nonzero(finite))
    values = a[finite]
    lo, hi, log = _png_window(values, bright=bright)
    window = {"low": lo, "high": hi, "bright": bright}
    if log:
        window.update(scale="log", step=float(np.log(hi) - np.log(lo)) / 65535.0)
    else:
        window["step"] = (hi - lo) / 65535.0
    clipped = int(np.count_nonzero((values < lo) | (values > hi)))
    if clipped:
        window["clipped"] = clipped
    if log:                             # lo > 0; zero and negative intensities drawn at lo
        shown = np.log(np.where(finite & (a > 0), a, lo))
        scaled = (shown - np.log(lo)) / (np.log(hi) - np.log(lo))
    elif hi > lo:
        scaled = (np.where(finite, a, lo) - lo) / (hi - lo)
    else:
        scaled = np.zeros_like(a)
    scaled[a == np.inf] = 1.0           # the top of the window; -inf and NaN stay at 0
    if bright == "low":
        scaled = 1.0 - scaled
    return np.round(np.clip(scaled, 0, 1) * 65535).astype(np.uint16), bad, window


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


def scene_target(path, *, command: str) -> Path:
    """Check ``-o`` of a command that writes a TOML scene file (``convert``, ``init``,
    ``register``): a ``.toml`` name in an existing folder that may be written
    (:func:`check_target`); returns ``path`` as a :class:`~pathlib.Path`.

    Raises
    ------
    SceneError
        Not a ``.toml`` name.
    SceneFileNotFoundError
        Its folder does not exist.
    OutputError
        See :func:`check_target`.
    """
    from xray_viz.errors import SceneError, SceneFileNotFoundError

    dst = Path(path)
    if dst.suffix.lower() != ".toml":
        raise SceneError(f"{dst}: {command} writes a TOML scene file; name it .toml")
    folder = dst.parent if str(dst.parent) else Path(".")
    if not folder.is_dir():
        raise SceneFileNotFoundError(f"{dst}: folder {folder} does not exist; create it first")
    check_target(dst)
    return dst


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
                                       suffix=format_of(target))
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


def format_of(path) -> str:
    """The output format of ``path``: its lower-case suffix, ``".nii.gz"`` for a gzipped NIfTI.

    Examples
    --------
    >>> format_of("a.TIFF"), format_of("scan.NII.GZ"), format_of("a.gz")
    ('.tiff', '.nii.gz', '.gz')
    """
    path = Path(path)
    return ".nii.gz" if path.name.lower().endswith(".nii.gz") else path.suffix.lower()


def check_format(path, *, stack: bool = False) -> str:
    """The format of ``path`` (:func:`format_of`) if :data:`SUFFIX_FORMATS` has it as an
    image (or, with ``stack``, as a projection stack).

    Raises
    ------
    OutputError
        An unknown suffix: one line listing the known ones.

    Examples
    --------
    >>> check_format("a.NII.GZ"), check_format("scan.zarr", stack=True)
    ('.nii.gz', '.zarr')
    """
    suffix = format_of(path)
    known = suffixes(image=not stack, stack=stack)
    if suffix not in known:
        names = ", ".join(k or "no suffix (a folder)" for k in known)
        raise OutputError(f"{path}: unknown output format {suffix or '(none)'!r}; use one of "
                          f"{names}")
    return suffix


def save_image(path, image, *, bright="high", scene=None, quantity=None,
               scatter=None) -> Path:
    """Save an (H, W) image; the format follows the suffix (see :data:`FORMATS`), in any case
    (``.NPY``, ``.Tiff``).

    Every format but ``.npy`` records what it holds and, given the ``scene``, where it was
    taken: the pixel pitch in the format's own resolution fields and the scene's geometry
    (source, detector centre, up, shape, pitch, energy or spectrum, SID, SOD), the quantity,
    the xray_viz version and the scene file itself (:meth:`~xray_viz.scene.Scene.to_toml`;
    left out when the scene cannot be written as a file: bodies built in Python or meshed from
    a label map) as JSON (:func:`image_metadata`), which :func:`load_image` returns as an
    :class:`ImageMetadata`:

    * ``.tiff``/``.tif`` (tifffile): float32, the JSON in ``ImageDescription``. TIFF has no
      millimetre unit: ``XResolution``/``YResolution`` hold pixels per centimetre,
      ``10 / pitch`` (``ResolutionUnit = CENTIMETER``), stored as rationals; the exact pitch
      is in the JSON.
    * ``.png`` (Pillow): 16 bits windowed to the finite values (:func:`to_uint16`); ``pHYs``
      holds the pitch as whole pixels per metre (``1000 / pitch``, rounded), an ``iTXt`` chunk
      ``xray_viz`` the JSON with the window (the values mapped to 0 and 65535, the bright
      end), from which :meth:`ImageMetadata.to_physical` maps the stored values back to the
      quantity within half a quantisation step.
    * ``.nii``/``.nii.gz`` (nibabel, the ``volumes`` extra): float64 as computed, stored
      ``(W, H)`` (voxel ``i`` the column, ``j`` the row, as ITK and viewers expect), the affine
      placing each pixel centre at its position on the detector in scene coordinates (mm,
      float32 as NIfTI-1 stores it);
      the JSON in a ``comment`` header extension.
    * ``.h5``/``.hdf5`` (h5py, the ``ct`` extra): float64 as computed at
      ``/entry/instrument/detector/data`` in a NeXus-style layout (``x_pixel_size``,
      ``y_pixel_size`` in mm, ``/entry/data`` the NXdata link), the JSON in
      ``/entry/xray_viz_metadata``.
    * ``.dcm``: DICOM DX with its own geometry fields (:func:`dicom_dataset`); needs ``scene``.

    The JSON of ``.tiff``, ``.png``, NIfTI and HDF5 also holds ``sha256`` (:data:`SEAL_KEY`),
    the SHA-256 of the stored pixels and of the rest of the JSON: :func:`load_image` refuses
    a file whose pixels or metadata no longer match it (a flipped bit, a cut), or whose
    xray_viz JSON no longer parses, in one line. ``.npy`` and ``.dcm`` hold no checksum.

    The file is written by :func:`atomic_write` and read back before it replaces a previous
    file: ``np.load`` for ``.npy`` (shape, dtype, values), tifffile for ``.tiff`` (values bit
    for bit, metadata), Pillow for ``.png`` (size, mode, pixels, metadata), nibabel and h5py
    for NIfTI and HDF5 (values, metadata), ``pydicom.dcmread`` for ``.dcm`` (rows, columns,
    pixel data).

    Parameters
    ----------
    path : path-like
    image : (H, W) float
    bright : {"high", "low"}
        Which end of the values is shown white (``.png``, ``.dcm``): ``"low"`` for intensities.
    scene : Scene, optional
        The geometry to record; required for ``.dcm`` (pixel spacing, distances, kVp or
        energy, see :func:`dicom_dataset`).
    quantity : str, optional
        What the image holds (``"intensity"``, ``"line-integral"``, ``"path-length"``).
    scatter : dict, optional
        The scatter the image includes (``mode``: ``"mc"`` or ``"kernel"``; ``histories``,
        ``seed``, ``smoothing_mm``), recorded in the JSON's ``"scatter"`` (with its ``scope``,
        :func:`~xray_viz.physics.dosimetry.scatter_scope`) and DICOM's ``ImageComments``.
        None: the primary alone (no ``"scatter"`` key; DICOM's comments say so).

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OutputError
        Unknown suffix, a format whose library is not installed, a read-only or otherwise
        unwritable target, a failed write or read-back (the previous file is kept).

    Warns
    -----
    RuntimeWarning
        A ``.png`` of an image with non-finite values (see :func:`to_uint16`).

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib, xray_viz
    >>> folder = pathlib.Path(tempfile.mkdtemp())
    >>> _ = save_image(folder / "a.npy", np.eye(2))
    >>> np.load(folder / "a.npy").tolist()
    [[1.0, 0.0], [0.0, 1.0]]
    >>> scene = xray_viz.load_scene("sphere")
    >>> _ = save_image(folder / "a.tiff", np.eye(2), scene=scene, quantity="path-length")
    >>> image, meta = load_image(folder / "a.tiff", with_metadata=True)
    >>> image.dtype.name, meta.quantity, meta.pitch, meta.geometry["sid_mm"]
    ('float32', 'path-length', (0.5, 0.5), 1500.0)
    """
    path = Path(path)
    suffix = check_format(path)
    fmt = FORMATS[suffix]
    image = np.asarray(image)
    if fmt.name == "npy":
        atomic_write(path, lambda tmp: _write_npy(tmp, image),
                     verify=lambda tmp: _check_npy(tmp, image))
        return path
    if image.ndim != 2:
        raise OutputError(f"{path}: {suffix} output needs an (H, W) image, got shape "
                          f"{image.shape}")
    if fmt.name == "dicom":
        if scene is None:
            raise OutputError(f"{path}: DICOM output needs the scene for its geometry: "
                              "save_image(path, image, scene=scene)")
        with warnings.catch_warnings(record=True) as caught:   # said with the file's name
            warnings.simplefilter("always")
            ds = dicom_dataset(image, scene, bright=bright, quantity=quantity, scatter=scatter)
        for w in caught:
            warnings.warn(f"{path}: {str(w.message).removeprefix('DICOM: ')}", w.category,
                          stacklevel=2)
        atomic_write(path, lambda tmp: _dcmwrite(tmp, ds), verify=lambda tmp: _check_dicom(tmp, ds))
        return path
    meta = image_metadata(scene, quantity=quantity, scatter=scatter)
    if fmt.library:
        _need(path, *fmt.library)
    if fmt.name == "tiff":
        data = image.astype(np.float32)
        _seal(meta, data)
        atomic_write(path, lambda tmp: _write_tiff(tmp, data, meta),
                     verify=lambda tmp: _check_tiff(tmp, data, meta))
    elif fmt.name == "png":
        data, bad, meta["window"] = _window(image, bright=bright)
        if bad:
            warnings.warn(_nonfinite_message(bad, data.size, f"{path}: "), RuntimeWarning,
                          stacklevel=2)
        _seal(meta, data)
        atomic_write(path, lambda tmp: _write_png(tmp, data, meta),
                     verify=lambda tmp: _check_png(tmp, data, meta))
    elif fmt.name == "nifti":
        data = image.astype(np.float64)
        affine = _detector_affine(scene, image.shape)
        _seal(meta, data)
        atomic_write(path, lambda tmp: _write_nifti(tmp, data, affine, meta),
                     verify=lambda tmp: _check_nifti(tmp, data, affine, meta))
    else:                                    # hdf5
        data = image.astype(np.float64)
        _seal(meta, data)
        check_room(path, data.nbytes + (1 << 16), what="the HDF5 image")
        atomic_write(path, lambda tmp: _write_hdf5(tmp, data, meta),
                     verify=lambda tmp: _check_hdf5(tmp, data, meta))
    return path


#: The metadata key of the SHA-256 of the stored pixels and of the rest of the metadata.
SEAL_KEY = "sha256"


def _seal_of(meta: dict, data) -> str:
    """Hex SHA-256 of the stored array (dtype little-endian, shape, bytes) and of the
    metadata's canonical JSON without :data:`SEAL_KEY`."""
    import hashlib

    a = np.ascontiguousarray(data)
    a = a.astype(a.dtype.newbyteorder("<"), copy=False)
    h = hashlib.sha256(json.dumps({k: v for k, v in meta.items() if k != SEAL_KEY},
                                  sort_keys=True).encode())
    h.update(f"{a.dtype.str}{a.shape}".encode())
    h.update(memoryview(a).cast("B"))
    return h.hexdigest()


def _seal(meta: dict, data) -> None:
    """Record :func:`_seal_of` in ``meta`` (the file then says what it holds, bit for bit)."""
    meta.pop(SEAL_KEY, None)
    meta[SEAL_KEY] = _seal_of(meta, data)


def _check_seal(path, suffix, image, raw, text_found: bool) -> None:
    """Refuse, in one line, a file whose pixels or metadata differ from the seal it records
    (a flipped bit, a cut), or whose xray_viz metadata no longer parse."""
    if raw is None or "xray_viz" not in raw:
        if text_found:
            raise OutputError(f"{path}: its xray_viz metadata are damaged (not JSON); the "
                              f"{suffix} file cannot be trusted: write it again")
        return
    seal = raw.get(SEAL_KEY)
    if seal is None:
        return                          # written before seals were recorded
    try:
        ok = _seal_of(raw, image) == seal
    except (TypeError, ValueError):
        ok = False
    if not ok:
        raise OutputError(f"{path}: its pixels or metadata differ from the SHA-256 it records "
                          f"(the {suffix} file is damaged); write it again")


def check_room(path, nbytes: int, *, what: str = "the file") -> None:
    """Refuse, before any work, to write about ``nbytes`` to ``path`` when the disk holding it
    has less free space, or the process may not write a file that large (``ulimit -f``,
    RLIMIT_FSIZE).

    HDF5 in particular cannot fail gracefully there: a write that fails for want of room
    leaves the library in a state where closing the file crashes the process (a segmentation
    fault after the error). A margin of 5 % and 1 MiB is asked for (the container's own
    structures).

    Raises
    ------
    OutputError
        One line: the file, what it needs, what there is, what to do.
    """
    import resource

    path = Path(path)
    need = int(nbytes * 1.05) + (1 << 20)
    soft, _ = resource.getrlimit(resource.RLIMIT_FSIZE)
    if soft != resource.RLIM_INFINITY and need > soft:
        raise OutputError(f"{path}: {what} needs about {_human(need)}, more than this process "
                          f"may write to one file ({_human(soft)}, ulimit -f); raise the "
                          "limit or write less")
    folder = path.absolute().parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    try:
        st = os.statvfs(folder)
    except OSError:
        return
    free = st.f_bavail * st.f_frsize
    if need > free:
        raise OutputError(f"{path}: {what} needs about {_human(need)}, only {_human(free)} "
                          "free on that disk; free some space or write it elsewhere")


def _human(nbytes: int) -> str:
    """``1536`` -> ``"1.5 KiB"``."""
    size = float(nbytes)
    for unit in ("bytes", "KiB", "MiB", "GiB", "TiB"):
        if size < 1024 or unit == "TiB":
            return f"{size:.0f} {unit}" if unit == "bytes" else f"{size:.3g} {unit}"
        size /= 1024
    return f"{size:.3g} TiB"


def _need(path, module: str, how: str) -> None:
    """Refuse, in one line, a format whose library is not installed."""
    import importlib.util

    if importlib.util.find_spec(module) is None:
        raise OutputError(f"{path}: {format_of(path)} output needs {module}: {how}")


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("xray_viz")
    except PackageNotFoundError:  # pragma: no cover - run from a source tree
        return "unknown"


def _scatter_meta(scatter) -> dict:
    """The JSON of the scatter an image includes: its plain values and ``scope``."""
    from xray_viz.physics.dosimetry import scatter_scope

    keep = {k: (int(v) if k in ("histories", "seed") else v) for k, v in dict(scatter).items()
            if k in ("mode", "histories", "seed", "smoothing_mm")}
    return {**keep, "scope": scatter_scope(keep.get("mode"))}


def image_metadata(scene=None, *, quantity=None, scatter=None) -> dict:
    """What :func:`save_image` records beside the pixels, as a JSON-ready dict.

    Keys: ``"xray_viz"`` (the version), ``"quantity"``, ``"units"`` (UCUM, see :data:`UNITS`),
    ``"pitch_mm"`` (``[along the rows, along the columns]``, i.e. column spacing then row
    spacing, as ``[detector] pitch``), ``"geometry"`` (``source``: position, kind, energy in
    keV or the spectrum table, mAs; ``detector``: centre, up, shape, pitch, response, focal
    spot; ``sid_mm``, ``sod_mm``, ``magnification``, see :mod:`xray_viz.physics.imaging`) and
    ``"scene_toml"`` (:meth:`~xray_viz.scene.Scene.to_toml`); the last three are ``None``
    without a scene, ``"scene_toml"`` also when the scene cannot be written as a file. With
    ``scatter`` (see :func:`save_image`) also ``"scatter"``: ``mode``, ``histories`` and
    ``seed`` where given, and ``scope``, what the image includes.

    Examples
    --------
    >>> import xray_viz
    >>> meta = image_metadata(xray_viz.load_scene("sphere"), quantity="intensity")
    >>> meta["pitch_mm"], meta["geometry"]["source"]["position"], meta["units"]
    ([0.5, 0.5], [0.0, 0.0, 1000.0], '1')
    """
    from collections.abc import Mapping

    meta = {"xray_viz": _version(), "quantity": quantity,
            "units": UNITS.get(quantity, ("1", "no units"))[0], "pitch_mm": None,
            "geometry": None, "scene_toml": None}
    if scatter is not None:
        meta["scatter"] = _scatter_meta(scatter)
    if scene is None:
        return meta
    from xray_viz._toml import plain
    from xray_viz.errors import SceneError
    from xray_viz.physics import imaging

    src, det = scene.source, scene.detector
    source = {"position": plain(np.asarray(src.position, np.float64)), "kind": src.kind}
    if src.spectrum is None:
        source["energy_keV"] = src.energy
    elif isinstance(src.spectrum, Mapping):
        source["spectrum"] = json.loads(json.dumps(plain(dict(src.spectrum)), default=str))
    else:
        source["spectrum"] = str(getattr(src.spectrum, "description", src.spectrum))
    if src.mas is not None:
        source["mas"] = src.mas
    pitch = [float(p) for p in det.pitch]
    detector = {"center": plain(np.asarray(det.center, np.float64)),
                "up": plain(np.asarray(det.up, np.float64)), "shape": [int(n) for n in det.shape],
                "pitch_mm": pitch, "response": det.response, "focal_spot_mm": det.focal_spot}
    meta["pitch_mm"] = pitch
    meta["geometry"] = {"source": source, "detector": detector,
                        "sid_mm": float(imaging.source_detector_distance(scene)),
                        "sod_mm": float(imaging.source_object_distance(scene)),
                        "magnification": float(imaging.magnification(scene))}
    try:
        meta["scene_toml"] = scene.to_toml()
    except SceneError:
        pass                      # bodies built in Python, a Spectrum object: no scene file
    return meta


def _json(meta: dict) -> str:
    """The metadata as 7-bit ASCII JSON (what TIFF's ImageDescription allows)."""
    return json.dumps(meta, ensure_ascii=True, allow_nan=False, sort_keys=True)


#: A PNG's window leaves out at most this fraction of the pixels, at the attenuating end.
OUTLIER_FRACTION = 0.005


def window_range(values, *, bright: str = "high") -> tuple[float, float]:
    """The values a PNG's 16 bits span: the range of ``values`` (finite), except that a few
    pixels far beyond the others at the attenuating end (a metal implant's) are left out.

    The attenuating end is the high one for ``bright="high"`` (line integrals, path lengths)
    and the low one for ``bright="low"`` (intensities). When the last
    :data:`OUTLIER_FRACTION` of the pixels at that end spans a wider range than all the others
    together, the window ends at the last value within a quarter of the others' range beyond
    that quantile ``q`` (``q + (q - lo) / 4``): the pixels beyond are drawn at the window's
    end, saturated, and the body's contrast keeps the whole window instead of a fraction. Otherwise (no such outliers, fewer than 1000 pixels) the whole range.

    Examples
    --------
    >>> body = np.linspace(0.0, 2.0, 10_000)               # line integrals through a limb
    >>> window_range(body)
    (0.0, 2.0)
    >>> implant = np.concatenate([body, np.full(20, 15.0)])   # 0.2 % of pixels through steel
    >>> lo, hi = window_range(implant)
    >>> lo, round(hi, 2)
    (0.0, 2.0)
    """
    f = np.asarray(values, dtype=np.float64).ravel()
    if f.size == 0:
        return 0.0, 0.0
    lo, hi = float(f.min()), float(f.max())
    if f.size >= 1000:
        if bright == "high":
            q = float(np.quantile(f, 1.0 - OUTLIER_FRACTION))
            if hi - q > q - lo:
                hi = float(f[f <= q + (q - lo) / 4].max())
        else:
            q = float(np.quantile(f, OUTLIER_FRACTION))
            if q - lo > hi - q:
                lo = float(f[f >= q - (hi - q) / 4].min())
    return lo, hi


#: Intensities whose window spans more than this factor are stored on a log scale in a PNG.
#: At this ratio ``r``, a linear window gives the darkest pixels a tenth of the contrast that a
#: logarithmic one gives them (``ln r / (r - 1) = 0.1``: a relative change ``dI / I`` moves a
#: pixel at ``I = lo`` by ``lo / (hi - lo)`` of the window linearly, ``1 / ln(hi / lo)`` on a
#: log scale). The bundled mesh phantoms but Shepp-Logan's stay below it; a chest CT at
#: 70 keV spans a factor ~2700.
LOG_WINDOW_RATIO = 37.0


def _png_window(finite, *, bright: str) -> tuple[float, float, bool]:
    """(low, high, logarithmic): the values a PNG stores as its ends, and its scale.

    Linear: :func:`window_range` of the values. Logarithmic, for intensities
    (``bright="low"``) whose positive values span more than :data:`LOG_WINDOW_RATIO` after
    :func:`window_range` of their line integral ``-ln I`` (the implant's pixels left out at
    the attenuating end as for a line-integral PNG): the smallest positive value kept and the
    largest value.
    """
    if bright == "low":
        positive = finite[finite > 0]
        if positive.size:
            depth = -np.log(positive)
            shallow, deep = window_range(depth, bright="high")
            if deep - shallow > np.log(LOG_WINDOW_RATIO):
                return float(positive[depth <= deep].min()), float(positive.max()), True
    lo, hi = window_range(finite, bright=bright)
    return lo, hi, False


def png_window(image, *, bright: str = "high") -> tuple[float, float, bool]:
    """``(low, high, logarithmic)``: the values that a PNG of ``image`` stores as its ends
    (:func:`to_uint16`), and whether its scale is logarithmic (intensities beyond
    :data:`LOG_WINDOW_RATIO`); the viewers' radiograph pane follows the same rule.

    Examples
    --------
    >>> png_window(np.array([[0.5, 1.0]]), bright="low")
    (0.5, 1.0, False)
    >>> png_window(np.array([[1e-3, 1.0]]), bright="low")
    (0.001, 1.0, True)
    """
    a = np.asarray(image, dtype=np.float64)
    return _png_window(a[np.isfinite(a)], bright=bright)


def _write_tiff(tmp, data, meta) -> None:
    import tifffile

    pitch = meta["pitch_mm"]
    options = {}
    if pitch is not None:      # pixels per centimetre: TIFF has no millimetre unit
        options.update(resolution=(10.0 / pitch[0], 10.0 / pitch[1]),
                       resolutionunit="CENTIMETER")
    with open(tmp, "wb") as fh:     # closed here also when a write fails (a full disk)
        tifffile.imwrite(fh, data, photometric="minisblack", description=_json(meta),
                         metadata=None, software=f"xray_viz {meta['xray_viz']}", **options)


def _read_tiff(path) -> tuple[np.ndarray, dict | None]:
    import tifffile

    with tifffile.TiffFile(path) as tif:
        page = tif.pages[0]
        data = page.asarray()
        text = page.description
        meta = _parse_json(text)
        if meta is None:                      # a TIFF from elsewhere: its resolution tags
            meta = {}
            unit = page.tags.get("ResolutionUnit")
            x, y = page.tags.get("XResolution"), page.tags.get("YResolution")
            per_mm = {2: 25.4, 3: 10.0}.get(int(unit.value) if unit else 2)
            if x is not None and y is not None and per_mm:
                rx, ry = (a / b for a, b in (x.value, y.value))
                if rx > 0 and ry > 0 and (x.value, y.value) != ((1, 1), (1, 1)):
                    meta["pitch_mm"] = [per_mm / rx, per_mm / ry]
    return data, meta


def _looks_ours(text) -> bool:
    """A text that was meant to be xray_viz's JSON metadata (it names xray_viz)."""
    if isinstance(text, bytes):
        text = text.decode("ascii", "replace")
    return bool(text) and str(text).lstrip().startswith("{") and "xray_viz" in str(text)


def _parse_json(text):
    """The xray_viz metadata in a description, or None."""
    if not text:
        return None
    try:
        meta = json.loads(text)
    except (ValueError, RecursionError):
        return None
    return meta if isinstance(meta, dict) and "xray_viz" in meta else None


def _check_tiff(tmp, data, meta) -> None:
    got, back = _read_tiff(tmp)
    if got.shape != data.shape or got.dtype != data.dtype:
        raise OutputError(f"it holds a {got.shape} {got.dtype} image, not {data.shape} "
                          f"{data.dtype}")
    if not np.array_equal(got, data, equal_nan=True):
        raise OutputError("its pixels differ from the image")
    if back != json.loads(_json(meta)):
        raise OutputError("its metadata differ from those written")


def _write_png(tmp, data, meta) -> None:
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    info.add_itxt("xray_viz", _json(meta), zip=True)
    info.add_text("Software", f"xray_viz {meta['xray_viz']}")
    options = {}
    if meta["pitch_mm"] is not None:   # pHYs: Pillow writes round(dpi / 0.0254) per metre
        options["dpi"] = tuple(1000.0 / p * 0.0254 for p in meta["pitch_mm"])
    Image.fromarray(data).save(tmp, format="PNG", pnginfo=info, **options)


def _check_png(tmp, data, meta) -> None:
    from PIL import Image

    _check_image_file(tmp, size=(data.shape[1], data.shape[0]), mode="I;16", values=data)
    with Image.open(tmp) as im:
        im.load()
        back = _parse_json(getattr(im, "text", {}).get("xray_viz"))
    if back != json.loads(_json(meta)):
        raise OutputError("its xray_viz text chunk differs from the one written")


def _detector_affine(scene, shape) -> np.ndarray:
    """The NIfTI affine of an (H, W) image stored as (W, H): voxel ``(i, j, 0)`` (column
    ``i``, row ``j``, row 0 at the top) to the pixel centre on the detector, mm.

    Columns: ``pitch_x * ho``, ``-pitch_y * ve`` (rows run down), the beam axis; a rotation
    (determinant +1). Without a scene: unit pitch, the detector in the plane z = 0 seen along
    -z, centred on the origin.
    """
    h, w = shape
    if scene is None:
        ho, ve, forward = np.eye(3)[0], np.eye(3)[1], -np.eye(3)[2]
        center, (px, py) = np.zeros(3), (1.0, 1.0)
    else:
        frame = scene.acquisition.frame
        ho, ve, forward, center = frame.ho, frame.ve, frame.forward, frame.center
        px, py = (float(p) for p in scene.detector.pitch)
    affine = np.eye(4)
    affine[:3, 0] = px * ho
    affine[:3, 1] = -py * ve
    affine[:3, 2] = forward
    affine[:3, 3] = center - (w - 1) / 2 * px * ho + (h - 1) / 2 * py * ve
    return affine


def _write_nifti(tmp, data, affine, meta) -> None:
    import nibabel as nib

    img = nib.Nifti1Image(np.ascontiguousarray(data.T), affine)
    img.header.set_xyzt_units("mm")
    img.header["descrip"] = f"xray_viz {meta['quantity'] or 'image'}"[:79].encode()
    img.header.extensions.append(nib.nifti1.Nifti1Extension("comment", _json(meta).encode()))
    nib.save(img, tmp)


def _read_nifti(path) -> tuple[np.ndarray, np.ndarray, dict | None]:
    from xray_viz._files import open_nifti

    with open_nifti(path) as img:                  # image.Nii as image.nii
        data = np.asarray(img.dataobj)
        affine = img.affine
        header = img.header
    if data.ndim == 3 and data.shape[2] == 1:
        data = data[:, :, 0]
    meta = None
    for ext in header.extensions:
        if ext.get_code() == 6:
            meta = _parse_json(ext.get_content().decode("ascii", "replace"))
            if meta is not None:
                break
    if meta is None:
        spacing = header.get_zooms()[:2]
        meta = {"pitch_mm": [float(s) for s in spacing]}
    return np.ascontiguousarray(data.T), affine, meta


def _check_nifti(tmp, data, affine, meta) -> None:
    got, got_affine, back = _read_nifti(tmp)
    if got.shape != data.shape or not np.array_equal(got, data, equal_nan=True):
        raise OutputError("its voxels differ from the image")
    if not np.allclose(got_affine, affine, rtol=1e-6, atol=1e-6):
        raise OutputError("its affine differs from the detector's")
    if back != json.loads(_json(meta)):
        raise OutputError("its metadata extension differs from the one written")


def _write_hdf5(tmp, data, meta) -> None:
    import h5py

    with h5py.File(tmp, "w") as f:
        entry = f.create_group("entry")
        entry.attrs["NX_class"] = "NXentry"
        inst = entry.create_group("instrument")
        inst.attrs["NX_class"] = "NXinstrument"
        det = inst.create_group("detector")
        det.attrs["NX_class"] = "NXdetector"
        dset = det.create_dataset("data", data=data)
        dset.attrs["units"] = meta["units"]
        dset.attrs["long_name"] = meta["quantity"] or "image"
        if meta["pitch_mm"] is not None:
            for name, value in zip(("x_pixel_size", "y_pixel_size"), meta["pitch_mm"]):
                det[name] = value
                det[name].attrs["units"] = "mm"
        nxdata = entry.create_group("data")
        nxdata.attrs["NX_class"] = "NXdata"
        nxdata.attrs["signal"] = "data"
        nxdata["data"] = dset
        entry["xray_viz_metadata"] = _json(meta)


def _refuse_hdf5_outside(path, f) -> None:
    """Raise :class:`OutputError` when the open HDF5 file ``f`` reaches into another file: an
    external link, a dataset with external raw storage or a virtual dataset (whose sources
    are other files), anywhere in it. Soft links stay inside the file and are not followed
    here (no cycles); hard links are walked once each.

    A crafted ``.h5`` would otherwise hand out another file's bytes as its image.
    """
    import h5py

    seen = set()

    def walk(group, where):
        for name in group:
            link = group.get(name, getlink=True)
            full = f"{where.rstrip('/')}/{name}"
            if isinstance(link, h5py.ExternalLink):
                what = "an external link"
            elif isinstance(link, h5py.SoftLink):
                continue
            else:
                obj = group.get(name)
                if obj is None or hash(obj.id) in seen:
                    continue
                seen.add(hash(obj.id))
                if isinstance(obj, h5py.Group):
                    walk(obj, full)
                    continue
                if not isinstance(obj, h5py.Dataset):
                    continue
                if obj.external:
                    what = "a dataset stored in another file (external raw storage)"
                elif obj.is_virtual:
                    what = "a virtual dataset (its data are in other files)"
                else:
                    continue
            raise OutputError(f"{path}: {full} is {what}: refused, an image is read from its "
                              "own file only (copy the data into the file, e.g. h5repack)")

    walk(f, "/")


def _read_hdf5(path) -> tuple[np.ndarray, dict | None]:
    import h5py

    with h5py.File(path, "r") as f:
        _refuse_hdf5_outside(path, f)
        if "entry/instrument/detector/data" in f:
            data = f["entry/instrument/detector/data"][()]
        else:                             # an HDF5 file from elsewhere: its one 2-D dataset
            found = []
            f.visititems(lambda name, obj: found.append(obj[()]) if isinstance(
                obj, h5py.Dataset) and obj.ndim == 2 else None)
            if len(found) != 1:
                raise OutputError(f"{path}: no /entry/instrument/detector/data and "
                                  f"{len(found)} 2-D datasets: not an xray_viz image")
            data = found[0]
        text = f["entry/xray_viz_metadata"][()] if "entry/xray_viz_metadata" in f else None
    if isinstance(text, bytes):
        text = text.decode("ascii", "replace")
    return data, _parse_json(text)


def _check_hdf5(tmp, data, meta) -> None:
    got, back = _read_hdf5(tmp)
    if got.shape != data.shape or not np.array_equal(got, data, equal_nan=True):
        raise OutputError("its values differ from the image")
    if back != json.loads(_json(meta)):
        raise OutputError("its metadata differ from those written")


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


def dicom_dataset(image, scene, *, bright="high", quantity=None, scatter=None):
    """A DICOM Digital X-Ray (for presentation) dataset of an image and its scene's geometry.

    Pixel data are 16-bit unsigned integers spanning the finite values of the image. The DX
    Image Module fixes ``RescaleSlope = 1``, ``RescaleIntercept = 0`` (``RescaleType = "US"``),
    so the physical values are carried by one item of the ``RealWorldValueMappingSequence``
    (0040,9096): ``value = stored * RealWorldValueSlope + RealWorldValueIntercept`` (double
    precision) for stored values 0..65535, with ``LUTLabel`` the quantity and
    ``MeasurementUnitsCodeSequence`` its UCUM unit (``"1"``, no units, for intensities in photons
    per pixel and line integrals; ``"mm"`` for path lengths). It recovers the values to within
    half a quantisation step, ``(max - min) / 65535 / 2`` (:func:`load_image`). Infinite values
    (a line integral through a body that stops every photon) are stored as the range's end,
    NaN as its low end; either is warned about (``RuntimeWarning``), as for a ``.png``.
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
    * With ``[detector] grid``: ``Grid = FOCUSED``, ``GridAbsorbingMaterial``,
      ``GridSpacingMaterial``, ``GridThickness`` (of the absorbing strips, mm), ``GridPitch``
      (mm), ``GridAspectRatio`` (the ratio as ``r x 1000 : 1000``) and ``GridFocalDistance``
      (mm).

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
    bad = int(a.size - np.count_nonzero(finite))
    if bad:                                   # as a PNG says it: the window's ends are not data
        warnings.warn(_nonfinite_message(bad, a.size, "DICOM: "), RuntimeWarning,
                      stacklevel=2)
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
    ds.PatientName = "Phantom^" + (scene.path.stem if scene.path else "scene")
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
    grid = scene.detector.grid
    if grid is not None:                  # the X-Ray Grid module's attributes (DICOM PS3.3)
        ds.Grid = ["FOCUSED"]
        ds.GridAbsorbingMaterial = grid.strip_material
        ds.GridSpacingMaterial = grid.interspace_material
        ds.GridThickness = _ds(grid.strip_thickness)              # the lead's, mm
        ds.GridPitch = _ds(grid.period)                           # mm
        ds.GridAspectRatio = [str(int(round(grid.ratio * 1000))), "1000"]
        ds.GridFocalDistance = _ds(grid.focus_distance)
    exposure = ""
    if scene.source.mas is not None:
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
    from xray_viz.physics.dosimetry import scatter_scope

    scope = scatter_scope(None)
    if scatter is not None:
        info = _scatter_meta(scatter)
        runs = "".join(f", {k.replace('_mm', '')} {info[k]}{' mm' * k.endswith('_mm')}"
                       for k in ("histories", "seed", "smoothing_mm") if k in info)
        scope = f"scatter {info['mode']}{runs}: {info['scope']}"
    ds.ImageComments = (f"{quantity or 'image'}; beam: {spectrum.description}; "
                        f"detector response: {scene.detector.response}; SID {sid:g} mm, "
                        f"SOD {sod:g} mm{exposure}; {scope}")[:10240]
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


@dataclass(frozen=True)
class ImageMetadata:
    """What an image file says about its pixels (:func:`load_image` with
    ``with_metadata=True``); ``None`` where the file does not say.

    Attributes
    ----------
    format : str
        The file's format (:func:`format_of`).
    quantity : str or None
        ``"intensity"``, ``"line-integral"``, ``"path-length"``.
    units : str or None
        UCUM units of the values (``"1"``, ``"mm"``).
    pitch : (float, float) or None
        mm between pixel centres along the rows and along the columns (``[detector] pitch``
        order: column spacing, then row spacing).
    geometry : dict or None
        The scene's geometry (:func:`image_metadata`); for DICOM the distances, magnification
        and kVp of its header.
    scene_toml : str or None
        The scene file the image was rendered from (:meth:`scene` loads it).
    window : dict or None
        A PNG's window: ``low``/``high`` (the values stored as 0 and 65535 with
        ``bright="high"``, swapped with ``"low"``), ``bright``, ``step`` (the quantisation step;
        of ``ln`` of the values when ``scale`` is ``"log"``), ``scale`` (``"log"``: intensities
        stored on a logarithmic scale, see :func:`to_uint16`; absent: linear), ``clipped``.
    version : str or None
        The xray_viz version that wrote the file.
    scatter : dict or None
        The scatter the image includes (``mode``, ``histories``, ``seed``, ``scope``: see
        :func:`image_metadata`); None for the primary alone or a file that does not say.
    """

    format: str
    quantity: str | None = None
    units: str | None = None
    pitch: tuple[float, float] | None = None
    geometry: dict | None = None
    scene_toml: str | None = None
    window: dict | None = None
    version: str | None = None
    scatter: dict | None = None

    def scene(self):
        """The scene of the embedded scene file (:func:`~xray_viz.scene_file.scene_from_dict`).

        Mesh paths in it are absolute: it loads where those files are.

        Raises
        ------
        OutputError
            The file holds no scene.
        """
        if self.scene_toml is None:
            raise OutputError(f"this {self.format} file holds no scene: save it with "
                              "save_image(..., scene=scene)")
        import tomllib

        from xray_viz.scene_file import scene_from_dict

        try:
            doc = tomllib.loads(self.scene_toml)
        except (tomllib.TOMLDecodeError, RecursionError) as exc:
            why = "nested too deeply (arrays or tables thousands of levels inside each other)" if isinstance(exc, RecursionError) else "not TOML"
            raise OutputError(f"this {self.format} file's embedded scene is {why}") from None
        return scene_from_dict(doc)

    def to_physical(self, image) -> np.ndarray:
        """The quantity a loaded image stands for: a PNG's 16-bit values mapped back through
        its window (within half a quantisation step, ``window["step"] / 2``, of the values
        saved; a saved ``+inf`` comes back as the window's top, ``-inf`` and NaN as its
        bottom; on a log scale, within a factor ``exp(step / 2)``, the zero and negative
        intensities come back as the window's bottom); other formats' values unchanged (as
        float64).

        Examples
        --------
        >>> meta = ImageMetadata(".png", window={"low": 1.0, "high": 3.0, "bright": "high"})
        >>> meta.to_physical(np.array([0, 65535], np.uint16)).tolist()
        [1.0, 3.0]
        """
        a = np.asarray(image, dtype=np.float64)
        if self.window is None:
            return a
        lo, hi = float(self.window["low"]), float(self.window["high"])
        scaled = a / 65535.0
        if self.window.get("bright") == "low":
            scaled = 1.0 - scaled
        if self.window.get("scale") == "log":
            return np.exp(np.log(lo) + scaled * (np.log(hi) - np.log(lo)))
        return lo + scaled * (hi - lo)


def _metadata(fmt: str, meta: dict | None) -> ImageMetadata:
    meta = meta or {}
    pitch = meta.get("pitch_mm")
    return ImageMetadata(format=fmt, quantity=meta.get("quantity"), units=meta.get("units"),
                         pitch=None if pitch is None else (float(pitch[0]), float(pitch[1])),
                         geometry=meta.get("geometry"), scene_toml=meta.get("scene_toml"),
                         window=meta.get("window"), version=meta.get("xray_viz"),
                         scatter=meta.get("scatter"))


def _dicom_metadata(ds) -> ImageMetadata:
    rwv = ds.get("RealWorldValueMappingSequence")
    quantity = str(rwv[0].LUTLabel) if rwv and "LUTLabel" in rwv[0] else None
    if quantity == "value":
        quantity = None
    units = None
    if rwv and rwv[0].get("MeasurementUnitsCodeSequence"):
        units = str(rwv[0].MeasurementUnitsCodeSequence[0].CodeValue)
    spacing = ds.get("ImagerPixelSpacing")
    pitch = None if spacing is None else (float(spacing[1]), float(spacing[0]))
    geometry = {}
    for key, name in (("sid_mm", "DistanceSourceToDetector"),
                      ("sod_mm", "DistanceSourceToPatient"),
                      ("magnification", "EstimatedRadiographicMagnificationFactor"),
                      ("kvp", "KVP")):
        if name in ds:
            geometry[key] = float(ds.get(name))
    return ImageMetadata(format=".dcm", quantity=quantity, units=units, pitch=pitch,
                         geometry=geometry or None)


def load_image(path, *, with_metadata=False):
    """Read an image written by :func:`save_image` (or a file of the same format from
    elsewhere), skimage-style: ``load_image(path)`` is the array, ``load_image(path,
    with_metadata=True)`` the pair ``(array, ImageMetadata)``.

    The array is what the file holds: ``.npy`` the saved array, ``.tiff`` its float32 values,
    NIfTI and HDF5 their float64 values (NIfTI's ``(W, H)`` voxels transposed back to
    ``(H, W)``), ``.dcm`` the float64 values of its Real World Value Mapping
    (:func:`dicom_values`), ``.png`` its 16-bit stored values (the picture):
    :meth:`ImageMetadata.to_physical` maps them back to the quantity through the window
    the file records.

    Parameters
    ----------
    path : path-like
    with_metadata : bool
        Also return what the file records (:class:`ImageMetadata`): quantity, pitch, geometry,
        the scene file. A ``.npy`` file records nothing (only ``format`` is set).

    Returns
    -------
    image : ndarray
    metadata : ImageMetadata
        Only with ``with_metadata=True``.

    Raises
    ------
    OutputError
        An unknown format, one whose library is not installed, a missing file or one that
        is not an image of its format (one line naming the file).

    Examples
    --------
    >>> import numpy as np, tempfile, pathlib, xray_viz
    >>> out = pathlib.Path(tempfile.mkdtemp()) / "li.png"
    >>> image = np.array([[0.0, 0.5], [1.0, 2.0]])
    >>> _ = save_image(out, image, scene=xray_viz.load_scene("sphere"), quantity="line-integral")
    >>> stored, meta = load_image(out, with_metadata=True)
    >>> stored.dtype.name, meta.quantity, meta.window["step"] == 2.0 / 65535
    ('uint16', 'line-integral', True)
    >>> bool(np.abs(meta.to_physical(stored) - image).max() <= meta.window["step"] / 2)
    True
    """
    from xray_viz._files import require_regular

    path = Path(path)
    suffix = check_format(path)
    require_regular(path, OutputError, "image file")
    try:
        image, meta = _read_image(path, suffix)
    except OutputError:
        raise
    except FileNotFoundError:
        raise OutputError(f"{path}: no such file") from None
    except Exception as exc:      # each format's library has its own errors for a bad file
        text = reader_reason(str(exc).strip().splitlines()[0]) if str(exc).strip() else ""
        raise OutputError(f"{path}: cannot read it as a {suffix} image ({type(exc).__name__}"
                          f"{': ' + text if text else ''})") from None
    return (image, meta) if with_metadata else image


def _read_image(path: Path, suffix: str):
    """``(image, ImageMetadata)`` of one file (:func:`load_image`)."""
    fmt = FORMATS[suffix]
    if fmt.library:
        _need(path, *fmt.library)
    if fmt.name == "npy":
        image, meta = np.load(path), ImageMetadata(".npy")
    elif fmt.name == "dicom":
        import pydicom

        ds = pydicom.dcmread(path)
        image, meta = dicom_values(ds), _dicom_metadata(ds)
    elif fmt.name == "tiff":
        image, raw = _read_tiff(path)
        _check_seal(path, suffix, image, raw,
                    "xray_viz" not in (raw or {}) and _text_of(path, suffix))
        meta = _metadata(suffix, raw)
    elif fmt.name == "png":
        from PIL import Image

        with Image.open(path) as im:
            image = np.asarray(im)
            raw = _parse_json(getattr(im, "text", {}).get("xray_viz"))
            dpi = im.info.get("dpi")
            _check_seal(path, suffix, image, raw, "xray_viz" in getattr(im, "text", {}))
        if raw is None and dpi and all(d > 0 for d in dpi):
            raw = {"pitch_mm": [25.4 / d for d in dpi]}
        meta = _metadata(suffix, raw)
    elif fmt.name == "nifti":
        image, _, raw = _read_nifti(path)
        _check_seal(path, suffix, image, raw, "xray_viz" not in raw and _text_of(path, suffix))
        meta = _metadata(suffix, raw)
    else:                                    # hdf5
        image, raw = _read_hdf5(path)
        _check_seal(path, suffix, image, raw, raw is None and _text_of(path, suffix))
        meta = _metadata(suffix, raw)
    return image, meta


def _text_of(path, suffix) -> bool:
    """Whether the file holds a text meant as xray_viz's metadata (for :func:`_check_seal`,
    when it did not parse): read again only on that path."""
    name = FORMATS[suffix].name
    try:
        if name == "tiff":
            import tifffile

            with tifffile.TiffFile(path) as tif:           # written by xray_viz
                page = tif.pages[0]
                software = page.tags.get("Software")
                return _looks_ours(page.description) or bool(
                    software and str(software.value).startswith("xray_viz"))
        if name == "png":
            from PIL import Image

            with Image.open(path) as im:
                return "xray_viz" in getattr(im, "text", {})
        if name == "nifti":
            import nibabel as nib

            header = nib.load(path).header
            return bytes(header["descrip"]).startswith(b"xray_viz") or any(
                ext.get_code() == 6 and _looks_ours(ext.get_content())
                for ext in header.extensions)
        import h5py

        with h5py.File(path, "r") as f:
            return "entry/xray_viz_metadata" in f
    except Exception:
        return True                         # it was readable a moment ago: damaged

"""Reading files whatever the case of their suffix (``scan.NII.GZ``, ``labels.MHA``).

xray_viz matches suffixes in lower case everywhere (:func:`xray_viz.output.format_of`,
``VOLUME_SUFFIXES``, ``MESH_SUFFIXES``); some libraries do not: nibabel finds neither the
type of ``image.Nii`` nor the compression of ``image.nii.GZ``, SimpleITK no reader for
``labels.MHA``. These helpers read such files with the reader their lower-case suffix names,
so that whatever xray_viz writes or accepts, it reads back.
"""

from __future__ import annotations

import contextlib
import gzip
from pathlib import Path

__all__ = ["open_nifti", "itk_read", "ITK_IMAGE_IO", "require_regular"]

#: SimpleITK's ImageIO for each suffix it is given (lower case).
ITK_IMAGE_IO = {".mha": "MetaImageIO", ".mhd": "MetaImageIO", ".nrrd": "NrrdImageIO",
                ".nhdr": "NrrdImageIO"}


@contextlib.contextmanager
def open_nifti(path):
    """A NIfTI-1 or NIfTI-2 image of ``path`` (``.nii`` or gzipped ``.nii.gz``, any case),
    nibabel's, readable inside the ``with`` block.

    Examples
    --------
    >>> import tempfile, pathlib, numpy as np, nibabel as nib
    >>> d = pathlib.Path(tempfile.mkdtemp())
    >>> nib.save(nib.Nifti1Image(np.ones((2, 3, 4), np.int16), np.eye(4)), d / "a.nii.gz")
    >>> _ = (d / "a.nii.gz").rename(d / "A.NII.GZ")
    >>> with open_nifti(d / "A.NII.GZ") as img:
    ...     int(np.asarray(img.dataobj).sum())
    24
    """
    import nibabel as nib

    path = Path(path)
    gz = path.name.lower().endswith(".gz")
    with (gzip.open(path, "rb") if gz else open(path, "rb")) as fh:
        head = fh.read(4)
        fh.seek(0)
        size = {348: nib.Nifti1Image, 540: nib.Nifti2Image}
        kind = size.get(int.from_bytes(head, "little")) or size.get(int.from_bytes(head, "big"))
        if kind is None:
            raise ValueError("not a NIfTI-1 or NIfTI-2 header")
        holder = nib.FileHolder(fileobj=fh)
        yield kind.from_file_map({"image": holder, "header": holder})


def itk_read(path):
    """SimpleITK's image of ``path`` (``.mha``, ``.mhd``, ``.nrrd``, ``.nhdr``, any case)."""
    import SimpleITK as sitk

    io = ITK_IMAGE_IO.get(Path(path).suffix.lower(), "")
    return sitk.ReadImage(str(path), imageIO=io)


def require_regular(path, error, what: str = "file") -> None:
    """Raise ``error`` (one line) when ``path`` exists but is not a regular file or a folder:
    a named pipe (FIFO) would block the reader for ever, a device read without end, a socket
    fail obscurely. A missing path or a folder is left to the caller's own message.

    Examples
    --------
    >>> import os, tempfile, pathlib
    >>> fifo = pathlib.Path(tempfile.mkdtemp()) / "pipe.stl"
    >>> os.mkfifo(fifo)
    >>> require_regular(fifo, ValueError, "mesh file")
    Traceback (most recent call last):
    ...
    ValueError: .../pipe.stl: is not a regular file (a named pipe, device or socket); give the mesh file itself
    """
    import os
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError:
        return
    if not (stat.S_ISREG(mode) or stat.S_ISDIR(mode)):
        raise error(f"{path}: is not a regular file (a named pipe, device or socket); give the "
                    f"{what} itself")

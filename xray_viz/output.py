"""Writing images: ``.npy`` (float64 as computed), ``.tiff`` (float32), ``.png`` (16-bit).

Files are written to a temporary name beside the target and renamed into place, so a failed
write never leaves a half-written file.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from xray_viz.errors import OutputError

__all__ = ["save_image", "load_image", "to_uint16", "FORMATS"]

#: Output suffixes and what they hold.
FORMATS = {
    ".npy": "the float64 array exactly as the API returns it",
    ".tiff": "float32 TIFF",
    ".tif": "float32 TIFF",
    ".png": "16-bit grey PNG, attenuation bright, windowed to the data",
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


def save_image(path, image, *, bright="high") -> Path:
    """Save an (H, W) image; the format follows the suffix (see :data:`FORMATS`).

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
    return path


def load_image(path) -> np.ndarray:
    """Read back an image written by :func:`save_image` (``.npy``, ``.tiff``, ``.png``)."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return np.load(path)
    from PIL import Image

    with Image.open(path) as im:
        return np.asarray(im)

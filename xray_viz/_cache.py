"""The one disk cache of xray_viz's data, and its one rule for where it is and when it is off.

Mesh reports and inside tests (:mod:`xray_viz.meshes._report_cache`), decimations
(:mod:`xray_viz.lod`) and meshed volumes (:mod:`xray_viz.meshes.volumes`) are kept on disk by
content hash, each kind in its own folder of one root, by :func:`cache_dir`:

1. ``XRAY_VIZ_CACHE_DIR`` set to ``off`` (or ``0``, ``no``, ``false``, ``none``, or empty, in
   any case): caching is off, silently (a choice; the test suite makes it);
2. ``XRAY_VIZ_CACHE_DIR`` set to a folder: the root is that folder;
3. unset: the user's cache folder, ``platformdirs.user_cache_dir("xray_viz")``
   (``$XDG_CACHE_HOME/xray_viz`` or ``~/.cache/xray_viz`` on Linux).

A kind's folder that cannot be made or written is off, with one :class:`CacheWarning` per
folder and process (one line, saying what is not cached and how to choose another place;
:class:`xray_viz.errors.CacheWarning`).
Caching never changes a result: off, every load computes again. Deleting the cache is always
safe.

The compiled kernels are cached apart, by numba's own rule (``NUMBA_CACHE_DIR``, the package's
``__pycache__``, numba's user-wide folder, a private temporary folder;
:mod:`xray_viz.tracing._numba_cache`): machine code has its own safety rules (a private folder,
checked files), and numba users already set ``NUMBA_CACHE_DIR``.
"""

from __future__ import annotations

import os
import tempfile
import threading
import warnings
from pathlib import Path

from xray_viz.errors import CacheWarning

__all__ = ["CacheWarning", "cache_dir", "root"]

#: The environment variable choosing the root (or ``off``).
ENV = "XRAY_VIZ_CACHE_DIR"
#: Values of :data:`ENV` that turn caching off (compared lower-case, stripped).
OFF = ("", "0", "off", "no", "false", "none")


_lock = threading.Lock()
_usable: set = set()      # folders found writable (each is checked once per process)
_warned: set = set()


def root() -> Path | None:
    """The cache's root folder by the rule of the module docstring, or None when it is off.

    Examples
    --------
    >>> import os
    >>> old = os.environ.get("XRAY_VIZ_CACHE_DIR")
    >>> os.environ["XRAY_VIZ_CACHE_DIR"] = "Off"
    >>> root() is None
    True
    >>> os.environ["XRAY_VIZ_CACHE_DIR"] = "/somewhere/else"
    >>> str(root())
    '/somewhere/else'
    >>> if old is None: del os.environ["XRAY_VIZ_CACHE_DIR"]
    ... else: os.environ["XRAY_VIZ_CACHE_DIR"] = old
    """
    env = os.environ.get(ENV)
    if env is not None:
        return None if env.strip().lower() in OFF else Path(env)
    import platformdirs

    return Path(platformdirs.user_cache_dir("xray_viz", appauthor=False))


def _writable(folder: Path) -> str | None:
    """None if ``folder`` exists or can be made and a file can be written in it, else why
    not (one line)."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=folder):
            pass
    except OSError as exc:
        return exc.strerror or type(exc).__name__
    return None


def cache_dir(kind: str, *, what: str) -> Path | None:
    """The folder of one kind of cached data, ``root() / kind`` (made if missing), or None
    when caching is off or that folder cannot be written (then one :class:`CacheWarning`
    naming ``what`` is not cached).

    Parameters
    ----------
    kind : str
        The folder's name under the root (``"mesh-reports"``, ``"lod"``, ``"volumes"``...).
    what : str
        What is kept there, for the warning (``"mesh reports"``).

    Examples
    --------
    >>> import os, tempfile
    >>> old = os.environ.get("XRAY_VIZ_CACHE_DIR")
    >>> os.environ["XRAY_VIZ_CACHE_DIR"] = d = tempfile.mkdtemp()
    >>> cache_dir("lod", what="decimations") == Path(d) / "lod"
    True
    >>> os.environ["XRAY_VIZ_CACHE_DIR"] = "off"
    >>> cache_dir("lod", what="decimations") is None
    True
    >>> if old is None: del os.environ["XRAY_VIZ_CACHE_DIR"]
    ... else: os.environ["XRAY_VIZ_CACHE_DIR"] = old
    """
    base = root()
    if base is None:
        return None
    folder = base / kind
    key = str(folder)
    if key in _usable:
        return folder
    why = _writable(folder)
    if why is None:
        with _lock:
            _usable.add(key)
        return folder
    with _lock:
        if key in _warned:
            return None
        _warned.add(key)
    warnings.warn(f"cache folder {folder} cannot be written ({why}): {what} are not cached; "
                  f"set {ENV} to a writable folder (or to off)", CacheWarning, stacklevel=3)
    return None

"""Mesh reports kept on disk by content hash, so that loading the same mesh again is free;
likewise whether one mesh lies inside another (:func:`pair_key`, the precedence rule's test).

:func:`xray_viz.meshes.repair.check_mesh` of a big mesh is the slowest part of loading a scene
(the self-intersection test of a 1.3M-face sphere alone takes seconds). Its report depends only
on the vertex and face arrays and on the checking code, so it is stored under the SHA-256 of
``(the arrays' bytes, shapes, dtypes, and the source of xray_viz/meshes/repair.py and of its
compiled kernels, _check_kernels.py)``: a changed mesh or a changed checker never reads an
old report.

Where: ``$XRAY_VIZ_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/xray_viz`` or
``~/.cache/xray_viz``, in ``mesh-reports/`` (and ``mesh-pairs/`` for the inside tests). ``XRAY_VIZ_CACHE_DIR=off`` (or a place that cannot
be written) turns it off: reports are then computed every time, nothing else changes. Files
are written to a temporary name and renamed, and a file that does not parse is ignored (and
replaced), so a killed process or a corrupt file never gives a wrong report.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import tempfile
from functools import lru_cache
from pathlib import Path

import numpy as np

#: Bumped when the stored format changes.
FORMAT = 1


def cache_dir() -> Path | None:
    """The folder of the stored reports, or None when caching is off."""
    env = os.environ.get("XRAY_VIZ_CACHE_DIR")
    if env is not None and env.strip().lower() in ("", "0", "off", "no", "false", "none"):
        return None
    if env:
        base = Path(env)
    else:
        xdg = os.environ.get("XDG_CACHE_HOME")
        base = Path(xdg) / "xray_viz" if xdg else Path.home() / ".cache" / "xray_viz"
    return base / "mesh-reports"


@lru_cache(maxsize=1)
def _checker_digest() -> bytes:
    """SHA-256 of the checking code: a change of it invalidates every stored report."""
    h = hashlib.sha256()
    for name in ("repair.py", "_check_kernels.py"):
        h.update(Path(__file__).with_name(name).read_bytes())
    return h.digest()


def mesh_key(vertices, faces) -> str:
    """Hex SHA-256 of a mesh's arrays and of the checking code."""
    h = hashlib.sha256()
    h.update(f"xray_viz mesh report {FORMAT}".encode())
    h.update(_checker_digest())
    for a in (vertices, faces):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(memoryview(a).cast("B"))
    return h.hexdigest()


@lru_cache(maxsize=1)
def _inside_digest() -> bytes:
    """SHA-256 of the code deciding that one mesh lies inside another (``repair.containers``
    and the winding numbers of ``tracing/hits.py``), besides the checking code."""
    h = hashlib.sha256(_checker_digest())
    h.update((Path(__file__).parents[1] / "tracing" / "hits.py").read_bytes())
    return h.digest()


def pair_key(inner: str, outer: str) -> str:
    """Hex SHA-256 naming whether the mesh of :func:`mesh_key` ``inner`` lies wholly inside
    the mesh of ``outer`` (see :func:`load_flag`)."""
    h = hashlib.sha256(f"xray_viz inside {FORMAT}".encode())
    h.update(_inside_digest())
    h.update(f"{inner} in {outer}".encode())
    return h.hexdigest()


def _pairs_dir() -> Path | None:
    folder = cache_dir()
    return None if folder is None else folder.parent / "mesh-pairs"


def load_flag(key: str):
    """The stored answer (True or False) of :func:`pair_key` ``key``, or None (kept in
    ``mesh-pairs/`` beside ``mesh-reports/``)."""
    folder = _pairs_dir()
    if folder is None:
        return None
    try:
        data = json.loads((folder / f"{key}.json").read_text(encoding="utf-8"))
        value = data["inside"] if data.get("format") == FORMAT else None
        return value if isinstance(value, bool) else None
    except (OSError, ValueError, KeyError, TypeError):
        return None


def store_flag(key: str, value: bool) -> None:
    """Keep the answer of :func:`pair_key` ``key`` (silently nothing where it cannot)."""
    folder = _pairs_dir()
    if folder is None:
        return
    text = json.dumps({"format": FORMAT, "inside": bool(value)})
    write_atomically(folder, f"{key}.json", lambda fh: fh.write(text.encode("utf-8")))


def load(key: str, report_type):
    """The stored report of ``key`` (a ``report_type``), or None."""
    folder = cache_dir()
    if folder is None:
        return None
    try:
        data = json.loads((folder / f"{key}.json").read_text(encoding="utf-8"))
        if data.get("format") != FORMAT:
            return None
        fields = {f.name for f in dataclasses.fields(report_type)}
        values = data["report"]
        if set(values) != fields:
            return None
        return report_type(**{k: tuple(v) if isinstance(v, list) else v
                              for k, v in values.items()})
    except (OSError, ValueError, KeyError, TypeError):
        return None


def write_atomically(folder: Path, name: str, write) -> None:
    """Write the cache file ``folder / name`` through ``write(binary file)``: to a temporary
    name, then renamed, so a reader never sees half a file; an unwritable folder is silently
    nothing (a cache). Also :mod:`xray_viz.lod`'s decimations."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(dir=folder, prefix=f".{name[:16]}-", suffix=".tmp")
        try:
            with os.fdopen(fd, "wb") as fh:
                write(fh)
            os.replace(tmp, folder / name)
        except BaseException:
            try:
                os.unlink(tmp)
            except OSError:
                pass
            raise
    except OSError:
        return


def store(key: str, report) -> None:
    """Keep ``report`` for ``key`` (silently nothing where the folder cannot be written)."""
    folder = cache_dir()
    if folder is None:
        return
    text = json.dumps({"format": FORMAT, "report": dataclasses.asdict(report)})
    write_atomically(folder, f"{key}.json", lambda fh: fh.write(text.encode("utf-8")))

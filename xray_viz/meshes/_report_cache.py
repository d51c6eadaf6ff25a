"""Mesh reports kept on disk by content hash, so that loading the same mesh again is free;
likewise whether one mesh lies inside another (:func:`pair_key`, the precedence rule's test).

:func:`xray_viz.meshes.repair.check_mesh` of a big mesh is the slowest part of loading a scene
(the self-intersection test of a 1.3M-face sphere alone takes seconds). Its report depends only
on the vertex and face arrays and on the checking code, so it is stored under the SHA-256 of
``(the arrays' bytes, shapes, dtypes, and the source of xray_viz/meshes/repair.py and of its
compiled kernels, _check_kernels.py)``: a changed mesh or a changed checker never reads an
old report.

Where: ``mesh-reports/`` (and ``mesh-pairs/`` for the inside tests) in the one cache of
:mod:`xray_viz._cache` (``$XRAY_VIZ_CACHE_DIR``, else the user's cache folder;
``XRAY_VIZ_CACHE_DIR=off`` turns it off, a folder that cannot be written is off with one
warning): reports are then computed every time, nothing else changes. Files
are written to a temporary name and renamed, and a file that does not parse is ignored (and
replaced), so a killed process or a corrupt file never gives a wrong report.

The bundled phantoms' reports and inside tests are also shipped with the package
(``phantoms/mesh-reports.json``, :func:`shipped`, :func:`shipped_pairs`), under the same keys,
so that the first load and render of a bundled phantom check nothing (the frog's checks and
inside tests, through pymeshlab, were ~2.5 s of a cold ``xray-viz render default``). They are read
whether or not the cache is on (they are part of the install, not a cache), and only under the
key of the running checker: a changed checker or mesh finds no shipped report and checks as
before, never a stale one (``tests/meshes/test_report_cache.py`` fails when the shipped file lacks a
current key; ``python phantoms/mesh_reports.py`` writes it anew).
``XRAY_VIZ_SHIPPED_REPORTS=off`` ignores them (the test suite sets it: a test that changes the
checker's behaviour must see it run).
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

from xray_viz import _cache

#: Bumped when the stored format changes.
FORMAT = 1


def cache_dir() -> Path | None:
    """The folder of the stored reports, or None when caching is off
    (:func:`xray_viz._cache.cache_dir`: the one rule)."""
    return _cache.cache_dir("mesh-reports", what="mesh reports")


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
    return _cache.cache_dir("mesh-pairs", what="inside tests of meshes")


def load_flag(key: str):
    """The stored answer (True or False) of :func:`pair_key` ``key``, or None (kept in
    ``mesh-pairs/`` beside ``mesh-reports/``; else the answers shipped with the package,
    :func:`shipped_pairs`)."""
    folder = _pairs_dir()
    if folder is not None:
        try:
            data = json.loads((folder / f"{key}.json").read_text(encoding="utf-8"))
            value = data["inside"] if data.get("format") == FORMAT else None
            if isinstance(value, bool):
                return value
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            pass
    value = shipped_pairs().get(key)
    return value if isinstance(value, bool) else None


def store_flag(key: str, value: bool) -> None:
    """Keep the answer of :func:`pair_key` ``key`` (silently nothing where it cannot)."""
    folder = _pairs_dir()
    if folder is None:
        return
    text = json.dumps({"format": FORMAT, "inside": bool(value)})
    write_atomically(folder, f"{key}.json", lambda fh: fh.write(text.encode("utf-8")))


#: The bundled phantoms' reports shipped with the package (:func:`shipped`).
SHIPPED = Path(__file__).parents[1] / "_phantoms" / "mesh-reports.json"
#: Its place in a source tree (``phantoms/`` is installed as ``xray_viz._phantoms``).
_SHIPPED_SOURCE = Path(__file__).parents[2] / "phantoms" / "mesh-reports.json"


@lru_cache(maxsize=1)
def _shipped_file() -> dict:
    for path in (SHIPPED, _SHIPPED_SOURCE):
        try:
            data = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            continue
        if isinstance(data, dict) and data.get("format") == FORMAT:
            return {k: data[k] if isinstance(data.get(k), dict) else {}
                    for k in ("reports", "pairs")}
    return {"reports": {}, "pairs": {}}


def _shipped_on() -> bool:
    return os.environ.get("XRAY_VIZ_SHIPPED_REPORTS", "").strip().lower() not in (
        "off", "0", "no", "false")


def shipped() -> dict:
    """The reports shipped with the package: key (:func:`mesh_key`) -> report fields; empty
    when ``XRAY_VIZ_SHIPPED_REPORTS`` is ``off`` (or ``0``, ``no``, ``false``)."""
    return _shipped_file()["reports"] if _shipped_on() else {}


def shipped_pairs() -> dict:
    """The inside tests of the bundled phantoms shipped with the package: key
    (:func:`pair_key`) -> whether the one mesh lies inside the other; empty as :func:`shipped`
    is."""
    return _shipped_file()["pairs"] if _shipped_on() else {}


def _report(values, report_type):
    fields = {f.name for f in dataclasses.fields(report_type)}
    if set(values) != fields:
        return None
    return report_type(**{k: tuple(v) if isinstance(v, list) else v for k, v in values.items()})


def load(key: str, report_type):
    """The stored report of ``key`` (a ``report_type``), or None: from the cache, else from
    the reports shipped with the package (:func:`shipped`)."""
    folder = cache_dir()
    if folder is not None:
        try:
            data = json.loads((folder / f"{key}.json").read_text(encoding="utf-8"))
            if data.get("format") == FORMAT:
                report = _report(data["report"], report_type)
                if report is not None:
                    return report
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            pass
    values = shipped().get(key)
    if values is None:
        return None
    try:
        return _report(values, report_type)
    except (ValueError, KeyError, TypeError, AttributeError):
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


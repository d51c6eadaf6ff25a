"""Error-budgeted level of detail: ``render(scene, max_error=...)``.

Each body is traced with the coarsest quadric decimation of its mesh
(:func:`xray_viz.meshes.decimate.decimate`) whose estimated error stays within its share of the
budget.

What the budget is
------------------
``max_error`` bounds, for **every pixel**, the absolute change of the line integral
``-ln(I / I0)`` (dimensionless) that the decimation causes, against the same render of the
full-resolution meshes (same rays, same supersampling, same detector model): to first order the
relative change of the intensity, ``|dI| / I <= exp(max_error) - 1``. It is the error of the
tessellation only: the pixel-scale (sampling) error of the full-resolution render - the
difference between a pixel and the exact average over its area - is not part of it, and the
supersampling is left as the caller set it (the Pareto benchmark, BENCHMARKS.md, says which
supersampling a given accuracy against the exact object needs). A noisy detector's budget holds
for the expected (noise-free) image.

How it is estimated
-------------------
A pixel's line integral is ``-ln`` of the mean of ``exp(-sum_b mu_b L_b)`` over its rays (and,
for a spectrum, over energies), so a pixel changes by at most the largest change of a ray's
``sum_b mu_b L_b``. Decimating body ``b`` moves its surface, changing the material along a ray
over the length where the two surfaces disagree; that changes the line integral by at most
``contrast_b x dL_b``, with ``contrast_b`` the largest ``|mu_b - mu_c|`` or ``mu_b`` between
``b`` and any body ``c`` whose bounding box meets ``b``'s (at the energy of the spectrum where
it is largest) and ``dL_b`` the largest change of the body's own path length along a line.

``dL_b`` is **measured**, not assumed from the Hausdorff distance: both meshes are traced alone
by the fast engine with parallel beams from :data:`DIRECTIONS` directions over the body, rays
:func:`measuring_pitch` apart (the ray spacing the scene traces the body at, or finer), and the
largest difference is kept. The largest change is at silhouettes, where it grows like the square
root of the surface's displacement (``2 sqrt(2 R h)`` for a sphere of radius ``R`` whose surface
moves by ``h``), not like ``2 h``; a Hausdorff bound per crossing (``2 h / cos``) would miss it
there. The estimate is ``SAFETY x contrast_b x dL_b``; :data:`SAFETY` covers rays of the scene
that meet a silhouette closer than the measuring lines did. It is validated, not proven: the
tests render every bundled phantom at full and reduced detail and check the measured error
against the budget.
A level is refused as soon as the views measured so far refuse it (a maximum over fewer
lines is a lower bound of the maximum over all of them); the rest of its views are measured
only if the choice later needs its complete value (the leftover pass below), so the choice is
the one the complete measurements would make.

Bodies whose footprints overlap share the budget. The footprints are traced: the
full-resolution bodies are rendered by the fast engine at the scene's own acquisition on a coarse
grid (:data:`COARSE` pixels across at most), a body's footprint is where its path length is > 0,
dilated by one coarse pixel for the rays between the coarse ones (a body whose projected box is
narrower than :data:`THIN` coarse pixels takes its box: it could lie between them). A body gets
``max_error / k`` where ``k`` is the most footprints meeting on any coarse pixel of its own, so
the shares of the bodies on any ray add up to at most ``max_error``. (Bounding boxes, the first
version, overcounted: a box covers pixels its body does not; for the frog's 16 bodies ``k`` goes
from 11 to 10 at most, the bodies really are that deep in places.)
Then (``spend_leftover``, on by default) what is left on each pixel goes to the levels that
save the most faces, keeping every pixel's sum of estimates within the budget.

Footprint
---------
A small body far from the source is traced by few rays: its measuring lines are then as far
apart as the scene's rays at its depth (pixel pitch x source-body / source-detector distance /
supersampling), so detail finer than the rays can resolve does not count against it, and it is
decimated as far as its footprint allows (down to :data:`MIN_FACES`).

Caching
-------
Decimated meshes are kept on disk by the SHA-256 of the mesh arrays, the face count and the
source of :mod:`xray_viz.meshes.decimate` and of this module, their measured ``dL`` (complete or
as far as it went) by the same and the measuring pitch (another acquisition of the same bodies
measures again, it does not decimate again), in ``lod/`` next to the mesh reports (``xray_viz.meshes._report_cache``: the same
``XRAY_VIZ_CACHE_DIR``, ``off`` turns it off), so a second run pays nothing; in memory, the
reduced :class:`~xray_viz.bodies.Bodies` are kept on the scene's bodies, so a CT orbit or a viewer
pays the set-up once, with the mesh checks made while the levels were measured.

Examples
--------
>>> import xray_viz
>>> scene = xray_viz.load_scene("sphere")
>>> image = xray_viz.render(scene, max_error=0.1)
>>> lod = image.lod
>>> lod.bodies[0].faces < lod.bodies[0].faces_full, lod.bodies[0].estimated_error <= 0.1
(True, True)
"""

from __future__ import annotations

import dataclasses
import hashlib
import logging
import math
import threading
from functools import lru_cache
from pathlib import Path

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["BodyLevel", "LevelOfDetail", "level_of_detail", "path_length_error",
           "measuring_pitch", "check_max_error", "cache_dir", "forget", "SAFETY", "MIN_FACES", "DIRECTIONS", "LINES"]

log = logging.getLogger("xray_viz.lod")

#: Factor on the measured error (see the module docstring).
SAFETY = 1.5

#: No body is decimated below this many faces.
MIN_FACES = 64

#: Directions of the parallel beams that measure a decimation's path-length error.
DIRECTIONS = 9

#: Measuring lines across a body's bounding sphere (along each detector axis), at most.
LINES = 128

#: Coarse grid of the traced footprints (pixels along the detector's longest side, at most).
COARSE = 128

#: A body whose projected box spans fewer coarse pixels than this (either way) shares the
#: budget by its box (it could lie between the coarse rays).
THIN = 4

#: Bumped when the stored format changes.
FORMAT = 2


@dataclasses.dataclass(frozen=True)
class BodyLevel:
    """The detail one body is traced at.

    Attributes
    ----------
    name : str
    faces_full, faces : int
        Faces of the scene's mesh, and of the mesh traced.
    estimated_error : float
        Estimated largest change of a pixel's line integral caused by this body's decimation
        (``SAFETY x contrast x path_error_mm``; 0 at full resolution).
    share : float
        This body's equal share of the budget, ``max_error / k`` (``k``: the most bodies whose
        footprints meet on a pixel of its own); every body is first decimated within it.
    allowance : float
        What the budget leaves this body once the others' estimates are counted on every pixel
        of its footprint (>= ``estimated_error``): the budget left over after the equal shares
        is spent where it saves the most faces.
    path_error_mm : float
        Measured largest change of the body's path length along a line (mm).
    contrast : float
        Largest attenuation difference at the body's surface (1/mm).
    pitch_mm : float
        Spacing of the measuring lines (mm).
    """

    name: str
    faces_full: int
    faces: int
    estimated_error: float
    share: float
    path_error_mm: float
    contrast: float
    pitch_mm: float
    allowance: float = math.nan


@dataclasses.dataclass(frozen=True)
class LevelOfDetail:
    """What ``render(scene, max_error=...)`` chose (:attr:`xray_viz.render.Radiograph.lod`).

    Attributes
    ----------
    max_error : float
        The budget: the largest change of any pixel's line integral ``-ln(I/I0)``.
    bodies : tuple of BodyLevel
    estimated_error : float
        Estimated largest change of a pixel's line integral: the largest sum of the bodies'
        estimates over the bodies whose footprints overlap (at most ``max_error``).
    """

    max_error: float
    bodies: tuple
    estimated_error: float

    @property
    def faces_full(self) -> int:
        """Faces of the scene's meshes."""
        return sum(b.faces_full for b in self.bodies)

    @property
    def faces(self) -> int:
        """Faces traced."""
        return sum(b.faces for b in self.bodies)

    def summary(self) -> str:
        """One line: faces before and after, the estimated error and the budget."""
        return (f"level of detail for max_error {self.max_error:g}: {self.faces_full} -> "
                f"{self.faces} faces, estimated error {self.estimated_error:.3g}")


# ------------------------------------------------------------------------------------------
# the disk cache of decimations


def cache_dir() -> Path | None:
    """The folder of the stored decimations (``lod/`` beside the mesh reports), or None when
    caching is off (``xray_viz._cache.cache_dir``: ``XRAY_VIZ_CACHE_DIR=off``, or a folder
    that cannot be written)."""
    from xray_viz import _cache

    return _cache.cache_dir("lod", what="decimations")


@lru_cache(maxsize=1)
def _code_digest() -> bytes:
    h = hashlib.sha256()
    for path in (Path(__file__).parent / "meshes" / "decimate.py", Path(__file__)):
        h.update(path.read_bytes())
    return h.digest()


def _mesh_digest(mesh) -> "hashlib._Hash":
    """SHA-256 state of the mesh arrays and the code (:func:`_key` finishes a copy of it)."""
    h = hashlib.sha256()
    h.update(f"xray_viz lod {FORMAT}".encode())
    h.update(_code_digest())
    for a in (np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)):
        a = np.ascontiguousarray(a)
        h.update(f"{a.dtype.str}{a.shape}".encode())
        h.update(memoryview(a).cast("B"))
    return h


def _key(mesh, target_faces: int, pitch: float | None, digest=None) -> str:
    """The stored name of one level's collapse (``pitch`` None) or of its measurement at
    ``pitch`` (``digest``: :func:`_mesh_digest` of ``mesh``, when known: the mesh is then not
    hashed again for every level)."""
    h = (_mesh_digest(mesh) if digest is None else digest).copy()
    h.update(f" {int(target_faces)} {'mesh' if pitch is None else float(pitch).hex()}".encode())
    return h.hexdigest()


def _load(key: str):
    """A stored npz as a dict of arrays, or None (missing, corrupt or another format)."""
    folder = cache_dir()
    if folder is None:
        return None
    try:
        with np.load(folder / f"{key}.npz") as data:
            if int(data["format"]) != FORMAT:
                return None
            return {k: np.array(data[k]) for k in data.files}
    except (OSError, ValueError, KeyError, EOFError):
        return None


def _store(key: str, **arrays) -> None:
    folder = cache_dir()
    if folder is None:
        return
    from xray_viz.meshes._report_cache import write_atomically

    write_atomically(folder, f"{key}.npz", lambda fh: np.savez(fh, format=FORMAT, **arrays))


# ------------------------------------------------------------------------------------------
# measuring a decimation


def _directions(n: int = DIRECTIONS) -> np.ndarray:
    """``n`` unit vectors spread over a half sphere (a line and its reverse are the same)."""
    k = np.arange(n) + 0.5
    z = 1.0 - k / n                                   # (0, 1]: one hemisphere
    phi = np.pi * (3.0 - math.sqrt(5.0)) * np.arange(n)
    r = np.sqrt(1.0 - z * z)
    return np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)


def _parallel_views(mesh, pitch: float):
    """Parallel-beam acquisitions through the mesh's bounding sphere, rays ``pitch`` mm apart
    (coarser when more than :data:`LINES` lines would be needed)."""
    from xray_viz.geometry import Acquisition
    from xray_viz.scene import Detector, Source

    v = np.asarray(mesh.vertices, np.float64)
    lo, hi = v.min(axis=0), v.max(axis=0)
    c = (lo + hi) / 2
    r = float(np.linalg.norm(hi - lo)) / 2 * 1.01 + pitch
    pitch = max(float(pitch), 2 * r / LINES)
    n = int(math.ceil(2 * r / pitch)) + 1
    views = []
    for d in _directions():
        up = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
        src = Source(position=c - 2 * r * d, kind="parallel", energy=60.0)
        det = Detector(center=c + 2 * r * d, up=up, shape=(n, n), pitch=(pitch, pitch))
        views.append(Acquisition(source=src, detector=det))
    return views


class _Measurement:
    """The largest path-length difference of one decimation from its mesh, over the views of
    :func:`_parallel_views` measured so far: ``worst`` (mm) over the views whose bits are set
    in ``done``; complete when all :data:`DIRECTIONS` are. Over some views it is a lower bound
    of the complete value (a maximum over fewer lines), which is all a refusal needs. Shared
    by the choices of one process (:data:`_MEMORY`): ``lock`` serialises its measuring."""

    __slots__ = ("worst", "done", "at", "part", "lock")

    ALL = (1 << DIRECTIONS) - 1

    def __init__(self, worst: float = 0.0, done: int = 0):
        self.worst, self.done, self.at, self.part = float(worst), int(done), 0, None
        self.lock = threading.Lock()

    @property
    def complete(self) -> bool:
        """Every view measured."""
        return self.done == self.ALL


def _measure(mesh, reduced, m: _Measurement, *, pitch: float, report=None, keep=None,
             refuse=None, first: int = 0) -> _Measurement:
    """Measure the views of ``m`` not yet measured, in place, starting at view ``first``;
    stop as soon as ``refuse(worst)`` (a test that stays true as ``worst`` grows) is true.
    ``keep``: as in :func:`path_length_error`, and also the views and which of ``mesh``'s
    traces were made (each made when first needed)."""
    from xray_viz.bodies import Bodies
    from xray_viz.scene import Body
    from xray_viz.tracing.engines import DEFAULT_ENGINE, ENGINES

    fast = ENGINES[DEFAULT_ENGINE]                   # the default (compiled) engine
    key = float(pitch)                               # (one dict per mesh: see below)
    ref = None if keep is None else keep.get(key)
    if ref is None or ref[0] is not mesh:
        ref = (mesh, _parallel_views(mesh, pitch), [None] * DIRECTIONS)
        if keep is not None:
            keep[key] = ref
    _, views, traces = ref
    full = None
    if m.part is None:
        m.part = Bodies([Body(name="reduced", mesh=reduced, mu=1.0)], check=False)
    for i in (np.arange(DIRECTIONS) + first) % DIRECTIONS:
        if m.done >> i & 1:
            continue
        if refuse is not None and refuse(m.worst):
            break
        if traces[i] is None:
            if full is None:
                full = Bodies([Body(name="full", mesh=mesh, mu=1.0)], check=False,
                              reports=None if report is None else (report,))
            traces[i] = np.array(fast.path_lengths(full, views[i], supersample=1))
        d = float(np.abs(traces[i] - fast.path_lengths(m.part, views[i], supersample=1)).max())
        if d > m.worst:
            m.worst, m.at = d, int(i)
        m.done |= 1 << int(i)
    return m


def path_length_error(mesh, reduced, *, pitch: float, report=None, keep=None) -> float:
    """The largest difference of the path lengths of two meshes along a line (mm), measured.

    Both meshes are traced alone by the fast engine along parallel lines ``pitch`` mm apart
    (at most :data:`LINES` across the bounding sphere) from :data:`DIRECTIONS` directions.

    Parameters
    ----------
    mesh, reduced : trimesh.Trimesh
        Closed meshes (the original and a decimation of it).
    pitch : float
        Spacing of the lines (mm).
    report : MeshReport, optional
        ``mesh``'s report when known (skips its check).
    keep : dict, optional
        Where ``mesh``'s own path lengths are kept between calls with the same ``mesh`` and
        ``pitch`` (the levels of one body: the full mesh is traced once, not per level); one
        dict per mesh (an entry made for another mesh is replaced).

    Returns
    -------
    float

    Examples
    --------
    >>> import trimesh
    >>> a = trimesh.creation.icosphere(subdivisions=4, radius=20.0)
    >>> b = trimesh.creation.icosphere(subdivisions=4, radius=20.1)
    >>> 0.2 < path_length_error(a, b, pitch=0.25) < 4 * (20 * 0.1) ** 0.5  # 2 dr .. rim
    True
    """
    return _measure(mesh, reduced, _Measurement(), pitch=pitch, report=report,
                    keep=keep).worst


def measuring_pitch(extent: float, spacing: float) -> float:
    """The spacing of a body's measuring lines: the scene's ray spacing at the body's depth,
    or ``extent / LINES`` when finer, rounded down to a power of two (mm) so that nearby
    acquisitions share the cached measurements.

    Examples
    --------
    >>> measuring_pitch(80.0, 0.3)       # 80 / 128 = 0.625 > 0.3, rounded down
    0.5
    """
    p = max(float(spacing), float(extent) / LINES)
    return 2.0 ** math.floor(math.log2(p))


#: Decimations and measurements of this process (key -> ``(vertices, faces)`` or
#: :class:`_Measurement`), the most recent ones, so that renders in one session share them
#: even with the disk cache off.
_MEMORY: dict = {}
_MEMORY_SIZE = 128


def forget() -> None:
    """Drop the decimations kept in memory (the disk cache stays)."""
    _MEMORY.clear()


def _remember(key, value):
    while len(_MEMORY) >= _MEMORY_SIZE:
        _MEMORY.pop(next(iter(_MEMORY)))
    _MEMORY[key] = value
    return value


def _decimation(mesh, target: int, pitch: float, report, source=None, keep=None,
                digest=None, refuse=None, first: int = 0):
    """``(reduced mesh, measurement)`` of one level, from memory or the disk cache when
    there. ``source``: the previous (finer) level of the halving sequence of :func:`_levels`,
    collapsed further instead of ``mesh`` (the collapse's cost goes with the faces it starts
    from; the levels are a fixed sequence, so the result still depends only on ``mesh`` and
    ``target``). The collapse is kept by ``(mesh, target)``, its :class:`_Measurement`
    against ``mesh`` by ``(mesh, target, pitch)`` (another acquisition of the same mesh
    measures again, it does not collapse again); the measurement stops where ``refuse``
    says (see :func:`_measure`) and is taken up again by a later call that needs more."""
    import trimesh

    key = _key(mesh, target, None, digest)
    hit = _MEMORY.get(key)
    if hit is None:
        data = _load(key)
        if data is not None and {"vertices", "faces"} <= data.keys():
            hit = (np.asarray(data["vertices"], np.float64), np.asarray(data["faces"], np.int64))
        else:
            from xray_viz.meshes.decimate import collapse

            reduced = collapse(mesh if source is None else source, target)
            hit = (np.asarray(reduced.vertices, np.float64), np.asarray(reduced.faces, np.int64))
            _store(key, vertices=hit[0], faces=hit[1])
        _remember(key, hit)
    reduced = trimesh.Trimesh(hit[0].copy(), hit[1].copy(), process=False)
    mkey = _key(mesh, target, pitch, digest)
    m = _MEMORY.get(mkey)
    if m is None:
        data = _load(mkey)
        m = _remember(mkey, _Measurement(float(data["worst"]), int(data["done"]))
                      if data is not None and {"worst", "done"} <= data.keys()
                      else _Measurement())
    if not reduced.is_watertight and not m.complete:
        with m.lock:
            m.worst, m.done = math.inf, _Measurement.ALL
        _store(mkey, worst=m.worst, done=m.done)
    _more(mesh, reduced, m, mkey, pitch=pitch, report=report, keep=keep, refuse=refuse,
          first=first)
    return reduced, m


def _more(mesh, reduced, m, mkey, *, pitch, report, keep, refuse, first) -> None:
    """Measure more of ``m`` unless it is complete or ``refuse`` already refuses it, and
    store it."""
    if m.complete or (refuse is not None and refuse(m.worst)):
        return
    with m.lock:
        _measure(mesh, reduced, m, pitch=pitch, report=report, keep=keep, refuse=refuse,
                 first=first)
        worst, done = m.worst, m.done
    _store(mkey, worst=worst, done=done)


# ------------------------------------------------------------------------------------------
# the choice


def _mu_max(scene) -> np.ndarray:
    """(n,) 1/mm: each body's attenuation at the energy of the beam where it is largest."""
    from xray_viz.physics.imaging import MM_PER_CM, body_mu
    from xray_viz.physics.spectra import source_spectrum

    spectrum = source_spectrum(scene.source)
    energies = np.asarray(spectrum.energies)[np.asarray(spectrum.weights) > 0]
    return body_mu(scene, energies).max(axis=0) / MM_PER_CM


def _overlaps(bounds) -> np.ndarray:
    """(n, n) bool: bounding boxes that meet (each meets itself)."""
    lo, hi = bounds[:, 0], bounds[:, 1]
    return np.all((lo[:, None] <= hi[None]) & (lo[None] <= hi[:, None]), axis=2)


def _boxes(scene):
    """Each body's projected bounding box on the detector as pixel index ranges
    ``(i0, i1, j0, j1)`` (``j`` counted from the bottom; None outside the detector)."""
    acq = scene.acquisition
    w, h = scene.detector.shape
    p = acq.projection_matrix()
    boxes = []
    for lo, hi in scene.bodies.bounds:
        corners = np.array([[x, y, z, 1.0] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                            for z in (lo[2], hi[2])])
        q = corners @ p.T
        if np.any(q[:, 2] <= 0):                     # reaches behind a point source: anywhere
            box = (0, w, 0, h)
        else:
            ij = q[:, :2] / q[:, 2:]
            i0, j0 = np.floor(ij.min(axis=0)).astype(int) - 1
            i1, j1 = np.ceil(ij.max(axis=0)).astype(int) + 2
            box = (max(i0, 0), min(i1, w), max(j0, 0), min(j1, h))
            if box[0] >= box[1] or box[2] >= box[3]:
                box = None
        boxes.append(box)
    return boxes


def _coarse_acquisition(scene):
    """``(acquisition, s)``: the scene's acquisition with pixels ``s`` times larger, at most
    :data:`COARSE` across, covering the whole detector."""
    from xray_viz.geometry import Acquisition

    det = scene.detector
    w, h = det.shape
    s = max(1, math.ceil(max(w, h) / COARSE))
    if s == 1:
        return scene.acquisition, 1
    coarse = dataclasses.replace(det, shape=(math.ceil(w / s), math.ceil(h / s)),
                                 pitch=tuple(float(p) * s for p in det.pitch))
    return Acquisition(source=scene.source, detector=coarse), s


def _box_mask(box, s, fine, coarse):
    """(ch, cw) bool: a box ``(i0, i1, j0, j1)`` of fine pixels (``j`` from the bottom) on the
    coarse grid of :func:`_coarse_acquisition` (same centre, row 0 at the top), one coarse
    pixel wider each way."""
    (w, h), (cw, ch) = fine, coarse
    i0, i1, j0, j1 = box

    def col(i):
        return (i - (w - 1) / 2) / s + (cw - 1) / 2

    def row(j):                                       # fine row from the bottom -> coarse row
        return (h - 1 - j - (h - 1) / 2) / s + (ch - 1) / 2

    m = np.zeros((ch, cw), bool)
    c0, c1 = max(math.floor(col(i0)) - 1, 0), min(math.ceil(col(i1)) + 2, cw)
    r0, r1 = max(math.floor(row(j1)) - 1, 0), min(math.ceil(row(j0)) + 2, ch)
    m[r0:r1, c0:c1] = True
    return m


def _footprints(scene, boxes):
    """(n, ch, cw) bool: where each body's rays may run, on a coarse grid of the detector.

    The full-resolution bodies are traced by the fast engine at :func:`_coarse_acquisition`;
    a body's footprint is where its path length is > 0, dilated by one coarse pixel (the
    scene's rays between the coarse ones, and the decimated surface's small displacement). A
    body whose box spans fewer than :data:`THIN` coarse pixels in either direction (it could
    lie between the coarse rays) takes its box instead; so does every body when the coarse
    trace is refused (a triangle across the plane of a point source)."""
    from scipy.ndimage import binary_dilation

    from xray_viz.tracing.engines import Projector

    acq, s = _coarse_acquisition(scene)
    cw, ch = acq.detector.shape
    n = len(scene.bodies)
    try:
        L = np.asarray(Projector(scene.bodies).path_lengths(acq, supersample=1))
        inside = (L > 0).reshape(ch, cw, n).transpose(2, 0, 1)
    except SceneError:
        inside = None
    out = np.zeros((n, ch, cw), bool)
    for b, box in enumerate(boxes):
        if box is None:
            continue
        thin = min(box[1] - box[0], box[3] - box[2]) < THIN * s
        if inside is None or thin:
            out[b] = _box_mask(box, s, scene.detector.shape, (cw, ch))
        else:
            out[b] = binary_dilation(inside[b], structure=np.ones((3, 3), bool))
    return out


def _sharing(footprints) -> list:
    """Each body's ``k``: the most bodies whose footprints meet at any coarse pixel of its own
    (1 for a body with no footprint)."""
    count = footprints.sum(axis=0)
    return [int(count[f].max()) if f.any() else 1 for f in footprints]


def _ray_spacing(scene, bounds, n: int) -> float:
    """The distance between neighbouring rays (mm) at the depth of a body's nearest point."""
    f = scene.acquisition.frame
    pitch = min(f.pitch)
    if f.parallel:
        return pitch / n
    lo, hi = bounds
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    depth = max(float(((corners - f.source) @ f.forward).min()), 1e-9 * f.sid)
    return pitch * depth / f.sid / n


def _levels(n_faces: int):
    """Face counts tried, finest first: halving down to :data:`MIN_FACES`."""
    out, t = [], n_faces // 2
    while t >= MIN_FACES:
        out.append(t)
        t //= 2
    return out


def check_max_error(max_error) -> float:
    """``max_error`` as a float, or the one-line refusal of a value that is not > 0."""
    if isinstance(max_error, bool) or not isinstance(max_error, (int, float, np.floating,
                                                                 np.integer)) \
            or not (math.isfinite(float(max_error)) and float(max_error) > 0):
        raise SceneError(f"max_error must be a number > 0 (the largest change of a pixel's line "
                         f"integral -ln(I/I0) allowed, e.g. 0.01), got {max_error!r}")
    return float(max_error)


def level_of_detail(scene, max_error, *, supersample: int = 1,
                    spend_leftover: bool = True):
    """The scene with each body at the coarsest decimation its share of the budget allows.

    Parameters
    ----------
    scene : Scene
    max_error : float
        Largest change of any pixel's line integral ``-ln(I/I0)`` allowed (see the module
        docstring for what is estimated and how).
    supersample : int, optional
        Rays per pixel along each axis of the render (sets the ray spacing at each body).
    spend_leftover : bool, optional
        After every body is decimated within its equal share ``max_error / k``, give what the
        budget leaves on each coarse pixel, step by step, to the next level that saves the
        most faces per unit of estimated error while every pixel's sum of the estimates of
        the bodies on it stays within ``max_error`` (as safe as the equal shares, by the same
        footprints; the frog, 16 overlapping bodies: 173,500 -> 111,874 faces at 0.2 instead
        of 168,500). On by default (what ``render(max_error=...)`` and ``--max-error`` do);
        False: the equal shares only, :attr:`BodyLevel.share` then bounds every estimate.

    Returns
    -------
    scene : Scene
        The same acquisition; bodies with reduced meshes (names, materials and precedence
        unchanged). The scene itself when no body is reduced.
    report : LevelOfDetail

    Raises
    ------
    SceneError
        ``max_error`` not a number > 0.
    """
    budget = check_max_error(max_error)
    bodies = scene.bodies
    if not len(bodies):
        return scene, LevelOfDetail(budget, (), 0.0)
    mu = _mu_max(scene)
    near = _overlaps(bodies.bounds)
    contrast = np.array([max(mu[b], float(np.abs(mu[b] - mu[near[b]]).max()))
                         for b in range(len(bodies))])
    boxes = _boxes(scene)
    acq = scene.acquisition
    fkey = ("lod", "footprints", acq.projection_matrix().tobytes(),
            np.asarray(acq.source.position, np.float64).tobytes(), tuple(scene.detector.shape),
            bool(acq.frame.parallel))
    footprints = bodies.cached(fkey, lambda: _footprints(scene, boxes), limit=4)
    k_max = _sharing(footprints)
    reports = bodies.reports
    n = len(bodies)
    pitches, shares, steps = [], [], []
    for b in range(n):
        extent = float(np.linalg.norm(bodies.bounds[b, 1] - bodies.bounds[b, 0]))
        pitches.append(measuring_pitch(extent, _ray_spacing(scene, bodies.bounds[b],
                                                            supersample)))
        shares.append(budget / k_max[b])
        steps.append(iter(_levels(len(bodies[b].faces)))
                     if boxes[b] is not None and contrast[b] > 0 else iter(()))
        if boxes[b] is None:
            log.debug("lod: body %r is outside the detector: kept as it is", bodies[b].name)

    last = [None] * n                                # the last level made of each body
    keeps = [{} for _ in range(n)]                   # each full mesh's measuring traces
    digests = [None] * n                             # each full mesh hashed once
    firsts = [0] * n                                 # where each body's last level was worst

    def estimate(b, worst):
        return float(SAFETY * contrast[b] * worst)

    def step(b, refuse):
        """The next level of body ``b``: ``(mesh, measurement, target)``, or None; measured
        until ``refuse(estimate)`` holds or completely (a refused level's estimate may be a
        lower bound: :func:`_measure`)."""
        target = next(steps[b], None)
        if target is None:
            return None
        if digests[b] is None:
            digests[b] = _mesh_digest(bodies[b].mesh)
        reduced, m = _decimation(bodies[b].mesh, target, pitches[b], reports[b],
                                 source=last[b], keep=keeps[b], digest=digests[b],
                                 refuse=lambda w: refuse(estimate(b, w)),
                                 first=firsts[b])
        last[b], firsts[b] = reduced, m.at
        log.debug("lod: body %r at %d faces: path error %.4g mm%s, estimated %.4g (share %.4g)",
                  bodies[b].name, len(reduced.faces), m.worst,
                  "" if m.complete else " or more", estimate(b, m.worst), shares[b])
        return reduced, m, target

    def finish(b, refuse):
        """Measure more of body ``b``'s pending level, until ``refuse`` holds or completely."""
        reduced, m, target = pending[b]
        _more(bodies[b].mesh, reduced, m, _key(bodies[b].mesh, target, pitches[b], digests[b]),
              pitch=pitches[b], report=reports[b], keep=keeps[b],
              refuse=lambda w: refuse(estimate(b, w)), first=firsts[b])

    chosen = [body.mesh for body in bodies]
    dls, errs, pending = [0.0] * n, [0.0] * n, [None] * n
    measured = [None] * n                            # the chosen levels' measurements
    # 1. every body within its equal share, budget / k (a level is refused as soon as part of
    # its measurement exceeds the share: the complete one could only be larger)
    for b in range(n):
        def over_share(e, s=shares[b]):
            return not e <= s

        while (nxt := step(b, over_share)) is not None and estimate(b, nxt[1].worst) <= shares[b]:
            chosen[b], dls[b], errs[b] = nxt[0], nxt[1].worst, estimate(b, nxt[1].worst)
            measured[b] = nxt[1]
        pending[b] = nxt
    # 2. what is left on each coarse pixel goes, step by step, to the next level saving the
    # most faces per unit of estimated error that keeps every pixel's sum within the budget
    acc = np.zeros(footprints.shape[1:])
    for b in range(n):
        acc[footprints[b]] += errs[b]

    def over_budget(b):
        """The test a level of body ``b`` fails now and, the sums only growing, for good."""
        top, own = acc[footprints[b]].max(initial=0.0), errs[b]
        return lambda e: not (top + (e - own) <= budget)

    while spend_leftover:
        best, rate = None, -1.0
        for b in range(n):
            if pending[b] is None:
                continue
            refuse = over_budget(b)
            if not pending[b][1].complete and not refuse(estimate(b, pending[b][1].worst)):
                finish(b, refuse)                    # part measured: the rest is needed now
            if refuse(estimate(b, pending[b][1].worst)):
                pending[b] = None                    # the sums only grow: never again
                continue
            extra = estimate(b, pending[b][1].worst) - errs[b]
            r = (len(chosen[b].faces) - len(pending[b][0].faces)) / max(extra, 1e-300)
            if r > rate:
                best, rate = b, r
        if best is None:
            break
        reduced, m, _ = pending[best]
        est = estimate(best, m.worst)
        acc[footprints[best]] += est - errs[best]
        chosen[best], dls[best], errs[best], measured[best] = reduced, m.worst, est, m
        pending[best] = step(best, over_budget(best))
    levels = []
    for b, body in enumerate(bodies):
        others = (acc[footprints[b]].max(initial=0.0) - errs[b]) if footprints[b].any() else 0.0
        levels.append(BodyLevel(name=body.name, faces_full=len(body.faces),
                                faces=len(chosen[b].faces), estimated_error=errs[b],
                                share=shares[b], path_error_mm=dls[b],
                                contrast=float(contrast[b]), pitch_mm=pitches[b],
                                allowance=float(max(budget - others, errs[b]))))
    total = _overlap_sum(footprints, [lv.estimated_error for lv in levels])
    report = LevelOfDetail(budget, tuple(levels), total)
    log.info("%s", report.summary())
    for lv in levels:
        log.debug("  %s: %d -> %d faces, estimated error %.3g (share %.3g)", lv.name,
                 lv.faces_full, lv.faces, lv.estimated_error, lv.share)
    if all(m is body.mesh for m, body in zip(chosen, bodies)):
        return scene, report
    key = ("lod", "bodies", tuple(lv.faces for lv in levels),
           tuple(float(lv.pitch_mm) for lv in levels))

    def build():
        from xray_viz.bodies import Bodies

        new = [body if m is body.mesh else dataclasses.replace(body, mesh=m)
               for m, body in zip(chosen, bodies)]
        # The checks made already (the full meshes', and each chosen level's while it was
        # measured) go with them: the render does not check the meshes again.
        known = [reports[b] if measured[b] is None else
                 None if measured[b].part is None else measured[b].part.reports[0]
                 for b in range(n)]
        # Where bodies overlap, the same body gives the material as at full resolution
        # (the decimated surfaces of touching bodies may cross where the originals did not).
        return Bodies(new, check=False, reports=None if None in known else known,
                      precedence=bodies.precedence if len(bodies) > 1 else None)

    reduced_bodies = bodies.cached(key, build, limit=4)
    return scene.replace(bodies=reduced_bodies), report


def _overlap_sum(footprints, errors) -> float:
    """The largest sum of the bodies' estimated errors over any coarse pixel."""
    acc = np.zeros(footprints.shape[1:])
    for f, e in zip(footprints, errors):
        if e > 0:
            acc[f] += e
    return float(acc.max()) if acc.size else 0.0

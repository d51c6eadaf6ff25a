"""The thesis' viewport geometry: HO, VE, FL, LHC (Eq. 1.2) and the pixel rays (Eq. 1.3-1.5).

Conventions (thesis section 1.0.1, with its errata fixed):

* ``FL = r0 - center`` points from the viewport centre to the source ``r0``.
* ``HO = |HO| * unit(forward x up)`` runs left to right as seen from the source, where
  ``forward = unit(-FL)`` is the beam direction.
* ``VE = |VE| * (unit(HO) x forward)`` runs bottom to top.
* ``LHC = r0 - HO/2 - VE/2 - FL`` (Eq. 1.2) is the lower-left corner of the viewport (a position).
* ``u_i = i / (W - 1)``, ``v_j = j / (H - 1)`` (Eq. 1.3-1.4), so the first and last rays lie on
  the viewport edges and ``|HO| = (W - 1) * pitch``.
* Ray (i, j) of a point source: ``r(t) = r0 + t (LHC + u_i HO + v_j VE - r0)``. Eq. 1.5 as printed
  omits ``- r0``, which is only right when the source sits at the origin.
* Parallel beam: ray (i, j) starts at ``r0 + (u_i - 1/2) HO + (v_j - 1/2) VE`` and runs along
  ``forward``.

A tilted or offset detector (:class:`~xray_viz.scene.Detector` ``u``, ``v``, ``offset``) keeps
these names for the untilted, unshifted case: the beam axis is still ``source -> center``, but
the pixel points lie on the detector's own plane (through ``center``, normal ``v x u``), at
``middle + (u_i - 1/2) |HO| u + (v_j - 1/2) |VE| v`` with ``middle = center + du u + dv v``
(:class:`DetectorFrame`). A point source's rays run from the source through the pixel points;
a parallel beam's run along the beam axis through them, from the plane through the source
parallel to the detector (for an untilted detector, the plane across the beam, as above).

Rays are returned in *image order*: ray ``k = row * W + col`` with ``col = i`` and
``row = H - 1 - j``, so that ``array.reshape(H, W)`` is an image whose row 0 is the top (v = 1)
and column 0 the left (u = 0).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["Acquisition", "DetectorFrame", "FineGrid", "Viewport", "viewport", "detector_axes",
           "tilted_normal", "TILT_TOLERANCE",
           "beam_direction", "pixel_coordinates", "detector_rays", "Rays", "check_supersample",
           "beam_planes", "boxes_outside_beam", "row_range", "UP_TOLERANCE"]

#: ``up`` is refused as parallel to the beam when ``|forward x unit(up)|`` is below this (the
#: sine of the angle between them): ``unit(forward x up)`` would lose most of its digits.
UP_TOLERANCE = 1e-9

#: A tilted detector is refused as (nearly) parallel to the beam when the cosine of the angle
#: between the beam axis and its normal is below this (an angle above 89.99994 degrees): its
#: pixels would be seen edge-on, and a parallel beam's oblique projection would blow up.
TILT_TOLERANCE = 1e-6


def beam_direction(source_position, detector_center) -> np.ndarray:
    """Unit vector from the source to the detector centre (``unit(-FL)``)."""
    fl = np.asarray(source_position, float) - np.asarray(detector_center, float)
    norm = np.linalg.norm(fl)
    if norm == 0:
        raise SceneError("the source sits at the detector centre: FL = r0 - center is zero")
    return -fl / norm


@dataclass(frozen=True)
class Viewport:
    """The thesis' viewport vectors (Figure 1.3), all in mm.

    Attributes
    ----------
    r0 : (3,) float
        Source position.
    HO, VE : (3,) float
        Horizontal (left to right) and vertical (bottom to top) extent of the viewport.
    FL : (3,) float
        From the viewport centre to ``r0``.
    LHC : (3,) float
        Lower-left corner of the viewport, Eq. 1.2.
    shape : (int, int)
        ``(W, H)``.
    """

    r0: np.ndarray
    HO: np.ndarray
    VE: np.ndarray
    FL: np.ndarray
    LHC: np.ndarray
    shape: tuple[int, int]

    @property
    def forward(self) -> np.ndarray:
        """Unit beam direction ``-FL / |FL|``."""
        return -self.FL / np.linalg.norm(self.FL)

    @property
    def normal(self) -> np.ndarray:
        """Unit normal of the untilted detector plane, pointing away from the source (=
        forward; a tilted detector's is :attr:`DetectorFrame.normal`)."""
        return self.forward

    def point(self, u, v) -> np.ndarray:
        """Point of the viewport at coordinates ``(u, v)`` in [0, 1]: ``LHC + u HO + v VE``."""
        u = np.asarray(u, float)[..., None]
        v = np.asarray(v, float)[..., None]
        return self.LHC + u * self.HO + v * self.VE


def detector_axes(source_position, detector_center, up) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit vectors of the detector frame: ``forward``, ``unit(HO)`` and ``unit(VE)``.

    ``forward = unit(-FL)`` is the beam axis, ``unit(HO) = unit(forward x up)`` and
    ``unit(VE) = unit(HO) x forward``.

    Raises
    ------
    SceneError
        When the source sits at the detector centre or ``up`` is parallel to the beam (within
        :data:`UP_TOLERANCE`).
    """
    forward = beam_direction(source_position, detector_center)
    up = np.asarray(up, dtype=np.float64)
    ho_dir = np.cross(forward, up)
    norm = np.linalg.norm(ho_dir)
    if not norm >= UP_TOLERANCE * np.linalg.norm(up):
        raise SceneError(f"[detector] up {up.tolist()} is parallel to the beam (source -> "
                         "detector centre); choose an up vector across the beam")
    ho_dir /= norm
    return forward, ho_dir, np.cross(ho_dir, forward)


def tilted_normal(source_position, detector_center, u, v) -> np.ndarray:
    """Unit normal ``v x u`` of a tilted detector's plane, checked to face the source.

    Raises
    ------
    SceneError
        When the plane is (nearly, :data:`TILT_TOLERANCE`) parallel to the beam axis (source
        -> detector centre) or its front (``u x v``) faces away from the source.
    """
    forward = beam_direction(source_position, detector_center)
    u = np.asarray(u, np.float64)
    v = np.asarray(v, np.float64)
    n = np.cross(v, u)
    n /= np.linalg.norm(n)
    cos = float(n @ forward)
    if not abs(cos) >= TILT_TOLERANCE:
        raise SceneError(f"[detector] u {u.tolist()}, v {v.tolist()}: the detector plane is "
                         f"parallel to the beam (source -> detector centre, cos = {cos:.3g}); "
                         "tilt it less than 89.9999 degrees")
    if cos < 0:
        raise SceneError(f"[detector] u {u.tolist()}, v {v.tolist()}: the detector faces away "
                         "from the source (u x v must point towards it, as unit(HO) x unit(VE) "
                         "does); negate u or v")
    return n


def viewport(source_position, detector) -> Viewport:
    """Compute HO, VE, FL and LHC (Eq. 1.2) for a source and a :class:`~xray_viz.scene.Detector`.

    Examples
    --------
    >>> from xray_viz.scene import Detector
    >>> det = Detector(center=[0, 0, -500], up=[0, 1, 0], shape=(5, 3), pitch=1.0)
    >>> vp = viewport([0, 0, 1000], det)
    >>> vp.HO.tolist(), vp.VE.tolist(), vp.LHC.tolist()
    ([4.0, 0.0, 0.0], [0.0, 2.0, 0.0], [-2.0, -1.0, -500.0])
    """
    r0 = np.asarray(source_position, dtype=np.float64)
    center = np.asarray(detector.center, dtype=np.float64)
    FL = r0 - center
    _, ho_dir, ve_dir = detector_axes(r0, center, detector.up)
    width, height = detector.size
    HO = width * ho_dir
    VE = height * ve_dir
    LHC = r0 - HO / 2 - VE / 2 - FL
    return Viewport(r0=r0, HO=HO, VE=VE, FL=FL, LHC=LHC, shape=tuple(detector.shape))


def pixel_coordinates(shape) -> tuple[np.ndarray, np.ndarray]:
    """Viewport coordinates of every ray in image order, Eq. 1.3-1.4.

    Returns
    -------
    u, v : (H, W) float
        ``u[row, col] = col / (W - 1)`` and ``v[row, col] = (H - 1 - row) / (H - 1)``. A detector
        one pixel wide (or high) has its single ray at the centre, ``u = 0.5``.
    """
    w, h = shape
    ui = np.arange(w) / (w - 1) if w > 1 else np.array([0.5])
    vj = np.arange(h) / (h - 1) if h > 1 else np.array([0.5])
    u, v = np.meshgrid(ui, vj[::-1])
    return u, v


@dataclass(frozen=True)
class Rays:
    """A set of rays ``r(t) = origin + t * direction`` for ``t`` in ``[t_min, t_max]``.

    Attributes
    ----------
    origins, directions : (n, 3) float
        Directions are unit vectors, so ``t`` is a distance in mm.
    t_max : (n,) float
        Where each ray reaches the detector.
    shape : (int, int) or None
        ``(W, H)`` when the rays are a detector grid in image order.
    """

    origins: np.ndarray
    directions: np.ndarray
    t_max: np.ndarray
    shape: tuple[int, int] | None = None

    def __len__(self) -> int:
        return len(self.directions)

    @property
    def ends(self) -> np.ndarray:
        """(n, 3) float: where each ray meets the detector."""
        return self.origins + self.t_max[:, None] * self.directions


def check_supersample(value, *, name: str = "supersample") -> int:
    """``value`` as an int if it is a whole number >= 1 (a Python or NumPy integer).

    Floats (``2.7``, even ``2.0``), strings and booleans are refused, not coerced.

    Raises
    ------
    SceneError
        (a ``ValueError``) naming the value and its type.

    Examples
    --------
    >>> import numpy as np
    >>> check_supersample(np.int64(3))
    3
    """
    import numbers

    if isinstance(value, (bool, np.bool_)) or not isinstance(value, numbers.Integral) \
            or value < 1:
        raise SceneError(f"{name} must be a whole number >= 1 (an int), got {value!r} "
                         f"({type(value).__name__})")
    return int(value)


def row_range(rows, h):
    """``(start, stop)`` of a range of image rows given as None, (start, stop), range or slice."""
    if rows is None:
        return 0, h
    if isinstance(rows, slice):
        if rows.step not in (None, 1):
            raise SceneError(f"rows must be a contiguous range of image rows, got {rows!r}")
        start, stop, _ = rows.indices(h)
    elif isinstance(rows, range):
        if rows.step != 1:
            raise SceneError(f"rows must be a contiguous range of image rows, got {rows!r}")
        start, stop = rows.start, rows.stop
    else:
        start, stop = (int(r) for r in rows)
    if not 0 <= start <= stop <= h:
        raise SceneError(f"rows {start}..{stop} are not within the detector's {h} rows")
    return start, stop


def detector_rays(scene, *, supersample: int = 1, rows=None) -> Rays:
    """The rays of a scene's detector grid, in image order.

    Parameters
    ----------
    scene : Scene or Acquisition
        Source and detector.
    supersample : int, optional
        ``n`` gives ``n x n`` rays per pixel on a regular sub-grid centred on the pixel's ray
        (ray ``k * n * n + s`` is sub-ray ``s`` of pixel ``k``). The default, 1, is the thesis grid.
    rows : (int, int), range or slice, optional
        Only the rays of image rows ``start .. stop - 1`` (row 0 at the top of the detector), in
        the same order and with the same values as in the whole grid: ray ``k`` of the result is
        ray ``start * W * n * n + k`` of ``detector_rays(scene, supersample=n)``. Default: every
        row. Memory is O(rays returned).

    Returns
    -------
    Rays
        Unit directions; ``t_max`` is the distance from the ray origin to the detector.

    Examples
    --------
    >>> import xray_viz
    >>> rays = detector_rays(xray_viz.load_scene("sphere"))
    >>> rays.origins.shape
    (65536, 3)
    >>> band = detector_rays(xray_viz.load_scene("sphere"), rows=(10, 12))
    >>> bool((band.directions == rays.directions[10 * 256:12 * 256]).all())
    True
    """
    n = check_supersample(supersample)
    acq = scene if isinstance(scene, Acquisition) else getattr(scene, "acquisition", None)
    if acq is None:
        acq = Acquisition(source=scene.source, detector=scene.detector)
    vp = acq.viewport
    w, h = vp.shape
    start, stop = row_range(rows, h)
    # The rows of pixel_coordinates(vp.shape), computed for these rows only (same values).
    ui = np.arange(w) / (w - 1) if w > 1 else np.array([0.5])
    vj = np.arange(h) / (h - 1) if h > 1 else np.array([0.5])
    u, v = np.meshgrid(ui, vj[::-1][start:stop])
    u, v = u.ravel(), v.ravel()
    if n > 1:
        du = 1.0 / max(w - 1, 1)
        dv = 1.0 / max(h - 1, 1)
        offs = (np.arange(n) + 0.5) / n - 0.5
        ou, ov = np.meshgrid(offs * du, offs[::-1] * dv)
        u = (u[:, None] + ou.ravel()[None, :]).ravel()
        v = (v[:, None] + ov.ravel()[None, :]).ravel()
    fr = acq.frame
    if not fr.plain:                 # a tilted or offset detector: its own pixel points
        width, height = acq.detector.size
        points = fr.middle + (u[:, None] - 0.5) * (width * fr.ho) \
            + (v[:, None] - 0.5) * (height * fr.ve)
        if fr.parallel:
            origins = points - fr.sid * fr.forward
            directions = np.broadcast_to(fr.forward, origins.shape).copy()
            t_max = np.full(len(origins), fr.sid)
        else:
            d = points - fr.source
            t_max = np.linalg.norm(d, axis=1)
            directions = d / t_max[:, None]
            origins = np.broadcast_to(fr.source, directions.shape).copy()
    elif scene.source.kind == "parallel":
        forward = vp.forward
        origins = vp.r0 + (u[:, None] - 0.5) * vp.HO + (v[:, None] - 0.5) * vp.VE
        directions = np.broadcast_to(forward, origins.shape).copy()
        t_max = np.full(len(origins), np.linalg.norm(vp.FL))
    else:
        targets = vp.point(u, v)
        d = targets - vp.r0
        t_max = np.linalg.norm(d, axis=1)
        directions = d / t_max[:, None]
        origins = np.broadcast_to(vp.r0, directions.shape).copy()
    return Rays(origins=origins, directions=directions, t_max=t_max, shape=vp.shape)


# --------------------------------------------------------------------------------------------
# How the bodies are imaged: the acquisition


@dataclass(frozen=True)
class FineGrid:
    """Where the rays of an ``n x n`` supersampled detector grid lie, in its frame.

    The fine (sub-ray) grid has ``n W`` columns and ``n H`` rows, sample ``(x, y)`` (x to the
    right, y up) at ``middle + p00 + x * ex + y * ey`` (:attr:`DetectorFrame.middle`, the
    detector centre). The projection of a point ``p`` onto the detector has fine coordinates
    ``(sx * a + bx, sy * b + by)`` with ``(a, b) = D (ho . (p - r0), ve . (p - r0)) /
    normal . (p - r0)`` for a point source (a plane-to-plane homography, ``D`` =
    :attr:`DetectorFrame.distance`) and ``(a, b) = (project_u . (p - r0), project_v . (p -
    r0))`` for a parallel beam (:attr:`DetectorFrame.project_u`): ``(bx, by)`` is the
    principal point, the projection of the source (:attr:`DetectorFrame.principal`; the
    detector centre when it is untilted and not offset).

    Attributes
    ----------
    n : int
        Rays per pixel along each axis.
    sx, sy : float
        Fine samples per mm along ``ho`` and ``ve``.
    bx, by : float
        Fine coordinates of the principal point.
    ex, ey : (3,) float
        One fine step along ``ho`` and ``ve`` (mm vectors).
    p00 : (3,) float
        Offset of fine sample ``(0, 0)`` from the detector centre (mm).
    q00 : (3,) float
        Where the ray of fine sample ``(0, 0)`` is taken from the source ``r0`` (mm): its
        detector point minus ``r0`` for a point source, its origin minus ``r0`` for a parallel
        beam (on the plane through the source parallel to the detector).
    """

    n: int
    sx: float
    sy: float
    bx: float
    by: float
    ex: np.ndarray
    ey: np.ndarray
    p00: np.ndarray
    q00: np.ndarray


@dataclass(frozen=True)
class DetectorFrame:
    """The detector's frame seen from the source, one name per concept.

    Attributes
    ----------
    source : (3,) float
        The source position ``r0`` (mm).
    center : (3,) float
        The detector centre (mm).
    forward : (3,) float
        Unit beam axis, from the source to ``center`` (``unit(-FL)``).
    ho, ve : (3,) float
        Unit vectors along the detector's rows (left to right, ``unit(HO)``) and columns
        (bottom to top, ``unit(VE)``); a tilted detector's own ``u`` and ``v``.
    sid : float
        Source-to-detector distance along the axis, ``|FL|`` (mm).
    parallel : bool
        A parallel beam (every ray along ``forward``) rather than a point source.
    shape : (int, int)
        ``(W, H)`` rays.
    pitch : (float, float)
        mm between neighbouring rays along ``ho`` and ``ve``.
    normal : (3,) float
        Unit normal of the detector plane, away from the source: ``forward`` when untilted,
        else ``ve x ho``.
    distance : float
        Source-to-detector-plane distance along ``normal``, ``D = normal . (center - r0)``
        (``sid`` when untilted).
    offset : (float, float)
        ``(du, dv)`` mm: the detector centre ``middle = center + du ho + dv ve``.
    middle : (3,) float
        The middle of the pixel grid (``center`` unless offset).
    tilted : bool
        The detector has its own axes (``ho``, ``ve`` were given, not derived).
    """

    source: np.ndarray
    center: np.ndarray
    forward: np.ndarray
    ho: np.ndarray
    ve: np.ndarray
    sid: float
    parallel: bool
    shape: tuple
    pitch: tuple
    normal: np.ndarray = None
    distance: float = None
    offset: tuple = (0.0, 0.0)
    middle: np.ndarray = None
    tilted: bool = False

    def __post_init__(self):
        if self.normal is None:
            object.__setattr__(self, "normal", self.forward)
        if self.distance is None:
            object.__setattr__(self, "distance", self.sid)
        if self.middle is None:
            object.__setattr__(self, "middle", self.center)

    @property
    def plain(self) -> bool:
        """Untilted and not offset: the thesis' detector (every formula as before)."""
        return not self.tilted and tuple(self.offset) == (0.0, 0.0)

    @cached_property
    def depth_axis(self) -> np.ndarray:
        """(3,) float: ``g`` with ``g . (p - r0)`` the depth of a point ``p`` that the fast
        engine uses: the distance from the source plane along the normal for a point source
        (``normal``), the distance along a parallel beam's ray from the plane through the
        source parallel to the detector (``normal / (normal . forward)``; ``forward`` when
        untilted). The detector lies at depth :attr:`depth`."""
        if self.parallel and self.tilted:
            return self.normal / float(self.normal @ self.forward)
        return self.normal

    @property
    def depth(self) -> float:
        """Depth of the detector along :attr:`depth_axis` (mm): ``distance`` for a point
        source, ``sid`` for a parallel beam (every ray's length from the source plane)."""
        return self.sid if self.parallel else self.distance

    @cached_property
    def project_u(self) -> np.ndarray:
        """(3,) float: the linear part of the projection onto the detector along ``ho``: ``ho``
        itself for a point source or an untilted detector; for a parallel beam onto a tilted
        one, the oblique projection along ``forward``, ``ho - (ho . forward) / (normal .
        forward) normal``."""
        return self._oblique(self.ho)

    @cached_property
    def project_v(self) -> np.ndarray:
        """(3,) float: as :attr:`project_u`, along ``ve``."""
        return self._oblique(self.ve)

    def _oblique(self, e):
        if self.parallel and self.tilted:
            return e - float(e @ self.forward) / float(self.normal @ self.forward) * self.normal
        return e

    @cached_property
    def principal(self) -> tuple[float, float]:
        """``(cu, cv)`` mm: where the source projects onto the detector, from its middle along
        ``ho`` and ``ve`` (the principal point: the foot of the perpendicular from a point
        source, the ray through ``center`` of a parallel beam); ``(0, 0)`` when untilted and
        not offset."""
        if self.tilted and not self.parallel:
            rel = self.source - self.center
            base = (float(self.ho @ rel), float(self.ve @ rel))
        else:            # the beam axis meets the plane at ``center``
            base = (0.0, 0.0)
        return (base[0] - self.offset[0], base[1] - self.offset[1])

    def grid(self, n: int = 1) -> FineGrid:
        """The ``n x n`` supersampled ray grid in this frame (:class:`FineGrid`)."""
        n = check_supersample(n)
        (w, h), (px, py) = self.shape, self.pitch
        bx = n * (w - 1) / 2 + (n - 1) / 2
        by = n * (h - 1) / 2 + (n - 1) / 2
        ex, ey = (px / n) * self.ho, (py / n) * self.ve
        p00 = -bx * ex - by * ey
        if not self.parallel:
            q00 = (self.middle + p00) - self.source
        elif self.plain:
            q00 = p00
        else:
            q00 = (self.middle + p00 - self.sid * self.forward) - self.source
        cu, cv = self.principal
        return FineGrid(n=n, sx=n / px, sy=n / py, bx=bx + (n / px) * cu, by=by + (n / py) * cv,
                        ex=ex, ey=ey, p00=p00, q00=q00)


def beam_planes(r0, forward, eu, ev, FL, half_u, half_v, perspective, *,
                principal=(0.0, 0.0)) -> np.ndarray:
    """Planes bounding the beam: every ray point ``x`` has ``n . (x - r0) <= c`` for each row
    ``(nx, ny, nz, c)`` of the result.

    Rows 0-3 are the side planes (through the source for a point source: the pyramid from the
    source through the detector rectangle of half-widths ``half_u``, ``half_v`` mm along ``eu``
    and ``ev``; the slab box of a parallel beam), row 4 the source plane (nothing behind it),
    row 5 the detector plane (rays end there, ``FL`` from the source). ``forward`` is the depth
    axis (:attr:`DetectorFrame.depth_axis`), ``eu``, ``ev`` the projection's linear parts
    (:attr:`DetectorFrame.project_u`) and ``principal`` the projection of the source relative
    to the middle of the rectangle (mm, :attr:`DetectorFrame.principal`): a point ``x``
    projects to ``a = FL eu . (x - r0) / forward . (x - r0) + cu`` (point source) or ``a = eu .
    (x - r0) + cu`` (parallel beam).
    """
    f = np.asarray(forward, np.float64)
    eu = np.asarray(eu, np.float64)
    ev = np.asarray(ev, np.float64)
    cu, cv = (float(c) for c in principal)
    rows = []
    for e, h, c in ((eu, half_u, cu), (ev, half_v, cv)):
        for s in (1.0, -1.0):
            if perspective:
                rows.append(np.append(s * FL * e - (h - s * c) * f, 0.0))   # |a| w <= h w
            else:
                rows.append(np.append(s * e, h - s * c))                    # |a| <= h
    rows.append(np.append(-f, 0.0))
    rows.append(np.append(f, FL))
    return np.ascontiguousarray(rows, dtype=np.float64)


def boxes_outside_beam(lo, hi, r0, planes) -> np.ndarray:
    """(n,) bool: which boxes ``[lo[k], hi[k]]`` lie wholly outside one of the beam's
    ``planes`` (see :func:`beam_planes`), so that no ray of the beam meets what is inside them.

    Exact up to a relative margin of 1e-12 kept on the safe (not outside) side.
    """
    lo = np.asarray(lo, np.float64).reshape(-1, 3)
    hi = np.asarray(hi, np.float64).reshape(-1, 3)
    n, c = planes[:, :3], planes[:, 3]
    mid, half = (lo + hi) / 2 - r0, (hi - lo) / 2
    nearest = mid @ n.T - half @ np.abs(n).T            # min of n . (x - r0) over each box
    scale = (np.abs(mid) + half) @ np.abs(n).T + np.abs(c)
    return np.any(nearest - c > 1e-12 * scale, axis=1)


@dataclass(frozen=True, eq=False)
class Acquisition:
    """How bodies are imaged: the source and the detector (the thesis' camera and viewport).

    Cheap to build and to replace: nothing here depends on the meshes, so a new acquisition
    (the source moved, the next angle of an orbit) reuses every per-mesh set-up kept by the
    :class:`~xray_viz.bodies.Bodies` it images. Derived geometry (the frame, the viewport
    vectors, the beam's bounding planes) is computed once per acquisition.

    Parameters
    ----------
    source : Source
        :class:`xray_viz.scene.Source`.
    detector : Detector
        :class:`xray_viz.scene.Detector`.

    Raises
    ------
    SceneError
        If the source sits at the detector centre, the detector's ``up`` is parallel to the
        beam, or a tilted detector's plane is parallel to the beam or faces away from the
        source (:func:`tilted_normal`).

    Examples
    --------
    >>> import xray_viz
    >>> acq = xray_viz.load_scene("sphere").acquisition
    >>> acq.frame.sid, (acq.frame.forward + 0.0).tolist()
    (1500.0, [0.0, 0.0, -1.0])
    >>> turned = acq.rotated(90.0, axis=[0, 1, 0])          # the source orbits the origin
    >>> (turned.source.position.round(6) + 0.0).tolist()
    [1000.0, 0.0, 0.0]
    """

    source: object
    detector: object

    def __post_init__(self):
        self.frame                       # validates: the source off the detector, up across

    @cached_property
    def frame(self) -> DetectorFrame:
        """The :class:`DetectorFrame` (beam axis, detector axes, distance)."""
        det = self.detector
        r0 = np.asarray(self.source.position, np.float64)
        center = np.asarray(det.center, np.float64)
        sid = float(np.linalg.norm(r0 - center))
        tilted = det.u is not None
        offset = tuple(float(x) for x in det.offset)
        if tilted:
            forward = beam_direction(r0, center)
            ho, ve = np.asarray(det.u, np.float64), np.asarray(det.v, np.float64)
            normal = tilted_normal(r0, center, ho, ve)
            distance = float(normal @ (center - r0))
        else:
            forward, ho, ve = detector_axes(r0, center, det.up)
            normal, distance = forward, sid
        middle = center if offset == (0.0, 0.0) else center + offset[0] * ho + offset[1] * ve
        return DetectorFrame(source=r0, center=center, forward=forward, ho=ho, ve=ve, sid=sid,
                             parallel=self.source.kind == "parallel", shape=tuple(det.shape),
                             pitch=tuple(det.pitch), normal=normal, distance=distance,
                             offset=offset, middle=middle, tilted=tilted)

    @cached_property
    def viewport(self) -> Viewport:
        """The thesis' viewport vectors ``HO``, ``VE``, ``FL``, ``LHC`` (:func:`viewport`)."""
        return viewport(self.source.position, self.detector)

    @property
    def parallel(self) -> bool:
        """A parallel beam (rather than a point source)."""
        return self.frame.parallel

    @cached_property
    def pixel_distances(self) -> np.ndarray:
        """(H, W) float, read-only: each pixel ray's length from the source to the detector
        (mm, image order: the ``t_max`` of :func:`detector_rays` without supersampling, to
        rounding), computed once per acquisition.

        A pixel's offset from the grid's middle is ``a ho + b ve`` with ``ho`` perpendicular
        to ``ve``, so ``r^2 = |m|^2 + (a^2 + 2 a m.ho) + (b^2 + 2 b m.ve)`` (``m`` from the
        source to the middle): a sum of a column and a row term, two passes over the image
        instead of every pixel's 3-vector. A parallel beam's rays are all ``sid`` long.
        """
        f = self.frame
        w, h = f.shape
        if f.parallel:
            out = np.full((h, w), f.sid)
        else:
            width, height = self.detector.size
            ui = np.arange(w) / (w - 1) if w > 1 else np.array([0.5])
            vj = np.arange(h) / (h - 1) if h > 1 else np.array([0.5])
            a = (ui - 0.5) * width
            b = (vj[::-1] - 0.5) * height
            m = f.middle - f.source
            rows = float(m @ m) + b * (b + 2.0 * float(m @ f.ve))
            cols = a * (a + 2.0 * float(m @ f.ho))
            out = np.add(rows[:, None], cols[None, :])
            np.sqrt(out, out=out)
        out.setflags(write=False)
        return out

    def replace(self, **changes) -> "Acquisition":
        """A copy with ``source=`` and/or ``detector=`` replaced."""
        return Acquisition(source=changes.pop("source", self.source),
                           detector=changes.pop("detector", self.detector), **changes)

    def rays(self, *, supersample: int = 1, rows=None) -> Rays:
        """The detector's rays in image order (:func:`detector_rays`)."""
        return detector_rays(self, supersample=supersample, rows=rows)

    @property
    def half_widths(self) -> tuple[float, float]:
        """Half-widths (mm) of the detector's ray grid, any supersampling included, plus one
        pixel: a margin far above rounding and fixed-point snapping, so culling by them is
        conservative."""
        (w, h), (pu, pv) = self.detector.shape, self.detector.pitch
        return (w / 2 + 1) * pu, (h / 2 + 1) * pv

    @cached_property
    def planes(self) -> np.ndarray:
        """(6, 4) float: the planes bounding the beam of any supersampling, widened by a pixel
        (:func:`beam_planes`, :attr:`half_widths`)."""
        f = self.frame
        hu, hv = self.half_widths
        out = beam_planes(f.source, f.depth_axis, f.project_u, f.project_v, f.depth, hu, hv,
                          not f.parallel, principal=f.principal)
        out.setflags(write=False)
        return out

    def outside_beam(self, bounds) -> np.ndarray:
        """(n,) bool: which boxes ``bounds[k] = [lo, hi]`` lie wholly outside the beam (a side
        plane of the pyramid from a point source through the detector's edges, or of a
        parallel beam's slab box, widened by a pixel; behind the source plane; beyond the
        detector), so that no ray meets what is inside them."""
        bounds = np.asarray(bounds, np.float64).reshape(-1, 2, 3)
        return boxes_outside_beam(bounds[:, 0], bounds[:, 1], self.frame.source, self.planes)

    @cached_property
    def key(self) -> tuple:
        """Hashable: equal for acquisitions whose rays are the same (results may be shared)."""
        src, det = self.source, self.detector
        f = self.frame
        tilt = (tuple(f.offset), tuple(f.ho.tolist()), tuple(f.ve.tolist())) if not f.plain \
            else ()
        return (tuple(np.asarray(src.position, float).tolist()), src.kind,
                tuple(np.asarray(det.center, float).tolist()),
                tuple(np.asarray(det.up, float).tolist()), tuple(det.shape), tuple(det.pitch)
                ) + tilt

    def rotated(self, angle: float, *, axis=(0.0, 0.0, 1.0), center=(0.0, 0.0, 0.0)
                ) -> "Acquisition":
        """The source and the detector turned by ``angle`` degrees about an axis.

        The bodies stay where they are: this is one step of an orbit (a CT gantry), and
        the radiograph equals that of the bodies turned by ``-angle`` about the same axis.

        Parameters
        ----------
        angle : float
            Degrees, counter-clockwise seen from the tip of ``axis``.
        axis : (3,) float, optional
            Direction of the rotation axis.
        center : (3,) float, optional
            A point of the rotation axis (mm).

        Returns
        -------
        Acquisition
        """
        import dataclasses
        import math

        from xray_viz._checks import vector3

        a = vector3(axis, "rotation axis", direction=True)
        if isinstance(angle, bool) or not isinstance(angle, (int, float, np.number)) \
                or not math.isfinite(float(angle)):
            raise SceneError(f"rotation angle must be a finite number of degrees, got {angle!r}")
        from xray_viz._rotation import rotation

        c = np.asarray(center, np.float64).reshape(3)
        rot = rotation(a, float(angle))
        source = dataclasses.replace(self.source, position=c + rot @ (self.source.position - c))
        turned = {"u": rot @ self.detector.u, "v": rot @ self.detector.v} \
            if self.detector.u is not None else {}
        detector = dataclasses.replace(self.detector, center=c + rot @ (self.detector.center - c),
                                       up=rot @ self.detector.up, **turned)
        return Acquisition(source=source, detector=detector)

    def projection_matrix(self) -> np.ndarray:
        """(3, 4) float: the map of a point (mm, homogeneous) to its pixel on the detector.

        ``P @ [x, y, z, 1] = w * [i, j, 1]`` with ``i`` the image column (0 at the left) and
        ``j`` the row counted from the *bottom* (``j = H - 1 - row``), both in pixels; ``w > 0``
        is the depth along the detector's normal of a point in front of a point source. A
        point source's matrix is ``K [R | -R r0]`` with ``R`` the rows ``ho``, ``ve``,
        ``normal`` and ``K = [[D/pu, 0, cx + cu/pu], [0, D/pv, cy + cv/pv], [0, 0, 1]]``
        (``D`` the distance to the detector plane, ``(cu, cv)`` the principal point,
        :attr:`DetectorFrame.principal`, ``(cx, cy)`` the middle pixel): a tilted or offset
        detector is a general pinhole camera. A parallel beam's matrix is affine (last row
        ``[0, 0, 0, 1]``; oblique for a tilted detector).

        Examples
        --------
        >>> import numpy as np, xray_viz
        >>> acq = xray_viz.load_scene("sphere").acquisition        # 256 x 256, 1.0 mm at SID
        >>> p = acq.projection_matrix() @ [0.0, 0.0, 0.0, 1.0]     # the origin: the centre
        >>> (p[:2] / p[2]).tolist()
        [127.5, 127.5]
        """
        f = self.frame
        (w, h), (pu, pv) = f.shape, f.pitch
        cx, cy = (w - 1) / 2, (h - 1) / 2
        if f.parallel:
            eu, ev = f.project_u, f.project_v
            rows = [np.append(eu / pu, cx - eu @ f.middle / pu),
                    np.append(ev / pv, cy - ev @ f.middle / pv), [0.0, 0.0, 0.0, 1.0]]
            return np.array(rows, np.float64)
        cu, cv = f.principal
        n, d = f.normal, f.distance
        m = np.array([d / pu * f.ho + (cx + cu / pu) * n, d / pv * f.ve + (cy + cv / pv) * n, n])
        return np.hstack([m, -(m @ f.source)[:, None]])

    @classmethod
    def from_projection_matrix(cls, matrix, *, shape, pitch, parallel: bool = False,
                               sid: float | None = None, depth: float = 0.0, like
                               ) -> "Acquisition":
        """The acquisition whose :meth:`projection_matrix` is ``matrix`` (to a scale factor).

        A point source's matrix is a general pinhole camera, decomposed by an RQ
        factorisation (:func:`scipy.linalg.rq`) into the source, the detector plane (its
        normal and distance) and the principal point. A tilted detector and an untilted one
        through the foot of the perpendicular from the source, offset to the same pixels, have
        the same rays and the same matrix: the untilted, offset one is returned. A parallel
        beam's affine matrix gives the ray direction and the detector axes seen along it; of
        the two mirror-image tilts that project alike, the one with ``u . forward >= 0`` is
        returned (untilted when the axes are across the beam).

        Parameters
        ----------
        matrix : (3, 4) array_like
            Pixel coordinates as in :meth:`projection_matrix`.
        shape : (int, int)
            ``(W, H)`` pixels.
        pitch : (float, float)
            mm per pixel along the rows and columns; a point source's matrix then gives the
            source-to-detector distance.
        parallel : bool, optional
            A parallel beam (an affine matrix). Its matrix does not say where along the beam
            the source and the detector are: give ``sid`` (mm) and ``depth`` (``forward .
            detector centre``, mm; default 0).
        like : Acquisition
            Gives the source's and the detector's other fields (energy, spectrum, ``I0``,
            noise, ...); its position, centre, up, axes, offset, shape and pitch are replaced.

        Raises
        ------
        SceneError
            A matrix that is not finite or not of this form: skewed pixel axes or different
            distances along the two axes at the given pitch (a non-square or skewed pixel grid
            is not supported yet).

        Examples
        --------
        >>> import numpy as np, xray_viz
        >>> acq = xray_viz.load_scene("sphere").acquisition.rotated(30.0, axis=[0, 1, 0])
        >>> back = Acquisition.from_projection_matrix(3.0 * acq.projection_matrix(),
        ...     shape=(256, 256), pitch=(1.0, 1.0), like=acq)
        >>> bool(np.allclose(back.frame.source, acq.frame.source, atol=1e-9))
        True
        """
        import dataclasses

        p = np.array(matrix, dtype=np.float64)
        if p.shape != (3, 4) or not np.all(np.isfinite(p)):
            raise SceneError(f"a projection matrix must be 3 x 4 finite numbers, got shape "
                             f"{p.shape}")
        w, h = (int(s) for s in shape)
        pu, pv = (float(s) for s in pitch)
        cx, cy = (w - 1) / 2, (h - 1) / 2
        tol = 1e-9

        def refuse(what):
            raise SceneError(f"projection matrix: {what} (skewed or non-square pixel grids are "
                             "not supported yet)")

        u = v = None
        offset = (0.0, 0.0)
        if parallel:
            if not abs(p[2, 3]) > 0 or np.any(p[2, :3] != 0):
                refuse("a parallel beam's matrix has the last row [0, 0, 0, 1]")
            if sid is None:
                raise SceneError("from_projection_matrix: a parallel beam needs sid= (mm)")
            p = p / p[2, 3]
            eu, ev = p[0, :3] * pu, p[1, :3] * pv            # the projection's linear parts
            forward = np.cross(ev, eu)
            if not np.linalg.norm(forward) > 0:
                refuse("its pixel axes are parallel")
            forward /= np.linalg.norm(forward)
            # The axes seen along the beam (the dual basis of eu, ev across it) ...
            g = np.linalg.inv(np.array([eu, ev, forward]))
            u0, v0 = g[:, 0], g[:, 1]
            # ... lifted along the beam to unit, perpendicular detector axes.
            # (the tilt is known to ~1e-8 rad only: 1 - |u0|^2 is its square; below 1e-12,
            # untilted)
            def lift(a0):
                a2 = 1.0 - float(a0 @ a0)
                return math.sqrt(a2) if a2 > 1e-12 else 0.0

            alpha = lift(u0)
            beta = -float(u0 @ v0) / alpha if alpha > 0 else lift(v0)
            ho, ve = u0 + alpha * forward, v0 + beta * forward
            if abs(np.linalg.norm(ho) - 1) > tol or abs(np.linalg.norm(ve) - 1) > tol \
                    or abs(ho @ ve) > tol:
                refuse("its pixel axes are not those of a detector of this pitch")
            center = u0 * (cx - p[0, 3]) * pu + v0 * (cy - p[1, 3]) * pv + forward * depth
            position = center - float(sid) * forward
            if alpha > 0 or abs(beta) > 0:
                u, v = ho, ve
        else:
            import scipy.linalg

            p = p / np.linalg.norm(p[2, :3])
            if np.linalg.det(p[:, :3]) > 0:
                p = -p
            m = p[:, :3]
            position = -np.linalg.solve(m, p[:, 3])
            k, q = scipy.linalg.rq(m)
            signs = np.sign(np.diag(k))
            if np.any(signs == 0):
                refuse("it is singular")
            k, q = k * signs, signs[:, None] * q              # K with a positive diagonal
            k = k / k[2, 2]
            ho, ve, forward = q
            if abs(k[0, 1]) > tol * k[0, 0]:
                refuse("its pixel axes are skewed")
            if abs(k[0, 0] * pu - k[1, 1] * pv) > tol * k[0, 0] * pu:
                refuse("the pitch gives different source-to-detector distances along u and v")
            distance = k[0, 0] * pu
            center = position + distance * forward            # the foot of the perpendicular
            du, dv = (cx - k[0, 2]) * pu, (cy - k[1, 2]) * pv
            offset = tuple(0.0 if abs(x) <= tol * max(1.0, distance) else float(x)
                           for x in (du, dv))
        source = dataclasses.replace(like.source, position=position,
                                     kind="parallel" if parallel else "point")
        detector = dataclasses.replace(like.detector, center=center, up=ve, shape=(w, h),
                                       pitch=(pu, pv), u=u, v=v, offset=offset)
        return cls(source=source, detector=detector)

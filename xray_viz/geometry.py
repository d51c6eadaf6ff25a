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

Rays are returned in *image order*: ray ``k = row * W + col`` with ``col = i`` and
``row = H - 1 - j``, so that ``array.reshape(H, W)`` is an image whose row 0 is the top (v = 1)
and column 0 the left (u = 0).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["Acquisition", "DetectorFrame", "FineGrid", "Viewport", "viewport", "detector_axes",
           "beam_direction", "pixel_coordinates", "detector_rays", "Rays", "check_supersample",
           "beam_planes", "boxes_outside_beam", "row_range", "UP_TOLERANCE"]

#: ``up`` is refused as parallel to the beam when ``|forward x unit(up)|`` is below this (the
#: sine of the angle between them): ``unit(forward x up)`` would lose most of its digits.
UP_TOLERANCE = 1e-9


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
        """Unit normal of the detector plane, pointing away from the source (= forward)."""
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
    vp = acq.viewport if acq is not None else viewport(scene.source.position, scene.detector)
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
    if scene.source.kind == "parallel":
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
    right, y up) at ``center + p00 + x * ex + y * ey``; a point ``(a, b)`` mm from the detector
    centre along ``ho``, ``ve`` has fine coordinates ``(a * sx + bx, b * sy + by)``.

    Attributes
    ----------
    n : int
        Rays per pixel along each axis.
    sx, sy : float
        Fine samples per mm along ``ho`` and ``ve``.
    bx, by : float
        Fine coordinates of the detector centre.
    ex, ey : (3,) float
        One fine step along ``ho`` and ``ve`` (mm vectors).
    p00 : (3,) float
        Offset of fine sample ``(0, 0)`` from the detector centre (mm).
    """

    n: int
    sx: float
    sy: float
    bx: float
    by: float
    ex: np.ndarray
    ey: np.ndarray
    p00: np.ndarray


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
        Unit beam axis, from the source to the detector centre (``unit(-FL)``).
    ho, ve : (3,) float
        Unit vectors along the detector's rows (left to right, ``unit(HO)``) and columns
        (bottom to top, ``unit(VE)``).
    sid : float
        Source-to-detector distance along the axis, ``|FL|`` (mm).
    parallel : bool
        A parallel beam (every ray along ``forward``) rather than a point source.
    shape : (int, int)
        ``(W, H)`` rays.
    pitch : (float, float)
        mm between neighbouring rays along ``ho`` and ``ve``.
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

    def grid(self, n: int = 1) -> FineGrid:
        """The ``n x n`` supersampled ray grid in this frame (:class:`FineGrid`)."""
        n = check_supersample(n)
        (w, h), (px, py) = self.shape, self.pitch
        bx = n * (w - 1) / 2 + (n - 1) / 2
        by = n * (h - 1) / 2 + (n - 1) / 2
        ex, ey = (px / n) * self.ho, (py / n) * self.ve
        return FineGrid(n=n, sx=n / px, sy=n / py, bx=bx, by=by, ex=ex, ey=ey,
                        p00=-bx * ex - by * ey)


def beam_planes(r0, forward, eu, ev, FL, half_u, half_v, perspective) -> np.ndarray:
    """Planes bounding the beam: every ray point ``x`` has ``n . (x - r0) <= c`` for each row
    ``(nx, ny, nz, c)`` of the result.

    Rows 0-3 are the side planes (through the source for a point source: the pyramid from the
    source through the detector rectangle of half-widths ``half_u``, ``half_v`` mm along ``eu``
    and ``ev``; the slab box of a parallel beam), row 4 the source plane (nothing behind it),
    row 5 the detector plane (rays end there, ``FL`` from the source).
    """
    f = np.asarray(forward, np.float64)
    eu = np.asarray(eu, np.float64)
    ev = np.asarray(ev, np.float64)
    rows = []
    for e, h in ((eu, half_u), (ev, half_v)):
        for s in (1.0, -1.0):
            if perspective:
                rows.append(np.append(s * FL * e - h * f, 0.0))   # |a| FL <= h w
            else:
                rows.append(np.append(s * e, h))                  # |a| <= h
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
        If the source sits at the detector centre or the detector's ``up`` is parallel to the
        beam.

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
        r0 = np.asarray(self.source.position, np.float64)
        center = np.asarray(self.detector.center, np.float64)
        forward, ho, ve = detector_axes(r0, center, self.detector.up)
        return DetectorFrame(source=r0, center=center, forward=forward, ho=ho, ve=ve,
                             sid=float(np.linalg.norm(r0 - center)),
                             parallel=self.source.kind == "parallel",
                             shape=tuple(self.detector.shape), pitch=tuple(self.detector.pitch))

    @cached_property
    def viewport(self) -> Viewport:
        """The thesis' viewport vectors ``HO``, ``VE``, ``FL``, ``LHC`` (:func:`viewport`)."""
        return viewport(self.source.position, self.detector)

    @property
    def parallel(self) -> bool:
        """A parallel beam (rather than a point source)."""
        return self.frame.parallel

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
        out = beam_planes(f.source, f.forward, f.ho, f.ve, f.sid, hu, hv, not f.parallel)
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
        return (tuple(np.asarray(src.position, float).tolist()), src.kind,
                tuple(np.asarray(det.center, float).tolist()),
                tuple(np.asarray(det.up, float).tolist()), tuple(det.shape), tuple(det.pitch))

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

        a = np.asarray(axis, np.float64).reshape(-1)
        if a.shape != (3,) or not np.all(np.isfinite(a)) or not np.linalg.norm(a) > 0:
            raise SceneError(f"rotation axis must be 3 finite numbers, not all 0; got {axis!r}")
        if isinstance(angle, bool) or not isinstance(angle, (int, float, np.number)) \
                or not math.isfinite(float(angle)):
            raise SceneError(f"rotation angle must be a finite number of degrees, got {angle!r}")
        c = np.asarray(center, np.float64).reshape(3)
        a = a / np.linalg.norm(a)
        t = math.radians(float(angle))
        k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
        rot = np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * (k @ k)     # Rodrigues
        source = dataclasses.replace(self.source, position=c + rot @ (self.source.position - c))
        detector = dataclasses.replace(self.detector, center=c + rot @ (self.detector.center - c),
                                       up=rot @ self.detector.up)
        return Acquisition(source=source, detector=detector)

    def projection_matrix(self) -> np.ndarray:
        """(3, 4) float: the map of a point (mm, homogeneous) to its pixel on the detector.

        ``P @ [x, y, z, 1] = w * [i, j, 1]`` with ``i`` the image column (0 at the left) and
        ``j`` the row counted from the *bottom* (``j = H - 1 - row``), both in pixels; ``w > 0``
        is the depth along the beam of a point in front of a point source. A parallel beam's
        matrix is affine (last row ``[0, 0, 0, 1]``).

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
            rows = [np.append(f.ho / pu, cx - f.ho @ f.center / pu),
                    np.append(f.ve / pv, cy - f.ve @ f.center / pv), [0.0, 0.0, 0.0, 1.0]]
            return np.array(rows, np.float64)
        m = np.array([f.sid / pu * f.ho + cx * f.forward, f.sid / pv * f.ve + cy * f.forward,
                      f.forward])
        return np.hstack([m, -(m @ f.source)[:, None]])

    @classmethod
    def from_projection_matrix(cls, matrix, *, shape, pitch, parallel: bool = False,
                               sid: float | None = None, depth: float = 0.0, like
                               ) -> "Acquisition":
        """The acquisition whose :meth:`projection_matrix` is ``matrix`` (to a scale factor).

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
            noise, ...); its position, centre, up, shape and pitch are replaced.

        Raises
        ------
        SceneError
            A matrix that is not finite or not of this form: skewed or mirrored pixel axes,
            a principal point off the detector centre (an offset detector) or different
            distances along the two axes (tilted detectors and offsets are not supported yet).

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
            raise SceneError(f"projection matrix: {what} (tilted or offset detectors are not "
                             "supported yet)")

        if parallel:
            if not abs(p[2, 3]) > 0 or np.any(p[2, :3] != 0):
                refuse("a parallel beam's matrix has the last row [0, 0, 0, 1]")
            if sid is None:
                raise SceneError("from_projection_matrix: a parallel beam needs sid= (mm)")
            p = p / p[2, 3]
            ho, ve = p[0, :3] * pu, p[1, :3] * pv
            if abs(np.linalg.norm(ho) - 1) > tol or abs(np.linalg.norm(ve) - 1) > tol \
                    or abs(ho @ ve) > tol:
                refuse("its pixel axes are not orthogonal at the given pitch")
            forward = np.cross(ve, ho)
            center = ho * (cx - p[0, 3]) * pu + ve * (cy - p[1, 3]) * pv + forward * depth
            position = center - float(sid) * forward
        else:
            p = p / np.linalg.norm(p[2, :3])
            if np.linalg.det(p[:, :3]) > 0:
                p = -p
            m = p[:, :3]
            forward = m[2]
            position = -np.linalg.solve(m, p[:, 3])
            pcx, pcy = m[0] @ forward, m[1] @ forward
            hs, vs = m[0] - pcx * forward, m[1] - pcy * forward
            ku, kv = np.linalg.norm(hs), np.linalg.norm(vs)
            ho, ve = hs / ku, vs / kv
            if abs(ho @ ve) > tol or not np.allclose(np.cross(ho, forward), ve, atol=tol):
                refuse("its pixel axes are skewed or mirrored")
            if abs(pcx - cx) > tol * max(1.0, cx) or abs(pcy - cy) > tol * max(1.0, cy):
                refuse(f"its principal point ({pcx:.6g}, {pcy:.6g}) is not the detector centre "
                       f"({cx:g}, {cy:g})")
            if abs(ku * pu - kv * pv) > tol * ku * pu:
                refuse("the pitch gives different source-to-detector distances along u and v")
            center = position + ku * pu * forward
        source = dataclasses.replace(like.source, position=position,
                                     kind="parallel" if parallel else "point")
        detector = dataclasses.replace(like.detector, center=center, up=ve, shape=(w, h),
                                       pitch=(pu, pv))
        return cls(source=source, detector=detector)

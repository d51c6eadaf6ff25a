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

import numpy as np

__all__ = ["Viewport", "viewport", "detector_axes", "beam_direction", "pixel_coordinates",
           "detector_rays", "Rays", "check_supersample"]


def beam_direction(source_position, detector_center) -> np.ndarray:
    """Unit vector from the source to the detector centre (``unit(-FL)``)."""
    fl = np.asarray(source_position, float) - np.asarray(detector_center, float)
    norm = np.linalg.norm(fl)
    if norm == 0:
        from xray_viz.errors import SceneError

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
        When the source sits at the detector centre or ``up`` is parallel to the beam.
    """
    forward = beam_direction(source_position, detector_center)
    up = np.asarray(up, dtype=np.float64)
    ho_dir = np.cross(forward, up)
    norm = np.linalg.norm(ho_dir)
    if norm < 1e-12 * np.linalg.norm(up):
        from xray_viz.errors import SceneError

        raise SceneError(f"[detector] up {up.tolist()} is parallel to the beam")
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
        from xray_viz.errors import SceneError

        raise SceneError(f"{name} must be a whole number >= 1 (an int), got {value!r} "
                         f"({type(value).__name__})")
    return int(value)


def row_range(rows, h):
    """``(start, stop)`` of a range of image rows given as None, (start, stop), range or slice."""
    if rows is None:
        return 0, h
    if isinstance(rows, slice):
        if rows.step not in (None, 1):
            raise ValueError(f"rows must be a contiguous range of image rows, got {rows!r}")
        start, stop, _ = rows.indices(h)
    elif isinstance(rows, range):
        if rows.step != 1:
            raise ValueError(f"rows must be a contiguous range of image rows, got {rows!r}")
        start, stop = rows.start, rows.stop
    else:
        start, stop = (int(r) for r in rows)
    if not 0 <= start <= stop <= h:
        raise ValueError(f"rows {start}..{stop} are not within the detector's {h} rows")
    return start, stop


def detector_rays(scene, *, supersample: int = 1, rows=None) -> Rays:
    """The rays of a scene's detector grid, in image order.

    Parameters
    ----------
    scene : Scene
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
    vp = viewport(scene.source.position, scene.detector)
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

"""Camera framing of the scene view, in NumPy alone (no VTK, no PyVista).

The 3D pane of :class:`~xray_viz.viz.SceneView` is pinned to one of two views, computed here
from the thesis' viewport vectors and the bodies' bounding box:

* :func:`side_view` - the whole set-up in a three-quarter view, source on the left, detector on
  the right with its face turned towards the viewer;
* :func:`bodies_view` - a close-up of the bodies from behind and beside the source, looking
  down the beam at their shadow on the detector;

and the radiograph pane to :func:`image_view` (a parallel projection of the image, centred in
its box). Each returns a :class:`Framing`: the camera position, focal point and view-up, the
perspective view angle or the parallel scale, and VTK's *window centre* (the shift of the
projection that puts the focal point at the centre of a box of the pane rather than of the
pane). :meth:`Framing.project` maps points to the pane as VTK's camera does, so what a framing
shows can be checked without a render window.

The general step is :func:`frame`: aim a perspective camera along a direction so that a set of
points fills a box of the pane, with a margin, centred.

Examples
--------
>>> import numpy as np
>>> from xray_viz.viz.camera import frame
>>> cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
>>> f = frame(cube, [0, 0, -1], [0, 1, 0], view_angle=30.0, aspect=1.0, margin=1.25)
>>> f.direction.tolist(), f.up.tolist()
([0.0, 0.0, -1.0], [0.0, 1.0, 0.0])
>>> xy = f.project(cube, aspect=1.0)                       # fractions of the pane
>>> bool(np.all((xy > 0) & (xy < 1)))
True
>>> round(float(np.abs(2 * xy - 1).max()), 6)              # the nearest corners touch 1 / margin
0.8
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["Framing", "frame", "side_view", "bodies_view", "image_view", "view_axes",
           "screen_axes", "scene_scale", "best_elevation", "side_points", "box_corners",
           "label_fraction", "SIDE_VIEW_BOX", "FULL_PANE"]

#: The box of the pane (left, bottom, right, top fractions) that the side view fills by default.
SIDE_VIEW_BOX = (0.02, 0.06, 0.98, 0.8)

#: The whole pane, as a box.
FULL_PANE = (0.0, 0.0, 1.0, 1.0)


@dataclass(frozen=True)
class Framing:
    """Where a camera is and what it sees: what :func:`frame` and the views compute.

    Attributes
    ----------
    position, focal_point : (3,) float
        The camera and the point it looks at (scene coordinates, mm).
    up : (3,) float
        Unit view-up, perpendicular to the line of sight.
    view_angle : float or None
        Vertical view angle in degrees of a perspective camera; None for a parallel one.
    parallel_scale : float or None
        Half the height of the view of a parallel camera (scene units); None in perspective.
    window_center : (float, float)
        VTK's window centre: the focal point appears at pane fraction
        ``((1 - window_center[0]) / 2, (1 - window_center[1]) / 2)``.
    box : (float, float, float, float)
        The box of the pane (left, bottom, right, top fractions) that was filled.
    elevation : float or None
        Degrees from above of the line of sight, when a view chose it (:func:`side_view`).
    """

    position: np.ndarray
    focal_point: np.ndarray
    up: np.ndarray
    view_angle: float | None = None
    parallel_scale: float | None = None
    window_center: tuple = (0.0, 0.0)
    box: tuple = FULL_PANE
    elevation: float | None = None

    @property
    def parallel(self) -> bool:
        """Whether the projection is parallel (else perspective)."""
        return self.view_angle is None

    @property
    def distance(self) -> float:
        """Distance from the camera to the focal point."""
        return float(np.linalg.norm(np.subtract(self.focal_point, self.position)))

    @property
    def direction(self) -> np.ndarray:
        """Unit line of sight, from the camera towards the focal point."""
        d = np.subtract(self.focal_point, self.position)
        return d / np.linalg.norm(d)

    @property
    def right(self) -> np.ndarray:
        """Unit screen right: ``direction x up``."""
        r = np.cross(self.direction, self.up)
        return r / np.linalg.norm(r)

    def project(self, points, *, aspect: float) -> np.ndarray:
        """Positions of 3D points in the pane, as fractions (0 to 1 across, 0 to 1 up).

        The projection of a VTK camera with this position, focal point, view-up, view angle
        (or parallel scale) and window centre, in a pane ``aspect`` times as wide as high.
        Points behind a perspective camera get NaN.

        Parameters
        ----------
        points : (n, 3) float
        aspect : float
            Width / height of the pane.

        Returns
        -------
        (n, 2) float
        """
        rel = np.asarray(points, float).reshape(-1, 3) - np.asarray(self.position, float)
        x, y, depth = rel @ self.right, rel @ np.asarray(self.up, float), rel @ self.direction
        if self.parallel:
            half = float(self.parallel_scale)
            nx, ny = x / (half * aspect), y / half
        else:
            half = math.tan(math.radians(self.view_angle) / 2)
            with np.errstate(divide="ignore", invalid="ignore"):
                nx, ny = x / depth / (half * aspect), y / depth / half
            nx = np.where(depth > 0, nx, np.nan)
            ny = np.where(depth > 0, ny, np.nan)
        wx, wy = self.window_center
        return np.column_stack([(nx - wx + 1) / 2, (ny - wy + 1) / 2])


def _unit(v) -> np.ndarray:
    v = np.asarray(v, float)
    return v / np.linalg.norm(v)


def view_axes(viewport) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit vectors ``forward`` (source to detector), ``up`` (the detector's VE, made
    perpendicular to ``forward``) and ``side`` (``up x forward``, the direction a side view
    looks along).

    Parameters
    ----------
    viewport : Viewport
        From :func:`xray_viz.geometry.viewport`.

    Examples
    --------
    >>> from xray_viz.geometry import Viewport
    >>> import numpy as np
    >>> vp = Viewport(r0=np.array([0, 0, 1000.]), HO=np.array([100., 0, 0]),
    ...               VE=np.array([0, 100., 0]), FL=np.array([0, 0, 1500.]),
    ...               LHC=np.array([-50., -50, -500]), shape=(8, 8))
    >>> [a.tolist() for a in view_axes(vp)]
    [[-0.0, -0.0, -1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]]
    """
    forward = -np.asarray(viewport.FL, float) / np.linalg.norm(viewport.FL)
    up = np.asarray(viewport.VE, float) / np.linalg.norm(viewport.VE)
    up = up - up.dot(forward) * forward
    up /= np.linalg.norm(up)
    return forward, up, np.cross(up, forward)


def screen_axes(direction, up) -> tuple[np.ndarray, np.ndarray]:
    """``(right, screen_up)`` of a camera looking along ``direction`` with ``up`` roughly up:
    ``right = unit(direction x up)``, ``screen_up = right x direction``.

    Examples
    --------
    >>> [(a + 0.0).tolist() for a in screen_axes([0, 0, -1.0], [0, 1.0, 0])]
    [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]
    """
    direction = np.asarray(direction, float)
    right = np.cross(direction, np.asarray(up, float))
    right /= np.linalg.norm(right)
    return right, np.cross(right, direction)


def scene_scale(viewport) -> float:
    """A length (mm) that sets marker and arrow-tip sizes: 1/40 of the set-up's extent
    (the largest of ``|FL|``, ``|HO|``, ``|VE|``).

    Examples
    --------
    >>> from xray_viz.geometry import Viewport
    >>> import numpy as np
    >>> vp = Viewport(r0=np.zeros(3), HO=np.array([100., 0, 0]), VE=np.array([0, 50., 0]),
    ...               FL=np.array([0, 0, 1000.]), LHC=np.zeros(3), shape=(4, 2))
    >>> scene_scale(vp)
    25.0
    """
    vp = viewport
    return float(max(np.linalg.norm(vp.FL), np.linalg.norm(vp.HO), np.linalg.norm(vp.VE)) / 40)


def box_corners(lo, hi) -> np.ndarray:
    """The eight corners of the axis-aligned box ``[lo, hi]``, ``(8, 3)``.

    Examples
    --------
    >>> box_corners([0, 0, 0], [1, 2, 3])[[0, -1]].tolist()
    [[0.0, 0.0, 0.0], [1.0, 2.0, 3.0]]
    """
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                     for z in (lo[2], hi[2])])


def _detector_corners(vp) -> np.ndarray:
    return np.array([vp.LHC, vp.LHC + vp.HO, vp.LHC + vp.VE, vp.LHC + vp.HO + vp.VE])


def side_points(viewport, bounds, *, source_radius=None) -> np.ndarray:
    """The points the side view keeps in the picture: the detector's four corners, the eight
    corners of the bodies' box and six points around the source, ``source_radius`` from it
    (default ``0.6 *`` :func:`scene_scale`, a little more than the source marker).

    Parameters
    ----------
    viewport : Viewport
    bounds : ((3,) float, (3,) float)
        ``(lo, hi)`` of the bodies.
    source_radius : float, optional

    Returns
    -------
    (18, 3) float
    """
    vp = viewport
    lo, hi = bounds
    r0 = np.asarray(vp.r0, float)
    radius = 0.6 * scene_scale(vp) if source_radius is None else float(source_radius)
    source = r0 + radius * np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0],
                                     [0, -1, 0], [0, 0, 1], [0, 0, -1]])
    return np.vstack([_detector_corners(vp), box_corners(lo, hi), source])


def _side_axes(forward, up, side, azimuth, elevation):
    e, a = math.radians(elevation), math.radians(azimuth)
    dop = math.cos(e) * (math.cos(a) * side + math.sin(a) * forward) - math.sin(e) * up
    right, screen_up = screen_axes(dop, up)
    return dop, right, screen_up


def best_elevation(points, axes, *, azimuth: float, aspect: float, box=SIDE_VIEW_BOX,
                   elevations=range(4, 33, 2)) -> float:
    """The elevation (degrees) of the side view whose picture of ``points`` fills ``box`` best.

    The elevation tilts the beam on screen without narrowing it (its width is set by the
    azimuth), so the picture's shape (the points' extents on screen, nearly a parallel
    projection) is matched to the box's: low in a wide box (the beam across it), higher in a
    squarer one (the beam rising along its diagonal). Of equally good ones, the lowest.

    Parameters
    ----------
    points : (n, 3) float
    axes : (forward, up, side)
        From :func:`view_axes`.
    azimuth : float
        Degrees, as in :func:`side_view`.
    aspect : float
        Width / height of the pane.
    box : (float, float, float, float)
        Left, bottom, right, top fractions of the pane.
    elevations : iterable of float
        The candidates.

    Returns
    -------
    float
    """
    forward, up, side = axes
    points = np.asarray(points, float)
    bx0, by0, bx1, by1 = box
    w, h = aspect * (bx1 - bx0), by1 - by0

    def filled(elev):
        _, right, screen_up = _side_axes(forward, up, side, azimuth, elev)
        ex = max(np.ptp(points @ right), 1e-12)
        ey = max(np.ptp(points @ screen_up), 1e-12)
        s = min(w / ex, h / ey)
        return round(s * s * ex * ey / (w * h), 3)

    return max(elevations, key=lambda e: (filled(e), -e))


def frame(points, direction, up, *, view_angle: float, aspect: float, box=FULL_PANE,
          margin: float = 1.06, min_distance: float = 0.0, anchor=None) -> Framing:
    """Aim a perspective camera along ``direction`` so that ``points`` fill ``box``, centred.

    The camera's distance is the smallest at which every point is inside the box shrunk by
    ``margin`` (a point's offset from the box centre, over the box's half-size, is at most
    ``1 / margin`` across and up); then the focal point moves to the middle of the points'
    angular extent, and both steps repeat (12 times) until the picture is centred.

    Parameters
    ----------
    points : (n, 3) float
    direction : (3,) float
        Unit line of sight, camera towards the scene.
    up : (3,) float
        Roughly up on screen (made perpendicular to ``direction``).
    view_angle : float
        Vertical view angle of the camera, degrees.
    aspect : float
        Width / height of the pane in pixels.
    box : (float, float, float, float)
        Left, bottom, right, top of the box to fill, fractions of the pane.
    margin : float
        Above 1 leaves room around the points; below 1 lets them overflow (a zoom).
    min_distance : float
        A floor for the camera's distance: it narrows its view angle instead of coming
        closer (see Notes).
    anchor : (3,) float, optional
        Default: the points' mean.

    Returns
    -------
    Framing

    Notes
    -----
    The floor is on the distance from the camera to the focal point (the points' centre,
    ``c``): at least ``min_distance + (anchor - c) . direction``. That keeps the camera
    ``min_distance`` from ``anchor`` along the line of sight when ``anchor`` is in the focal
    plane. An anchor nearer the camera than ``c`` (the bodies' centre in front of the
    detector, in :func:`bodies_view`) brings the camera closer than ``min_distance`` to it, by
    twice ``(c - anchor) . direction``: the sign the scene view was tuned with, kept so that
    its pictures stay as they are.
    """
    points = np.asarray(points, float)
    dop = np.asarray(direction, float)
    right, screen_up = screen_axes(dop, up)
    bx0, by0, bx1, by1 = box
    window_center = (1.0 - bx0 - bx1, 1.0 - by0 - by1)   # focal point at the box centre
    sx = aspect * (bx1 - bx0)                   # the box's half-width / half-height,
    sy = by1 - by0                              # in units of the view's half-height
    view_angle = float(view_angle)
    half_v = math.tan(math.radians(view_angle) / 2) / margin
    focal = points.mean(axis=0)
    anchor = focal if anchor is None else np.asarray(anchor, float)
    for _ in range(12):
        rel = points - focal
        x, y, depth = rel @ right, rel @ screen_up, rel @ dop
        need = np.maximum(np.abs(x) / (half_v * sx), np.abs(y) / (half_v * sy))
        distance = float(np.max(need - depth))
        floor = min_distance + float((anchor - focal) @ dop)
        if distance < floor:                    # too close: step back, narrow the view
            distance = floor
            tx, ty = x / (distance + depth), y / (distance + depth)
            half_v = max((tx.max() - tx.min()) / 2 / sx, (ty.max() - ty.min()) / 2 / sy)
            view_angle = math.degrees(2 * math.atan(half_v * margin))
        # re-centre: shift the focal point to the middle of the points' angular extent
        tx, ty = x / (distance + depth), y / (distance + depth)
        focal = focal + distance * ((tx.max() + tx.min()) / 2 * right
                                    + (ty.max() + ty.min()) / 2 * screen_up)
    return Framing(position=focal - distance * dop, focal_point=focal, up=screen_up,
                   view_angle=view_angle, window_center=window_center,
                   box=(bx0, by0, bx1, by1))


def side_view(viewport, bounds, *, aspect: float, box=SIDE_VIEW_BOX, azimuth: float = 60.0,
              elevation: float | None = None, view_angle: float = 12.0, zoom: float = 1.0,
              source_radius=None) -> Framing:
    """The whole set-up in a three-quarter view that fills ``box``: the source on the left,
    the detector on the right with its face (the pixel grid, HO and VE) turned towards the
    viewer, the bodies between them.

    Parameters
    ----------
    viewport : Viewport
    bounds : ((3,) float, (3,) float)
        ``(lo, hi)`` of the bodies.
    aspect : float
        Width / height of the pane.
    box : (float, float, float, float)
        Left, bottom, right, top fractions of the pane to fill.
    azimuth : float
        Degrees the line of sight turns from the side axis (``up x forward``, a view across
        the beam that sees the detector edge-on) towards the beam direction: 0 is a pure side
        view, 90 looks down the beam from behind the source.
    elevation : float, optional
        Degrees from above (the detector's ``up`` stays screen up); by default
        :func:`best_elevation`.
    view_angle : float
        Of the perspective camera, degrees; small is nearly a parallel projection.
    zoom : float
        Above 1 the picture grows beyond the box (the margin 1.04 is divided by it).
    source_radius : float, optional
        See :func:`side_points`.

    Returns
    -------
    Framing
        With ``elevation`` set.
    """
    axes = view_axes(viewport)
    forward, up, side = axes
    points = side_points(viewport, bounds, source_radius=source_radius)
    if elevation is None:
        elevation = best_elevation(points, axes, azimuth=azimuth, aspect=aspect, box=box)
    dop, _, _ = _side_axes(forward, up, side, azimuth, elevation)
    f = frame(points, dop, up, view_angle=view_angle, aspect=aspect, box=box,
              margin=1.04 / zoom)
    return _with(f, elevation=float(elevation))


def _with(framing: Framing, **changes) -> Framing:
    from dataclasses import replace

    return replace(framing, **changes)


def bodies_view(viewport, bounds, *, aspect: float, box=SIDE_VIEW_BOX, zoom: float = 1.0,
                azimuth: float = -14.0, elevation: float = 4.0,
                view_angle: float = 30.0) -> Framing:
    """Close-up of the bodies from the source's side, looking down the beam: the bodies in
    front, the detector behind them, all in ``box``.

    The camera is held back (:func:`frame` with ``min_distance`` 1.15 times the source's
    distance from the bodies' centre along the line of sight, anchored at that centre) and
    narrows its view angle instead of coming closer; as :func:`frame`'s Notes say, the floor
    is measured from the framed points' centre, which lies beyond the bodies (towards the
    detector), so the camera ends up nearer than the source on a long beam.

    Parameters
    ----------
    viewport : Viewport
    bounds : ((3,) float, (3,) float)
        ``(lo, hi)`` of the bodies.
    aspect : float
        Width / height of the pane.
    box : (float, float, float, float)
        Left, bottom, right, top fractions of the pane to fill.
    zoom : float
        Divides the margin 1.06.
    azimuth, elevation : float
        Degrees the line of sight turns away from the beam axis, to the side and from above,
        so the bodies do not hide their shadow.
    view_angle : float
        Of the perspective camera, degrees, before any narrowing.

    Returns
    -------
    Framing
    """
    vp = viewport
    forward, up, side = view_axes(vp)
    lo, hi = (np.asarray(b, float) for b in bounds)
    points = np.vstack([_detector_corners(vp), box_corners(lo, hi)])
    a, e = math.radians(azimuth), math.radians(elevation)
    dop = (math.cos(e) * (math.cos(a) * forward + math.sin(a) * side)
           - math.sin(e) * up)                       # camera -> focal point
    # the camera held back (1.15 times as far from the bodies as the source; see frame())
    behind = float((np.asarray(vp.r0) - (lo + hi) / 2) @ -dop) * 1.15
    return frame(points, dop, up, view_angle=view_angle, aspect=aspect, box=box,
                 margin=1.06 / zoom, min_distance=behind, anchor=(lo + hi) / 2)


def image_view(shape, *, aspect: float, box) -> Framing:
    """Parallel camera of the radiograph pane: an ``(H, W)`` image, its pixel ``(i, j)`` at
    ``(x, y) = (i, j)`` (:func:`~xray_viz.viz.scene_view.image_to_grid`), centred in ``box``
    and as large as fits, seen from +z with +y up.

    Parameters
    ----------
    shape : (int, int)
        ``(H, W)``.
    aspect : float
        Width / height of the pane.
    box : (float, float, float, float)
        Left, bottom, right, top fractions of the pane.

    Returns
    -------
    Framing

    Examples
    --------
    >>> f = image_view((100, 200), aspect=2.0, box=(0.0, 0.0, 1.0, 1.0))
    >>> f.focal_point.tolist(), f.parallel_scale
    ([99.5, 49.5, 0.0], 50.0)
    """
    h, w = shape
    x0, y0, x1, y1 = box
    scale = 0.5 * max(h / (y1 - y0), w / ((x1 - x0) * aspect))     # half the view height
    cx = (w - 1) / 2 - ((x0 + x1) / 2 - 0.5) * 2 * scale * aspect
    cy = (h - 1) / 2 - ((y0 + y1) / 2 - 0.5) * 2 * scale
    return Framing(position=np.array([cx, cy, 10.0 * max(w, h)]),
                   focal_point=np.array([cx, cy, 0.0]), up=np.array([0.0, 1.0, 0.0]),
                   parallel_scale=scale, box=(x0, y0, x1, y1))


def label_fraction(xy, fractions, at: float, boxes) -> float:
    """Where along an arrow to put its label: ``at`` (a fraction from its start) if that
    place is in the first box, else the nearest of ``fractions`` whose projection ``xy``
    (fractions of the pane) is in it, trying each box in turn (clear of its edges: 0.03,
    0.06 on the right), else ``at``.

    Parameters
    ----------
    xy : (n, 2) float
        Pane fractions of the points ``start + fractions[k] * vector``.
    fractions : (n,) float
    at : float
    boxes : sequence of (float, float, float, float)

    Returns
    -------
    float

    Examples
    --------
    >>> import numpy as np
    >>> frac = np.linspace(0, 1, 11)
    >>> xy = np.column_stack([frac * 2 - 0.5, np.full(11, 0.5)])    # leaves the pane at 0.75
    >>> round(label_fraction(xy, frac, 0.9, [(0.0, 0.0, 1.0, 1.0)]), 12)
    0.7
    """
    xy = np.asarray(xy, float)
    fractions = np.asarray(fractions, float)
    for bx0, by0, bx1, by1 in boxes:
        inside = ((xy[:, 0] > bx0 + 0.03) & (xy[:, 0] < bx1 - 0.06)
                  & (xy[:, 1] > by0 + 0.03) & (xy[:, 1] < by1 - 0.03))
        if inside.any():
            return float(fractions[inside][np.argmin(np.abs(fractions[inside] - at))])
    return float(at)

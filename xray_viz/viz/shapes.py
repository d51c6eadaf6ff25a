"""The geometry the scene view and the walkthroughs draw, as PyVista datasets.

Each function builds one shape from the thesis' quantities (a :class:`~xray_viz.geometry.Viewport`,
points, rays) and returns a :class:`pyvista.PolyData` (or :class:`pyvista.StructuredGrid`);
how it is painted is :mod:`xray_viz.viz.style`, where the camera goes is
:mod:`xray_viz.viz.camera`.

* the source marker (:func:`source_marker`), the detector (:func:`detector_quad`,
  :func:`detector_plane`) and its pixel grid (:func:`pixel_grid`);
* the HO, VE, FL and LHC arrows (:func:`viewport_vectors`, :func:`viewport_arrows`,
  :func:`line_arrow`) and solid arrows (:func:`solid_arrow`);
* rays and the beam's frustum (:func:`segments`, :func:`polyline`, :func:`frustum`), entry
  and exit markers (:func:`entry_markers`, :func:`exit_markers`);
* body surfaces (:func:`body_surface`) and outlines in the image pane (:func:`rectangle`).

Examples
--------
>>> import numpy as np
>>> from xray_viz.viz.shapes import segments
>>> lines = segments(np.zeros((2, 3)), [[1, 0, 0], [0, 1, 0]])
>>> lines.n_points, lines.n_lines
(4, 2)
"""

from __future__ import annotations

import numpy as np
import pyvista as pv

__all__ = ["segments", "polyline", "rectangle", "glyphs", "line_arrow", "solid_arrow",
           "source_marker", "detector_corners", "detector_quad", "detector_plane",
           "pixel_grid", "viewport_vectors", "viewport_arrows", "frustum", "entry_markers",
           "exit_markers", "body_surface"]


def segments(starts, ends) -> pv.PolyData:
    """Separate line segments ``starts[k] -> ends[k]`` as one :class:`pyvista.PolyData`
    (an empty one for no segments).

    Parameters
    ----------
    starts, ends : (n, 3) float

    Returns
    -------
    pyvista.PolyData
        ``2 n`` points, ``n`` lines.
    """
    starts = np.asarray(starts, float).reshape(-1, 3)
    ends = np.asarray(ends, float).reshape(-1, 3)
    n = len(starts)
    points = np.empty((2 * n, 3))
    points[0::2], points[1::2] = starts, ends
    cells = np.column_stack([np.full(n, 2), np.arange(0, 2 * n, 2), np.arange(1, 2 * n, 2)])
    return pv.PolyData(points, lines=cells.ravel()) if n else pv.PolyData()


def polyline(points) -> pv.PolyData:
    """A line through ``points`` ((n, 3) float), in order.

    Examples
    --------
    >>> polyline([[0, 0, 0], [1, 0, 0], [1, 1, 0]]).n_points
    3
    """
    return pv.lines_from_points(np.asarray(points, float))


def rectangle(x0, y0, x1, y1, z) -> pv.PolyData:
    """The closed outline of the rectangle ``[x0, x1] x [y0, y1]`` in the plane ``z``: five
    points from ``(x0, y0)`` counter-clockwise back to it.

    Examples
    --------
    >>> rectangle(-0.5, -0.5, 1.5, 0.5, 0.1).bounds[:4]
    (-0.5, 1.5, -0.5, 0.5)
    """
    return pv.lines_from_points(np.array([[x0, y0, z], [x1, y0, z], [x1, y1, z],
                                          [x0, y1, z], [x0, y0, z]]))


def glyphs(points, geom) -> pv.PolyData:
    """A copy of ``geom`` at each of ``points`` ((n, 3) float), unscaled and unturned (an
    empty dataset for no points)."""
    points = np.asarray(points, float).reshape(-1, 3)
    if not len(points):
        return pv.PolyData()
    return pv.PolyData(points).glyph(geom=geom, scale=False, orient=False)


def line_arrow(start, vector, *, tip: float, tip_radius: float) -> pv.PolyData:
    """An arrow from ``start`` along ``vector``: a line for the shaft (drawn a fixed number
    of pixels wide, so it is neither invisible far away nor a fat cylinder beside the
    camera) and a cone ``tip`` long (at most 40% of the arrow) of radius ``tip_radius``.

    Examples
    --------
    >>> a = line_arrow([0, 0, 0], [10.0, 0, 0], tip=2.0, tip_radius=0.5)
    >>> a.n_lines, [round(b, 6) for b in a.bounds[:2]]
    (1, [0.0, 10.0])
    """
    start = np.asarray(start, float)
    vector = np.asarray(vector, float)
    tip = min(float(tip), 0.4 * float(np.linalg.norm(vector)))
    unit = vector / max(float(np.linalg.norm(vector)), 1e-300)
    end = start + vector
    shaft = pv.Line(start, end - tip * unit)
    cone = pv.Cone(center=end - 0.5 * tip * unit, direction=unit, height=tip,
                   radius=float(tip_radius), resolution=24)
    return shaft.append_polydata(cone)


def solid_arrow(start, end, *, tip=None, shaft=None) -> pv.PolyData:
    """A :func:`pyvista.Arrow` (a cylinder and a cone) from ``start`` to ``end`` whose tip
    keeps a fixed size.

    Parameters
    ----------
    start, end : (3,) float
        Tail and head of the arrow.
    tip : float, optional
        Length of the tip in scene units (default: 12% of the arrow's length, at most 1/3).
    shaft : float, optional
        Radius of the shaft in scene units (default ``tip / 8``).

    Returns
    -------
    pyvista.PolyData
    """
    start = np.asarray(start, float)
    vec = np.asarray(end, float) - start
    length = float(np.linalg.norm(vec))
    tip = 0.12 * length if tip is None else float(tip)
    tip = min(tip, length / 3)
    shaft = tip / 8 if shaft is None else float(shaft)
    return pv.Arrow(start=start, direction=vec, scale=length, tip_length=tip / length,
                    tip_radius=0.35 * tip / length, shaft_radius=shaft / length)


def source_marker(center, *, radius: float) -> pv.PolyData:
    """The source: a sphere of ``radius`` at ``center`` (the thesis' ``r0``)."""
    return pv.Sphere(radius=radius, center=center)


def detector_corners(viewport) -> np.ndarray:
    """The detector's corners in order round its edge, ``(4, 3)``: ``LHC``, ``LHC + HO``,
    ``LHC + HO + VE``, ``LHC + VE``."""
    vp = viewport
    return np.array([vp.LHC, vp.LHC + vp.HO, vp.LHC + vp.HO + vp.VE, vp.LHC + vp.VE])


def detector_quad(viewport) -> pv.PolyData:
    """The detector (the thesis' viewport) as one quadrilateral, corners as
    :func:`detector_corners`.

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> scene = xray_viz.load_scene("sphere")
    >>> vp = xray_viz.viewport(scene.source.position, scene.detector)
    >>> quad = detector_quad(vp)
    >>> quad.n_cells, bool(np.isclose(quad.area, np.linalg.norm(np.cross(vp.HO, vp.VE))))
    (1, True)
    """
    return pv.PolyData(detector_corners(viewport), faces=[4, 0, 1, 2, 3])


def detector_plane(viewport, *, offset=(0.0, 0.0, 0.0)) -> pv.PolyData:
    """The detector quadrilateral moved by ``offset`` (the scene view sets it a hair behind
    the pixel positions, so the grid lines stay visible), with texture coordinates: the
    image's lower-left corner at ``LHC``, (1, 1) at ``LHC + HO + VE``."""
    plane = pv.PolyData(detector_corners(viewport) + offset, faces=[4, 0, 1, 2, 3])
    plane.active_texture_coordinates = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
    return plane


def pixel_grid(viewport, columns, rows) -> pv.StructuredGrid:
    """The pixel positions ``LHC + u_i HO + v_j VE`` of some columns and rows as a grid.

    Parameters
    ----------
    viewport : Viewport
    columns : (ni,) int
        Pixel columns ``i`` (0 on the left).
    rows : (nj,) int
        Rows counted from the bottom, ``j = 0`` at ``LHC`` (image row ``H - 1``).

    Returns
    -------
    pyvista.StructuredGrid
        ``ni x nj`` points.
    """
    from xray_viz.geometry import pixel_coordinates

    vp = viewport
    u, v = pixel_coordinates(tuple(vp.shape))
    uu = u[0, columns]                    # u of the columns
    vv = v[::-1, 0][rows]                 # v of the rows from the bottom
    pts = vp.LHC + uu[:, None, None] * vp.HO + vv[None, :, None] * vp.VE   # (ni, nj, 3)
    return pv.StructuredGrid(pts[..., 0][..., None], pts[..., 1][..., None],
                             pts[..., 2][..., None])


def viewport_vectors(viewport) -> dict:
    """``{name: (start, vector)}`` of the HO, VE, FL and LHC arrows (thesis Figure 1.3):
    ``HO`` and ``VE`` along the detector's edges from ``LHC``, ``FL`` from its centre to
    ``r0``, ``LHC`` from ``r0`` to the lower-left corner (the ray of pixel (0, 0))."""
    vp = viewport
    center = vp.LHC + vp.HO / 2 + vp.VE / 2
    return {"HO": (vp.LHC, vp.HO), "VE": (vp.LHC, vp.VE), "FL": (center, vp.FL),
            "LHC": (vp.r0, vp.LHC - vp.r0)}


def viewport_arrows(viewport) -> dict:
    """``{name: PolyData}``: the :func:`viewport_vectors` drawn by :func:`line_arrow`.

    The tips are sized by the detector, not by ``|FL|`` (the same arrows on a 1 m or a 10 cm
    beam): a tenth of its shorter side long, 0.28 of that in radius.
    """
    vp = viewport
    det = float(min(np.linalg.norm(vp.HO), np.linalg.norm(vp.VE)))
    tip = 0.1 * det
    return {key: line_arrow(start, vec, tip=tip, tip_radius=0.28 * tip)
            for key, (start, vec) in viewport_vectors(vp).items()}


def frustum(viewport, *, parallel: bool = False) -> pv.PolyData:
    """The beam's edges: four lines from the source (or, for a parallel beam, from the
    detector's corners moved by ``FL``) to the detector's corners."""
    vp = viewport
    corners = detector_corners(vp)
    if parallel:
        starts = corners + vp.FL
    else:
        starts = np.repeat(vp.r0[None], 4, axis=0)
    return segments(starts, corners)


def entry_markers(points, *, radius: float) -> pv.PolyData:
    """Where rays enter bodies: a sphere of ``radius`` at each point."""
    return glyphs(points, pv.Sphere(radius=radius))


def exit_markers(points, *, radius: float) -> pv.PolyData:
    """Where rays leave bodies: a cube ``1.6 radius`` wide at each point (about the
    sphere's volume, a different shape)."""
    return glyphs(points, pv.Cube(x_length=1.6 * radius, y_length=1.6 * radius,
                                  z_length=1.6 * radius))


def body_surface(vertices, faces) -> pv.PolyData:
    """A body's triangle mesh (``(n, 3)`` vertices, ``(m, 3)`` faces) as a PolyData."""
    return pv.PolyData.from_regular_faces(vertices, faces)

"""The thesis' set-up in 3D beside the radiograph it produces (PyVista).

:func:`plot_scene` draws, in the left subplot of a ``Plotter(shape=(1, 2))``:

* the bodies, translucent, coloured by material, with a legend;
* the source ``r0`` as a marker;
* the detector (the thesis' viewport) as a plane with its pixel grid ``LHC + u_i HO + v_j VE``
  (subsampled on large detectors, which the label says);
* ``HO``, ``VE`` (along the viewport edges from its lower-left corner), ``FL`` (from the
  viewport centre to ``r0``) and ``LHC`` (from ``r0`` to the lower-left corner, the ray
  direction of pixel (0, 0) in Eq. 1.5) as labelled arrows (thesis Figure 1.3);
* optionally the beam's frustum (``r0`` to the four corners);
* a chosen subset of rays from the source to their pixels, the parts inside bodies drawn dark
  and half transparent (the material colours show through), entries and exits as spheres and
  cubes - every point taken from :func:`xray_viz.tracing.trace_rays`;

and in the right subplot the radiograph, row 0 at the top as in the image arrays, with its
own colour bar (round ticks, :func:`colorbar_ticks`) and window/level (shown as ``W=..., L=...``
in its title; :meth:`SceneView.set_window_level`). Until a window/level is set, an intensity
image is shown as its PNG is written (:func:`display_window`): on a log scale when it spans more
than :data:`xray_viz.output.LOG_WINDOW_RATIO` (a chest), so that the lungs, the heart and an
implant keep their contrast. It can also be draped on the detector plane as a texture.

:class:`SceneView` keeps the actors, their groups and toggles and redraws them
(:meth:`SceneView.set_scene`); the shapes it draws come from :mod:`xray_viz.viz.shapes`, their
colours, widths and fonts from :mod:`xray_viz.viz.style`, and where the camera goes from
:mod:`xray_viz.viz.camera` (NumPy only, tested without VTK).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pyvista as pv

from xray_viz.errors import SceneError
from xray_viz.geometry import viewport
from xray_viz.output import png_window
from xray_viz.viz import camera, shapes
from xray_viz.viz.rays import RaySelection, inside_segments, trace_selection
# the look of the view, importable from here as before
from xray_viz.viz.style import (ARROW_WIDTH, BODY_SPECULAR, COLORS, CORNER_FONT, FONT_SIZES,
                                LEGEND, LINE_WIDTHS, OPACITY, PALETTE, material_color)  # noqa: F401

__all__ = ["SceneView", "plot_scene", "material_label", "grid_indices", "image_to_grid",
           "quantity_title", "window_level_limits", "display_window", "gray_levels",
           "colorbar_ticks"]

#: Actor names of each toggleable group of the 3D view.
GROUPS = {
    "bodies": (),            # filled per scene: "body:<name>"
    "source": ("source",),
    "detector": ("detector",),
    "grid": ("grid",),
    # add_point_labels(name="vec-labels") registers its actor as "vec-labels-labels"
    "vectors": ("vec:HO", "vec:VE", "vec:FL", "vec:LHC", "vec-labels-labels"),
    "frustum": ("frustum",),
    "rays": ("rays", "rays-inside"),
    "hits": ("hits-entry", "hits-exit"),
    "picked": ("picked-ray", "picked-ray-inside", "picked-entry", "picked-exit"),
}


def material_label(body) -> str:
    """What a body is made of, as shown in the legend.

    Examples
    --------
    >>> import xray_viz
    >>> material_label(xray_viz.load_scene("sphere").bodies[0])
    'mu = 0.2 /cm'
    >>> from xray_viz.scene import Body
    >>> ball = xray_viz.load_scene("sphere").bodies[0].mesh
    >>> mix = {"Water, Liquid": 0.7, "Bone, Cortical (ICRP)": 0.3}
    >>> material_label(Body("b", ball, material=mix, density=1.25))
    '70% Water, Liquid + 30% Bone, Cortical (ICRP), 1.25 g/cm3'
    """
    if body.material is not None:
        density = f" {body.density:g} g/cm3" if body.density else ""
        if isinstance(body.material, str):
            return body.material + density
        from xray_viz.physics.materials import material_key

        parts = sorted(material_key(body.material), key=lambda p: (-p[1], p[0]))
        mixture = " + ".join(f"{100 * w:.3g}% {name}" for name, w in parts)
        return mixture + density.replace(" ", ", ", 1)
    return f"mu = {body.mu:g} /cm"


def grid_indices(n: int, *, max_lines: int = 33) -> np.ndarray:
    """Indices of the pixel rows/columns drawn in the grid: all of them, or an even subset.

    The first and last pixels (the viewport edges) are always included.

    Examples
    --------
    >>> grid_indices(5).tolist()
    [0, 1, 2, 3, 4]
    >>> grid_indices(256, max_lines=5).tolist()
    [0, 64, 128, 192, 255]
    """
    if n <= max_lines:
        return np.arange(n)
    step = math.ceil((n - 1) / (max_lines - 1))
    idx = np.arange(0, n, step)
    return np.unique(np.r_[idx, n - 1])


def quantity_title(quantity: str, scene=None) -> str:
    """What an image of ``quantity`` holds, with its unit, as the colour bar's title.

    The intensity image is ``I0 F T`` (:mod:`xray_viz.physics.imaging`): with the detector's
    ``I0`` left at 1 that is the transmitted fraction ``I / I0``; with ``I0`` set (photons per
    unattenuated pixel) it is the detected intensity in photons, shown as it is.

    Examples
    --------
    >>> import xray_viz
    >>> quantity_title("intensity", xray_viz.load_scene("sphere"))
    'I / I0'
    >>> quantity_title("path-length")
    'path length (mm)'
    """
    if quantity in ("intensity", "total", "primary", "scatter"):
        i0 = 1.0 if scene is None else scene.detector.i0
        unit = "I / I0" if i0 == 1 else "I (photons)"
        return unit if quantity == "intensity" else f"{quantity} {unit}"
    return {"line-integral": "line integral", "path-length": "path length (mm)",
            "spr": "scatter / primary"}.get(quantity, quantity)


def window_level_limits(image, *, window=None, level=None) -> tuple[float, float]:
    """Colour limits ``(level - window / 2, level + window / 2)``.

    Unset ``window`` / ``level`` default to the finite range of the image.

    Examples
    --------
    >>> window_level_limits([[0.0, 1.0]])
    (0.0, 1.0)
    >>> window_level_limits([[0.0, 1.0]], window=0.2, level=0.9)
    (0.8, 1.0)
    """
    a = np.asarray(image, dtype=float)
    finite = a[np.isfinite(a)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    if window is None:
        window = hi - lo
    if level is None:
        level = (hi + lo) / 2
    window = max(float(window), 1e-12)
    return float(level - window / 2), float(level + window / 2)


def display_window(image, *, bright: str = "high", window=None, level=None
                   ) -> tuple[float, float, bool]:
    """Colour limits ``(low, high)`` of the radiograph pane and whether its scale is
    logarithmic.

    Unset ``window`` and ``level``: an intensity image (``bright="low"``) whose PNG is written
    on a log scale (:func:`xray_viz.output.png_window`: it spans more than
    :data:`xray_viz.output.LOG_WINDOW_RATIO`) is shown on the same log scale between the same
    ends (an implant's few pixels beyond them saturated); any other image over its finite
    range, as :func:`window_level_limits`. A window or a level set: linear, as
    :func:`window_level_limits` (in the image's units, as the sliders say).

    Examples
    --------
    >>> display_window([[0.5, 1.0]], bright="low")
    (0.5, 1.0, False)
    >>> display_window([[1e-3, 1.0]], bright="low")
    (0.001, 1.0, True)
    >>> display_window([[1e-3, 1.0]], bright="low", window=0.5, level=0.5)
    (0.25, 0.75, False)
    """
    if window is None and level is None and bright == "low":
        lo, hi, log = png_window(image, bright=bright)
        if log:
            return lo, hi, True
    lo, hi = window_level_limits(image, window=window, level=level)
    return lo, hi, False


def gray_levels(image, lo: float, hi: float, *, log: bool = False) -> np.ndarray:
    """The image's values as fractions 0 to 1 of the window ``[lo, hi]`` (clipped; NaN at 0):
    linearly, or of ``[ln lo, ln hi]`` with ``log`` (values <= 0 at 0, as the PNG).

    Examples
    --------
    >>> gray_levels([[0.5, 2.0]], 0.0, 1.0).tolist()
    [[0.5, 1.0]]
    >>> gray_levels([[0.01, 0.1, 0.0]], 0.01, 1.0, log=True).tolist()
    [[0.0, 0.5, 0.0]]
    """
    a = np.asarray(image, dtype=float)
    if log:
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.log(np.where(a > 0, a, lo))
        lo, hi = math.log(lo), math.log(hi)
    gray = np.clip((a - lo) / max(hi - lo, 1e-300), 0, 1)
    return np.nan_to_num(gray, nan=0.0)


def colorbar_ticks(lo: float, hi: float, *, n: int = 5, log: bool = False
                   ) -> tuple[np.ndarray, str]:
    """Round tick values in ``[lo, hi]`` (steps of 1, 2 or 5 times a power of ten, about
    ``n`` of them) and a printf format that shows them without spurious digits. With ``log``
    (a log colour scale, ``lo > 0``): the values 1, 2 and 5 times a power of ten in
    ``[lo, hi]``, or the powers of ten alone when those are too many.

    Examples
    --------
    >>> ticks, fmt = colorbar_ticks(0.202, 1.0)
    >>> [fmt % t for t in ticks]
    ['0.4', '0.6', '0.8', '1.0']
    >>> ticks, fmt = colorbar_ticks(0.8, 1.0)
    >>> [fmt % t for t in ticks]
    ['0.80', '0.85', '0.90', '0.95', '1.00']
    >>> ticks, fmt = colorbar_ticks(3.7e-4, 1.0, log=True)
    >>> [fmt % t for t in ticks]
    ['0.001', '0.01', '0.1', '1']
    """
    lo, hi = float(lo), float(hi)
    if log and 0 < lo < hi and np.isfinite(hi):
        decades = np.arange(math.floor(math.log10(lo)), math.ceil(math.log10(hi)) + 1)
        for mantissas in ((1, 2, 5), (1,)):
            ticks = np.array([m * 10.0 ** d for d in decades for m in mantissas])
            ticks = ticks[(ticks >= lo * (1 - 1e-9)) & (ticks <= hi * (1 + 1e-9))]
            if len(ticks) <= 2 * n:
                break
        if len(ticks) >= 2:
            return ticks, "%g"
    if not (np.isfinite(lo) and np.isfinite(hi)) or hi <= lo:
        return np.array([lo]), "%.3g"
    mag = 10.0 ** math.floor(math.log10((hi - lo) / max(n, 1)))
    best = None
    for step in (m * mag for m in (0.5, 1, 2, 5, 10, 20)):   # the count nearest n wins
        ticks = np.arange(math.ceil(lo / step - 1e-9), math.floor(hi / step + 1e-9) + 1) * step
        if len(ticks) >= 2 and (best is None or abs(len(ticks) - n) < abs(len(best[0]) - n)):
            best = (ticks, step)
    if best is None:
        return np.array([lo, hi]), "%.3g"
    ticks, step = best
    digits = max(0, -math.floor(math.log10(step) + 1e-9))
    fmt = f"%.{digits}f" if max(abs(lo), abs(hi)) < 1e5 else "%.3g"
    return np.round(ticks, digits + 2) + 0.0, fmt


def image_to_grid(image, *, name="value") -> pv.ImageData:
    """An (H, W) image as cells of a flat :class:`pyvista.ImageData`, pixel (i, j) at (i, j).

    Cell ``(i, j)`` is centred on ``x = i`` (column from the left) and ``y = j`` (row from the
    bottom), so the top row of the array (row 0) is drawn at the top, ``y = H - 1``, and a
    picked point ``(x, y)`` is pixel ``(round(x), round(y))``.

    Examples
    --------
    >>> import numpy as np
    >>> grid = image_to_grid(np.array([[1.0, 2.0], [3.0, 4.0]]))
    >>> grid.cell_data["value"].tolist()         # bottom row first: row 1, then row 0
    [3.0, 4.0, 1.0, 2.0]
    """
    image = np.asarray(image, dtype=float)
    h, w = image.shape
    grid = pv.ImageData(dimensions=(w + 1, h + 1, 1), spacing=(1.0, 1.0, 1.0),
                        origin=(-0.5, -0.5, 0.0))
    grid.cell_data[name] = image[::-1].ravel()
    return grid


@dataclass
class SceneView:
    """The plotter of :func:`plot_scene` and the names of what it drew, for updates.

    Callbacks change the view through its methods (:meth:`set_scene`, :meth:`set_rays`,
    :meth:`set_radiograph`, :meth:`show_pixel`, :meth:`set_visible`); each re-adds actors under
    the same names, which replaces them.

    Attributes
    ----------
    plotter : pyvista.Plotter
    scene : Scene
    radiograph : Radiograph or None
    selection : RaySelection or None
        The rays drawn, with their hits.
    picked : RaySelection or None
        The ray of the pixel shown with :meth:`show_pixel`.
    datasets : dict of str to pyvista.DataSet
        What each named actor draws, in scene coordinates (mm).
    grid_ij : (numpy.ndarray, numpy.ndarray)
        The pixel columns ``i`` and rows ``j`` whose positions the grid draws.
    """

    plotter: pv.Plotter
    scene: object
    rays: object = "grid 7"
    radiograph: object = None
    quantity: str = "intensity"
    window: float | None = None
    level: float | None = None
    texture: bool = False
    max_grid_lines: int = 33
    show: dict = field(default_factory=dict)
    subplot_3d: tuple = (0, 0)
    subplot_image: tuple | None = (0, 1)
    selection: RaySelection | None = None
    picked: RaySelection | None = None
    datasets: dict = field(default_factory=dict)
    grid_ij: tuple = ()
    zoom: float = 1.0
    status: str = ""
    slider_band: float = 0.0
    view_box: tuple = camera.SIDE_VIEW_BOX
    bodies_view_box: tuple | None = None
    camera_view: str = "side"
    # how voxel volumes are drawn: "slices" or "volume" (set_volume_style)
    volume_style: str = "slices"
    _camera_set: bool = False
    #: Texts of fixed pixel size, by name: (actor, font size at the reference window).
    _fixed_texts: dict = field(default_factory=dict)

    #: The smallest window the font sizes are chosen for; smaller windows get smaller text
    #: (:attr:`font_scale`), so that the key help, the legend and the titles do not overlap.
    REFERENCE_WINDOW = (1200, 600)
    MIN_FONT_SCALE = 0.6

    # ---------------------------------------------------------------- helpers
    @property
    def font_scale(self) -> float:
        """Factor of the texts' font sizes for the current window: 1 at
        :attr:`REFERENCE_WINDOW` (1200 x 600) and larger, down to :attr:`MIN_FONT_SCALE` in
        proportion to the window's width or height, whichever is relatively smaller."""
        w, h = self.plotter.window_size
        ref_w, ref_h = self.REFERENCE_WINDOW
        return float(np.clip(min(w / ref_w, h / ref_h), self.MIN_FONT_SCALE, 1.0))

    def fixed_text(self, actor, name: str, base_size: int):
        """Register a text actor of fixed pixel size, drawn at ``base_size`` points in the
        reference window and scaled by :attr:`font_scale` (now and by :meth:`fit_text`)."""
        self._fixed_texts[name] = (actor, int(base_size))
        actor.GetTextProperty().SetFontSize(max(1, int(base_size * self.font_scale)))
        return actor

    def fit_text(self) -> None:
        """Rescale every registered text to the window's current size (after a resize)."""
        scale = self.font_scale
        for actor, base in self._fixed_texts.values():
            actor.GetTextProperty().SetFontSize(max(1, int(base * scale)))

    @property
    def viewport(self):
        """The thesis' viewport vectors of the current scene."""
        return viewport(self.scene.source.position, self.scene.detector)

    @property
    def size_scale(self) -> float:
        """A length (mm) that sets marker and arrow-tip sizes: 1/40 of the scene's extent."""
        return camera.scene_scale(self.viewport)

    @property
    def bodies_bounds(self):
        """``(lo, hi)``, the (3,) corners of the box around all bodies (the detector's if
        there are none)."""
        volumes = self.scene.volumes
        if self.scene.bodies or volumes:
            boxes = [(b.vertices.min(axis=0), b.vertices.max(axis=0)) for b in self.scene.bodies]
            boxes += [tuple(v.bounds) for v in volumes]      # voxel volumes (issue 40)
            return np.min([a for a, _ in boxes], axis=0), np.max([b for _, b in boxes], axis=0)
        vp = self.viewport
        corners = np.array([vp.LHC, vp.LHC + vp.HO + vp.VE])
        return corners.min(axis=0), corners.max(axis=0)

    @property
    def glyph_radius(self) -> float:
        """Radius (mm) of the entry/exit glyphs: 1/120 of the bodies' size, so they are
        dots on the bodies, never larger than 1/10 of :attr:`size_scale`."""
        lo, hi = self.bodies_bounds
        return float(min(0.1 * self.size_scale, np.linalg.norm(hi - lo) / 120))

    def _add(self, name, mesh, *, group=None, **kwargs):
        self.plotter.subplot(*self.subplot_3d)
        if mesh is None or mesh.n_points == 0:
            self.plotter.remove_actor(name, render=False)
            self.datasets.pop(name, None)
            return None
        self.datasets[name] = mesh
        kwargs.setdefault("pickable", False)
        actor = self.plotter.add_mesh(mesh, name=name, reset_camera=False, render=False,
                                      **kwargs)
        if group is not None:
            actor.SetVisibility(bool(self.show.get(group, True)))
        return actor

    def _group_names(self, group):
        if group == "bodies":     # a volume's box, and its parts of the current style
            return tuple(f"body:{b.name}" for b in self.scene.bodies) + tuple(
                f"volume:{v.name}{part}" for v in self.scene.volumes
                for part in (":box",) + VOLUME_PARTS[self.volume_style])
        return GROUPS[group]

    def set_visible(self, group: str, visible: bool) -> None:
        """Show or hide a group: ``"bodies"``, ``"source"``, ``"detector"``, ``"grid"``,
        ``"vectors"``, ``"frustum"``, ``"rays"``, ``"hits"`` or ``"picked"``."""
        if group not in GROUPS:
            raise SceneError(f"unknown group {group!r}; choose one of {', '.join(GROUPS)}")
        self.show[group] = bool(visible)
        if group == "hits":
            names = GROUPS["hits"] + ("picked-entry", "picked-exit")
        else:
            names = self._group_names(group)
        for name in names:
            actor = self.plotter.actors.get(name)
            if actor is not None:
                actor.SetVisibility(bool(visible))
        if group == "frustum" and visible and "frustum" not in self.plotter.actors:
            self._draw_frustum()

    def is_visible(self, group: str) -> bool:
        """Whether a group is shown."""
        return bool(self.show.get(group, True))

    # ---------------------------------------------------------------- drawing
    def draw(self) -> "SceneView":
        """(Re)draw everything from :attr:`scene`, :attr:`rays` and :attr:`radiograph`."""
        self._draw_bodies()
        self._draw_source()
        self._draw_detector()
        self._draw_vectors()
        if self.show.get("frustum", False):
            self._draw_frustum()
        else:
            self.plotter.remove_actor("frustum", render=False)
        self._draw_rays()
        if self.picked is not None:
            self.show_pixel(int(self.picked.i[0]), int(self.picked.j[0]))
        self._draw_legend()
        if self.subplot_image is not None and self.radiograph is not None:
            self._draw_radiograph()
        if not self._camera_set:
            self.reset_camera()
        return self

    def _draw_bodies(self):
        labels = {}
        for name in [n for n in self.plotter.actors if n.startswith("body:")]:
            if name[5:] not in self.scene.body_names:
                self.plotter.remove_actor(name, render=False)
        drawn = getattr(self, "_drawn_bodies", {})
        for body in self.scene.bodies:
            label = material_label(body)
            color = labels.setdefault(label, material_color(len(labels)))
            name = f"body:{body.name}"
            try:
                key = (id(body.mesh), hash(body.mesh), color)
            except TypeError:
                key = None
            if key is not None and drawn.get(name) == key and name in self.plotter.actors:
                continue        # the same mesh in the same colour (the source moved): keep it
            mesh = shapes.body_surface(body.vertices, body.faces)
            self._add(name, mesh, group="bodies", color=color, opacity=OPACITY["body"],
                      smooth_shading=True, specular=BODY_SPECULAR)
            drawn[name] = key
        self._drawn_bodies = drawn
        self.material_colors = labels
        volumes = self.scene.volumes
        names = {v.name for v in volumes}
        for name in [n for n in self.plotter.actors if n.startswith("volume:")]:
            if name.split(":")[1] not in names:           # a volume no longer in the scene
                self.plotter.remove_actor(name, render=False)
                self.datasets.pop(name, None)
        for vol in volumes:
            self._draw_volume(vol)

    def _draw_volume(self, vol):
        """A voxel volume (issue 40): its grid's box, and either three orthogonal slices
        through its middle (:func:`volume_slices`), a CT's in the HU window
        :attr:`volume_window`, a label map's by class, or a volume rendering
        (:meth:`_draw_volume_rendering`), as :attr:`volume_style` says. The other style's
        actors, once drawn, are kept hidden."""
        c = vol.corners                       # corner order: i, then j, then k (bits 2, 1, 0)
        edges = [(a, b) for a in range(8) for b in range(a + 1, 8)
                 if bin(a ^ b).count("1") == 1]
        lines = np.hstack([[2, a, b] for a, b in edges])
        self._add(f"volume:{vol.name}:box", pv.PolyData(c, lines=lines), group="bodies",
                  color="black", line_width=1)
        shown = self.is_visible("bodies")
        for style, parts in VOLUME_PARTS.items():
            if style != self.volume_style:
                for part in parts:
                    actor = self.plotter.actors.get(f"volume:{vol.name}{part}")
                    if actor is not None:
                        actor.SetVisibility(False)
        if self.volume_style == "volume":
            self._draw_volume_rendering(vol)
            actor = self.plotter.actors.get(f"volume:{vol.name}:render")
            if actor is not None:
                actor.SetVisibility(shown)
            return
        ct = _is_ct(vol)
        width, level = getattr(self, "volume_window", VOLUME_WINDOW)
        for axis, grid in volume_slices(vol).items():
            if ct:
                self._add(f"volume:{vol.name}:slice:{axis}", grid, group="bodies",
                          scalars="hu", cmap="gray", clim=hu_window_limits(width, level),
                          show_scalar_bar=False, opacity=OPACITY_SLICE)
            else:
                self._add(f"volume:{vol.name}:slice:{axis}", grid, group="bodies",
                          scalars="class", cmap="tab10", clim=(0, max(1, len(vol.names))),
                          show_scalar_bar=False, opacity=OPACITY_SLICE)

    def _draw_volume_rendering(self, vol):
        """The volume rendering of a voxel volume (:func:`volume_grid`, at most
        :data:`VOLUME_RENDER_VOXELS` voxels), a CT's HU through :data:`CT_OPACITY` and
        :data:`CT_COLORS`, a label map's classes each a faint colour; drawn once per volume
        (moving the source keeps it)."""
        name = f"volume:{vol.name}:render"
        drawn = self.__dict__.setdefault("_drawn_volumes", {})
        if drawn.get(name) is vol and name in self.plotter.actors:
            return
        grid, matrix = volume_grid(vol)
        self.plotter.subplot(*self.subplot_3d)
        ct = _is_ct(vol)
        scalars = "hu" if ct else "class"
        actor = self.plotter.add_volume(grid, scalars=scalars, name=name, opacity="linear",
                                        show_scalar_bar=False, reset_camera=False,
                                        render=False, pickable=False,
                                        opacity_unit_distance=1.0, user_matrix=matrix)
        opacity, colors = (CT_OPACITY, CT_COLORS) if ct else _label_transfer(vol)
        actor.prop.SetScalarOpacity(_piecewise(opacity))
        actor.prop.SetColor(_color_function(colors))
        if ct:
            actor.prop.SetInterpolationTypeToLinear()
        else:                                          # classes are not interpolated
            actor.prop.SetInterpolationTypeToNearest()
        self.datasets[name] = grid
        drawn[name] = vol

    def set_volume_style(self, style: str) -> None:
        """Draw the voxel volumes as ``"slices"`` (three orthogonal slices in an HU window,
        the default) or as a ``"volume"`` rendering (air transparent, soft tissue faint, bone
        opaque: ``CT_OPACITY`` of this module); the meshes are drawn as before either way."""
        if style not in VOLUME_PARTS:
            raise SceneError(f"volume style must be one of {', '.join(VOLUME_PARTS)}, got "
                             f"{style!r}")
        self.volume_style = style
        for vol in self.scene.volumes:
            self._draw_volume(vol)

    def set_volume_window(self, window: float, level: float) -> None:
        """Show the CT volumes' slices in the HU window ``level +- window / 2`` (default
        ``VOLUME_WINDOW``, soft tissue)."""
        if not (np.isfinite(window) and np.isfinite(level) and window > 0):
            raise SceneError(f"volume window must be a width > 0 and a level in HU, got "
                             f"{window!r}, {level!r}")
        self.volume_window = (float(window), float(level))
        for vol in self.scene.volumes:
            if _is_ct(vol):
                for axis in "ijk":
                    actor = self.plotter.actors.get(f"volume:{vol.name}:slice:{axis}")
                    if actor is not None:
                        actor.GetMapper().SetScalarRange(*hu_window_limits(window, level))

    def _draw_source(self):
        marker = shapes.source_marker(self.viewport.r0, radius=0.4 * self.size_scale)
        self._add("source", marker, group="source", color=COLORS["source"])

    def _draw_detector(self):
        vp = self.viewport
        w, h = vp.shape
        # The plane sits a hair behind the pixel positions so the grid lines stay visible.
        back = vp.forward * 1e-3 * self.size_scale
        plane = shapes.detector_plane(vp, offset=back)
        if self.texture and self.radiograph is not None:
            image = self.radiograph.quantity(self.quantity)
            lo, hi, log = self.display_window
            gray = gray_levels(image, lo, hi, log=log)
            if self.cmap == "gray_r":                 # as in the 2D view: attenuation bright
                gray = 1.0 - gray
            rgb = np.repeat((gray * 255).astype(np.uint8)[..., None], 3, axis=2)
            self._add("detector", plane, group="detector", texture=pv.Texture(rgb),
                      lighting=False)
        else:
            self._add("detector", plane, group="detector", color=COLORS["detector"],
                      opacity=OPACITY["detector"], lighting=False)
        ii = grid_indices(w, max_lines=self.max_grid_lines)
        jj = grid_indices(h, max_lines=self.max_grid_lines)
        grid = shapes.pixel_grid(vp, ii, jj)
        self.grid_ij = (ii, jj)
        dense = len(ii) > OPACITY["grid_dense_lines"]
        self._add("grid", grid, group="grid", style="wireframe", color=COLORS["grid"],
                  line_width=LINE_WIDTHS["grid"], lighting=False,
                  opacity=OPACITY["grid_dense"] if dense else OPACITY["grid"])
        if len(ii) < w or len(jj) < h:
            si, sj = (int(ii[1] - ii[0]) if len(ii) > 1 else 1,
                      int(jj[1] - jj[0]) if len(jj) > 1 else 1)
            steps = f"step {si}" if si == sj else f"column step {si}, row step {sj}"
            self.grid_label = (f"pixel grid: {len(ii)} x {len(jj)} of {w} x {h} rays drawn "
                               f"({steps})")
        else:
            self.grid_label = f"pixel grid: all {w} x {h} rays"
        self.plotter.subplot(*self.subplot_3d)
        self._text(self.grid_label, (0.01, 0.008), "grid-label",
                   font_size=FONT_SIZES["grid_label"], vertical="bottom")

    #: Where along each arrow its label sits by default (fraction from its start).
    LABEL_AT = {"HO": 0.6, "VE": 0.6, "FL": 0.5, "LHC": 0.35}

    def _vector_arrows(self):
        """``{name: (start, vector)}`` of the HO, VE, FL and LHC arrows (thesis Figure 1.3)."""
        return shapes.viewport_vectors(self.viewport)

    def _draw_vectors(self):
        # Tips sized by the detector, not by |FL| (the same arrows on a 1 m or a 10 cm
        # beam); shafts are lines ARROW_WIDTH pixels wide: visible in the whole-set-up view,
        # not fat cylinders where the FL and LHC arrows run past the camera of the close-up.
        for key, arrow in shapes.viewport_arrows(self.viewport).items():
            self._add(f"vec:{key}", arrow, group="vectors", color=COLORS[key],
                      line_width=ARROW_WIDTH)
        self._draw_vector_labels()

    def _world_to_box(self, points) -> np.ndarray:
        """``(n, 2)`` positions of 3D points in the 3D pane, as fractions of the pane (0 to 1
        across, 0 to 1 up); points behind the camera get NaN."""
        self.plotter.subplot(*self.subplot_3d)
        cam = self.plotter.camera
        m = cam.GetCompositeProjectionTransformMatrix(self._pane_aspect(), -1, 1)
        mat = np.array([[m.GetElement(r, c) for c in range(4)] for r in range(4)])
        pts = np.c_[np.asarray(points, float).reshape(-1, 3), np.ones(len(points))]
        h = pts @ mat.T
        with np.errstate(divide="ignore", invalid="ignore"):
            xy = (h[:, :2] / h[:, 3:4] + 1) / 2
        xy[h[:, 3] <= 0] = np.nan
        return xy

    def _draw_vector_labels(self):
        """Label the arrows and ``r0``: each label at its usual place along the arrow
        (:attr:`LABEL_AT`), or, where that is out of the pinned view, at the nearest place
        along the arrow that is in the box the camera framed (or, failing that, in the
        pane)."""
        vp = self.viewport
        label_pts, labels = [], []
        frac = np.linspace(0.05, 0.95, 37)
        for key, (start, vec) in self._vector_arrows().items():
            start, vec = np.asarray(start, float), np.asarray(vec, float)
            at = self.LABEL_AT[key]
            if self._camera_set:
                xy = self._world_to_box(start + frac[:, None] * vec)
                # in the view box if the arrow passes through it, else anywhere in the pane
                box = getattr(self, "_framed_box", self.view_box)
                at = camera.label_fraction(xy, frac, at, (box, camera.FULL_PANE))
            label_pts.append(start + at * vec)
            labels.append(key if key != "LHC" else "LHC - r0")
        label_pts.append(vp.r0)
        labels.append("r0 (source)")
        self.plotter.subplot(*self.subplot_3d)
        actor = self.plotter.add_point_labels(
            np.asarray(label_pts), labels, font_size=FONT_SIZES["vector_label"], bold=True,
            show_points=False, shape_opacity=OPACITY["label_box"], always_visible=True, name="vec-labels", reset_camera=False,
            render=False)
        actor.SetVisibility(self.is_visible("vectors"))
        self.vector_label_points = dict(zip(labels, np.asarray(label_pts)))

    def _draw_frustum(self):
        lines = shapes.frustum(self.viewport, parallel=self.scene.source.kind == "parallel")
        self._add("frustum", lines, group="frustum", color=COLORS["frustum"],
                  line_width=LINE_WIDTHS["frustum"])

    def _ray_actors(self, sel: RaySelection, prefix: str, *, color, width):
        starts, ends, _ = inside_segments(sel.hits)
        entry = sel.hits.point[sel.hits.entering]
        exit_ = sel.hits.point[~sel.hits.entering]
        r = self.glyph_radius
        group = "rays" if prefix == "rays" else "picked"
        self._add(prefix, shapes.segments(sel.origins, sel.ends), group=group, color=color,
                  line_width=width, lighting=False)
        # inside a body: a little wider than the ray, dark and half transparent, so the
        # body's own (material) colour still shows around and through it
        self._add(f"{prefix}-inside", shapes.segments(starts, ends), group=group,
                  color=COLORS["inside"], line_width=width + LINE_WIDTHS["inside_extra"],
                  opacity=OPACITY["inside"], lighting=False)
        hits_group = "hits" if prefix == "rays" else "picked"
        name_entry = "hits-entry" if prefix == "rays" else "picked-entry"
        name_exit = "hits-exit" if prefix == "rays" else "picked-exit"
        a = self._add(name_entry, shapes.entry_markers(entry, radius=r), group=hits_group,
                      color=COLORS["entry"])
        b = self._add(name_exit, shapes.exit_markers(exit_, radius=r), group=hits_group,
                      color=COLORS["exit"])
        for actor in (a, b):
            if actor is not None and prefix != "rays":
                actor.SetVisibility(self.is_visible("hits") and self.is_visible("picked"))

    def _draw_rays(self):
        self.selection = trace_selection(self.scene, self.rays)
        self._ray_actors(self.selection, "rays", color=COLORS["ray"],
                         width=LINE_WIDTHS["ray"])

    def _draw_legend(self):
        self.plotter.subplot(*self.subplot_3d)
        entries = [[f"{label}", color] for label, color in self.material_colors.items()]
        entries += [["source r0", COLORS["source"]], ["ray", COLORS["ray"]],
                    ["inside a body", COLORS["inside"]], ["entry hit (sphere)", COLORS["entry"]],
                    ["exit hit (cube)", COLORS["exit"]]]
        height = min(LEGEND["max_height"], LEGEND["entry_height"] * len(entries))
        self.plotter.add_legend(entries, bcolor=LEGEND["bcolor"], border=True,
                                size=(LEGEND["width"], height), loc=LEGEND["loc"],
                                face=LEGEND["face"], background_opacity=OPACITY["legend"])

    def _draw_radiograph(self):
        """The image in the right subplot, laid out in fractions of the pane: the title on
        top, the image in a box below it (above :attr:`slider_band`, kept for the viewer's
        sliders), the colour bar to its right."""
        pl = self.plotter
        pl.subplot(*self.subplot_image)
        rg = self.radiograph
        image = rg.quantity(self.quantity)
        h, w = image.shape
        title = self.quantity_title
        grid = image_to_grid(image, name=title)
        self.datasets["radiograph"] = grid
        *clim, log = self.display_window
        clim = tuple(clim)
        # Attenuation bright, as radiologists read films: low I / I0 is white.
        cmap = self.cmap
        # box of the image, fractions of the pane: left, bottom, right, top
        x0, x1 = 0.06, 0.76
        y0, y1 = max(0.07, self.slider_band + 0.06), 0.86
        for old in list(pl.scalar_bars.keys()):            # re-placed on every draw
            pl.remove_scalar_bar(old, render=False)
        pl.add_mesh(grid, name="radiograph", scalars=title, cmap=cmap, clim=clim,
                    log_scale=log, lighting=False, show_scalar_bar=True, reset_camera=False, render=False,
                    scalar_bar_args=dict(title=title, vertical=True, position_x=0.8,
                                         position_y=y0 + 0.05 * (y1 - y0),
                                         height=0.8 * (y1 - y0), width=0.05,
                                         fmt="%.3g",
                                         title_font_size=FONT_SIZES["colorbar_title"],
                                         label_font_size=FONT_SIZES["colorbar_labels"],
                                         color="black", n_labels=5))
        # round ticks (0.2, 0.4, ...) rather than five evenly spaced odd values, and the
        # title clear of the top tick label
        bar = pl.scalar_bars[title]
        ticks, fmt = colorbar_ticks(*clim, n=5, log=log)
        from vtkmodules.vtkCommonCore import vtkDoubleArray

        values = vtkDoubleArray()
        for t in ticks:
            values.InsertNextValue(float(t))
        bar.SetCustomLabels(values)
        bar.SetUseCustomLabels(True)
        bar.SetLabelFormat(fmt)
        bar.SetVerticalTitleSeparation(int(0.6 * bar.GetTitleTextProperty().GetFontSize()) + 6)
        self.colorbar_labels = [fmt % t for t in ticks]
        frame = shapes.rectangle(-.5, -.5, w - .5, h - .5, .05)
        pl.add_mesh(frame, name="radiograph-frame", color="black",
                    line_width=LINE_WIDTHS["image_frame"],
                    lighting=False, reset_camera=False, render=False, pickable=False)
        # camera: parallel projection, the image centred in its box
        framing = camera.image_view((h, w), aspect=self._pane_aspect(), box=(x0, y0, x1, y1))
        scale = framing.parallel_scale
        pl.view_xy()
        pl.camera.parallel_projection = True
        pl.camera.focal_point = tuple(framing.focal_point)
        pl.camera.position = tuple(framing.position)
        pl.camera.up = tuple(framing.up)
        pl.camera.parallel_scale = scale
        pl.reset_camera_clipping_range()
        # corner labels just outside the frame: (0, 0) below its lower-left corner,
        # (w-1, h-1) above its upper-right corner
        pad = 0.012 * 2 * scale
        corners = np.array([[-0.5, -0.5 - pad, 0.1], [w - 0.5, h - 0.5 + pad, 0.1]])
        self._label(corners[:1], "(i, j) = (0, 0): LHC", "radiograph-corner-00",
                    justify="left", vertical="top", font_size=CORNER_FONT)
        self._label(corners[1:], f"({w - 1}, {h - 1})", "radiograph-corner-wh",
                    justify="right", vertical="bottom", font_size=CORNER_FONT)
        engine = getattr(rg, "engine", "?")
        total = rg.timing.get("total", float("nan")) if getattr(rg, "timing", None) else math.nan
        lines = [f"radiograph: {self.quantity}, {w} x {h}, row 0 at the top"]
        if self.status:
            lines.append(self.status)
        wl, lv = clim[1] - clim[0], (clim[0] + clim[1]) / 2
        if log:
            self.window_level_text = f"log scale {clim[0]:.3g} to {clim[1]:.3g} (as the PNG)"
        else:
            self.window_level_text = (f"W={wl:.3g}, L={lv:.3g}"
                                      + (" (image range)" if self.window is None
                                         and self.level is None else ""))
        # the render time last: its digits change from run to run, nothing after them moves
        lines.append(f"window/level {self.window_level_text};  engine {engine}: "
                     f"{total * 1000:.0f} ms")
        self._text("\n".join(lines), (0.03, 0.985), "radiograph-title",
                   font_size=FONT_SIZES["image_title"])
        pl.subplot(*self.subplot_3d)

    @property
    def quantity_title(self) -> str:
        """Name and unit of the image shown (the colour bar's title), see
        :func:`quantity_title`."""
        return quantity_title(self.quantity, self.scene)

    @property
    def bright(self) -> str:
        """``"low"`` for the images whose low values are drawn white (intensities, see
        :attr:`cmap`), else ``"high"``: as :func:`xray_viz.output.to_uint16` is told."""
        return "low" if self.cmap == "gray_r" else "high"

    @property
    def display_window(self) -> tuple[float, float, bool]:
        """``(low, high, logarithmic)`` of the radiograph shown: the module's
        :func:`~xray_viz.viz.scene_view.display_window` of its image with ``window`` and
        ``level``."""
        return display_window(self.radiograph.quantity(self.quantity), bright=self.bright,
                              window=self.window, level=self.level)

    @property
    def cmap(self) -> str:
        """Colour map of the image: grey reversed for intensity (and the total and primary of
        a render with scatter), so attenuation is bright; grey for line integrals and path
        lengths; a colour map for the smooth scatter and the scatter-to-primary ratio."""
        if self.quantity in ("scatter", "spr"):
            return "viridis"
        return "gray_r" if self.quantity in ("intensity", "total", "primary") else "gray"

    def _text(self, text, position, name, *, font_size=FONT_SIZES["text"], justify="left", vertical="top",
              color="black"):
        """Text in the current subplot at ``position``, fractions of the pane, anchored at
        its ``justify`` / ``vertical`` side (fixed pixel size, so it never scales)."""
        actor = self.plotter.add_text(text, position=position, viewport=True,
                                      font_size=font_size, name=name, color=color)
        self.fixed_text(actor, name, actor.GetTextProperty().GetFontSize())
        prop = actor.GetTextProperty()
        getattr(prop, f"SetJustificationTo{justify.capitalize()}")()
        getattr(prop, f"SetVerticalJustificationTo{vertical.capitalize()}")()
        return actor

    def _label(self, point, text, name, *, justify="left", vertical="bottom",
               font_size=FONT_SIZES["text"]):
        """A text anchored at a 3D point of the current subplot."""
        from vtkmodules.vtkRenderingCore import vtkTextActor

        actor = vtkTextActor()
        actor.SetInput(text)
        coord = actor.GetPositionCoordinate()
        coord.SetCoordinateSystemToWorld()
        coord.SetValue(*np.asarray(point, float).ravel()[:3])
        prop = actor.GetTextProperty()
        prop.SetFontSize(font_size)          # (the radiograph's corner labels: never smaller)
        prop.SetColor(0.1, 0.1, 0.1)
        getattr(prop, f"SetJustificationTo{justify.capitalize()}")()
        getattr(prop, f"SetVerticalJustificationTo{vertical.capitalize()}")()
        self.plotter.add_actor(actor, name=name, reset_camera=False, render=False,
                               pickable=False)
        return actor

    # ---------------------------------------------------------------- updates
    def _pane_aspect(self) -> float:
        """Width / height of the current subplot in pixels."""
        w, h = self.plotter.window_size
        x0, y0, x1, y1 = self.plotter.renderer.GetViewport()
        return max((x1 - x0) * w, 1.0) / max((y1 - y0) * h, 1.0)

    def _axes(self):
        """Unit vectors: ``forward`` (source to detector), ``up`` (the detector's VE) and
        ``side`` (``up x forward``, the direction a side view looks along)."""
        return camera.view_axes(self.viewport)

    def view_side(self, *, azimuth: float = 60.0, elevation: float | None = None,
                  view_angle: float = 12.0) -> None:
        """The whole set-up in a three-quarter view, framed to fill :attr:`view_box`: the
        source on the left, the detector on the right with its face (the pixel grid, HO and
        VE) turned towards the viewer, the bodies and rays between them.

        Parameters
        ----------
        azimuth : float
            Degrees the line of sight turns from the side axis (``up x forward``, a view
            across the beam that sees the detector edge-on) towards the beam direction: 0 is
            a pure side view, 90 looks down the beam from behind the source.
        elevation : float, optional
            Degrees from above (the detector's ``up`` stays screen up). By default the one of
            4, 6, ... 32 degrees whose picture fills :attr:`view_box` best: low in a wide box
            (the beam across it), higher in a squarer one (the beam rising along its
            diagonal).
        view_angle : float
            Of the perspective camera, degrees; small is nearly a parallel projection (the
            source end does not look much larger than the detector end).
        """
        self.plotter.subplot(*self.subplot_3d)
        framing = camera.side_view(self.viewport, self.bodies_bounds,
                                   aspect=self._pane_aspect(), box=self.view_box,
                                   azimuth=azimuth, elevation=elevation,
                                   view_angle=view_angle, zoom=self.zoom,
                                   source_radius=0.6 * self.size_scale)
        self._apply(framing)
        self.camera_view = "side"
        self.side_elevation = framing.elevation

    def view_bodies(self, *, zoom: float = 1.0, azimuth: float = -14.0,
                    elevation: float = 4.0) -> None:
        """Close-up of the bodies from behind and beside the source, looking down the beam:
        the bodies in front, the detector (and its texture) behind them, all in view.

        ``azimuth`` and ``elevation`` (degrees) turn the line of sight away from the beam
        axis, to the side and from above, so the bodies do not hide their shadow. The
        defaults put the (out of view) source to the right at about mid-height, so the rays
        come in from the right edge of the pane, clear of the legend, the key help, the check
        boxes (left) and the mu(t) chart (below)."""
        self.plotter.subplot(*self.subplot_3d)
        framing = camera.bodies_view(self.viewport, self.bodies_bounds,
                                     aspect=self._pane_aspect(),
                                     box=self.bodies_view_box or self.view_box, zoom=zoom,
                                     azimuth=azimuth, elevation=elevation)
        self._apply(framing)
        self.camera_view = "bodies"

    def _apply(self, framing) -> None:
        """Put the 3D camera where ``framing`` (:mod:`xray_viz.viz.camera`) says and pin it
        there."""
        cam = self.plotter.camera
        cam.parallel_projection = False
        cam.view_angle = framing.view_angle
        self._framed_box = framing.box
        cam.SetWindowCenter(*framing.window_center)     # focal point at the box centre
        cam.focal_point = tuple(framing.focal_point)
        cam.position = tuple(framing.position)
        cam.up = tuple(framing.up)
        self.plotter.reset_camera_clipping_range()
        self._pinned = self._camera_state()
        self._camera_set = True
        if "vec-labels-labels" in self.plotter.actors:
            self._draw_vector_labels()          # keep the labels in the new view

    def _camera_state(self):
        cam = self.plotter.renderers[self.plotter.renderers.loc_to_index(
            self.subplot_3d)].camera
        return (tuple(np.round(cam.position, 6)), tuple(np.round(cam.focal_point, 6)),
                tuple(np.round(cam.up, 6)))

    def camera_is_pinned(self) -> bool:
        """Whether the 3D camera is still where :meth:`view_side` / :meth:`view_bodies`
        put it (the user has not turned or zoomed it)."""
        return getattr(self, "_pinned", None) == self._camera_state()

    def reset_camera(self) -> None:
        """Pin the 3D camera to the side view of the whole set-up (:meth:`view_side`)."""
        self.view_side()

    def set_scene(self, scene, *, radiograph=None) -> None:
        """Show another scene (for example the source moved), and optionally its radiograph."""
        self.scene = scene
        if radiograph is not None:
            self.radiograph = radiograph
        self.draw()

    def set_rays(self, rays) -> None:
        """Choose which rays are drawn (see :func:`~xray_viz.viz.rays.select_pixels`)."""
        self.rays = rays
        self._draw_rays()

    def set_radiograph(self, radiograph, *, window=None, level=None) -> None:
        """Show a new radiograph (and texture, when on); ``window``/``level`` as in
        :func:`window_level_limits`."""
        self.radiograph = radiograph
        self.window, self.level = window, level
        if self.texture:
            self._draw_detector()
        if self.subplot_image is not None:
            self._draw_radiograph()

    def set_window_level(self, window=None, level=None) -> None:
        """Grey-level window of the radiograph (and its texture): colours span
        ``level +- window / 2``; None for either takes it from the image's range (see
        :func:`window_level_limits`)."""
        self.set_radiograph(self.radiograph, window=window, level=level)

    @property
    def window_level(self) -> tuple[float, float]:
        """``(window, level)`` in use, the image's range filled in for unset values."""
        if self.radiograph is None:
            return math.nan, math.nan
        lo, hi, _ = self.display_window
        return hi - lo, (hi + lo) / 2

    def show_pixel(self, i: int, j: int) -> RaySelection:
        """Draw the ray of pixel (i, j) and its hits in 3D, and mark the pixel in the image.

        Returns
        -------
        RaySelection
            One ray, with its hits from the tracer.
        """
        sel = trace_selection(self.scene, [(int(i), int(j))])
        self.picked = sel
        self.show["picked"] = True
        self._ray_actors(sel, "picked-ray", color=COLORS["picked"],
                         width=LINE_WIDTHS["picked"])
        if self.subplot_image is not None and self.radiograph is not None:
            self.plotter.subplot(*self.subplot_image)
            x, y = float(i), float(j)
            outline = shapes.rectangle(x - .5, y - .5, x + .5, y + .5, .2)
            self.datasets["picked-pixel"] = outline
            self.plotter.add_mesh(outline, name="picked-pixel", color=COLORS["picked"],
                                  line_width=LINE_WIDTHS["picked_pixel"], lighting=False,
                                  reset_camera=False,
                                  render=False, pickable=False)
            self.plotter.subplot(*self.subplot_3d)
        return sel



# ------------------------------------------------------------------------------------------
# voxel volumes (issue 40): three orthogonal slices

#: The CT slices' default HU window (width, level): soft tissue (W 400, L 40).
VOLUME_WINDOW = (400.0, 40.0)
#: Opacity of a volume's slices (the bodies inside show through).
OPACITY_SLICE = 0.85
#: Points drawn along a slice's side, at most.
SLICE_POINTS = 256


#: The actors of a volume drawn in each style (:meth:`SceneView.set_volume_style`), after
#: ``volume:<name>``; its ``:box`` is drawn in both.
VOLUME_PARTS = {"slices": (":slice:i", ":slice:j", ":slice:k"), "volume": (":render",)}

#: At most this many voxels go to the volume rendering (2**23, 32 MB of float32): a larger
#: grid is shown every n-th voxel along each axis (:func:`volume_grid`).
VOLUME_RENDER_VOXELS = 2 ** 23

#: The CT volume rendering's opacity per mm of ray (VTK's scalar opacity at unit distance) at
#: HU points (the HU of the slices, :func:`voxel_hu`), linear between: air and lung
#: transparent, fat and soft tissue faint, bone (and contrast-filled vessels) from faint to
#: nearly opaque.
CT_OPACITY = ((-1000.0, 0.0), (-300.0, 0.0), (-100.0, 0.002), (100.0, 0.006),
              (180.0, 0.03), (400.0, 0.5), (1000.0, 0.85), (3000.0, 0.95))

#: The CT volume rendering's colours (RGB, 0 to 1) at HU points, linear between: soft tissue
#: red-brown, bone ivory to white.
CT_COLORS = ((-1000.0, (0.0, 0.0, 0.0)), (-100.0, (0.75, 0.45, 0.35)),
             (100.0, (0.85, 0.35, 0.3)), (250.0, (0.95, 0.88, 0.75)),
             (1000.0, (1.0, 1.0, 0.97)), (3000.0, (1.0, 1.0, 1.0)))

#: A label map's classes in the volume rendering: opacity per mm of each non-empty class.
LABEL_OPACITY = 0.02


def _piecewise(points):
    """A ``vtkPiecewiseFunction`` through ``(x, y)`` points."""
    from vtkmodules.vtkCommonDataModel import vtkPiecewiseFunction

    f = vtkPiecewiseFunction()
    for x, y in points:
        f.AddPoint(float(x), float(y))
    return f


def _color_function(points):
    """A ``vtkColorTransferFunction`` through ``(x, (r, g, b))`` points."""
    from vtkmodules.vtkRenderingCore import vtkColorTransferFunction

    f = vtkColorTransferFunction()
    for x, rgb in points:
        f.AddRGBPoint(float(x), *(float(c) for c in rgb))
    return f


def _label_transfer(vol):
    """A label map's opacity and colour points: class 0 transparent, each class a step of
    :data:`LABEL_OPACITY` in its ``tab10`` colour (as on the slices)."""
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    n = max(1, len(vol.materials))
    opacity, colors = [(0.0, 0.0), (0.5, 0.0)], [(0.0, (0.0, 0.0, 0.0))]
    for k in range(1, n + 1):
        opacity += [(k - 0.49, LABEL_OPACITY), (k + 0.49, LABEL_OPACITY)]
        colors += [(float(k), tuple(cmap(k / n)[:3]))]
    return opacity, colors


def volume_grid(vol, *, max_voxels: int = VOLUME_RENDER_VOXELS):
    """A voxel volume as a ``pyvista.ImageData`` for the volume rendering, and the matrix
    that places it in the scene.

    The grid's points are the voxel centres (every ``step``-th along each axis when the volume
    has more than ``max_voxels`` voxels: ``step`` is the smallest whole number that brings it
    under), its spacing the voxels' sizes in mm, its origin 0; the matrix (the actor's user
    matrix) is the affine's direction cosines and its origin, so that grid point ``p`` lands at
    ``matrix @ p = affine @ (step * index)``. Point data: ``hu`` (:func:`voxel_hu`, float32)
    and ``class``.

    Parameters
    ----------
    vol : VoxelVolume
    max_voxels : int
        At most this many voxels in the grid.

    Returns
    -------
    grid : pyvista.ImageData
    matrix : (4, 4) numpy.ndarray

    Examples
    --------
    >>> import numpy as np
    >>> from xray_viz.volume import ct_volume
    >>> vol = ct_volume(np.zeros((40, 30, 20)), np.diag([2.0, 1.0, 3.0, 1.0]), name="ct")
    >>> grid, matrix = volume_grid(vol, max_voxels=5000)
    >>> grid.dimensions, grid.spacing
    ((20, 15, 10), (4.0, 2.0, 6.0))
    >>> grid.point_data["hu"].max()
    np.float32(0.0)
    """
    shape = np.asarray(vol.shape)
    step = 1
    while int(np.prod(-(-shape // step))) > max_voxels:
        step += 1
    take = (slice(None, None, step),) * 3
    a = np.asarray(vol.affine, dtype=np.float64)
    spacing = np.linalg.norm(a[:3, :3], axis=0)
    matrix = np.eye(4)
    matrix[:3, :3] = a[:3, :3] / spacing
    matrix[:3, 3] = a[:3, 3]
    classes = np.asarray(vol.classes[take])
    hu = voxel_hu(vol.weights[take], classes).astype(np.float32)
    grid = pv.ImageData(dimensions=hu.shape, spacing=tuple(step * spacing), origin=(0, 0, 0))
    grid.point_data["hu"] = hu.ravel(order="F")
    grid.point_data["class"] = classes.ravel(order="F").astype(np.float32)
    return grid, matrix


def hu_window_limits(window: float, level: float) -> tuple:
    """``(low, high)`` HU of a window of ``window`` HU about ``level``.

    Examples
    --------
    >>> hu_window_limits(400.0, 40.0)
    (-160.0, 240.0)
    """
    return (float(level) - float(window) / 2, float(level) + float(window) / 2)


def _is_ct(vol) -> bool:
    """A CT traced by voxel densities (its classes' materials at 1 g/cm3), not a label map."""
    table = getattr(vol, "table", None)
    if table is not None:
        return table[0] == "ct"
    return all(m.density == 1.0 or m.mu is not None for m in vol.materials) and bool(
        np.any(np.asarray(vol.weights) != 1.0))


def voxel_hu(weights, classes) -> np.ndarray:
    """HU shown for a CT's voxels: the density through the water line of the Hounsfield
    scale, ``HU = 1000 (rho - 1)`` (the CT's own calibration below 120 HU; bone, whose HU
    rise faster with density, shows lower than its HU: 1200 HU as about 730), and -1000 for
    empty voxels (air).

    Examples
    --------
    >>> voxel_hu(np.array([1.04, 0.26, 0.0]), np.array([3, 1, 0], np.uint8)).tolist()
    [40.0, -740.0, -1000.0]
    """
    w = np.asarray(weights, dtype=np.float64)
    hu = np.round(1000.0 * (w - 1.0), 6)
    return np.where(np.asarray(classes) > 0, hu, -1000.0)


def volume_slices(vol, *, index=None, max_points: int = SLICE_POINTS) -> dict:
    """Three orthogonal slices of a voxel volume as PyVista grids in scene mm.

    Parameters
    ----------
    vol : VoxelVolume
    index : (int, int, int), optional
        The voxel the three slices pass through (default: the middle one).
    max_points : int
        At most this many points along a slice's side (every n-th voxel).

    Returns
    -------
    dict
        ``{"i": grid, "j": grid, "k": grid}``: the slice across each index axis, each a
        ``pyvista.StructuredGrid`` at the voxel centres with point data ``weight`` (the
        voxel's weight: a CT's density, g/cm3), ``class`` and ``hu`` (:func:`voxel_hu`).
    """
    import pyvista as pv

    shape = vol.shape
    centre = [n // 2 for n in shape] if index is None else [int(x) for x in index]
    out = {}
    for axis, name in enumerate("ijk"):
        others = [a for a in range(3) if a != axis]
        step = max(1, -(-max(shape[a] for a in others) // max_points))
        ranges = [np.arange(0, shape[a], step) for a in others]
        u, v = np.meshgrid(*ranges, indexing="ij")
        idx = np.zeros(u.shape + (3,))
        idx[..., others[0]] = u
        idx[..., others[1]] = v
        idx[..., axis] = centre[axis]
        take = [slice(None)] * 3
        take[axis] = centre[axis]
        take[others[0]] = slice(None, None, step)
        take[others[1]] = slice(None, None, step)
        weights = np.asarray(vol.weights[tuple(take)], dtype=np.float64)
        classes = np.asarray(vol.classes[tuple(take)])
        grid = pv.StructuredGrid()
        # points in Fortran order of (u, v): VTK's structured order, u fastest
        pts = idx.transpose(1, 0, 2).reshape(-1, 3) @ vol.affine[:3, :3].T + vol.affine[:3, 3]
        grid.points = pts
        grid.dimensions = (u.shape[0], u.shape[1], 1)
        grid.point_data["weight"] = weights.T.ravel()
        grid.point_data["class"] = classes.T.ravel().astype(np.float64)
        grid.point_data["hu"] = voxel_hu(weights, classes).T.ravel()
        out[name] = grid
    return out


def plot_scene(scene, *, plotter=None, rays="grid 7", radiograph=None, quantity="intensity",
               window=None, level=None, texture=False, show_grid=True, show_vectors=True,
               show_hits=True, show_rays=True, frustum=False, max_grid_lines=33,
               window_size=(1400, 700), off_screen=None) -> SceneView:
    """Draw a scene in 3D (and its radiograph beside it).

    Parameters
    ----------
    scene : Scene
        From :func:`xray_viz.load_scene`. Only read.
    plotter : pyvista.Plotter, optional
        Draw into this plotter: the 3D view in subplot (0, 0), the radiograph in (0, 1) when
        the plotter has two subplots. By default a new ``Plotter(shape=(1, 2))`` (or one
        subplot without a radiograph).
    rays : str, int, sequence of (i, j) or None
        Which rays to draw: ``"grid 7"`` (default), ``"every 16"``, ``"row 128"``,
        ``"column 10"``, ``"center"``, ``[(i, j), ...]`` or None
        (see :func:`~xray_viz.viz.rays.select_pixels`).
    radiograph : Radiograph, True or None
        The image to show on the right; True renders it now with :func:`xray_viz.render`.
    quantity : {"intensity", "line-integral", "path-length"}
        Which image of the radiograph to show.
    window, level : float, optional
        Grey-level window: colours span ``level +- window / 2`` (default: the image range).
    texture : bool
        Also drape the radiograph on the detector plane in 3D.
    show_grid, show_vectors, show_hits, show_rays, frustum : bool
        Initial visibility of the pixel grid, the HO/VE/FL/LHC arrows, the hit glyphs, the rays
        and the beam's frustum.
    max_grid_lines : int
        Draw at most this many grid lines each way (always including the viewport edges).
    window_size : (int, int)
        Size of a new plotter's window in pixels.
    off_screen : bool, optional
        For a new plotter; default ``pyvista.OFF_SCREEN``.

    Returns
    -------
    SceneView

    Examples
    --------
    >>> import pyvista as pv, xray_viz
    >>> from xray_viz.viz import plot_scene
    >>> view = plot_scene(xray_viz.load_scene("sphere"), rays="row 128", radiograph=True,
    ...                   off_screen=True)
    >>> sorted(n for n in view.plotter.actors if n.startswith("vec:"))
    ['vec:FL', 'vec:HO', 'vec:LHC', 'vec:VE']
    >>> view.plotter.close()
    """
    if radiograph is True:
        from xray_viz.render import render

        radiograph = render(scene)
    if plotter is None:
        shape = (1, 2) if radiograph is not None else (1, 1)
        plotter = pv.Plotter(shape=shape, window_size=list(window_size),
                             off_screen=pv.OFF_SCREEN if off_screen is None else off_screen,
                             border=False)
        plotter.set_background("white")
    two = getattr(plotter, "shape", (1, 1)) != (1, 1)
    view = SceneView(
        plotter=plotter, scene=scene, rays=rays, radiograph=radiograph, quantity=quantity,
        window=window, level=level, texture=bool(texture), max_grid_lines=max_grid_lines,
        show={"grid": show_grid, "vectors": show_vectors, "hits": show_hits,
              "rays": show_rays, "frustum": frustum},
        subplot_image=(0, 1) if two else None,
    )
    return view.draw()

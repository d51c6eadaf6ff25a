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
* a chosen subset of rays from the source to their pixels, the parts inside bodies highlighted,
  entries and exits as spheres and cubes - every point taken from
  :func:`xray_viz.tracing.trace_rays`;

and in the right subplot the radiograph, row 0 at the top as in the image arrays, with its
own colour bar and window/level. It can also be draped on the detector plane as a texture.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import pyvista as pv

from xray_viz.geometry import pixel_coordinates, viewport
from xray_viz.viz.rays import RaySelection, inside_segments, trace_selection

__all__ = ["SceneView", "plot_scene", "material_label", "grid_indices", "image_to_grid",
           "window_level_limits"]

#: Colours given to materials in order of appearance (matplotlib's tab10).
PALETTE = ("#1f77b4", "#ff7f0e", "#2ca02c", "#d62728", "#9467bd", "#8c564b", "#e377c2",
           "#7f7f7f", "#bcbd22", "#17becf")

COLORS = {
    "source": "gold",
    "detector": "#9aa4b1",
    "grid": "#303841",
    "ray": "#e0c000",
    "inside": "#d62728",
    "entry": "#2ca02c",
    "exit": "#1f3fbf",
    "picked": "magenta",
    "frustum": "#888888",
    "HO": "#d62728",
    "VE": "#2ca02c",
    "FL": "#1f77b4",
    "LHC": "#9467bd",
}

#: Actor names of each toggleable group of the 3D view.
GROUPS = {
    "bodies": (),            # filled per scene: "body:<name>"
    "source": ("source",),
    "detector": ("detector",),
    "grid": ("grid",),
    "vectors": ("vec:HO", "vec:VE", "vec:FL", "vec:LHC", "vec-labels"),
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
    """
    if body.material is not None:
        return body.material + (f" {body.density:g} g/cm3" if body.density else "")
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


def _arrow(start, vector, *, tip: float) -> pv.PolyData:
    """An arrow from ``start`` along ``vector`` with a tip ``tip`` mm long (not scaled)."""
    length = float(np.linalg.norm(vector))
    f = min(0.4, tip / max(length, 1e-12))
    return pv.Arrow(start=start, direction=vector, tip_length=f, tip_radius=0.35 * f,
                    shaft_radius=0.08 * f, scale=length)


def _lines(starts, ends) -> pv.PolyData:
    starts = np.asarray(starts, float).reshape(-1, 3)
    ends = np.asarray(ends, float).reshape(-1, 3)
    n = len(starts)
    points = np.empty((2 * n, 3))
    points[0::2], points[1::2] = starts, ends
    cells = np.column_stack([np.full(n, 2), np.arange(0, 2 * n, 2), np.arange(1, 2 * n, 2)])
    return pv.PolyData(points, lines=cells.ravel()) if n else pv.PolyData()


def _glyphs(points, geom) -> pv.PolyData:
    points = np.asarray(points, float).reshape(-1, 3)
    if not len(points):
        return pv.PolyData()
    return pv.PolyData(points).glyph(geom=geom, scale=False, orient=False)


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
    zoom: float = 0.88
    status: str = ""
    slider_band: float = 0.0
    view_box: tuple = (0.02, 0.06, 0.98, 0.8)
    camera_view: str = "side"
    _camera_set: bool = False

    # ---------------------------------------------------------------- helpers
    @property
    def viewport(self):
        """The thesis' viewport vectors of the current scene."""
        return viewport(self.scene.source.position, self.scene.detector)

    @property
    def size_scale(self) -> float:
        """A length (mm) that sets marker and arrow-tip sizes: 1/40 of the scene's extent."""
        vp = self.viewport
        return max(np.linalg.norm(vp.FL), np.linalg.norm(vp.HO), np.linalg.norm(vp.VE)) / 40

    @property
    def bodies_bounds(self):
        """``(lo, hi)``, the (3,) corners of the box around all bodies (the detector's if
        there are none)."""
        if self.scene.bodies:
            lo = np.min([b.vertices.min(axis=0) for b in self.scene.bodies], axis=0)
            hi = np.max([b.vertices.max(axis=0) for b in self.scene.bodies], axis=0)
            return lo, hi
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
        if group == "bodies":
            return tuple(f"body:{b.name}" for b in self.scene.bodies)
        return GROUPS[group]

    def set_visible(self, group: str, visible: bool) -> None:
        """Show or hide a group: ``"bodies"``, ``"source"``, ``"detector"``, ``"grid"``,
        ``"vectors"``, ``"frustum"``, ``"rays"``, ``"hits"`` or ``"picked"``."""
        if group not in GROUPS:
            raise ValueError(f"unknown group {group!r}; choose one of {', '.join(GROUPS)}")
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
            color = labels.setdefault(label, PALETTE[len(labels) % len(PALETTE)])
            name = f"body:{body.name}"
            try:
                key = (id(body.mesh), hash(body.mesh), color)
            except TypeError:
                key = None
            if key is not None and drawn.get(name) == key and name in self.plotter.actors:
                continue        # the same mesh in the same colour (the source moved): keep it
            mesh = pv.PolyData.from_regular_faces(body.vertices, body.faces)
            self._add(name, mesh, group="bodies", color=color, opacity=0.35,
                      smooth_shading=True, specular=0.3)
            drawn[name] = key
        self._drawn_bodies = drawn
        self.material_colors = labels

    def _draw_source(self):
        vp = self.viewport
        marker = pv.Sphere(radius=0.4 * self.size_scale, center=vp.r0)
        self._add("source", marker, group="source", color=COLORS["source"])

    def _draw_detector(self):
        vp = self.viewport
        w, h = vp.shape
        corners = np.array([vp.LHC, vp.LHC + vp.HO, vp.LHC + vp.HO + vp.VE, vp.LHC + vp.VE])
        # The plane sits a hair behind the pixel positions so the grid lines stay visible.
        back = vp.forward * 1e-3 * self.size_scale
        plane = pv.PolyData(corners + back, faces=[4, 0, 1, 2, 3])
        plane.active_texture_coordinates = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], float)
        if self.texture and self.radiograph is not None:
            image = self.radiograph.quantity(self.quantity)
            lo, hi = window_level_limits(image, window=self.window, level=self.level)
            gray = np.clip((image - lo) / max(hi - lo, 1e-300), 0, 1)
            gray = np.nan_to_num(gray, nan=0.0)
            if self.cmap == "gray_r":                 # as in the 2D view: attenuation bright
                gray = 1.0 - gray
            rgb = np.repeat((gray * 255).astype(np.uint8)[..., None], 3, axis=2)
            self._add("detector", plane, group="detector", texture=pv.Texture(rgb),
                      lighting=False)
        else:
            self._add("detector", plane, group="detector", color=COLORS["detector"],
                      opacity=0.45, lighting=False)
        ii = grid_indices(w, max_lines=self.max_grid_lines)
        jj = grid_indices(h, max_lines=self.max_grid_lines)
        u, v = pixel_coordinates((w, h))
        uu = u[0, ii]                         # u of columns ii
        vv = v[::-1, 0][jj]                   # v of rows-from-bottom jj
        pts = vp.LHC + uu[:, None, None] * vp.HO + vv[None, :, None] * vp.VE   # (ni, nj, 3)
        grid = pv.StructuredGrid(pts[..., 0][..., None], pts[..., 1][..., None],
                                 pts[..., 2][..., None])
        self.grid_ij = (ii, jj)
        self._add("grid", grid, group="grid", style="wireframe", color=COLORS["grid"],
                  line_width=1, lighting=False, opacity=0.7 if len(ii) > 12 else 1.0)
        if len(ii) < w or len(jj) < h:
            self.grid_label = (f"pixel grid: {len(ii)} x {len(jj)} of {w} x {h} rays drawn "
                               f"(step {max(1, ii[1] - ii[0]) if len(ii) > 1 else 1})")
        else:
            self.grid_label = f"pixel grid: all {w} x {h} rays"
        self.plotter.subplot(*self.subplot_3d)
        self._text(self.grid_label, (0.01, 0.008), "grid-label", font_size=8,
                   vertical="bottom")

    def _draw_vectors(self):
        vp = self.viewport
        # tips: readable in the side view, not swamping the detector in a close-up
        tip = min(1.5 * self.size_scale,
                  0.15 * min(np.linalg.norm(vp.HO), np.linalg.norm(vp.VE)))
        center = vp.LHC + vp.HO / 2 + vp.VE / 2
        arrows = {
            "HO": (vp.LHC, vp.HO),
            "VE": (vp.LHC, vp.VE),
            "FL": (center, vp.FL),
            "LHC": (vp.r0, vp.LHC - vp.r0),
        }
        label_pts, labels = [], []
        for key, (start, vec) in arrows.items():
            self._add(f"vec:{key}", _arrow(start, vec, tip=tip), group="vectors",
                      color=COLORS[key])
            frac = {"HO": 0.6, "VE": 0.6, "FL": 0.5, "LHC": 0.35}[key]
            label_pts.append(np.asarray(start) + frac * np.asarray(vec))
            labels.append(key if key != "LHC" else "LHC - r0")
        label_pts.append(vp.r0)
        labels.append("r0 (source)")
        self.plotter.subplot(*self.subplot_3d)
        actor = self.plotter.add_point_labels(
            np.asarray(label_pts), labels, font_size=12, bold=True, show_points=False,
            shape_opacity=0.6, always_visible=True, name="vec-labels", reset_camera=False,
            render=False)
        actor.SetVisibility(self.is_visible("vectors"))

    def _draw_frustum(self):
        vp = self.viewport
        corners = np.array([vp.LHC, vp.LHC + vp.HO, vp.LHC + vp.HO + vp.VE, vp.LHC + vp.VE])
        if self.scene.source.kind == "parallel":
            starts = corners + vp.FL
        else:
            starts = np.repeat(vp.r0[None], 4, axis=0)
        self._add("frustum", _lines(starts, corners), group="frustum",
                  color=COLORS["frustum"], line_width=1)

    def _ray_actors(self, sel: RaySelection, prefix: str, *, color, width):
        starts, ends, _ = inside_segments(sel.hits)
        entry = sel.hits.point[sel.hits.entering]
        exit_ = sel.hits.point[~sel.hits.entering]
        r = self.glyph_radius
        group = "rays" if prefix == "rays" else "picked"
        self._add(prefix, _lines(sel.origins, sel.ends), group=group, color=color,
                  line_width=width, lighting=False)
        self._add(f"{prefix}-inside", _lines(starts, ends), group=group,
                  color=COLORS["inside"], line_width=width + 3, lighting=False)
        hits_group = "hits" if prefix == "rays" else "picked"
        name_entry = "hits-entry" if prefix == "rays" else "picked-entry"
        name_exit = "hits-exit" if prefix == "rays" else "picked-exit"
        a = self._add(name_entry, _glyphs(entry, pv.Sphere(radius=r)), group=hits_group,
                      color=COLORS["entry"])
        b = self._add(name_exit, _glyphs(exit_, pv.Cube(x_length=1.6 * r, y_length=1.6 * r,
                                                        z_length=1.6 * r)),
                      group=hits_group, color=COLORS["exit"])
        for actor in (a, b):
            if actor is not None and prefix != "rays":
                actor.SetVisibility(self.is_visible("hits") and self.is_visible("picked"))

    def _draw_rays(self):
        self.selection = trace_selection(self.scene, self.rays)
        self._ray_actors(self.selection, "rays", color=COLORS["ray"], width=1)

    def _draw_legend(self):
        self.plotter.subplot(*self.subplot_3d)
        entries = [[f"{label}", color] for label, color in self.material_colors.items()]
        entries += [["source r0", COLORS["source"]], ["ray", COLORS["ray"]],
                    ["inside a body", COLORS["inside"]], ["entry hit (sphere)", COLORS["entry"]],
                    ["exit hit (cube)", COLORS["exit"]]]
        self.plotter.add_legend(entries, bcolor="white", border=True, size=(0.28, min(0.3, 0.026 * len(entries))),
                                loc="upper left", face="rectangle", background_opacity=0.7)

    def _draw_radiograph(self):
        """The image in the right subplot, laid out in fractions of the pane: the title on
        top, the image in a box below it (above :attr:`slider_band`, kept for the viewer's
        sliders), the colour bar to its right."""
        pl = self.plotter
        pl.subplot(*self.subplot_image)
        rg = self.radiograph
        image = rg.quantity(self.quantity)
        h, w = image.shape
        title = {"intensity": "I / I0", "line-integral": "line integral",
                 "path-length": "path length (mm)"}.get(self.quantity, self.quantity)
        grid = image_to_grid(image, name=title)
        self.datasets["radiograph"] = grid
        clim = window_level_limits(image, window=self.window, level=self.level)
        # Attenuation bright, as radiologists read films: low I / I0 is white.
        cmap = self.cmap
        # box of the image, fractions of the pane: left, bottom, right, top
        x0, x1 = 0.06, 0.76
        y0, y1 = max(0.07, self.slider_band + 0.06), 0.86
        for old in list(pl.scalar_bars.keys()):            # re-placed on every draw
            pl.remove_scalar_bar(old, render=False)
        pl.add_mesh(grid, name="radiograph", scalars=title, cmap=cmap, clim=clim,
                    lighting=False, show_scalar_bar=True, reset_camera=False, render=False,
                    scalar_bar_args=dict(title=title, vertical=True, position_x=0.8,
                                         position_y=y0 + 0.1 * (y1 - y0),
                                         height=0.8 * (y1 - y0), width=0.05,
                                         fmt="%.3g", title_font_size=12, label_font_size=11,
                                         color="black", n_labels=5))
        frame = pv.lines_from_points(np.array([[-.5, -.5, .05], [w - .5, -.5, .05],
                                               [w - .5, h - .5, .05], [-.5, h - .5, .05],
                                               [-.5, -.5, .05]]))
        pl.add_mesh(frame, name="radiograph-frame", color="black", line_width=1,
                    lighting=False, reset_camera=False, render=False, pickable=False)
        # camera: parallel projection, the image centred in its box
        aspect = self._pane_aspect()
        scale = 0.5 * max(h / (y1 - y0), w / ((x1 - x0) * aspect))     # half the view height
        cx = (w - 1) / 2 - ((x0 + x1) / 2 - 0.5) * 2 * scale * aspect
        cy = (h - 1) / 2 - ((y0 + y1) / 2 - 0.5) * 2 * scale
        pl.view_xy()
        pl.camera.parallel_projection = True
        pl.camera.focal_point = (cx, cy, 0.0)
        pl.camera.position = (cx, cy, 10.0 * max(w, h))
        pl.camera.up = (0.0, 1.0, 0.0)
        pl.camera.parallel_scale = scale
        pl.reset_camera_clipping_range()
        # corner labels just outside the frame: (0, 0) below its lower-left corner,
        # (w-1, h-1) above its upper-right corner
        pad = 0.012 * 2 * scale
        corners = np.array([[-0.5, -0.5 - pad, 0.1], [w - 0.5, h - 0.5 + pad, 0.1]])
        self._label(corners[:1], "(i, j) = (0, 0): LHC", "radiograph-corner-00",
                    justify="left", vertical="top")
        self._label(corners[1:], f"({w - 1}, {h - 1})", "radiograph-corner-wh",
                    justify="right", vertical="bottom")
        engine = getattr(rg, "engine", "?")
        total = rg.timing.get("total", float("nan")) if getattr(rg, "timing", None) else math.nan
        lines = [f"radiograph: {self.quantity}, {w} x {h}, row 0 at the top"]
        if self.status:
            lines.append(self.status)
        lines.append(f"engine {engine}: {total * 1000:.0f} ms")
        self._text("\n".join(lines), (0.03, 0.985), "radiograph-title", font_size=8)
        pl.subplot(*self.subplot_3d)

    @property
    def cmap(self) -> str:
        """Grey map of the image: reversed for intensity, so attenuation is bright."""
        return "gray_r" if self.quantity == "intensity" else "gray"

    def _text(self, text, position, name, *, font_size=9, justify="left", vertical="top",
              color="black"):
        """Text in the current subplot at ``position``, fractions of the pane, anchored at
        its ``justify`` / ``vertical`` side (fixed pixel size, so it never scales)."""
        actor = self.plotter.add_text(text, position=position, viewport=True,
                                      font_size=font_size, name=name, color=color)
        prop = actor.GetTextProperty()
        getattr(prop, f"SetJustificationTo{justify.capitalize()}")()
        getattr(prop, f"SetVerticalJustificationTo{vertical.capitalize()}")()
        return actor

    def _label(self, point, text, name, *, justify="left", vertical="bottom", font_size=9):
        """A text anchored at a 3D point of the current subplot."""
        from vtkmodules.vtkRenderingCore import vtkTextActor

        actor = vtkTextActor()
        actor.SetInput(text)
        coord = actor.GetPositionCoordinate()
        coord.SetCoordinateSystemToWorld()
        coord.SetValue(*np.asarray(point, float).ravel()[:3])
        prop = actor.GetTextProperty()
        prop.SetFontSize(font_size)
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
        vp = self.viewport
        forward = -np.asarray(vp.FL, float) / np.linalg.norm(vp.FL)
        up = np.asarray(vp.VE, float) / np.linalg.norm(vp.VE)
        up = up - up.dot(forward) * forward
        up /= np.linalg.norm(up)
        return forward, up, np.cross(up, forward)

    def view_side(self, *, elevation: float = 25.0, azimuth: float = 12.0) -> None:
        """The whole set-up from the side: the beam axis across the pane, the source on the
        left, the detector on the right, seen from ``elevation`` degrees above the axis (the
        detector's ``up`` is screen up) and ``azimuth`` degrees towards the source (so the
        detector's face shows), zoomed so source-to-detector fills the pane's width."""
        vp = self.viewport
        self.plotter.subplot(*self.subplot_3d)
        forward, up, side = self._axes()
        e, a = math.radians(elevation), math.radians(azimuth)
        dop = math.cos(e) * (math.cos(a) * side + math.sin(a) * forward) - math.sin(e) * up
        right = np.cross(dop, up)
        right /= np.linalg.norm(right)
        cam_up = np.cross(right, dop)
        center = np.asarray(vp.LHC + vp.HO / 2 + vp.VE / 2, float)
        focal = (center + np.asarray(vp.r0, float)) / 2
        width = float(np.linalg.norm(vp.FL)) * abs(forward @ right)
        cam = self.plotter.camera
        cam.parallel_projection = False
        cam.view_angle = 20.0
        half = math.tan(math.radians(cam.view_angle) / 2)
        bx0, by0, bx1, by1 = self.view_box
        distance = width / self.zoom / (2 * half * self._pane_aspect() * (bx1 - bx0))
        cam.SetWindowCenter(1.0 - bx0 - bx1, 1.0 - by0 - by1)   # focal point at the box centre
        cam.focal_point = tuple(focal)
        cam.position = tuple(focal - distance * dop)
        cam.up = tuple(cam_up)
        self.plotter.reset_camera_clipping_range()
        self.camera_view = "side"
        self._pinned = self._camera_state()
        self._camera_set = True

    def view_bodies(self, *, zoom: float = 1.0, azimuth: float = 14.0,
                    elevation: float = 10.0) -> None:
        """Close-up of the bodies from behind and beside the source, looking down the beam:
        the bodies in front, the detector (and its texture) behind them, all in view.

        ``azimuth`` and ``elevation`` (degrees) turn the line of sight away from the beam
        axis, to the side and from above, so the bodies do not hide their shadow."""
        vp = self.viewport
        self.plotter.subplot(*self.subplot_3d)
        forward, up, side = self._axes()
        lo, hi = self.bodies_bounds
        corners = np.array([vp.LHC, vp.LHC + vp.HO, vp.LHC + vp.VE, vp.LHC + vp.HO + vp.VE])
        box = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
        a, e = math.radians(azimuth), math.radians(elevation)
        dop = (math.cos(e) * (math.cos(a) * forward + math.sin(a) * side)
               - math.sin(e) * up)                       # camera -> focal point
        right = np.cross(dop, up)
        right /= np.linalg.norm(right)
        screen_up = np.cross(right, dop)
        cam = self.plotter.camera
        cam.parallel_projection = False
        cam.view_angle = 30.0
        # the camera behind the source (as far from the bodies as the source is, or more)
        behind = float((np.asarray(vp.r0) - (lo + hi) / 2) @ -dop) * 1.15
        self._frame(np.vstack([corners, box]), dop, right, screen_up, margin=1.06 / zoom,
                    min_distance=behind, anchor=(lo + hi) / 2)
        self.camera_view = "bodies"

    def _frame(self, points, dop, right, screen_up, *, margin=1.06, min_distance=0.0,
               anchor=None) -> None:
        """Aim the (perspective) camera along ``dop`` so that ``points`` fill the pane,
        centred. With ``min_distance`` the camera stays at least that far (along ``dop``)
        from ``anchor`` and narrows its view angle instead."""
        cam = self.plotter.camera
        bx0, by0, bx1, by1 = self.view_box
        cam.SetWindowCenter(1.0 - bx0 - bx1, 1.0 - by0 - by1)   # focal point at the box centre
        sx = self._pane_aspect() * (bx1 - bx0)      # the box's half-width / half-height,
        sy = by1 - by0                              # in units of the view's half-height
        half_v = math.tan(math.radians(cam.view_angle) / 2) / margin
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
                cam.view_angle = math.degrees(2 * math.atan(half_v * margin))
            # re-centre: shift the focal point to the middle of the points' angular extent
            tx, ty = x / (distance + depth), y / (distance + depth)
            focal = focal + distance * ((tx.max() + tx.min()) / 2 * right
                                        + (ty.max() + ty.min()) / 2 * screen_up)
        cam.focal_point = tuple(focal)
        cam.position = tuple(focal - distance * dop)
        cam.up = tuple(screen_up)
        self.plotter.reset_camera_clipping_range()
        self._pinned = self._camera_state()
        self._camera_set = True

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
        self._ray_actors(sel, "picked-ray", color=COLORS["picked"], width=3)
        if self.subplot_image is not None and self.radiograph is not None:
            self.plotter.subplot(*self.subplot_image)
            x, y = float(i), float(j)
            box = np.array([[x - .5, y - .5, .2], [x + .5, y - .5, .2], [x + .5, y + .5, .2],
                            [x - .5, y + .5, .2], [x - .5, y - .5, .2]])
            outline = pv.lines_from_points(box)
            self.datasets["picked-pixel"] = outline
            self.plotter.add_mesh(outline, name="picked-pixel", color=COLORS["picked"],
                                  line_width=3, lighting=False, reset_camera=False,
                                  render=False, pickable=False)
            self.plotter.subplot(*self.subplot_3d)
        return sel


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

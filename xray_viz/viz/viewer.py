"""The interactive viewer: move the source, turn the bodies, change the energy, pick pixels.

Every widget calls a plain method (:meth:`Viewer.set_source_distance`,
:meth:`Viewer.set_body_rotation`, :meth:`Viewer.set_energy`, :meth:`Viewer.set_resolution`,
:meth:`Viewer.set_window`, :meth:`Viewer.set_level`, :meth:`Viewer.pick_pixel`,
:meth:`Viewer.toggle`), so scripts and tests drive the viewer exactly as the mouse does.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import pyvista as pv

from xray_viz.errors import SceneError
from xray_viz.geometry import viewport
from xray_viz.viz.rays import attenuation_profile, effective_energy, pixel_ray_index
from xray_viz.viz.scene_view import plot_scene

__all__ = ["Viewer", "KEYS", "window_level_ranges"]

#: Key shortcuts (key -> (action, description)), shown on screen.
KEYS = {
    "y": ("rays", "rays"),
    "g": ("grid", "pixel grid"),
    "h": ("hits", "hit points"),
    "o": ("vectors", "HO/VE/FL/LHC arrows"),
    "m": ("frustum", "frustum"),
    "x": ("volume-style", "volume slices/rendering"),
    "v": ("view-side", "side view"),
    "b": ("view-bodies", "bodies close-up"),
    "i": ("screenshot", "screenshot"),
}


def help_text(*, volumes: bool = False) -> str:
    """The on-screen key help: a few short lines (it sits above the 3D view); the voxel
    volumes' key (slices or a volume rendering) only for a scene with ``volumes``."""
    toggles = [f"{k} {d}" for k, (a, d) in KEYS.items()
               if not a.startswith(("view", "scr")) and (volumes or a != "volume-style")]
    others = [f"{k} {d}" for k, (a, d) in KEYS.items() if a.startswith(("view", "scr"))]
    return ("toggle: " + "  ".join(toggles[:3]) + "\n" + "  ".join(toggles[3:])
            + "\n" + "  ".join(others) + "  q quit"
            + "\nclick the radiograph: its ray + mu(t)")

def window_level_ranges(image) -> tuple[tuple[float, float], tuple[float, float], str]:
    """Ranges of the window and level sliders for an image, and the format of their values.

    The level runs over the image's finite range ``[lo, hi]`` and the window from 1/100 of
    that range to twice it (the default window, the whole range, sits mid-way: it can be
    narrowed for contrast or widened), in the image's own units (``I / I0``, or photons when the
    detector's ``I0`` is set); a flat image gets a range of ``|value|`` (or 1) around its
    value. The format shows about three significant digits of the range.

    Examples
    --------
    >>> window_level_ranges([[0.2, 1.0]])
    ((0.008, 1.6), (0.2, 1.0), '%.2f')
    >>> window_level_ranges([[26.0, 1120.0]])
    ((10.94, 2188.0), (26.0, 1120.0), '%.0f')
    """
    a = np.asarray(image, dtype=float)
    finite = a[np.isfinite(a)]
    lo, hi = (float(finite.min()), float(finite.max())) if finite.size else (0.0, 1.0)
    span = hi - lo
    if not span > 0:
        span = abs(hi) or 1.0
        lo, hi = hi - span / 2, hi + span / 2
    digits = max(0, 1 - math.floor(math.log10(span)))
    return (span / 100, 2 * span), (lo, hi), f"%.{digits}f"


#: The check boxes at the bottom left of the 3D pane, from the bottom up.
CHECK_BOXES = ("rays", "grid", "hits", "vectors")

#: Fraction of the radiograph pane's height kept below the image for the sliders.
SLIDER_BAND = 0.3

#: Left and right ends of the three sliders of a row, fractions of the radiograph pane.
SLIDER_COLUMNS = ((0.04, 0.30), (0.37, 0.63), (0.70, 0.96))

#: Part of the 3D pane (left, bottom, right, top fractions) the pinned views fill: between
#: the key help and legend above and the check boxes and mu(t) chart below.
VIEW_BOX = (0.02, 0.35, 0.98, 0.84)

#: The box of the bodies close-up (key ``b``): right of the legend, below the key help.
BODIES_VIEW_BOX = (0.3, 0.35, 0.98, 0.84)


class Viewer:
    """The scene in 3D, its radiograph live beside it, and the controls.

    Parameters
    ----------
    scene : Scene
        The scene as loaded; the controls derive new scenes from it (it is never modified).
    rays : str, int or sequence of (i, j)
        Rays drawn in 3D (see :func:`~xray_viz.viz.rays.select_pixels`).
    resolution : int, optional
        Preview resolution: pixels along the detector's longer side (the physical size is
        kept). Default: the scene's own.
    texture : bool
        Drape the radiograph on the detector plane.
    window_size : (int, int)
    off_screen : bool, optional
        Default ``pyvista.OFF_SCREEN``.
    widgets : bool
        Add the sliders, check boxes and key bindings.
    scatter : {None, "mc", "kernel"}
        Render with scatter (:func:`xray_viz.render`'s ``scatter``; every change of the
        controls renders again, so ``"mc"`` is slow): the radiograph can then be shown as the
        detected total, its primary and scatter parts or their ratio (:meth:`set_quantity`;
        the key ``k`` cycles through them).
    histories : int, optional
        The Monte Carlo's photons for ``scatter="mc"``.
    scatter_smoothing : float, optional
        mm: the Gaussian smoothing of the Monte Carlo's scatter (:func:`xray_viz.render`).

    Notes
    -----
    The anti-scatter grid in front of the detector is on or off (:meth:`set_anti_scatter_grid`,
    the key ``a``): on at first where the scene's detector has one (its ``grid``); turned on,
    a scene without one gets the default grid (:class:`~xray_viz.physics.grid.Grid`: ratio 10,
    60 lines per cm), which lowers the primary by its transmission and the scatter more.

    Examples
    --------
    >>> import pyvista as pv, xray_viz
    >>> from xray_viz.viz import Viewer
    >>> viewer = Viewer(xray_viz.load_scene("sphere"), resolution=64, off_screen=True)
    >>> viewer.set_source_distance(1200.0)
    >>> profile = viewer.pick_pixel(32, 32)
    >>> round(profile.line_integral, 2) == round(float(viewer.radiograph.line_integral[31, 32]), 2)
    True
    >>> viewer.close()
    """

    def __init__(self, scene, *, rays="grid 7", resolution=None, texture=False,
                 window_size=(1400, 700), off_screen=None, widgets=True, scatter=None,
                 histories=None, scatter_smoothing=None):
        self.base_scene = scene
        vp = viewport(scene.source.position, scene.detector)
        self.axis = -vp.forward                          # unit(FL): detector centre -> source
        self.source_distance = float(np.linalg.norm(vp.FL))
        self.rotation = 0.0
        from xray_viz.physics.spectra import DEFAULT_ENERGY

        self.energy = float(scene.source.energy if scene.source.energy is not None
                            else DEFAULT_ENERGY)
        self.kvp = None
        #: The source's spectrum when it is fixed (a CSV file's, or a Spectrum given through
        #: the API): no energy or kVp control then. None for a tube spectrum (the kVp slider)
        #: or a monochromatic beam (the energy slider).
        self.fixed_spectrum = None
        spec = scene.source.spectrum
        if isinstance(spec, Mapping) and "kvp" in spec:
            self.kvp = float(spec["kvp"])
        elif spec is not None:
            from xray_viz.physics.spectra import source_spectrum

            self.fixed_spectrum = source_spectrum(scene.source)
        self.resolution = int(resolution or max(scene.detector.shape))
        from xray_viz.physics.grid import Grid

        #: The anti-scatter grid the key ``a`` puts in front of the detector: the scene's own,
        #: or the default :class:`~xray_viz.physics.grid.Grid` where it has none.
        self.grid = scene.detector.grid if scene.detector.grid is not None else Grid()
        #: Whether the renders have :attr:`grid` in front of the detector
        #: (:meth:`set_anti_scatter_grid`).
        self.anti_scatter_grid = scene.detector.grid is not None
        self.profile = None
        self.picked_pixel = None
        self._listeners = []
        self._shots = itertools.count()
        self.scene = self._build_scene()
        from xray_viz.render import ScatterSource, render

        #: ``"mc"``, ``"kernel"`` or None: what the renders include.
        self.scatter, histories = ScatterSource.options(scene, scatter, histories)
        smoothing = ScatterSource.check_smoothing(self.scatter, scatter_smoothing)
        self._render = functools.partial(render, scatter=self.scatter, histories=histories,
                                         scatter_smoothing=smoothing)
        self.radiograph = self._render(self.scene)
        self.view = plot_scene(self.scene, rays=rays, radiograph=self.radiograph,
                               texture=texture, window_size=window_size, off_screen=off_screen,
                               quantity="intensity" if self.scatter is None else "total")
        self.plotter = self.view.plotter
        if widgets:
            self.view.slider_band = SLIDER_BAND
            self.view.view_box = VIEW_BOX
            self.view.bodies_view_box = BODIES_VIEW_BOX
            self.view.reset_camera()
        # bottom right of the 3D pane, right of the check boxes, below the beam
        self.chart = pv.Chart2D(size=(0.74, 0.28), loc=(0.24, 0.05), x_label="t (mm)",
                                y_label="mu (1/cm)")
        self.chart.visible = False
        self.plotter.subplot(0, 0)
        self.plotter.add_chart(self.chart)
        if widgets:
            self._add_widgets()
        self.plotter.render_window.AddObserver("WindowResizeEvent",
                                               lambda *_: self.fit_to_window())

    # ------------------------------------------------------------------ scene from controls
    def _build_scene(self):
        base = self.base_scene
        det = base.detector
        center = np.asarray(det.center, float)
        source = dataclasses.replace(base.source,
                                     position=center + self.source_distance * self.axis)
        if self.kvp is not None:
            source = dataclasses.replace(source, spectrum={**dict(base.source.spectrum),
                                                           "kvp": self.kvp})
        elif base.source.spectrum is None:
            source = dataclasses.replace(source, energy=self.energy)
        w, h = det.shape
        n = max(2, int(self.resolution))
        scale = n / max(w, h)
        shape = (max(2, round(w * scale)), max(2, round(h * scale)))
        detector = det.from_size(det.center, det.up, shape, det.size) if shape != det.shape \
            else det
        if self.anti_scatter_grid != (det.grid is not None):       # switched by the user
            detector = dataclasses.replace(detector,
                                           grid=self.grid if self.anti_scatter_grid else None)
        from xray_viz.geometry import Acquisition

        acquisition = Acquisition(source=source, detector=detector)
        if self.rotation % 360 != 0 and len(base.bodies):
            # Turning the bodies by +angle is seeing them from a source and detector turned by
            # -angle: the bodies, and all their per-mesh set-up, stay as they are.
            box = base.bodies.bounds
            centre = (box[:, 0].min(axis=0) + box[:, 1].max(axis=0)) / 2
            acquisition = acquisition.rotated(-self.rotation, axis=det.up, center=centre)
        return base.replace(acquisition=acquisition)

    def update(self) -> None:
        """Rebuild the scene from the controls, re-render and redraw (keeps a picked pixel)."""
        self.scene = self._build_scene()
        self.radiograph = self._render(self.scene)
        picked = self.view.picked
        self.view.picked = None
        pinned = self.view.camera_is_pinned()
        self.view.set_scene(self.scene, radiograph=self.radiograph)
        if pinned:                        # follow the source, unless the user moved the camera
            {"side": self.view.view_side, "bodies": self.view.view_bodies}.get(
                self.view.camera_view, self.view.view_side)()
        if picked is not None:
            w, h = self.scene.detector.shape
            self.pick_pixel(min(int(picked.i[0]), w - 1), min(int(picked.j[0]), h - 1))
        self._update_status()
        self._notify()

    def add_listener(self, listener) -> None:
        """Call ``listener(viewer)`` after every change: a re-render, a picked pixel, a
        window/level, a toggled group (the web page follows the viewer this way)."""
        self._listeners.append(listener)

    def _notify(self) -> None:
        for listener in self._listeners:
            listener(self)

    # ------------------------------------------------------------------ callbacks
    def set_source_distance(self, distance: float) -> None:
        """Move the source along the beam axis to ``distance`` mm from the detector centre."""
        distance = float(distance)
        if not distance > 0:
            raise SceneError(f"source distance must be > 0 mm, got {distance}")
        if distance == self.source_distance:
            return
        self.source_distance = distance
        self.update()

    def set_body_rotation(self, degrees: float) -> None:
        """See the bodies turned by ``degrees`` about the detector's up axis through their
        centre: the source and the detector orbit the other way (the bodies and their
        per-mesh set-up stay as they are)."""
        if float(degrees) == self.rotation:
            return
        self.rotation = float(degrees)
        self.update()

    def set_energy(self, kev: float) -> None:
        """Set the photon energy of a monochromatic source (keV).

        Raises
        ------
        ValueError
            When the source has a spectrum (set its kVp with :meth:`set_kvp` if it is a tube's).
        """
        if self.kvp is not None or self.fixed_spectrum is not None:
            raise SceneError(f"the source has a spectrum ({self._beam_text()}), not one energy"
                             + ("; use set_kvp" if self.kvp is not None else ""))
        if float(kev) == self.energy:
            return
        self.energy = float(kev)
        self.update()

    def set_kvp(self, kvp: float) -> None:
        """Set the tube voltage of a source with a spectrum (kVp)."""
        if float(kvp) == self.kvp:
            return
        self.kvp = float(kvp)
        self.update()

    def set_resolution(self, pixels: float) -> None:
        """Preview resolution: pixels along the detector's longer side (same physical size)."""
        if int(round(pixels)) == self.resolution:
            return
        self.resolution = int(round(pixels))
        self.update()

    def set_anti_scatter_grid(self, on: bool | None = None) -> None:
        """Put the anti-scatter grid (:attr:`grid`) in front of the detector (``True``), take
        it away (``False``) or switch it (None: the key ``a``), and render again: the grid
        lowers the primary by its transmission and, with scatter, the scatter and the SPR
        more."""
        on = (not self.anti_scatter_grid) if on is None else bool(on)
        if on == self.anti_scatter_grid:
            return
        self.anti_scatter_grid = on
        self.update()

    @property
    def quantities(self) -> tuple:
        """What the radiograph can be shown as: ``("intensity",)``, or with scatter
        ``("total", "primary", "scatter", "spr")`` (:meth:`set_quantity`)."""
        from xray_viz.render import SCATTER_QUANTITIES

        return ("intensity",) if self.scatter is None else SCATTER_QUANTITIES

    def set_quantity(self, quantity: str) -> None:
        """Show the radiograph as ``quantity`` (one of :attr:`quantities`; with scatter the
        detected ``"total"``, the noise-free ``"primary"`` and ``"scatter"`` in the
        intensity's units, or ``"spr"``, their ratio); the window and level follow the new
        image's range.

        Raises
        ------
        SceneError
            A quantity the radiograph does not have (a scatter view without scatter).
        """
        if quantity not in self.quantities:
            raise SceneError(f"cannot show the radiograph as {quantity!r}: choose one of "
                             f"{', '.join(self.quantities)}" + (
                                 "" if self.scatter is not None else
                                 " (open the viewer with scatter='mc' or 'kernel' for the "
                                 "primary, scatter and SPR views)"))
        self.view.quantity = quantity
        self.view.window = self.view.level = None
        self._update_status()
        self._notify()

    def _next_quantity(self) -> None:
        q = self.quantities
        now = self.view.quantity if self.view.quantity in q else q[-1]
        self.set_quantity(q[(q.index(now) + 1) % len(q)])

    def set_window(self, window: float) -> None:
        """Grey-level window of the radiograph (a width in the image's units: ``I / I0``, or
        photons when the detector's ``I0`` is set); the level stays (the middle of the
        image's range until it is set)."""
        window = float(window)
        if not window > 0:
            raise SceneError(f"window must be > 0, got {window}")
        self.set_window_level(window, self.view.level)

    def set_level(self, level: float) -> None:
        """Grey-level window's centre (in the image's units, as :meth:`set_window`); the
        window stays (the image's range until it is set)."""
        self.set_window_level(self.view.window, float(level))

    def set_window_level(self, window=None, level=None) -> None:
        """Show the radiograph with colours spanning ``level +- window / 2``; None for
        either: from the image's range (the default). Kept while the other controls
        re-render the image."""
        self.view.set_window_level(window, level)
        self._sync_sliders()
        self._notify()

    def pick_pixel(self, i: int, j: int):
        """Show pixel (i, j)'s ray in 3D and mu along it in the chart.

        With a monochromatic source mu is that of its energy and the chart's line integral is
        the image's. With a spectrum the image holds ``-ln(I / I0)`` of the whole spectrum,
        which no single mu(t) integrates to in general: the chart shows mu at the ray's
        effective energy (:func:`~xray_viz.viz.rays.effective_energy`, the energy whose line
        integral is the image's value) and says what the spectrum's mean energy would give
        (less or more: beam hardening). Where no energy fits (the ray misses every body, or
        its mu is constant) it uses the mean energy.

        Parameters
        ----------
        i, j : int
            Column from the left, row from the bottom (``image[H - 1 - j, i]``).

        Returns
        -------
        AttenuationProfile
            Its ``energy`` is the energy of the chart's mu.
        """
        from xray_viz.physics.spectra import source_spectrum

        w, h = self.scene.detector.shape
        pixel_ray_index((w, h), i, j)                    # range check
        sel = self.view.show_pixel(i, j)
        rg_li = float(self.radiograph.line_integral[h - 1 - j, i])
        spectrum = source_spectrum(self.scene.source)
        t_max = float(sel.t_max[0])
        if len(spectrum) == 1:
            energy = float(spectrum.energies[0])
            profile = attenuation_profile(self.scene, sel.hits, t_max, energy=energy)
            title = (f"pixel ({i}, {j}) at {energy:g} keV: integral mu dt = "
                     f"{profile.line_integral:.4g} (image {rg_li:.4g})")
        else:
            beam = f"{spectrum.kvp:g} kVp" if spectrum.kvp else "spectrum"
            mean = spectrum.mean_energy
            at_mean = attenuation_profile(self.scene, sel.hits, t_max, energy=mean)
            e_eff = effective_energy(self.scene, at_mean, rg_li,
                                     energies=(spectrum.energies[0], spectrum.energies[-1]))
            if e_eff is not None:
                profile = attenuation_profile(self.scene, sel.hits, t_max, energy=e_eff)
                title = (f"pixel ({i}, {j}), {beam}: mu at E_eff = {e_eff:.1f} keV, "
                         f"integral mu dt = {profile.line_integral:.4g}\n= image -ln(I/I0) "
                         f"of the whole spectrum (mean {mean:.1f} keV gives "
                         f"{at_mean.line_integral:.4g}: beam hardening)")
            else:
                profile = at_mean
                title = (f"pixel ({i}, {j}), {beam}: mu at the mean {mean:.1f} keV, "
                         f"integral mu dt = {profile.line_integral:.4g}\nimage -ln(I/I0) of "
                         f"the whole spectrum: {rg_li:.4g}")
        self.profile = profile
        self.picked_pixel = (int(i), int(j))
        x, y = profile.steps()
        self.chart.clear()
        self.chart.line(x, y, color="tab:red", width=2.0)
        self.chart.title = title
        # two lines with a spectrum: smaller, to fit the chart of a 1200 x 600 window
        self.chart.GetTitleProperties().SetFontSize(12 if "\n" not in title else 10)
        self.chart.y_label = f"mu at {profile.energy:.3g} keV (1/cm)"
        self.chart.x_range = [float(profile.t[0]), float(profile.t[-1])]
        top = float(max(profile.mu.max(), 1e-3)) * 1.15
        self.chart.y_range = [0.0, top]
        self.chart.visible = True
        self._notify()
        return profile

    def on_pick(self, point) -> None:
        """Callback of the picker: a point in the radiograph's subplot -> :meth:`pick_pixel`."""
        if point is None:
            return
        w, h = self.scene.detector.shape
        i, j = int(round(point[0])), int(round(point[1]))
        if 0 <= i < w and 0 <= j < h and abs(point[2]) < 0.5:
            self.pick_pixel(i, j)

    def toggle(self, group: str, visible: bool | None = None) -> None:
        """Show/hide ``"rays"``, ``"grid"``, ``"hits"``, ``"vectors"`` or ``"frustum"``."""
        if visible is None:
            visible = not self.view.is_visible(group)
        self.view.set_visible(group, visible)
        self._notify()

    def set_volume_style(self, style: str | None = None) -> None:
        """Draw the voxel volumes as ``"slices"`` or a ``"volume"`` rendering
        (:meth:`~xray_viz.viz.scene_view.SceneView.set_volume_style`); None switches to the other one (key ``x``)."""
        if style is None:
            style = "volume" if self.view.volume_style == "slices" else "slices"
        self.view.set_volume_style(style)
        self.plotter.render()
        self._notify()

    def view_side(self) -> None:
        """Camera: the whole set-up from the side (key ``v``)."""
        self.view.view_side()
        self.plotter.render()

    def view_bodies(self) -> None:
        """Camera: close-up of the bodies with the detector behind them (key ``b``)."""
        self.view.view_bodies()
        self.plotter.render()

    def screenshot(self, path=None) -> Path:
        """Save the window as an image (``xray-viz-N.png`` in the working directory)."""
        path = Path(path) if path else Path(f"xray-viz-{next(self._shots)}.png")
        # Off-screen, once the window has been drawn, the screenshot alone shows the slider
        # labels and the justified texts as they were before the last update: draw first.
        self.plotter.render()
        self.plotter.screenshot(str(path))
        return path

    def show(self) -> None:
        """Open the window (blocks until it is closed)."""
        self.plotter.show()

    def close(self) -> None:
        """Close the window and free the render window.

        Its widgets are taken off first and the garbage collected at once: a closed window's
        objects left to the cyclic collector were finalised later, inside another window's
        render, which crashed Mesa's software rasterizer (a segmentation fault in a slider's
        text overlay, after some hundred tests in one process)."""
        import gc

        plotter = self.plotter
        plotter.clear_slider_widgets()
        plotter.clear_button_widgets()
        plotter.close()
        gc.collect()

    # ------------------------------------------------------------------ widgets
    def _place_checkboxes(self) -> None:
        """The check boxes and their labels at the bottom left of the 3D pane, sized and
        spaced by the window's font scale (26 px boxes 34 px apart at 1200 x 600 and larger)."""
        s = self.view.font_scale
        for k, (box, label) in enumerate(getattr(self, "checkboxes", {}).values()):
            x, y, size = 10 * s, (40 + 34 * k) * s, 26 * s
            box.GetRepresentation().PlaceWidget([x, x + size, y, y + size, 0.0, 0.0])
            label.SetPosition(42 * s, (44 + 34 * k) * s)

    def fit_to_window(self) -> None:
        """Re-scale the fixed-size texts and the check boxes to the window's size (called on
        every resize of the render window: a desktop window or the web page's view)."""
        self.view.fit_text()
        self._place_checkboxes()

    def _beam_text(self) -> str:
        if self.kvp is not None:
            return f"{self.kvp:g} kVp"
        if self.fixed_spectrum is not None:
            return f"spectrum, mean {self.fixed_spectrum.mean_energy:.3g} keV"
        return f"{self.energy:g} keV"

    def _update_status(self) -> None:
        beam = self._beam_text()
        grid = f", grid {self.grid.ratio:g}:1" if self.anti_scatter_grid else ""
        self.view.status = (f"source {self.source_distance:.0f} mm from the detector, bodies "
                            f"turned {self.rotation:.0f} deg, {beam}{grid}")
        self.view.set_radiograph(self.radiograph, window=self.view.window,
                                 level=self.view.level)
        if self.view.picked is not None:
            self.view.show_pixel(int(self.view.picked.i[0]), int(self.view.picked.j[0]))
        self._sync_sliders()

    def _sync_sliders(self) -> None:
        """Put every slider's knob at the value in use; the window and level sliders' ranges
        follow the image's (:func:`window_level_ranges`), widened to the value in use."""
        window, level = self.view.window_level
        values = {"source_distance": self.source_distance, "rotation": self.rotation,
                  "kvp": self.kvp, "energy": self.energy, "resolution": self.resolution,
                  "window": window, "level": level}
        sliders = getattr(self, "sliders", {})
        if "window" in sliders:
            w_rng, l_rng, fmt = window_level_ranges(self.radiograph.quantity(self.view.quantity))
            for key, rng in (("window", w_rng), ("level", l_rng)):
                rep = sliders[key].GetRepresentation()
                rep.SetMinimumValue(min(rng[0], values[key]))
                rep.SetMaximumValue(max(rng[1], values[key]))
                rep.SetLabelFormat(fmt)
        for key, widget in sliders.items():
            widget.GetRepresentation().SetValue(values[key])

    @property
    def slider_ranges(self) -> dict:
        """``{name: (min, max)}`` of every slider, as the widgets have them."""
        return {key: (w.GetRepresentation().GetMinimumValue(),
                      w.GetRepresentation().GetMaximumValue())
                for key, w in getattr(self, "sliders", {}).items()}

    def _add_widgets(self) -> None:
        pl = self.plotter
        fl0 = self.source_distance
        pl.subplot(0, 1)
        style = dict(title_height=0.02, tube_width=0.004, slider_width=0.015,
                     color="black", title_color="black", interaction_event="end")
        rows = (0.2, 0.075)                  # two rows of sliders inside the band kept free
        cols = SLIDER_COLUMNS                # three sliders a row
        window, level = self.view.window_level
        w_rng, l_rng, wl_fmt = window_level_ranges(self.radiograph.quantity(self.view.quantity))
        unit = "photons" if self.view.quantity_title.endswith("(photons)") else "I / I0"
        specs = [
            ("source_distance", self.set_source_distance, (0.3 * fl0, 3.0 * fl0), fl0,
             "source distance (mm)", "%.0f"),
            ("rotation", self.set_body_rotation, (-180.0, 180.0), 0.0,
             "body rotation (deg)", "%.0f"),
            ("kvp", self.set_kvp, (20.0, 150.0), self.kvp, "kVp", "%.0f")
            if self.kvp is not None else None if self.fixed_spectrum is not None else
            ("energy", self.set_energy, (10.0, 150.0), self.energy, "energy (keV)", "%.0f"),
            ("resolution", self.set_resolution, (16, max(512, self.resolution)),
             self.resolution, "preview resolution (px)", "%.0f"),
            ("window", self.set_window, w_rng, window, f"window W ({unit})", wl_fmt),
            ("level", self.set_level, l_rng, level, f"level L ({unit})", wl_fmt),
        ]
        self.sliders = {}
        for k, spec in enumerate(specs):
            if spec is None:                 # a fixed spectrum: no energy control, a gap
                continue
            key, callback, rng, value, title, fmt = spec
            y = rows[k // 3]
            x0, x1 = cols[k % 3]
            rng = (min(rng[0], value), max(rng[1], value))
            # pyvista calls the callback once with the initial value: not a user's choice
            # (it would fix the window/level that follows the image by default)
            self._adding_widgets = True
            self.sliders[key] = pl.add_slider_widget(
                lambda v, f=callback: None if self._adding_widgets else f(v), rng,
                value=value, title=title, pointa=(x0, y), pointb=(x1, y), fmt=fmt, **style)
            self._adding_widgets = False
            pl.subplot(0, 1)
        for widget in self.sliders.values():
            rep = widget.GetRepresentation()
            rep.SetLabelHeight(0.02)         # the value, above the slider
            # VTK widgets toggle themselves on the "i" key (our screenshot key) and come back
            # in the renderer under the mouse: the slider would jump into the 3D pane.
            widget.KeyPressActivationOff()
        pl.subplot(0, 0)
        self.checkboxes = {}
        for k, group in enumerate(CHECK_BOXES):
            box = pl.add_checkbox_button_widget(lambda on, g=group: self.toggle(g, on),
                                                value=self.view.is_visible(group),
                                                position=(10, 40 + 34 * k), size=26,
                                                border_size=2, color_on="#1f77b4")
            box.KeyPressActivationOff()
            label = pl.add_text(group, position=(42, 44 + 34 * k), font_size=9,
                                color="black", name=f"check-{group}")
            self.view.fixed_text(label, f"check-{group}", label.GetTextProperty().GetFontSize())
            self.checkboxes[group] = (box, label)
        self._place_checkboxes()
        if self.scatter is not None:                  # total -> primary -> scatter -> SPR
            pl.clear_events_for_key("k")
            pl.add_key_event("k", self._next_quantity)
        pl.clear_events_for_key("a")                  # the anti-scatter grid on / off
        pl.add_key_event("a", self.set_anti_scatter_grid)
        for key, (action, _) in KEYS.items():
            pl.clear_events_for_key(key)              # pyvista binds "b" and "v" itself
            if action == "screenshot":
                pl.add_key_event(key, lambda: print(f"saved {self.screenshot()}"))
            elif action == "view-side":
                pl.add_key_event(key, self.view_side)
            elif action == "view-bodies":
                pl.add_key_event(key, self.view_bodies)
            elif action == "volume-style":
                pl.add_key_event(key, self.set_volume_style)
            else:
                pl.add_key_event(key, lambda a=action: self.toggle(a))
        self.view._text(help_text(volumes=bool(self.scene.volumes)),
                        (0.985, 0.985), "help", font_size=8, justify="right")
        pl.enable_point_picking(self.on_pick, left_clicking=True, picker="cell",
                                show_message=False, show_point=False, tolerance=0.0)
        for actor in self.plotter.renderers[0].actors.values():
            if hasattr(actor, "SetPickable"):
                actor.SetPickable(False)
        self._update_status()

"""The viewer in a web browser: a trame server for one :class:`~xray_viz.viz.viewer.Viewer`.

The page shows the viewer's own render window - the 3D scene, the radiograph, its sliders, check
boxes and mu(t) chart - rendered on the server (off-screen VTK) and streamed as images
(trame-vtk's remote view, which needs no WebGL in the browser). Mouse and keys on the picture
go to the same VTK interactor as in the desktop window: dragging turns the camera, the VTK
sliders slide, a click on the radiograph picks the pixel and draws its ray in 3D. Above it, a
row of HTML controls (the acquisition sliders, the camera buttons and the picked pixel's
line integral) call the same :class:`~xray_viz.viz.viewer.Viewer` methods: there is one
viewer model, whatever drives it.

Everything the page loads comes from the installed trame packages on the server (no CDN, no
VTK.wasm: trame-vtklocal is never imported). ``xray-viz show SCENE --web`` serves it
(:func:`serve`); in a notebook :func:`xray_viz.show` displays it in the output cell
(:mod:`xray_viz.viz.notebook`). Needs the ``jupyter`` extra (``pip install xray_viz[jupyter]``).
"""

from __future__ import annotations

import functools
import itertools
import os
import sys

from xray_viz.errors import XrayVizError

__all__ = ["WebViewer", "serve", "require_trame", "DEFAULT_HOST"]

#: Interface the server binds to unless told otherwise: this machine only.
DEFAULT_HOST = "127.0.0.1"

_names = itertools.count()


def require_trame() -> None:
    """Raise a one-line error when the ``jupyter`` extra (trame, trame-vtk) is missing.

    Raises
    ------
    XrayVizError
        ``the web viewer needs trame and trame-vtk ...; pip install 'xray_viz[jupyter]'``.
    """
    import importlib.util

    missing = [m for m in ("trame", "trame_vtk", "trame_server", "trame_client")
               if importlib.util.find_spec(m) is None]
    if missing:
        raise XrayVizError(f"the web viewer needs {', '.join(missing)} (not installed); "
                           "install the jupyter extra: pip install 'xray_viz[jupyter]'")


def _use_egl_if_headless() -> None:
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY") \
            and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def _slider_specs(viewer) -> list[tuple[str, str, float, float, float, float]]:
    """The page's HTML sliders: (state name, label, min, max, step, value), with the ranges
    of the viewer's own VTK sliders (a tube's kVp or a monochromatic energy; neither for a
    fixed spectrum)."""
    fl0 = viewer.source_distance
    specs = [("source_distance", "source distance (mm)", 0.3 * fl0, 3.0 * fl0, 1.0,
              viewer.source_distance),
             ("rotation", "body rotation (deg)", -180.0, 180.0, 1.0, viewer.rotation)]
    if viewer.kvp is not None:
        specs.append(("kvp", "kVp", 20.0, 150.0, 1.0, viewer.kvp))
    elif viewer.fixed_spectrum is None:
        specs.append(("energy", "energy (keV)", 10.0, 150.0, 1.0, viewer.energy))
    specs.append(("resolution", "preview resolution (px)", 16.0,
                  float(max(512, viewer.resolution)), 1.0, float(viewer.resolution)))
    return [(k, t, min(lo, v), max(hi, v), s, v) for k, t, lo, hi, s, v in specs]


class WebViewer:
    """A :class:`~xray_viz.viz.viewer.Viewer` served by trame: the page and its state.

    Parameters
    ----------
    scene : Scene
        Shown as :class:`~xray_viz.viz.viewer.Viewer` shows it.
    height : int
        Height of the render view on the page, in CSS pixels (its width follows the page).
    **viewer_options
        Keyword options of :class:`~xray_viz.viz.viewer.Viewer` (``rays``, ``resolution``,
        ``texture``, ``window_size``); it is always off-screen.

    Attributes
    ----------
    viewer : Viewer
        The one viewer model: the page's controls and the picture's widgets all call its
        methods, and scripts may too (:meth:`refresh` then pushes the change to the page).
    server : trame_server.core.Server
        The trame server (a new one per :class:`WebViewer`).

    Examples
    --------
    >>> import xray_viz
    >>> from xray_viz.viz.web import WebViewer
    >>> web = WebViewer(xray_viz.load_scene("sphere"), resolution=32)
    >>> web.state["source_distance"] == web.viewer.source_distance
    True
    >>> web.set("source_distance", 900)
    >>> web.viewer.source_distance
    900.0
    >>> web.viewer.pick_pixel(16, 16).line_integral > 0
    True
    >>> web.state["picked"].startswith("pixel (16, 16)")
    True
    >>> web.close()
    """

    def __init__(self, scene, *, height=700, **viewer_options):
        require_trame()
        _use_egl_if_headless()
        # trame-vtklocal fetches VTK.wasm from the web when it is loaded: never load it.
        sys.modules.setdefault("trame.widgets.vtklocal", None)
        from trame.app import get_server

        from xray_viz.viz.viewer import Viewer

        viewer_options.setdefault("window_size", (1400, height))
        self.viewer = Viewer(scene, off_screen=True, **viewer_options)
        self.height = int(height)
        self.server = get_server(f"xray_viz-{next(_names)}", client_type="vue3")
        # trame reads --host/--port/... from sys.argv (xray-viz's, or a kernel's): the options
        # given here are the only ones
        cli = self.server.cli
        cli.parse_known_args = functools.partial(type(cli).parse_known_args, cli, [])
        self.state = self.server.state
        self._specs = _slider_specs(self.viewer)
        self._syncing = False
        with self.state:
            for key, _, _, _, _, value in self._specs:
                self.state[key] = float(value)
            self.state["picked"] = ""
            self.state["status"] = self.viewer.view.status
        for key, *_ in self._specs:
            self.state.change(key)(functools.partial(self._on_slider, key))
        self.viewer.add_listener(self._on_viewer_change)
        self._build_ui()

    # ------------------------------------------------------------------ state <-> viewer
    _SETTERS = {"source_distance": "set_source_distance", "rotation": "set_body_rotation",
                "energy": "set_energy", "kvp": "set_kvp", "resolution": "set_resolution"}

    def set(self, key: str, value: float) -> None:
        """Set a control as the page's slider does (``"source_distance"``, ``"rotation"``,
        ``"energy"`` or ``"kvp"``, ``"resolution"``)."""
        getattr(self.viewer, self._SETTERS[key])(float(value))

    def _on_slider(self, key, **_):
        if self._syncing:
            return
        value = self.state[key]
        if value is None:
            return
        self.set(key, value)

    def _on_viewer_change(self, viewer) -> None:
        """Listener of the viewer: every control's value, the picked pixel, a new image."""
        values = {"source_distance": viewer.source_distance, "rotation": viewer.rotation,
                  "energy": viewer.energy, "kvp": viewer.kvp,
                  "resolution": float(viewer.resolution)}
        self._syncing = True
        try:
            with self.state:
                for key, *_ in self._specs:
                    self.state[key] = float(values[key])
                self.state["status"] = viewer.view.status
                self.state["picked"] = self.picked_text()
        finally:
            self._syncing = False
        self.refresh()

    def picked_text(self) -> str:
        """``"pixel (i, j): integral mu dt = ..."`` of the picked pixel, or ``""``."""
        viewer = self.viewer
        if viewer.profile is None or getattr(viewer, "picked_pixel", None) is None:
            return ""
        i, j = viewer.picked_pixel
        h = viewer.scene.detector.shape[1]
        image = float(viewer.radiograph.line_integral[h - 1 - j, i])
        return (f"pixel ({i}, {j}): integral mu dt = {viewer.profile.line_integral:.4g} at "
                f"{viewer.profile.energy:.3g} keV (image {image:.4g})")

    def refresh(self) -> None:
        """Push a new picture of the render window to the page."""
        update = getattr(self, "_view_update", None)
        if update is not None and self.server.protocol:
            update()

    # ------------------------------------------------------------------ page
    def _build_ui(self) -> None:
        from trame.ui.html import DivLayout
        from trame.widgets import html
        from trame.widgets import vtk as vtk_widgets

        bar = ("display: flex; flex-wrap: wrap; gap: 4px 18px; align-items: center; "
               "font: 13px sans-serif; padding: 4px 8px; background: #f3f3f3")
        with DivLayout(self.server, style="margin: 0; height: 100%") as layout:
            with html.Div(style=bar, id="xray-viz-controls"):
                for key, title, lo, hi, step, _ in self._specs:
                    with html.Label(style="display: flex; gap: 6px; align-items: center"):
                        html.Span(title)
                        html.Input(type="range", min=lo, max=hi, step=step, id=f"slider-{key}",
                                   value=(key,),
                                   change=f"{key} = Number($event.target.value)",
                                   style="width: 130px")
                        html.Span("{{ Math.round(%s) }}" % key, id=f"value-{key}",
                                  style="min-width: 3em")
                html.Button("side view", click=self._side, id="button-side")
                html.Button("bodies close-up", click=self._bodies, id="button-bodies")
            html.Div("{{ status }}", id="xray-viz-status",
                     style="font: 13px sans-serif; padding: 2px 8px")
            html.Div("{{ picked || 'click a pixel of the radiograph: its ray in 3D, mu(t) in "
                     "the chart' }}", id="xray-viz-picked",
                     style="font: 13px sans-serif; padding: 2px 8px; min-height: 1.3em")
            with html.Div(style=f"width: 100%; height: {self.height}px; position: relative",
                          id="xray-viz-view"):
                view = vtk_widgets.VtkRemoteView(self.viewer.plotter.render_window,
                                                 ref="xray_viz_view", interactive_ratio=1,
                                                 still_quality=95, interactive_quality=80)
        self.layout = layout
        self._view_update = view.update
        self.remote_view = view

    def _side(self) -> None:
        self.viewer.view_side()
        self.refresh()

    def _bodies(self) -> None:
        self.viewer.view_bodies()
        self.refresh()

    # ------------------------------------------------------------------ running
    def url(self, host: str = DEFAULT_HOST) -> str:
        """The page's address once the server listens."""
        shown = "127.0.0.1" if host in ("", "0.0.0.0") else host
        shown = f"[{shown}]" if ":" in shown else shown
        return f"http://{shown}:{self.server.port}/index.html"

    def start(self, *, host=DEFAULT_HOST, port=0, exec_mode="main", on_ready=None):
        """Start the trame server (``exec_mode="main"`` blocks until it stops; ``"task"``
        returns its asyncio task, for a running event loop such as a Jupyter kernel's).

        With ``"main"`` the server's own event loop drops the errors of messages to a page
        whose connection is closing (:func:`_drop_closing_connections`)."""
        if exec_mode == "main":
            self.server.controller.on_server_ready.add(_own_loop_drops_closing_connections)
        if on_ready is not None:
            self.server.controller.on_server_ready.add(lambda **_: on_ready(self))
        return self.server.start(host=host, port=int(port), exec_mode=exec_mode,
                                 open_browser=False, show_connection_info=False,
                                 disable_logging=True, timeout=0)

    def close(self) -> None:
        """Free the viewer's render window (the server, if running, is left to its loop)."""
        self.viewer.close()


def _drop_closing_connections(loop, context) -> None:
    """asyncio exception handler: an image or state update sent to a page whose connection
    is closing (the tab closed, or the server stopping on Ctrl-C while a frame was on its way)
    raises ``ConnectionResetError`` in a task of wslink's that nobody awaits, which asyncio
    would print as a traceback; there is nobody left to tell, so it is dropped. Anything else
    is reported as asyncio does."""
    if isinstance(context.get("exception"), ConnectionResetError):
        return
    loop.default_exception_handler(context)


def _own_loop_drops_closing_connections(**_) -> None:
    import asyncio

    asyncio.get_running_loop().set_exception_handler(_drop_closing_connections)


def serve(scene, *, host=DEFAULT_HOST, port=0, announce=print, **viewer_options) -> int:
    """Serve the viewer of ``scene`` on ``host:port`` until Ctrl-C (``xray-viz show --web``).

    Parameters
    ----------
    scene : Scene or WebViewer
        A scene (its :class:`WebViewer` is made here) or a :class:`WebViewer` made already.
    host : str
        Interface to bind: ``127.0.0.1`` (this machine only) unless another is given.
    port : int
        0: any free port. The URL is announced once the server listens.
    announce : callable
        Called with the line that gives the URL, and with ``"stopped"`` at the end.
    **viewer_options
        As :class:`WebViewer` (with a scene).

    Returns
    -------
    int
        0 once stopped (Ctrl-C).
    """
    web = scene if isinstance(scene, WebViewer) else WebViewer(scene, **viewer_options)

    def ready(w):
        announce(f"serving the viewer at {w.url(host)} (Ctrl-C stops it)")

    try:
        web.start(host=host, port=port, on_ready=ready)
    except KeyboardInterrupt:
        pass
    finally:
        web.close()
    announce("stopped")
    return 0

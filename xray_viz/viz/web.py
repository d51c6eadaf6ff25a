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
VTK.wasm: trame-vtklocal is never imported).

Another web page open in the same browser must not drive the viewer: every request whose
``Host:`` header is not the name the server is bound to (a loopback name by default: this is
what DNS rebinding changes) and every request - the websocket's included - whose ``Origin`` is
another site is refused with 403 (:func:`_request_guard`); the websocket only authenticates
with a random per-run secret (:attr:`WebViewer.secret`, carried by the printed URL's
``?secret=``) instead of trame's public default. Binding another interface than loopback
(``--host 0.0.0.0``) is said loudly on stderr, with the URL a remote browser would use. ``xray-viz show SCENE --web`` serves it
(:func:`serve`); in a notebook :func:`xray_viz.show` displays it in the output cell
(:mod:`xray_viz.viz.notebook`). Needs the ``jupyter`` extra (``pip install xray_viz[jupyter]``).
"""

from __future__ import annotations

import functools
import ipaddress
import itertools
import os
import secrets
import socket
import sys

from xray_viz.errors import XrayVizError

__all__ = ["WebViewer", "serve", "require_trame", "DEFAULT_HOST"]

#: Interface the server binds to unless told otherwise: this machine only.
DEFAULT_HOST = "127.0.0.1"

_names = itertools.count()

#: Host names of this machine's loopback interface.
LOOPBACK_NAMES = frozenset({"localhost", "127.0.0.1", "::1"})
#: Bind addresses meaning "every interface".
WILDCARD_HOSTS = frozenset({"", "0.0.0.0", "::"})


def is_loopback(host: str) -> bool:
    """True when ``host`` (a name or an address) is this machine's loopback interface only.

    Examples
    --------
    >>> [is_loopback(h) for h in ("127.0.0.1", "localhost", "::1", "127.0.0.2", "0.0.0.0",
    ...                           "192.0.2.7", "example.org")]
    [True, True, True, True, False, False, False]
    """
    host = host.strip("[]").lower()
    if host in ("localhost", "localhost."):
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def _bind_warning(host: str) -> str | None:
    """The loud warning for a bind that other machines can reach, or None (loopback)."""
    if is_loopback(host):
        return None
    where = ("every network interface" if host in WILDCARD_HOSTS
             else f"the interface {host!r}")
    return (f"WARNING: --host {host or repr(host)} serves the viewer on {where}: not only this machine "
            "but anyone who can reach it may open the viewer with the URL below (its ?secret= "
            "is the only lock, and the traffic is plain http, not encrypted); use the default "
            "--host 127.0.0.1 unless that is what you want")


def _warn(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _split_host(value: str) -> tuple[str, int | None]:
    """``"name:port"``, ``"[::1]:port"`` or ``"name"`` -> (lower-case name, port or None)."""
    value = value.strip().lower()
    if value.startswith("["):
        name, _, rest = value[1:].partition("]")
        port = rest[1:] if rest.startswith(":") else ""
    elif value.count(":") == 1:
        name, _, port = value.partition(":")
    else:
        name, port = value, ""
    return name.rstrip("."), (int(port) if port.isdigit() else None)


def _request_guard(bound_host: str, *, proxied: bool = False):
    """aiohttp middleware: refuse (403) a request whose ``Host:`` is not a name of the bound
    interface (DNS rebinding), and one whose ``Origin`` is another site (a foreign page's
    websocket or fetch). With a wildcard bind (``0.0.0.0``) any ``Host:`` is answered (remote
    browsers use this machine's names) but the ``Origin`` must still be the page's own.

    ``proxied``: the page is served through jupyter-server-proxy (:mod:`xray_viz.viz.notebook`),
    which connects from this machine but passes the browser's ``Host:`` and ``Origin`` on - the
    notebook server's site (``hub.example.org`` on JupyterHub), which the proxy has checked
    already (Jupyter's own origin rules, its token or login cookie). Neither header is then
    checked: the websocket's per-run secret, which only the notebook's output carries, is the
    lock (what the page's HTML and scripts show is the installed trame packages, public)."""
    from aiohttp import web as aiohttp_web

    allowed = set(LOOPBACK_NAMES) if is_loopback(bound_host) else set()
    if bound_host not in WILDCARD_HOSTS:
        allowed.add(bound_host.strip("[]").lower().rstrip("."))

    def refuse(why: str):
        return aiohttp_web.Response(status=403, text=f"refused by the xray_viz viewer: {why}\n")

    @aiohttp_web.middleware
    async def guard(request, handler):
        if proxied:
            return await handler(request)
        raw_host = request.headers.get("Host")
        if raw_host is None:
            return refuse("no Host header")
        host, _ = _split_host(raw_host)
        if allowed and host not in allowed:
            return refuse(f"Host header {raw_host[:80]!r} is not the viewer's address "
                          f"({', '.join(sorted(allowed))})")
        origin = request.headers.get("Origin")
        if origin is not None:
            from urllib.parse import urlsplit

            parts = urlsplit(origin.strip())
            try:
                port = parts.port or {"http": 80, "https": 443}.get(parts.scheme)
            except ValueError:
                port = None
            sockname = request.transport.get_extra_info("sockname") if request.transport \
                else None
            own_port = sockname[1] if sockname else None
            name = (parts.hostname or "").rstrip(".")
            same = name in allowed if allowed else name == host
            if parts.scheme not in ("http", "https") or not same or port != own_port:
                return refuse(f"Origin {origin[:80]!r} is another site than the viewer's page")
        return await handler(request)

    return guard


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
        #: The websocket's per-run secret (trame's default, ``wslink-secret``, is public); the
        #: page learns it from the URL (:meth:`url`), which trame's client then strips.
        self.secret = secrets.token_urlsafe(32)
        # trame reads --host/--port/... from sys.argv (xray-viz's, or a kernel's): the options
        # given here are the only ones
        cli = self.server.cli
        cli.parse_known_args = functools.partial(type(cli).parse_known_args, cli,
                                                 ["--authKey", self.secret])
        self.state = self.server.state
        self._specs = _slider_specs(self.viewer)
        # one set of controls: the VTK sliders that the page's HTML row repeats are hidden
        for key, *_ in self._specs:
            widget = getattr(self.viewer, "sliders", {}).get(key)
            if widget is not None:
                widget.Off()
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

    def snapshot(self, format: str = "PNG", **save_options) -> bytes:
        """The render window as it is now, an image file's bytes (``"PNG"`` or ``"JPEG"``):
        the page's first picture, and the notebook's static fallback."""
        import io

        from PIL import Image

        self.viewer.plotter.render()
        pixels = self.viewer.plotter.screenshot(None, return_img=True)
        out = io.BytesIO()
        Image.fromarray(pixels).convert("RGB").save(out, format=format, **save_options)
        return out.getvalue()

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
            # the first picture is there at once, under the stream's (which needs the
            # websocket and a render first)
            import base64

            first = base64.b64encode(self.snapshot("JPEG", quality=85)).decode()
            view_style = (f"width: 100%; height: {self.height}px; position: relative; "
                          f"background: url(data:image/jpeg;base64,{first}) 0 0 / 100% 100% "
                          "no-repeat")
            with html.Div(style=view_style, id="xray-viz-view"):
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
        """The page's address once the server listens, with its ``?secret=``: for a wildcard
        bind (``0.0.0.0``), this machine's host name (what a remote browser would use)."""
        shown = socket.gethostname() if host in WILDCARD_HOSTS else host.strip("[]")
        shown = f"[{shown}]" if ":" in shown else shown
        return f"http://{shown}:{self.server.port}{self.page_query()}"

    def page_query(self, path: str = "/") -> str:
        """``index.html?secret=...&sessionURL=...`` under the page's path ``path`` (``"/"``, or
        a proxy's ``/prefix/proxy/PORT/``): the websocket's address is given relative to the
        page's host (``USE_HOST``, the scheme following the page's), so that trame's client
        does not first POST to a session manager (``/paraview/``, answered 405)."""
        from urllib.parse import quote

        session = quote(f"ws://USE_HOST{path}ws", safe="")
        return f"{path}index.html?secret={self.secret}&sessionURL={session}"

    def start(self, *, host=DEFAULT_HOST, port=0, exec_mode="main", on_ready=None,
              proxied=False):
        """Start the trame server (``exec_mode="main"`` blocks until it stops; ``"task"``
        returns its asyncio task, for a running event loop such as a Jupyter kernel's).

        A message to a page whose connection is closing (the tab closed while a reply or a
        picture was on its way) is dropped, not written to stderr as a traceback
        (``_quiet_closing_websockets``); with ``"main"`` the server's own event loop also
        drops those errors in tasks nobody awaits (``_drop_closing_connections``).
        ``proxied``: the page is also reached through jupyter-server-proxy
        (:func:`_request_guard`)."""
        guard = _request_guard(host, proxied=proxied)

        def bind(wslink_server):
            wslink_server.app.middlewares.append(guard)
            _quiet_closing_websockets(wslink_server)

        self.server.controller.on_server_bind.add(bind)
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


def _drop_if_closing(send):
    """``send`` (a websocket's ``send_bytes``) that drops its message, instead of raising,
    when the connection is closing: the page is gone, there is nobody left to tell."""

    @functools.wraps(send)
    async def send_or_drop(*args, **kwargs):
        try:
            return await send(*args, **kwargs)
        except ConnectionResetError:        # aiohttp: "Cannot write to closing transport"
            return None

    return send_or_drop


def _quiet_closing_websockets(wslink_server) -> None:
    """Every websocket of the server's pages drops a message to a closing connection
    (``_drop_if_closing``).

    Closing the tab while wslink sends it a reply (an RPC's result, a picture) made
    ``ws.send_bytes`` raise ``ConnectionResetError`` inside wslink's message handler, which
    logged it as "Exception raised", failed again sending the error back, and left aiohttp
    to print "Error handling request" with both tracebacks on stderr. The other pages'
    websockets are apart: each gets its messages whatever happened to another's.
    """
    for handler in getattr(wslink_server, "_ws_handlers", ()):
        connect = handler.onConnect

        async def on_connect(request, client_id, _handler=handler, _connect=connect):
            ws = _handler.connections.get(client_id)
            if ws is not None:
                ws.send_bytes = _drop_if_closing(ws.send_bytes)
            await _connect(request, client_id)

        handler.onConnect = on_connect


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
        Interface to bind: ``127.0.0.1`` (this machine only) unless another is given; any
        other (``0.0.0.0``: every interface) is warned about on stderr.
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
    warning = _bind_warning(host)
    if warning:
        _warn(warning)
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

"""The viewer in a notebook: :func:`show` puts the web viewer in the output cell.

In a Jupyter kernel, :func:`show` starts the :class:`~xray_viz.viz.web.WebViewer`'s trame server
inside the kernel (on its event loop, bound to 127.0.0.1 and a free port) and displays the page
in an ``<iframe>``: the 3D scene, the radiograph, the sliders and pixel picking, all working in
JupyterLab, the classic notebook or VS Code. Outside a kernel it opens the desktop window.
Nothing is downloaded: the page's scripts come from the installed trame packages.

Remote notebooks (JupyterHub, Binder, remote VS Code): the browser is not on the kernel's machine,
so ``http://127.0.0.1:PORT`` is not the viewer there. With jupyter-server-proxy (in the
``jupyter`` extra) the page goes through the notebook server instead, at the path
``{base_url}proxy/{port}/`` (relative to the notebook's own site; the websocket too), as PyVista's
trame backend does with ``server_proxy_enabled`` / ``server_proxy_prefix``. :func:`proxy_prefix`
decides: ``show(..., proxy=...)``, else the environment variable ``XRAY_VIZ_PROXY`` (``1``/``0``,
or the prefix itself, e.g. ``/user/me/proxy/``), else detected (JupyterHub's
``JUPYTERHUB_SERVICE_PREFIX``, or the Jupyter server that started this kernel, when
jupyter-server-proxy is installed). The output cell first shows a still picture of the viewer
(a PNG), then replaces it by the live page once the page answers (proxied address first, then
the direct one); when no server can be reached the picture stays, with a line saying so.
``show(..., backend="static")`` shows the picture only.
"""

from __future__ import annotations

import base64
import html
import itertools
import json
import os
import sys

__all__ = ["show", "in_notebook", "NotebookViewer", "proxy_prefix"]

#: Environment variable: ``1``/``0`` (proxy or not), or the proxy's path prefix.
PROXY_ENV = "XRAY_VIZ_PROXY"
_FALSE = ("", "0", "false", "no", "off")
_TRUE = ("1", "true", "yes", "on")


def _server_base_url() -> str | None:
    """``base_url`` of the Jupyter server that started this kernel (its parent process)."""
    try:
        from jupyter_server.serverapp import list_running_servers
    except ImportError:
        return None
    parent = os.getppid()
    try:
        for info in list_running_servers():
            if info.get("pid") == parent:
                return info.get("base_url") or "/"
    except OSError:
        return None
    return None


def proxy_prefix(proxy=None) -> str | None:
    """The path under which jupyter-server-proxy serves local ports (``/prefix/proxy/``), or None.

    Parameters
    ----------
    proxy : bool, str or None
        True: through the proxy of this kernel's Jupyter server (its ``base_url`` +
        ``proxy/``); False: not proxied; a string: the prefix itself (``/user/me/proxy/``,
        ending in ``proxy/`` or ``proxy/absolute/`` as the proxy is set up); None: the
        environment variable ``XRAY_VIZ_PROXY`` (the same values), else detected.

    Examples
    --------
    >>> proxy_prefix(False) is None
    True
    >>> proxy_prefix("/user/me/proxy")
    '/user/me/proxy/'
    """
    if proxy is None:
        value = os.environ.get(PROXY_ENV)
        if value is not None:
            low = value.strip().lower()
            proxy = False if low in _FALSE else True if low in _TRUE else value.strip()
    if proxy is False:
        return None
    if isinstance(proxy, str):
        return proxy.rstrip("/") + "/"
    import importlib.util

    hub = os.environ.get("JUPYTERHUB_SERVICE_PREFIX")
    base = hub or _server_base_url()
    if base is None:
        return "/proxy/" if proxy else None
    if proxy is None and importlib.util.find_spec("jupyter_server_proxy") is None:
        return None
    return base.rstrip("/") + "/proxy/"


def in_notebook() -> bool:
    """True inside a Jupyter kernel (an IPython kernel app is running).

    Examples
    --------
    >>> in_notebook()
    False
    """
    ipython = sys.modules.get("IPython")
    if ipython is None:
        return False
    shell = ipython.get_ipython()
    return shell is not None and "IPKernelApp" in getattr(shell, "config", {})


class NotebookViewer:
    """The web viewer of a scene, shown in a notebook's output cell.

    Made by :func:`show`; its :attr:`viewer` is the :class:`~xray_viz.viz.viewer.Viewer`
    that the page drives (scripts may drive it too: ``nv.viewer.set_source_distance(900)``;
    the page follows).

    Attributes
    ----------
    web : WebViewer
    viewer : Viewer
    url : str
        The page's address (``http://127.0.0.1:PORT/index.html``).
    """

    def __init__(self, web, *, host, width="100%", prefix=None, live=True):
        self.web = web
        self.viewer = web.viewer
        self.host = host
        self.width = width
        #: jupyter-server-proxy's path prefix (:func:`proxy_prefix`), or None.
        self.prefix = prefix
        #: False: the still picture only (``backend="static"``).
        self.live = live
        self._shown_in = None

    @property
    def url(self) -> str:
        """The page's address: relative to the notebook's site when proxied
        (``/prefix/proxy/PORT/index.html?...``), else ``http://127.0.0.1:PORT/index.html?...``."""
        if self.prefix is not None:
            return self.web.page_query(f"{self.prefix}{self.web.server.port}/")
        return self.web.url(self.host)

    def candidates(self) -> list[str]:
        """The addresses the output cell tries, in order (proxied, then direct)."""
        if not self.live:
            return []
        urls = [self.url]
        if self.prefix is not None:
            urls.append(self.web.url(self.host))
        return urls

    def _repr_png_(self) -> bytes:
        return self.web.snapshot("PNG")

    def _repr_html_(self) -> str:
        height = self.web.height + 100          # the controls above the render view
        box = f"xray-viz-{next(_boxes)}"
        png = base64.b64encode(self._repr_png_()).decode()
        note = ("the interactive viewer's server cannot be reached from this browser: a still "
                "picture (proxy: pip install jupyter-server-proxy, or set XRAY_VIZ_PROXY)"
                if self.live else "a still picture of the viewer")
        frame = (f'<iframe id="xray-viz-frame" title="xray_viz viewer" '
                 f'style="border: none; width: {self.width}; height: {height}px"></iframe>')
        # the still picture first; the live page replaces it once an address answers (an
        # opaque answer for another site's address: no-cors, nothing is read from it)
        script = f"""<script>(async () => {{
  const box = document.getElementById({json.dumps(box)});
  for (const url of {json.dumps(self.candidates())}) {{
    try {{
      const same = new URL(url, document.baseURI).origin === window.location.origin;
      const r = await fetch(url, {{mode: same ? "same-origin" : "no-cors", cache: "no-store"}});
      if (r.type === "opaque" || r.ok) {{
        box.innerHTML = {json.dumps(frame)};
        box.querySelector("iframe").src = url;
        return;
      }}
    }} catch (e) {{}}
  }}
  box.querySelector(".xray-viz-note").style.display = "block";
}})();</script>"""
        return (f'<div id="{box}" class="xray-viz-output">'
                f'<img class="xray-viz-static" alt="xray_viz viewer (still)" '
                f'src="data:image/png;base64,{png}" style="max-width: {self.width}"/>'
                f'<div class="xray-viz-note" style="display: {"none" if self.live else "block"}; '
                f'font: 12px sans-serif; color: #555">{html.escape(note)}</div></div>'
                + (script if self.live else ""))

    def _ipython_display_(self) -> None:
        from IPython import get_ipython
        from IPython.display import display_html

        cell = getattr(get_ipython(), "execution_count", None)
        if self._shown_in == cell:           # show() displayed it already in this cell
            self._shown_in = None
            return
        self._shown_in = cell
        display_html(self._repr_html_(), raw=True)

    def __repr__(self) -> str:
        if not self.live:
            return "<xray_viz viewer (still picture)>"
        return f"<xray_viz viewer at {self.url}>"


_boxes = itertools.count()


def show(scene, *, host="127.0.0.1", port=0, height=700, backend="auto", proxy=None,
         **viewer_options):
    """Show a scene in the interactive viewer: in the notebook's output cell, or a window.

    Parameters
    ----------
    scene : Scene or str
        A scene, or what :func:`xray_viz.load_scene` takes (a phantom name, a TOML path).
    host, port : str, int
        Where the viewer's server listens in a notebook (default 127.0.0.1, a free port).
    height : int
        Height of the render view in a notebook, CSS pixels.
    backend : {"auto", "server", "static"}
        In a notebook: ``"static"`` shows a still picture (PNG) of the viewer and starts no
        server; otherwise the live viewer (its still picture until the page answers).
    proxy : bool, str or None
        Through jupyter-server-proxy (:func:`proxy_prefix`): None decides from
        ``XRAY_VIZ_PROXY`` or detects it.
    **viewer_options
        Keyword options of :class:`~xray_viz.viz.viewer.Viewer`: ``rays``, ``resolution``,
        ``texture``, ``window_size``.

    Returns
    -------
    NotebookViewer or Viewer
        In a notebook, the object displayed (its ``viewer`` is the model; displaying it again
        in another cell shows a second view of the same viewer); else the desktop
        :class:`~xray_viz.viz.viewer.Viewer`, once its window is closed.

    Raises
    ------
    XrayVizError
        Outside a notebook, when there is no display to open a window on.
    """
    from xray_viz.scene_file import load_scene

    if isinstance(scene, (str, bytes)) or hasattr(scene, "__fspath__"):
        scene = load_scene(scene)
    if not in_notebook():
        from xray_viz.viz.display import require_display
        from xray_viz.viz.viewer import Viewer

        require_display("xray_viz.show in a Jupyter notebook, or `xray-viz show SCENE --web` "
                        "to serve the viewer to a browser")

        viewer = Viewer(scene, **viewer_options)
        viewer.show()
        return viewer
    import asyncio

    from xray_viz.viz.web import WebViewer, require_trame

    if backend not in ("auto", "server", "static"):
        raise ValueError(f"backend={backend!r}: use 'auto', 'server' or 'static'")
    require_trame()
    web = WebViewer(scene, height=height, **viewer_options)
    if backend == "static":
        shown = NotebookViewer(web, host=host, live=False)
        shown._ipython_display_()
        return shown
    prefix = proxy_prefix(proxy)
    web.start(host=host, port=port, exec_mode="task", proxied=prefix is not None)
    # the kernel's loop is running (this cell is in it): wait for the server to listen, so the
    # iframe finds it, the way pyvista's trame backend does (nest_asyncio2)
    import nest_asyncio2

    nest_asyncio2.apply()
    asyncio.get_event_loop().run_until_complete(web.server.ready)
    shown = NotebookViewer(web, host=host, prefix=prefix)
    shown._ipython_display_()
    return shown

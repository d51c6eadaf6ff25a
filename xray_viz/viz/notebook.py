"""The viewer in a notebook: :func:`show` puts the web viewer in the output cell.

In a Jupyter kernel, :func:`show` starts the :class:`~xray_viz.viz.web.WebViewer`'s trame server
inside the kernel (on its event loop, bound to 127.0.0.1 and a free port) and displays the page
in an ``<iframe>``: the 3D scene, the radiograph, the sliders and pixel picking, all working in
JupyterLab, the classic notebook or VS Code. Outside a kernel it opens the desktop window.
Nothing is downloaded: the page's scripts come from the installed trame packages.
"""

from __future__ import annotations

import sys

__all__ = ["show", "in_notebook", "NotebookViewer"]


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

    def __init__(self, web, *, host, width="100%"):
        self.web = web
        self.viewer = web.viewer
        self.host = host
        self.width = width
        self._shown_in = None

    @property
    def url(self) -> str:
        """The page's address."""
        return self.web.url(self.host)

    def _repr_html_(self) -> str:
        height = self.web.height + 100          # the controls above the render view
        return (f'<iframe src="{self.url}" id="xray-viz-frame" title="xray_viz viewer" '
                f'style="border: none; width: {self.width}; height: {height}px"></iframe>')

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
        return f"<xray_viz viewer at {self.url}>"


def show(scene, *, host="127.0.0.1", port=0, height=700, **viewer_options):
    """Show a scene in the interactive viewer: in the notebook's output cell, or a window.

    Parameters
    ----------
    scene : Scene or str
        A scene, or what :func:`xray_viz.load_scene` takes (a phantom name, a TOML path).
    host, port : str, int
        Where the viewer's server listens in a notebook (default 127.0.0.1, a free port).
    height : int
        Height of the render view in a notebook, CSS pixels.
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
    from xray_viz.scene import load_scene

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

    require_trame()
    web = WebViewer(scene, height=height, **viewer_options)
    web.start(host=host, port=port, exec_mode="task")
    # the kernel's loop is running (this cell is in it): wait for the server to listen, so the
    # iframe finds it, the way pyvista's trame backend does (nest_asyncio2)
    import nest_asyncio2

    nest_asyncio2.apply()
    asyncio.get_event_loop().run_until_complete(web.server.ready)
    shown = NotebookViewer(web, host=host)
    shown._ipython_display_()
    return shown

"""Helpers for the walkthroughs that rebuild the thesis step by step.

The walkthroughs live in ``apps/walkthroughs/NN_topic.py`` in the repository and are installed
as the package ``xray_viz._walkthroughs``. Each is a sphinx-gallery style script (a docstring
title, then ``# %%`` cells of narrative and code) that runs

* interactively: PyVista windows and Matplotlib figures open (``plotter.show()``), or
* off-screen, when ``PYVISTA_OFF_SCREEN=true``: every figure is written as a PNG into the folder
  named by ``XRAY_VIZ_OUTPUT`` (default ``out/walkthroughs/NN/``), or
* in the documentation's gallery, when sphinx-gallery runs it with ``pyvista.BUILDING_GALLERY``
  set: the figures stay open for :data:`gallery_scraper`, which puts them on the page (each 3D
  scene both as a picture and as an interactive vtk.js view).

From the command line: ``xray-viz walkthrough --list`` and
``xray-viz walkthrough N [--off-screen]``.

Examples
--------
>>> from xray_viz.walkthroughs import list_walkthroughs
>>> list_walkthroughs()[0][:2]
(1, '01_parametric_ray')
"""

from __future__ import annotations

import ast
import importlib.resources
import os
import re
from pathlib import Path

from xray_viz import progress as _progress
from xray_viz.errors import XrayVizError

__all__ = [
    "WalkthroughNotFoundError", "is_off_screen", "output_dir", "new_plotter", "show_or_save",
    "show_or_save_figure", "save_frame", "list_walkthroughs", "walkthrough_path", "run_walkthrough",
    "walkthrough_command", "add_walkthrough_parser", "arrow", "polyline", "segments", "pyplot",
    "is_building_gallery", "GalleryScraper", "gallery_scraper", "reset_gallery",
]

_TRUE = ("1", "true", "yes", "on")
_NAME = re.compile(r"^(\d\d)_([a-z0-9_]+)\.py$")

#: Window size of every walkthrough figure (pixels); fixed so that screenshots are reproducible.
WINDOW_SIZE = (1024, 768)


class WalkthroughNotFoundError(XrayVizError, LookupError):
    """There is no walkthrough with the number asked for."""


def is_off_screen() -> bool:
    """True when figures should be written as PNGs instead of opening windows.

    Off-screen means ``PYVISTA_OFF_SCREEN`` is set to a true value (``true``, ``1``, ``yes``) or
    ``pyvista.OFF_SCREEN`` is already True.

    Returns
    -------
    bool
    """
    if os.environ.get("PYVISTA_OFF_SCREEN", "").strip().lower() in _TRUE:
        return True
    import sys

    pv = sys.modules.get("pyvista")
    return bool(pv is not None and getattr(pv, "OFF_SCREEN", False))


def is_building_gallery() -> bool:
    """True while sphinx-gallery runs the walkthroughs for the documentation.

    That is when PyVista is imported and ``pyvista.BUILDING_GALLERY`` is True (``docs/conf.py``
    sets it, as PyVista's own gallery does). Then :func:`show_or_save`, :func:`save_frame` and
    :func:`show_or_save_figure` write no files and leave the figures to
    :data:`gallery_scraper` and sphinx-gallery's Matplotlib scraper.

    Returns
    -------
    bool
    """
    import sys

    pv = sys.modules.get("pyvista")
    return bool(pv is not None and getattr(pv, "BUILDING_GALLERY", False))


def output_dir(walkthrough: int) -> Path:
    """Folder where walkthrough ``walkthrough`` writes its figures when off-screen.

    Parameters
    ----------
    walkthrough : int
        Number of the walkthrough.

    Returns
    -------
    Path
        ``$XRAY_VIZ_OUTPUT`` when set, else ``out/walkthroughs/NN`` (relative to the current
        directory). Created if missing.
    """
    env = os.environ.get("XRAY_VIZ_OUTPUT")
    path = Path(env) if env else Path("out") / "walkthroughs" / f"{int(walkthrough):02d}"
    path.mkdir(parents=True, exist_ok=True)
    return path


def _quiet_vtk() -> None:
    # Off-screen VTK first tries X and logs "bad X server connection" before it picks EGL.
    try:
        from vtkmodules.vtkCommonCore import vtkLogger

        vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    except ImportError:  # pragma: no cover - very old VTK
        pass


def new_plotter(*, shape=(1, 1), window_size=WINDOW_SIZE, **kwargs):
    """A :class:`pyvista.Plotter` for a walkthrough figure: fixed size, off-screen when asked.

    Parameters
    ----------
    shape : (int, int), optional
        Subplot layout.
    window_size : (int, int), optional
        Width and height in pixels.
    **kwargs
        Passed to :class:`pyvista.Plotter`.

    Returns
    -------
    pyvista.Plotter
    """
    import pyvista as pv

    off = is_off_screen()
    if off:
        pv.OFF_SCREEN = True
        _quiet_vtk()
    plotter = pv.Plotter(shape=shape, window_size=list(window_size), off_screen=off, **kwargs)
    plotter.set_background("white")
    return plotter


def show_or_save(plotter, name: str, *, walkthrough: int) -> Path | None:
    """Show a plotter in a window, or write it to ``output_dir(walkthrough) / name.png``.

    Parameters
    ----------
    plotter : pyvista.Plotter
    name : str
        File name without extension.
    walkthrough : int
        Number of the walkthrough (chooses the default output folder).

    Returns
    -------
    Path or None
        The PNG written when off-screen, else None (after the window is closed, or, in the
        documentation's gallery, once the plotter is rendered for :data:`gallery_scraper`).
    """
    if is_building_gallery():
        # pyvista.Plotter.show() keeps the picture (last_image) and the vtk.js scene
        # (last_vtksz) of a gallery plotter, and keeps the plotter for the scraper.
        plotter.show(title=f"xray_viz walkthrough {walkthrough:02d}: {name}")
        return None
    if is_off_screen():
        path = output_dir(walkthrough) / f"{name}.png"
        plotter.screenshot(str(path))
        plotter.close()
        _progress.wrote(path)
        return path
    plotter.show(title=f"xray_viz walkthrough {walkthrough:02d}: {name}")
    return None


def save_frame(plotter, name: str, *, walkthrough: int) -> Path | None:
    """Off-screen: write the plotter's current view as a PNG and keep the plotter open.

    On screen this does nothing: the window shows the scene live. Use it to record the states
    a slider would go through, before the final :func:`show_or_save`.

    Parameters
    ----------
    plotter : pyvista.Plotter
    name : str
        File name without extension.
    walkthrough : int
        Number of the walkthrough.

    Returns
    -------
    Path or None
        The PNG written, or None on screen and in the documentation's gallery (there the frame
        is kept on the plotter, and :data:`gallery_scraper` shows it before the final scene).
    """
    if is_building_gallery():
        frames = list(getattr(plotter, "_xray_viz_frames", ()))
        frames.append(plotter.screenshot(None, return_img=True))
        plotter._xray_viz_frames = frames
        return None
    if not is_off_screen():
        return None
    path = output_dir(walkthrough) / f"{name}.png"
    plotter.screenshot(str(path))
    _progress.wrote(path)
    return path


def show_or_save_figure(figure, name: str, *, walkthrough: int) -> Path | None:
    """Show a Matplotlib figure, or write it to ``output_dir(walkthrough) / name.png``.

    Parameters
    ----------
    figure : matplotlib.figure.Figure
    name : str
        File name without extension.
    walkthrough : int
        Number of the walkthrough.

    Returns
    -------
    Path or None
        The PNG written when off-screen, else None. In the documentation's gallery the figure
        is left open for sphinx-gallery's Matplotlib scraper.
    """
    import matplotlib.pyplot as plt

    if is_building_gallery():
        return None
    if is_off_screen():
        path = output_dir(walkthrough) / f"{name}.png"
        figure.savefig(path, dpi=100)
        plt.close(figure)
        _progress.wrote(path)
        return path
    plt.show()
    return None


def pyplot():
    """``matplotlib.pyplot``, with the non-interactive Agg backend when off-screen."""
    import matplotlib

    if is_off_screen():
        matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


# --------------------------------------------------------------------------------------------
# The documentation's gallery (sphinx-gallery runs the walkthroughs; docs/conf.py)


class GalleryScraper:
    """Image scraper of the walkthroughs' gallery: the slider states, then each 3D scene.

    sphinx-gallery calls it after every code block of a walkthrough. For every PyVista plotter
    of the block it writes, in order, the frames recorded by :func:`save_frame` (pictures) and,
    once the plotter was shown by :func:`show_or_save`, its final scene: a picture and, when
    trame-pyvista is installed, the scene exported for vtk.js (``.vtksz``), which PyVista's
    ``offlineviewer`` directive shows as an interactive view in a tab beside the picture.

    A plotter that was not shown yet stays open for the next block, so a figure can be built
    over several cells of narrative; :func:`reset_gallery` closes what is left at the end of a
    walkthrough.

    Unlike ``pyvista.DynamicScraper`` (which captures and closes every open plotter after every
    block) this works with plotters that span cells and records intermediate slider states.

    Parameters
    ----------
    dynamic : bool, optional
        Also embed the interactive vtk.js scene (default True).
    """

    def __init__(self, *, dynamic: bool = True):
        self.dynamic = bool(dynamic)

    def __repr__(self) -> str:  # stable: sphinx-gallery hashes its configuration
        return f"GalleryScraper(dynamic={self.dynamic})"

    def __call__(self, block, block_vars, gallery_conf) -> str:
        """Write the block's figures and return their reST (sphinx-gallery's scraper API).

        Parameters
        ----------
        block : tuple
            The code block (sphinx-gallery's ``(label, content, line_number)``).
        block_vars : dict
            sphinx-gallery's block variables; ``image_path_iterator`` names the files.
        gallery_conf : dict
            sphinx-gallery's configuration (``src_dir``).

        Returns
        -------
        str
            reST for the figures, empty when the block made none.

        Raises
        ------
        RuntimeError
            If a plotter was closed without being rendered (nothing to show).
        """
        import pyvista as pv
        from PIL import Image
        from pyvista.plotting.utilities.sphinx_gallery import html_rst

        paths = block_vars["image_path_iterator"]
        names = []
        plotters = pv.plotting.plotter._ALL_PLOTTERS
        for key, plotter in list(plotters.items()):
            for frame in getattr(plotter, "_xray_viz_frames", ()):
                path = Path(next(paths)).with_suffix(".png")
                Image.fromarray(frame).save(path)
                names.append(str(path))
            plotter._xray_viz_frames = []
            if not plotter._closed:
                continue                        # not shown yet: a later block shows it
            plotters.pop(key)
            if plotter.last_image is None:
                raise RuntimeError("a walkthrough closed a plotter without rendering it; "
                                   "end each figure with show_or_save()")
            path = Path(next(paths)).with_suffix(".png")
            Image.fromarray(plotter.last_image).save(path)
            vtksz = getattr(plotter, "last_vtksz", None)
            if self.dynamic and vtksz is not None:
                path = path.with_suffix(".vtksz")
                path.write_bytes(vtksz)
            names.append(str(path))
        return html_rst(names, gallery_conf["src_dir"]) if names else ""


#: The scraper instance ``docs/conf.py`` names (``"xray_viz.walkthroughs.gallery_scraper"``).
gallery_scraper = GalleryScraper()


def reset_gallery(gallery_conf, fname) -> None:
    """Close every PyVista plotter left open between two walkthroughs (sphinx-gallery reset).

    Parameters
    ----------
    gallery_conf : dict
        sphinx-gallery's configuration (unused).
    fname : str or None
        The walkthrough about to run or just run (unused).
    """
    import sys

    pv = sys.modules.get("pyvista")
    if pv is not None:
        pv.close_all()


# --------------------------------------------------------------------------------------------
# Finding and running the walkthroughs


def _folder():
    return importlib.resources.files("xray_viz._walkthroughs")


def _title(text: str) -> str:
    try:
        doc = ast.get_docstring(ast.parse(text)) or ""
    except SyntaxError:  # pragma: no cover - the test suite runs every walkthrough
        doc = ""
    return doc.strip().splitlines()[0].strip() if doc.strip() else ""


def list_walkthroughs() -> list[tuple[int, str, str]]:
    """Every walkthrough, in order.

    Returns
    -------
    list of (int, str, str)
        ``(number, name, title)``, e.g. ``(1, "01_parametric_ray", "The parametric ray ...")``.
    """
    out = []
    for entry in _folder().iterdir():
        m = _NAME.match(entry.name)
        if m:
            out.append((int(m.group(1)), entry.name[:-3], _title(entry.read_text("utf-8"))))
    return sorted(out)


def walkthrough_path(n: int) -> Path:
    """Path of walkthrough ``n``'s script.

    Raises
    ------
    WalkthroughNotFoundError
        If there is no walkthrough ``n``; the message lists the valid numbers.
    """
    for number, name, _ in list_walkthroughs():
        if number == n:
            return Path(str(_folder() / f"{name}.py"))
    valid = ", ".join(str(k) for k, _, _ in list_walkthroughs())
    raise WalkthroughNotFoundError(f"no walkthrough {n}; choose one of {valid}")


def run_walkthrough(n: int, *, off_screen: bool | None = None) -> dict:
    """Run walkthrough ``n`` as a script (``runpy``) in a fresh namespace.

    Parameters
    ----------
    n : int
        Number of the walkthrough (see :func:`list_walkthroughs`).
    off_screen : bool or None, optional
        True writes the figures as PNGs instead of opening windows (sets
        ``PYVISTA_OFF_SCREEN=true`` for the run); None leaves the environment as it is.

    Returns
    -------
    dict
        The script's global namespace after it ran.

    Raises
    ------
    WalkthroughNotFoundError
        If there is no walkthrough ``n``.
    """
    import runpy

    import sys

    path = walkthrough_path(int(n))
    saved_env = os.environ.get("PYVISTA_OFF_SCREEN")
    pv = sys.modules.get("pyvista")
    saved_pv = getattr(pv, "OFF_SCREEN", None)
    if off_screen is not None:
        os.environ["PYVISTA_OFF_SCREEN"] = "true" if off_screen else "false"
        if pv is not None:
            pv.OFF_SCREEN = bool(off_screen)
    try:
        return runpy.run_path(str(path), run_name="__main__")
    finally:
        if off_screen is not None:
            if saved_env is None:
                os.environ.pop("PYVISTA_OFF_SCREEN", None)
            else:
                os.environ["PYVISTA_OFF_SCREEN"] = saved_env
            pv = sys.modules.get("pyvista")
            if pv is not None:
                pv.OFF_SCREEN = bool(saved_pv) if saved_pv is not None else bool(
                    (saved_env or "").strip().lower() in _TRUE)


def add_walkthrough_parser(subparsers):
    """Add the ``walkthrough`` sub-command to an :mod:`argparse` sub-parsers object.

    Parameters
    ----------
    subparsers : argparse._SubParsersAction
        From ``parser.add_subparsers()``.

    Returns
    -------
    argparse.ArgumentParser
        The new sub-parser (its ``func`` default is :func:`walkthrough_command`).
    """
    p = subparsers.add_parser(
        "walkthrough", help="list or run the walkthroughs that rebuild the thesis step by step",
        description="Run a walkthrough: a script that rebuilds one step of the thesis with the "
                    "code, opening PyVista windows (or writing PNGs with --off-screen).")
    p.add_argument("number", nargs="?", type=int, metavar="N", help="walkthrough to run, 1 to %d (see --list)" % len(list_walkthroughs()))
    p.add_argument("--list", action="store_true", help="list the walkthroughs and exit")
    p.add_argument("--off-screen", action="store_true",
                   help="write the figures as PNGs (into $XRAY_VIZ_OUTPUT, default "
                        "out/walkthroughs/NN/) instead of opening windows")
    p.set_defaults(func=walkthrough_command)
    return p


def walkthrough_command(args) -> int:
    """Run the ``walkthrough`` sub-command.

    Parameters
    ----------
    args : argparse.Namespace
        With ``list`` (bool), ``number`` (int or None) and ``off_screen`` (bool).

    Returns
    -------
    int
        Exit status, 0.

    Raises
    ------
    WalkthroughNotFoundError
        If ``number`` is not a walkthrough, or neither ``--list`` nor a number was given.
    XrayVizError
        On screen (no ``--off-screen``, ``PYVISTA_OFF_SCREEN`` not set) without a display to
        open the windows on (:func:`xray_viz.viz.display.require_display`).
    """
    if args.list or args.number is None:
        if not args.list:
            valid = ", ".join(str(k) for k, _, _ in list_walkthroughs())
            raise WalkthroughNotFoundError(f"give a walkthrough number ({valid}) or --list")
        for number, name, title in list_walkthroughs():
            print(f"{number:2d}  {name:32s} {title}")
        return 0
    walkthrough_path(args.number)                  # an unknown number first: its own error
    if not args.off_screen and not is_off_screen():
        from xray_viz.viz.display import require_display

        require_display("--off-screen to write the figures as PNGs")
    from xray_viz.scene_options import _compile_notice

    with _compile_notice("fast"), _progress.task(f"walkthrough {args.number}", unit="figures"):
        run_walkthrough(args.number, off_screen=True if args.off_screen else None)
    return 0


# --------------------------------------------------------------------------------------------
# Small drawing helpers shared by the walkthroughs


def arrow(start, end, *, tip=None, shaft=None):
    """:func:`xray_viz.viz.shapes.solid_arrow` (a fixed-size tip), imported only when a
    walkthrough draws one."""
    from xray_viz.viz.shapes import solid_arrow

    return solid_arrow(start, end, tip=tip, shaft=shaft)


def polyline(points):
    """A :class:`pyvista.PolyData` line through ``points`` ((n, 3) float), in order
    (:func:`xray_viz.viz.shapes.polyline`)."""
    from xray_viz.viz.shapes import polyline as _polyline

    return _polyline(points)


def segments(starts, ends):
    """Many separate line segments ``starts[k] -> ends[k]`` as one :class:`pyvista.PolyData`
    (:func:`xray_viz.viz.shapes.segments`, as the scene view draws its rays)."""
    from xray_viz.viz.shapes import segments as _segments

    return _segments(starts, ends)

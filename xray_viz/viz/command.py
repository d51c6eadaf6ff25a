"""``xray-viz show SCENE [--screenshot OUT.png] [--size W H]``: the viewer from the command line.

``--size`` is the *window's* size in pixels; the detector's is ``--detector-size`` (mm) or
``--shape`` (pixels), the scene overrides that ``render`` has too
(:func:`xray_viz.scene_options.add_scene_overrides`).

The lead's :mod:`xray_viz.cli` wires it in with :func:`add_show_parser`.
"""

from __future__ import annotations

import argparse
import functools
import os
import sys
from pathlib import Path

from xray_viz.errors import OutputError, XrayVizError
from xray_viz.viz.display import require_display

__all__ = ["add_show_parser", "show_command", "require_display", "SCREENSHOT_FORMATS",
           "MAX_RESOLUTION"]

#: File suffixes ``--screenshot`` can write.
SCREENSHOT_FORMATS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff")

#: Smallest window ``--size`` accepts.
MIN_SIZE = (400, 200)

#: Largest window side ``--size`` accepts, in pixels (VTK aborts with ``std::bad_alloc`` when
#: it cannot allocate a render window of, say, 100000 x 100000).
MAX_SIZE = 8192


#: Largest preview resolution ``--resolution`` accepts, pixels along the detector's longer side
#: (the viewer re-renders at it on every slider move; 2048 x 2048 already takes seconds).
MAX_RESOLUTION = 2048


def _use_egl_if_headless() -> None:
    """Off-screen without an X server: let VTK pick EGL (Mesa llvmpipe) instead of X."""
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY") \
            and not os.environ.get("WAYLAND_DISPLAY"):
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def add_show_parser(subparsers) -> argparse.ArgumentParser:
    """Add the ``show`` sub-command to ``xray-viz``'s sub-parsers.

    Examples
    --------
    >>> import argparse
    >>> parser = argparse.ArgumentParser(prog="xray-viz")
    >>> _ = add_show_parser(parser.add_subparsers())
    >>> args = parser.parse_args(["show", "sphere", "--screenshot", "out.png"])
    >>> args.size
    [1400, 700]
    """
    p = subparsers.add_parser(
        "show", help="open the interactive 3D viewer (or save a screenshot of it)",
        description="Show a scene in 3D - the source r0, the detector's pixel grid, the "
                    "vectors HO, VE, FL and LHC, a few rays with their entry and exit points - "
                    "beside its radiograph. Sliders move the source, turn the bodies and change "
                    "the energy and preview resolution; clicking a pixel of the radiograph "
                    "shows its ray and mu along it. With --screenshot the same view is "
                    "rendered off-screen (no display needed) and saved.")
    p.add_argument("scene", metavar="SCENE",
                   help="a scene .toml file, or a bundled phantom name (`xray-viz phantoms`)")
    p.add_argument("--screenshot", metavar="OUT", default=None,
                   help="render off-screen, save the window to OUT (.png, .jpg, .bmp, .tiff) "
                        "and exit")
    p.add_argument("--size", nargs=2, type=int, metavar=("W", "H"), default=[1400, 700],
                   help=f"window size in pixels, from {MIN_SIZE[0]} x {MIN_SIZE[1]} to "
                        f"{MAX_SIZE} a side (default: 1400 700)")
    p.add_argument("--rays", default="grid 7",
                   help="rays drawn in 3D: 'grid N', 'every K', 'row J', 'column I', 'center' "
                        "or 'none' (default: %(default)s)")
    p.add_argument("--resolution", type=int, default=None, metavar="N",
                   help="preview resolution: pixels along the detector's longer side, at "
                        f"most {MAX_RESOLUTION} (default: the scene's)")
    p.add_argument("--texture", action="store_true",
                   help="also drape the radiograph on the detector plane")
    p.add_argument("--view", choices=("side", "bodies"), default="side",
                   help="starting camera: the whole set-up from the side (default), or a "
                        "close-up of the bodies with the detector behind them (keys v and b)")
    p.add_argument("--volume-style", choices=("slices", "volume"), default="slices",
                   help="how a voxel volume ([[ct]] or [[labels]] traced as voxels) is drawn: "
                        "three orthogonal slices in an HU window (default), or a volume "
                        "rendering with air transparent, soft tissue faint and bone opaque "
                        "(key x switches)")
    p.add_argument("--web", action="store_true",
                   help="serve the viewer as a web page (a trame server; needs the jupyter "
                        "extra) instead of opening a window: for a browser on this machine, or "
                        "with --host on others; Ctrl-C stops it")
    p.add_argument("--host", default=None, metavar="HOST",
                   help="with --web: the interface to listen on (default: 127.0.0.1, this "
                        "machine only; 0.0.0.0 for every interface)")
    p.add_argument("--port", type=int, default=None, metavar="N",
                   help="with --web: the port (default: 0, any free port; the URL is printed)")
    add_dose_arguments(p)
    from xray_viz.render import add_scatter_arguments

    add_scatter_arguments(p, per="view")
    p.add_argument("--radiograph", choices=("total", "primary", "scatter", "spr"),
                   default=None, help="with --scatter: the view of the radiograph to start "
                                      "with (default: total)")
    from xray_viz.scene_options import add_scene_overrides

    add_scene_overrides(p)
    p.set_defaults(func=show_command)
    return p


def show_command(args) -> int:
    """Run ``xray-viz show``: open the viewer, or save a screenshot of it off-screen.

    Raises
    ------
    OutputError
        Unsupported screenshot format, or a window smaller than 400 x 200 or with a side
        larger than 8192 pixels.
    XrayVizError
        No display to open a window on (use ``--screenshot``), a bad ``--rays``, a
        ``--resolution`` below 2 or above :data:`MAX_RESOLUTION`.
    SceneError, SceneFileNotFoundError
        From :func:`xray_viz.load_scene`.
    """
    from xray_viz import progress
    from xray_viz.scene_options import _compile_notice, load_scene_with_overrides

    out = Path(args.screenshot) if args.screenshot else None
    if args.web and out is not None:
        raise XrayVizError("--web and --screenshot do not go together: --web serves the viewer "
                           "to a browser, --screenshot saves a picture of it")
    if args.port is not None and not 0 <= args.port <= 65535:
        raise XrayVizError(f"--port {args.port}: a port is a number from 0 (any free one) to "
                           "65535")
    if out is not None and out.suffix.lower() not in SCREENSHOT_FORMATS:
        raise OutputError(f"{out}: unknown screenshot format {out.suffix or '(none)'!r}; use "
                          f"one of {', '.join(SCREENSHOT_FORMATS)}")
    if out is not None and not out.parent.is_dir():
        raise OutputError(f"{out}: the directory {out.parent} does not exist")
    w, h = (int(s) for s in args.size)
    if w < MIN_SIZE[0] or h < MIN_SIZE[1]:
        raise OutputError(f"--size {w} {h}: the window must be at least "
                          f"{MIN_SIZE[0]} x {MIN_SIZE[1]} pixels")
    if w > MAX_SIZE or h > MAX_SIZE:
        raise OutputError(f"--size {w} {h}: {max(w, h)} pixels is too large; each side must "
                          f"be at most {MAX_SIZE} pixels")
    if args.resolution is not None and args.resolution < 2:
        raise XrayVizError(f"--resolution must be >= 2 pixels, got {args.resolution}")
    if args.resolution is not None and args.resolution > MAX_RESOLUTION:
        raise XrayVizError(f"--resolution {args.resolution}: too large; the preview can be at "
                           f"most {MAX_RESOLUTION} pixels along the detector's longer side")
    from xray_viz.render import scatter_arguments

    scatter, histories, smoothing = scatter_arguments(args)
    if getattr(args, "radiograph", None) is not None and scatter is None:
        raise XrayVizError(f"--radiograph {args.radiograph} needs --scatter mc or kernel: "
                           "without scatter the radiograph is the primary alone")
    from xray_viz.viz.rays import select_pixels

    scene = load_scene_with_overrides(args)
    if args.volume_style != "slices" and not scene.volumes:
        raise XrayVizError(f"--volume-style {args.volume_style}: {args.scene} has no voxel "
                           "volume ([[ct]] or [[labels]] with trace = \"voxels\"); leave the "
                           "option out")
    try:
        select_pixels(scene.detector.shape, args.rays)
    except ValueError as exc:
        raise XrayVizError(f"--rays: {exc}") from None
    if getattr(args, "dose", None) is not None:
        return dose_window(args, scene, (w, h), out)
    if args.web:
        return _serve_web(args, scene, (w, h))
    if args.host is not None or args.port is not None:
        raise XrayVizError("--host and --port go with --web (serve the viewer as a web page)")
    if out is None:
        require_display("--screenshot OUT.png to render the view off-screen, or --web to "
                        "serve it to a browser")
    if out is not None:
        _use_egl_if_headless()
    from xray_viz.viz.viewer import Viewer

    with _compile_notice("fast"), progress.task("opening the viewer", unit="rows"):
        viewer = Viewer(scene, rays=args.rays, resolution=args.resolution,
                        texture=args.texture, window_size=(w, h), off_screen=out is not None,
                        scatter=scatter, histories=histories, scatter_smoothing=smoothing)
    if getattr(args, "volume_style", "slices") != "slices":
        viewer.set_volume_style(args.volume_style)
    if args.view == "bodies":
        viewer.view_bodies()
    if getattr(args, "radiograph", None) is not None:
        viewer.set_quantity(args.radiograph)
    if out is None:
        viewer.show()
        return 0
    viewer.screenshot(out)
    viewer.close()
    sw, sh = viewer.scene.detector.shape               # the preview's, at --resolution
    print(f"wrote {out} ({w}x{h} window: 3D scene left, {sw}x{sh} radiograph right, render "
          f"{viewer.radiograph.timing['total'] * 1000:.0f} ms)")
    return 0


def add_dose_arguments(p) -> None:
    """``show``'s ``--dose N`` (issue 38): the transport's window (its seed: ``--seed``)."""
    p.add_argument("--dose", type=int, default=None, metavar="N",
                   help="run the photon transport with N histories (seed: --seed, default 0) "
                        "and show its four detector images (primary, single incoherent, single "
                        "coherent, multiple) and the energy and dose per body as a table, "
                        "instead of the 3D scene")


def dose_window(args, scene, window_size, out) -> int:
    """``show --dose N``: :func:`xray_viz.transport` of the scene, shown by
    :func:`xray_viz.viz.dose_view.plot_transport` (or saved with ``--screenshot``)."""
    if args.web:
        raise XrayVizError("--dose and --web do not go together yet: use --dose with a window "
                           "or --screenshot, or `xray-viz dose` for the table alone")
    if out is None:
        require_display("--screenshot OUT.png to save the transport's window off-screen")
    else:
        _use_egl_if_headless()
    import xray_viz
    from xray_viz import progress
    from xray_viz.viz.dose_view import plot_transport

    seed = 0 if getattr(args, "seed", None) is None else int(args.seed)
    with progress.task(f"transport of {args.dose} histories", unit="histories"):
        result = xray_viz.transport(scene, args.dose, seed=seed)
    name = Path(str(scene.path)).stem if scene.path else "scene"
    plotter = plot_transport(result, window_size=window_size, off_screen=out is not None,
                             title=f"{name}: photon transport, seed {seed}").plotter
    if out is None:
        plotter.show()
        return 0
    plotter.screenshot(str(out))
    plotter.close()
    print(f"wrote {out} (transport of {result.histories} histories: four detector images and "
          f"the energy per body)")
    return 0


def _serve_web(args, scene, window_size) -> int:
    """``--web``: the viewer on a trame server (:func:`xray_viz.viz.web.serve`)."""
    from xray_viz import progress
    from xray_viz.scene_options import _compile_notice
    from xray_viz.viz import web

    web.require_trame()
    host = args.host if args.host is not None else web.DEFAULT_HOST
    port = args.port if args.port is not None else 0
    with _compile_notice("fast"), progress.task("opening the viewer", unit="rows"):
        viewer = web.WebViewer(scene, rays=args.rays, resolution=args.resolution,
                               texture=args.texture, window_size=window_size,
                               height=window_size[1],
                               scatter=None if args.scatter == "none" else args.scatter,
                               histories=args.histories,
                               scatter_smoothing=args.scatter_smoothing)
    if getattr(args, "volume_style", "slices") != "slices":
        viewer.viewer.set_volume_style(args.volume_style)
    if args.view == "bodies":
        viewer.viewer.view_bodies()
    if args.radiograph is not None:
        viewer.viewer.set_quantity(args.radiograph)

    return web.serve(viewer, host=host, port=port,
                     announce=functools.partial(print, flush=True))

"""The ``xray-viz`` command line.

Every sub-command reports bad input as one line on stderr (``xray-viz: error: ...``) and exits
with status 2, without a traceback; nothing is half-written.

Messages go through :mod:`logging` (the logger ``"xray_viz"``, see :mod:`xray_viz.progress`):
notices and one-line warnings on stderr by default, debug lines with ``-v``, warnings only with
``-q`` (``-qq``: errors only). Progress bars appear on a terminal only, for jobs longer than a
couple of seconds, and never with ``-q``.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import sys
import textwrap
from pathlib import Path

from xray_viz import progress
from xray_viz.errors import XrayVizError

log = logging.getLogger("xray_viz.cli")

DESCRIPTION = """\
Simulate X-ray radiographs of triangle meshes by backward ray tracing (after Meneghini's thesis):
rays run from an X-ray point source (or a parallel beam) through each pixel of a detector, every
intersection with the scene's closed meshes is found (a watertight footprint rasteriser by
default, a watertight Moller-Trumbore reference with --engine numpy), and each ray is attenuated
by Beer-Lambert's law over the path lengths it crossed.

A scene is a TOML file ([source], [detector], [[body]] tables) or the name of a bundled phantom
(see `xray-viz phantoms`). Geometry is in mm, mu in 1/cm, energies in keV.
"""

EPILOG = """\
examples:
  xray-viz render default -o out/default.png       render the bundled default scene
  xray-viz render part.stl -o part.png             a mesh alone, framed, aluminium (it says so)
  xray-viz init --from part.stl -o scene.toml      that scene as a commented file to edit
  xray-viz render scene.toml -o image.npy          float64 intensity array, as the API returns it
  xray-viz render scene.toml -o li.tiff --quantity line-integral
  xray-viz render limb -o limb.png --energy 40     a scene file's value, changed for one run
  xray-viz render frog -o frog.tiff --scatter mc --histories 2000000   with the Monte Carlo's scatter
  xray-viz phantoms                                 list the bundled phantoms
  xray-viz show frog                                the interactive 3D viewer beside the radiograph
  xray-viz show sphere --screenshot view.png        the same view, off-screen, to a PNG
  xray-viz bench --suite peers                      time and error against Open3D, embree, gVXR
  xray-viz mesh scan.stl -o fixed.stl --decimate 50000   repair (always) and decimate a mesh
  xray-viz mesh seg.nii.gz -o bodies/               a label map's meshes and a scene snippet
  xray-viz convert gvxr.json -o scene.toml          a gVirtualXray JSON scene as a scene file
  xray-viz walkthrough --list                       the walkthroughs that rebuild the thesis
  xray-viz walkthrough 6                            Moller-Trumbore step by step, one ray
  xray-viz register scene.toml li.tiff --body stem -o fitted.toml   a body's pose from its X-ray
  xray-viz --version --verbose                      versions of everything, for a bug report

Options for every command: -v/--verbose (debug messages), -q/--quiet (no progress bars or
notices; -qq: no warnings either).

Run `xray-viz COMMAND --help` for the options of each command.
"""


from xray_viz.scene_options import (OVERRIDES, _compile_notice, add_scene_overrides,  # noqa: F401
                                    load_scene_with_overrides, turn_acquisition)


# --------------------------------------------------------------------------------------------
# Commands


def _render_command(args) -> int:
    import xray_viz
    from xray_viz.output import check_format, save_image
    from xray_viz.render import ENGINES

    out = Path(args.output)
    check_format(out)                 # an unknown suffix (.nii.gz is one format) is refused
    if args.supersample is not None and args.supersample < 1:
        raise XrayVizError(f"--supersample must be >= 1, got {args.supersample}")
    if args.max_error is not None and not (args.max_error > 0 and args.max_error < float("inf")):
        raise XrayVizError(f"--max-error must be a number > 0 (the largest change of a pixel's "
                           f"line integral, e.g. 0.01), got {args.max_error}")
    if args.engine not in ENGINES:
        raise XrayVizError(f"unknown engine {args.engine!r}; choose one of {', '.join(ENGINES)}")
    from xray_viz.render import scatter_arguments

    scatter, _, _ = scatter_arguments(args)
    from xray_viz.output import check_target

    check_target(out)                 # a read-only target is refused before the render
    if ENGINES[args.engine].compiled:   # kernels missing from numba's cache: compiled meanwhile
        from xray_viz._kernel_hint import likely_paths
        from xray_viz.tracing._raster import KERNELS

        KERNELS.prepare(first=likely_paths(args.scene))
    with _compile_notice(args.engine):   # said when a kernel is first needed, if compiling
        scene = load_scene_with_overrides(args)
        h = scene.detector.shape[1]
        log.debug("rendering with engine %s, supersample %s", args.engine,
                  args.supersample or scene.detector.supersample)
        with progress.task("rendering", total=h, unit="rows"), \
                contextlib.ExitStack() as monte_carlo:
            bar = []

            def histories_done(done, total):        # the Monte Carlo's own bar, once it runs
                if not bar:
                    bar.append(monte_carlo.enter_context(progress.task(
                        "scatter (Monte Carlo)", total=total, unit="histories")))
                bar[0].update_to(done, total)

            image = xray_viz.render(scene, engine=args.engine, supersample=args.supersample,
                                    max_error=args.max_error, scatter=scatter,
                                    histories=args.histories,
                                    scatter_smoothing=args.scatter_smoothing,
                                    progress=histories_done if scatter == "mc" else None)
    log.debug("timing (s): %s", {k: round(v, 4) for k, v in image.timing.items()})
    data = image.quantity(args.quantity)
    engine, total_ms = image.engine, image.timing["total"] * 1000
    details = image.scatter_details
    spr = None
    if details is not None:
        import numpy as np

        spr = float(np.sum(image.scatter) / np.sum(image.primary))    # over the field
    if details is not None:
        details = {k: v for k, v in details.items() if k != "error"}
    del image                         # only the image written stays in memory while saving
    save_image(out, data, bright="low" if args.quantity == "intensity" else "high", scene=scene,
               quantity=args.quantity, scatter=details)
    w, h = scene.detector.shape
    n = len(scene.bodies)
    dose = ""
    if scene.source.mas is not None:
        from xray_viz.physics.dosimetry import air_kerma

        k = air_kerma(scene)
        dose = (f", {k.mas:g} mAs: air kerma " + (f"{k.entrance_uGy:.4g} uGy at entrance, "
                if k.entrance_uGy is not None else "") + f"{k.detector_uGy:.4g} uGy at detector")
    nv = len(scene.volumes)
    vols = f", {nv} voxel volume{'s' * (nv > 1)}" if nv else ""
    scattered = "" if spr is None else f", scatter {details['mode']}: SPR {spr:.3g} over the field"
    if not args.quiet:                # -q: nothing on success, as `cp` says nothing
        print(f"wrote {out} ({args.quantity}, {w}x{h}, {n} bod{'y' if n == 1 else 'ies'}{vols}, "
              f"engine {engine}, {total_ms:.0f} ms{dose}{scattered})")
    if ENGINES[args.engine].compiled:   # the compiled mesh checks, for the next runs
        from xray_viz.meshes import _check_kernels

        _check_kernels.prepare(nice=10)
    return 0


def _phantoms_command(args) -> int:
    from xray_viz import phantoms

    for name in phantoms.names():
        text = textwrap.fill(phantoms.describe(name), width=92, initial_indent="    ",
                             subsequent_indent="    ")
        print(f"{name}{'  (default)' if name == phantoms.DEFAULT else ''}\n{text}")
    return 0


#: The packages of a bug report (:func:`version_report`): the core, then what is optional.
REPORT_CORE = ("xray_viz", "numpy", "scipy", "numba", "llvmlite", "vtk", "pyvista", "pymeshlab",
               "trimesh", "xraylib", "spekpy", "pydicom", "PIL", "tqdm", "matplotlib")
REPORT_OPTIONAL = ("trame_pyvista", "nbclient", "sphinx", "open3d", "embreex", "gvxr")


def version_report(*, gpu: bool = True) -> str:
    """The versions of xray_viz, its dependencies and the render window, for bug reports.

    A :class:`scooby.Report` (as :class:`pyvista.Report` is): the platform, Python, every
    package of :data:`REPORT_CORE` and those of :data:`REPORT_OPTIONAL` that are installed,
    and with ``gpu`` the OpenGL renderer and VTK's render-window class (from an off-screen
    window, EGL when there is no display; ``error: ...`` when none can be made).

    Examples
    --------
    >>> "numba :" in version_report(gpu=False)
    True
    """
    import scooby

    meta = _render_window_info() if gpu else []
    return str(scooby.Report(core=list(REPORT_CORE), optional=list(REPORT_OPTIONAL),
                             extra_meta=meta, sort=False, text_width=92))


#: Run in a subprocess by :func:`_render_window_info` (a broken GPU driver may crash it): the
#: OpenGL strings and VTK's render-window class, as pyvista.Report's GPUInfo reads them, with
#: only the two VTK modules a window needs imported (``import vtk`` loads every module: ~1 s).
_WINDOW_PROBE = """
from vtkmodules.vtkRenderingCore import vtkRenderer, vtkRenderWindow
import vtkmodules.vtkRenderingOpenGL2
win = vtkRenderWindow()
win.OffScreenRenderingOn()
win.AddRenderer(vtkRenderer())
win.Render()
print(win.ReportCapabilities())
print("vtkRenderWindow class name:", win.GetClassName())
"""


def _render_window_info() -> list[tuple[str, str]]:
    """The OpenGL vendor, renderer and version and VTK's render-window class (from an
    off-screen window, EGL when there is no display), or ``error: ...`` rows."""
    import os
    import re
    import subprocess

    env = dict(os.environ)
    if sys.platform.startswith("linux") and not env.get("DISPLAY") \
            and not env.get("WAYLAND_DISPLAY"):    # as `xray-viz show --screenshot` does
        env.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")
    try:
        done = subprocess.run([sys.executable, "-c", _WINDOW_PROBE], env=env, timeout=60,
                              capture_output=True, text=True)
        text = done.stdout if done.returncode == 0 else ""
        error = "" if text else (done.stderr.strip().splitlines() or
                                 [f"exit status {done.returncode}"])[-1]
    except (OSError, subprocess.SubprocessError) as exc:
        text, error = "", str(exc)

    def field(name):
        found = re.findall(rf"{name}:(.+)\n", text)
        return found[0].strip() if found else f"error: {error or 'not reported'}"

    return [("GPU Vendor", field("OpenGL vendor string")),
            ("GPU Renderer", field("OpenGL renderer string")),
            ("GPU Version", field("OpenGL version string")),
            ("Render Window", field("vtkRenderWindow class name"))]


def _report_command(args) -> int:
    print(version_report())
    return 0


def bench_suites() -> Path | None:
    """``benchmarks/suites.py`` of the source checkout this package runs from, if any."""
    import xray_viz

    path = Path(xray_viz.__file__).resolve().parents[1] / "benchmarks" / "suites.py"
    return path if path.is_file() else None


def _bench_command(args) -> int:
    """``xray-viz bench ARGS``: the benchmark suites (a thin entry: they are not installed)."""
    suites = bench_suites()
    if suites is None:
        from xray_viz import __version__

        raise XrayVizError(
            "the benchmark suites are not in an installed wheel: they ship in the source "
            f"distribution (xray_viz-{__version__}.tar.gz) and the repository, in benchmarks/; "
            "in that source tree install the benchmark extra with `pip install -e '.[bench]'` "
            "(Open3D, embreex, gVXR) and run `bash benchmarks/setup.sh` (their Debian "
            "libraries), then `xray-viz bench` (see BENCHMARKS.md)")
    import runpy

    module = runpy.run_path(str(suites), run_name="xray_viz_bench_suites")
    return module["main"](list(args.bench_args))


# --------------------------------------------------------------------------------------------
# The parser


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line, like every other error of the CLI."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def _add_verbosity(parser, *, top: bool) -> None:
    """``-v`` and ``-q``: on the main parser, and again on every command (so that they can
    follow it); a command's own count replaces the main parser's."""
    default = 0 if top else argparse.SUPPRESS
    g = parser.add_argument_group("messages") if not top else parser
    g.add_argument("-v", "--verbose", action="count", default=default,
                   help="also print debug messages on stderr (with --version: the versions of "
                        "every dependency)" if top else "also print debug messages on stderr")
    g.add_argument("-q", "--quiet", action="count", default=default,
                   help="no progress bars or notices on stderr, no 'wrote ...' line (-qq: no "
                        "warnings either)")


def build_parser(*, only: str | None = None) -> argparse.ArgumentParser:
    """The ``xray-viz`` argument parser with every subcommand.

    Parameters
    ----------
    only : str, optional
        Build the sub-parser of this command only (``"render"``): it parses that command's
        arguments exactly as the whole parser does, without importing the other commands'
        modules (see :func:`_only_command`).
    """
    parser = _Parser(
        prog="xray-viz", description=DESCRIPTION, epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter)

    parser.add_argument("--version", action="store_true",
                        help="print the version and exit (with -v: every dependency's, as "
                             "`xray-viz report`)")
    _add_verbosity(parser, top=True)
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    from xray_viz.output import FORMATS, suffixes
    from xray_viz.render import ENGINES, QUANTITIES

    images = suffixes(image=True)
    said = {FORMATS[k].holds: k for k in reversed(images)}     # each description once
    p = sub.add_parser(
        "render", help="render a scene's radiograph to an image file",
        description="Render a scene's radiograph and write it to OUT. The format follows OUT's "
                    "suffix: " + "; ".join(f"{k} = {FORMATS[k]}" for k in images
                                           if said[FORMATS[k].holds] == k)
                    + ".", formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", metavar="SCENE",
                   help="a scene .toml file (or a gVirtualXray .json scene), or a bundled phantom "
                        "name (`xray-viz phantoms`)")
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="output file: " + ", ".join(images) + "; all but .npy keep the pixel "
                        "pitch and the scene's geometry (xray_viz.load_image reads them back)")
    p.add_argument("--quantity", choices=QUANTITIES, default="intensity",
                   help="what to write: intensity I = I0 exp(-line integral) (default), the "
                        "line integral sum(mu L), or the total path length in mm")
    p.add_argument("--supersample", type=int, default=None, metavar="N",
                   help="trace N x N rays per pixel and average them (anti-aliasing); default: "
                        "the scene's [detector] supersample, else 1")
    p.add_argument("--engine", default="fast", choices=sorted(ENGINES),
                   help="tracing engine (default: %(default)s)")
    p.add_argument("--max-error", type=float, default=None, metavar="E",
                   help="level of detail: trace each body at the coarsest mesh decimation that "
                        "keeps every pixel's line integral -ln(I/I0) within E (e.g. 0.01, ~1%% "
                        "of the intensity) of the full-resolution render; the choice is printed "
                        "(per body with -v). Default: the meshes as they are")
    from xray_viz.render import add_scatter_arguments

    add_scatter_arguments(p, per="render")
    add_scene_overrides(p)
    p.set_defaults(func=_render_command)
    if only is None:
        _add_other_commands(sub)
    for name, command in sub.choices.items():
        if name != "bench":                    # bench passes its options to the suites
            _add_verbosity(command, top=False)
    return parser


def _add_other_commands(sub) -> None:
    """Every sub-parser but ``render``'s."""
    from xray_viz.meshes.command import add_mesh_parser
    from xray_viz.viz.command import add_show_parser

    add_show_parser(sub)
    add_mesh_parser(sub)
    from xray_viz.convert import add_convert_parser, add_init_parser

    add_convert_parser(sub)
    add_init_parser(sub)
    p = sub.add_parser(
        "bench", help="benchmark the engines: time vs error, peers, scaling (source checkout)",
        add_help=False, description="Runs benchmarks/suites.py of the source repository.")
    p.set_defaults(func=_bench_command, bench_args=[])
    from xray_viz.walkthroughs import add_walkthrough_parser

    add_walkthrough_parser(sub)
    from xray_viz.scan import add_scan_parser

    add_scan_parser(sub)
    from xray_viz.reconstruct import add_reconstruct_parser

    add_reconstruct_parser(sub)
    # the photon transport (issue 38): energy and dose per body
    from xray_viz.montecarlo.command import add_dose_parser

    add_dose_parser(sub)
    from xray_viz.registration import add_register_parser      # issue 41

    add_register_parser(sub)

    p = sub.add_parser("phantoms", help="list the bundled phantoms",
                       description="List the bundled phantoms with their descriptions. Each name "
                                   "can be used wherever a scene file is expected.")
    p.set_defaults(func=_phantoms_command)
    p = sub.add_parser("report", help="print the versions of everything, for a bug report",
                       description="Print the platform, Python, the versions of xray_viz and "
                                   "its dependencies (numba, VTK, pyvista, pymeshlab, xraylib, "
                                   "spekpy, ...) and the render window VTK opens (as "
                                   "pyvista.Report() does). The same as `xray-viz --version "
                                   "--verbose`.")
    p.set_defaults(func=_report_command)


#: The main parser's options that may come before the command (none takes a value).
_LEADING = frozenset({"-v", "--verbose", "-q", "--quiet"})


def _only_command(argv) -> str | None:
    """``"render"`` when the arguments are those of ``xray-viz [-v|-q]... render ...``: then
    the render sub-parser alone parses them as the whole parser would (the main parser's own
    options take no value, so the command is the first other argument), and the other
    commands' modules are not imported. None otherwise (``--help``, ``--version`` or anything
    else before the command, or another command): the whole parser.

    Examples
    --------
    >>> _only_command(["-v", "render", "default", "-o", "x.png"]), _only_command(["-h", "render"])
    ('render', None)
    """
    for arg in argv:
        if arg == "render":
            return arg
        if not (arg in _LEADING or (len(arg) > 1 and arg[0] == "-" and set(arg[1:]) in ({"v"},
                                                                                        {"q"}))):
            return None
    return None


def _level(verbose: int, quiet: int) -> int:
    """The logger's level for ``-v`` x ``verbose`` and ``-q`` x ``quiet``."""
    return min(logging.ERROR, max(logging.DEBUG, logging.INFO + 10 * (quiet - verbose)))


def main(argv=None) -> int:
    """Run the command line; return the exit status.

    0 on success; 2 for bad input (one line ``xray-viz: error: ...`` on stderr); 130 after
    Ctrl-C; ``128 + signum`` when SIGTERM or SIGHUP interrupted the writing of an output file
    (:func:`xray_viz.output.atomic_write` removed its temporary file first; one line says so).
    """
    argv = sys.argv[1:] if argv is None else list(argv)
    only = _only_command(argv)
    if "--version" in argv and all(a == "--version" or a in _LEADING or (
            len(a) > 1 and a[0] == "-" and set(a[1:]) <= {"v", "q"}) for a in argv):
        only = "render"        # the version or the report: the other commands' modules unused
    parser = build_parser(only=only)
    args, extra = parser.parse_known_args(argv)
    if extra and getattr(args, "command", None) == "bench":
        args.bench_args = extra              # the suites' own options (see `xray-viz bench --help`)
    elif extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    verbose, quiet = args.verbose, args.quiet
    progress.configure(enabled=not quiet and sys.stderr.isatty())
    try:
        with progress.setup_logging(_level(verbose, quiet)):
            if args.version:
                from xray_viz import __version__

                print(version_report() if verbose else f"xray-viz {__version__}")
                return 0
            if not getattr(args, "func", None):
                parser.print_help()
                return 2
            return _run(args)
    finally:
        progress.configure(enabled=False)


def _run(args) -> int:
    from xray_viz.errors import WriteInterrupted, one_line

    try:
        return int(args.func(args) or 0)
    except (XrayVizError, OSError) as exc:
        if isinstance(exc, XrayVizError):
            msg = str(exc)
        else:
            reason = exc.strerror or one_line(exc) or type(exc).__name__
            msg = f"{exc.filename}: {reason}" if exc.filename else reason
        print(f"xray-viz: error: {' '.join(msg.splitlines())}", file=sys.stderr)
        return 2
    except WriteInterrupted as exc:
        print(f"xray-viz: error: {exc}", file=sys.stderr)
        return exc.code
    except KeyboardInterrupt as exc:
        print(f"xray-viz: interrupted{f': {exc}' if str(exc) else ''}", file=sys.stderr)
        return 130


def run() -> None:
    """The ``xray-viz`` program (and ``python -m xray_viz``): :func:`main`, then exit.

    After ``render``, the process ends without the interpreter's teardown once the atexit
    handlers have run (the compile workers are waited for, logging is flushed) and stdout and
    stderr are flushed: freeing numba's compiled kernels and the libraries' module graphs one
    object at a time took ~0.4 s of a 2.3 s ``render default`` (``BENCHMARKS.md``, cold start).
    The image is written and closed by then (:func:`xray_viz.output.atomic_write`). Any other
    command, a thread still running that is not the library's idle pool, or a profiler or
    tracer (``python -m cProfile``, coverage: they write their data at the teardown) exits as
    usual.
    """
    argv = sys.argv[1:]
    code = main(argv)
    if (_only_command(argv) == "render" and _quiet_threads() and sys.getprofile() is None
            and sys.gettrace() is None and "coverage" not in sys.modules):
        import atexit
        import os

        run_exitfuncs = getattr(atexit, "_run_exitfuncs", None)
        if run_exitfuncs is not None:
            run_exitfuncs()
            for stream in (sys.stdout, sys.stderr):
                try:
                    stream.flush()
                except (OSError, ValueError):     # a closed pipe: nothing more to say
                    pass
            os._exit(code)
    sys.exit(code)


def _quiet_threads() -> bool:
    """Whether every thread but this one is a daemon or one of the engine's pool (idle now)."""
    import threading

    return all(t is threading.current_thread() or t.daemon or t.name.startswith("xray_viz-")
               for t in threading.enumerate())


if __name__ == "__main__":
    run()

"""The ``xray-viz`` command line.

Every sub-command reports bad input as one line on stderr (``xray-viz: error: ...``) and exits
with status 2, without a traceback; nothing is half-written.
"""

from __future__ import annotations

import argparse
import sys
import textwrap
from pathlib import Path

from xray_viz.errors import XrayVizError

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
  xray-viz render scene.toml -o image.npy          float64 intensity array, as the API returns it
  xray-viz render scene.toml -o li.tiff --quantity line-integral
  xray-viz phantoms                                 list the bundled phantoms
  xray-viz show frog                                the interactive 3D viewer beside the radiograph
  xray-viz show sphere --screenshot view.png        the same view, off-screen, to a PNG
  xray-viz bench --suite peers                      time and error against Open3D, embree, gVXR
  xray-viz mesh scan.stl -o fixed.stl --decimate 50000   repair (always) and decimate a mesh
  xray-viz walkthrough --list                       the walkthroughs that rebuild the thesis
  xray-viz walkthrough 6                            Moller-Trumbore step by step, one ray

Run `xray-viz COMMAND --help` for the options of each command.
"""


def _compile_notice(engine: str):
    """A context in which numba's first compilation of a fast-engine kernel prints one line
    on stderr, saying where numba will cache the kernels (numba's own answer, see
    :mod:`xray_viz.tracing._numba_cache`). Kernels loaded from the cache are not compiled, so
    a warm cache prints nothing, wherever it is."""
    import contextlib

    if engine != "fast":
        return contextlib.nullcontext()
    from xray_viz.tracing import _numba_cache

    def notice(where):
        then = f"cached in {where} afterwards" if where else "not cached: no writable place"
        print(f"xray-viz: compiling the fast engine on first use (10-30 s, {then})...",
              file=sys.stderr, flush=True)

    return _numba_cache.on_first_compile(notice)


def _render_command(args) -> int:
    import xray_viz
    from xray_viz.output import FORMATS, save_image
    from xray_viz.render import ENGINES

    out = Path(args.output)
    if out.suffix.lower() not in FORMATS:
        from xray_viz.errors import OutputError

        raise OutputError(f"{out}: unknown output format {out.suffix or '(none)'!r}; "
                          f"use one of {', '.join(FORMATS)}")
    if args.supersample is not None and args.supersample < 1:
        raise XrayVizError(f"--supersample must be >= 1, got {args.supersample}")
    if args.engine not in ENGINES:
        raise XrayVizError(f"unknown engine {args.engine!r}; choose one of {', '.join(ENGINES)}")
    from xray_viz.output import check_target

    check_target(out)                 # a read-only target is refused before the render
    scene = xray_viz.load_scene(args.scene)
    with _compile_notice(args.engine):
        image = xray_viz.render(scene, engine=args.engine, supersample=args.supersample)
    data = image.quantity(args.quantity)
    engine, total_ms = image.engine, image.timing["total"] * 1000
    del image                         # only the image written stays in memory while saving
    save_image(out, data, bright="low" if args.quantity == "intensity" else "high", scene=scene,
               quantity=args.quantity)
    w, h = scene.detector.shape
    n = len(scene.bodies)
    dose = ""
    if getattr(scene.source, "mas", None) is not None:
        from xray_viz.physics.dosimetry import air_kerma

        k = air_kerma(scene)
        dose = (f", {k.mas:g} mAs: air kerma " + (f"{k.entrance_uGy:.4g} uGy at entrance, "
                if k.entrance_uGy is not None else "") + f"{k.detector_uGy:.4g} uGy at detector")
    print(f"wrote {out} ({args.quantity}, {w}x{h}, {n} bod{'y' if n == 1 else 'ies'}, "
          f"engine {engine}, {total_ms:.0f} ms{dose})")
    return 0


def _phantoms_command(args) -> int:
    from xray_viz import phantoms

    for name in phantoms.names():
        text = textwrap.fill(phantoms.describe(name), width=92, initial_indent="    ",
                             subsequent_indent="    ")
        print(f"{name}{'  (default)' if name == phantoms.DEFAULT else ''}\n{text}")
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
        raise XrayVizError(
            "the benchmarks are not part of the installed package: they live in the source "
            "repository's benchmarks/ folder; clone it, run `pip install -e '.[bench]'` and "
            "`bash benchmarks/setup.sh` there, then `xray-viz bench` (see BENCHMARKS.md)")
    import runpy

    module = runpy.run_path(str(suites), run_name="xray_viz_bench_suites")
    return module["main"](list(args.bench_args))


class _Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line, like every other error of the CLI."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="xray-viz", description=DESCRIPTION, epilog=EPILOG,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    from xray_viz import __version__

    parser.add_argument("--version", action="version", version=f"xray-viz {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")

    from xray_viz.output import FORMATS
    from xray_viz.render import ENGINES, QUANTITIES

    p = sub.add_parser(
        "render", help="render a scene's radiograph to an image file",
        description="Render a scene's radiograph and write it to OUT. The format follows OUT's "
                    "suffix: " + "; ".join(f"{k} = {v}" for k, v in FORMATS.items() if k != ".tif")
                    + ".", formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("scene", metavar="SCENE",
                   help="a scene .toml file, or a bundled phantom name (`xray-viz phantoms`)")
    p.add_argument("-o", "--output", required=True, metavar="OUT",
                   help="output file: .npy, .tiff, .png or .dcm (DICOM with the geometry)")
    p.add_argument("--quantity", choices=QUANTITIES, default="intensity",
                   help="what to write: intensity I = I0 exp(-line integral) (default), the "
                        "line integral sum(mu L), or the total path length in mm")
    p.add_argument("--supersample", type=int, default=None, metavar="N",
                   help="trace N x N rays per pixel and average them (anti-aliasing); default: "
                        "the scene's [detector] supersample, else 1")
    p.add_argument("--engine", default="fast", choices=sorted(ENGINES),
                   help="tracing engine (default: %(default)s)")
    p.set_defaults(func=_render_command)

    from xray_viz.meshes.command import add_mesh_parser
    from xray_viz.viz.command import add_show_parser

    add_show_parser(sub)
    add_mesh_parser(sub)
    p = sub.add_parser(
        "bench", help="benchmark the engines: time vs error, peers, scaling (source checkout)",
        add_help=False, description="Runs benchmarks/suites.py of the source repository.")
    p.set_defaults(func=_bench_command, bench_args=[])
    from xray_viz.walkthroughs import add_walkthrough_parser

    add_walkthrough_parser(sub)
    from xray_viz.reconstruct import add_reconstruct_parser

    add_reconstruct_parser(sub)

    p = sub.add_parser("phantoms", help="list the bundled phantoms",
                       description="List the bundled phantoms with their descriptions. Each name "
                                   "can be used wherever a scene file is expected.")
    p.set_defaults(func=_phantoms_command)
    return parser


def _show_warning(message, category, filename, lineno, file=None, line=None):
    """Warnings (a mesh repaired at load time, ...) as one visible line on stderr."""
    print(f"xray-viz: warning: {message}", file=sys.stderr)


def main(argv=None) -> int:
    """Run the command line; return the exit status.

    0 on success; 2 for bad input (one line ``xray-viz: error: ...`` on stderr); 130 after
    Ctrl-C; ``128 + signum`` when SIGTERM or SIGHUP interrupted the writing of an output file
    (:func:`xray_viz.output.atomic_write` removed its temporary file first; one line says so).
    """
    import warnings

    from xray_viz.errors import WriteInterrupted, one_line

    warnings.showwarning = _show_warning
    parser = build_parser()
    args, extra = parser.parse_known_args(argv)
    if extra and getattr(args, "command", None) == "bench":
        args.bench_args = extra              # the suites' own options (see `xray-viz bench --help`)
    elif extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
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


if __name__ == "__main__":
    sys.exit(main())

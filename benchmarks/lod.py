"""Error-budgeted level of detail: what ``render(scene, max_error=...)`` saves, and what the
choice costs.

For each bundled phantom (and the sphere phantom's ball as a finer icosphere, ``--large``), its detector rescaled to ``--size`` pixels along its longest side
(same field of view), and each budget:

- ``full ms``: median render of the full-resolution scene (fast engine, per-mesh set-up done,
  the engine's kept results dropped before every repeat, so every repeat traces);
- ``reduced ms``: the same for the scene the level of detail chose (the reduced meshes, set-up
  done): the trace a ``max_error`` render pays once the choice is made;
- ``choice cold s``: :func:`xray_viz.lod.level_of_detail` with the disk cache empty and nothing
  in memory (decimations and their measurements computed); ``choice disk ms``: the same with
  the disk cache filled by that run (nothing in memory: a new process); ``choice memory ms``:
  a second choice in the same process;
- ``render(max_error) ms``: the choice and the render of a new scene of the same bodies with the
  decimations in memory (what each view of an orbit pays; ``render(scene, max_error=...)``
  with equal shares);
- ``shares``: equal (``max_error / k``, what ``render(scene, max_error=...)`` does) or the
  leftover spent (``level_of_detail(..., spend_leftover=True)``), for scenes of several bodies;
- faces before and after, the measured largest change of a pixel's line integral against the
  full render (same rays) and the estimate.

All figures of one phantom are measured in the same run, interleaved; read the ratios.

``--first-choice``: only the first choice (what a user feels: a new process, nothing cached,
``XRAY_VIZ_CACHE_DIR=off``; the scene rendered once before, so kernels and the per-mesh set-up
are not counted), each a new process, CPU seconds (``time.process_time``) and wall, medians;
with ``--before TREE`` the same in a second source tree (e.g. a worktree of main), alternated
A B A B in the same run, with the ratio and whether both chose the same faces and estimates.

Usage::

    python benchmarks/lod.py [--repeat 7] [--cold-repeat 3] [--size 512]
                             [--budgets 0.05 0.2] [--phantoms frog sphere ...]
    python benchmarks/lod.py --first-choice [--before /tmp/before] [--repeat 3] ...
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import platform
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _scaled(scene, size):
    w, h = scene.detector.shape
    f = size / max(w, h)
    det = dataclasses.replace(scene.detector, shape=(max(8, round(w * f)), max(8, round(h * f))),
                              pitch=tuple(p / f for p in scene.detector.pitch))
    return scene.replace(detector=det)


def _median_time(fn, repeat, before=None):
    times = []
    for _ in range(repeat):
        if before is not None:
            before()
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _machine() -> str:
    cpu = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    from importlib.metadata import version

    try:
        commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], capture_output=True,
                                text=True, cwd=Path(__file__).parent, check=False).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "xray_viz"], capture_output=True,
                               text=True, cwd=Path(__file__).parent, check=False).stdout.strip()
    except OSError:
        commit, dirty = "?", ""
    return (f"nproc {os.cpu_count()}, {cpu}, {platform.system()} {platform.machine()}; "
            f"Python {platform.python_version()}, numpy {version('numpy')}, numba "
            f"{version('numba')}, pymeshlab {version('pymeshlab')}; "
            f"commit {commit}{' (xray_viz modified)' if dirty else ''}; "
            f"load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}")


_CHILD = """
import json, os, sys, time
os.environ["XRAY_VIZ_CACHE_DIR"] = "off"
sys.path.insert(0, sys.argv[1])
sys.path.insert(0, sys.argv[7])                   # this script's folder (its _named_scene)
import xray_viz
from xray_viz import lod
from lod import _named_scene  # noqa
scene = _named_scene(sys.argv[2], int(sys.argv[3]), int(sys.argv[6]))
xray_viz.render(scene)
c0, t0 = time.process_time(), time.perf_counter()
_, report = lod.level_of_detail(scene, float(sys.argv[4]), spend_leftover=sys.argv[5] == "1")
cpu, wall = time.process_time() - c0, time.perf_counter() - t0
print(json.dumps({"cpu": cpu, "wall": wall, "faces": report.faces, "full": report.faces_full,
                  "levels": [[b.faces, b.estimated_error] for b in report.bodies],
                  "estimated": report.estimated_error}))
"""


def _named_scene(name, size, large):
    """A bundled phantom at ``size`` pixels, or ``"large"``: the sphere phantom's ball as an
    icosphere of ``large`` subdivisions."""
    import xray_viz

    if name != "large":
        return _scaled(xray_viz.load_scene(name), size)
    import trimesh

    from xray_viz.bodies import Bodies

    base = xray_viz.load_scene("sphere")
    ball = trimesh.creation.icosphere(subdivisions=large, radius=40.0)
    return _scaled(base.replace(bodies=Bodies([dataclasses.replace(base.bodies[0], mesh=ball)])),
                   size)


def _first_choice(args, names) -> int:
    """The ``--first-choice`` table (see the module docstring)."""
    import json
    import statistics as st

    trees = [("after", Path(__file__).resolve().parent.parent)]
    if args.before:
        trees.append(("before", Path(args.before).resolve()))
    print(f"machine: {_machine()}")
    print(f"command: {' '.join([Path(sys.executable).name, *sys.argv])}")
    print()
    head = "| phantom | detector | budget | shares | faces full | faces |"
    for label, _ in trees:
        head += f" {label} CPU s | {label} wall s |"
    if len(trees) > 1:
        head += " CPU after / before | wall after / before | same choice |"
    print(head)
    print("|" + "---|" * (head.count("|") - 1))

    def run(tree, name, spend, budget):
        env = dict(os.environ, PYTHONPATH=str(tree))
        out = subprocess.run([sys.executable, "-c", _CHILD, str(tree), name, str(args.size),
                              str(budget), "1" if spend else "0", str(args.large),
                              str(Path(__file__).resolve().parent)], env=env,
                             capture_output=True, text=True, check=True)
        return json.loads(out.stdout.strip().splitlines()[-1])

    for name in names:
        multi = len(_named_scene(name, 8, args.large).bodies) > 1
        for budget, spend in ((b, m) for b in args.budgets for m in ([False, True] if multi
                                                                      else [False])):
            runs = {label: [] for label, _ in trees}
            for tree in trees:                                  # warm the kernels' caches
                run(tree[1], name, spend, budget)
            for _ in range(args.repeat):                        # A B A B
                for label, tree in trees:
                    runs[label].append(run(tree, name, spend, budget))
            a = runs["after"][0]
            scene = _named_scene(name, args.size, args.large)
            w, h = scene.detector.shape
            title = f"sphere, {a['full']:,} faces" if name == "large" else name
            row = (f"| {title} | {w} x {h} | {budget:g} | "
                   f"{'leftover spent' if spend else 'equal'} | {a['full']:,} | {a['faces']:,} |")
            med = {}
            for label, _ in trees:
                med[label] = [st.median(r[k] for r in runs[label]) for k in ("cpu", "wall")]
                row += f" {med[label][0]:.2f} | {med[label][1]:.2f} |"
            if len(trees) > 1:
                same = all(r["levels"] == a["levels"] for rs in runs.values() for r in rs)
                row += (f" {med['after'][0] / med['before'][0]:.2f} | "
                        f"{med['after'][1] / med['before'][1]:.2f} | {'yes' if same else 'NO'} |")
            print(row, flush=True)
    print()
    print(f"load average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeat", type=int, default=7)
    p.add_argument("--cold-repeat", type=int, default=3,
                   help="cold choices (disk cache emptied before each)")
    p.add_argument("--size", type=int, default=512)
    p.add_argument("--budgets", type=float, nargs="+", default=[0.05, 0.2])
    p.add_argument("--phantoms", nargs="+", default=None)
    p.add_argument("--large", type=int, default=7, metavar="SUBDIVISIONS",
                   help="also the sphere phantom's ball as an icosphere of this subdivision "
                        "(7: 327,680 faces; 0: not)")
    p.add_argument("--first-choice", action="store_true",
                   help="only the first choice, each in a new process (see above)")
    p.add_argument("--before", default=None, metavar="TREE",
                   help="with --first-choice: also this source tree, alternated")
    args = p.parse_args(argv)
    if args.first_choice:
        from xray_viz import phantoms

        names = list(args.phantoms or phantoms.names()) + (["large"] if args.large else [])
        return _first_choice(args, names)

    root = Path(tempfile.mkdtemp(prefix="xray-viz-lod-bench-"))
    os.environ["XRAY_VIZ_CACHE_DIR"] = str(root)       # before anything reads it
    import numpy as np

    import xray_viz
    from xray_viz import lod, phantoms

    names = list(args.phantoms or phantoms.names())
    if args.large:
        names.append("large")
    print(f"machine: {_machine()}")
    print(f"command: {' '.join([Path(sys.executable).name, *sys.argv])}")
    print()
    print("| phantom | detector | budget | shares | faces full | faces | full ms | reduced ms | "
          "reduced / full | choice cold s | choice disk ms | choice memory ms | "
          "render(max_error) ms | measured error | estimated |")
    print("|---|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|")
    try:
        for name in names:
            if name == "large":
                import trimesh

                from xray_viz.bodies import Bodies

                base = xray_viz.load_scene("sphere")
                ball = trimesh.creation.icosphere(subdivisions=args.large, radius=40.0)
                scene = _scaled(base.replace(bodies=Bodies(
                    [dataclasses.replace(base.bodies[0], mesh=ball)])), args.size)
                name = f"sphere, {len(ball.faces):,} faces"
            else:
                scene = _scaled(xray_viz.load_scene(name), args.size)
            w, h = scene.detector.shape
            full = xray_viz.render(scene)                      # compile, set-up
            modes = [False, True] if len(scene.bodies) > 1 else [False]
            for budget, spend in ((b, m) for b in args.budgets for m in modes):
                cache = root / "lod"
                options = {"spend_leftover": spend}

                def cold():
                    shutil.rmtree(cache, ignore_errors=True)
                    lod.forget()
                    return lod.level_of_detail(scene, budget, **options)

                t_cold = _median_time(cold, args.cold_repeat)
                t_disk = _median_time(lambda: lod.level_of_detail(scene, budget, **options), args.repeat,
                                      before=lod.forget)
                t_mem = _median_time(lambda: lod.level_of_detail(scene, budget, **options), args.repeat)
                reduced_scene, report = lod.level_of_detail(scene, budget, **options)
                image = xray_viz.render(reduced_scene)
                err = float(np.abs(image.line_integral - full.line_integral).max())
                xray_viz.render(reduced_scene)                 # set-up of the reduced meshes

                def fresh(s):
                    return lambda: s.bodies.forget(("fast", "result"))

                # interleaved: full, reduced, full, reduced, ...
                t_full, t_red, t_call = [], [], []
                for _ in range(args.repeat):
                    for s, out in ((scene, t_full), (reduced_scene, t_red)):
                        out.append(_median_time(lambda s=s: xray_viz.render(s), 1,
                                                before=fresh(s)))
                    new = scene.replace(acquisition=scene.acquisition)
                    t_call.append(_median_time(
                        lambda new=new: xray_viz.render(
                            lod.level_of_detail(new, budget, **options)[0]), 1,
                        before=fresh(reduced_scene)))
                tf, tr, tc = (statistics.median(t) for t in (t_full, t_red, t_call))
                print(f"| {name} | {w} x {h} | {budget:g} | "
                      f"{'leftover spent' if spend else 'equal'} | {report.faces_full:,} | "
                      f"{report.faces:,} | {tf * 1e3:.1f} | {tr * 1e3:.1f} | {tr / tf:.2f} | "
                      f"{t_cold:.2f} | {t_disk * 1e3:.0f} | {t_mem * 1e3:.0f} | "
                      f"{tc * 1e3:.1f} | {err:.3g} | {report.estimated_error:.3g} |",
                      flush=True)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    print()
    print(f"load average at the end: {' '.join(f'{x:.1f}' for x in os.getloadavg())}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

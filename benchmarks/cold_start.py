"""Cold and warm start of ``xray-viz render``: whole-process wall and CPU time (issue 18).

Usage::

    python benchmarks/cold_start.py [-n RUNS] [--case NAME ...] [--python PYTHON]
                                    [--tree DIR ...]

Each run is a new ``xray-viz render SCENE -o <tmp>.png`` process. *Cold*: numba's cache is
empty (``NUMBA_CACHE_DIR`` pointed at a new temporary directory for that run, removed after
it), so every kernel the run uses is compiled, by the command's background processes. *Warm*:
one run fills a cache directory, then the counted runs load the kernels from it.

Three figures per run: ``image`` the wall seconds until the command exits (its image
written: what a user waits for); ``all`` the wall seconds until every background compile
process it started has ended too (every kernel variant of the engine is cached then, the
ones of other kinds of scene included; a worker left compiling those goes on alone, at a
lower priority, after the command exits); ``cpu`` the CPU seconds of the command and of every
process it started, detached ones included (this process is made their "subreaper" on Linux,
so that they are its children when their parent is gone, and their time is counted in
``RUSAGE_CHILDREN``). Prints min / median / max per case, tree and mode.

Cases: ``default`` (the frog, 16 bodies, 512 x 512), ``sphere`` (one body, 256 x 256),
``supersample2`` (the default scene with ``--supersample 2``) and ``parallel`` (the sphere in a
parallel beam, a scene file written to a temporary directory).

``--tree DIR`` (repeatable) runs with ``PYTHONPATH=DIR`` (another checkout of xray_viz, e.g.
a before-tree made with ``git worktree add``); with several trees the runs alternate
A B A B ... so that each tree sees the same load. ``--python`` runs another interpreter.
``XRAY_VIZ_CACHE_DIR=off`` is set for every run (no mesh-report disk cache).
"""

from __future__ import annotations

import argparse
import ctypes
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def _parallel_scene(tmp: Path) -> Path:
    from xray_viz import phantoms

    src = phantoms.scene_path("sphere")
    text = src.read_text().replace('kind = "point"', 'kind = "parallel"')
    text = text.replace('mesh = "sphere/', f'mesh = "{src.parent / "sphere"}/')
    path = tmp / "parallel_sphere.toml"
    path.write_text(text)
    return path


def _cases(tmp: Path) -> dict:
    return {"default": ["default"], "sphere": ["sphere"],
            "supersample2": ["default", "--supersample", "2"],
            "parallel": [str(_parallel_scene(tmp))]}


def _subreaper() -> bool:
    """Make this process the subreaper of its descendants (Linux ``PR_SET_CHILD_SUBREAPER``)."""
    try:
        return ctypes.CDLL(None, use_errno=True).prctl(36, 1, 0, 0, 0) == 0
    except (OSError, AttributeError):
        return False


def _reap_all() -> None:
    """Wait for every child left (detached workers re-parented to this process)."""
    while True:
        try:
            os.waitpid(-1, 0)
        except ChildProcessError:
            return


def _run(python: str, tree: str | None, args: list, cache: str, out: Path):
    env = dict(os.environ, NUMBA_CACHE_DIR=cache, XRAY_VIZ_CACHE_DIR="off")
    if tree:
        env["PYTHONPATH"] = tree
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    proc = subprocess.run([python, "-m", "xray_viz.cli", "render", *args, "-o", str(out)],
                          env=env, capture_output=True, text=True, cwd=tempfile.gettempdir())
    image = time.perf_counter() - t
    if proc.returncode:
        sys.exit(f"{' '.join(args)}: exit {proc.returncode}: {proc.stderr.strip()[-500:]}")
    _reap_all()
    every = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return image, every, cpu


def _stats(xs) -> str:
    return f"{min(xs):6.2f} {statistics.median(xs):6.2f} {max(xs):6.2f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=3, help="counted runs per case and mode (3)")
    ap.add_argument("--case", action="append", help="default, sphere, supersample2, parallel")
    ap.add_argument("--mode", action="append", choices=("cold", "warm"),
                    help="cold, warm (default both)")
    ap.add_argument("--python", default=sys.executable, help="interpreter to run xray-viz with")
    ap.add_argument("--tree", action="append",
                    help="PYTHONPATH of a run (repeat: runs alternate between the trees)")
    args = ap.parse_args(argv)
    if not _subreaper():
        print("note: not a subreaper (not Linux?): detached workers' CPU is not counted")
    trees = args.tree or [None]
    with tempfile.TemporaryDirectory(prefix="xray_viz-cold-") as tmp:
        tmp = Path(tmp)
        cases = _cases(tmp)
        print(f"{'case':13s} {'mode':5s} {'tree':24s} image wall s (min med max)  "
              f"all cached wall s       cpu s (all processes)")
        for name in args.case or list(cases):
            for mode in args.mode or ("cold", "warm"):
                res = {tree: ([], [], []) for tree in trees}
                warm = {tree: tempfile.mkdtemp(dir=tmp) for tree in trees}
                if mode == "warm":
                    for tree in trees:        # fills the cache
                        _run(args.python, tree, cases[name], warm[tree], tmp / "x.png")
                for _ in range(args.n):
                    for tree in trees:
                        cache = tempfile.mkdtemp(dir=tmp) if mode == "cold" else warm[tree]
                        for xs, x in zip(res[tree], _run(args.python, tree, cases[name], cache,
                                                         tmp / "x.png")):
                            xs.append(x)
                        if mode == "cold":
                            shutil.rmtree(cache)
                for tree in trees:
                    image, every, cpu = res[tree]
                    label = Path(tree).name if tree else "-"
                    print(f"{name:13s} {mode:5s} {label:24s} {_stats(image)}  {_stats(every)}"
                          f"  {_stats(cpu)}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

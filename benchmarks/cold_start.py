"""Cold and warm start of ``xray-viz render``: whole-process wall and CPU time (issue 18).

Usage::

    python benchmarks/cold_start.py [-n RUNS] [--case NAME ...] [--python PYTHON]

Each run is a new ``xray-viz render SCENE -o <tmp>.png`` process. *Cold*: numba's cache is
empty (``NUMBA_CACHE_DIR`` pointed at a new temporary directory for that run, removed after
it), so every kernel the run uses is compiled - by the command's background processes too, whose
CPU time is counted (``RUSAGE_CHILDREN``). *Warm*: one run fills a cache directory, then the
counted runs load the kernels from it. Prints min / median / max of wall and CPU seconds per
case. Cases: ``default`` (the frog, 16 bodies, 512 x 512), ``sphere`` (one body, 256 x 256),
``supersample2`` (the default scene with ``--supersample 2``) and ``parallel`` (the sphere in a
parallel beam, a scene file written to a temporary directory).

``--python`` runs another interpreter (another checkout's environment) for a before/after.
"""

from __future__ import annotations

import argparse
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


def _run(python: str, args: list, cache: str, out: Path) -> tuple[float, float]:
    env = dict(os.environ, NUMBA_CACHE_DIR=cache)
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    proc = subprocess.run([python, "-m", "xray_viz.cli", "render", *args, "-o", str(out)],
                          env=env, capture_output=True, text=True, cwd=tempfile.gettempdir())
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode:
        sys.exit(f"{' '.join(args)}: exit {proc.returncode}: {proc.stderr.strip()[-500:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def _stats(xs) -> str:
    return f"{min(xs):6.2f} {statistics.median(xs):6.2f} {max(xs):6.2f}"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=3, help="counted runs per case and mode (3)")
    ap.add_argument("--case", action="append", help="default, sphere, supersample2, parallel")
    ap.add_argument("--python", default=sys.executable, help="interpreter to run xray-viz with")
    args = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="xray_viz-cold-") as tmp:
        tmp = Path(tmp)
        cases = _cases(tmp)
        print(f"{'case':14s} {'mode':5s} wall s (min median max)   cpu s (min median max)")
        for name in args.case or list(cases):
            for mode in ("cold", "warm"):
                warm_dir = tempfile.mkdtemp(dir=tmp)
                if mode == "warm":
                    _run(args.python, cases[name], warm_dir, tmp / "x.png")   # fills the cache
                walls, cpus = [], []
                for _ in range(args.n):
                    cache = tempfile.mkdtemp(dir=tmp) if mode == "cold" else warm_dir
                    wall, cpu = _run(args.python, cases[name], cache, tmp / "x.png")
                    walls.append(wall)
                    cpus.append(cpu)
                    if mode == "cold":
                        shutil.rmtree(cache)
                print(f"{name:14s} {mode:5s} {_stats(walls)}     {_stats(cpus)}", flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

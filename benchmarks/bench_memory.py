"""Peak memory of a render, against pixels and bodies: each job in a fresh subprocess.

Every job is ``xray-viz render SCENE -o OUT.tiff --engine ENGINE`` (through
:func:`xray_viz.cli.main`, in a child process) on a scene file written for it:

* ``frog``: the bundled frog phantom (16 bodies, 173k faces) at a square detector of the same
  size in mm (the pitch scaled), so the frog fills the same part of the image at any shape;
* ``balls``: ``N`` small icospheres (80 faces each, one body each) on a square grid across the
  beam, at a detector of a given shape;
* ``baseline``: a 16 x 16 render of one ball: the interpreter, numpy, numba and the compiled
  kernels, without any image.

The child reports its peak resident set size (``VmHWM`` of ``/proc/self/status``, which is
``ru_maxrss``); a job is run ``--repeat`` times and the median is reported.

Usage::

    python benchmarks/bench_memory.py                       # the table of BENCHMARKS.md
    python benchmarks/bench_memory.py --job frog:2048:fast  # one job
    python benchmarks/bench_memory.py --python /work/main/.venv/bin/python --job frog:2048:fast

``--python`` runs the children with another interpreter (another checkout's virtual
environment, e.g. for before/after figures).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

#: The child: write the job's scene, run the CLI, print peak RSS (bytes) and seconds as JSON.
CHILD = r'''
import json, sys, time
spec = json.loads(sys.argv[1])
sys.path.insert(0, spec["here"])
from bench_memory import write_scene
from xray_viz.cli import main
scene = write_scene(spec["kind"], spec["shape"], spec["bodies"], spec["dir"])
t0 = time.perf_counter()
rc = main(["render", str(scene), "-o", str(scene.with_suffix(".tiff")), "--engine",
           spec["engine"]])
seconds = time.perf_counter() - t0
hwm = 0
for line in open("/proc/self/status"):
    if line.startswith("VmHWM:"):
        hwm = int(line.split()[1]) * 1024
print(json.dumps({"rc": rc, "peak": hwm, "seconds": seconds}))
'''


def write_scene(kind: str, shape: int, bodies: int, folder) -> Path:
    """Write the scene file of a job into ``folder`` and return its path."""
    import numpy as np
    import trimesh

    folder = Path(folder)
    if kind == "frog":
        import dataclasses

        import xray_viz

        scene = xray_viz.load_scene("frog")
        pitch = 0.274 * 511 / (shape - 1)
        scene = scene.replace(detector=dataclasses.replace(
            scene.detector, shape=(shape, shape), pitch=(pitch, pitch)))
        path = folder / f"frog_{shape}.toml"
        path.write_text(scene.to_toml())         # the frog's meshes by absolute path
        return path
    if kind in ("balls", "baseline"):
        ball = folder / "ball.stl"
        if not ball.exists():
            trimesh.creation.icosphere(subdivisions=1, radius=1.0).export(ball)
        k = int(np.ceil(np.sqrt(bodies)))
        spacing = 100.0 / k                               # a 100 mm field
        radius = 0.35 * spacing
        from xray_viz._toml import dumps

        doc = {"source": {"position": [0.0, 0.0, 1000.0], "energy": 60.0},
               "detector": {"center": [0.0, 0.0, -100.0], "up": [0.0, 1.0, 0.0],
                            "shape": [shape, shape], "size": [120.0, 120.0]},
               "body": [{"name": f"ball{b}", "mesh": ball.as_posix(), "mu": 0.2,
                         "position": [(b % k - (k - 1) / 2) * spacing,
                                      (b // k - (k - 1) / 2) * spacing, 0.0],
                         "scale": radius} for b in range(bodies)]}
        path = folder / f"{kind}_{bodies}_{shape}.toml"
        path.write_text(dumps(doc))
        return path
    raise ValueError(kind)


def run_job(kind, shape, bodies, engine, *, python=sys.executable, timeout=3600):
    """Run one job in a fresh child process: ``{"rc", "peak" (bytes), "seconds"}``."""
    with tempfile.TemporaryDirectory() as folder:
        spec = dict(kind=kind, shape=shape, bodies=bodies, engine=engine, dir=folder,
                    here=str(Path(__file__).resolve().parent))
        # cwd: not a checkout, whose xray_viz would shadow the interpreter's installed one.
        res = subprocess.run([python, "-c", CHILD, json.dumps(spec)], capture_output=True,
                             text=True, timeout=timeout, cwd=folder)
        if res.returncode != 0:
            raise RuntimeError(f"job {kind} {shape} {bodies} {engine} failed:\n{res.stderr}")
        return json.loads(res.stdout.strip().splitlines()[-1])


def median_job(kind, shape, bodies, engine, repeat, python):
    runs = [run_job(kind, shape, bodies, engine, python=python) for _ in range(repeat)]
    if any(r["rc"] != 0 for r in runs):
        return None
    return (statistics.median(r["peak"] for r in runs),
            statistics.median(r["seconds"] for r in runs))


def machine() -> str:
    cpu = "?"
    try:
        for line in open("/proc/cpuinfo"):
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
        mem = next(int(l.split()[1]) for l in open("/proc/meminfo") if l.startswith("MemTotal"))
        mem = f"{mem / 2**20:.0f} GiB"
    except (OSError, StopIteration):
        mem = "?"
    return f"{os.cpu_count()} cores ({cpu}), {mem}, Python {platform.python_version()}"


def _mib(b):
    return f"{b / 2**20:,.0f}"


def parse_job(text):
    kind, shape, *rest = text.split(":")
    if kind == "frog":
        return "frog", int(shape), 16, rest[0] if rest else "fast"
    return kind, int(shape), int(rest[0]), rest[1] if len(rest) > 1 else "fast"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--python", default=sys.executable,
                   help="interpreter of the children (another checkout's .venv/bin/python)")
    p.add_argument("--job", action="append", default=[],
                   help="frog:SHAPE[:ENGINE] or balls:SHAPE:BODIES[:ENGINE]; repeatable")
    p.add_argument("--numpy-max", type=int, default=1024,
                   help="largest shape run with the NumPy engine in the default table")
    args = p.parse_args(argv)
    jobs = [parse_job(j) for j in args.job]
    if not jobs:
        for engine in ("fast", "numpy"):
            for s in (256, 512, 1024, 2048, 4096, 8192):
                if engine == "fast" or s <= args.numpy_max:
                    jobs.append(("frog", s, 16, engine))
            for nb in (1, 10, 100, 1000):
                jobs.append(("balls", 512, nb, engine))
            jobs.append(("balls", 1024, 1000, engine))
    print(f"machine: {machine()}; children: {args.python}; median of {args.repeat}")
    base = median_job("baseline", 16, 1, "fast", args.repeat, args.python)
    print(f"baseline (16 x 16, one ball): {_mib(base[0])} MiB\n")
    print("| job | bodies | pixels | engine | peak RSS (MiB) | above baseline, bytes per pixel "
          "| seconds |")
    print("| --- | ---: | ---: | --- | ---: | ---: | ---: |")
    from xray_viz import progress

    progress.configure(enabled=sys.stderr.isatty())
    for kind, shape, nb, engine in progress.iterate(jobs, "memory jobs", unit="jobs"):
        r = median_job(kind, shape, nb, engine, args.repeat, args.python)
        if r is None:
            progress.echo(f"| {kind} | {nb} | {shape}^2 | {engine} | failed | | |")
            continue
        peak, seconds = r
        per = (peak - base[0]) / shape ** 2
        progress.echo(f"| {kind} | {nb} | {shape}^2 | {engine} | {_mib(peak)} | {per:.0f} | "
                      f"{seconds:.1f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())

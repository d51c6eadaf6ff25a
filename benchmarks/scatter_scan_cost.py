"""The cost of a CT scan with the scatter kernel model against its primary scan (issue 39:
"with the kernel model a 360-view scan costs at most twice its primary scan").

The scene (default ``--scene cylinder``): a water cylinder of 20 cm diameter (300 mm long, a
256-sided mesh) on the rotation axis (y), a point source 600 mm from the axis, a flat detector
400 mm behind it (SID 1000 mm) of ``--shape`` pixels (default 384 x 256) of ``--pitch`` mm
(default 1.0: 384 x 256 mm at the detector, the whole cylinder in the field), 60 keV
monochromatic (``--kvp`` for a SpekPy spectrum with 2.5 mm Al instead), noise-free. Or a
bundled phantom by name (``--scene frog``), at its own detector, orbiting about its
detector's up axis (:func:`xray_viz.scan.default_orbit`).

Measured in one process, after a warm-up scan of each kind (the compiled kernels loaded):
``xray_viz.scan(scene, orbit)`` (line integrals) and ``xray_viz.scan(scene, orbit,
scatter="kernel")`` of the same ``--views`` views (default 360) in turn, primary then kernel,
``--repeats`` times (default 5); printed: each one's median wall time and CPU time of the
process (``time.process_time``: all its threads; steadier than the wall time on a machine
other jobs load), the medians of the pair-by-pair ratios kernel / primary, and the CPU time
the kernel model's ``scatter`` took inside the kernel scans (its calls counted and timed
through a wrapper; the rest of the difference is the path lengths weighted by material the
tracer sums for the model and the detector adding the scatter). Run it with
``NUMBA_NUM_THREADS=1`` for the cost per core, as a Dask worker scans (one numba thread a
task).

Usage: PYTHONPATH=$PWD .venv/bin/python benchmarks/scatter_scan_cost.py [--views 360]
       [--repeats 5] [--shape 384 256] [--pitch 1.0] [--kvp 80] [--scene cylinder]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import numpy as np
import trimesh

import xray_viz
from xray_viz.orbit import Orbit
from xray_viz.scene import Body, Detector, Scene, Source

RADIUS = 100.0


def cylinder_scene(shape=(384, 256), pitch=1.0, kvp=None) -> Scene:
    """The 20 cm water cylinder along y, the source on +z, the detector on -z."""
    cyl = trimesh.creation.cylinder(radius=RADIUS, height=300.0, sections=256)
    cyl.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    if kvp is None:
        source = Source(position=[0, 0, 600], energy=60.0)
    else:
        from xray_viz.physics.spectra import tube_spectrum

        source = Source(position=[0, 0, 600],
                        spectrum=tube_spectrum(float(kvp), filters={"Al": 2.5}))
    return Scene(source=source,
                 detector=Detector(center=[0, 0, -400], shape=tuple(shape),
                                   pitch=(pitch, pitch)),
                 bodies=(Body(name="water", mesh=cyl, material="Water, Liquid"),))


class _Timed:
    """Wraps ``KernelModel.scatter``: counts and times its calls."""

    def __init__(self):
        from xray_viz.scatter_kernel import KernelModel

        self.cls, self.original = KernelModel, KernelModel.scatter
        self.calls, self.seconds = 0, 0.0

    def __enter__(self):
        original = self.original

        def scatter(model, *args, **kwargs):
            t0 = time.process_time()
            try:
                return original(model, *args, **kwargs)
            finally:
                self.seconds += time.process_time() - t0
                self.calls += 1

        self.cls.scatter = scatter
        return self

    def __exit__(self, *exc):
        self.cls.scatter = self.original


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=360)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--shape", type=int, nargs=2, default=(384, 256), metavar=("W", "H"))
    parser.add_argument("--pitch", type=float, default=1.0)
    parser.add_argument("--kvp", type=float, default=None)
    parser.add_argument("--scene", default="cylinder")
    args = parser.parse_args(argv)

    if args.scene == "cylinder":
        scene = cylinder_scene(args.shape, args.pitch, args.kvp)
        orbit = Orbit(projections=args.views, axis=[0, 1, 0])
    else:
        from xray_viz.scan import default_orbit

        scene = xray_viz.load_scene(args.scene)
        orbit = default_orbit(scene, projections=args.views)
    w, h = scene.detector.shape
    warm = Orbit(projections=4, axis=orbit.axis, center=orbit.center)
    xray_viz.scan(scene, warm)
    xray_viz.scan(scene, warm, scatter="kernel")

    primary, kernel, ratios, model_s, calls = [], [], [], [], []
    cpu_p, cpu_k, cpu_ratios = [], [], []
    for _ in range(args.repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        p = xray_viz.scan(scene, orbit)
        t1, c1 = time.perf_counter(), time.process_time()
        with _Timed() as timed:
            s = xray_viz.scan(scene, orbit, scatter="kernel")
        t2, c2 = time.perf_counter(), time.process_time()
        primary.append(t1 - t0)
        kernel.append(t2 - t1)
        ratios.append((t2 - t1) / (t1 - t0))
        cpu_p.append(c1 - c0)
        cpu_k.append(c2 - c1)
        cpu_ratios.append((c2 - c1) / (c1 - c0))
        model_s.append(timed.seconds)
        calls.append(timed.calls)
    spr = np.exp(p.projections[:, h // 2, w // 2] - s.projections[:, h // 2, w // 2]) - 1.0
    assert np.all(s.projections <= p.projections + 1e-6)      # scatter lowers every li

    med = statistics.median
    beam = (f"{args.kvp:g} kVp" if args.kvp else
            "its own source" if args.scene != "cylinder" else f"{scene.source.energy:g} keV")
    print(f"scene {args.scene}: {w} x {h} pixels, {args.views} views, {beam}; "
          f"{args.repeats} repeats; python {platform.python_version()}, numpy "
          f"{np.__version__}, nproc {os.cpu_count()}, NUMBA_NUM_THREADS "
          f"{os.environ.get('NUMBA_NUM_THREADS', 'default')}, load (1 min) at the end "
          f"{os.getloadavg()[0]:.1f}")
    print(f"SPR at the detector centre (median over views): {med(spr):.3f}")
    print("primary scan   (s): " + " ".join(f"{t:.2f}" for t in primary)
          + f"  median {med(primary):.2f} ({1e3 * med(primary) / args.views:.2f} ms/view)")
    print("kernel scan    (s): " + " ".join(f"{t:.2f}" for t in kernel)
          + f"  median {med(kernel):.2f} ({1e3 * med(kernel) / args.views:.2f} ms/view)")
    print("primary scan CPU (s): " + " ".join(f"{t:.2f}" for t in cpu_p)
          + f"  median {med(cpu_p):.2f} ({1e3 * med(cpu_p) / args.views:.2f} ms/view)")
    print("kernel scan  CPU (s): " + " ".join(f"{t:.2f}" for t in cpu_k)
          + f"  median {med(cpu_k):.2f} ({1e3 * med(cpu_k) / args.views:.2f} ms/view)")
    print("  of which KernelModel.scatter, CPU (s): " + " ".join(f"{t:.2f}" for t in model_s)
          + f"  median {med(model_s):.2f} ({1e3 * med(model_s) / max(1, calls[0]):.2f} "
          f"ms/call, {calls[0]} calls)")
    print("ratio kernel / primary, wall (pair by pair): "
          + " ".join(f"{r:.2f}" for r in ratios) + f"  median {med(ratios):.2f}")
    print("ratio kernel / primary, CPU  (pair by pair): "
          + " ".join(f"{r:.2f}" for r in cpu_ratios) + f"  median {med(cpu_ratios):.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

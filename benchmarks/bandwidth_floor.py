"""The physical floor of a frame: bytes a trace must read, over this machine's memory bandwidth.

Usage::

    python benchmarks/bandwidth_floor.py [-n RUNS]

Bandwidth: ``np.copyto`` of a 512 MiB float64 array (read + write counted, 1 GiB moved per
copy), the median of RUNS copies, one thread (NumPy's copy is single threaded) - what one core
streams. The floor of a one-body frame at 512 x 512 is reading the vertices (24 bytes each) and
faces (12 bytes each, int32) once and writing the path lengths (8 bytes a ray); it is set
beside the measured per-frame trace (a new Scene, the source moved, medians) of icospheres of
82k and 1.3M faces (the peers suite's meshes), both engine threads.

The floor of a whole frame (``xray_viz.render``: trace and image) adds what the image step
must move at least: read the path lengths again (8 bytes a ray) and write the three images
a :class:`~xray_viz.render.Radiograph` returns (intensity, line integral, total path length:
24 bytes a pixel); it is set beside the measured render() per frame (``scene.replace(source=
...)``, medians; wall and CPU).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time

import numpy as np


def bandwidth(runs: int) -> float:
    """Bytes per second moved by a large NumPy copy (read + write)."""
    a = np.ones(64 << 20)               # 512 MiB
    b = np.empty_like(a)
    np.copyto(b, a)
    ts = []
    for _ in range(runs):
        t = time.perf_counter()
        np.copyto(b, a)
        ts.append(time.perf_counter() - t)
    return 2 * a.nbytes / statistics.median(ts)


def main(argv=None) -> int:
    import trimesh

    import xray_viz
    from xray_viz.tracing import fast

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=9)
    args = ap.parse_args(argv)
    bw = bandwidth(args.n)
    print(f"memory bandwidth (NumPy copy, 1 thread): {bw / 1e9:.2f} GB/s")
    base = xray_viz.load_scene("sphere")
    det = dataclasses.replace(base.detector, shape=(512, 512),
                              pitch=tuple(p / 2 for p in base.detector.pitch))
    print(f"{'faces':>9s} {'MB read':>8s} {'floor ms':>9s} {'trace ms':>9s} "
          f"{'CPU ms':>7s} {'x floor':>8s} | {'MB frame':>8s} {'floor ms':>9s} "
          f"{'render ms':>9s} {'CPU ms':>7s} {'x floor':>8s}")
    for sub in (6, 8):
        m = trimesh.creation.icosphere(subdivisions=sub, radius=40.0)
        scene = base.replace(detector=det,
                             bodies=[dataclasses.replace(base.bodies[0], name="ball", mesh=m)])
        nbytes = len(m.vertices) * 24 + len(m.faces) * 12 + 512 * 512 * 8
        floor = nbytes / bw
        fast.trace_once(scene)
        ts, cs = [], []
        for i in range(args.n):
            src = dataclasses.replace(scene.source, position=np.asarray(scene.source.position)
                                      + np.array([1e-3 * (i + 1), 0.0, 0.0]))
            s = scene.replace(source=src)
            t, c = time.perf_counter(), time.process_time()
            fast.trace_once(s)
            ts.append(time.perf_counter() - t)
            cs.append(time.process_time() - c)
        t, c = statistics.median(ts), statistics.median(cs)
        fbytes = nbytes + 512 * 512 * (8 + 24)
        ffloor = fbytes / bw
        rs, rc = [], []
        for i in range(args.n):
            src = dataclasses.replace(scene.source, position=np.asarray(scene.source.position)
                                      + np.array([0.0, 1e-3 * (i + 1), 0.0]))
            s = scene.replace(source=src)
            t0, c0 = time.perf_counter(), time.process_time()
            image = xray_viz.render(s)
            rs.append(time.perf_counter() - t0)
            rc.append(time.process_time() - c0)
            del image
        r, q = statistics.median(rs), statistics.median(rc)
        print(f"{len(m.faces):9d} {nbytes / 1e6:8.1f} {floor * 1e3:9.2f} {t * 1e3:9.2f} "
              f"{c * 1e3:7.2f} {t / floor:7.1f}x | {fbytes / 1e6:8.1f} {ffloor * 1e3:9.2f} "
              f"{r * 1e3:9.2f} {q * 1e3:7.2f} {r / ffloor:7.1f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())

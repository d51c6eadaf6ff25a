"""Per-frame trace of the frog (16 bodies) against one body of the same face count (issue 18).

Usage::

    python benchmarks/multi_body.py [-n RUNS]

Both at 512 x 512 with the frog's source and detector; the one body is a UV sphere of radius
50 mm (about the frog's footprint) with as many faces as the frog's 16 meshes together. Each
frame is a new ``Scene`` with the source moved 1 um (nothing but the per-mesh set-up reused),
traced with the fast engine; frames alternate frog, sphere, frog, ... so that both see the same
load. Prints the median per-frame milliseconds (wall, and CPU of all threads: steadier on a
shared machine) and their ratios. ``--threads`` sets numba's thread count (the engine's).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time

import numpy as np


def main(argv=None) -> int:
    import trimesh

    import xray_viz
    from xray_viz.scene import Body
    from xray_viz.tracing import fast

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=21)
    ap.add_argument("--threads", type=int)
    args = ap.parse_args(argv)
    if args.threads:
        import numba

        numba.set_num_threads(args.threads)
    frog = xray_viz.load_scene("frog")
    faces = sum(len(b.faces) for b in frog.bodies)
    k = int(round(np.sqrt(faces / 4)))      # a UV sphere of count [k, k] has ~4 k^2 faces
    ball = trimesh.creation.uv_sphere(radius=50.0, count=[k, k])
    b0 = frog.bodies[0]
    one = frog.replace(bodies=[Body(name="sphere", mesh=ball, material=b0.material)])
    scenes = {"frog": frog, "one body": one}
    times = {name: [] for name in scenes}
    cpu = {name: [] for name in scenes}
    for i in range(args.n + 1):
        for name, scene in scenes.items():
            src = scene.source
            moved = dataclasses.replace(src, position=np.asarray(src.position, float)
                                        + np.array([1e-3 * i, 0.0, 0.0]))
            s = scene.replace(source=moved)
            t, c = time.perf_counter(), time.process_time()
            fast.trace_once(s)
            if i:
                times[name].append(time.perf_counter() - t)
                cpu[name].append(time.process_time() - c)
    med = {k: statistics.median(v) * 1e3 for k, v in times.items()}
    med_cpu = {k: statistics.median(v) * 1e3 for k, v in cpu.items()}
    print(f"frog: {len(frog.bodies)} bodies, {faces} faces; one body: {len(ball.faces)} faces; "
          f"512 x 512, medians of {args.n} frames")
    for name, ms in med.items():
        print(f"  {name:9s} {ms:8.2f} ms wall, {med_cpu[name]:8.2f} ms CPU per frame")
    print(f"  ratio frog / one body: {med['frog'] / med['one body']:.2f}x wall, "
          f"{med_cpu['frog'] / med_cpu['one body']:.2f}x CPU")
    return 0


if __name__ == "__main__":
    sys.exit(main())

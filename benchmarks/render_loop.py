"""A render loop: ``xray_viz.render`` of one scene with the source moved 1 um a frame (issue 18).

Usage::

    python benchmarks/render_loop.py [SCENE] [-n FRAMES]

What an interactive session or a scripted series of frames pays per frame through the public
API: a new ``Scene`` (``scene.replace(source=...)``), the trace through the fast engine's
result cache and the image step. Prints the median wall milliseconds per frame (the first two
frames, which load kernels and build the per-mesh set-up, are left out). Compare trees by
running it with ``PYTHONPATH=<tree>`` in turn.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time

import numpy as np


def main(argv=None) -> int:
    import xray_viz

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default="frog")
    ap.add_argument("-n", type=int, default=21, help="frames measured (default 21)")
    args = ap.parse_args(argv)
    scene = xray_viz.load_scene(args.scene)
    times = []
    for i in range(args.n + 2):
        src = scene.source
        s = scene.replace(source=dataclasses.replace(
            src, position=np.asarray(src.position, float) + np.array([1e-3 * i, 0.0, 0.0])))
        t = time.perf_counter()
        image = xray_viz.render(s)
        times.append(time.perf_counter() - t)
        del image
    w, h = scene.detector.shape
    print(f"{args.scene}: {len(scene.bodies)} bodies, {w} x {h}; render() per frame "
          f"{statistics.median(times[2:]) * 1e3:.2f} ms (median of {args.n})")
    return 0


if __name__ == "__main__":
    sys.exit(main())

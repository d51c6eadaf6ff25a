"""Interactive preview target: 256 x 256 of an 82k-face sphere re-rendered after the first call.

Usage: python benchmarks/interactive.py [--repeat N]

Prints the median time of ``xray_viz.render`` (trace + image) when
  * only the material changes (the trace is reused from the cache), and
  * the source moves every frame (a full re-trace; set-up cached per mesh).
"""
import argparse
import dataclasses
import time

import numpy as np
import trimesh

import xray_viz
from xray_viz.scene import Body, Detector, Scene, Source


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeat", type=int, default=21)
    args = parser.parse_args()
    mesh = trimesh.creation.icosphere(subdivisions=6, radius=40.0)
    scene = Scene(source=Source(position=[0.0, 0.0, 1000.0]),
                  detector=Detector(center=[0.0, 0.0, -500.0], shape=(256, 256),
                                    pitch=150 / 255),
                  bodies=(Body(name="ball", mesh=mesh, mu=0.2),))
    t0 = time.perf_counter()
    xray_viz.render(scene)
    first = time.perf_counter() - t0
    same, moved = [], []
    for k in range(args.repeat):
        body = dataclasses.replace(scene.bodies[0], mu=0.1 + 0.01 * k)
        t0 = time.perf_counter()
        xray_viz.render(scene.replace(bodies=(body,)))
        same.append(time.perf_counter() - t0)
        src = dataclasses.replace(scene.source, position=[5.0 * np.sin(k), 5.0 * np.cos(k), 1000])
        t0 = time.perf_counter()
        xray_viz.render(scene.replace(source=src))
        moved.append(time.perf_counter() - t0)
    print(f"82k faces, 256x256: first render {first * 1e3:.0f} ms (includes numba cache load "
          f"or compile); material change {np.median(same) * 1e3:.2f} ms; "
          f"source moved (re-trace) {np.median(moved) * 1e3:.2f} ms (median of {args.repeat})")


if __name__ == "__main__":
    main()

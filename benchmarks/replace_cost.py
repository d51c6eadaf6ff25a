"""What a new acquisition of the same bodies costs, against a render of the same scene.

For each phantom: the median time of ``scene.replace(source=...)`` (the source moved), of
``scene.replace(acquisition=scene.acquisition.rotated(...))`` (what the viewer's rotation
slider and a CT orbit do: the source and the detector turned about the bodies), and of
``xray_viz.render`` of the moved scene (the fast engine's kept results bypassed by moving the
source a little every time). Nothing is cached in modules: the per-mesh set-up lives on the
scene's :class:`xray_viz.bodies.Bodies`, which the new scenes share.

Usage::

    python benchmarks/replace_cost.py [--repeat 21] [--phantoms frog sphere ...]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import numpy as np

import xray_viz


def _median(fn, repeat):
    times = []
    for k in range(repeat):
        t0 = time.perf_counter()
        fn(k)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--repeat", type=int, default=21)
    p.add_argument("--phantoms", nargs="+", default=["sphere", "nested_spheres", "frog",
                                                     "shepp_logan"])
    args = p.parse_args(argv)
    print("| phantom | bodies | faces | replace(source) ms | rotated acquisition ms | "
          "render ms | replace / render | rotated / render |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name in args.phantoms:
        scene = xray_viz.load_scene(name)
        xray_viz.render(scene)                               # compile, per-mesh set-up
        src = scene.source

        def moved(k):
            return scene.replace(source=dataclasses.replace(
                src, position=src.position + np.array([0.0, 0.0, 1e-3 * (k + 1)])))

        centre = scene.bodies.bounds.mean(axis=(0, 1))

        def rotated(k):
            return scene.replace(acquisition=scene.acquisition.rotated(
                1.0 + k, axis=scene.detector.up, center=centre))

        t_replace = _median(moved, args.repeat)
        t_rotate = _median(rotated, args.repeat)
        t_render = _median(lambda k: xray_viz.render(rotated(k)), args.repeat)
        faces = sum(len(b.faces) for b in scene.bodies)
        print(f"| {name} | {len(scene.bodies)} | {faces:,} | {1e3 * t_replace:.3f} | "
              f"{1e3 * t_rotate:.3f} | {1e3 * t_render:.1f} | {100 * t_replace / t_render:.2f} % "
              f"| {100 * t_rotate / t_render:.2f} % |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

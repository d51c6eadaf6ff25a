"""Render and scan of the frog, medians of wall and CPU time: the pipeline as values (issue 37).

Usage (one tree after the other, in turns, on the same machine)::

    PYTHONPATH=/path/to/old/tree python benchmarks/stages_cost.py old
    PYTHONPATH=$PWD python benchmarks/stages_cost.py new

A render builds a ``Projector``, a ``Beam`` and a ``DetectorModel`` once (the spectrum and the
attenuation derived once per render); a scan builds them once for all of its projections and
no scene per projection. CPU time (``time.process_time``, every thread) is the steadier
figure on a shared machine.
"""

from __future__ import annotations

import dataclasses
import statistics
import sys
import time

import xray_viz
from xray_viz.orbit import Orbit


def _median(f, n):
    f()
    wall, cpu = [], []
    for _ in range(n):
        t, p = time.perf_counter(), time.process_time()
        f()
        wall.append(time.perf_counter() - t)
        cpu.append(time.process_time() - p)
    return statistics.median(wall) * 1e3, statistics.median(cpu) * 1e3


def main(label: str = "") -> None:
    scene = xray_viz.load_scene("frog")
    det = scene.detector
    small = scene.replace(detector=dataclasses.replace(det, shape=(128, 128),
                                                       pitch=(det.pitch[0] * 4, det.pitch[1] * 4)))
    spec = scene.replace(
        source=dataclasses.replace(scene.source, spectrum={"kvp": 80.0, "filters": {"Al": 2.0}}),
        detector=dataclasses.replace(det, noise=True, seed=1, i0=1e4))
    orbit = Orbit(projections=16, axis=[0, 1, 0])
    cases = [("render frog 512x512 mono", lambda: xray_viz.render(scene), 21),
             ("render frog 512x512 80kVp+noise", lambda: xray_viz.render(spec), 9),
             ("render frog 128x128 mono (kept trace)", lambda: xray_viz.render(small), 201),
             ("scan frog 16 x 128x128 mono", lambda: xray_viz.scan(small, orbit), 7)]
    for name, f, n in cases:
        wall, cpu = _median(f, n)
        print(f"{label:5s} {name:40s} wall {wall:9.3f} ms  cpu {cpu:9.3f} ms", flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:2])

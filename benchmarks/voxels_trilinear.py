"""Render time of the chest phantom (a real CT, 170 x 152 x 133 voxels, 512 x 512 DRR) with
its voxels traced as exact voxels and with trilinear interpolation (integrated exactly).

``PYTHONPATH=. python benchmarks/voxels_trilinear.py [--repeat N]``: medians of N warm renders.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

import numpy as np

import xray_viz


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args(argv)
    scene = xray_viz.load_scene(Path(__file__).resolve().parents[1] / "phantoms" / "chest.toml")
    for mode in ("nearest", "trilinear"):
        vol = dataclasses.replace(scene.volumes[0], interpolation=mode)
        s = scene.replace(volumes=(vol,))
        xray_viz.render(s)  # warm: kernels compiled or loaded, the grid's copy made
        runs = []
        for _ in range(args.repeat):
            t = time.perf_counter()
            xray_viz.render(s)
            runs.append(time.perf_counter() - t)
        print(f"{mode:10s} median {np.median(runs):.2f} s  runs "
              + ", ".join(f"{r:.2f}" for r in runs))


if __name__ == "__main__":
    main()

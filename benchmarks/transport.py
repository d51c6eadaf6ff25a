"""Photon transport speed: histories per second per core on AAPM TG-195 case 2 (56.4 keV,
air around the slab and its nine VOIs) and on the frog phantom (16 bodies, 173,500
triangles), and the wall time of a long case-2 run.

Run from the repository root::

    python benchmarks/transport.py [--histories N] [--long N]

Per core: the CPU seconds of one thread over the histories of whole groups (so a machine
shared with other jobs still measures the code, not the load); the wall time of ``--long``
histories on every core numba may use (the issue's "must": 1e7 of case 2 in < 60 s on 2
cores). Medians of three runs; the first call compiles or loads the kernels and is not timed.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "_support"))
sys.path.insert(0, str(Path(__file__).resolve().parent))


def per_core(scene, histories: int, repeats: int = 3) -> float:
    """Histories per CPU second of one thread (median of ``repeats``)."""
    from xray_viz.transport import prepare
    from xray_viz.montecarlo.tallies import run_group

    p = prepare(scene, histories, seed=1, batch=max(1, histories // 16))
    run_group(p, 0, threads=1)                       # compile / load the kernels
    rates = []
    for _ in range(repeats):
        c0 = time.thread_time()
        run_group(p, 0, threads=1)
        rates.append(histories / (time.thread_time() - c0))
    return statistics.median(rates)


def ct_scene():
    """The synthetic chest CT of ``benchmarks/voxels.py`` as a voxel volume (the Schneider
    classes, a density per voxel) with its titanium pedicle screw, 100 kVp, a 64 x 64
    detector over the chest (the same field as the 512 x 512 DRR)."""
    import tempfile

    import xray_viz
    from voxels import synthetic_ct, write_scene

    hu, affine = synthetic_ct()
    folder = Path(tempfile.mkdtemp(prefix="xray_viz_ct_"))
    return xray_viz.load_scene(write_scene(folder, hu, affine, 64))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--histories", type=int, default=200_000)
    ap.add_argument("--ct", action="store_true",
                    help="also the synthetic 512 x 512 x 133 chest CT of benchmarks/voxels.py "
                         "traced as voxels, with its titanium screw (Woodcock tracking)")
    ap.add_argument("--long", type=int, default=0, metavar="N",
                    help="also time N histories of case 2 on every core (wall clock)")
    args = ap.parse_args()
    import xray_viz
    from tg195 import case2_scene

    print(f"machine: {os.cpu_count()} CPUs, load average {os.getloadavg()[0]:.1f}")
    case2 = case2_scene("56.4 keV")
    print(f"TG-195 case 2, 56.4 keV: {per_core(case2, args.histories):,.0f} histories/s per core")
    case2_120 = case2_scene("120 kVp")
    print(f"TG-195 case 2, 120 kVp: {per_core(case2_120, args.histories):,.0f} histories/s "
          "per core")
    frog = xray_viz.load_scene("frog")
    print(f"frog (16 bodies, {len(frog.triangles):,} triangles, 60 keV, vacuum): "
          f"{per_core(frog, args.histories // 4):,.0f} histories/s per core")
    if args.ct:
        print(f"chest CT 512 x 512 x 133 voxels + a Ti screw, 100 kVp: "
              f"{per_core(ct_scene(), args.histories // 4):,.0f} histories/s per core")
    if args.long:
        xray_viz.transport(case2, 1000, seed=2)          # kernels loaded
        t0, c0 = time.perf_counter(), time.process_time()
        xray_viz.transport(case2, args.long, seed=2)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
        print(f"case 2, {args.long:.3g} histories: {wall:.1f} s wall, {cpu:.1f} s CPU "
              f"({args.long / wall:,.0f} histories/s)")


if __name__ == "__main__":
    main()

"""Time a polychromatic render against the same spectrum done as monochromatic renders.

A render traces the geometry once (path lengths per ray and body), then turns path lengths into
intensities; a spectrum adds one (rays x bodies) @ (bodies x bins) matrix product and an exp
over (rays x bins) per chunk of rays. Two settings are timed, each as the median of
``--repeat`` runs:

* **cold**: :func:`xray_viz.tracing.fast.clear_caches` before *every* render, so each render
  pays the per-mesh set-up and the trace; the 150 monochromatic renders are 150 such cold
  renders, all of them timed (not one render x 150), unless ``--mono-renders`` says fewer;
* **warm**: the caches kept, so the path lengths of the first render are reused (the trace
  costs ~0 s) and only the attenuation step is timed.

In both, numba is compiled and the attenuation tables (xraylib mu(E), cached per energy grid)
are filled before timing. Run::

    python benchmarks/bench_spectrum.py [--bins 150] [--phantom sphere] [--repeat 5]
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import time

import numpy as np

import xray_viz
from xray_viz.physics.spectra import Spectrum
from xray_viz.tracing.fast import clear_caches


def _timed(render, scene, *, cold: bool):
    if cold:
        clear_caches(scene)
    t = time.perf_counter()
    image = render(scene)
    return time.perf_counter() - t, image.timing


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bins", type=int, default=150)
    parser.add_argument("--phantom", default="sphere")
    parser.add_argument("--repeat", type=int, default=5, help="runs per figure (median)")
    parser.add_argument("--mono-renders", type=int, default=None,
                        help="monochromatic renders actually timed per run (default: all bins; "
                             "fewer are extrapolated to all bins)")
    args = parser.parse_args(argv)

    base = xray_viz.load_scene(args.phantom)
    energies = np.linspace(10.0, 150.0, args.bins)
    spectrum = Spectrum(energies, np.exp(-((energies - 60.0) / 30.0) ** 2))
    bodies = tuple(dataclasses.replace(b, mu=None, material="Water, Liquid")
                   for b in base.bodies)
    poly = base.replace(bodies=bodies,
                        source=dataclasses.replace(base.source, energy=None, spectrum=spectrum))
    monos = [base.replace(bodies=bodies, source=dataclasses.replace(
        base.source, energy=float(e), spectrum=None)) for e in energies]
    n_mono = min(args.mono_renders or args.bins, args.bins)
    w, h = base.detector.shape
    print(f"phantom {args.phantom!r}: {w} x {h} pixels, {len(base.triangles)} triangles, "
          f"material 'Water, Liquid'; {args.bins}-bin spectrum 10-150 keV; "
          f"median of {args.repeat} runs")

    render = xray_viz.render
    render(poly)                       # compile numba, fill the mu tables of the spectrum ...
    for scene in monos:                # ... and of every monochromatic energy
        render(scene)

    rows = {}
    import sys

    from xray_viz import progress

    progress.configure(enabled=sys.stderr.isatty())
    for mode in progress.iterate(("cold", "warm"), "spectrum renders", unit="modes"):
        cold = mode == "cold"
        if not cold:
            render(poly)               # the path lengths are cached from here on
        poly_runs = [_timed(render, poly, cold=cold) for _ in range(args.repeat)]
        one_runs = [_timed(render, monos[len(monos) // 2], cold=cold)[0]
                    for _ in range(args.repeat)]
        mono_runs = []
        for _ in range(args.repeat):
            total = sum(_timed(render, scene, cold=cold)[0] for scene in monos[:n_mono])
            mono_runs.append(total * args.bins / n_mono)
        rows[mode] = {
            "poly": statistics.median(t for t, _ in poly_runs),
            "trace": statistics.median(tm["trace"] for _, tm in poly_runs),
            "image": statistics.median(tm["image"] for _, tm in poly_runs),
            "one": statistics.median(one_runs),
            "mono": statistics.median(mono_runs),
        }

    what = ("all measured" if n_mono == args.bins
            else f"{n_mono} measured, scaled to {args.bins}")
    print()
    print(f"| caches | {args.bins}-bin spectrum, 1 render (s) | of which trace / attenuation (s) "
          f"| 1 mono render (s) | {args.bins} mono renders (s) | speed-up "
          f"| spectrum / 1 mono |")
    print("|---|---|---|---|---|---|---|")
    for mode, r in rows.items():
        print(f"| {mode} | {r['poly']:.4f} | {r['trace']:.4f} / {r['image']:.4f} | "
              f"{r['one']:.4f} | {r['mono']:.3f} | {r['mono'] / r['poly']:.1f} x | "
              f"{r['poly'] / r['one']:.2f} x |")
    print(f"\n{args.bins} mono renders: {what}; cold = clear_caches(scene) before every render.")
    return rows


if __name__ == "__main__":
    main()

"""Time a polychromatic render against the same spectrum done as monochromatic renders.

The geometry is traced once per render; a spectrum adds one (rays x bodies) @ (bodies x bins)
matrix product and an exp over (rays x bins). Run::

    python benchmarks/bench_spectrum.py [--bins 150] [--phantom sphere]
"""

from __future__ import annotations

import argparse
import dataclasses
import time

import numpy as np

import xray_viz
from xray_viz.physics.spectra import Spectrum


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--bins", type=int, default=150)
    parser.add_argument("--phantom", default="sphere")
    parser.add_argument("--mono-renders", type=int, default=None,
                        help="monochromatic renders actually timed (default: all bins)")
    args = parser.parse_args(argv)

    base = xray_viz.load_scene(args.phantom)
    energies = np.linspace(10.0, 150.0, args.bins)
    spectrum = Spectrum(energies, np.exp(-((energies - 60.0) / 30.0) ** 2))
    bodies = tuple(dataclasses.replace(b, mu=None, material="Water, Liquid")
                   for b in base.bodies)
    poly = base.replace(bodies=bodies,
                        source=dataclasses.replace(base.source, energy=None, spectrum=spectrum))
    w, h = base.detector.shape
    print(f"phantom {args.phantom!r}: {w} x {h} pixels, {len(base.triangles)} triangles, "
          f"material 'Water, Liquid'")
    xray_viz.render(poly)  # warm the caches (mu tables)

    t = time.perf_counter()
    image = xray_viz.render(poly)
    t_poly = time.perf_counter() - t
    print(f"{args.bins}-bin spectrum, one render : {t_poly:8.3f} s "
          f"(trace {image.timing['trace']:.3f} s, spectrum {image.timing['image']:.3f} s)")

    mono_scene = lambda e: base.replace(bodies=bodies, source=dataclasses.replace(
        base.source, energy=float(e), spectrum=None))
    t = time.perf_counter()
    xray_viz.render(mono_scene(60.0))
    t_one = time.perf_counter() - t
    print(f"one monochromatic render        : {t_one:8.3f} s")
    n = args.mono_renders or args.bins
    t = time.perf_counter()
    for e in energies[:n]:
        xray_viz.render(mono_scene(e))
    t_mono = (time.perf_counter() - t) * args.bins / n
    what = "measured" if n == args.bins else f"extrapolated from {n}"
    print(f"{args.bins} monochromatic renders     : {t_mono:8.3f} s ({what})")
    print(f"speed-up of the spectrum render : {t_mono / t_poly:8.1f} x; "
          f"cost of the spectrum vs one mono render: {t_poly / t_one:.2f} x")


if __name__ == "__main__":
    main()

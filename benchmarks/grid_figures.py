"""The default anti-scatter grid's IEC 60627 figures of merit at 60, 80, 100 and 120 kVp.

Usage::

    python benchmarks/grid_figures.py [--histories N]

The grid: :class:`xray_viz.physics.grid.Grid` () - ratio 10, 60 lines/cm, 0.036 mm lead,
aluminium interspace, focused at 1000 mm. The primary beam at the grid: SpekPy's spectrum
(2.5 mm Al) through 200 mm of water, weighted by the energy (an ideal energy-integrating
detector). Two scatter estimates:

* *model*: scatter isotropic over the half space with the primary's spectrum, SPR 4 in front
  of the grid (an adult abdomen; :meth:`Grid.figures_of_merit`);
* *transport*: the Monte Carlo (``xray_viz.transport``, N histories) of a 200 mm water slab,
  300 x 300 mm, 50 mm above a 300 x 300 mm detector, source at 1000 mm (the grid's focus),
  with and without the grid, the same photons: Ts is the ratio of the scatter images' sums,
  Tp of the primary images', the SPR in the middle 100 x 100 mm; the figures follow from
  them and the SPR without the grid.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import trimesh

import xray_viz
from xray_viz.physics.grid import Grid
from xray_viz.physics.materials import linear_attenuation
from xray_viz.physics.spectra import source_spectrum
from xray_viz.scene import Body, Detector, Scene, Source


def beam_at_grid(kvp: float):
    """Energies and energy weights of the beam behind 200 mm of water."""
    spectrum = source_spectrum(Source(position=[0, 0, 1000],
                                      spectrum={"kvp": kvp, "filters": {"Al": 2.5}}))
    e = spectrum.energies
    w = spectrum.weights * np.exp(-linear_attenuation("Water, Liquid", e) * 20.0) * e
    return e, w


def transport_figures(kvp: float, histories: int) -> dict:
    box = trimesh.creation.box(extents=[300, 300, 200])
    box.apply_translation([0, 0, 150.0])
    water = (Body(name="water", mesh=box, material="Water, Liquid"),)
    source = Source(position=[0, 0, 1000], spectrum={"kvp": kvp, "filters": {"Al": 2.5}})
    results = []
    for grid in (None, Grid()):
        scene = Scene(source=source, detector=Detector(center=[0, 0, 0], shape=(10, 10),
                                                       pitch=(30.0, 30.0), grid=grid),
                      bodies=water)
        results.append(xray_viz.transport(scene, histories, seed=39))
    a, b = results
    keys = ("incoherent", "coherent", "multiple")
    sa, sb = (sum(r.images[k] for k in keys) for r in (a, b))
    tp = b.images["primary"].sum() / a.images["primary"].sum()
    ts = sb.sum() / sa.sum()
    mid = slice(3, 7)
    spr = sa[mid, mid].sum() / a.images["primary"][mid, mid].sum()
    tt = (tp + spr * ts) / (1 + spr)
    return {"Tp": tp, "Ts": ts, "SPR": spr, "bucky_factor": 1 / tt, "selectivity": tp / ts,
            "contrast_improvement": tp / tt}


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--histories", type=int, default=200_000)
    args = parser.parse_args(argv)
    g = Grid()
    print(f"grid: ratio {g.ratio:g}, {g.frequency:g} lines/cm, {g.strip_thickness} mm "
          f"{g.strip_material}, {g.interspace_material} interspace, h = {g.strip_height:.3f} mm, "
          f"focus {g.focus_distance:g} mm")
    print("model (isotropic scatter, SPR 4):")
    print(f"{'kVp':>5} {'Tp':>6} {'Ts':>6} {'Tt':>6} {'Bucky':>6} {'Sigma':>6} {'K':>6}")
    for kvp in (60.0, 80.0, 100.0, 120.0):
        e, w = beam_at_grid(kvp)
        f = g.figures_of_merit(e, w, spr=4.0)
        print(f"{kvp:5.0f} {f['Tp']:6.3f} {f['Ts']:6.3f} {f['Tt']:6.3f} {f['bucky_factor']:6.2f} "
              f"{f['selectivity']:6.2f} {f['contrast_improvement']:6.2f}")
    print(f"transport ({args.histories} histories, 200 mm water slab):")
    print(f"{'kVp':>5} {'Tp':>6} {'Ts':>6} {'SPR':>6} {'Bucky':>6} {'Sigma':>6} {'K':>6} {'s':>6}")
    for kvp in (60.0, 80.0, 100.0, 120.0):
        t0 = time.perf_counter()
        f = transport_figures(kvp, args.histories)
        print(f"{kvp:5.0f} {f['Tp']:6.3f} {f['Ts']:6.3f} {f['SPR']:6.2f} {f['bucky_factor']:6.2f} "
              f"{f['selectivity']:6.2f} {f['contrast_improvement']:6.2f} "
              f"{time.perf_counter() - t0:6.1f}")


if __name__ == "__main__":
    main()

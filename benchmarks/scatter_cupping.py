"""Scatter cupping in CT: a 20 cm water cylinder scanned with and without the Monte Carlo's
scatter, reconstructed with RTK's FDK, the central profiles compared (issue 39).

The scene: a water cylinder (radius 100 mm, 300 mm long, 256 sides) on the rotation axis (y),
a 60 keV monochromatic point source at 600 mm from the axis, a flat detector at 400 mm behind
it (SID 1000 mm), 64 x 32 pixels of 6 mm (a coarse cone-beam CT: 230 x 115 mm at the axis).
A single energy leaves out beam hardening, the other cause of cupping: what cups here is
scatter alone. The detector is noise-free, so the primary-only reconstruction is flat but for
the FDK's own discretisation.

The scan with scatter is ``xray_viz.scan(scene, orbit, scatter="mc", histories=N,
scatter_smoothing=MM)``: each view's scatter is the photon Monte Carlo's, ``--histories`` per
view, seeded with ``projection_seed(0, k)``. Behind 20 cm of water a pixel receives only a few
scattered photons per view at these histories, so each view's scatter is smoothed with a
Gaussian of ``--smooth`` mm at the detector (the scatter of a water cylinder is smooth on the
scale of centimetres; ``--smooth 0`` turns it off) before the detector reads primary plus
scatter, ``li = -ln(exp(-li_primary) + s)``.

The cupping is ``(mu_edge - mu_centre) / mu_edge`` from the radial mean of mu over the
central 5 axial slices (centre r < 20 mm, edge 70 mm < r < 85 mm), in %.

Usage: PYTHONPATH=$PWD .venv/bin/python benchmarks/scatter_cupping.py [--views 90]
       [--histories 200000] [--smooth 12] [--out benchmarks/figures/scatter_cupping.png]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
import trimesh

import xray_viz
from xray_viz.orbit import Orbit
from xray_viz.physics.materials import linear_attenuation
from xray_viz.scene import Body, Detector, Scene, Source

RADIUS = 100.0


def water_cylinder_scene() -> Scene:
    """The cylinder along y, the source on +z, the detector on -z."""
    cyl = trimesh.creation.cylinder(radius=RADIUS, height=300.0, sections=256)
    cyl.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    return Scene(source=Source(position=[0, 0, 600], energy=60.0),
                 detector=Detector(center=[0, 0, -400], shape=(64, 32), pitch=(6.0, 6.0)),
                 bodies=(Body(name="water", mesh=cyl, material="Water, Liquid"),))


def radial_profile(mu, spacing, slices=5):
    """Mean mu (1/cm) in 2 mm rings over the central axial slices (axis y: mu[z, y, x])."""
    nz, ny, nx = mu.shape
    sl = mu[:, ny // 2 - slices // 2: ny // 2 + slices // 2 + 1, :].mean(axis=1)   # (z, x)
    sx, _, sz = spacing
    z = (np.arange(nz) - (nz - 1) / 2) * sz
    x = (np.arange(nx) - (nx - 1) / 2) * sx
    r = np.hypot(z[:, None], x[None, :])
    edges = np.arange(0.0, RADIUS + 10.0, 2.0)
    idx = np.digitize(r.ravel(), edges) - 1
    prof = np.array([sl.ravel()[idx == i].mean() if np.any(idx == i) else np.nan
                     for i in range(len(edges) - 1)])
    return 0.5 * (edges[1:] + edges[:-1]), prof, x, sl[nz // 2]


def cupping(r, prof):
    centre = np.nanmean(prof[r < 20.0])
    edge = np.nanmean(prof[(r > 70.0) & (r < 85.0)])
    return 100.0 * (edge - centre) / edge, centre, edge


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=90)
    parser.add_argument("--histories", type=int, default=200_000)
    parser.add_argument("--smooth", type=float, default=12.0,
                        help="Gaussian sigma (mm at the detector) of each view's scatter; "
                             "0: none")
    parser.add_argument("--out", default="benchmarks/figures/scatter_cupping.png")
    args = parser.parse_args(argv)

    scene = water_cylinder_scene()
    orbit = Orbit(projections=args.views, axis=[0, 1, 0])
    t0 = time.perf_counter()
    primary = xray_viz.scan(scene, orbit)                        # line integrals
    t1 = time.perf_counter()
    scattered = xray_viz.scan(scene, orbit, scatter="mc", histories=args.histories,
                              scatter_smoothing=args.smooth or None)
    total = scattered.projections
    assert np.all(total <= primary.projections + 1e-6)     # scatter lowers every li
    h, w = total.shape[1:]
    spr = np.exp(primary.projections[:, h // 2, w // 2] - total[:, h // 2, w // 2]) - 1.0
    t2 = time.perf_counter()
    vol_p = xray_viz.reconstruct(primary.projections, primary.geometry, method="fdk")
    vol_s = xray_viz.reconstruct(total, primary.geometry, method="fdk")
    t3 = time.perf_counter()

    r, prof_p, x, line_p = radial_profile(vol_p.mu, vol_p.spacing)
    _, prof_s, _, line_s = radial_profile(vol_s.mu, vol_s.spacing)
    cup_p, c_p, e_p = cupping(r, prof_p)
    cup_s, c_s, e_s = cupping(r, prof_s)
    mu_water = float(np.ravel(linear_attenuation("Water, Liquid", [60.0], density=1.0))[0])
    print(f"{args.views} views, {args.histories} histories per view, smoothing "
          f"{args.smooth} mm; voxel {vol_p.spacing} mm, volume {vol_p.mu.shape}")
    print(f"mu of water at 60 keV (xraylib): {mu_water:.4f} /cm")
    print(f"SPR at the detector centre: median over views {np.median(spr):.3f}")
    print(f"primary only : centre {c_p:.4f}, edge {e_p:.4f} /cm, cupping {cup_p:+.1f} %")
    print(f"with scatter : centre {c_s:.4f}, edge {e_s:.4f} /cm, cupping {cup_s:+.1f} %")
    print(f"time: primary scan {t1 - t0:.1f} s, scan with scatter {t2 - t1:.1f} s, "
          f"two FDK {t3 - t2:.1f} s")

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4.2))
    top = 1.2 * mu_water
    axes[0].imshow(vol_s.mu[:, vol_s.mu.shape[1] // 2, :], cmap="gray", vmin=0, vmax=top,
                   origin="lower")
    axes[0].set_title("FDK with scatter, central slice")
    axes[0].axis("off")
    axes[1].plot(x, line_p, label="primary only")
    axes[1].plot(x, line_s, label="primary + MC scatter")
    axes[1].axhline(mu_water, color="grey", lw=0.8, ls="--", label="water, 60 keV")
    axes[1].set_xlabel("x (mm)")
    axes[1].set_ylabel("mu (1/cm)")
    axes[1].set_title("central profile (5 slices)")
    axes[1].set_ylim(0, top)
    axes[1].legend(fontsize=8)
    axes[2].plot(r, prof_p, label=f"primary only ({cup_p:+.1f} %)")
    axes[2].plot(r, prof_s, label=f"with scatter ({cup_s:+.1f} %)")
    axes[2].axhline(mu_water, color="grey", lw=0.8, ls="--")
    axes[2].set_xlabel("radius (mm)")
    axes[2].set_title("radial mean (cupping = edge vs centre)")
    axes[2].set_xlim(0, RADIUS)
    axes[2].set_ylim(0, top)
    axes[2].legend(fontsize=8)
    fig.suptitle(f"20 cm water cylinder, 60 keV, {args.views} views, "
                 f"{args.histories:,} histories/view, scatter smoothed {args.smooth:g} mm")
    fig.tight_layout()
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=100)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

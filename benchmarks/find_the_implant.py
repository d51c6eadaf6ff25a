"""Find the implant: a stem rendered at an unknown pose with noise, registered from 10 mm / 10 deg.

The figure (``benchmarks/find_the_implant.png``): for each of the two views, the noisy target
image with the outline of the stem at the start (red) and at the fitted pose (green), and the
loss curve over the evaluations of every pyramid level. The mTRE is printed.

Usage::

    python benchmarks/find_the_implant.py [--out benchmarks/find_the_implant.png]
"""

from __future__ import annotations

import argparse

import numpy as np

import xray_viz
from xray_viz import gradients as G
from xray_viz import registration as R
from xray_viz.scene import Body, Detector, Scene, Source


def main(argv=None) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", default="benchmarks/find_the_implant.png")
    args = p.parse_args(argv)
    truth = Scene(source=Source(position=[0, 0, 600.0]),
                  detector=Detector(center=[0, 0, -300.0], shape=(128, 128), pitch=(1.2, 1.2)),
                  bodies=(Body(name="stem", mesh=R.demo_stem(4), mu=2.0),))
    rng = np.random.default_rng(7)
    views = []
    for angle in (0.0, 90.0):
        acq = truth.acquisition.rotated(angle, axis=(0, 1, 0)) if angle else truth.acquisition
        li = xray_viz.render(truth.replace(acquisition=acq)).line_integral
        counts = rng.poisson(1e4 * np.exp(-li))
        views.append((acq, -np.log(np.maximum(counts, 1) / 1e4)))
    c = G.centroid(truth.bodies[0])
    d, a = rng.normal(size=3), rng.normal(size=3)
    start = G.pose_matrix(np.r_[d * 10 / np.linalg.norm(d),
                                a * np.radians(10) / np.linalg.norm(a)], c)
    off = G.move_bodies(truth, {"stem": start})
    reg = R.register(off, views, bodies=["stem"], levels=(8, 4, 2, 1))
    mtre0 = R.target_registration_error(truth.bodies[0], start)
    mtre = R.target_registration_error(truth.bodies[0], reg.transforms["stem"] @ start)
    print(f"mTRE {mtre0:.2f} mm at the start, {mtre:.4f} mm fitted; {reg.iterations} "
          f"iterations, loss {reg.initial_loss:.4g} -> {reg.loss:.4g}")
    fig, axes = plt.subplots(1, 3, figsize=(13, 4.6))
    for k, (acq, image) in enumerate(views):
        ax = axes[k]
        ax.imshow(image, cmap="gray_r")
        for scene, colour, label in ((off, "red", "start"), (reg.scene, "lime", "fitted")):
            li = xray_viz.render(scene.replace(acquisition=acq)).line_integral
            ax.contour(li > 0, levels=[0.5], colors=colour, linewidths=1.0)
            ax.plot([], [], color=colour, label=label)
        ax.set_title(f"view {k + 1} ({'front' if k == 0 else 'side'}): target, outlines")
        ax.set_xticks([])
        ax.set_yticks([])
        ax.legend(loc="lower right", fontsize=8)
    losses = [h["loss"] for h in reg.history]
    levels = [h["level"] for h in reg.history]
    ax = axes[2]
    ax.semilogy(losses, color="k", lw=1)
    for f in sorted(set(levels), reverse=True):
        first = levels.index(f)
        ax.axvline(first, color="0.7", lw=0.8)
        ax.text(first + 0.5, max(losses), f"1/{f}" if f > 1 else "full", fontsize=8, va="top")
    ax.set_xlabel("evaluation (pyramid levels: detector 1/f)")
    ax.set_ylabel("mean squared difference of line integrals")
    ax.set_title(f"mTRE {mtre0:.1f} mm -> {mtre:.3f} mm")
    fig.suptitle("Find the implant: biplane registration from 10 mm / 10 deg, Poisson noise "
                 "(1e4 photons per pixel)")
    fig.tight_layout()
    fig.savefig(args.out, dpi=90)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

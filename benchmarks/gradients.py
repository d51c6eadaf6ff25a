"""Exact pose gradients and 2D/3D registration (issue 41): speed and accuracy.

Speed (``--part speed``), for :func:`xray_viz.registration.demo_stem` (an asymmetric
implant-like stem, icosphere subdivision 6: 81,920 faces) on a 256 x 256 detector, point
source, the medians of ``--repeat`` runs of

* ``render``: :func:`xray_viz.render` of the stem at a new pose every time (a moved body is a
  new mesh: the fast engine's set-up and kept results are paid as in a registration step);
* ``gradient (fast)``: :func:`xray_viz.gradients.line_integral_gradient` with the numba
  kernel at a new pose (the line-integral image and the 6 derivatives);
* ``gradient (numpy)``: the same from the NumPy reference;
* ``finite differences``: 12 renders (central differences of the 6 parameters);
* one registration iteration: biplane SSD, 64 x 64 and 256 x 256 detectors.

Accuracy (``--part accuracy``): biplane and single-view registration of the stem
(subdivision 3, 64 x 64 detectors, 2.4 mm pitch, SID 900 mm, magnification 1.5, Poisson
noise at ``--i0`` photons per pixel, default 1e5) from random starts ``--mm`` mm / ``--deg``
degrees off (a random direction and axis each), the mean target registration error (mTRE)
over the vertices, the in-plane and out-of-plane errors of the single view; the capture range
is the success rate (mTRE < 0.1 mm) against the starting error.

Usage::

    python benchmarks/gradients.py --part speed [--repeat 7]
    python benchmarks/gradients.py --part accuracy [--starts 20]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np

import xray_viz
from xray_viz import gradients as G
from xray_viz import registration as R
from xray_viz.scene import Body, Detector, Scene, Source


def _scene(n, pitch, subdivisions):
    return Scene(source=Source(position=[0, 0, 600.0]),
                 detector=Detector(center=[0, 0, -300.0], shape=(n, n), pitch=(pitch, pitch)),
                 bodies=(Body(name="stem", mesh=R.demo_stem(subdivisions), mu=2.0),))


def _median(fn, repeat):
    times = []
    for k in range(repeat):
        t0 = time.perf_counter()
        fn(k)
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _pose(k):
    return G.pose_matrix([0.01 * (k + 1), 0, 0, 0, 0.001 * (k + 1), 0], [0, 0, 0])


def speed(repeat):
    scene = _scene(256, 0.6, 6)
    print(f"stem: {len(scene.bodies[0].faces)} faces, 256 x 256, point source; "
          f"medians of {repeat}")
    moved = [G.move_bodies(scene, {"stem": _pose(k)}) for k in range(repeat + 1)]
    xray_viz.render(moved[-1])                                     # compile / warm
    G.line_integral_gradient(moved[-1], engine="fast")
    t_render = _median(lambda k: xray_viz.render(moved[k]), repeat)
    moved = [G.move_bodies(scene, {"stem": _pose(k + 50)}) for k in range(repeat)]
    t_fast = _median(lambda k: G.line_integral_gradient(moved[k], engine="fast"), repeat)
    moved = [G.move_bodies(scene, {"stem": _pose(k + 100)}) for k in range(3)]
    t_numpy = _median(lambda k: G.line_integral_gradient(moved[k], engine="numpy"), 3)

    def fd(k):
        c = G.centroid(scene.bodies[0])
        for j in range(6):
            for s in (-1, 1):
                p = np.zeros(6)
                p[j] = s * 1e-4 * (k + 1)
                xray_viz.render(G.move_bodies(scene, {"stem": G.pose_matrix(p, c)}))
    t_fd = _median(fd, 3)
    print(f"render                     {t_render * 1e3:8.1f} ms")
    print(f"gradient, fast kernel      {t_fast * 1e3:8.1f} ms   ({t_fast / t_render:.2f} x render)")
    print(f"gradient, numpy reference  {t_numpy * 1e3:8.1f} ms   ({t_numpy / t_render:.2f} x)")
    print(f"finite differences (12 r.) {t_fd * 1e3:8.1f} ms   ({t_fd / t_render:.2f} x)")
    for n, pitch in ((64, 2.4), (256, 0.6)):
        sc = _scene(n, pitch, 6 if n == 256 else 3)
        rng = np.random.default_rng(0)
        pairs = _views(sc, rng)
        off = G.move_bodies(sc, {"stem": _start(sc, rng, 5.0, 5.0)})
        t0 = time.perf_counter()
        reg = R.register(off, pairs, bodies=["stem"])
        dt = time.perf_counter() - t0
        print(f"biplane SSD registration {n}x{n} ({len(sc.bodies[0].faces)} faces): {dt:.2f} s, "
              f"{reg.iterations} iterations, {len(reg.history)} evaluations, "
              f"{dt / len(reg.history) * 1e3:.0f} ms per evaluation (2 views, all levels)")


def _views(scene, rng, i0=1e5, angles=(0.0, 90.0)):
    out = []
    for angle in angles:
        acq = scene.acquisition.rotated(angle, axis=(0, 1, 0)) if angle else scene.acquisition
        li = xray_viz.render(scene.replace(acquisition=acq)).line_integral
        counts = rng.poisson(i0 * np.exp(-li))
        out.append((acq, -np.log(np.maximum(counts, 1) / i0)))
    return out


def _start(scene, rng, mm, deg):
    d, a = rng.normal(size=3), rng.normal(size=3)
    p = np.r_[d * mm / np.linalg.norm(d), a * np.radians(deg) / np.linalg.norm(a)]
    return G.pose_matrix(p, G.centroid(scene.bodies[0]))


def _errors(scene, transform):
    v = np.c_[scene.bodies[0].vertices, np.ones(len(scene.bodies[0].vertices))]
    err = (v @ transform.T - v)[:, :3]
    return (float(np.linalg.norm(err, axis=1).mean()),
            float(np.linalg.norm(err[:, :2], axis=1).mean()), float(np.abs(err[:, 2]).mean()))


def accuracy(starts, mm, deg, similarity, capture, i0=1e5):
    scene = _scene(64, 2.4, 3)
    rng = np.random.default_rng(41)
    bi, single, times = [], [], []
    for _ in range(starts):
        pairs = _views(scene, rng, i0)
        start = _start(scene, rng, mm, deg)
        off = G.move_bodies(scene, {"stem": start})
        t0 = time.perf_counter()
        reg = R.register(off, pairs, bodies=["stem"], similarity=similarity)
        times.append(time.perf_counter() - t0)
        bi.append(_errors(scene, reg.transforms["stem"] @ start)[0])
        reg1 = R.register(off, [pairs[0]], bodies=["stem"], similarity=similarity)
        single.append(_errors(scene, reg1.transforms["stem"] @ start))
    bi, single = np.array(bi), np.array(single)
    print(f"{similarity}, {starts} starts {mm} mm / {deg} deg off, 64 x 64, I0 = {i0:g}:")
    print(f"  biplane mTRE: median {np.median(bi):.4f} mm, max {bi.max():.4f} mm, "
          f"< 0.1 mm in {np.mean(bi < 0.1) * 100:.0f} %; median time {np.median(times):.2f} s")
    print(f"  single view: in-plane median {np.median(single[:, 1]):.4f} mm (max "
          f"{single[:, 1].max():.4f}, < 0.2 mm in {np.mean(single[:, 1] < 0.2) * 100:.0f} %), "
          f"out-of-plane median {np.median(single[:, 2]):.4f} mm (max {single[:, 2].max():.4f}),"
          f" mTRE median {np.median(single[:, 0]):.4f} mm")
    for error in capture:
        ok = []
        for _ in range(10):
            pairs = _views(scene, rng, i0)
            start = _start(scene, rng, error, error)
            reg = R.register(G.move_bodies(scene, {"stem": start}), pairs, bodies=["stem"],
                             similarity=similarity)
            ok.append(_errors(scene, reg.transforms["stem"] @ start)[0] < 0.1)
        print(f"  capture: {error} mm / {error} deg off: {np.mean(ok) * 100:.0f} % of 10 "
              "biplane starts below 0.1 mm")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--part", choices=("speed", "accuracy"), default="speed")
    p.add_argument("--repeat", type=int, default=7)
    p.add_argument("--starts", type=int, default=20)
    p.add_argument("--mm", type=float, default=5.0)
    p.add_argument("--deg", type=float, default=5.0)
    p.add_argument("--similarity", default="ssd", choices=R.SIMILARITIES)
    p.add_argument("--capture", type=float, nargs="*", default=[10.0, 15.0, 20.0])
    p.add_argument("--i0", type=float, default=1e5, help="photons per pixel of the noise")
    args = p.parse_args(argv)
    if args.part == "speed":
        speed(args.repeat)
    else:
        accuracy(args.starts, args.mm, args.deg, args.similarity, args.capture, args.i0)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

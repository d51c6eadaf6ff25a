"""The scatter kernel model against the transport on cases it was not fitted on, and its cost.

Held-out cases: water slabs of other thicknesses, fields, gaps and spectra than the
calibration's (benchmarks/calibrate_scatter_kernel.py), a cortical bone layer in a water slab,
the bundled phantoms step_wedge (aluminium), limb, nested_spheres and the frog (an anatomy
label map surfaced into 15 tissues), and two water slabs behind the default anti-scatter grid
(the model's grid factor comes from its angular spread, not from a fit). For each: the
transport's scatter (incoherent + coherent + multiple over the flat field) and the model's
from the renderer's noise-free ``ln T`` and path lengths per body, both averaged over blocks of pixels (about 8 x 8 blocks over the field); the SPR of a block is its
scatter over its primary (the same primary for both, so the SPR's relative error is the
scatter's). Reported: over the blocks where the transport's own relative error is below 2 %,
the median and 90th percentile of ``|SPR_model / SPR_transport - 1|`` (and the blocks kept).

Then the cost on the frog at 512 x 512: the primary render (the fast engine, warm) and the
model (``KernelModel.of`` once, then ``scatter`` with the path lengths per body, and
``render(scatter="kernel")`` whole, at the same pose and at a new one), medians of
``--repeats`` runs, the renders at new poses in alternation; and the
transport's throughput on the frog, with the histories it needs for the model's median error
and for 2 % per block.

Usage::

    PYTHONPATH=$PWD .venv/bin/python benchmarks/scatter_kernel_accuracy.py \
        [--scattered 400000] [--max-histories 20000000] [--cache /tmp/skacc.npz] [--cost-only] \
        [--parameters FILE]

A case already in the cache at another budget is used as it is (its histories are in the
table).
"""

from __future__ import annotations

import argparse
import platform
import statistics
import sys
import time
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from calibrate_scatter_kernel import slab_scene  # noqa: E402

AL = {"filters": {"Al": 2.5}}


def held_out():
    """``(label, scene factory)`` of the cases the fit did not see."""
    import xray_viz

    def phantom(name):
        return lambda: xray_viz.load_scene(name)

    return [
        ("water 150 mm, field 250 mm, gap 100 mm, 100 kVp",
         lambda: slab_scene(150.0, 250.0, 100.0, {"spectrum": {"kvp": 100.0, **AL}})),
        ("water 250 mm, field 100 mm, gap 50 mm, 75 kVp",
         lambda: slab_scene(250.0, 100.0, 50.0, {"spectrum": {"kvp": 75.0, **AL}})),
        ("water 80 mm, field 300 mm, gap 200 mm, 60 keV",
         lambda: slab_scene(80.0, 300.0, 200.0, {"energy": 60.0})),
        ("bone 20 mm in water 150 mm, field 200 mm, gap 50 mm, 90 kVp",
         lambda: slab_scene(150.0, 200.0, 50.0, {"spectrum": {"kvp": 90.0, **AL}},
                            insert=("Bone, Cortical (ICRP)", 20.0))),
        ("step_wedge (Al), 60 keV", phantom("step_wedge")),
        ("limb, 60 keV", phantom("limb")),
        ("nested_spheres, 60 keV", phantom("nested_spheres")),
        ("frog (15 tissues), 60 keV", phantom("frog")),
        ("water 150 mm, field 250 mm, gap 100 mm, 100 kVp, default grid",
         lambda: gridded(slab_scene(150.0, 250.0, 100.0, {"spectrum": {"kvp": 100.0, **AL}}))),
        ("water 200 mm, field 300 mm, gap 20 mm, 80 kVp, default grid",
         lambda: gridded(slab_scene(200.0, 300.0, 20.0, {"spectrum": {"kvp": 80.0, **AL}}))),
        ("water 180 mm, field 300 mm, gap 40 mm, 100 kVp, grid 12:1, 70 lines/cm, "
         "focused at 1500 mm",
         lambda: gridded(slab_scene(180.0, 300.0, 40.0, {"spectrum": {"kvp": 100.0, **AL}}),
                         ratio=12.0, frequency=70.0, focus_distance=1500.0)),
        ("chest (CT + implant), 70 keV: outside the fitted ranges", phantom("chest")),
    ]


def gridded(scene, **grid):
    """``scene`` with an anti-scatter grid (default: ratio 10, 60 lines/cm, focused at
    1000 mm; ``grid``: other :class:`~xray_viz.physics.grid.Grid` fields)."""
    import dataclasses

    from xray_viz.physics.grid import Grid

    return scene.replace(detector=dataclasses.replace(scene.detector, grid=Grid(**grid)))


def blocks(a, b, *, squared=False):
    """Means over ``b x b`` blocks (errors of the means with ``squared``)."""
    h, w = a.shape
    x = a[:h // b * b, :w // b * b].reshape(h // b, b, w // b, b)
    if squared:
        return np.sqrt((x ** 2).sum(axis=(1, 3))) / (b * b)
    return x.mean(axis=(1, 3))


def transport_images(scene, *, scattered, max_histories, seed):
    """The transport's scatter and error over the flat field, the renderer's ``ln T``, the
    histories and the seconds they took."""
    from calibrate_scatter_kernel import simulate

    t0 = time.perf_counter()
    s, e, log_t, n = simulate(scene, scattered=scattered, max_histories=max_histories,
                              seed=seed)
    return s, e, log_t, n, time.perf_counter() - t0


def cached(store, label):
    """The key of ``label``'s transport in ``store`` (the run of the most histories, whatever
    budget it had: a case run at another ``--max-histories`` is used as it is, its
    histories in the table), or None."""
    keys = [k[:-2] for k in store if k.startswith(label + "|") and k.endswith("|s")]
    return max(keys, key=lambda k: int(store[k + "|n"])) if keys else None


def compare(scene, s, e, log_t, parameters=None):
    """Blocks: the transport's scatter, the model's, the transport's error, the primary;
    and the model's warnings (``parameters``: a calibration file, default the package's)."""
    from xray_viz.scatter_kernel import KernelModel, load_parameters

    import xray_viz

    # each pixel's path length per body (and voxel class): the amplitude sees the materials,
    # as render's does
    lengths = xray_viz.render(scene, path_lengths=True).path_length
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model = KernelModel.of(scene, parameters=load_parameters(parameters))
        pred = model.scatter(log_t, scene.acquisition, scene.bodies, path_lengths=lengths,
                             volumes=scene.volumes)
    h, w = s.shape
    b = max(1, min(h, w) // 8)
    return (blocks(s, b), blocks(pred, b), blocks(e, b, squared=True),
            blocks(np.exp(log_t), b), [str(c.message) for c in caught])


def cost(repeats):
    """Medians (s) on the frog at 512 x 512: the primary render at a new pose (the source
    moved by a micrometre: its trace not reused), the primary render at the same pose (the
    trace reused from the bodies' cache: the image stage only), ``KernelModel.of`` and
    ``scatter``."""
    import dataclasses

    import xray_viz
    from xray_viz.scatter_kernel import KernelModel

    scene = xray_viz.load_scene("frog")
    r = xray_viz.render(scene)                                 # compile, caches
    lengths = xray_viz.render(scene, path_lengths=True).path_length
    t_new, t_same, t_of, t_scatter, t_kernel, t_kernel_new = [], [], [], [], [], []
    for i in range(repeats):
        moved = scene.replace(source=dataclasses.replace(
            scene.source, position=np.asarray(scene.source.position) + [1e-3 * (i + 1), 0, 0]))
        t = time.perf_counter()
        xray_viz.render(moved)
        t_new.append(time.perf_counter() - t)
        moved = scene.replace(source=dataclasses.replace(
            scene.source, position=np.asarray(scene.source.position) - [1e-3 * (i + 1), 0, 0]))
        t = time.perf_counter()
        xray_viz.render(moved, scatter="kernel")
        t_kernel_new.append(time.perf_counter() - t)
        t = time.perf_counter()
        r = xray_viz.render(scene)
        t_same.append(time.perf_counter() - t)
        t = time.perf_counter()
        model = KernelModel.of(scene)
        t_of.append(time.perf_counter() - t)
        log_t = -r.line_integral
        t = time.perf_counter()
        model.scatter(log_t, scene.acquisition, scene.bodies, path_lengths=lengths)
        t_scatter.append(time.perf_counter() - t)
        t = time.perf_counter()
        xray_viz.render(scene, scatter="kernel")
        t_kernel.append(time.perf_counter() - t)
    return tuple(statistics.median(x) for x in (t_new, t_same, t_of, t_scatter, t_kernel,
                                                 t_kernel_new))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scattered", type=int, default=400_000)
    parser.add_argument("--max-histories", type=int, default=20_000_000)
    parser.add_argument("--cache", default=None)
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--cost-only", action="store_true")
    parser.add_argument("--parameters", default=None,
                        help="a calibration file other than the package's (a previous fit)")
    args = parser.parse_args(argv)
    print(f"machine: {platform.machine()}, {platform.processor() or '?'}, "
          f"Python {platform.python_version()}")
    rows = []
    if not args.cost_only:
        store = {}
        if args.cache and Path(args.cache).exists():
            with np.load(args.cache, allow_pickle=False) as z:
                store = {k: z[k] for k in z.files}
        print("| case | histories | transport s | blocks kept / all | median | 90th pct. "
              "| SPR (transport, centre block) | transport s for the model's median error |")
        print("|---|---|---|---|---|---|---|---|")
        for i, (label, make) in enumerate(held_out()):
            scene = make()
            key = cached(store, label) or f"{label}|{args.scattered}|{args.max_histories}"
            if key + "|s" not in store:
                s, e, log_t, n, sec = transport_images(scene, scattered=args.scattered,
                                                       max_histories=args.max_histories,
                                                       seed=100 + i)
                store.update({key + "|s": s, key + "|e": e, key + "|l": log_t,
                              key + "|n": np.array(n), key + "|sec": np.array(sec)})
                if args.cache:
                    np.savez(args.cache, **store)
            s, e, log_t = (store[key + k] for k in ("|s", "|e", "|l"))
            n, sec = int(store[key + "|n"]), float(store[key + "|sec"])
            sb, pb, eb, tb, msgs = compare(scene, s, e, log_t, args.parameters)
            with np.errstate(divide="ignore", invalid="ignore"):
                rel_err = eb / sb
                dev = np.abs(pb / sb - 1)
            keep = np.isfinite(rel_err) & (rel_err < 0.02) & (sb > 0)
            c = tuple(x // 2 for x in sb.shape)
            spr = sb[c] / tb[c]
            if keep.any():
                med, p90 = np.median(dev[keep]), np.percentile(dev[keep], 90)
                figs = f"{100 * med:.1f} % | {100 * p90:.1f} %"
                # the transport's error falls as 1 / sqrt(histories): the seconds for its
                # median block error to equal the model's median error
                own = float(np.median(rel_err[np.isfinite(rel_err)]))
                same = f"{sec * (own / med) ** 2:.1f}"
            else:
                # no block reaches 2 %: the medians over every block, with the transport's
                # own median error beside them (its noise is in these figures)
                own = float(np.median(rel_err[np.isfinite(rel_err)]))
                figs = (f"({100 * np.median(dev):.1f} % all blocks, transport error "
                        f"{100 * own:.1f} %) | -")
                same = "-"
            print(f"| {label} | {n:,} | {sec:.0f} | {int(keep.sum())} / {keep.size} | {figs} | "
                  f"{spr:.3f} | {same} |", flush=True)
            sel = keep if keep.any() else np.isfinite(dev)
            print(f"    signed median of SPR_model / SPR_transport - 1: "
                  f"{100 * np.median((pb / sb - 1)[sel]):+.1f} %")
            for m in msgs:
                print(f"    warning: {m}")
            rows.append((label, keep, dev))
    if args.repeats < 1:
        return 0
    t_new, t_same, t_of, t_scatter, t_kernel, t_kernel_new = cost(args.repeats)
    print(f"frog 512x512, medians of {args.repeats}: primary render at a new pose "
          f"{1e3 * t_new:.1f} ms, at the same pose {1e3 * t_same:.1f} ms, KernelModel.of "
          f"{1e3 * t_of:.1f} ms, scatter (with the path lengths) {1e3 * t_scatter:.1f} ms, "
          f"render(scatter='kernel') at the same pose {1e3 * t_kernel:.1f} ms, at a new "
          f"pose {1e3 * t_kernel_new:.1f} ms ({t_kernel_new / t_new:.2f} times the primary "
          f"render's)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

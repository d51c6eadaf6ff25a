"""Fit the scatter kernel model (xray_viz/scatter_kernel.py) on the transport's water bodies.

Each calibration case is a body of water ("Water, Liquid"), its exit side ``gap`` mm above a
square detector of 32 x 32 pixels ``field`` mm wide, 1500 mm from a point source; the
transport emits into the detector's field, so the field at the detector is the detector. The
bodies: slabs (boxes) wider than the field (thicknesses 10-300 mm), blocks narrower than it
(:data:`NARROW`), and cylinders and spheres narrower than it (:data:`SMALL`, 25-150 mm
across). Then water slabs and a cylinder behind the default anti-scatter grid (:data:`GRIDDED`). The
transport's scatter (incoherent + coherent + multiple) over the flat field
(:func:`xray_viz.transport.flat_signal`) is compared, in blocks of 4 x 4 pixels, with the
model's scatter from the primary renderer's noise-free ``ln T``; the parameters minimise the
relative residuals (``scipy.optimize.least_squares``, each block weighted by its transport
error plus 3 %) in three stages, each with the previous ones' held: the amplitude and the
kernels (:data:`SLAB_PARAMETERS`) on the slabs wider than the field, the edge term
(:data:`EDGE_PARAMETERS`) on the bodies narrower than it, the angles through a grid
(:data:`GRID_PARAMETERS`) on the cases behind the grid (``--slab-parameters FILE``,
``--edge-parameters FILE``: those of a previous calibration held, not fitted). Histories per
case: a pilot of 40,000 estimates the scattered photons per history, then enough for
``--scattered`` of them (at most ``--max-histories``; ``--small-scattered`` and
``--small-max-histories`` for the bodies narrower than the field, which most photons miss,
``--grid-scattered`` and ``--grid-max-histories`` for the cases behind the grid).

Usage::

    PYTHONPATH=$PWD .venv/bin/python benchmarks/calibrate_scatter_kernel.py \
        [--scattered 60000] [--max-histories 4000000] [--small-scattered 150000] \
        [--small-max-histories 8000000] [--grid-scattered 150000] \
        [--grid-max-histories 20000000] [--cache /tmp/skcal.npz] [--slab-parameters FILE] \
        [--edge-parameters FILE] [--out FILE]

Writes ``xray_viz/data/scatter_kernel.json`` (or ``--out``) with the date, commit, histories,
ranges and the residuals of the fit.
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import json
import math
import os
import platform
import subprocess
import sys
import time
import warnings
import zlib
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
SID = 1500.0
PIXELS = 32
BIN = 4

#: name -> the [source] keys of each calibration spectrum
SPECTRA = {"60kVp": {"spectrum": {"kvp": 60.0, "filters": {"Al": 2.5}}},
           "90kVp": {"spectrum": {"kvp": 90.0, "filters": {"Al": 2.5}}},
           "120kVp": {"spectrum": {"kvp": 120.0, "filters": {"Al": 2.5}}},
           "60keV": {"energy": 60.0}}
THICKNESSES = (50.0, 100.0, 200.0, 300.0)
FIELDS = (50.0, 150.0, 400.0)
#: 5 mm, not 0: a body face lying in the detector plane loses about a third of the
#: transport's scatter (measured: 50 mm of water, a 400 mm field, 120 kVp: 0.140 at a gap of
#: 0, 0.207 at 0.5 mm, 0.211 at 10 mm), a degenerate case of its scoring
GAPS = (5.0, 150.0, 300.0)
#: Water blocks narrower than the field: (thickness, width, spectrum)
NARROW = ((50.0, 60.0, "60keV"), (100.0, 100.0, "60keV"), (60.0, 150.0, "90kVp"),
          (100.0, 60.0, "90kVp"), (150.0, 120.0, "120kVp"), (30.0, 40.0, "60keV"),
          (10.0, 60.0, "60keV"), (20.0, 100.0, "60keV"))
#: Thin slabs wider than the field (the frog is 2-30 mm of water-equivalent tissue):
#: (thickness, field, gap, spectrum)
THIN = ((10.0, 150.0, 50.0, "60keV"), (25.0, 300.0, 200.0, "90kVp"),
        (10.0, 300.0, 100.0, "120kVp"), (25.0, 100.0, 20.0, "60keV"))
#: Water bodies narrower than the field, round (issue 39's small bodies: the limb, the frog):
#: (shape, diameter, field, gap, spectrum); a cylinder lies along the detector's v axis,
#: ``CYLINDER_LENGTH`` of the field long (its ends inside the field, as the limb's are)
SMALL = (("cylinder", 40.0, 150.0, 50.0, "60keV"), ("cylinder", 60.0, 200.0, 300.0, "60keV"),
         ("cylinder", 80.0, 200.0, 150.0, "60keV"), ("cylinder", 80.0, 250.0, 400.0, "90kVp"),
         ("cylinder", 120.0, 200.0, 20.0, "120kVp"), ("cylinder", 150.0, 300.0, 250.0, "60kVp"),
         ("sphere", 50.0, 120.0, 100.0, "60keV"), ("sphere", 80.0, 150.0, 250.0, "120kVp"),
         ("sphere", 100.0, 200.0, 450.0, "60keV"), ("sphere", 150.0, 250.0, 50.0, "90kVp"),
         ("cylinder", 25.0, 120.0, 75.0, "60keV"))
CYLINDER_LENGTH = 0.75
#: Water slabs behind the default anti-scatter grid (ratio 10, 60 lines/cm, focused at 1000
#: mm, 1500 mm from the source: cut off toward the edges): (thickness, field, gap,
#: spectrum); and one cylinder narrower than the field, ("cylinder", diameter, field, gap,
#: spectrum). The grid's angle parameter (:data:`GRID_PARAMETERS`)
GRIDDED = ((50.0, 200.0, 10.0, "60kVp"), (100.0, 300.0, 50.0, "90kVp"),
           (200.0, 250.0, 150.0, "120kVp"), (300.0, 400.0, 20.0, "90kVp"),
           (100.0, 150.0, 300.0, "60keV"), (150.0, 400.0, 5.0, "120kVp"),
           ("cylinder", 120.0, 250.0, 30.0, "90kVp"))
#: A wider field (the limb's detector is 415 mm long)
WIDE_FIELD = 450.0
#: Longer gaps (the bundled phantoms stand 0.2-0.5 m above their detectors)
LONG_GAP = 500.0


def slab_scene(thickness, field, gap, spectrum, *, pixels=PIXELS, sid=SID, insert=None,
               material="Water, Liquid", side=None):
    """A slab (box) of ``material`` ``thickness`` mm thick, its exit side ``gap`` mm above a
    ``pixels``-square detector ``field`` mm wide at z = 0, source at z = ``sid``.
    ``insert``: ``(material, thickness)`` of a slab in its middle (a bone layer).
    ``spectrum``: a name of :data:`SPECTRA` or the ``[source]`` keys themselves. ``side``:
    the slab's width (default wider than the field)."""
    import trimesh

    from xray_viz.scene import Body, Detector, Scene, Source

    side = 1.3 * field + 20.0 if side is None else side
    box = trimesh.creation.box(extents=[side, side, thickness])
    box.apply_translation([0.0, 0.0, gap + thickness / 2])
    bodies = [Body(name="slab", mesh=box, material=material)]
    if insert is not None:
        mat, t = insert
        inner = trimesh.creation.box(extents=[side - 4.0, side - 4.0, t])
        inner.apply_translation([0.0, 0.0, gap + thickness / 2])
        bodies.append(Body(name="insert", mesh=inner, material=mat))
    pitch = field / pixels
    keys = SPECTRA[spectrum] if isinstance(spectrum, str) else spectrum
    return Scene(source=Source(position=[0.0, 0.0, sid], **keys),
                 detector=Detector(center=[0.0, 0.0, 0.0], shape=(pixels, pixels),
                                   pitch=(pitch, pitch)),
                 bodies=tuple(bodies))


def round_scene(shape, diameter, field, gap, spectrum, *, pixels=PIXELS, sid=SID,
                 material="Water, Liquid"):
    """A water ``shape`` ("cylinder" or "sphere") ``diameter`` mm across, its exit side
    ``gap`` mm above a ``pixels``-square detector ``field`` mm wide at z = 0, source at
    z = ``sid``; a cylinder lies along the detector's v axis, :data:`CYLINDER_LENGTH` of the
    field long."""
    import trimesh

    from xray_viz.scene import Body, Detector, Scene, Source

    r = diameter / 2
    if shape == "cylinder":
        mesh = trimesh.creation.cylinder(radius=r, height=CYLINDER_LENGTH * field,
                                         sections=96)
        mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    elif shape == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=4, radius=r)
    else:
        raise ValueError(f"shape {shape!r}: 'cylinder' or 'sphere'")
    mesh.apply_translation([0.0, 0.0, gap + r])
    pitch = field / pixels
    keys = SPECTRA[spectrum] if isinstance(spectrum, str) else spectrum
    return Scene(source=Source(position=[0.0, 0.0, sid], **keys),
                 detector=Detector(center=[0.0, 0.0, 0.0], shape=(pixels, pixels),
                                   pitch=(pitch, pitch)),
                 bodies=(Body(name=shape, mesh=mesh, material=material),))


def case_scene(case):
    """The scene of a :func:`calibration_cases` row."""
    label, t, f, g, s, w = case[:6]
    shape = case[6] if len(case) > 6 else None
    gridded = len(case) > 7 and case[7]
    if shape is None:
        scene = slab_scene(t, f, g, s, side=w)
    else:
        scene = round_scene(shape, t, f, g, s)
    if gridded:
        import dataclasses

        from xray_viz.physics.grid import Grid

        scene = scene.replace(detector=dataclasses.replace(scene.detector, grid=Grid()))
    return scene


def calibration_cases():
    """``(label, thickness, field, gap, spectrum, width, shape)``: every corner of the ranges,
    the centre lines, a seeded sample of the rest of the grid (slabs wider than the field:
    width None, shape None), blocks narrower than the field (:data:`NARROW`, shape None) and
    water cylinders and spheres (:data:`SMALL`: thickness their diameter, shape theirs)."""
    grid = list(itertools.product(THICKNESSES, FIELDS, GAPS, SPECTRA))
    rng = np.random.default_rng(39)
    pick = set()
    for t, s in itertools.product(THICKNESSES, SPECTRA):       # thickness x spectrum
        pick.add((t, 150.0, GAPS[0], s))
    for t, f in itertools.product((100.0, 300.0), FIELDS):      # field
        pick.add((t, f, GAPS[1], "90kVp"))
    for t, g in itertools.product((50.0, 200.0), GAPS):         # gap
        pick.add((t, 400.0, g, "120kVp"))
    pick.add((300.0, 400.0, 300.0, "60kVp"))
    pick.add((50.0, 50.0, 300.0, "60keV"))
    for i in rng.permutation(len(grid))[:8]:
        pick.add(grid[i])
    for t, f, s in ((50.0, 150.0, "60keV"), (100.0, 400.0, "90kVp"), (200.0, 150.0, "120kVp"),
                    (300.0, 400.0, "60kVp"), (100.0, 50.0, "120kVp"), (50.0, 400.0, "60keV")):
        pick.add((t, f, LONG_GAP, s))
    for t, g, s in ((100.0, 150.0, "60keV"), (200.0, 5.0, "90kVp"), (50.0, 300.0, "120kVp")):
        pick.add((t, WIDE_FIELD, g, s))
    pick.update(THIN)
    out = [(f"water {t:.0f} mm, field {f:.0f} mm, gap {g:.0f} mm, {s}", t, f, g, s, None, None)
           for (t, f, g, s) in sorted(pick, key=lambda c: (c[3], c[0], c[1], c[2]))]
    # blocks narrower than the field (square, ``w`` mm wide): the edge term
    for t, w, s in NARROW:
        out.append((f"water {t:.0f} mm, {w:.0f} mm wide, field 200 mm, gap 100 mm, {s}",
                    t, 200.0, 100.0, s, w, None))
    for shape, d, f, g, s in SMALL:
        out.append((f"water {shape} {d:.0f} mm across, field {f:.0f} mm, gap {g:.0f} mm, {s}",
                    d, f, g, s, None, shape))
    for row in GRIDDED:
        shape, (t, f, g, s) = (row[0], row[1:]) if isinstance(row[0], str) else (None, row)
        what = f"{shape} {t:.0f} mm across" if shape else f"{t:.0f} mm"
        out.append((f"water {what}, field {f:.0f} mm, gap {g:.0f} mm, {s}, default grid",
                    t, f, g, s, None, shape, True))
    return out


def simulate(scene, *, scattered, max_histories, seed, pilot=40_000):
    """The transport's scatter and its standard error over the flat field, the primary's
    noise-free ``ln T`` (the renderer) and the histories run."""
    import xray_viz
    from xray_viz.transport import flat_signal

    keys = ("incoherent", "coherent", "multiple")
    probe = xray_viz.transport(scene, pilot, seed=seed + 1_000_003)
    from xray_viz.physics.spectra import source_spectrum

    spec = source_spectrum(scene.source)
    mean_ev = 1000.0 * float(spec.weights @ spec.energies / spec.weights.sum())
    rate = sum(probe.images[k].sum() for k in keys) / (0.8 * mean_ev)    # photons / history
    n = int(min(max_histories, max(pilot, scattered / max(rate, 1e-9))))
    r = xray_viz.transport(scene, n, seed=seed)
    flat = flat_signal(scene)
    s = sum(r.images[k] for k in keys) / flat
    # the three images come from the same histories: their errors add in quadrature as an
    # upper bound (a history scores in one of them per pixel at most, mostly)
    e = np.sqrt(sum(r.image_errors[k] ** 2 for k in keys)) / flat
    log_t = -xray_viz.render(scene).line_integral
    return s, e, log_t, n


def bin_image(a, b=BIN, *, squared=False):
    """Mean over ``b x b`` blocks (of the squares with ``squared``: the mean's error)."""
    h, w = a.shape
    blocks = a[:h // b * b, :w // b * b].reshape(h // b, b, w // b, b)
    if squared:
        return np.sqrt((blocks ** 2).sum(axis=(1, 3))) / (b * b)
    return blocks.mean(axis=(1, 3))


def run_cases(cases, *, scattered, max_histories, cache=None, seed=0, small=None,
              gridded=None):
    """Each case's scene, binned transport scatter, error, ``ln T``, histories, seconds and
    stage (0 a slab wider than the field, 1 a body narrower than it, 2 behind a grid)
    (read from ``cache`` where it has them, then stored there). ``small``:
    ``(scattered, max_histories)`` of the bodies narrower than the field (cheap: most
    photons miss them; they need more for the same error), default the others'; ``gridded``
    the same for the cases behind a grid."""
    store = {}
    if cache is not None and Path(cache).exists():
        with np.load(cache, allow_pickle=False) as z:
            store = {k: z[k] for k in z.files}
    out = []
    for case in cases:
        label = case[0]
        scene = case_scene(case)
        narrow = case[5] is not None or (len(case) > 6 and case[6] is not None)
        stage = 2 if len(case) > 7 and case[7] else int(narrow)
        budget = {0: None, 1: small, 2: gridded}[stage]
        want, cap = budget if budget is not None else (scattered, max_histories)
        # the case's seed from its label: the same numbers whatever the other cases
        case_seed = seed + zlib.crc32(label.encode()) % 1_000_000
        prefix = f"{label}|{want}|{cap}|"
        found = [k[:-2] for k in store if k.startswith(prefix) and k.endswith("|s")]
        key = found[0] if found else prefix + str(case_seed)
        if key + "|s" not in store:
            t0 = time.perf_counter()
            img, err, log_t, n = simulate(scene, scattered=want, max_histories=cap,
                                          seed=case_seed)
            store.update({key + "|s": img, key + "|e": err, key + "|l": log_t,
                          key + "|n": np.array(n),
                          key + "|sec": np.array(time.perf_counter() - t0)})
            print(f"{label}: {n} histories, {time.perf_counter() - t0:.0f} s, "
                  f"centre scatter {img[12:20, 12:20].mean():.4g}", flush=True)
            if cache is not None:
                np.savez(cache, **store)
        out.append((label, scene, store[key + "|s"], store[key + "|e"], store[key + "|l"],
                    int(store[key + "|n"]), float(store.get(key + "|sec", np.nan)), stage))
    return out


#: The slab parameters (stage 1: water slabs wider than the field) and the edge parameters
#: (stage 2: bodies narrower than the field, the slab parameters held): the edge term is
#: 1 over a shadow that covers the field, so stage 2 leaves the slabs as stage 1 fits them
SLAB_PARAMETERS = ("a0", "a1", "a2", "a3", "a4", "fraction", "s1", "s2", "n1", "n2")
EDGE_PARAMETERS = ("b_edge", "c_edge", "l_edge")
GRID_PARAMETERS = ("grid_depth", "grid_hardening")
#: start, low and high of each parameter
BOUNDS = {"a0": (0.40, -5, 5), "a1": (1.02, 0.05, 5), "a2": (0.33, -5, 5),
          "a3": (-0.28, -5, 5), "a4": (0.02, -5, 5), "fraction": (0.95, 0.0, 1.0),
          "s1": (1.0, 0.001, 2.0), "s2": (0.49, 0.01, 10.0), "n1": (99.0, 0.0, 100.0),
          "n2": (1.67, 0.0, 30.0), "b_edge": (0.2, 0.0, 1.0), "c_edge": (0.5, 0.0, 1.0),
          "l_edge": (50.0, 0.5, 100.0), "grid_depth": (50.0, 1.0, 2000.0),
          "grid_hardening": (0.5, 0.0, 2.0)}

#: more starts of the edge term's fit
EDGE_STARTS = ((0.2, 1.0, 100.0), (0.35, 0.2, 1.0))


def _models(results, values):
    """Each case's model, scene, ``ln T``, binned transport scatter and residual weight."""
    from xray_viz.scatter_kernel import KernelModel, KernelParameters

    ranges = {"energy_kev": (0.0, 1e9), "thickness_mm": (0.0, 1e9), "field_mm": (0.0, 1e9),
              "gap_mm": (0.0, 1e9)}
    models = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _, scene, s, e, log_t, *_ in results:
            m = KernelModel.of(scene, parameters=KernelParameters(dict(values), ranges, {}))
            sb, eb = bin_image(s), bin_image(e, squared=True)
            models.append((m, scene, log_t, sb, np.sqrt(eb ** 2 + (0.03 * sb) ** 2) + 1e-12))
    return models, ranges


def _predict(models, ranges, values):
    from xray_viz.scatter_kernel import KernelParameters

    params = KernelParameters(dict(values), ranges, {})
    out = []
    for m, scene, log_t, sb, wb in models:
        m.parameters = params
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            out.append((bin_image(m.scatter(log_t, scene.acquisition, scene.bodies)), sb, wb))
    return out


def fit(results, start=None, *, held=()):
    """Least-squares parameters in three stages, each with the previous ones' held:
    :data:`SLAB_PARAMETERS` on the slabs wider than the field, :data:`EDGE_PARAMETERS` on
    the bodies narrower than it, :data:`GRID_PARAMETERS` on the cases behind a grid:
    ``(values dict, per-case median |relative error|, the stages' solutions)``.
    ``results``: :func:`run_cases`' rows, their last item the stage. ``held``: the stages
    whose parameters ``start`` gives and are not fitted."""
    from scipy.optimize import least_squares

    values = {k: v[0] for k, v in BOUNDS.items()}
    values.update(start or {})
    solutions = [None, None, None]
    for stage, names in enumerate((SLAB_PARAMETERS, EDGE_PARAMETERS, GRID_PARAMETERS)):
        if stage in held:
            continue
        models, ranges = _models([r for r in results if r[-1] == stage], values)
        lo = np.array([BOUNDS[k][1] for k in names])
        hi = np.array([BOUNDS[k][2] for k in names])
        x0 = np.clip([values[k] for k in names], lo, hi)

        def residuals(x, names=names, models=models, ranges=ranges):
            trial = {**values, **dict(zip(names, x))}
            return np.concatenate([((p - sb) / wb).ravel()
                                   for p, sb, wb in _predict(models, ranges, trial)])

        # the edge term has local minima (a short reach with a large share, a long one with
        # a small share): from a few starts, the least cost
        starts = [x0] if stage != 1 else [x0] + [np.clip(x, lo, hi) for x in EDGE_STARTS]
        # the grid's depth moves the kernels' angle heights, rounded to HEIGHT_STEP: a
        # difference step that crosses a step
        step = 0.05 if stage == 2 else None
        sol = min((least_squares(residuals, x, bounds=(lo, hi), x_scale="jac",
                                 diff_step=step) for x in starts), key=lambda r: r.cost)
        values.update(zip(names, (float(v) for v in sol.x)))
        solutions[stage] = sol
    models, ranges = _models(results, values)
    errors = [float(np.median(np.abs(p / sb - 1))) for p, sb, _ in
              _predict(models, ranges, values)]
    return values, errors, solutions


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scattered", type=int, default=60_000,
                        help="scattered photons on the detector per case (default 60000)")
    parser.add_argument("--max-histories", type=int, default=4_000_000)
    parser.add_argument("--small-scattered", type=int, default=150_000,
                        help="the same for the bodies narrower than the field (default 150000)")
    parser.add_argument("--small-max-histories", type=int, default=8_000_000)
    parser.add_argument("--grid-scattered", type=int, default=150_000,
                        help="the same for the cases behind a grid (default 150000)")
    parser.add_argument("--grid-max-histories", type=int, default=20_000_000)
    parser.add_argument("--cache", default=None, help="npz of the transport results")
    parser.add_argument("--slab-parameters", default=None,
                        help="a calibration file whose slab parameters are held")
    parser.add_argument("--edge-parameters", default=None,
                        help="a calibration file whose edge parameters are held")
    parser.add_argument("--out", default=str(ROOT / "xray_viz" / "data" / "scatter_kernel.json"))
    args = parser.parse_args(argv)
    cases = calibration_cases()
    results = run_cases(cases, scattered=args.scattered, max_histories=args.max_histories,
                        cache=args.cache,
                        small=(args.small_scattered, args.small_max_histories),
                        gridded=(args.grid_scattered, args.grid_max_histories))
    t_mc = sum(r[6] for r in results)           # each case's transport and render, s
    start, held = {}, set()
    for stage, (path, names) in enumerate(((args.slab_parameters, SLAB_PARAMETERS),
                                           (args.edge_parameters, EDGE_PARAMETERS))):
        if path:
            # a previous calibration's file
            doc = json.loads(Path(path).read_text(encoding="utf-8"))["parameters"]
            start.update({k: doc[k] for k in names})
            held.add(stage)
    values, errors, sol = fit(results, start, held=held)
    from xray_viz.scatter_kernel import KernelModel, KernelParameters, PARAMETER_NAMES

    values = {k: values[k] for k in PARAMETER_NAMES}

    energies = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _, scene, *_ in results:
            energies.append(KernelModel.of(scene, parameters=KernelParameters(
                values, {"energy_kev": (0, 1e9)}, {})).energy_kev)
    try:
        commit = subprocess.run(["git", "rev-parse", "HEAD"], cwd=ROOT, capture_output=True,
                                text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        commit = "unknown"
    doc = {"parameters": values,
           # outward to 0.01 keV: the fit's own spectra inside the range
           "ranges": {"energy_kev": [math.floor(100 * min(energies)) / 100,
                                     math.ceil(100 * max(energies)) / 100],
                      "thickness_mm": [min(c[1] for c in cases), max(c[1] for c in cases)],
                      "field_mm": [min(c[2] for c in cases), max(c[2] for c in cases)],
                      "gap_mm": [min(c[3] for c in cases), max(c[3] for c in cases)]},
           "meta": {"date": datetime.datetime.now(datetime.timezone.utc).isoformat(
                        timespec="seconds"),
                    "commit": commit, "script": "benchmarks/calibrate_scatter_kernel.py",
                    "model": "scatter kernel superposition, two virtual-source cos^n kernels "
                             "(Ohnesorge 1999; Sun & Star-Lack 2010)",
                    "material": "Water, Liquid", "detector": f"{PIXELS}x{PIXELS} pixels, "
                    f"compared in {BIN}x{BIN} blocks", "sid_mm": SID,
                    "spectra": {k: v for k, v in SPECTRA.items()},
                    "histories": int(sum(r[5] for r in results)),
                    "transport_seconds": round(t_mc, 1),
                    "machine": f"{platform.machine()}, {os.cpu_count()} cores (shared)",
                    "cases": [{"case": r[0], "histories": r[5],
                               "median_abs_rel_error": round(err, 4)}
                              for r, err in zip(results, errors)],
                    "cost": [None if x is None else float(x.cost) for x in sol],
                    "evaluations": [None if x is None else int(x.nfev) for x in sol],
                    "slab_parameters_held_from": args.slab_parameters,
                    "edge_parameters_held_from": args.edge_parameters,
                    "stages": {"slabs wider than the field": list(SLAB_PARAMETERS),
                               "bodies narrower than the field": list(EDGE_PARAMETERS),
                               "behind the default grid": list(GRID_PARAMETERS)}}}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    Path(args.out).write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    for r, err in zip(results, errors):
        print(f"{r[0]}: median |rel. error| {err:.3f}")
    print(json.dumps(values, indent=1))
    print(f"wrote {args.out}: {doc['meta']['histories']} histories, transport {t_mc:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""DiffDRR's Siddon renderer on the CPU beside the exact voxel DRR and RTK, same CT (issue 40).

The synthetic 512 x 512 x 133 chest CT of ``benchmarks/voxels.py`` (:func:`synthetic_ct`,
0.7 x 0.7 x 2.5 mm voxels), its densities from :func:`xray_viz.volume.ct_volume` and the same
512 x 512 DRR geometry (:func:`drr_scene`: a point source at y = +600 mm, the detector centre
at y = -400 mm, SID 1000 mm, 0.859 mm pixels, up = +z) rendered three ways, paired in rounds
(ours, DiffDRR, RTK, ours, DiffDRR, RTK, ...) after one warm-up each:

- xray_viz's exact voxel traversal (this process, numba, every core);
- DiffDRR's ``DRR(..., renderer="siddon")`` on the CPU (``torch.set_num_threads(--threads)``),
  in its own interpreter (a venv with diffdrr, the ``bench`` extra) started by this script as
  a worker: the volume and the rays are exchanged as ``.npy`` files in ``--data``, the timings
  over a pipe; the worker imports no part of xray_viz;
- RTK's CPU Joseph projector (``--rtk``; this process, as in ``benchmarks/voxels.py``).

DiffDRR's conventions, matched rather than assumed: the volume is given with xray_viz's affine
(voxel centres, ``read(..., orientation="AP")``; its centring moves nothing: the affine is
centred on the origin already); the pose is DiffDRR's ``euler_angles`` / ``ZXY`` with zero
rotation and the translation ``(0, 600, 0)`` (its AP frame puts the source on +y, rows along
-z, columns from +x to -x with ``reverse_x_axis=True``), ``sdd = 1000``, ``delx`` our pitch; the
worker checks that DiffDRR's source and 512 x 512 target points (``drr.detector(pose)``) are
xray_viz's ray origins and pixel points, and prints the largest difference in mm. Units:
DiffDRR integrates its ``density`` buffer times mm; the worker renders (a) with that buffer
replaced by xray_viz's density per voxel (g/cm^3, the same numbers as ours: the timed case)
and (b) once with DiffDRR's own HU -> [0, 1] mapping (``read`` of the HU), compared by
correlation only.

Usage::

    PYTHONPATH=. python benchmarks/voxels_diffdrr.py --python /tmp/ddrr/bin/python
        [--repeat 5] [--rtk] [--threads 2] [--patch 128] [--data /tmp/voxels_diffdrr]

``--patch P`` is DiffDRR's ``patch_size`` (the image rendered in ``(512 / P)^2`` pieces in
series; its whole-image Siddon holds ~1,160 float32 plane crossings per ray and several
intermediates of that size, ~10 GB at 512 x 512); ``--patch 0``: the whole image at once.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
import warnings
from pathlib import Path

import numpy as np

SOURCE_Y, DETECTOR_Y = 600.0, -400.0


def _worker(args):
    """The DiffDRR side (its own venv): load the exchange folder, render, answer ``time``."""
    import torch
    from diffdrr.data import read
    from diffdrr.drr import DRR
    from torchio import ScalarImage

    torch.set_num_threads(args.threads)
    d = Path(args.data)
    meta = json.loads((d / "meta.json").read_text())
    affine = np.load(d / "affine.npy")
    density = np.load(d / "density.npy")
    n, pitch, sdd = meta["pixels"], meta["pitch"], meta["sdd"]
    patch = args.patch or None

    def make(volume_hu, density_override=None):
        subject = read(ScalarImage(tensor=torch.from_numpy(volume_hu)[None], affine=affine),
                       orientation="AP")
        drr = DRR(subject, sdd=sdd, height=n, delx=pitch, renderer="siddon", patch_size=patch)
        if density_override is not None:
            drr.density = torch.from_numpy(density_override)
        return drr

    # the timed renderer: DiffDRR's volume, its density buffer holding xray_viz's densities
    # (read() wants HU: the densities stand in for them there, then the buffer is replaced)
    drr = make(density, density)
    rot = torch.zeros(1, 3)
    tra = torch.tensor([[0.0, meta["source_y"], 0.0]])
    from diffdrr.pose import convert

    pose = convert(rot, tra, parameterization="euler_angles", convention="ZXY")
    src, tgt = drr.detector(pose, None)
    ours_src = np.load(d / "ray_source.npy")
    ours_tgt = np.load(d / "ray_targets.npy")
    dev_s = float(np.abs(src[0, 0].double().numpy() - ours_src).max())
    dev_t = float(np.abs(tgt[0].double().numpy() - ours_tgt).max())
    print(f"diffdrr {__import__('diffdrr').__version__}, torch {torch.__version__}, "
          f"{torch.get_num_threads()} threads, patch_size {patch}; source and {len(ours_tgt)} "
          f"pixel points against xray_viz's: largest difference {dev_s:.2e} / {dev_t:.2e} mm",
          flush=True)

    def render():
        with torch.no_grad():
            return drr(rot, tra, parameterization="euler_angles", convention="ZXY")

    t0, c0 = time.perf_counter(), time.process_time()
    img = render()
    print(f"DiffDRR first run: {time.perf_counter() - t0:.2f} s wall, "
          f"{time.process_time() - c0:.2f} s CPU", flush=True)
    np.save(d / "diffdrr_density.npy", img[0, 0].double().numpy())
    # (b) DiffDRR's own HU -> density mapping, once, for the correlation
    own = make(np.load(d / "hu.npy"))
    with torch.no_grad():
        img_hu = own(rot, tra, parameterization="euler_angles", convention="ZXY")
    np.save(d / "diffdrr_hu.npy", img_hu[0, 0].double().numpy())
    del own, img_hu
    print("READY", flush=True)
    for line in sys.stdin:
        if line.strip() != "time":
            break
        t0, c0 = time.perf_counter(), time.process_time()
        render()
        print(f"TIME {time.perf_counter() - t0:.6f} {time.process_time() - c0:.6f}",
              flush=True)
    return 0


def _read_until(proc, key):
    """Lines of the worker until one starting with ``key`` (echoing the others)."""
    for line in proc.stdout:
        if line.startswith(key):
            return line.split()[1:]
        print("  [diffdrr]", line.rstrip(), flush=True)
    raise SystemExit(f"the DiffDRR worker ended before {key!r} (exit {proc.wait()}); its "
                     f"errors are above")


def _stats(label, wall, cpu):
    print(f"{label:44s} median {statistics.median(wall):7.3f} s wall, "
          f"{statistics.median(cpu):7.3f} s CPU; runs {[round(x, 3) for x in wall]}", flush=True)


def _compare(label, ref, img):
    peak = ref.max()
    diff = img - ref
    print(f"  {label}: RMS difference {np.sqrt((diff ** 2).mean()) / peak:.2e} of ours' peak, "
          f"largest {np.abs(diff).max() / peak:.2e}, sums {img.sum() / ref.sum() - 1:+.2e}, "
          f"correlation {np.corrcoef(ref.ravel(), img.ravel())[0, 1]:.6f}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("mode", nargs="?", choices=("driver", "worker"), default="driver")
    p.add_argument("--python", default="/tmp/ddrr/bin/python",
                   help="the interpreter of a venv holding diffdrr and torch")
    p.add_argument("--data", default="/tmp/voxels_diffdrr")
    p.add_argument("--shape", type=int, nargs=3, default=(512, 512, 133))
    p.add_argument("--detector", type=int, default=512)
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--threads", type=int, default=2, help="torch threads (DiffDRR)")
    p.add_argument("--patch", type=int, default=128, help="DiffDRR's patch_size; 0: none")
    p.add_argument("--rtk", action="store_true", help="RTK's Joseph projector too")
    args = p.parse_args(argv)
    if args.mode == "worker":
        return _worker(args)

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from voxels import drr_scene, synthetic_ct

    from xray_viz import _threads
    from xray_viz.geometry import detector_rays
    from xray_viz.volume import ct_volume

    d = Path(args.data)
    d.mkdir(parents=True, exist_ok=True)
    print(f"load average {os.getloadavg()}", flush=True)
    hu, affine = synthetic_ct(tuple(args.shape))
    vol = ct_volume(hu, affine, name="ct")
    scene = drr_scene(args.detector)
    rays = detector_rays(scene)
    pitch = float(scene.detector.pitch[0])
    assert np.allclose(scene.source.position, [0, SOURCE_Y, 0])
    assert np.allclose(scene.detector.center, [0, DETECTOR_Y, 0])
    np.save(d / "hu.npy", hu.astype(np.float32))
    np.save(d / "density.npy", np.ascontiguousarray(vol.weights, dtype=np.float32))
    np.save(d / "affine.npy", affine)
    np.save(d / "ray_source.npy", rays.origins[0])
    np.save(d / "ray_targets.npy", rays.origins + rays.directions * rays.t_max[:, None])
    (d / "meta.json").write_text(json.dumps({
        "pixels": args.detector, "pitch": pitch, "sdd": SOURCE_Y - DETECTOR_Y,
        "source_y": SOURCE_Y}))
    print(f"CT {hu.shape}, voxels {np.diag(affine)[:3].tolist()} mm, detector {args.detector}^2 "
          f"of {pitch} mm, SID {SOURCE_Y - DETECTOR_Y} mm -> {d}", flush=True)
    worker = subprocess.Popen(
        [args.python, str(Path(__file__).resolve()), "worker", "--data", str(d),
         "--threads", str(args.threads), "--patch", str(args.patch)],
        stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)

    def ours():
        r = detector_rays(scene)
        return vol.trace(r.origins, r.directions, r.t_max, across=scene.acquisition.frame.ho)

    t0 = time.perf_counter()
    L = ours()
    print(f"xray_viz first run: {time.perf_counter() - t0:.2f} s "
          f"({_threads.count()} threads)", flush=True)
    mine = L.sum(axis=1).reshape(args.detector, args.detector)
    rtk = None
    if args.rtk:
        from xray_viz.orbit import Orbit
        from xray_viz.reconstruct import rtk_forward_project
        from xray_viz.scan import scan_geometry

        geometry = scan_geometry(scene, Orbit(projections=1, axis=[0, 0, 1], center=[0, 0, 0]))
        density = vol.weights.astype(np.float32)

        def rtk():
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                return rtk_forward_project(density, affine, geometry)

        t0 = time.perf_counter()
        R = rtk()
        print(f"RTK first run: {time.perf_counter() - t0:.2f} s", flush=True)
    _read_until(worker, "READY")
    print(f"load average {os.getloadavg()} (timed rounds start)", flush=True)
    times = {"ours": ([], []), "diffdrr": ([], []), "rtk": ([], [])}
    for _ in range(args.repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        ours()
        times["ours"][0].append(time.perf_counter() - t0)
        times["ours"][1].append(time.process_time() - c0)
        worker.stdin.write("time\n")
        worker.stdin.flush()
        w, c = map(float, _read_until(worker, "TIME"))
        times["diffdrr"][0].append(w)
        times["diffdrr"][1].append(c)
        if rtk is not None:
            t0, c0 = time.perf_counter(), time.process_time()
            rtk()
            times["rtk"][0].append(time.perf_counter() - t0)
            times["rtk"][1].append(time.process_time() - c0)
    worker.stdin.write("quit\n")
    worker.stdin.close()
    worker.wait()
    print(f"load average {os.getloadavg()} (timed rounds end)")
    _stats("xray_viz voxels (exact)", *times["ours"])
    _stats("DiffDRR Siddon (CPU)", *times["diffdrr"])
    if rtk is not None:
        _stats("RTK Joseph (CPU)", *times["rtk"])
    for k in ("diffdrr", "rtk"):
        if times[k][0]:
            ratio = [a / b for a, b in zip(times[k][0], times["ours"][0])]
            print(f"{k} / xray_viz wall, per round: median {statistics.median(ratio):.2f} "
                  f"{[round(x, 2) for x in ratio]}")
    dd = np.load(d / "diffdrr_density.npy")
    print(f"images ({args.detector} x {args.detector}, density x mm; ours' peak {mine.max():.2f}):")
    _compare("DiffDRR (our densities) vs xray_viz", mine, dd)
    if rtk is not None:
        _compare("RTK Joseph vs xray_viz", mine, R[0].astype(np.float64))
    own = np.load(d / "diffdrr_hu.npy")
    a, b = np.polyfit(own.ravel(), mine.ravel(), 1)
    print(f"  DiffDRR's own HU mapping vs xray_viz: correlation "
          f"{np.corrcoef(mine.ravel(), own.ravel())[0, 1]:.5f}; after the best line "
          f"({a:.4g} x + {b:.4g}) RMS {np.sqrt(((a * own + b - mine) ** 2).mean()) / mine.max():.4f}"
          f" of ours' peak")
    np.save(d / "xray_viz.npy", mine)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

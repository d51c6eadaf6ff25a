"""A DRR of a CT traced as voxels, side by side with RTK's CPU forward projector (issue 40).

A synthetic chest CT in HU (:func:`synthetic_ct`: 512 x 512 x 133 voxels of 0.7 x 0.7 x
2.5 mm, an ellipse of soft tissue with a fat rim, two lungs, a heart and a liver of their own
HU, a spine and ribs of bone, 10 HU of noise) is classified and given densities by
:func:`xray_viz.volume.ct_volume`, and its 512 x 512 DRR (point source, SID 1000 mm) is traced
by :func:`xray_viz.tracing.voxels.voxel_sums`: the geometry once for every class. RTK's
``JosephForwardProjectionImageFilter`` (CPU, itk-rtk; bilinear interpolation between planes
of voxel centres) projects the same grid (one float32 value per voxel: the density) onto
the same detector in the same process (:func:`xray_viz.reconstruct.rtk_forward_project`).
Both use every core. Medians of ``--repeat`` runs after one warm-up (numba's compile, RTK's
first run).

Usage::

    PYTHONPATH=. python benchmarks/voxels.py [--shape 512 512 133] [--detector 512]
        [--repeat 3] [--write-scene DIR]

``--write-scene DIR`` also writes the CT (``ct.nii``), a titanium pedicle screw in the
vertebral body (``screw.stl``, touching its bone) and ``scene.toml`` for ``xray-viz render``.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
import warnings
from pathlib import Path

import numpy as np


def synthetic_ct(shape=(512, 512, 133), spacing=(0.7, 0.7, 2.5), *, seed=0):
    """A synthetic chest CT in HU, float32, and its affine (RAS, centred on the origin).

    x: patient left-right, y: anterior (+) - posterior, z: superior. Organs: body ellipse
    (soft tissue 40 HU, 12 mm of fat at -100 HU under the skin), lungs (-820 HU with
    vessels), heart (45 HU), liver (60 HU, low in the volume), a spine (vertebral bodies of
    cancellous bone 250 HU in a 1000 HU cortical shell, discs 80 HU) and ribs (700 HU),
    air outside (-1000 HU), noise 10 HU.
    """
    rng = np.random.default_rng(seed)
    nx, ny, nz = shape
    sx, sy, sz = spacing
    x = (np.arange(nx) - (nx - 1) / 2) * sx
    y = (np.arange(ny) - (ny - 1) / 2) * sy
    z = (np.arange(nz) - (nz - 1) / 2) * sz
    X, Y = np.meshgrid(x, y, indexing="ij")
    hu = np.full(shape, -1000.0, np.float32)
    body = (X / 165.0) ** 2 + (Y / 115.0) ** 2 <= 1.0
    inner = (X / 153.0) ** 2 + (Y / 103.0) ** 2 <= 1.0
    lungs = [((X - sgn * 72.0) / 55.0) ** 2 + ((Y + 5.0) / 70.0) ** 2 for sgn in (-1, 1)]
    heart = ((X + 20.0) / 48.0) ** 2 + ((Y - 25.0) / 40.0) ** 2
    spine_r = np.hypot(X, Y + 70.0)
    ring = np.hypot(X / 140.0, Y / 93.0)
    vessels = rng.normal(0, 1, (nx // 8 + 1, ny // 8 + 1))
    for k in range(nz):
        zk = z[k]
        s = np.where(body, -100.0, -1000.0)
        s[inner] = 40.0
        for lung in lungs:
            scale = 1.0 - 0.3 * (zk / (nz * sz / 2)) ** 2
            s[lung <= scale] = -820.0
        s[(heart <= 1.0) & (zk < 60)] = 45.0
        if zk < -40:                                     # the liver, under the diaphragm
            s[((X - 50.0) / 85.0) ** 2 + ((Y - 5.0) / 70.0) ** 2 <= 1.0] = 60.0
        disc = (zk % 28.0) < 5.0
        if disc:
            s[spine_r <= 17.0] = 80.0
        else:
            s[spine_r <= 17.0] = 1000.0
            s[spine_r <= 14.5] = 250.0
        ribs = (np.abs(ring - 1.0) < 0.035) & (np.cos(np.arctan2(Y, X) * 9 + zk / 15.0) > 0.3) \
            & (np.abs((zk % 24.0) - 12.0) < 5.0)
        s[ribs] = 700.0
        hu[:, :, k] = s
    # vessels in the lungs: a smooth random field, coarse
    from scipy.ndimage import zoom

    field = zoom(vessels, (nx / vessels.shape[0], ny / vessels.shape[1]), order=1)[:nx, :ny]
    lung_mask = hu < -700
    hu[lung_mask] += (np.maximum(field, 0.0)[:, :, None] * 120.0
                      * np.ones((1, 1, nz), np.float32))[lung_mask]
    hu += rng.normal(0, 10.0, shape).astype(np.float32)
    affine = np.diag([sx, sy, sz, 1.0])
    affine[:3, 3] = [x[0], y[0], z[0]]
    return hu, affine


def drr_scene(n_pixels, *, kind="point"):
    from xray_viz.scene import Detector, Scene, Source

    # antero-posterior: the source in front, the detector behind the patient's back
    pitch = 440.0 / n_pixels
    return Scene(source=Source(position=[0.0, 600.0, 0.0], kind=kind, energy=70.0),
                 detector=Detector(center=[0.0, -400.0, 0.0], up=[0.0, 0.0, 1.0],
                                   shape=(n_pixels, n_pixels), pitch=(pitch, pitch)))


def write_scene(folder: Path, hu, affine, n_pixels) -> Path:
    import nibabel as nib
    import trimesh

    folder.mkdir(parents=True, exist_ok=True)
    nib.save(nib.Nifti1Image(hu, affine), str(folder / "ct.nii"))
    screw = trimesh.creation.cylinder(radius=3.0, height=45.0, sections=48)
    # a pedicle screw: from the back, tilted 20 degrees, its tip in the vertebral body
    screw.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    screw.apply_transform(trimesh.transformations.rotation_matrix(np.radians(20), [0, 0, 1]))
    screw.apply_translation([8.0, -82.0, 0.0])
    screw.export(folder / "screw.stl")
    pitch = 440.0 / n_pixels
    (folder / "scene.toml").write_text(f"""# A synthetic chest CT traced as voxels, a titanium pedicle screw in a vertebra
[source]
position = [0.0, 600.0, 0.0]
spectrum = {{ kvp = 100.0, filters = {{ Al = 3.0 }} }}

[detector]
center = [0.0, -400.0, 0.0]
up = [0.0, 0.0, 1.0]
shape = [{n_pixels}, {n_pixels}]
pitch = {pitch}

[[body]]
name = "screw"
mesh = "screw.stl"
material = "Ti"
density = 4.5

[[ct]]
file = "ct.nii"
# trace = "voxels" is the default for a CT
""")
    return folder / "scene.toml"


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--shape", type=int, nargs=3, default=(512, 512, 133))
    p.add_argument("--detector", type=int, default=512)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--write-scene", type=Path, default=None)
    p.add_argument("--no-rtk", action="store_true")
    args = p.parse_args(argv)

    from xray_viz import _threads
    from xray_viz.geometry import detector_rays
    from xray_viz.volume import ct_volume

    t = time.perf_counter()
    hu, affine = synthetic_ct(tuple(args.shape))
    print(f"synthetic CT {hu.shape}: {time.perf_counter() - t:.1f} s")
    if args.write_scene:
        print("scene:", write_scene(args.write_scene, hu, affine, args.detector))
    t = time.perf_counter()
    vol = ct_volume(hu, affine, name="ct")
    print(f"classes and densities: {time.perf_counter() - t:.2f} s, "
          f"{(vol.classes.nbytes + vol.weights.nbytes) / 2**20:.0f} MiB")
    scene = drr_scene(args.detector)
    print(f"machine: {platform.processor() or platform.machine()}, "
          f"{len(os.sched_getaffinity(0))} cores, threads {_threads.count()}")

    def ours():
        rays = detector_rays(scene)
        return vol.trace(rays.origins, rays.directions, rays.t_max,
                         across=scene.acquisition.frame.ho)

    def time_it(fn):
        t0 = time.perf_counter()
        fn()                                            # warm-up: compile, first run
        print(f"  first run (compile or cache load, the axis-order copy): "
              f"{time.perf_counter() - t0:.2f} s")
        times = []
        for _ in range(args.repeat):
            t0 = time.perf_counter()
            out = fn()
            times.append(time.perf_counter() - t0)
        return statistics.median(times), times, out

    med, times, L = time_it(ours)
    print(f"xray_viz voxels (exact, {len(vol.materials)} classes at once): median {med:.3f} s "
          f"{[round(x, 3) for x in times]}")
    if args.no_rtk:
        return
    from xray_viz.orbit import Orbit
    from xray_viz.reconstruct import rtk_forward_project
    from xray_viz.scan import scan_geometry

    geometry = scan_geometry(scene, Orbit(projections=1, axis=[0, 0, 1], center=[0, 0, 0]))
    density = vol.weights.astype(np.float32)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        med_r, times_r, R = time_it(lambda: rtk_forward_project(density, affine, geometry))
    print(f"RTK Joseph (CPU, one value per voxel): median {med_r:.3f} s "
          f"{[round(x, 3) for x in times_r]}")
    ours_density = L.sum(axis=1).reshape(args.detector, args.detector)
    theirs = R[0].astype(np.float64)
    peak = ours_density.max()
    print(f"ratio RTK / xray_viz: {med_r / med:.2f}; images: RMS difference "
          f"{np.sqrt(((theirs - ours_density) ** 2).mean()) / peak:.4f} of the peak, sums "
          f"{theirs.sum() / ours_density.sum() - 1:+.4f}")


if __name__ == "__main__":
    main()

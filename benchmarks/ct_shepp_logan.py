"""CT reconstruction: Shepp-Logan (BENCHMARKS.md). Scans the bundled shepp_logan phantom on a
circular orbit about its vertical axis, reconstructs it with RTK's FDK
(:func:`xray_viz.reconstruct`), prints the mean mu inside each eroded ellipsoid against the
truth, and writes benchmarks/ct_shepp_logan.png (central slices beside the truth).

    python benchmarks/ct_shepp_logan.py [N N_PROJECTIONS DETECTOR]      # default 64 180 128

The scan and the measurement are tests/reconstruct/test_reconstruct.py's ``shepp_logan_validation``.
"""

import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE.parent / "tests" / "_support")]   # tests.*, helpers
warnings.simplefilter("ignore", DeprecationWarning)       # ITK's SWIG load-time warning


def truth_volume(vol):
    """mu (1/cm) of the exact ellipsoids at the voxel centres (the renderer's precedence)."""
    import tests.reconstruct.test_reconstruct as t
    import xray_viz
    from xray_viz.physics.imaging import body_mu

    scene = xray_viz.load_scene("shepp_logan")
    mu = body_mu(scene, [scene.source.energy])[0]
    suites = t._suites()
    ells = suites.shepp_logan_ellipsoids()
    rank = suites.ellipsoid_precedence(ells)
    z, y, x = np.meshgrid(vol.centers(2), vol.centers(1), vol.centers(0), indexing="ij")
    pts = np.stack([x, y, z], -1)
    out = np.zeros(x.shape)
    best = np.full(x.shape, -1)
    for b, (_, A, c) in enumerate(ells):
        u = (pts - c) @ np.linalg.inv(A)
        inside = (np.einsum("...i,...i", u, u) < 1) & (rank[b] > best)
        out[inside], best[inside] = mu[b], rank[b]
    return out


def main(argv):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import tests.reconstruct.test_reconstruct as t

    n, n_proj, det = (int(a) for a in argv) if argv else (64, 180, 128)
    t0 = time.perf_counter()
    result, vol, _ = t.shepp_logan_validation(n, n_proj, det)
    seconds = time.perf_counter() - t0
    print(f"{n}^3 voxels of {vol.spacing[0]:.2f} mm, {n_proj} projections of {det}^2: "
          f"{seconds:.0f} s (scan + FDK)")
    print("| ellipsoid | truth mu (1/cm) | mean reconstructed | error | voxels |")
    print("|---|---|---|---|---|")
    brain = result["brain"][0]
    for name, (truth, mean, count) in result.items():
        if count == 0:
            print(f"| {name} | {truth:.5f} | (no voxel left after erosion) | | 0 |")
            continue
        rel = (f"{(mean - truth) / truth * 100:+.2f} %" if truth > 0.01 * brain else
               f"{(mean - truth) / brain * 100:+.2f} % of brain mu")
        print(f"| {name} | {truth:.5f} | {mean:.5f} | {rel} | {count} |")
    truth = truth_volume(vol)
    fig, axes = plt.subplots(2, 2, figsize=(9, 8.6), constrained_layout=True)
    ext = lambda a, b: [vol.centers(a)[0], vol.centers(a)[-1], vol.centers(b)[0],  # noqa: E731
                        vol.centers(b)[-1]]
    ky = int(np.argmin(np.abs(vol.centers(1) - (-25.0))))   # through the ventricles and tumour
    kx = n // 2
    for row, (img, title) in enumerate(((truth, "truth"), (vol.mu, "FDK (RTK)"))):
        for col, (sl, e, lab) in enumerate(((img[:, ky, :], ext(0, 2), ("x (mm)", "z (mm)")),
                                            (img[:, :, kx], ext(1, 2), ("y (mm)", "z (mm)")))):
            ax = axes[row, col]
            im = ax.imshow(sl, origin="lower", extent=e, cmap="gray", vmin=0.17, vmax=0.32)
            ax.set_title(f"{title}: {'y = %.0f mm' % vol.centers(1)[ky] if col == 0 else 'x = %.0f mm' % vol.centers(0)[kx]}")
            ax.set_xlabel(lab[0])
            ax.set_ylabel(lab[1])
    fig.colorbar(im, ax=axes, shrink=0.6, label="mu (1/cm), window 0.17-0.32")
    fig.suptitle(f"Shepp-Logan, 60 keV: {n}^3 voxels, {n_proj} projections of {det}^2, "
                 "circular cone-beam orbit about y")
    out = HERE / "ct_shepp_logan.png"
    fig.savefig(out, dpi=80)
    print(f"wrote {out}")


if __name__ == "__main__":
    main(sys.argv[1:])

"""CT reconstruction of a few-view scan (BENCHMARKS.md): the bundled shepp_logan head scanned
with few views about its vertical axis, reconstructed by RTK's FDK, SART and conjugate
gradient (:func:`xray_viz.reconstruct`); prints the RMSE against the partial-volume truth inside
the head and outside it, and writes benchmarks/ct_few_view.png (a slice of each beside the truth).

    python benchmarks/ct_few_view.py [N VIEWS DETECTOR]      # default 48 16 64

The scan and the measure are tests/reconstruct/test_reconstruct_iterative.py's.
"""

import sys
import time
import warnings
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent), str(HERE.parent / "tests" / "_support")]   # tests.*, helpers
warnings.simplefilter("ignore", DeprecationWarning)       # ITK's SWIG load-time warning

METHODS = [("fdk", None), ("sart", 20), ("cg", 10)]


def main(argv):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import tests.reconstruct.test_reconstruct_iterative as t

    n, views, det = (int(a) for a in argv) if argv else (48, 16, 64)
    t0 = time.perf_counter()
    truth, vols = t.few_view_shepp_logan(n, views, det, METHODS)
    print(f"{n}^3 voxels of {205 / n:.2f} mm, {views} views of {det}^2: "
          f"{time.perf_counter() - t0:.0f} s (scan + {len(METHODS)} reconstructions)")
    support = truth > 0
    print("| method | iterations | RMSE inside the head (1/cm) | RMSE outside (1/cm) |")
    print("|---|---|---|---|")
    for m, it in METHODS:
        print(f"| {m} | {it or '-'} | {t.rmse(vols[m], truth, support):.4f} | "
              f"{t.rmse(vols[m], truth, ~support):.4f} |")
    vol = vols["fdk"]
    ky = int(np.argmin(np.abs(vol.centers(1) - (-25.0))))   # through the ventricles and tumour
    e = [vol.centers(0)[0], vol.centers(0)[-1], vol.centers(2)[0], vol.centers(2)[-1]]
    fig, axes = plt.subplots(1, 4, figsize=(15, 4.2), constrained_layout=True)
    panels = [(truth, "truth (partial volume)")] + [
        (vols[m].mu, f"{m.upper()}" + (f", {it} iterations" if it else "")) for m, it in METHODS]
    for ax, (img, title) in zip(axes, panels):
        im = ax.imshow(img[:, ky, :], origin="lower", extent=e, cmap="gray", vmin=0.17,
                       vmax=0.32)
        ax.set_title(f"{title}\ny = {vol.centers(1)[ky]:.0f} mm")
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("z (mm)")
    fig.colorbar(im, ax=axes, shrink=0.8, label="mu (1/cm)")
    fig.suptitle(f"Shepp-Logan head, {views} views: FDK streaks, the iterative methods less")
    out = HERE / "ct_few_view.png"
    fig.savefig(out, dpi=80)
    print(out)


if __name__ == "__main__":
    main(sys.argv[1:])

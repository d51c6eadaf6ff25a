"""SPR maps: the transport's and the scatter kernel model's, for six held-out cases.

Reads the transport images cached by ``benchmarks/scatter_kernel_accuracy.py --cache FILE``
and draws, for the held-out water slab, the bone layer in water, the aluminium step wedge,
the frog, and two water slabs behind grids (the default one and a 12:1 grid the fit did not
see), the transport's SPR, the model's (given the path lengths per body) and their ratio
over the same blocks, into ``benchmarks/scatter_kernel_spr.png``.

Usage::

    PYTHONPATH=$PWD .venv/bin/python benchmarks/scatter_kernel_maps.py /tmp/skacc_v2.npz
"""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import scatter_kernel_accuracy as acc  # noqa: E402


def main(argv=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cache = (argv or sys.argv[1:])[0]
    store = dict(np.load(cache))
    wanted = ("water 150 mm, field 250 mm, gap 100 mm, 100 kVp",
              "bone 20 mm in water 150 mm, field 200 mm, gap 50 mm, 90 kVp",
              "step_wedge (Al), 60 keV", "frog (15 tissues), 60 keV",
              "water 150 mm, field 250 mm, gap 100 mm, 100 kVp, default grid",
              "water 180 mm, field 300 mm, gap 40 mm, 100 kVp, grid 12:1, 70 lines/cm, "
              "focused at 1500 mm")
    fig, axes = plt.subplots(len(wanted), 3, figsize=(11, 3.5 * len(wanted)),
                             constrained_layout=True)
    for row, (label, make) in zip(axes, [c for c in acc.held_out() if c[0] in wanted]):
        key = acc.cached(store, label)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            sb, pb, eb, tb, _ = acc.compare(make(), store[key + "|s"], store[key + "|e"],
                                            store[key + "|l"])
        hi = max((sb / tb).max(), (pb / tb).max())
        for ax, img, title in ((row[0], sb / tb, "transport SPR"),
                               (row[1], pb / tb, "model SPR")):
            im = ax.imshow(img, vmin=0, vmax=hi, cmap="viridis")
            name = label.split(", ")[0] + (", grid" if "grid" in label else "")
            ax.set_title(f"{name}\n{title}", fontsize=8)
            fig.colorbar(im, ax=ax, shrink=0.8)
        ok = eb / sb < 0.02
        ratio = np.where(ok, pb / sb, np.nan)
        im = row[2].imshow(ratio, vmin=0.5, vmax=1.5, cmap="RdBu_r")
        row[2].set_title("model / transport (blocks with transport error < 2 %)", fontsize=8)
        fig.colorbar(im, ax=row[2], shrink=0.8)
    out = Path(__file__).resolve().parent / "scatter_kernel_spr.png"
    fig.savefig(out, dpi=80)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

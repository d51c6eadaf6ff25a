"""The transport against AAPM TG-195's four codes: a Markdown table for BENCHMARKS.md.

Run from the repository root::

    python benchmarks/tg195_table.py [--case2 N] [--case3 N] [--seed S]

Case 1: air kerma behind the Al filters and the HVL/QVL ratios (narrow beam, the transport's
own attenuation tables); cases 2 and 3 (radiography): energy deposited, eV per history, by
:func:`xray_viz.transport` with N histories. Columns: ours, our standard error, the four
codes' mean (the median at 16.8 keV, where PENELOPE is off), their spread, our deviation, and
the issue's tolerance max(2 %, 2 x spread) + 3 SE.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "_support"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case2", type=int, default=10_000_000)
    ap.add_argument("--case3", type=int, default=4_000_000)
    ap.add_argument("--seed", type=int, default=2015)
    args = ap.parse_args()
    import xray_viz
    from tg195 import (case1_kermas, case2_scene, case3_scene, case3_total_body, reference,
                       total_body)

    print("| case | source | volume | ours | SE | four codes | spread % | ours - ref | "
          "tolerance |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|")
    for label in ("30 keV", "100 keV", "30 kVp", "100 kVp"):
        k = case1_kermas(label)
        for name, v in k.items():
            ref = reference("1", name, label)
            m = float(ref["mean"])
            print(f"| 1 | {label} | kerma, {name} | {v:.6g} | - | {m:.6g} | {ref['spread_pct']} "
                  f"| {100 * (v / m - 1):+.2f} % | 0.3 % |")
        for ratio, filt in (("HVL ratio", "HVL filter"), ("QVL ratio", "QVL filter")):
            ref = reference("1", ratio, label)
            v = k[filt] / k["no filter"]
            print(f"| 1 | {label} | {ratio} | {v:.5f} | - | {float(ref['mean']):.5f} | "
                  f"{ref['spread_pct']} | {v - float(ref['mean']):+.5f} | 0.002 |")
    runs = [("2", lab, case2_scene, args.case2, total_body, 10)
            for lab in ("56.4 keV", "120 kVp")]
    runs += [("3", lab, case3_scene, args.case3, case3_total_body, 8)
             for lab in ("16.8 keV", "30 kVp")]
    for case, label, build, n, whole, n_voi in runs:
        t0 = time.process_time()
        result = xray_viz.transport(build(label), n, seed=args.seed)
        cpu = time.process_time() - t0
        rows = [("Total body",) + whole(result)]
        rows += [(f"VOI {k}", result.energy[f"VOI {k}"], result.energy_error[f"VOI {k}"])
                 for k in range(1, n_voi)]
        for name, v, se in rows:
            ref = reference(case, name, label)
            m = float(ref["median" if label == "16.8 keV" else "mean"])
            spread = float(ref["spread_pct"])
            tol = max(0.02 * m, 2 * spread / 100 * m) + 3 * se
            flag = "" if abs(v - m) < tol else " **out**"
            print(f"| {case} | {label} | {name} | {v:.5g} | {se:.2g} | {m:.5g} | {spread:.2f} | "
                  f"{100 * (v / m - 1):+.2f} %{flag} | {100 * tol / m:.1f} % |")
        print(f"<!-- case {case} {label}: {n:.3g} histories, {cpu:.0f} s CPU -->")


if __name__ == "__main__":
    main()

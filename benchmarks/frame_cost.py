"""What a frame costs beyond the trace: the Scene, the image step, per frame (issue 18).

Usage::

    python benchmarks/frame_cost.py [-n FRAMES] [--cases ...] [--json]
    python benchmarks/frame_cost.py --compare BEFORE_TREE [--pairs 3]

Each case renders FRAMES frames of 512 x 512 (the phantoms at their own size), each a new
``Scene`` with the source moved by a micrometre (``scene.replace(source=...)``: the bodies and
their per-mesh set-up are kept, the path lengths are traced again) and ``xray_viz.render``.
Per case: medians of the whole frame (wall and CPU seconds, ``time.process_time``), of the
Scene construction, and of render's own ``timing`` split, ``trace`` (the engine) and
``image`` (Beer-Lambert, the pixel means, the detector model, the checks).

``--open3d`` times, interleaved frame by frame (A B A B, so both see the same load), the
one-body frames against Open3D's ``list_intersections`` plus the same path-length step on the
same rays (the peers suite's ``peer_open3d``, BVH built before), and prints the ratio of the
medians: issue 18's per-frame target (<= 0.10x at 82k and 1.3M faces).

``--compare`` runs this script in the tree given and in this one in turn, A B A B ... (new
processes, ``PYTHONPATH`` set to each tree), so that both see the same machine load, and
prints the medians over the pairs and the ratio after / before of each column.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

RADIUS = 40.0
TUBE = {"kvp": 80.0, "filters": {"Al": 2.5}}
CASES = ("sphere-82k", "sphere-1.3M", "frog", "frog-tube", "sphere-82k-tube", "sphere-82k-falloff",
         "sphere-82k-heel", "sphere-82k-ss2")


def _sphere(subdivisions):
    import trimesh

    from xray_viz.scene import Body, Detector, Scene, Source

    mesh = trimesh.creation.icosphere(subdivisions=subdivisions, radius=RADIUS)
    pitch = 2 * RADIUS * 1.5 / 0.8 / 511
    return Scene(source=Source(position=[0.0, 0.0, 1000.0]),
                 detector=Detector(center=[0.0, 0.0, -500.0], shape=(512, 512), pitch=pitch),
                 bodies=(Body(name="ball", mesh=mesh, mu=0.2),))


def scene_of(case):
    """The scene of a case name."""
    import xray_viz

    parts = case.split("-")
    if parts[0] == "sphere":
        scene = _sphere({"82k": 6, "1.3M": 8}[parts[1]])
        extra = parts[2:]
    else:
        scene = xray_viz.load_scene(parts[0])
        extra = parts[1:]
    if "tube" in extra or "heel" in extra:
        scene = scene.replace(source=dataclasses.replace(scene.source, spectrum=TUBE,
                                                         heel="heel" in extra))
    if "ss2" in extra:
        scene = scene.replace(detector=dataclasses.replace(scene.detector, supersample=2))
    if "falloff" in extra:
        scene = scene.replace(detector=dataclasses.replace(scene.detector, falloff=True,
                                                           i0=1e4))
    return scene


def frames(case, n):
    """Medians (ms) of ``n`` frames of a case (after one warm-up frame)."""
    import xray_viz

    base = scene_of(case)
    xray_viz.render(base)
    p0 = np.asarray(base.source.position, dtype=np.float64)
    rows = {k: [] for k in ("frame", "cpu", "scene", "trace", "image")}
    image = None
    for k in range(n):
        c0, t0 = time.process_time(), time.perf_counter()
        src = dataclasses.replace(base.source, position=p0 + [1e-3 * (k + 1), 0.0, 0.0])
        scene = base.replace(source=src)
        t1 = time.perf_counter()
        image = xray_viz.render(scene)
        t2 = time.perf_counter()
        rows["cpu"].append(time.process_time() - c0)
        rows["frame"].append(t2 - t0)
        rows["scene"].append(t1 - t0)
        rows["trace"].append(image.timing["trace"])
        rows["image"].append(image.timing["image"])
        del image
    return {k: 1e3 * statistics.median(v) for k, v in rows.items()}


def versus_open3d(case, n):
    """Medians (ms) of ``n`` render() frames and ``n`` Open3D queries, interleaved."""
    import xray_viz
    from xray_viz.geometry import detector_rays

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from suites import peer_open3d

    build, query = peer_open3d()
    base = scene_of(case)
    mesh = base.bodies[0].mesh
    rays = detector_rays(base)
    state = build(mesh)
    query(state, rays)                          # the BVH is built in the first query
    xray_viz.render(base)
    p0 = np.asarray(base.source.position, dtype=np.float64)
    ours, theirs = [], []
    for k in range(n):
        t0 = time.perf_counter()
        scene = base.replace(source=dataclasses.replace(
            base.source, position=p0 + [1e-3 * (k + 1), 0.0, 0.0]))
        image = xray_viz.render(scene)
        ours.append(time.perf_counter() - t0)
        del image
        t0 = time.perf_counter()
        query(state, rays)
        theirs.append(time.perf_counter() - t0)
    a, b = 1e3 * statistics.median(ours), 1e3 * statistics.median(theirs)
    return {"render": a, "open3d": b, "ratio": a / b}


def run(cases, n):
    return {case: frames(case, n) for case in cases}


def _table(results, before=None):
    cols = ("frame", "cpu", "scene", "trace", "image")
    head = "| case | " + " | ".join(f"{c} ms" for c in cols) + " |"
    lines = [head, "|---" * (len(cols) + 1) + "|"]
    for case, row in results.items():
        cells = []
        for c in cols:
            if before is None:
                cells.append(f"{row[c]:.2f}")
            else:
                b = before[case][c]
                cells.append(f"{b:.2f} -> {row[c]:.2f} ({row[c] / b:.2f}x)" if b > 0 else
                             f"{row[c]:.2f}")
        lines.append(f"| {case} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _child(tree, cases, n):
    env = dict(os.environ, PYTHONPATH=str(tree))
    out = subprocess.run([sys.executable, str(Path(__file__).resolve()), "-n", str(n),
                          "--cases", *cases, "--json"], env=env, cwd=str(tree),
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def _median_of(runs):
    return {case: {k: statistics.median(r[case][k] for r in runs) for k in runs[0][case]}
            for case in runs[0]}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=15, help="frames per case (default 15)")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=CASES)
    ap.add_argument("--json", action="store_true", help="print the medians as JSON")
    ap.add_argument("--compare", type=Path, help="a before-tree: run A B A B ...")
    ap.add_argument("--pairs", type=int, default=3)
    ap.add_argument("--open3d", action="store_true",
                    help="render() per frame against Open3D's query, interleaved")
    args = ap.parse_args(argv)
    if args.open3d:
        print(f"load average {os.getloadavg()[0]:.1f}")
        print("| case | render() ms | Open3D list_intersections + path length ms | ratio |")
        print("|---|---|---|---|")
        for case in ("sphere-82k", "sphere-1.3M"):
            r = versus_open3d(case, args.n)
            print(f"| {case} | {r['render']:.2f} | {r['open3d']:.2f} | {r['ratio']:.3f}x |")
        print(f"load average {os.getloadavg()[0]:.1f}")
        return 0
    if args.compare is not None:
        here = Path(__file__).resolve().parents[1]
        a, b = [], []
        for _ in range(args.pairs):
            a.append(_child(args.compare, args.cases, args.n))
            b.append(_child(here, args.cases, args.n))
        print(f"before: {args.compare}; after: {here}; {args.pairs} pairs A B, medians; "
              f"load average {os.getloadavg()[0]:.1f}")
        print(_table(_median_of(b), _median_of(a)))
        return 0
    results = run(args.cases, args.n)
    if args.json:
        print(json.dumps(results))
    else:
        print(_table(results))
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The fast engine's per-mesh set-up and one-body frame beside Open3D, optionally A/B against a
before-tree (issue 18).

Usage::

    python benchmarks/setup_frame.py [--before TREE] [--rounds 3] [-n 7]

Icospheres of 82k and 1.3M faces (the peers suite's meshes), 512 x 512, point source. Each round
runs one fresh process per tree (this one, then ``--before``: a checkout of the same project,
interleaved A B A B); a process measures, medians of ``-n`` runs, wall and CPU ms:

- *order*: the per-mesh spatial order alone (``_geometry`` after forgetting it);
- *set-up*: ``clear_caches`` then a first trace, minus a warm trace (the peers suite's figure:
  the order plus fresh scratch memory);
- *frame*: a trace of the same bodies with the source moved 1 um (``trace_once``);
- *Open3D build*: ``add_triangles`` + a first ``count_intersections`` minus a second one;
- *Open3D frame*: ``list_intersections`` and the signed path-length sum of the peers suite.

Ratios are ours over Open3D's measured in the same process.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
from pathlib import Path

CHILD = r'''
import dataclasses, json, statistics, sys, time
sys.path.insert(0, sys.argv[1] + "/benchmarks")
import numpy as np
from suites import peer_open3d, sphere_mesh, sphere_scene
from xray_viz.geometry import detector_rays
from xray_viz.scene import Body, Scene
from xray_viz.tracing import _raster as R, fast

assert fast.__file__.startswith(sys.argv[1]), fast.__file__     # the tree asked for
R.KERNELS.compile()
n = int(sys.argv[2])
try:
    import open3d as o3d
    build, query = peer_open3d()
except ImportError:
    o3d = None

def timed(f, n):
    ws, cs = [], []
    for _ in range(n):
        t, c = time.perf_counter(), time.process_time()
        f()
        ws.append(time.perf_counter() - t)
        cs.append(time.process_time() - c)
    return statistics.median(ws) * 1e3, statistics.median(cs) * 1e3

out = {}
for sub in (6, 8):
    mesh = sphere_mesh(sub)
    b = sphere_scene(mesh, (512, 512))
    scene = Scene(source=b.source, detector=b.detector,
                  bodies=(Body(name="ball", mesh=mesh, mu=0.2),))
    fast.trace_once(scene)

    def order():
        scene.bodies.forget(("fast", "prepared"))
        scene.bodies.forget(("fast", "geometry"))
        fast._geometry(scene.bodies, (0,))

    def cold():
        fast.clear_caches(scene)
        fast.trace_once(scene)
    k = iter(range(1, 10**6))

    def frame():
        src = dataclasses.replace(scene.source, position=[1e-3 * next(k), 0.0, 1000.0])
        fast.trace_once(scene.replace(source=src))
    warm = timed(lambda: fast.trace_once(scene), n)
    first = timed(cold, n)
    r = dict(order=timed(order, n), setup=[first[0] - warm[0], first[1] - warm[1]],
             frame=timed(frame, 3 * n))
    if o3d is not None:
        rays = detector_rays(scene)
        rt = o3d.core.Tensor(np.hstack([rays.origins, rays.directions]).astype(np.float32))
        state = build(mesh)
        builds = []
        for _ in range(3):
            s = o3d.t.geometry.RaycastingScene()
            s.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                            o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
            first = timed(lambda: s.count_intersections(rt), 1)
            again = timed(lambda: s.count_intersections(rt), 1)
            builds.append((first[0] - again[0], first[1] - again[1]))
        add = timed(lambda: build(mesh), 3)
        r["o3d build"] = [add[0] + statistics.median(x[0] for x in builds),
                          add[1] + statistics.median(x[1] for x in builds)]
        query(state, rays)
        r["o3d frame"] = timed(lambda: query(state, rays), n)
    out[len(mesh.faces)] = r
print(json.dumps(out))
'''


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--before", help="a before-tree (checkout) to measure interleaved")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("-n", type=int, default=7)
    ap.add_argument("--json", help="also write every process's figures to this file")
    args = ap.parse_args(argv)
    trees = {"after": str(Path(__file__).resolve().parents[1])}
    if args.before:
        trees["before"] = str(Path(args.before).resolve())
    res = {name: [] for name in trees}
    for _ in range(args.rounds):
        for name, tree in trees.items():
            p = subprocess.run([sys.executable, "-c", CHILD, tree, str(args.n)], text=True,
                               capture_output=True, cwd=tree,     # -c puts the cwd first on the path
                               env={"PYTHONPATH": tree, "PATH": "/usr/bin:/bin"})
            if p.returncode:
                sys.stderr.write(p.stderr)
                return 1
            res[name].append(json.loads(p.stdout.strip().splitlines()[-1]))
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))

    def med(name, faces, key):
        rows = [r[faces][key] for r in res[name] if key in r[faces]]
        return tuple(statistics.median(x[i] for x in rows) for i in (0, 1)) if rows else None
    print("medians over rounds, ms wall (CPU); ratio = ours / Open3D's of the same process")
    for faces in res["after"][0]:
        mf = int(faces) / 1e6
        print(f"{int(faces):,} faces")
        for name in trees:
            o_b, o_f = med(name, faces, "o3d build"), med(name, faces, "o3d frame")
            for key, peer in (("order", o_b), ("setup", o_b), ("frame", o_f)):
                w, c = med(name, faces, key)
                line = f"  {name:6s} {key:6s} {w:7.1f} ({c:7.1f})"
                if key != "frame":
                    line += f"  per Mface {w / mf:6.1f} ({c / mf:6.1f})"
                if peer:
                    line += f"  / Open3D {peer[0]:7.1f} ({peer[1]:7.1f}) = {w / peer[0]:.3f} " \
                            f"(CPU {c / peer[1]:.3f})"
                print(line)
    return 0


if __name__ == "__main__":
    sys.exit(main())

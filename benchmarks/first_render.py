"""First render of a never-seen mesh: the mesh checks and the engine's set-up against Open3D's
BVH build, per million faces (issue 18).

Usage::

    python benchmarks/first_render.py [--subdivisions 6 8] [-n RUNS]

Icospheres (82k and 1.3M faces), 512 x 512, point source. Per mesh, medians of RUNS:

- *checks*: :func:`xray_viz.meshes.repair.check_mesh` without its on-disk cache (what a mesh
  never seen before pays; the next load of the same file reads the stored report), with the
  compiled check kernels (:mod:`xray_viz.meshes._check_kernels`, compiled before timing) and,
  interleaved in the same run, *pymeshlab path*: the same checks while the kernels are not
  compiled (NumPy edge facts, pymeshlab's self-intersection filter: what main does);
- *set-up*: the fast engine's per-mesh set-up (Morton order, renumbering): a first trace after
  :func:`xray_viz.tracing.fast.clear_caches` minus a warm trace of the same scene;
- *Open3D build*: ``RaycastingScene.add_triangles`` and its first ``count_intersections`` on
  the same rays (the BVH is built on the first query) minus a second query.

Wall and CPU seconds (CPU: steadier on a shared machine). Open3D missing: its columns say so.
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
import sys
import time

import numpy as np


def _timed(f, runs):
    ts, cs = [], []
    for _ in range(runs):
        t, c = time.perf_counter(), time.process_time()
        f()
        ts.append(time.perf_counter() - t)
        cs.append(time.process_time() - c)
    return statistics.median(ts), statistics.median(cs)


def main(argv=None) -> int:
    import trimesh

    import xray_viz
    from xray_viz.meshes import _check_kernels
    from xray_viz.meshes.repair import check_mesh
    from xray_viz.tracing import fast

    _check_kernels.compile_kernels()

    def pymeshlab_path(m):
        ready = _check_kernels.is_ready
        _check_kernels.is_ready = lambda: False
        try:
            return check_mesh(m, cache=False)
        finally:
            _check_kernels.is_ready = ready

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--subdivisions", type=int, nargs="+", default=[6, 8])
    ap.add_argument("-n", type=int, default=3)
    args = ap.parse_args(argv)
    try:
        import open3d as o3d
    except ImportError:
        o3d = None
    base = xray_viz.load_scene("sphere")
    det = dataclasses.replace(base.detector, shape=(512, 512),
                              pitch=tuple(p / 2 for p in base.detector.pitch))
    print("per million faces, medians; wall s (CPU s)")
    for sub in args.subdivisions:
        m = trimesh.creation.icosphere(subdivisions=sub, radius=40.0)
        m = trimesh.Trimesh(m.vertices.copy(), m.faces.copy(), process=False)
        mf = len(m.faces) / 1e6
        assert check_mesh(m, cache=False) == pymeshlab_path(m)
        checks, old = [], []
        for _ in range(args.n):                       # interleaved: compiled, pymeshlab, ...
            checks.append(_timed(lambda: check_mesh(m, cache=False), 1))
            old.append(_timed(lambda: pymeshlab_path(m), 1))
        checks = tuple(statistics.median(c[k] for c in checks) for k in (0, 1))
        old = tuple(statistics.median(c[k] for c in old) for k in (0, 1))
        scene = base.replace(detector=det,
                             bodies=[dataclasses.replace(base.bodies[0], name="ball", mesh=m)])
        fast.trace_once(scene)
        warm = _timed(lambda: fast.trace_once(scene), args.n)

        def cold():
            fast.clear_caches(scene)
            fast.trace_once(scene)
        first = _timed(cold, args.n)
        setup = (first[0] - warm[0], first[1] - warm[1])
        line = (f"{len(m.faces):8d} faces: checks {checks[0] / mf:6.2f} ({checks[1] / mf:5.2f}) "
                f"[pymeshlab path {old[0] / mf:5.2f} ({old[1] / mf:5.2f}): "
                f"{checks[1] / old[1]:.2f}x CPU], "
                f"set-up {setup[0] / mf:6.3f} ({setup[1] / mf:5.3f}), trace {warm[0]:.4f} s")
        if o3d is not None:
            rays = scene.acquisition.rays()
            r = np.hstack([rays.origins, rays.directions]).astype(np.float32)
            rt = o3d.core.Tensor(r)

            def build():
                rs = o3d.t.geometry.RaycastingScene()
                rs.add_triangles(o3d.core.Tensor(np.asarray(m.vertices, np.float32)),
                                 o3d.core.Tensor(np.asarray(m.faces, np.uint32)))
                rs.count_intersections(rt)
                return rs
            rs = build()
            q = _timed(lambda: rs.count_intersections(rt), args.n)
            b = _timed(build, args.n)
            ob = (b[0] - q[0], b[1] - q[1])
            line += (f"; Open3D build {ob[0] / mf:6.3f} ({ob[1] / mf:5.3f}): checks + set-up = "
                     f"{(checks[0] + setup[0]) / ob[0]:.1f}x its build (CPU "
                     f"{(checks[1] + setup[1]) / ob[1]:.1f}x), set-up alone "
                     f"{setup[0] / ob[0]:.2f}x; first render (checks + set-up + trace) "
                     f"{checks[0] + setup[0] + warm[0]:.3f} s = "
                     f"{(checks[0] + setup[0] + warm[0]) / b[0]:.2f}x Open3D build + query "
                     f"{b[0]:.3f} s (CPU {(checks[1] + setup[1] + warm[1]) / b[1]:.2f}x)")
        else:
            line += "; Open3D not installed (pip install -e '.[bench]')"
        print(line, flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

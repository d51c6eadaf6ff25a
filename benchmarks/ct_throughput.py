"""CT scan throughput: projections per second, serial and on a Dask LocalCluster, against
gVirtualXray's CT acquisition of the same scene; and a simulated scaling curve for N workers.

Cases: the ``frog`` phantom (16 bodies, 173k faces) at 256^2 (pitch doubled: the same field
of view) and 512^2 (its own detector), and the 1.3M-face sphere of ``benchmarks/suites.py``
(icosphere of subdivision 8, radius 40 mm, ``sphere_scene``) at 512^2. Every scene is a scene
file (the sphere's mesh written to an STL first), as a Dask scan needs. Orbit: a circular
scan about the detector's up axis (:func:`xray_viz.scan.default_orbit`), fast engine, line
integrals.

Per case:

* serial, in this process: the scene loaded, then projection 0 (it pays the per-mesh set-up
  held by the scene's ``Bodies``) and projections 1..n-1 (steady state), with numba on 1
  thread (the per-task cost of a worker) and on every core; the Zarr write of one projection
  (chunk + ``done`` flag); ``xray_viz.scan(..., store=)`` end to end (numba on every core);
* Dask: ``xray_viz.scan(..., client=, store=)`` on a ``LocalCluster`` of ``--workers``
  processes (one thread, one numba thread each), twice on the same cluster: the first run's
  first task on each worker loads the scene (scene file text -> meshes -> per-mesh set-up),
  the second run finds it loaded. Per-task compute times from Dask's task stream;
* gVirtualXray (``gvxr``, OpenGL; Mesa llvmpipe on this machine): the same meshes, mu at
  60 keV, the same source/detector per projection, ``computeXRayImage``.

The Dask scheduler's per-task overhead is measured with no-op tasks. ``--plot`` then
simulates N = 1..64 workers (see :func:`simulate`) and draws ``benchmarks/ct_scaling.png``.

Usage::

    python benchmarks/ct_throughput.py [--projections 24] [--batch 4] [--workers 2]
    python benchmarks/ct_throughput.py --plot-only    # the plot from the last results JSON
    python benchmarks/ct_throughput.py --geometry 100000   # random-pose geometry build + store
"""

from __future__ import annotations

import argparse
import dataclasses
import importlib
import json
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
RESULTS = HERE / "results" / "ct_throughput.json"


def _median(xs):
    return float(statistics.median(xs)) if len(xs) else float("nan")


# ----------------------------------------------------------------------------- scenes

def _scene_files(tmp: Path) -> dict:
    """``{case: scene .toml path}``."""
    import xray_viz

    out = {}
    frog = xray_viz.load_scene("frog")
    text = frog.to_toml()
    (tmp / "frog512.toml").write_text(text)
    out["frog 512^2"] = tmp / "frog512.toml"
    small = frog.replace(detector=dataclasses.replace(
        frog.detector, shape=(256, 256), pitch=tuple(2 * p for p in frog.detector.pitch)))
    (tmp / "frog256.toml").write_text(small.to_toml())
    out["frog 256^2"] = tmp / "frog256.toml"

    from suites import sphere_mesh, sphere_scene

    mesh = sphere_mesh(8)
    stl = tmp / "sphere8.stl"
    mesh.export(stl)
    sc = sphere_scene(mesh, (512, 512))
    det = sc.detector
    (tmp / "sphere8.toml").write_text(
        f"[source]\nposition = {sc.source.position.tolist()}\nkind = \"point\"\nenergy = 60.0\n"
        f"\n[detector]\ncenter = {np.asarray(det.center).tolist()}\n"
        f"up = {np.asarray(det.up).tolist()}\nshape = [512, 512]\n"
        f"pitch = {list(det.pitch)}\n\n[[body]]\nname = \"ball\"\nmesh = \"{stl}\"\n"
        f"mu = 0.2\n")
    out["sphere 1.3M faces 512^2"] = tmp / "sphere8.toml"
    return out


# ----------------------------------------------------------------------------- xray_viz

def _set_numba_threads(n):
    import numba

    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    return numba.get_num_threads()


def serial_case(path: Path, n: int, tmp: Path) -> dict:
    """Serial figures of one scene file (see the module docstring)."""
    import numba

    import xray_viz
    S = importlib.import_module("xray_viz.scan")

    out = {}
    for threads in (1, numba.config.NUMBA_NUM_THREADS):
        used = _set_numba_threads(threads)
        t0 = time.perf_counter()
        scene = xray_viz.load_scene(path)
        t_load = time.perf_counter() - t0
        orbit = S.default_orbit(scene, projections=n)
        times = []
        for k in range(n):
            t0 = time.perf_counter()
            image = S.projection(scene, orbit, k)
            times.append(time.perf_counter() - t0)
        out[f"threads_{used}"] = {"load_s": t_load, "first_s": times[0],
                                  "steady_s": _median(times[1:]), "all_s": times}
    # one projection's store write (chunk + flag), into a store of this scan
    store = tmp / "write.zarr"
    shutil.rmtree(store, ignore_errors=True)
    geometry = S.scan_geometry(scene, orbit)
    group = S.open_store(store, scene=scene, geometry=geometry)
    writes = []
    for k in range(n):
        t0 = time.perf_counter()
        S._write_projection(group, k, image)
        writes.append(time.perf_counter() - t0)
    out["write_s"] = _median(writes)
    out["image_mib"] = image.nbytes / 2**20
    # end to end, every core (load + geometry + n projections + writes)
    shutil.rmtree(store, ignore_errors=True)
    t0 = time.perf_counter()
    scene = xray_viz.load_scene(path)
    S.scan(scene, S.default_orbit(scene, projections=n), store=store)
    out["scan_s"] = time.perf_counter() - t0
    out["scan_proj_per_s"] = n / out["scan_s"]
    shutil.rmtree(store, ignore_errors=True)
    return out


def _noop(x):
    return x


def scheduler_overhead(client, tasks=200) -> dict:
    """Per-task cost of Dask itself: ``tasks`` no-op tasks at once (throughput) and one at a
    time (round trip)."""
    client.gather(client.map(_noop, range(20), pure=False))          # warm
    t0 = time.perf_counter()
    client.gather(client.map(_noop, range(tasks), pure=False))
    bulk = (time.perf_counter() - t0) / tasks
    trips = []
    for i in range(21):
        t0 = time.perf_counter()
        client.submit(_noop, i, pure=False).result()
        trips.append(time.perf_counter() - t0)
    return {"bulk_per_task_s": bulk, "round_trip_s": _median(trips)}


def dask_case(client, path: Path, n: int, batch: int, tmp: Path) -> dict:
    """Two scans of one scene file on the cluster; per-task figures from the task stream."""
    from distributed import get_task_stream

    import xray_viz
    S = importlib.import_module("xray_viz.scan")

    scene = xray_viz.load_scene(path)
    orbit = S.default_orbit(scene, projections=n)
    runs = []
    for run in range(2):
        store = tmp / f"dask{run}.zarr"
        shutil.rmtree(store, ignore_errors=True)
        with get_task_stream(client) as ts:
            t0 = time.perf_counter()
            S.scan(scene, orbit, store=store, client=client, batch=batch)
            wall = time.perf_counter() - t0
        tasks = []
        for rec in ts.data:
            if not str(rec.get("key", "")).startswith("xray-viz-scan"):
                continue
            comp = [s for s in rec["startstops"] if s["action"] == "compute"]
            if comp:
                tasks.append((rec["worker"], comp[0]["start"], comp[0]["stop"]))
        tasks.sort(key=lambda t: t[1])
        first, steady, busy = [], [], {}
        for w, start, stop in tasks:
            per = (stop - start) / batch
            (steady if w in busy else first).append(per)
            busy[w] = busy.get(w, 0.0) + (stop - start)
        runs.append({"wall_s": wall, "proj_per_s": n / wall, "tasks": len(tasks),
                     "first_task_per_proj_s": _median(first),
                     "steady_per_proj_s": _median(steady),
                     "busiest_worker_s": max(busy.values()),
                     "workers_used": len(busy)})
        shutil.rmtree(store, ignore_errors=True)
    return {"run1": runs[0], "run2": runs[1]}


# ----------------------------------------------------------------------------- gVirtualXray

def gvxr_case(path: Path, n: int) -> dict:
    """gVirtualXray's CT acquisition of the scene file's bodies (OpenGL, EGL)."""
    import xray_viz
    from suites import _quiet_gvxr
    S = importlib.import_module("xray_viz.scan")
    from xray_viz.physics.materials import linear_attenuation

    try:
        from gvxrPython3 import gvxr
    except ImportError as exc:
        return {"unavailable": f"gvxr not importable: {exc} (pip install -e '.[bench]')"}
    scene = xray_viz.load_scene(path)
    orbit = S.default_orbit(scene, projections=n)
    with _quiet_gvxr():
        try:
            if not getattr(gvxr_case, "window", False):
                gvxr.createWindow(-1, 0, "EGL")
                gvxr_case.window = True
            gvxr.removePolygonMeshesFromSceneGraph()
            det = scene.detector
            gvxr.usePointSource()
            gvxr.setDetectorNumberOfPixels(*det.shape)
            gvxr.setDetectorPixelSize(det.pitch[0], det.pitch[1], "mm")
            gvxr.setMonoChromatic(60, "keV", 1000)
            t0 = time.perf_counter()
            for body in scene.bodies:
                m = body.mesh
                mu = body.mu if body.mu is not None else float(
                    linear_attenuation(body.material, [60.0], density=body.density)[0])
                gvxr.makeTriangularMesh(body.name,
                                        np.asarray(m.vertices, np.float32).ravel().tolist(),
                                        np.asarray(m.faces, np.int32).ravel().tolist(), "mm")
                gvxr.setLinearAttenuationCoefficient(body.name, float(mu), "cm-1")
                gvxr.addPolygonMeshAsInnerSurface(body.name)
            t_meshes = time.perf_counter() - t0
            times, images = [], []
            for k in range(n):
                acq = orbit.acquisition(scene.acquisition, k)
                t0 = time.perf_counter()
                gvxr.setSourcePosition(*acq.source.position.tolist(), "mm")
                gvxr.setDetectorPosition(*np.asarray(acq.detector.center).tolist(), "mm")
                gvxr.setDetectorUpVector(*np.asarray(acq.detector.up).tolist())
                img = np.asarray(gvxr.computeXRayImage(), np.float32)
                times.append(time.perf_counter() - t0)
                if k < 2:
                    images.append(img)
        except Exception as exc:            # gvxr raises its own kinds
            return {"unavailable": f"gvxr failed: {type(exc).__name__}: {exc}"}
    out = {"meshes_s": t_meshes, "first_s": times[0], "steady_s": _median(times[1:]),
           "shape": list(images[0].shape)}
    # the same picture? line integrals -ln(I / I_max) against xray_viz's, best flip
    from suites import _gvxr_orient

    ours = np.asarray(S.projection(scene, orbit, 0), np.float64)
    theirs = -np.log(np.maximum(images[0], 1e-30) / images[0].max())
    theirs = _gvxr_orient(theirs, ours)
    inside = ours > 0.05 * ours.max()            # where the bodies are
    out["inside_median_rel_diff"] = float(np.median(np.abs(theirs - ours)[inside]
                                                    / ours[inside]))
    out["max_line_integral"] = float(ours.max())
    return out


# ----------------------------------------------------------------------------- model

def simulate(per_proj_s, write_s, setup_s, sched_s, workers, *, n=2048, batch=8,
             one_store_channel=False):
    """Projections per second of an ``n``-projection scan on ``workers`` workers.

    A discrete-event model: the scheduler hands out one task every ``sched_s`` seconds at
    most (Dask's measured per-task cost, serialised on the scheduler); a free worker takes
    the next task; a task costs ``batch * (per_proj_s + write_s)``, plus ``setup_s`` on the
    worker's first task (scene loaded, per-mesh set-up). Writes scale with the workers (each
    writes its own chunks), unless ``one_store_channel``: a store that takes one write at a
    time at one writer's measured speed (one disk, one NFS server) caps the rate at
    ``1 / write_s``.
    """
    import heapq

    tasks = -(-n // batch)
    free = [(0.0, w) for w in range(workers)]
    heapq.heapify(free)
    started = set()
    sched_t = end = 0.0
    for i in range(tasks):
        size = min(batch, n - i * batch)
        t_free, w = heapq.heappop(free)
        sched_t = max(sched_t + sched_s, t_free)          # the scheduler's next slot
        t = sched_t + (0.0 if w in started else setup_s) + size * (per_proj_s + write_s)
        started.add(w)
        end = max(end, t)
        heapq.heappush(free, (t, w))
    rate = n / end
    return min(rate, 1.0 / write_s) if one_store_channel else rate


def plot(results: dict, path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    ns = np.unique(np.round(np.geomspace(1, 64, 25)).astype(int))
    sched = results["scheduler"]["bulk_per_task_s"]
    batch = results["batch"]
    fig, ax = plt.subplots(figsize=(7.5, 5.2))
    colors = ["C0", "C1", "C2"]
    for (case, r), c in zip(results["cases"].items(), colors):
        s = r["serial"]["threads_1"]
        per, write = s["steady_s"], r["serial"]["write_s"]
        setup = max(0.0, r["dask"]["run1"]["first_task_per_proj_s"] * batch - batch * per)
        y = [simulate(per, write, setup, sched, int(k), batch=batch) for k in ns]
        yb = [simulate(per, write, setup, sched, int(k), batch=batch,
                       one_store_channel=True) for k in ns]
        ax.plot(ns, y, "-", color=c, label=f"{case}: model")
        ax.plot(ns, yb, ":", color=c, label=f"{case}: model, one store channel")
        ax.plot(ns, ns / (per + write), "-", color=c, alpha=0.25, lw=4)
        ax.plot([1], [1 / (per + write)], "o", color=c)
        w = results["workers"]
        ax.plot([w], [r["dask"]["run2"]["proj_per_s"]], "s", color=c, mfc="none", ms=9)
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("Dask workers (one core each)")
    ax.set_ylabel("projections per second")
    ax.set_title(f"CT scan scaling, simulated from measured costs\n(2048 projections, batch "
                 f"{batch}, scheduler {sched * 1e3:.2f} ms/task; faint: ideal)", fontsize=10)
    ax.plot([], [], "ko", label="measured serial, 1 numba thread")
    ax.plot([], [], "ks", mfc="none", label=f"measured LocalCluster, {results['workers']} "
            "workers (2 shared cores)")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


# ----------------------------------------------------------------------------- geometry

def geometry_build(n: int) -> dict:
    """Seconds to build the geometry of ``n`` random poses (``scan_geometry``), to create
    its Zarr store (``open_store``, no projection rendered) and to read it back
    (``read_zarr(lazy=True)``), and the size of the store's JSON attributes. Whichever
    ``xray_viz`` is first on ``sys.path`` (``PYTHONPATH=/work/main`` for main's)."""
    import dataclasses

    import xray_viz
    from xray_viz.orbit import orbit_from_dict

    S = importlib.import_module("xray_viz.scan")
    scene = xray_viz.load_scene("sphere")
    scene = scene.replace(detector=dataclasses.replace(scene.detector, shape=(16, 16),
                                                       pitch=(16.0, 16.0)))
    orbit = orbit_from_dict({"axis": [0.0, 1.0, 0.0], "poses": {
        "random": n, "seed": 7, "tilt": [-15.0, 15.0], "sod": [900.0, 1100.0]}})
    tmp = Path(tempfile.mkdtemp(prefix="ct-geometry-"))
    try:
        t0 = time.perf_counter()
        g = S.scan_geometry(scene, orbit)
        t1 = time.perf_counter()
        S.open_store(tmp / "g.zarr", scene=scene, geometry=g)
        t2 = time.perf_counter()
        S.read_zarr(tmp / "g.zarr", require_complete=False, lazy=True)
        t3 = time.perf_counter()
        size = (tmp / "g.zarr" / "zarr.json").stat().st_size
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return {"n": n, "code": S.__file__, "scan_geometry_s": t1 - t0, "open_store_s": t2 - t1,
            "read_zarr_s": t3 - t2, "attrs_bytes": size}


# ----------------------------------------------------------------------------- main

def machine() -> str:
    import platform

    cpu = "?"
    for line in open("/proc/cpuinfo"):
        if line.startswith("model name"):
            cpu = line.split(":", 1)[1].strip()
            break
    return (f"nproc {os.cpu_count()} ({cpu}), load average {os.getloadavg()[0]:.1f} at the "
            f"start, Python {platform.python_version()}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--projections", type=int, default=24)
    p.add_argument("--batch", type=int, default=4)
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--no-gvxr", action="store_true")
    p.add_argument("--gvxr-only", action="store_true", help="only gVirtualXray's figures")
    p.add_argument("--plot-only", action="store_true")
    p.add_argument("--cases", nargs="+", default=None)
    p.add_argument("--geometry", type=int, default=None, metavar="N",
                   help="only time the geometry and store of N random poses")
    args = p.parse_args(argv)
    if args.geometry:
        print(json.dumps(geometry_build(args.geometry)))
        return 0
    if args.plot_only:
        plot(json.loads(RESULTS.read_text()), HERE / "ct_scaling.png")
        return 0
    from distributed import Client

    S = importlib.import_module("xray_viz.scan")

    S.warm_kernels()
    results = {"machine": machine(), "projections": args.projections, "batch": args.batch,
               "workers": args.workers, "cases": {}}
    tmp = Path(tempfile.mkdtemp(prefix="ct-throughput-"))
    try:
        files = _scene_files(tmp)
        if args.cases:
            files = {k: v for k, v in files.items() if any(c in k for c in args.cases)}
        if args.gvxr_only:
            for case, path in files.items():
                print(json.dumps({case: gvxr_case(path, args.projections)}), flush=True)
            return 0
        for case, path in files.items():
            print(f"serial: {case}", flush=True)
            results["cases"][case] = {"serial": serial_case(path, args.projections, tmp)}
        with S.local_cluster(args.workers) as cluster, Client(cluster) as client:
            results["scheduler"] = scheduler_overhead(client)
            for case, path in files.items():
                print(f"dask: {case}", flush=True)
                results["cases"][case]["dask"] = dask_case(client, path, args.projections,
                                                           args.batch, tmp)
        if not args.no_gvxr:
            for case, path in files.items():
                print(f"gvxr: {case}", flush=True)
                results["cases"][case]["gvxr"] = gvxr_case(path, args.projections)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps(results, indent=1))
    print(json.dumps(results, indent=1, default=str))
    plot(results, HERE / "ct_scaling.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

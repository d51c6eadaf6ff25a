"""Benchmarks (``xray-viz bench``): run time against error, peers side by side, scaling.

Not timed tests: figures depend on the machine. Every peer runs on the *same rays* in the same
process, so ratios are meaningful even on a noisy machine. Three suites:

``pareto``
    A sphere of radius 40 mm meshed as an icosphere (subdivisions 1-8, and pymeshlab quadric
    decimations of a fine one) x supersampling 1, 2, 4: median render time against the max and
    RMS error of the path-length image against the analytic radiograph (the exact sphere chord
    averaged over each pixel). Writes a Pareto plot and a table of the fastest setting for each
    error budget.
``peers``
    The fast engine, the NumPy engine, Open3D ``RaycastingScene.list_intersections``,
    trimesh + embreex ``multiple_hits``, pyvista ``multi_ray_trace`` and gVXR (when installed)
    on 512 x 512 rays through 82k- and 1.3M-face spheres, and on the cube edge suite (rays
    miscounted). Peers get the same path-length step: ``L = sum(t * sign(d . n))``.
``scaling``
    Time against the number of triangles (fixed detector) and of pixels (fixed mesh).

Results go to ``--out`` (default ``benchmarks/results``): JSON, Markdown tables and PNG plots.
"""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import numpy as np

__all__ = ["bench_command", "add_bench_parser"]

RADIUS = 40.0


# --------------------------------------------------------------------------------------------
# Scenes and references


def sphere_mesh(subdivisions):
    import trimesh

    return trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=RADIUS)


def sphere_scene(mesh, shape, *, kind="point"):
    """The sphere phantom's camera (source 1 m above, detector 0.5 m below), sphere filling
    ~80 % of the detector."""
    from xray_viz.scene import Body, Detector, Scene, Source

    pitch = 2 * RADIUS * 1.5 / 0.8 / (shape[0] - 1)
    return Scene(source=Source(position=[0.0, 0.0, 1000.0], kind=kind),
                 detector=Detector(center=[0.0, 0.0, -500.0], shape=tuple(shape), pitch=pitch),
                 bodies=(Body(name="ball", mesh=mesh, mu=0.2),))


def cube_scene(kind, shape=(255, 255)):
    import trimesh

    from xray_viz.scene import Body, Detector, Scene, Source

    cube = trimesh.creation.box(extents=(40.0, 40.0, 40.0))
    return Scene(source=Source(position=[0.0, 0.0, -1000.0], kind=kind),
                 detector=Detector(center=[0.0, 0.0, 249.5], shape=shape, pitch=0.5),
                 bodies=(Body(name="cube", mesh=cube, mu=0.2),))


def sphere_chord(origins, directions):
    """Exact chord of rays (unit directions) through the sphere of radius 40 at the origin."""
    proj = -np.einsum("ij,ij->i", origins, directions)
    d2 = np.einsum("ij,ij->i", origins, origins) - proj ** 2
    return 2 * np.sqrt(np.maximum(RADIUS ** 2 - d2, 0.0))


def analytic_pixel_average(scene, *, m=16):
    """The exact sphere chord averaged over each pixel (m x m midpoint rule), (H * W,)."""
    w, h = scene.detector.shape
    out = np.zeros(w * h)
    for k in range(0, m):             # one sub-row at a time keeps memory O(pixels)
        rays = _subrow_rays(scene, m, k)
        out += sphere_chord(rays.origins, rays.directions).reshape(w * h, m).sum(axis=1)
    return out / (m * m)


def _subrow_rays(scene, m, k):
    """Rays of sub-row k of an m x m sub-grid (the offsets of ``detector_rays``)."""
    from xray_viz.geometry import Rays, pixel_coordinates, viewport

    vp = viewport(scene.source.position, scene.detector)
    u, v = pixel_coordinates(vp.shape)
    w, h = vp.shape
    offs = (np.arange(m) + 0.5) / m - 0.5
    uu = (u.ravel()[:, None] + offs[None, :] / max(w - 1, 1)).ravel()
    vv = np.repeat(v.ravel() + offs[::-1][k] / max(h - 1, 1), m)
    targets = vp.point(uu, vv)
    d = targets - vp.r0
    t_max = np.linalg.norm(d, axis=1)
    return Rays(origins=np.broadcast_to(vp.r0, d.shape), directions=d / t_max[:, None],
                t_max=t_max)


def decimated_sphere(target_faces, source_subdivisions=7):
    """A fine icosphere decimated by pymeshlab quadric edge collapse to ``target_faces``."""
    import pymeshlab
    import trimesh

    fine = sphere_mesh(source_subdivisions)
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(vertex_matrix=fine.vertices, face_matrix=fine.faces))
    ms.meshing_decimation_quadric_edge_collapse(targetfacenum=int(target_faces),
                                                preservenormal=True, preservetopology=True,
                                                preserveboundary=True)
    cur = ms.current_mesh()
    return trimesh.Trimesh(cur.vertex_matrix(), cur.face_matrix(), process=False)


# --------------------------------------------------------------------------------------------
# Timing


def median_time(fn, repeat):
    times = []
    out = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)), out


def fast_engine(scene, supersample=1):
    from xray_viz.tracing.fast import trace_once

    return trace_once(scene, supersample=supersample)[:, 0]


def numpy_engine(scene, supersample=1):
    from xray_viz.render import ENGINES

    return ENGINES["numpy"](scene, supersample=supersample, keep_hits=False)[0][:, 0]


# --------------------------------------------------------------------------------------------
# Peers: each returns (build(mesh) -> state, query(state, rays) -> L) or raises ImportError.


def _signed_sum(ray, t, tri, normals, directions, n):
    sign = np.sign(np.einsum("ij,ij->i", normals[tri], directions[ray]))
    return np.bincount(ray, weights=t * sign, minlength=n)


def peer_open3d():
    import open3d as o3d

    def build(mesh):
        scene = o3d.t.geometry.RaycastingScene()
        scene.add_triangles(o3d.core.Tensor(np.asarray(mesh.vertices, np.float32)),
                            o3d.core.Tensor(np.asarray(mesh.faces, np.uint32)))
        return scene, np.asarray(mesh.face_normals)

    def query(state, rays):
        scene, normals = state
        r = np.hstack([rays.origins, rays.directions]).astype(np.float32)
        res = scene.list_intersections(o3d.core.Tensor(r))
        ray = res["ray_ids"].numpy().astype(np.int64)
        t = res["t_hit"].numpy().astype(np.float64)
        tri = res["primitive_ids"].numpy().astype(np.int64)
        return _signed_sum(ray, t, tri, normals, rays.directions, len(rays))

    return build, query


def peer_embree():
    import trimesh

    if not trimesh.ray.has_embree:
        raise ImportError("embreex is not installed")

    def build(mesh):
        m = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False)
        from trimesh.ray.ray_pyembree import RayMeshIntersector

        return RayMeshIntersector(m), np.asarray(m.face_normals)

    def query(state, rays):
        inter, normals = state
        loc, ray, tri = inter.intersects_location(rays.origins, rays.directions,
                                                  multiple_hits=True)
        t = np.einsum("ij,ij->i", loc - rays.origins[ray], rays.directions[ray])
        return _signed_sum(ray, t, tri, normals, rays.directions, len(rays))

    return build, query


def peer_pyvista():
    import pyvista as pv

    def build(mesh):
        return (pv.PolyData.from_regular_faces(np.asarray(mesh.vertices), np.asarray(mesh.faces)),
                np.asarray(mesh.face_normals))

    def query(state, rays):
        poly, normals = state
        pts, ray, tri = poly.multi_ray_trace(rays.origins, rays.directions, first_point=False)
        t = np.einsum("ij,ij->i", pts - rays.origins[ray], rays.directions[ray])
        return _signed_sum(ray, t, tri, normals, rays.directions, len(rays))

    return build, query


_GVXR_WINDOW = []


def peer_gvxr():
    """gVXR's L-buffer (``computePathLength``), OpenGL on the CPU (llvmpipe) here."""
    from gvxrPython3 import gvxr

    def build(mesh, scene):
        if not _GVXR_WINDOW:
            gvxr.createWindow(-1, 0, "EGL")
            _GVXR_WINDOW.append(True)
        gvxr.removePolygonMeshesFromSceneGraph()
        src, det = scene.source, scene.detector
        gvxr.setSourcePosition(*src.position.tolist(), "mm")
        if src.kind == "parallel":
            gvxr.useParallelBeam()
        else:
            gvxr.usePointSource()
        gvxr.setDetectorPosition(*det.center.tolist(), "mm")
        gvxr.setDetectorUpVector(*det.up.tolist())
        gvxr.setDetectorNumberOfPixels(*det.shape)
        gvxr.setDetectorPixelSize(det.pitch[0], det.pitch[1], "mm")
        gvxr.setMonoChromatic(60, "keV", 1000)
        gvxr.makeTriangularMesh("body", np.asarray(mesh.vertices, np.float32).ravel().tolist(),
                                np.asarray(mesh.faces, np.int32).ravel().tolist(), "mm")
        gvxr.setLinearAttenuationCoefficient("body", 0.2, "cm-1")
        gvxr.addPolygonMeshAsInnerSurface("body")
        return "body"

    def query(label, scene):
        # gVXR's L-buffer is in cm.
        return np.asarray(gvxr.computePathLength(label), dtype=np.float64) * 10.0

    return build, query


def _gvxr_orient(img, ref_image):
    """gVXR's image in our orientation: the flip that matches the reference best."""
    best = None
    for cand in (img, img[::-1], img[:, ::-1], img[::-1, ::-1]):
        err = np.abs(cand - ref_image).max()
        if best is None or err < best[0]:
            best = (err, cand)
    return best[1]


PEERS = {"open3d": peer_open3d, "trimesh+embreex": peer_embree,
         "pyvista multi_ray_trace": peer_pyvista}


def _quiet_gvxr():
    """Silence gVXR's log lines on stdout for the duration of a call (fd-level)."""
    import contextlib

    @contextlib.contextmanager
    def ctx():
        import sys

        sys.stdout.flush()
        saved = os.dup(1)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        try:
            yield
        finally:
            os.dup2(saved, 1)
            os.close(saved)
            os.close(devnull)

    return ctx()


# --------------------------------------------------------------------------------------------
# Suites


def _progress(iterable, **kw):
    from tqdm.auto import tqdm

    return tqdm(iterable, **kw)


def run_pareto(out, *, repeat, subdivisions, shape, supersamples, decimations):
    from xray_viz.tracing.fast import trace_once

    meshes = [(f"icosphere {k}", sphere_mesh(k)) for k in subdivisions]
    for n_faces in decimations:
        meshes.append((f"decimated {n_faces}", decimated_sphere(n_faces)))
    rows = []
    truth = None
    for label, mesh in _progress(meshes, desc="pareto meshes"):
        scene = sphere_scene(mesh, shape)
        if truth is None:
            truth = analytic_pixel_average(scene)
        for n in supersamples:
            trace_once(scene, supersample=n)            # compile / warm caches
            t, L = median_time(lambda: trace_once(scene, supersample=n), repeat)
            img = L[:, 0].reshape(-1, n * n).mean(axis=1)
            err = img - truth
            rows.append(dict(mesh=label, faces=len(mesh.faces), supersample=n, time_s=t,
                             max_error_mm=float(np.abs(err).max()),
                             rms_error_mm=float(np.sqrt(np.mean(err ** 2)))))
    (out / "pareto.json").write_text(json.dumps(rows, indent=1))
    _pareto_plot(rows, out / "pareto.png", shape)
    table = _pareto_table(rows)
    (out / "pareto.md").write_text(table)
    return rows, table


def _pareto_front(rows, key):
    front = []
    for r in sorted(rows, key=lambda r: r["time_s"]):
        if not front or r[key] < front[-1][key]:
            front.append(r)
    return front


def _pareto_plot(rows, path, shape):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 4.5))
    markers = {1: "o", 2: "s", 4: "^"}
    for ax, key, title in ((axes[0], "max_error_mm", "max error"),
                           (axes[1], "rms_error_mm", "RMS error")):
        for n in sorted({r["supersample"] for r in rows}):
            for deci in (False, True):
                sel = [r for r in rows if r["supersample"] == n
                       and r["mesh"].startswith("decimated") == deci]
                if not sel:
                    continue
                color = {1: "C0", 2: "C1", 4: "C2"}.get(n, "C3")
                ax.scatter([r["time_s"] * 1e3 for r in sel], [r[key] for r in sel],
                           marker=markers.get(n, "x"), edgecolors=color,
                           facecolors="none" if deci else color,
                           label=f"{n}x{n} rays/pixel" + (", pymeshlab decimated" if deci
                                                          else ", icosphere"))
        front = _pareto_front(rows, key)
        ax.plot([r["time_s"] * 1e3 for r in front], [r[key] for r in front], "k--", lw=1,
                label="Pareto front")
        for r in front:
            ax.annotate(f"{r['faces'] // 1000 if r['faces'] >= 1000 else r['faces']}"
                        f"{'k' if r['faces'] >= 1000 else ''}/{r['supersample']}x",
                        (r["time_s"] * 1e3, r[key]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("render time per image (ms, median)")
        ax.set_ylabel(f"{title} of the path-length image (mm)")
        ax.set_title(f"sphere r=40 mm, {shape[0]}x{shape[1]}: {title}")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle("Fast engine: time vs error (labels: faces / supersampling on the front)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _pareto_table(rows):
    lines = ["| mesh | faces | supersample | time (ms) | max error (mm) | RMS error (mm) |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['mesh']} | {r['faces']} | {r['supersample']} | "
                     f"{r['time_s'] * 1e3:.2f} | {r['max_error_mm']:.3g} | "
                     f"{r['rms_error_mm']:.3g} |")
    lines += ["", "Fastest setting for an error budget (RMS error of the path-length image):", "",
              "| RMS budget (mm) | use | time (ms) | RMS / max error (mm) |", "|---|---|---|---|"]
    for budget in (1.0, 0.3, 0.1, 0.03, 0.01, 0.003, 0.001):
        ok = [r for r in rows if r["rms_error_mm"] <= budget]
        if ok:
            best = min(ok, key=lambda r: r["time_s"])
            lines.append(f"| {budget:g} | {best['mesh']} ({best['faces']} faces), "
                         f"supersample {best['supersample']} | {best['time_s'] * 1e3:.2f} | "
                         f"{best['rms_error_mm']:.3g} / {best['max_error_mm']:.3g} |")
        else:
            lines.append(f"| {budget:g} | (none measured) | | |")
    return "\n".join(lines) + "\n"


def run_peers(out, *, repeat, subdivisions, shape):
    from xray_viz.geometry import detector_rays

    results = []
    engines = {"fast": None, "numpy": None}
    for sub in _progress(subdivisions, desc="peers meshes"):
        mesh = sphere_mesh(sub)
        scene = sphere_scene(mesh, shape)
        rays = detector_rays(scene)
        truth = sphere_chord(rays.origins, rays.directions)
        # Inscribed-mesh bound: every correct engine lies between the two spheres' chords.
        fast_engine(scene)
        rep = repeat
        for name in engines:
            if name == "numpy" and len(mesh.faces) > 400_000:
                reps = 1
            else:
                reps = rep
            t, L = median_time(lambda: (fast_engine if name == "fast" else numpy_engine)(scene),
                               reps)
            results.append(dict(mesh_faces=len(mesh.faces), shape=list(shape), engine=name,
                                build_s=0.0, query_s=t, max_error_mm=float(np.abs(L - truth).max())))
        for name, make in PEERS.items():
            try:
                build, query = make()
            except ImportError as exc:
                results.append(dict(mesh_faces=len(mesh.faces), engine=name,
                                    unavailable=str(exc)))
                continue
            if name.startswith("pyvista") and len(mesh.faces) > 400_000:
                reps = 1
            else:
                reps = rep
            t_build, state = median_time(lambda: build(mesh), 1)
            try:
                query(state, rays)
                t, L = median_time(lambda: query(state, rays), reps)
            except Exception as exc:        # a peer failing is a result, not a crash
                results.append(dict(mesh_faces=len(mesh.faces), engine=name,
                                    unavailable=f"{type(exc).__name__}: {exc}"))
                continue
            if name.startswith("pyvista"):
                t_build = 0.0      # multi_ray_trace rebuilds its acceleration structure per call
            results.append(dict(mesh_faces=len(mesh.faces), shape=list(shape), engine=name,
                                build_s=t_build, query_s=t,
                                max_error_mm=float(np.abs(L - truth).max())))
        results.extend(_gvxr_row(mesh, scene, truth, rep))
    cube = cube_suite()
    (out / "peers.json").write_text(json.dumps(dict(sphere=results, cube=cube), indent=1))
    table = _peers_table(results, cube)
    (out / "peers.md").write_text(table)
    return results, cube, table


def _gvxr_row(mesh, scene, truth, repeat):
    try:
        build, query = peer_gvxr()
    except ImportError as exc:
        return [dict(mesh_faces=len(mesh.faces), engine="gvxr", unavailable=str(exc))]
    try:
        with _quiet_gvxr():
            t_build, label = median_time(lambda: build(mesh, scene), 1)
            query(label, scene)
            t, img = median_time(lambda: query(label, scene), repeat)
    except Exception as exc:
        return [dict(mesh_faces=len(mesh.faces), engine="gvxr",
                     unavailable=f"{type(exc).__name__}: {exc}")]
    w, h = scene.detector.shape
    img = _gvxr_orient(img, truth.reshape(h, w))
    return [dict(mesh_faces=len(mesh.faces), shape=[w, h], engine="gvxr", build_s=t_build,
                 query_s=t, max_error_mm=float(np.abs(img.ravel() - truth).max()))]


def cube_suite():
    """Rays miscounted on the cube edge suite, per engine and beam (|L - exact| > 1e-3 mm)."""
    import trimesh

    from xray_viz.geometry import detector_rays

    rows = []
    for kind in ("parallel", "point"):
        scene = cube_scene(kind)
        rays = detector_rays(scene)
        w, h = scene.detector.shape
        row, col = np.divmod(np.arange(w * h), w)
        x, y = (col - 127) / 2, (127 - row) / 2
        ref = _box_chord(rays, 20.0)
        amb = np.zeros(len(ref), bool)
        if kind == "parallel":
            amb = ((np.abs(x) == 20) | (np.abs(y) == 20)) & (np.abs(x) <= 20) & (np.abs(y) <= 20)
        mesh = trimesh.creation.box(extents=(40.0, 40.0, 40.0))

        def wrong(L):
            ok = np.abs(L - ref) <= 1e-3
            ok |= amb & ((np.abs(L) <= 1e-3) | (np.abs(L - 40) <= 1e-3))
            return int(np.count_nonzero(~ok))

        rows.append(dict(kind=kind, engine="fast", wrong=wrong(fast_engine(scene))))
        rows.append(dict(kind=kind, engine="numpy", wrong=wrong(numpy_engine(scene))))
        for name, make in PEERS.items():
            try:
                build, query = make()
                rows.append(dict(kind=kind, engine=name, wrong=wrong(query(build(mesh), rays))))
            except Exception as exc:
                rows.append(dict(kind=kind, engine=name, unavailable=str(exc)))
        try:
            build, query = peer_gvxr()
            with _quiet_gvxr():
                img = query(build(mesh, scene), scene)
            img = _gvxr_orient(img, ref.reshape(h, w))
            rows.append(dict(kind=kind, engine="gvxr", wrong=wrong(img.ravel())))
        except Exception as exc:
            rows.append(dict(kind=kind, engine="gvxr", unavailable=str(exc)))
    return rows


def _box_chord(rays, half):
    o, d = rays.origins, rays.directions
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - o) / d
        t2 = (half - o) / d
    zero = d == 0
    inside = np.abs(o) <= half
    tn = np.where(zero, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2)).max(axis=1)
    tf = np.where(zero, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2)).min(axis=1)
    tn, tf = np.maximum(tn, 0), np.minimum(tf, rays.t_max)
    return np.where(tf > tn, tf - tn, 0.0)


def _peers_table(results, cube):
    lines = ["| faces | engine | build (ms) | query + path length (ms, median) | "
             "x fast | x Open3D (query) | x Open3D (build + query) | max error vs exact sphere (mm) |",
             "|---|---|---|---|---|---|---|---|"]
    by_faces = {}
    for r in results:
        by_faces.setdefault(r["mesh_faces"], []).append(r)
    for faces, rs in by_faces.items():
        fast = next((r for r in rs if r["engine"] == "fast"), None)
        o3d = next((r for r in rs if r["engine"] == "open3d" and "query_s" in r), None)
        for r in rs:
            if "unavailable" in r:
                lines.append(f"| {faces} | {r['engine']} | - | unavailable: {r['unavailable'][:60]} "
                             "| | | | |")
                continue
            tot = r["build_s"] + r["query_s"]
            x_fast = r["query_s"] / fast["query_s"] if fast else float("nan")
            x_o3d = r["query_s"] / o3d["query_s"] if o3d else float("nan")
            x_o3d_b = tot / (o3d["query_s"] + o3d["build_s"]) if o3d else float("nan")
            lines.append(f"| {faces} | {r['engine']} | {r['build_s'] * 1e3:.1f} | "
                         f"{r['query_s'] * 1e3:.1f} | {x_fast:.2f} | {x_o3d:.3f} | {x_o3d_b:.3f} | "
                         f"{r['max_error_mm']:.3g} |")
    lines += ["", "Cube edge suite (255 x 255 rays, cube [-20, 20]^3): rays miscounted", "",
              "| engine | parallel | point source |", "|---|---|---|"]
    engines = list(dict.fromkeys(r["engine"] for r in cube))
    for e in engines:
        cells = []
        for kind in ("parallel", "point"):
            r = next((r for r in cube if r["engine"] == e and r["kind"] == kind), None)
            cells.append(str(r["wrong"]) if r and "wrong" in r else "n/a")
        lines.append(f"| {e} | {cells[0]} | {cells[1]} |")
    return "\n".join(lines) + "\n"


def run_scaling(out, *, repeat, subdivisions, sizes, sub_for_pixels):
    from xray_viz.tracing.fast import trace_once

    tri_rows, pix_rows = [], []
    for sub in _progress(subdivisions, desc="scaling: triangles"):
        mesh = sphere_mesh(sub)
        scene = sphere_scene(mesh, (512, 512))
        trace_once(scene)
        t, _ = median_time(lambda: trace_once(scene), repeat)
        tri_rows.append(dict(faces=len(mesh.faces), pixels=512 * 512, time_s=t))
    mesh = sphere_mesh(sub_for_pixels)
    for size in _progress(sizes, desc="scaling: pixels"):
        scene = sphere_scene(mesh, (size, size))
        trace_once(scene)
        t, _ = median_time(lambda: trace_once(scene), repeat)
        pix_rows.append(dict(faces=len(mesh.faces), pixels=size * size, time_s=t))
    (out / "scaling.json").write_text(json.dumps(dict(triangles=tri_rows, pixels=pix_rows),
                                                 indent=1))
    _scaling_plot(tri_rows, pix_rows, out / "scaling.png")
    return tri_rows, pix_rows


def _scaling_plot(tri_rows, pix_rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4))
    for ax, rows, key, label in ((axes[0], tri_rows, "faces", "triangles (512 x 512 rays)"),
                                 (axes[1], pix_rows, "pixels",
                                  f"pixels ({pix_rows[0]['faces']} faces)" if pix_rows else "")):
        if not rows:
            continue
        x = np.array([r[key] for r in rows], float)
        y = np.array([r["time_s"] * 1e3 for r in rows])
        ax.loglog(x, y, "o-", label="fast engine (median)")
        # Least-squares fit of a + b x: linear cost plus a fixed per-image part.
        a, b = np.linalg.lstsq(np.column_stack([np.ones_like(x), x]), y, rcond=None)[0]
        xs = np.geomspace(x.min(), x.max(), 50)
        ax.loglog(xs, a + b * xs, "k--", lw=1,
                  label=f"fit {a:.2f} ms + {b * 1e6:.3g} ms per million {key}")
        ax.loglog(xs, b * xs, "k:", lw=1, label="its linear part")
        ax.set_xlabel(label)
        ax.set_ylabel("time per image (ms)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Fast engine scaling (sphere r = 40 mm)")
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


# --------------------------------------------------------------------------------------------
# Command line


def add_bench_parser(subparsers):
    """Add the ``bench`` sub-command to an ``argparse`` sub-parsers object."""
    p = subparsers.add_parser(
        "bench", help="benchmark the engines: time vs error, peers, scaling",
        description=__doc__.split("\n\n")[0] + " See BENCHMARKS.md.")
    p.add_argument("--suite", choices=("all", "pareto", "peers", "scaling"), default="all",
                   help="which benchmark to run (default: %(default)s)")
    p.add_argument("--out", default="benchmarks/results",
                   help="directory for JSON, Markdown tables and plots (default: %(default)s)")
    p.add_argument("--repeat", type=int, default=7,
                   help="timed runs per measurement; the median is reported (default: 7)")
    p.add_argument("--quick", action="store_true",
                   help="smaller meshes and detectors (a minute instead of several)")
    p.set_defaults(func=bench_command)
    return p


def bench_command(args) -> int:
    """Run the benchmarks selected by ``args`` (from :func:`add_bench_parser`)."""
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    quick = getattr(args, "quick", False)
    repeat = max(1, int(args.repeat))
    suite = args.suite
    report = {}
    if suite in ("all", "pareto"):
        rows, table = run_pareto(
            out, repeat=repeat, subdivisions=range(1, 7 if quick else 9),
            shape=(128, 128) if quick else (256, 256), supersamples=(1, 2, 4),
            decimations=() if quick else (1280, 5120, 20480, 81920))
        print(table)
        report["pareto"] = str(out / "pareto.png")
    if suite in ("all", "peers"):
        _, _, table = run_peers(out, repeat=repeat, subdivisions=(4, 6) if quick else (6, 8),
                                shape=(256, 256) if quick else (512, 512))
        print(table)
    if suite in ("all", "scaling"):
        run_scaling(out, repeat=repeat, subdivisions=range(2, 7 if quick else 9),
                    sizes=(128, 256, 512) if quick else (128, 256, 512, 1024, 2048),
                    sub_for_pixels=5 if quick else 6)
        report["scaling"] = str(out / "scaling.png")
    for k, v in report.items():
        print(f"{k} plot: {v}")
    return 0


if __name__ == "__main__":  # pragma: no cover
    import argparse

    parser = argparse.ArgumentParser(prog="xray-viz")
    add_bench_parser(parser.add_subparsers(dest="command", required=True))
    ns = parser.parse_args()
    raise SystemExit(ns.func(ns))

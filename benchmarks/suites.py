"""Benchmarks (``xray-viz bench``, or ``python benchmarks/suites.py``): run time against error,
peers side by side, scaling.

They live in the source repository, not in the installed package (they generate phantoms and
import the peers: ``pip install -e '.[bench]'`` and ``bash benchmarks/setup.sh``).

Not timed tests: figures depend on the machine. Every peer runs on the *same rays* in the same
process, so ratios are meaningful even on a noisy machine. Three suites:

``pareto``
    Two phantoms x mesh resolution x supersampling 1, 2, 4: median render time against the max
    and RMS error against the analytic radiograph. The sphere of radius 40 mm as an icosphere
    (subdivisions 1-8) and pymeshlab quadric decimations of a fine one (error of the path-length
    image, mm, against the exact chord averaged over each pixel). The Shepp-Logan head: the ten
    ellipsoids of ``phantoms/generate.py`` (its table and mesher; the bundled scene's camera,
    materials and energy), each an icosphere of subdivisions 1-8 mapped onto the ellipsoid (8:
    13M faces in all) or decimated from subdivision 7; error of the line-integral image
    ``-ln(I/I0)`` against exact ray-ellipsoid intervals combined with the renderer's precedence
    rule (innermost, then later-listed, wins), intensities averaged over a 16 x 16 sub-grid of
    each pixel (and, separately, over the renderer's own sub-rays: tessellation error only).
    Writes a Pareto plot (one column per phantom, error budgets labelled with the cheapest
    setting meeting them) and tables.
``peers``
    The fast engine (``trace_once``; its per-mesh set-up measured as ``clear_caches(scene)`` + a
    first trace minus a warm one; and ``xray_viz.render`` with a new Scene per frame, all
    per-render work included), the NumPy engine, Open3D ``RaycastingScene.list_intersections``,
    trimesh + embreex ``multiple_hits``, pyvista ``multi_ray_trace`` and gVXR (when installed)
    on 512 x 512 rays through 82k- and 1.3M-face spheres, and on the cube edge suite (rays
    miscounted). Peers get the same path-length step: ``L = sum(t * sign(d . n))``. A missing
    peer is reported with how to install it (``pip install -e '.[bench]'`` and
    ``bash benchmarks/setup.sh``).
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

__all__ = ["bench_command", "add_bench_parser", "main"]

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
    """A fine icosphere decimated by :func:`xray_viz.meshes.decimate` (pymeshlab quadric edge
    collapse) to ``target_faces``; returns the mesh and its Hausdorff distance to the fine one
    (mm)."""
    from xray_viz.meshes import decimate

    return decimate(sphere_mesh(source_subdivisions), target_faces=int(target_faces))


# --------------------------------------------------------------------------------------------
# Shepp-Logan: the ellipsoids of phantoms/generate.py, meshed at any resolution, and their
# exact radiograph


def _generate():
    """``phantoms/generate.py`` (shipped as ``xray_viz._phantoms.generate``): the ellipsoid table
    (``SHEPP_LOGAN``), its scale and rotation, and the ``ellipsoid`` mesher."""
    from xray_viz._phantoms import generate

    return generate


def _sl_ellipsoid(g, row, subdivisions):
    """One Shepp-Logan ellipsoid meshed as ``make_shepp_logan`` does, at ``subdivisions``."""
    name, a, b, c, x0, y0, z0, theta, _, material = row
    return g.ellipsoid(np.array([x0, y0, z0]) * g.SHEPP_LOGAN_SCALE,
                       np.array([a, b, c]) * g.SHEPP_LOGAN_SCALE, angle_deg=theta,
                       subdivisions=int(subdivisions), rotation=g.SHEPP_LOGAN_ROTATION)


def shepp_logan_meshes(subdivisions=None, *, decimate_to=None, source_subdivisions=7):
    """``[(name, mesh)]`` of the Shepp-Logan ellipsoids: each an icosphere of ``subdivisions``
    mapped onto the ellipsoid, or (``decimate_to``) the subdivision-``source_subdivisions``
    one decimated by :func:`xray_viz.meshes.decimate` to that many faces. Also returns the
    largest Hausdorff distance (mm) of a decimation (0 for icospheres)."""
    g = _generate()
    out, worst = [], 0.0
    for row in g.SHEPP_LOGAN:
        if decimate_to is None:
            mesh = _sl_ellipsoid(g, row, subdivisions)
        else:
            from xray_viz.meshes import decimate

            mesh, h = decimate(_sl_ellipsoid(g, row, source_subdivisions),
                               target_faces=int(decimate_to))
            worst = max(worst, float(h))
        out.append((row[0], mesh))
    return out, worst


def shepp_logan_ellipsoids():
    """The exact ellipsoids: ``[(name, A, c)]`` with surface ``{u @ A + c : |u| = 1}`` (mm).

    Recovered from ``generate.ellipsoid`` itself (an affine image of the unit icosphere): the
    affine map is fitted to its vertices, so whatever that function and the table say, the
    reference follows them. Refuses a mesher that is not an affine image of the unit sphere."""
    import trimesh

    g = _generate()
    unit = trimesh.creation.icosphere(subdivisions=1, radius=1.0).vertices
    X = np.column_stack([unit, np.ones(len(unit))])
    out = []
    for row in g.SHEPP_LOGAN:
        v = np.asarray(_sl_ellipsoid(g, row, 1).vertices, float)
        coef = np.linalg.lstsq(X, v, rcond=None)[0]
        if np.abs(X @ coef - v).max() > 1e-9 * max(1.0, np.abs(v).max()):
            raise RuntimeError(f"Shepp-Logan {row[0]}: generate.ellipsoid is no longer an affine "
                               "image of the unit icosphere; update the analytic reference")
        out.append((row[0], coef[:3], coef[3]))
    return out


def ellipsoid_precedence(ells):
    """The renderer's precedence rule (:func:`xray_viz.attenuation.body_precedence`: a body
    wholly inside another wins there, otherwise list order) applied to the exact ellipsoids:
    ``a`` is inside ``b`` when all of 2562 points spread over its surface are inside ``b``
    (for ellipsoids, whose surfaces are smooth and convex, a dense surface sample decides
    containment)."""
    import trimesh

    from xray_viz.attenuation import rank_by_nesting

    unit = trimesh.creation.icosphere(subdivisions=4, radius=1.0).vertices
    n = len(ells)
    containers = [[] for _ in range(n)]
    for a, (_, Aa, ca) in enumerate(ells):
        pts = unit @ Aa + ca
        for b, (_, Ab, cb) in enumerate(ells):
            if a == b:
                continue
            u = (pts - cb) @ np.linalg.inv(Ab)
            if np.all(np.einsum("ij,ij->i", u, u) < 1.0):
                containers[a].append(b)
    return rank_by_nesting(containers)


def ellipsoid_line_integrals(rays, ells, mu_mm, rank, *, chunk=1 << 17):
    """Exact line integral ``sum mu * length`` of each ray through the ellipsoids, where they
    overlap the highest ``rank`` among those containing a point gives the material (the
    renderer's rule), the ray ending at ``t_max``. ``mu_mm`` in 1/mm; returns ``(n_rays,)``."""
    o_all = np.broadcast_to(rays.origins, rays.directions.shape)
    n, nb = len(rays.directions), len(ells)
    inv = [(np.linalg.inv(A), c) for _, A, c in ells]
    by_rank = np.argsort(rank)
    out = np.zeros(n)
    for s in range(0, n, chunk):
        o, d = o_all[s:s + chunk], rays.directions[s:s + chunk]
        tmax = np.asarray(rays.t_max)[s:s + chunk]
        lo, hi = np.zeros((len(d), nb)), np.zeros((len(d), nb))
        for b, (Ai, c) in enumerate(inv):
            q, e = (o - c) @ Ai, d @ Ai          # ellipsoid coordinates: |q + t e| = 1
            aa = np.einsum("ij,ij->i", e, e)
            bb = np.einsum("ij,ij->i", q, e)
            cc = np.einsum("ij,ij->i", q, q) - 1.0
            disc = bb * bb - aa * cc
            hit = disc > 0
            sq = np.sqrt(np.where(hit, disc, 0.0))
            lo[:, b] = np.where(hit, np.clip((-bb - sq) / aa, 0.0, tmax), 0.0)
            hi[:, b] = np.where(hit, np.clip((-bb + sq) / aa, 0.0, tmax), 0.0)
        live = np.flatnonzero((hi > lo).any(axis=1))
        lo, hi = lo[live], hi[live]
        pts = np.sort(np.concatenate([lo, hi], axis=1), axis=1)
        mid = 0.5 * (pts[:, 1:] + pts[:, :-1])
        seg = np.diff(pts, axis=1)
        mu_seg = np.zeros_like(seg)
        for b in by_rank:                      # later (higher-ranked) bodies overwrite
            inside = (lo[:, b, None] < mid) & (mid < hi[:, b, None])
            mu_seg = np.where(inside, mu_mm[b], mu_seg)
        out[s + live] = (mu_seg * seg).sum(axis=1)
    return out


def shepp_logan_scene(meshes, shape):
    """The bundled ``shepp_logan`` scene (camera, materials, energy) with these meshes and a
    ``shape`` detector covering the same field of view."""
    import dataclasses

    import xray_viz

    base = xray_viz.load_scene("shepp_logan")
    by_name = {b.name: b for b in base.bodies}
    (w0, h0), (px, py) = base.detector.shape, base.detector.pitch
    det = dataclasses.replace(base.detector, shape=tuple(shape),
                              pitch=(px * (w0 - 1) / (shape[0] - 1),
                                     py * (h0 - 1) / (shape[1] - 1)))
    src = base.source
    if src.spectrum is not None:          # the line integral needs one energy
        src = dataclasses.replace(src, spectrum=None, energy=60.0)
    bodies = tuple(dataclasses.replace(by_name[name], mesh=mesh, source_file=None)
                   for name, mesh in meshes)
    return base.replace(source=src, detector=det, bodies=bodies)


def _mu_mm(scene):
    from xray_viz.physics.imaging import body_mu

    return body_mu(scene, [scene.source.energy])[0] / 10.0


def _pixel_line_integral(p_rays, n):
    """Per-pixel line integral ``-ln(mean over the pixel's n x n rays of exp(-p))``: the
    renderer's rule (intensities averaged over sub-rays)."""
    return -np.log(np.exp(-p_rays).reshape(-1, n * n).mean(axis=1))


def shepp_logan_pixel_reference(scene, ells, mu_mm, rank, *, m=16):
    """The analytic radiograph as a line integral per pixel: exact line integrals on an m x m
    sub-grid of each pixel (midpoint rule), intensities averaged, ``-ln`` of the mean."""
    w, h = scene.detector.shape
    acc = np.zeros(w * h)
    for k in _progress(range(m), desc="Shepp-Logan analytic reference", leave=False):
        p = ellipsoid_line_integrals(_subrow_rays(scene, m, k), ells, mu_mm, rank)
        acc += np.exp(-p).reshape(w * h, m).sum(axis=1)
    return -np.log(acc / (m * m))


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
    """Silence gVXR's log lines (stdout and stderr, fd-level) for the duration of a call;
    its errors still arrive as Python exceptions."""
    import contextlib

    @contextlib.contextmanager
    def ctx():
        import sys

        sys.stdout.flush()
        sys.stderr.flush()
        saved = [os.dup(1), os.dup(2)]
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, 1)
        os.dup2(devnull, 2)
        try:
            yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            for fd in saved + [devnull]:
                os.close(fd)

    return ctx()


# --------------------------------------------------------------------------------------------
# Suites


def _progress(iterable, *, desc, leave=None):
    """A progress bar over ``iterable`` on a terminal (:mod:`xray_viz.progress`; ``xray-viz
    -q bench`` turns it off)."""
    from xray_viz import progress

    return progress.iterate(iterable, desc)


def run_pareto(out, *, repeat, subdivisions, shape, supersamples, decimations,
               sl_subdivisions=(), sl_shape=(256, 256), sl_decimations=()):
    """Both time-vs-error series (sphere, Shepp-Logan): JSON, plot and Markdown tables."""
    rows = _pareto_sphere(repeat=repeat, subdivisions=subdivisions, shape=shape,
                          supersamples=supersamples, decimations=decimations)
    if sl_subdivisions or sl_decimations:
        rows += _pareto_shepp_logan(repeat=repeat, subdivisions=sl_subdivisions, shape=sl_shape,
                                    supersamples=supersamples, decimations=sl_decimations)
    (out / "pareto.json").write_text(json.dumps(rows, indent=1))
    _pareto_plot(rows, out / "pareto.png")
    table = _pareto_table(rows)
    (out / "pareto.md").write_text(table)
    return rows, table


def _pareto_sphere(*, repeat, subdivisions, shape, supersamples, decimations):
    """Sphere r = 40 mm: error of the path-length image (mm) against the exact chord averaged
    over each pixel (16 x 16 midpoint rule)."""
    from xray_viz.tracing.fast import trace_once

    levels = [("icosphere", k) for k in subdivisions] + [("decimated", n) for n in decimations]
    rows, truth = [], None
    for kind, level in _progress(levels, desc="pareto: sphere meshes"):
        if kind == "icosphere":
            mesh, label, hausdorff = sphere_mesh(level), f"icosphere {level}", 0.0
        else:
            (mesh, hausdorff), label = decimated_sphere(level), f"decimated {level}"
        scene = sphere_scene(mesh, shape)
        if truth is None:
            truth = analytic_pixel_average(scene)
        for n in supersamples:
            trace_once(scene, supersample=n)            # compile / warm caches
            t, L = median_time(lambda: trace_once(scene, supersample=n), repeat)
            img = L[:, 0].reshape(-1, n * n).mean(axis=1)
            err = img - truth
            rows.append(dict(phantom="sphere", mesh=label, faces=len(mesh.faces),
                             supersample=n, time_s=t, shape=list(shape),
                             max_error=float(np.abs(err).max()),
                             rms_error=float(np.sqrt(np.mean(err ** 2))),
                             quantity="path length (mm)", hausdorff_mm=hausdorff))
    return rows


def _pareto_shepp_logan(*, repeat, subdivisions, shape, supersamples, decimations):
    """Shepp-Logan head (ten ellipsoids, materials of the bundled scene at its energy): error of
    the line-integral image ``-ln(I/I0)`` against the analytic radiograph."""
    import gc

    from xray_viz.geometry import detector_rays
    from xray_viz.tracing.fast import trace_once

    ells = shepp_logan_ellipsoids()
    rank = ellipsoid_precedence(ells)
    levels = [("icosphere", k) for k in subdivisions] + [("decimated", n) for n in decimations]
    rows, truth, same_ray_truth = [], None, {}
    for kind, level in _progress(levels, desc="pareto: Shepp-Logan meshes"):
        if kind == "icosphere":
            meshes, hausdorff = shepp_logan_meshes(level)
            label = f"icosphere {level}"
        else:
            meshes, hausdorff = shepp_logan_meshes(decimate_to=level)
            label = f"decimated {level}/ellipsoid"
        scene = shepp_logan_scene(meshes, shape)
        mu = _mu_mm(scene)
        precedence_ok = bool(np.array_equal(scene.precedence, rank))
        if truth is None:
            truth = shepp_logan_pixel_reference(scene, ells, mu, rank)
        for n in supersamples:
            if n not in same_ray_truth:   # exact line integrals on the renderer's own sub-rays
                p = ellipsoid_line_integrals(detector_rays(scene, supersample=n), ells, mu, rank)
                same_ray_truth[n] = _pixel_line_integral(p, n)

            def frame():
                return _pixel_line_integral(trace_once(scene, supersample=n) @ mu, n)

            frame()                                      # compile / warm caches
            t, img = median_time(frame, repeat)
            err, err_same = img - truth, img - same_ray_truth[n]
            rows.append(dict(phantom="shepp_logan", mesh=label,
                             faces=int(sum(len(m.faces) for _, m in meshes)), supersample=n,
                             time_s=t, shape=list(shape),
                             max_error=float(np.abs(err).max()),
                             rms_error=float(np.sqrt(np.mean(err ** 2))),
                             max_error_same_rays=float(np.abs(err_same).max()),
                             rms_error_same_rays=float(np.sqrt(np.mean(err_same ** 2))),
                             quantity="line integral -ln(I/I0)", hausdorff_mm=hausdorff,
                             precedence_matches_analytic=precedence_ok,
                             max_line_integral=float(truth.max())))
        scene = meshes = None           # 13M faces at subdivision 8: free them before the next
        gc.collect()
    return rows


#: Error budgets drawn on the plot and listed in the table, per phantom and error key.
_BUDGETS = (3.0, 1.0, 0.3, 0.1, 0.03, 0.01, 0.003, 0.001, 0.0003)

_PHANTOM_TITLES = {"sphere": "sphere r = 40 mm", "shepp_logan": "Shepp-Logan head (10 ellipsoids)"}


def _pareto_front(rows, key):
    front = []
    for r in sorted(rows, key=lambda r: r["time_s"]):
        if not front or r[key] < front[-1][key]:
            front.append(r)
    return front


def _budget_choices(rows, key, *, collapse=False):
    """``[(budget, cheapest row meeting it or None)]`` for the budgets between the worst and
    best error measured, down to the first budget not met. ``collapse``: of budgets with the
    same answer keep only the tightest (the plot's labels)."""
    out = []
    best = min(r[key] for r in rows)
    for budget in _BUDGETS:
        if budget > max(r[key] for r in rows):
            continue
        ok = [r for r in rows if r[key] <= budget]
        out.append((budget, min(ok, key=lambda r: r["time_s"]) if ok else None))
        if budget < best:
            break
    if collapse:
        out = [c for i, c in enumerate(out)
               if i + 1 == len(out) or c[1] is None or out[i + 1][1] is not c[1]]
    return out


def _short(r):
    faces = r["faces"]
    size = (f"{faces / 1e6:.1f}M" if faces >= 1e6 else f"{faces / 1e3:.0f}k" if faces >= 1e4
            else f"{faces / 1e3:.1f}k" if faces >= 1e3 else str(faces))
    level = r["mesh"].split()[1]
    mesh = f"ico {level}" if r["mesh"].startswith("icosphere") else f"decimated {level}"
    return f"{mesh}, {size} faces, {r['supersample']}x{r['supersample']}"


def _pareto_plot(rows, path):
    """One column per phantom, RMS error (top) and max error (bottom) against time. Each error
    budget is a dotted line labelled (right margin) with the cheapest measured setting meeting
    it, marked by a gold star joined to its line."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import FuncFormatter, LogLocator

    phantoms = list(dict.fromkeys(r["phantom"] for r in rows))
    fig, axes = plt.subplots(2, len(phantoms), figsize=(8.6 * len(phantoms), 10), squeeze=False)
    markers = {1: "o", 2: "s", 4: "^"}
    colors = {1: "C0", 2: "C1", 4: "C2"}
    plain = FuncFormatter(lambda v, _: f"{v:g}")
    for col, ph in enumerate(phantoms):
        sel_ph = [r for r in rows if r["phantom"] == ph]
        unit = sel_ph[0]["quantity"]
        shape = sel_ph[0]["shape"]
        for row_i, (key, title) in enumerate((("rms_error", "RMS error"),
                                              ("max_error", "max error"))):
            ax = axes[row_i, col]
            for n in sorted({r["supersample"] for r in sel_ph}):
                for deci in (False, True):
                    sel = [r for r in sel_ph if r["supersample"] == n
                           and r["mesh"].startswith("decimated") == deci]
                    if not sel:
                        continue
                    c = colors.get(n, "C3")
                    ax.scatter([r["time_s"] * 1e3 for r in sel], [r[key] for r in sel],
                               marker=markers.get(n, "x"), edgecolors=c, s=36, zorder=3,
                               facecolors="none" if deci else c,
                               label=f"{n}x{n} rays/pixel, " + ("pymeshlab decimated" if deci
                                                                else "icosphere"))
            front = _pareto_front(sel_ph, key)
            ax.plot([r["time_s"] * 1e3 for r in front], [r[key] for r in front], "k--", lw=1,
                    zorder=2, label="Pareto front")
            ax.set_xscale("log")
            ax.set_yscale("log")
            lo = min(r[key] for r in sel_ph)
            hi = max(r[key] for r in sel_ph)
            ax.set_ylim(lo / 3, hi * 2)
            for budget, best in _budget_choices(sel_ph, key, collapse=True):
                ax.axhline(budget, color="0.55", lw=0.9, ls=":", zorder=1)
                if best is None:
                    text, color = f"<= {budget:g}: not reached", "0.45"
                else:
                    text = f"<= {budget:g}: {_short(best)}, {best['time_s'] * 1e3:.3g} ms"
                    color = "k"
                    x, y = best["time_s"] * 1e3, best[key]
                    ax.plot([x, x], [y, budget], color="goldenrod", lw=1, zorder=3)
                    ax.plot(x, y, marker="*", ms=13, mfc="gold", mec="k", zorder=4, ls="none")
                ax.annotate(text, xy=(1.01, budget), xycoords=("axes fraction", "data"),
                            ha="left", va="center", fontsize=7.5, color=color,
                            annotation_clip=False)
            ax.set_xlabel("render time per image (ms, median)")
            ax.set_ylabel(f"{title} of the {unit}")
            ax.set_title(f"{_PHANTOM_TITLES.get(ph, ph)}, {shape[0]}x{shape[1]}: {title}",
                         fontsize=10)
            ax.xaxis.set_major_formatter(plain)
            ax.xaxis.set_minor_locator(LogLocator(subs=(2, 5)))
            ax.xaxis.set_minor_formatter(plain)
            ax.tick_params(axis="x", which="minor", labelsize=7)
            ax.grid(True, which="both", alpha=0.25)
            if row_i == 1:
                ax.legend(fontsize=7, loc="lower left")
    fig.suptitle("Fast engine, time vs error. Which setting for an error budget: each dotted "
                 "line is a budget, labelled on the right with the cheapest measured setting "
                 "meeting it (gold star)", fontsize=10.5)
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    fig.savefig(path, dpi=90, bbox_inches="tight")
    plt.close(fig)


def _pareto_table(rows):
    lines = []
    for ph in dict.fromkeys(r["phantom"] for r in rows):
        sel = [r for r in rows if r["phantom"] == ph]
        unit = sel[0]["quantity"]
        same = "max_error_same_rays" in sel[0]
        lines += [f"### {_PHANTOM_TITLES.get(ph, ph)}, {sel[0]['shape'][0]}x{sel[0]['shape'][1]}"
                  f" (error of the {unit})", ""]
        head = "| mesh | faces | supersample | time (ms) | max error | RMS error |"
        rule = "|---|---|---|---|---|---|"
        if same:
            head += " max / RMS error on the same sub-rays | precedence as analytic |"
            rule += "---|---|"
        lines += [head, rule]
        for r in sel:
            line = (f"| {r['mesh']} | {r['faces']} | {r['supersample']} | "
                    f"{r['time_s'] * 1e3:.2f} | {r['max_error']:.3g} | {r['rms_error']:.3g} |")
            if same:
                line += (f" {r['max_error_same_rays']:.3g} / {r['rms_error_same_rays']:.3g} | "
                         f"{'yes' if r['precedence_matches_analytic'] else 'NO'} |")
            lines.append(line)
        for key, name in (("rms_error", "RMS"), ("max_error", "max")):
            lines += ["", f"Fastest measured setting for a {name} error budget ({unit}):", "",
                      f"| {name} budget | use | time (ms) | RMS / max error |", "|---|---|---|---|"]
            for budget, best in _budget_choices(sel, key):
                if best is None:
                    lines.append(f"| {budget:g} | not reached (best measured: "
                                 f"{min(r[key] for r in sel):.3g}) | | |")
                else:
                    lines.append(f"| {budget:g} | {best['mesh']} ({best['faces']} faces), "
                                 f"supersample {best['supersample']} | "
                                 f"{best['time_s'] * 1e3:.2f} | "
                                 f"{best['rms_error']:.3g} / {best['max_error']:.3g} |")
        lines.append("")
    return "\n".join(lines) + "\n"


#: Appended to every "peer unavailable" message.
INSTALL_HINT = ("install the peers with: pip install -e '.[bench]' and bash benchmarks/setup.sh "
                "(setup.sh also installs the Debian packages Open3D and gVXR load)")


def _unavailable(name, exc):
    """A peer that cannot be imported: its message with how to install it (also on stderr)."""
    import sys

    msg = f"{type(exc).__name__}: {exc}" if not isinstance(exc, ImportError) else str(exc)
    if isinstance(exc, (ImportError, OSError)):
        msg = f"{msg}; {INSTALL_HINT}"
    if name not in _WARNED:
        _WARNED.add(name)
        print(f"bench: peer {name} unavailable: {msg}", file=sys.stderr)
    return msg


_WARNED: set = set()


def fast_build_time(scene, warm_s, repeat=3):
    """The fast engine's per-mesh set-up: ``clear_caches(scene)`` then a first trace, minus a warm
    trace (median of ``repeat``)."""
    from xray_viz.tracing.fast import clear_caches, trace_once

    times = []
    for _ in range(repeat):
        clear_caches(scene)
        t0 = time.perf_counter()
        trace_once(scene)
        times.append(time.perf_counter() - t0)
    return max(float(np.median(times)) - warm_s, 0.0)


def fast_render_frames(mesh, shape, repeat):
    """What a user pays per frame for ``xray_viz.render``: a new Scene with the source moved
    (by a micrometre per frame, so the path-length cache misses and the geometry is re-traced)
    then ``render`` (trace + Beer-Lambert image).

    The new Scene is ``scene.replace(source=...)``, the documented way to move the source: it
    keeps the scene's :class:`~xray_viz.bodies.Bodies`, which hold the mesh checks and the
    per-mesh set-up (no module-level caches since issue 13), so a frame pays neither. A Scene
    built from new ``Body`` objects each frame makes new Bodies and pays the per-mesh set-up
    (and a mesh check from the disk cache) every frame: that is a first render, timed by the
    build column and by ``benchmarks/first_render.py``.

    Returns medians (seconds) of the whole frame and of the Scene construction alone.
    """
    import dataclasses

    import xray_viz

    base = sphere_scene(mesh, shape)
    frames, builds = [], []
    for k in range(repeat + 1):
        t0 = time.perf_counter()
        src = dataclasses.replace(base.source, position=[1e-3 * (k + 1), 0.0, 1000.0])
        scene = base.replace(source=src)
        t1 = time.perf_counter()
        xray_viz.render(scene)
        t2 = time.perf_counter()
        if k:                              # the first frame also pays the per-mesh set-up
            frames.append(t2 - t0)
            builds.append(t1 - t0)
    return float(np.median(frames)), float(np.median(builds))


def run_peers(out, *, repeat, subdivisions, shape):
    from xray_viz.geometry import detector_rays

    results = []
    for sub in _progress(subdivisions, desc="peers meshes"):
        mesh = sphere_mesh(sub)
        scene = sphere_scene(mesh, shape)
        rays = detector_rays(scene)
        truth = sphere_chord(rays.origins, rays.directions)
        faces = len(mesh.faces)
        fast_engine(scene)
        t, L = median_time(lambda: fast_engine(scene), repeat)
        err = float(np.abs(L - truth).max())
        build = fast_build_time(scene, t)
        results.append(dict(mesh_faces=faces, shape=list(shape), engine="fast",
                            build_s=build, query_s=t, max_error_mm=err,
                            what="trace_once: a full re-trace, no result cache"))
        t_frame, t_scene = fast_render_frames(mesh, shape, repeat)
        results.append(dict(mesh_faces=faces, shape=list(shape), engine="fast render()",
                            build_s=build, query_s=t_frame, scene_s=t_scene, max_error_mm=err,
                            what="new Scene + xray_viz.render (trace + image) per frame"))
        reps = 1 if faces > 400_000 else repeat
        t, L = median_time(lambda: numpy_engine(scene), reps)
        results.append(dict(mesh_faces=faces, shape=list(shape), engine="numpy", build_s=None,
                            query_s=t, max_error_mm=float(np.abs(L - truth).max())))
        for name, make in PEERS.items():
            try:
                build, query = make()
            except (ImportError, OSError) as exc:
                results.append(dict(mesh_faces=faces, engine=name,
                                    unavailable=_unavailable(name, exc)))
                continue
            reps = 1 if name.startswith("pyvista") and faces > 400_000 else repeat
            t_build, state = median_time(lambda: build(mesh), 1)
            try:
                # Open3D and embree build their BVH lazily, inside the first query: that extra
                # cost over a warm query belongs to the build, as the fast engine's set-up does.
                t_first, _ = median_time(lambda: query(state, rays), 1)
                t, L = median_time(lambda: query(state, rays), reps)
                t_build += max(t_first - t, 0.0)
            except Exception as exc:        # a peer failing is a result, not a crash
                results.append(dict(mesh_faces=faces, engine=name,
                                    unavailable=f"{type(exc).__name__}: {exc}"))
                continue
            if name.startswith("pyvista"):
                t_build = None     # multi_ray_trace rebuilds its acceleration structure per call
            results.append(dict(mesh_faces=faces, shape=list(shape), engine=name,
                                build_s=t_build, query_s=t,
                                max_error_mm=float(np.abs(L - truth).max())))
        results.extend(_gvxr_row(mesh, scene, truth, repeat))
    cube = cube_suite()
    (out / "peers.json").write_text(json.dumps(dict(sphere=results, cube=cube), indent=1))
    table = _peers_table(results, cube)
    (out / "peers.md").write_text(table)
    return results, cube, table


def _gvxr_row(mesh, scene, truth, repeat):
    try:
        build, query = peer_gvxr()
    except (ImportError, OSError) as exc:
        return [dict(mesh_faces=len(mesh.faces), engine="gvxr",
                     unavailable=_unavailable("gvxr", exc))]
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
            except (ImportError, OSError) as exc:
                rows.append(dict(kind=kind, engine=name, unavailable=f"{exc}; {INSTALL_HINT}"))
                continue
            try:
                rows.append(dict(kind=kind, engine=name, wrong=wrong(query(build(mesh), rays))))
            except Exception as exc:
                rows.append(dict(kind=kind, engine=name, unavailable=str(exc)))
        try:
            build, query = peer_gvxr()
        except (ImportError, OSError) as exc:
            rows.append(dict(kind=kind, engine="gvxr", unavailable=f"{exc}; {INSTALL_HINT}"))
            continue
        try:
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
             "x fast trace | x Open3D (query) | x Open3D (build + query) | "
             "max error vs exact sphere (mm) |",
             "|---|---|---|---|---|---|---|---|"]
    by_faces = {}
    for r in results:
        by_faces.setdefault(r["mesh_faces"], []).append(r)
    missing = False
    for faces, rs in by_faces.items():
        fast = next((r for r in rs if r["engine"] == "fast"), None)
        o3d = next((r for r in rs if r["engine"] == "open3d" and "query_s" in r), None)
        for r in rs:
            if "unavailable" in r:
                missing = True
                lines.append(f"| {faces} | {r['engine']} | - | unavailable: "
                             f"{r['unavailable'].split('; install')[0]} | | | | |")
                continue
            b = r["build_s"] or 0.0
            x_fast = r["query_s"] / fast["query_s"] if fast else float("nan")
            x_o3d = r["query_s"] / o3d["query_s"] if o3d else float("nan")
            x_o3d_b = (b + r["query_s"]) / (o3d["query_s"] + o3d["build_s"]) if o3d \
                else float("nan")
            build = "-" if r["build_s"] is None else f"{r['build_s'] * 1e3:.1f}"
            query = f"{r['query_s'] * 1e3:.1f}"
            if "scene_s" in r:
                query += f" (Scene {r['scene_s'] * 1e3:.1f})"
            lines.append(f"| {faces} | {r['engine']} | {build} | {query} | {x_fast:.2f} | "
                         f"{x_o3d:.3f} | {x_o3d_b:.3f} | {r['max_error_mm']:.3g} |")
    lines += ["", "fast: `trace_once`, a full re-trace (projection, raster, path lengths) with "
              "the per-mesh set-up cached; build = `clear_caches(scene)` then a first trace, minus a "
              "warm trace. fast render(): per frame a new `Scene` (`scene.replace(source=...)`, "
              "source moved 1 um, so nothing but the bodies' mesh checks and per-mesh set-up "
              "is reused) and `xray_viz.render` (trace + image); the Scene part in brackets. pyvista rebuilds inside every call (build -)."]
    if missing:
        lines += ["", f"Some peers are unavailable: {INSTALL_HINT}."]
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
        description="Benchmarks of the engines: run time against error (sphere and Shepp-Logan "
                    "at increasing mesh resolution and supersampling, with a Pareto plot), the "
                    "peers side by side on the same rays (Open3D, trimesh+embree, pyvista, "
                    "gVXR: install them with pip install -e '.[bench]' and bash "
                    "benchmarks/setup.sh), and scaling with triangles and pixels. Results go "
                    "to --out as JSON, Markdown tables and PNG plots. See BENCHMARKS.md.")
    p.add_argument("--suite", choices=("all", "pareto", "peers", "scaling"), default="all",
                   help="which benchmark to run (default: %(default)s)")
    p.add_argument("--out", default="benchmarks/results", metavar="DIR",
                   help="directory for JSON, Markdown tables and plots (default: %(default)s)")
    p.add_argument("--repeat", type=int, default=7, metavar="N",
                   help="timed runs per measurement; the median is reported (default: 7)")
    p.add_argument("--quick", action="store_true",
                   help="smaller meshes and detectors: about a minute (62 s measured on 2 "
                        "cores, numba kernels cached) instead of ~6 min for the full suites")
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
            decimations=() if quick else (1280, 5120, 20480, 81920),
            sl_subdivisions=range(1, 6 if quick else 9),
            sl_shape=(128, 128) if quick else (256, 256),
            sl_decimations=() if quick else (1280, 5120, 20480, 81920))
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


def main(argv=None) -> int:
    """``python benchmarks/suites.py [--suite ...]``: parse ``argv`` and run the suites."""
    import argparse

    parser = argparse.ArgumentParser(prog="xray-viz")
    add_bench_parser(parser.add_subparsers(dest="command", required=True))
    ns = parser.parse_args(["bench", *(argv if argv is not None else __import__("sys").argv[1:])])
    return int(ns.func(ns))


if __name__ == "__main__":  # pragma: no cover
    import sys

    from xray_viz import progress

    progress.configure(enabled=sys.stderr.isatty())
    raise SystemExit(main())

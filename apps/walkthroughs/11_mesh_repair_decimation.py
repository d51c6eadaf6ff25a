"""
Mesh repair and decimation: what they do to accuracy and speed
==============================================================

The tracer's path lengths rest on one assumption: every body is a **closed, outward-oriented**
surface. Then along any ray entries and exits alternate, and the chord is "exits minus entries",
:math:`L = \\sum \\pm t` (walkthrough 7). Meshes from CAD tools or segmentations often break it:

* a **hole** (missing triangles): a ray through it misses an entry or an exit, and :math:`L` is off
  by a whole :math:`t`, about a metre for a source 1 m away;
* **flipped triangles** (inside-out normals): an entry is counted as an exit, same damage;
* a **triangle soup** (every triangle with its own copies of the vertices, as STL stores them): the
  triangles do not know their neighbours, so nothing can be checked or repaired until equal
  vertices are merged.

:func:`xray_viz.meshes.repair_mesh` fixes these with pymeshlab (and the scene loader does it for
you, with a warning). Then, the other way round: a good mesh may have far more triangles than
the image needs. :func:`xray_viz.meshes.decimate` removes triangles by quadric edge collapse,
keeping the surface closed. Fewer triangles render faster, but the polyhedron moves away from
the true surface. We measure both.
"""

# %%
# Breaking a ball
# ---------------
# An icosphere of radius 40 mm with 1280 triangles; then a soup of it with 5 triangles removed
# and 40 flipped.
import time

import numpy as np
import trimesh

import xray_viz
from xray_viz.meshes import check_mesh, decimate, repair_mesh
from xray_viz.scene import Body, Detector, Scene, Source
from xray_viz.tracing import trace_triangles
from xray_viz.tracing.fast import clear_caches
from xray_viz.walkthroughs import new_plotter, pyplot, show_or_save, show_or_save_figure

WALKTHROUGH = 11

ball = trimesh.creation.icosphere(subdivisions=3, radius=40.0)
rng = np.random.default_rng(3)
faces = ball.faces.copy()
flip = rng.choice(len(faces), 40, replace=False)
faces[flip] = faces[flip][:, ::-1]
keep = np.setdiff1d(np.arange(len(faces)), rng.choice(len(faces), 5, replace=False))
soup = ball.vertices[faces[keep]].reshape(-1, 3)
broken = trimesh.Trimesh(soup, np.arange(len(soup)).reshape(-1, 3), process=False)
report = check_mesh(broken)
print(f"broken: {report.faces} faces, {report.vertices} vertices, watertight {report.watertight}, "
      f"boundary edges {report.boundary_edges}, outward {report.outward}")

# %%
# What the damage does to the path lengths
# ----------------------------------------
# A parallel beam on a 1 mm grid straight through the ball; each ray's :math:`L = \sum \pm t`
# (sign from the triangle's normal) is compared with the intact mesh's chord.
g = np.arange(-44.5, 45.0, 1.0)
gx, gy = np.meshgrid(g, g)
origins = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, 1000.0)])
directions = np.broadcast_to([0.0, 0.0, -1.0], origins.shape)


def chords(mesh):
    """Path length of every ray through one mesh: sum of +t at exits, -t at entries."""
    ray, _, t, _, entering = trace_triangles(mesh.vertices[mesh.faces], origins, directions)
    return np.bincount(ray, weights=np.where(entering, -t, t), minlength=len(origins))


L_intact = chords(ball)
L_broken = chords(broken)
wrong = np.abs(L_broken - L_intact) > 0.5
print(f"broken mesh: {int(wrong.sum())} of {len(origins)} rays off by more than 0.5 mm, "
      f"worst by {np.abs(L_broken - L_intact).max():.0f} mm")

# %%
# Repair
# ------
# Merge duplicate vertices, remove degenerate faces, close holes, orient every face outward
# (FIELD-NOTES section 7 lists the pymeshlab filters, in this order). The report says what
# changed.
t0 = time.perf_counter()
fixed, rep = repair_mesh(broken)
t_repair = time.perf_counter() - t0
print(rep.table())
L_fixed = chords(fixed)
err_fixed = np.abs(L_fixed - L_intact)
print(f"repaired in {t_repair:.2f} s: {int((err_fixed > 0.5).sum())} rays off by more than 0.5 mm,"
      f" worst by {err_fixed.max():.3f} mm")

# %%
# The metre-sized errors are gone. Holes are closed with new flat triangles; here each hole was
# one or two missing triangles, and the patch is (nearly) the triangles that were removed, so the
# repaired chords match the intact mesh. A big hole would be patched with a flat cap and leave a
# dent. Note the "before" column: a soup is "winding consistent" and "outward" only because no
# two triangles share an edge that could disagree; the 3825 boundary edges give it away.
#
# The picture: the broken mesh (flipped triangles in red, the edges of the holes outlined in
# black) and the repair.
import pyvista as pv  # noqa: E402

plotter = new_plotter(shape=(1, 2), window_size=(1400, 700))
plotter.subplot(0, 0)
plotter.add_text("broken: 5 holes, 40 flipped triangles, a soup", font_size=12, color="black",
                 position="lower_left")
pv_broken = pv.wrap(broken)
is_flipped = np.isin(keep, flip).astype(float)
pv_broken.cell_data["flipped"] = is_flipped
plotter.add_mesh(pv_broken, scalars="flipped", cmap=["lightsteelblue", "red"], show_edges=True,
                 show_scalar_bar=False)
edges = pv.wrap(trimesh.Trimesh(ball.vertices, faces[keep], process=False)).extract_feature_edges(
    boundary_edges=True, feature_edges=False, manifold_edges=False, non_manifold_edges=False)
plotter.add_mesh(edges, color="black", line_width=6)
plotter.subplot(0, 1)
plotter.add_text(f"repaired: {rep.after.faces} faces, watertight {rep.after.watertight}",
                 font_size=12, color="black", position="lower_left")
plotter.add_mesh(pv.wrap(fixed), color="lightsteelblue", show_edges=True)
plotter.link_views()
plotter.camera_position = [(120.0, -140.0, 110.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)]
show_or_save(plotter, "repair", walkthrough=WALKTHROUGH)

# %%
# Decimation: triangles against error against time
# -------------------------------------------------
# An icosphere with 81 920 triangles, decimated to 5120, 1280 and 320. For each level: the
# Hausdorff distance to the original (the largest distance between the two surfaces, measured
# by pymeshlab), the worst and RMS error of the rays' chords against the *ideal* sphere, and the
# render time of a 128 x 128 radiograph with both engines: the best of 3 renders, so that a
# render that happened to share the processor with something else does not make a spike. The
# fast engine caches path lengths per geometry (a second render of the same mesh is free), so
# its caches are cleared before each run: every time is that of a first, "cold" render.
fine = trimesh.creation.icosphere(subdivisions=6, radius=40.0)
detector = Detector(center=[0.0, 0.0, -500.0], shape=(128, 128), pitch=1.0)
source = Source(position=[0.0, 0.0, 1000.0])
rays = xray_viz.detector_rays(Scene(source, detector, ()))
b = np.linalg.norm(np.cross(-rays.origins, rays.directions), axis=1)   # ray-centre distances
ideal = 2 * np.sqrt(np.clip(40.0**2 - b**2, 0, None))

t0 = time.perf_counter()
xray_viz.render(Scene(source, Detector(center=[0, 0, -500], shape=(2, 2)),
                      (Body(name="warm", mesh=ball, mu=0.2),)), engine="fast")
print(f"fast engine ready in {time.perf_counter() - t0:.1f} s (numba compiles on first use, "
      "then caches)")
levels = []
print("  faces   Hausdorff (mm)   chord error max / RMS (mm)   render numpy / fast (ms, best of 3)")
for target in (None, 5120, 1280, 320):
    mesh, hausdorff = (fine, 0.0) if target is None else decimate(fine, target_faces=target)
    scene = Scene(source, detector, (Body(name="ball", mesh=mesh, mu=0.2),))
    times = {}
    for engine in ("numpy", "fast"):
        best = []
        for _ in range(3):                        # best of 3: the least disturbed run
            clear_caches(scene)                   # a cold render, not a cache hit
            image = xray_viz.render(scene, engine=engine)
            best.append(image.timing["total"])
        times[engine] = min(best)
    err = image.total_path_length.ravel() - ideal
    levels.append((len(mesh.faces), hausdorff, np.abs(err).max(), np.sqrt(np.mean(err**2)),
                   times["numpy"], times["fast"], mesh))
    print(f"{len(mesh.faces):7d} {hausdorff:14.3f} {np.abs(err).max():16.3f} / "
          f"{np.sqrt(np.mean(err**2)):.4f} {1000 * times['numpy']:13.0f} / "
          f"{1000 * times['fast']:.0f}")

# %%
# The worst chord errors sit at the rim, where a ray can cross the ideal sphere but just miss the
# polyhedron inside it. The chord error grows roughly as 1/faces (the gap between a flat triangle
# and the sphere goes as the square of the triangle's size), and it is an *error of the geometry*,
# not of the arithmetic: every correct engine gives the same numbers for the same mesh. The render
# time falls far less than the triangle count, because part of it is per ray, not per triangle.
# Decimate to the error you can accept (``decimate(mesh, max_error=0.1)`` bisects for it), not
# further.
plt = pyplot()
fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(11, 4.5))
nf = np.array([lv[0] for lv in levels])
ax1.loglog(nf, [lv[2] for lv in levels], "o-", label="max chord error")
ax1.loglog(nf, [lv[3] for lv in levels], "s-", label="RMS chord error")
ax1.loglog(nf[1:], [lv[1] for lv in levels[1:]], "^--", label="Hausdorff to the 81 920-face mesh")
ax1.set_xlabel("triangles")
ax1.set_ylabel("mm")
ax1.set_title("accuracy against the ideal sphere")
ax1.legend()
ax2.loglog(nf, [1000 * lv[4] for lv in levels], "o-", label="numpy engine")
ax2.loglog(nf, [1000 * lv[5] for lv in levels], "s-", label="fast engine (numba)")
ax2.set_xlabel("triangles")
ax2.set_ylabel("render time, 128 x 128 (ms, best of 3)")
ax2.set_title("speed")
ax2.legend()
fig.tight_layout()
show_or_save_figure(fig, "error_and_time", walkthrough=WALKTHROUGH)

plotter = new_plotter(shape=(1, 4), window_size=(1600, 450))
for k, lv in enumerate(levels):
    plotter.subplot(0, k)
    plotter.add_text(f"{lv[0]} faces\nmax chord error {lv[2]:.2f} mm", font_size=11,
                     color="black", position="lower_left")
    plotter.add_mesh(pv.wrap(lv[6]), color="lightsteelblue", show_edges=lv[0] <= 5120)
plotter.link_views()
plotter.camera_position = [(0.0, -230.0, 90.0), (0.0, 0.0, 8.0), (0.0, 0.0, 1.0)]
show_or_save(plotter, "decimation_levels", walkthrough=WALKTHROUGH)

"""
Shared edges: why the textbook test double-counts, and the watertight fix
=========================================================================

A closed mesh is a surface of triangles that share edges and corners. A ray that passes *exactly*
through a shared edge touches two triangles at once. The textbook Moller-Trumbore test of
walkthrough 6 accepts a point on an edge (:math:`\\beta, \\gamma \\ge 0`, :math:`\\beta + \\gamma \\le 1`
with equality allowed), so it reports the crossing **twice**, once per triangle.

For a camera picture that is harmless: the nearest hit is the same point either way. For an
X-ray it is not. The path length through a closed body is "exits minus entries",
:math:`L = \\sum \\pm t` (walkthrough 7): a doubled entry adds a whole :math:`-t` (about a metre
from a source 1 m away), and a doubled entry *and* exit doubles the chord. Rays through edges are
not rare either: on a regular detector grid, whole rows of pixels line up with a box's edges.

The fix is a **watertight** test (Woop, Benthin and Wald, JCGT 2013): decide the edge tests with
exact signs, and break exact ties (the ray exactly on an edge) with a fixed rule that gives the
edge to exactly one of its two triangles. xray_viz's engine uses it
(:func:`~xray_viz.tracing.intersect.watertight_intersect`).
"""

# %%
# The workload: a 12-triangle cube
# --------------------------------
# The cube :math:`[-20, 20]^3` mm as 12 triangles (two per face, split along a diagonal). Two
# beams, both on a 0.5 mm grid: a parallel beam whose rays include :math:`x, y \in \{0, \pm 20\}`
# (the middle of the faces, and rays *in* the side faces' planes), and a point source 1 m away.
import numpy as np
import trimesh

import xray_viz
from xray_viz.scene import Body, Detector, Scene, Source
from xray_viz.tracing.intersect import moller_trumbore
from xray_viz.walkthroughs import new_plotter, pyplot, segments, show_or_save, show_or_save_figure

WALKTHROUGH = 10

cube = trimesh.creation.box(extents=(40.0, 40.0, 40.0))
print(f"cube: {len(cube.faces)} triangles, watertight {cube.is_watertight}, "
      f"volume {cube.volume:.0f} mm^3")
beams = {
    "parallel": Scene(Source(position=[0.0, 0.0, 1000.0], kind="parallel"),
                      Detector(center=[0.0, 0.0, -500.0], shape=(101, 101), pitch=0.5),
                      (Body(name="cube", mesh=cube, mu=0.2),)),
    "point source": Scene(Source(position=[0.0, 0.0, -1000.0]),
                          Detector(center=[0.0, 0.0, 249.5], shape=(255, 255), pitch=0.5),
                          (Body(name="cube", mesh=cube, mu=0.2),)),
}


# %%
# Both tests on every ray
# -----------------------
# The textbook test runs on every ray-triangle pair; the chord is :math:`\sum \pm t` with the sign
# of :math:`\hat d \cdot \vec n` (exit +, entry -). The watertight engine's hits go through the
# same sum. The reference is the exact chord of a box (the "slab" method: intersect the three
# pairs of planes). A ray that only grazes the cube (along a face, or through a silhouette edge)
# may count as 0 or as the full chord: both are accepted.
def textbook_chords(rays, mesh, *, strict=False):
    """Chords from the textbook test; ``strict`` rejects points on an edge (beta, gamma > 0,
    beta + gamma < 1) instead of accepting them."""
    tris = mesh.vertices[mesh.faces]
    normals = np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0])
    n_r, n_t = len(rays), len(tris)
    ray = np.repeat(np.arange(n_r), n_t)
    tri = np.tile(np.arange(n_t), n_r)
    hit, t, beta, gamma = moller_trumbore(rays.origins[ray], rays.directions[ray], tris[tri, 0],
                                          tris[tri, 1], tris[tri, 2], t_max=rays.t_max[ray])
    if strict:
        with np.errstate(invalid="ignore"):
            hit &= (beta > 0) & (gamma > 0) & (beta + gamma < 1)
    sign = np.sign(np.einsum("ij,ij->i", rays.directions[ray], normals[tri]))
    L = np.bincount(ray[hit], weights=(sign * t)[hit], minlength=n_r)
    return L, np.bincount(ray[hit], minlength=n_r)


def watertight_chords(scene, rays):
    hits = xray_viz.trace_rays(scene, rays.origins, rays.directions, t_max=rays.t_max)
    signed = np.where(hits.entering, -hits.t, hits.t)
    n = len(rays)
    return np.bincount(hits.ray, weights=signed, minlength=n), np.bincount(hits.ray, minlength=n)


def slab_chords(rays, lo=-20.0, hi=20.0):
    o, d = rays.origins, rays.directions
    with np.errstate(divide="ignore", invalid="ignore"):
        t1, t2 = (lo - o) / d, (hi - o) / d
    inside = (o >= lo) & (o <= hi)
    tn = np.where(d == 0, np.where(inside, -np.inf, np.inf), np.minimum(t1, t2)).max(axis=1)
    tf = np.where(d == 0, np.where(inside, np.inf, -np.inf), np.maximum(t1, t2)).min(axis=1)
    chord = np.where(tf > tn, tf - tn, 0.0)
    # Grazing rays: on the boundary of the cube's shadow (a face plane or a silhouette edge).
    grazing = np.isclose(tf, tn, atol=1e-9) | np.any(
        (d == 0) & (np.isclose(o, lo) | np.isclose(o, hi)), axis=1)
    return chord, grazing


results = {}
for name, scene in beams.items():
    rays = xray_viz.detector_rays(scene)
    exact, grazing = slab_chords(rays)
    row = {}
    for test, (L, count) in (("textbook", textbook_chords(rays, cube)),
                             ("watertight", watertight_chords(scene, rays))):
        ok = np.isclose(L, exact, atol=1e-6) | (grazing & np.isclose(L, 0.0, atol=1e-6))
        row[test] = (~ok, L, count)
        print(f"{name:>12s} beam, {test:>10s} test: {int((~ok).sum())} of {len(rays)} rays wrong")
    results[name] = (rays, exact, grazing, row)

# %%
# The centre ray of the point-source beam goes exactly through the centre of the near and far
# faces, which is where each face's diagonal runs:
rays, exact, grazing, row = results["point source"]
centre = (len(rays) - 1) // 2
for test in ("textbook", "watertight"):
    wrong, L, count = row[test]
    print(f"centre ray, {test:>10s}: {count[centre]} hits, L = {L[centre]:.1f} mm "
          f"(exact {exact[centre]:.1f} mm)")

# %%
# Four hits (two per face, one per triangle) give :math:`L = 80` mm instead of 40: twice the
# attenuation. Rays through an edge between a front and a side face, or through a corner, go
# wrong in other ways (three hits: an odd count, so the "inside" bookkeeping breaks). The
# watertight test gets every ray right, including those along the side faces.
#
# Which rays go wrong, and why the count is not a constant
# --------------------------------------------------------
# Every one of the cube's 18 edges (its 12 edges and the 6 face diagonals) is shared by two
# triangles. Which rays cross one is geometry, not arithmetic: the ray's line passes within
# :math:`10^{-6}` mm of the edge (and does not run along it). Some of those rays only graze
# the cube, along a side face or through a corner of its shadow's rim; the others cross it.
def through_an_edge(rays, mesh, tol=1e-6):
    """Rays whose line passes within ``tol`` mm of an edge of ``mesh`` (not along it)."""
    o = rays.origins
    d = rays.directions / np.linalg.norm(rays.directions, axis=1, keepdims=True)
    found = np.zeros(len(rays), bool)
    for a, b in mesh.edges_unique:
        p, e = mesh.vertices[a], mesh.vertices[b] - mesh.vertices[a]
        w = o - p
        de, ee = d @ e, e @ e
        den = ee - de * de                                  # 0: the ray runs along the edge
        with np.errstate(divide="ignore", invalid="ignore"):
            u = np.clip((w @ e - de * np.einsum("ij,ij->i", w, d)) / den, 0, 1)
        gap = np.linalg.norm(np.cross(p + u[:, None] * e - o, d), axis=1)
        found |= (gap < tol) & (np.abs(den) > 1e-12 * ee)
    return found


for name, (rays, exact, grazing, row) in results.items():
    wrong = row["textbook"][0]
    edge = through_an_edge(rays, cube)
    inside = edge & ~grazing
    saved = inside & ~wrong
    x, y = (float(c) for c in rays.ends[saved][0, :2]) if saved.any() else (np.nan, np.nan)
    print(f"{name:>12s} beam: {int(wrong.sum())} wrong rays, {int((wrong & edge).sum())} of "
          f"them through a shared edge ({int((wrong & inside).sum())} crossing the cube, "
          f"{int((wrong & grazing).sum())} grazing it)")
    print(f"{'':>12s}       of the {int(inside.sum())} rays that cross the cube through a "
          f"shared edge, {int(saved.sum())} come out right, e.g. the ray to the pixel at "
          f"({x!r}, {y!r})")

# %%
# So every wrong ray goes through a shared edge, but not every ray through one goes wrong:
# most do, some come out right. Which ones is decided by rounding. The pixel positions
# :math:`LHC + u_i HO + v_j VE` are computed in floating point: the pixel that should be at
# :math:`(-15.5, 15.5)`, on the diagonal of a face, is at :math:`(-15.5, 15.500000000000004)`,
# a rounding error beside it, so only one triangle takes the ray and its chord is right; in the
# point-source beam the rounding of the rays' directions and of the test's own arithmetic (the
# cross products and the barycentric coordinates of Eq. 1.15-1.16) moves other rays off their
# edges the same way. Whether exact ties count (the inclusive test above accepts
# :math:`\beta, \gamma \ge 0`; a strict one only :math:`> 0`), the order of the floating-point
# operations and which diagonal splits each face all move rays between "wrong" and "right".
# The strict test on the same rays:
for name, (rays, exact, grazing, row) in results.items():
    L, _ = textbook_chords(rays, cube, strict=True)
    ok = np.isclose(L, exact, atol=1e-6) | (grazing & np.isclose(L, 0.0, atol=1e-6))
    print(f"{name:>12s} beam, strict edges: {int((~ok).sum())} of {len(rays)} rays wrong "
          f"(inclusive: {int(row['textbook'][0].sum())})")

# %%
# That is why FIELD-NOTES section 3, whose own inclusive textbook test on this cube and these
# beams found 160 (parallel) and 462 (point source) wrong rays, does not match the counts this
# script prints: the same failure, rounded differently (other code, another order of
# operations). What does not depend on the rounding: the counts are not zero, the wrong rays
# are rays through shared edges, and the watertight test gets every ray right.
#
# Where the wrong rays are
# ------------------------
# Each panel is the detector; a dark pixel is a ray with the wrong path length.
plt = pyplot()
fig, axes = plt.subplots(2, 2, figsize=(9, 9))
for c, (name, (rays, exact, grazing, row)) in enumerate(results.items()):
    w, h = rays.shape
    for r, test in enumerate(("textbook", "watertight")):
        wrong = row[test][0].reshape(h, w)
        ax = axes[r, c]
        ax.imshow(~wrong, cmap="gray", vmin=0, vmax=1, interpolation="nearest")
        ax.set_title(f"{test}, {name} beam: {int(wrong.sum())} wrong", fontsize=11)
        ax.set_xticks([])
        ax.set_yticks([])
fig.tight_layout()
show_or_save_figure(fig, "wrong_rays", walkthrough=WALKTHROUGH)

# %%
# In the parallel beam the rays through a shared edge that cross the cube are those through
# the diagonals of the top and bottom faces (the two faces are split along different
# diagonals, hence the X); the corners of the X graze the cube's vertical edges. Most of them
# are wrong, the few rounded off their diagonal are right. In 3D: the cube's 12 triangles, the
# wrong rays (red), two sheets through the face diagonals, and the diagonal rays that came out
# right (green).
plotter = new_plotter()
plotter.add_mesh(cube, color="lightsteelblue", opacity=0.35, show_edges=True, edge_color="navy",
                 line_width=2)
rays, exact, grazing, row = results["parallel"]
bad = row["textbook"][0]
lucky = through_an_edge(rays, cube) & ~grazing & ~bad
for mask, color, width in ((bad, "red", 1.5), (lucky, "limegreen", 4.0)):
    xy = rays.origins[mask, :2]
    plotter.add_mesh(segments(np.column_stack([xy, np.full(len(xy), 45.0)]),
                              np.column_stack([xy, np.full(len(xy), -45.0)])),
                     color=color, line_width=width)
plotter.add_text(f"textbook test: {int(bad.sum())} parallel rays with a wrong path length (red)"
                 f"\n{int(lucky.sum())} rays through a diagonal that rounding saved (green)",
                 position="lower_left", font_size=12, color="black")
plotter.camera_position = [(180.0, -50.0, 140.0), (0.0, 0.0, 0.0), (0.0, 0.0, 1.0)]
show_or_save(plotter, "wrong_rays_3d", walkthrough=WALKTHROUGH)

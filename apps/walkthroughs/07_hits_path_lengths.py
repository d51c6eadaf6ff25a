"""
All hits along a ray, path lengths and Beer-Lambert
===================================================

A camera ray tracer wants the *nearest* hit: what you see. An X-ray wants *every* hit, because the
beam goes through everything and is attenuated by all of it. That is why Listing 1 of the thesis
pushes every hit into a list (``rec.t.push_back(t)``) instead of keeping the closest.

With a unit direction, :math:`t` is a distance (Eq. 1.1), so the length of ray inside a body is
simply "exit :math:`t` minus entry :math:`t`". Along a ray crossing bodies with linear attenuation
coefficients :math:`\\mu_b`, over path lengths :math:`L_b`, the Beer-Lambert law gives the
fraction of photons that get through without interacting:

.. math:: \\frac{I}{I_0} = \\exp\\Big(-\\sum_b \\mu_b L_b\\Big),

and the exponent :math:`\\sum_b \\mu_b L_b = -\\ln(I/I_0)` is the ray's *line integral*.
"""

# %%
# A small nested phantom
# ----------------------
# Soft tissue (a ball of radius 40 mm, :math:`\mu = 0.2` /cm) with a "bone" ball of radius 15 mm
# inside it (:math:`\mu = 0.5` /cm), both icospheres with 5120 triangles. Where bodies are
# nested, the innermost one's material wins: inside the bone there is bone, not bone plus tissue.
import numpy as np
import trimesh

import xray_viz
from xray_viz.attenuation import path_lengths
from xray_viz.physics.imaging import transmission
from xray_viz.scene import Body, Detector, Scene, Source
from xray_viz.walkthroughs import new_plotter, pyplot, segments, show_or_save, show_or_save_figure

WALKTHROUGH = 7
np.set_printoptions(precision=4, suppress=True)

tissue = trimesh.creation.icosphere(subdivisions=4, radius=40.0)
bone = trimesh.creation.icosphere(subdivisions=4, radius=15.0)
bone.apply_translation([12.0, 0.0, 0.0])
scene = Scene(
    source=Source(position=[0.0, 0.0, 1000.0], energy=60.0),
    detector=Detector(center=[0.0, 0.0, -500.0], shape=(64, 64), pitch=2.0),
    bodies=(Body(name="tissue", mesh=tissue, mu=0.2), Body(name="bone", mesh=bone, mu=0.5)),
)

# %%
# Every hit of one ray
# --------------------
# One ray from the source towards the detector point (18, 6, -500), traced with
# :func:`xray_viz.trace_rays`. Hits come back sorted by :math:`t`, each with its body and whether
# the ray enters or leaves (the sign of :math:`\hat d \cdot \vec n`, the triangle's outward normal).
r0 = scene.source.position
target = np.array([18.0, 6.0, -500.0])
d = (target - r0) / np.linalg.norm(target - r0)
t_det = np.linalg.norm(target - r0)
hits = xray_viz.trace_rays(scene, r0, d[None], t_max=t_det)
print("  t (mm)     body    entering")
for t, b, e in zip(hits.t, hits.body, hits.entering):
    print(f"{t:9.4f}  {scene.bodies[b].name:>7s}  {bool(e)}")

# %%
# Path lengths
# ------------
# For one closed body, exits minus entries gives its chord: :math:`L = \sum \pm t` (+ for an
# exit, - for an entry); no sorting needed. With nesting, the bone's length must be taken out of
# the tissue's: :func:`xray_viz.attenuation.path_lengths` sweeps the sorted hits and gives each
# stretch of the ray to the innermost body it is in.
chord = {name: float(np.sum(np.where(hits.entering, -hits.t, hits.t)[hits.body == k]))
         for k, name in enumerate(scene.body_names)}
L = path_lengths(hits.ray, hits.t, hits.body, hits.entering, n_rays=1, n_bodies=2,
                 precedence=scene.precedence, t_max=np.array([t_det]))[0]


def sphere_chord(centre, radius):
    """Exact chord of the ray through an ideal sphere."""
    b = np.linalg.norm(np.cross(np.asarray(centre) - r0, d))      # line-to-centre distance
    return 2 * np.sqrt(max(radius**2 - b**2, 0.0))


exact = {"tissue": sphere_chord([0, 0, 0], 40.0), "bone": sphere_chord([12, 0, 0], 15.0)}
for k, name in enumerate(scene.body_names):
    print(f"{name:>7s}: chord (sum of +-t) = {chord[name]:.4f} mm, "
          f"ideal sphere {exact[name]:.4f} mm, effective path length L = {L[k]:.4f} mm")
print(f"tissue L = tissue chord - bone chord: {chord['tissue'] - chord['bone']:.4f} mm")

# %%
# The mesh chords fall short of the ideal spheres by less than a tenth of a millimetre: that is
# tessellation (a polyhedron is not a sphere), not arithmetic.
#
# Beer-Lambert
# ------------
# :math:`\mu` is in 1/cm and :math:`L` in mm, hence the factor 1/10.
mu = np.array([b.mu for b in scene.bodies])
line_integral = float(mu @ L / 10)
ratio = float(np.exp(-line_integral))
naive = float(np.exp(-(mu @ np.array([chord["tissue"], chord["bone"]])) / 10))
print(f"line integral = sum mu L = {line_integral:.5f}")
print(f"I/I0 = exp(-line integral) = {ratio:.5f}")
print(f"xray_viz.physics.imaging.transmission: {float(transmission(L[None], scene)[0]):.5f}")
print(f"without the nesting rule (tissue counted inside the bone too): I/I0 = {naive:.5f}")

# %%
# Along the ray
# -------------
# :math:`\mu(t)` is a step function, and the surviving fraction :math:`I(t)/I_0` falls
# exponentially in each stretch, faster in bone.
plt = pyplot()
t_in, t_out = hits.t[0] - 15, hits.t[-1] + 15
ts = np.linspace(t_in, t_out, 2000)
inside_tissue = (ts > hits.t[0]) & (ts < hits.t[-1])
inside_bone = np.zeros_like(ts, bool)
bone_t = hits.t[hits.body == 1]
if len(bone_t) == 2:
    inside_bone = (ts > bone_t[0]) & (ts < bone_t[1])
mu_t = np.where(inside_bone, 0.5, np.where(inside_tissue, 0.2, 0.0))
surviving = np.exp(-np.concatenate([[0], np.cumsum(mu_t[1:] * np.diff(ts))]) / 10)
fig, (ax1, ax2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
ax1.step(ts, mu_t, where="post", color="k")
ax1.set_ylabel("mu (1/cm)")
ax1.set_title("one ray through tissue with a bone inside")
for t, e in zip(hits.t, hits.entering):
    for ax in (ax1, ax2):
        ax.axvline(t, color="green" if e else "red", ls=":", lw=1)
ax2.plot(ts, surviving, color="royalblue")
ax2.axhline(ratio, color="grey", ls="--", lw=1)
ax2.text(ts[0] + 2, ratio + 0.02, f"I/I0 = {ratio:.3f}", color="grey")
ax2.set_ylabel("I(t) / I0")
ax2.set_xlabel("t (mm from the source)")
fig.tight_layout()
show_or_save_figure(fig, "mu_and_intensity_along_ray", walkthrough=WALKTHROUGH)

# %%
# In 3D
# -----
# The ray (grey), its stretches in tissue (orange) and bone (red), entry points (green) and exit
# points (purple).
plotter = new_plotter()
plotter.add_mesh(tissue, color="peachpuff", opacity=0.25)
plotter.add_mesh(bone, color="ivory", opacity=0.6)
start, end = r0 + (hits.t[0] - 60) * d, r0 + (hits.t[-1] + 60) * d
plotter.add_mesh(segments(start, end), color="grey", line_width=2)
pts = hits.point
plotter.add_mesh(segments(pts[:-1], pts[1:]), color="darkorange", line_width=6)
if len(bone_t) == 2:
    b_pts = pts[hits.body == 1]
    plotter.add_mesh(segments(b_pts[0], b_pts[1]), color="red", line_width=8)
plotter.add_points(pts[hits.entering], color="green", point_size=16, render_points_as_spheres=True)
plotter.add_points(pts[~hits.entering], color="purple", point_size=16,
                   render_points_as_spheres=True)
plotter.add_legend([["entry", "green"], ["exit", "purple"], ["tissue", "darkorange"],
                    ["bone", "red"]], bcolor="white", size=(0.18, 0.18))
plotter.add_text("source above, detector below: the ray runs downwards", position="lower_left",
                 font_size=11, color="black")
plotter.camera_position = [(-40.0, -190.0, 60.0), (6.0, 2.0, 0.0), (0.0, 0.0, 1.0)]
show_or_save(plotter, "hits_3d", walkthrough=WALKTHROUGH)

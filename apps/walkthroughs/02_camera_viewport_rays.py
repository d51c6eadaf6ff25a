"""
Camera, viewport and rays: backward ray tracing (Figure 1.2)
============================================================

A ray tracer needs three things (thesis Figure 1.2): a **camera** at :math:`\\vec r_0` where every
ray starts, a **viewport**, the rectangle the rays pass through, cut into a grid (one grid point
per pixel of the image), and the **rays** themselves, one per grid point.

For an X-ray radiograph the roles are: the camera is the X-ray tube's focal spot (the source),
the viewport is the detector, and a pixel's ray is the straight line from the focal spot to
that pixel. An unscattered photon that reaches the pixel travelled exactly that line, so
Beer-Lambert attenuation along it (walkthrough 7) is that pixel's signal.

Why trace *backward*, one ray per pixel, rather than following photons *forward* from the
source? Because almost every forward photon misses the detector. This walkthrough counts how
many.
"""

# %%
# A scene built in code
# ---------------------
# The bundled ``sphere`` phantom's ball (radius 40 mm), a source 300 mm above it and a small
# detector 150 mm below it: 9 x 7 rays so that each one can be drawn.
import numpy as np

import xray_viz
from xray_viz.scene import Detector, Source
from xray_viz.viz.shapes import detector_quad
from xray_viz.viz.style import COLORS
from xray_viz.walkthroughs import new_plotter, segments, show_or_save

WALKTHROUGH = 2

ball = xray_viz.load_scene("sphere")
scene = ball.replace(
    source=Source(position=[0.0, 0.0, 300.0]),
    detector=Detector(center=[0.0, 0.0, -150.0], up=[0.0, 1.0, 0.0], shape=(9, 7), pitch=20.0),
)
vp = xray_viz.viewport(scene.source.position, scene.detector)
rays = xray_viz.detector_rays(scene)
w, h = scene.detector.shape
print(f"source r0 = {vp.r0}, detector {w} x {h} rays, {np.linalg.norm(vp.HO):.0f} x "
      f"{np.linalg.norm(vp.VE):.0f} mm, {np.linalg.norm(vp.FL):.0f} mm from the source")

# %%
# Forward: photons leave the source in random directions
# -------------------------------------------------------
# An X-ray tube emits (roughly) in all directions. The fraction of photons that reach the
# detector is the solid angle :math:`\Omega` the detector subtends at the source, over
# :math:`4\pi`. For a rectangle of half-widths :math:`a, b` centred at distance :math:`D`,
# :math:`\Omega = 4 \arcsin\big(ab / \sqrt{(a^2 + D^2)(b^2 + D^2)}\big)`.
rng = np.random.default_rng(7)
n_photons = 200_000
dirs = rng.normal(size=(n_photons, 3))
dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
D = np.linalg.norm(vp.FL)
forward = vp.forward
toward = dirs @ forward
with np.errstate(divide="ignore"):
    t_plane = np.where(toward > 0, D / toward, np.inf)
hit_plane = vp.r0 + np.where(np.isfinite(t_plane), t_plane, 0.0)[:, None] * dirs
local = hit_plane - vp.LHC
u = local @ vp.HO / (vp.HO @ vp.HO)
v = local @ vp.VE / (vp.VE @ vp.VE)
reach = np.isfinite(t_plane) & (u >= 0) & (u <= 1) & (v >= 0) & (v <= 1)

a, b = np.linalg.norm(vp.HO) / 2, np.linalg.norm(vp.VE) / 2
omega = 4 * np.arcsin(a * b / np.sqrt((a**2 + D**2) * (b**2 + D**2)))
print(f"forward: {reach.sum()} of {n_photons} photons reach the detector "
      f"(fraction {reach.mean():.4f}; solid angle Omega/4pi = {omega / (4 * np.pi):.4f})")
per_pixel = n_photons * reach.mean() / (w * h)
print(f"forward: about {per_pixel:.0f} photons per pixel, with Poisson noise of "
      f"{100 / np.sqrt(per_pixel):.1f}% per pixel")
print(f"backward: {len(rays)} rays, exactly one per pixel, every one reaches the detector")

# %%
# Fewer than one photon in a hundred lands on this detector, and each pixel collects only a couple
# of dozen: a noisy image from 200 000 photons. Backward tracing spends its work only on rays that
# form the image, and gives each pixel its exact, noise-free expected signal (noise can be added
# afterwards). A forward simulation is still needed for *scattered* photons, which do not travel
# straight: this package, like the thesis, models only the primary beam.
#
# The picture
# -----------
# Left: forward photons, green when they reach the detector, grey when they miss (8 hits and
# 52 misses are drawn; the true ratio is worse, about 1 to 130). Right:
# the backward rays, one per grid point, red where they are inside the ball.


def draw_common(plotter):
    plotter.add_mesh(scene.bodies[0].mesh, color="wheat", opacity=0.35)
    # the detector: the quadrilateral LHC, LHC + HO, LHC + HO + VE, LHC + VE
    plotter.add_mesh(detector_quad(vp), color="lightsteelblue", opacity=0.6, show_edges=True)
    plotter.add_points(vp.r0[None], color=COLORS["source"], point_size=20,
                       render_points_as_spheres=True)
    plotter.add_point_labels([vp.r0 + [0, 0, 30], vp.point(1, 1) + [0, 0, -25]],
                             ["source r0 (camera)", "detector (viewport)"], font_size=16,
                             point_size=1, shape_opacity=0.0, always_visible=True)
    plotter.camera_position = [(820.0, -930.0, 480.0), (0.0, 0.0, 75.0), (0.0, 0.0, 1.0)]


plotter = new_plotter(shape=(1, 2), window_size=(1400, 700))
plotter.subplot(0, 0)
plotter.add_text("forward: photons from the source", font_size=12, color="black",
                 position="lower_left")
draw_common(plotter)
show = np.flatnonzero(reach)[:8].tolist() + np.flatnonzero(~reach)[:52].tolist()
length = np.where(reach[show], t_plane[show], 260.0)
ends = vp.r0 + length[:, None] * dirs[show]
plotter.add_mesh(segments(np.broadcast_to(vp.r0, (reach[show].sum(), 3)), ends[reach[show]]),
                 color="green", line_width=3)
plotter.add_mesh(segments(np.broadcast_to(vp.r0, ((~reach[show]).sum(), 3)), ends[~reach[show]]),
                 color="grey", line_width=1.5)
# the missing photons fly 260 mm from the source in every direction, up to 560 mm above the
# ball: frame them all (same line of sight as the right-hand panel, further back)
plotter.camera_position = [(1150.0, -1300.0, 760.0), (0.0, 0.0, 190.0), (0.0, 0.0, 1.0)]

plotter.subplot(0, 1)
plotter.add_text("backward: one ray per pixel", font_size=12, color="black",
                 position="lower_left")
draw_common(plotter)
plotter.add_points(rays.ends, color="navy", point_size=8, render_points_as_spheres=True)
plotter.add_mesh(segments(rays.origins, rays.ends), color="dimgray", line_width=1.5)
hits = xray_viz.trace_rays(scene, rays.origins, rays.directions, t_max=rays.t_max)
entry, leave = hits.entering, ~hits.entering
plotter.add_mesh(segments(hits.point[entry], hits.point[leave]), color="red", line_width=5)
show_or_save(plotter, "forward_vs_backward", walkthrough=WALKTHROUGH)

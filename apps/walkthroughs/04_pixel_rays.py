"""
Pixel rays: Eq. 1.3-1.5 and the missing "- r0" (Figure 1.4)
===========================================================

The viewport is cut into a grid with one point per pixel. Pixel :math:`(i, j)` sits at the
viewport coordinates

.. math:: u_i = \\frac{i}{W - 1} \\quad (1.3), \\qquad v_j = \\frac{j}{H - 1} \\quad (1.4)

with :math:`i = 0 \\dots W-1` from left to right and :math:`j = 0 \\dots H-1` from bottom to top,
so :math:`u, v \\in [0, 1]` and the first and last rays lie exactly on the viewport's edges. The
grid point itself is :math:`\\overrightarrow{LHC} + u_i \\overrightarrow{HO} + v_j \\overrightarrow{VE}`,
a *position* (walkthrough 3). The ray from the camera to it is

.. math:: \\vec r_{i,j}(t) = \\vec r_0 + t \\left(\\overrightarrow{LHC} + u_i \\overrightarrow{HO}
          + v_j \\overrightarrow{VE} - \\vec r_0\\right),

a direction is "where you go minus where you are". The thesis prints Eq. 1.5 *without* the
:math:`- \\vec r_0`. That is correct only for a camera at the origin, which is where the thesis'
source code keeps it. Below we build the rays both ways and watch the printed form fail as soon
as the camera moves.
"""

# %%
# Viewport coordinates
# --------------------
import numpy as np

import xray_viz
from xray_viz.geometry import pixel_coordinates
from xray_viz.scene import Detector, Scene, Source
from xray_viz.viz.shapes import detector_quad
from xray_viz.viz.style import COLORS
from xray_viz.walkthroughs import arrow, new_plotter, segments, show_or_save

WALKTHROUGH = 4

W, H = 5, 4
i, j = np.arange(W), np.arange(H)
print("u_i =", i / (W - 1), "  (Eq. 1.3)")
print("v_j =", j / (H - 1), "  (Eq. 1.4)")

# %%
# The package stores the rays in *image order* (row 0 at the top, as an image is displayed):
# :func:`~xray_viz.geometry.pixel_coordinates` gives ``u`` and ``v`` for every pixel of the
# image, so ``v`` falls from 1 at the top row to 0 at the bottom row.
u, v = pixel_coordinates((W, H))
print("v of the image rows, top to bottom:", v[:, 0])


# %%
# Two ways to build the rays
# --------------------------
def rays_both_ways(r0, center):
    """Unit directions from the corrected and from the printed Eq. 1.5, and the package's."""
    detector = Detector(center=center, up=[0.0, 1.0, 0.0], shape=(W, H), pitch=40.0)
    vp = xray_viz.viewport(r0, detector)
    grid = vp.point(u.ravel(), v.ravel())                 # LHC + u HO + v VE: positions
    correct = grid - vp.r0                                # Eq. 1.5 with "- r0"
    printed = grid                                        # Eq. 1.5 as printed
    package = xray_viz.detector_rays(Scene(Source(position=r0), detector, ())).directions
    return vp, grid, correct, printed, package


def where_printed_rays_land(vp, printed, grid):
    """Where each printed ray meets the detector plane, and how far that is from its pixel."""
    n = vp.forward
    centre = vp.r0 - vp.FL
    toward = printed @ n
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(toward > 0, ((centre - vp.r0) @ n) / toward, np.nan)
    land = vp.r0 + t[:, None] * printed
    return t, np.linalg.norm(land - grid, axis=1)


unit = lambda a: a / np.linalg.norm(a, axis=1, keepdims=True)  # noqa: E731

for label, r0, center in (("camera at the origin", [0.0, 0.0, 0.0], [0.0, 0.0, -180.0]),
                          ("camera away from the origin", [160.0, 120.0, 200.0],
                           [160.0, 120.0, 20.0]),
                          ("camera on the axis, 1 m up", [0.0, 0.0, 1000.0], [0.0, 0.0, -500.0])):
    vp, grid, correct, printed, package = rays_both_ways(r0, center)
    t, miss = where_printed_rays_land(vp, printed, grid)
    agree = np.abs(unit(correct) - package).max()
    angle = np.degrees(np.arccos(np.clip(np.sum(unit(correct) * unit(printed), axis=1), -1, 1)))
    print(f"{label}: r0 = {vp.r0}")
    print(f"  corrected Eq. 1.5 vs xray_viz.detector_rays: max difference {agree:.1e}")
    lost = int(np.isnan(t).sum())
    if lost < W * H:
        far = f"max miss distance {np.nanmax(miss):.1f} mm"
        if lost:
            far += f" (of the {W * H - lost} that do)"
    else:
        far = "so there is no miss distance to measure (none of them points towards it)"
    print(f"  printed Eq. 1.5: max angle to the correct ray {angle.max():.1f} deg, "
          f"{lost} of {W * H} rays never reach the detector, {far}")

# %%
# With the camera at the origin, :math:`\vec r_0 = 0` and both forms agree (angle 0). Move the
# camera to :math:`(160, 120, 200)` above a detector at height 20 mm and the printed form's
# "directions" are the pixel *positions*, which all point up and away from the detector: not one
# ray arrives. With the camera on the axis 1 m above a detector 1.5 m away (the ``sphere``
# phantom's geometry) the printed rays do reach the detector, but 3 times too far from its centre
# (they point at the pixels' positions *as seen from the origin*): the image would be silently
# magnified 3 times. The corrected form matches :func:`xray_viz.detector_rays` to rounding error.
#
# Figure 1.4 and the failure, in 3D
# ---------------------------------
# Left: the camera at the origin. For one pixel, :math:`(i, j) = (3, 2)`, the ray direction is
# built from LHC - r0 (black), :math:`u_i` HO (red) and :math:`v_j` VE (green); the ray is blue.
# Right: the camera away from the origin. Correct rays (blue) end on their pixels; the printed
# Eq. 1.5's rays (red) start at the camera and leave in the wrong direction.
def draw_viewport(plotter, vp, grid):
    plotter.add_mesh(detector_quad(vp), color="lightsteelblue", opacity=0.5, show_edges=True)
    plotter.add_points(grid, color="navy", point_size=10, render_points_as_spheres=True)
    plotter.add_points(vp.r0[None], color=COLORS["source"], point_size=18,
                       render_points_as_spheres=True)
    plotter.add_points(np.zeros((1, 3)), color="black", point_size=10,
                       render_points_as_spheres=True)


plotter = new_plotter(shape=(1, 2), window_size=(1400, 700))
plotter.subplot(0, 0)
plotter.add_text("camera at the origin: Eq. 1.5 as printed works", font_size=11, color="black",
                 position="lower_left")
vp, grid, correct, printed, _ = rays_both_ways([0.0, 0.0, 0.0], [0.0, 0.0, -180.0])
draw_viewport(plotter, vp, grid)
ii, jj = 3, 2
uu, vv = ii / (W - 1), jj / (H - 1)
a = vp.LHC
b = a + uu * vp.HO
c = b + vv * vp.VE
plotter.add_mesh(arrow(vp.r0, a, tip=10), color="black")
plotter.add_mesh(arrow(a, b, tip=10), color="red")
plotter.add_mesh(arrow(b, c, tip=10), color="green")
plotter.add_mesh(arrow(vp.r0, c, tip=10), color="royalblue")
plotter.add_point_labels(
    np.array([vp.r0 + [0, 0, 12], (vp.r0 + a) / 2 + [-30, 0, 0], (a + b) / 2 + [0, -18, 0],
              (b + c) / 2 + [40, 0, 8], (vp.r0 + c) / 2 + [25, 0, 0]]),
    ["r0 = origin", "LHC - r0", "u_i HO", "v_j VE", "ray (3, 2)"],
    font_size=16, point_size=1, shape_opacity=0.0, always_visible=True)
plotter.camera_position = [(-260.0, -430.0, 120.0), (0.0, 0.0, -110.0), (0.0, 0.0, 1.0)]

plotter.subplot(0, 1)
plotter.add_text("camera away from the origin: printed Eq. 1.5 fails", font_size=11,
                 color="black", position="lower_left")
vp, grid, correct, printed, _ = rays_both_ways([160.0, 120.0, 200.0], [160.0, 120.0, 20.0])
draw_viewport(plotter, vp, grid)
plotter.add_mesh(segments(np.broadcast_to(vp.r0, grid.shape), grid), color="royalblue",
                 line_width=2)
bad_end = vp.r0 + 220 * unit(printed)
plotter.add_mesh(segments(np.broadcast_to(vp.r0, grid.shape), bad_end), color="red",
                 line_width=2)
plotter.add_point_labels(np.array([vp.r0 + [25, 0, -20], [0, -10, -15], grid.mean(0) + [0, -90, 0],
                                   bad_end.mean(0) + [0, 0, 20]]),
                         ["r0", "origin", "correct rays", "printed Eq. 1.5"], font_size=16,
                         point_size=1, shape_opacity=0.0, always_visible=True)
plotter.camera_position = [(-420.0, -720.0, 470.0), (100.0, 80.0, 120.0), (0.0, 0.0, 1.0)]
show_or_save(plotter, "pixel_rays", walkthrough=WALKTHROUGH)

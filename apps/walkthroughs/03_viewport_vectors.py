"""
HO, VE, FL and LHC: placing the viewport (Figure 1.3, Eq. 1.2)
==============================================================

To put the viewport (our detector) somewhere in the scene, the thesis defines three vectors:

* :math:`\\overrightarrow{HO}` runs along the viewport's bottom edge, from its left-most to its
  right-most point (the image's :math:`+x` direction);
* :math:`\\overrightarrow{VE}` runs up its left edge, from bottom to top (the image's :math:`+y`);
* :math:`\\overrightarrow{FL}` points from the *centre* of the viewport to the camera
  :math:`\\vec r_0`. Its length is the focal length (for X-rays: the source-detector distance).

The lower-left corner then follows by walking from the camera: back along FL to the centre,
half of HO to the left, half of VE down:

.. math:: \\overrightarrow{LHC} = \\vec r_0 - \\tfrac12 \\overrightarrow{HO}
          - \\tfrac12 \\overrightarrow{VE} - \\overrightarrow{FL} \\qquad (1.2)

Note what kind of vector this is. The thesis' text calls LHC a vector "from :math:`\\vec r_0` to
the bottom-left corner", but Eq. 1.2 starts at :math:`\\vec r_0` and ends at the corner, so the
sum is the corner's *position* (a vector from the origin). The vector from the camera to the
corner is :math:`\\overrightarrow{LHC} - \\vec r_0`. The two agree only when the camera sits at the
origin; walkthrough 4 shows what that does to Eq. 1.5.
"""

# %%
# The vectors for a camera away from the origin
# ---------------------------------------------
# :func:`xray_viz.viewport` computes the four vectors for a source and a detector. HO follows
# from the beam direction and the detector's ``up`` vector: ``unit(forward x up)``; VE completes
# the frame.
import numpy as np

import xray_viz
from xray_viz.scene import Detector
from xray_viz.viz.shapes import detector_quad
from xray_viz.walkthroughs import arrow, new_plotter, show_or_save

WALKTHROUGH = 3

r0 = np.array([160.0, 120.0, 200.0])
detector = Detector(center=[160.0, 120.0, 20.0], up=[0.0, 1.0, 0.0], shape=(5, 4), pitch=40.0)
vp = xray_viz.viewport(r0, detector)
for name in ("r0", "HO", "VE", "FL", "LHC"):
    print(f"{name:3s} = {getattr(vp, name)}")

corner = vp.LHC
check = r0 - vp.HO / 2 - vp.VE / 2 - vp.FL
centre = r0 - vp.FL
print(f"Eq. 1.2: r0 - HO/2 - VE/2 - FL = {check}  (= LHC: {np.allclose(check, corner)})")
print(f"centre = r0 - FL = {centre}  (detector centre {detector.center})")
print(f"camera -> corner: LHC - r0 = {corner - r0}")

# %%
# Checks on the numbers: the centre of the viewport is :math:`\vec r_0 - \overrightarrow{FL}`,
# HO and VE are perpendicular to each other and to FL, and the four corners are
# LHC, LHC + HO, LHC + HO + VE and LHC + VE.
print(f"HO.VE = {vp.HO @ vp.VE:.1f}, HO.FL = {vp.HO @ vp.FL:.1f}, VE.FL = {vp.VE @ vp.FL:.1f}")

# %%
# Figure 1.3 in 3D
# ----------------
# HO (red) and VE (green) drawn from the corner along the viewport's edges, FL (blue) from the
# centre to the camera, LHC (black) from the origin to the corner, and the vector
# LHC - r0 (grey) from the camera to the same corner.
plotter = new_plotter()
# the viewport: the quadrilateral LHC, LHC + HO, LHC + HO + VE, LHC + VE
plotter.add_mesh(detector_quad(vp), color="lightsteelblue", opacity=0.5, show_edges=True)
plotter.add_mesh(arrow(corner, corner + vp.HO, tip=12), color="red")
plotter.add_mesh(arrow(corner, corner + vp.VE, tip=12), color="green")
plotter.add_mesh(arrow(centre, r0, tip=12), color="blue")
plotter.add_mesh(arrow([0, 0, 0], corner, tip=12), color="black")
plotter.add_mesh(arrow(r0, corner, tip=12), color="grey", opacity=0.7)
plotter.add_points(np.array([r0, centre, [0, 0, 0]]), color="gold", point_size=14,
                   render_points_as_spheres=True)
labels = {
    "HO": corner + vp.HO / 2 + [0, -18, -6],
    "VE": corner + vp.VE / 2 + [-28, 0, 0],
    "FL": (centre + r0) / 2 + [12, 0, 0],
    "LHC": corner / 2 + [12, -14, 0],
    "LHC - r0": (r0 + corner) / 2 + [-40, 0, 0],
    "r0 (camera)": r0 + [0, 0, 14],
    "origin": [0, -8, -14],
    "centre": centre + [14, 0, 8],
}
plotter.add_point_labels(np.array(list(labels.values())), list(labels), font_size=18,
                         point_size=1, shape_opacity=0.0, always_visible=True)
plotter.add_axes()
plotter.camera_position = [(-160.0, -560.0, 430.0), (120.0, 80.0, 80.0), (0.0, 0.0, 1.0)]
show_or_save(plotter, "ho_ve_fl_lhc", walkthrough=WALKTHROUGH)

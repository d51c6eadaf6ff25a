"""
Moller-Trumbore step by step (Eq. 1.10-1.17, Listing 1)
=======================================================

Where does the ray :math:`\\vec r(t) = \\vec r_0 + \\hat d t` (Eq. 1.1) meet the triangle
:math:`\\vec v_0, \\vec v_1, \\vec v_2`? Write the meeting point both ways, as a point of the ray and as
a point of the triangle's plane in barycentric form (Eq. 1.13):

.. math:: \\vec r_0 + \\hat d\\, t = \\vec v_0 + \\beta \\vec e_1 + \\gamma \\vec e_2,
          \\qquad \\vec e_1 = \\vec v_1 - \\vec v_0 \\ (1.10), \\quad \\vec e_2 = \\vec v_2 - \\vec v_0 \\ (1.11).

Moved around, with :math:`\\vec T = \\vec r_0 - \\vec v_0`, this is Eq. 1.14 (the thesis drops the
:math:`t`):

.. math:: \\vec T = -\\hat d\\, t + \\beta \\vec e_1 + \\gamma \\vec e_2,

three linear equations for the three unknowns :math:`t, \\beta, \\gamma`. Moller and Trumbore solve
them with Cramer's rule written as triple products: with :math:`\\vec p = \\hat d \\times \\vec e_2`,
:math:`C = \\vec e_1 \\cdot \\vec p` (the determinant; zero when the ray is parallel to the plane)
and :math:`\\vec q = \\vec T \\times \\vec e_1`,

.. math:: \\beta = \\frac{\\vec T \\cdot \\vec p}{C} \\ (1.15), \\qquad
          \\gamma = \\frac{\\hat d \\cdot \\vec q}{C} \\ (1.16), \\qquad
          t = \\frac{\\vec e_2 \\cdot \\vec q}{C} \\ (1.17).

The ray hits the triangle when :math:`C \\ne 0`, :math:`\\beta, \\gamma \\ge 0`,
:math:`\\beta + \\gamma \\le 1` (so :math:`\\alpha = 1 - \\beta - \\gamma \\ge 0`, Eq. 1.9), and
:math:`t_\\mathrm{min} \\le t \\le t_\\mathrm{max}`.
"""

# %%
# One ray, one triangle, every intermediate value
# -----------------------------------------------
import numpy as np

from xray_viz.tracing.intersect import moller_trumbore
from xray_viz.walkthroughs import arrow, new_plotter, polyline, show_or_save

WALKTHROUGH = 6
np.set_printoptions(precision=4, suppress=True)

v0 = np.array([-2.0, -1.0, 6.0])
v1 = np.array([3.0, -1.0, 4.0])
v2 = np.array([0.0, 4.0, 5.0])
r0 = np.array([0.5, 0.5, 0.0])
d = np.array([0.1, 0.05, 1.0])
d = d / np.linalg.norm(d)                     # unit, so t is a distance (mm)

e1 = v1 - v0                                  # Eq. 1.10
e2 = v2 - v0                                  # Eq. 1.11
p = np.cross(d, e2)
C = e1 @ p
T = r0 - v0
beta = (T @ p) / C                            # Eq. 1.15
q = np.cross(T, e1)
gamma = (d @ q) / C                           # Eq. 1.16
t = (e2 @ q) / C                              # Eq. 1.17
alpha = 1 - beta - gamma
print(f"e1 = {e1}")
print(f"e2 = {e2}")
print(f"p = d x e2 = {p}")
print(f"C = e1 . p = {C:.6f}")
print(f"T = r0 - v0 = {T}")
print(f"beta = T . p / C = {beta:.6f}")
print(f"q = T x e1 = {q}")
print(f"gamma = d . q / C = {gamma:.6f}")
print(f"t = e2 . q / C = {t:.6f}")
hit = bool(min(alpha, beta, gamma) >= 0 and t >= 0)
print(f"alpha = 1 - beta - gamma = {alpha:.6f}; hit: {hit}")

# %%
# :math:`C` is negative here: seen along the ray, :math:`\vec v_0, \vec v_1, \vec v_2` run
# clockwise, so the ray meets the triangle's back face (its normal :math:`\vec e_1 \times \vec e_2`
# points towards +z, along the ray). The formulas do not care; the sign of :math:`C` is what later
# tells an entry into a closed body from an exit (walkthrough 7).
#
# Checks
# ------
# The same point three ways, and :math:`t` against the textbook ray-plane formula
# :math:`t = \vec n \cdot (\vec v_0 - \vec r_0) / (\vec n \cdot \hat d)` with the normal
# :math:`\vec n = \vec e_1 \times \vec e_2`. The package's vectorised
# :func:`~xray_viz.tracing.intersect.moller_trumbore` must agree.
n = np.cross(e1, e2)
t_plane = n @ (v0 - r0) / (n @ d)
hit_ray = r0 + t * d
hit_tri = alpha * v0 + beta * v1 + gamma * v2
print(f"t from the plane equation = {t_plane:.6f}")
print(f"r(t) = {hit_ray}, alpha v0 + beta v1 + gamma v2 = {hit_tri}")
print(f"Eq. 1.14 with t: -d t + beta e1 + gamma e2 - T = {-d * t + beta * e1 + gamma * e2 - T}")
ok, t_pkg, b_pkg, g_pkg = moller_trumbore(r0[None], d[None], v0[None], v1[None], v2[None])
print(f"xray_viz moller_trumbore: hit {bool(ok[0])}, t = {t_pkg[0]:.6f}, beta = {b_pkg[0]:.6f}, "
      f"gamma = {g_pkg[0]:.6f}")

# %%
# The "* C" bug of Listing 1
# --------------------------
# Listing 1 computes ``inv_det = 1.0 / C`` and then never uses it: it multiplies by ``C``
# (``u = dot(tvec, pvec) * C``, and the same for ``v`` and ``t``). Every result is then
# :math:`C^2` times too large: :math:`\beta C^2, \gamma C^2, t C^2`.
beta_bug, gamma_bug, t_bug = (T @ p) * C, (d @ q) * C, (e2 @ q) * C
print(f"Listing 1 (* C): beta = {beta_bug:.3f}, gamma = {gamma_bug:.3f}, t = {t_bug:.3f}  "
      f"(C^2 = {C * C:.3f})")
ok_bug, *_ = moller_trumbore(r0[None], d[None], v0[None], v1[None], v2[None], listing_bug=True)
print(f"Listing 1 (* C): hit {bool(ok_bug[0])} (beta > 1: rejected as outside the triangle)")

# %%
# Here :math:`C^2 \approx 670`: the bug rejects a ray that plainly hits. At millimetre scale a
# 40 mm triangle has :math:`|C|` in the thousands, so nearly every hit is lost and the radiograph
# comes out blank. Why did the listing seem to work? Because the bug is invisible when
# :math:`C = \pm 1` (then :math:`C = 1/C`): a unit right triangle facing the ray, the natural first
# test case.
ut = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])
down = np.array([[0.0, 0, -1]])
start = np.array([[0.2, 0.3, 2.0]])
good = moller_trumbore(start, down, ut[:1], ut[1:2], ut[2:])
bug = moller_trumbore(start, down, ut[:1], ut[1:2], ut[2:], listing_bug=True)
C_unit = (ut[1] - ut[0]) @ np.cross(down[0], ut[2] - ut[0])
print(f"unit triangle: C = {C_unit:.1f}; correct t = {good[1][0]:.3f}, "
      f"Listing 1 t = {bug[1][0]:.3f}")

# %%
# Listing 1 also tests ``abs(C) < 1e-9`` for "parallel": an absolute threshold, which means
# nothing when C scales with the square of the triangle's size. The package's version compares
# :math:`|C|` with :math:`|\vec e_1||\vec e_2||\hat d|` instead.
#
# The picture
# -----------
# The triangle, the ray (grey), :math:`\vec e_1` (red) and :math:`\vec e_2` (green) from
# :math:`\vec v_0`, :math:`\vec p = \hat d \times \vec e_2` (purple) and the hit point (gold).
import pyvista as pv  # noqa: E402

plotter = new_plotter()
plotter.add_mesh(pv.PolyData(np.array([v0, v1, v2]), faces=[3, 0, 1, 2]), color="lightsteelblue",
                 opacity=0.7, show_edges=True)
plotter.add_mesh(polyline([r0, r0 + 9 * d]), color="grey", line_width=3)
plotter.add_mesh(arrow(r0, r0 + 1.5 * d, tip=0.4), color="black")
plotter.add_mesh(arrow(v0, v1, tip=0.4), color="red")
plotter.add_mesh(arrow(v0, v2, tip=0.4), color="green")
plotter.add_mesh(arrow(v0, v0 + p / np.linalg.norm(p) * 3, tip=0.4), color="purple")
plotter.add_points(hit_ray[None], color="gold", point_size=20, render_points_as_spheres=True)
plotter.add_point_labels(
    np.array([v0 + [-0.6, -0.4, 0], v1 + [0.5, 0, 0], v2 + [0, 0.4, 0],
              (v0 + v1) / 2 + [0, -0.5, 0],
              (v0 + v2) / 2 + [-0.7, 0, 0], v0 + p / np.linalg.norm(p) * 3 + [-0.5, 0, 0],
              r0 + [0.4, 0, 0], hit_ray + [0.6, 0.2, 0], r0 + 1.5 * d + [0.5, 0, 0]]),
    ["v0", "v1", "v2", "e1", "e2", "p", "r0", f"hit, t = {t:.3f}", "d"],
    font_size=18, point_size=1, shape_opacity=0.0, always_visible=True)
plotter.camera_position = [(-9.5, -6.0, -4.0), (0.5, 1.0, 3.8), (0.0, 0.0, 1.0)]
plotter.reset_camera()          # keep the direction, fit everything in view
plotter.camera.zoom(1.3)
show_or_save(plotter, "moller_trumbore", walkthrough=WALKTHROUGH)

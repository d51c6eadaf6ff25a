"""
The parametric ray (Eq. 1.1)
============================

Everything in a ray tracer is built from one object: the ray. The thesis writes a ray as the
parametric line

.. math:: \\vec r(t) = \\vec r_0 + \\hat d\\, t \\qquad (1.1)

where :math:`\\vec r_0` is where the ray starts (for us: the X-ray source), :math:`\\hat d` is a
*unit* vector along the ray, and the parameter :math:`t` says how far along the ray we are.
Because :math:`|\\hat d| = 1`, :math:`t` is not just a parameter: it is the distance from
:math:`\\vec r_0` in millimetres. That is what lets us read path lengths straight off the
:math:`t` values of the points where a ray enters and leaves an object (walkthrough 7).

This walkthrough draws Figure 1.1 of the thesis and moves :math:`t`: with a window open, drag
the slider and watch the point slide along the ray.
"""

# %%
# A ray in numbers
# ----------------
# Pick a start point and a direction. The direction can be any non-zero vector; dividing it
# by its length gives the unit vector :math:`\hat d` of Eq. 1.1.
import numpy as np

from xray_viz.walkthroughs import arrow, new_plotter, polyline, save_frame, show_or_save

WALKTHROUGH = 1

r0 = np.array([1.0, 2.0, 0.5])            # where the ray starts (mm)
direction = np.array([3.0, 1.0, 2.0])     # any vector along the ray
d_hat = direction / np.linalg.norm(direction)


def r(t):
    """Eq. 1.1: the point at parameter t."""
    return r0 + d_hat * t


print(f"r0    = {r0}")
print(f"d_hat = {np.round(d_hat, 4)}   |d_hat| = {np.linalg.norm(d_hat):.6f}")
for t in (0.0, 1.0, 2.5, 6.0):
    p = r(t)
    print(f"t = {t:4.1f}  r(t) = {np.round(p, 4)}   |r(t) - r0| = {np.linalg.norm(p - r0):.4f}")

# %%
# The distance :math:`|\vec r(t) - \vec r_0|` equals :math:`t` in every row: with a unit
# direction, ``t`` *is* the distance along the ray. Negative ``t`` would be behind the start
# point; a ray tracer only accepts hits with :math:`t_\mathrm{min} \le t \le t_\mathrm{max}`
# (in Listing 1 of the thesis, ``t_min`` and ``t_max``).
#
# Figure 1.1 in 3D
# ----------------
# The origin, the position vector :math:`\vec r_0` (black), the unit vector :math:`\hat d`
# (red, drawn at the start of the ray), the ray itself (grey) and the point
# :math:`\vec r(t)` (blue) with the position vector that reaches it. The slider sets ``t``.

t_max = 8.0
plotter = new_plotter()
plotter.add_axes()
plotter.add_mesh(polyline([r0, r(t_max)]), color="grey", line_width=3)
plotter.add_mesh(arrow([0, 0, 0], r0, tip=0.4), color="black")
plotter.add_mesh(arrow(r0, r0 + d_hat, tip=0.3), color="red")
plotter.add_point_labels([[0, 0, -0.5], r0 / 2 + [0.3, 0, -0.5], r0 + d_hat + [0.5, 0, 0]],
                         ["origin", "r0", "d_hat"],
                         font_size=20, point_size=1, shape_opacity=0.0, always_visible=True,
                         text_color="black")


def set_t(t):
    """Move the point to r(t): redraw the actors named 'point', 'rt' and 'label'."""
    p = r(t)
    plotter.add_mesh(arrow([0, 0, 0], p, tip=0.4), color="royalblue", opacity=0.6, name="rt")
    plotter.add_points(p[None], color="royalblue", point_size=18, render_points_as_spheres=True,
                       name="point")
    plotter.add_point_labels(p[None] + [0, 0, 0.4], [f"r(t), t = {t:.1f} mm"], font_size=20,
                             point_size=1, shape_opacity=0.0, always_visible=True,
                             text_color="royalblue", name="label")


slider = plotter.add_slider_widget(set_t, [0.0, t_max], value=3.0, title="t (mm)",
                                   pointa=(0.05, 0.9), pointb=(0.45, 0.9),
                                   interaction_event="always", color="black")

# Look at the plane that holds the origin, r0 and the ray, from a little above it.
normal = np.cross(r0, d_hat)
normal /= np.linalg.norm(normal)
focus = r(t_max) / 2
plotter.camera_position = [focus + 20 * normal + [0, 0, 3], focus, (0.0, 0.0, 1.0)]

# %%
# Off-screen, the figure is saved for two values of ``t`` (the slider's states); on screen,
# drag the slider.
slider.GetRepresentation().SetValue(2.0)
set_t(2.0)
save_frame(plotter, "ray_t2", walkthrough=WALKTHROUGH)
slider.GetRepresentation().SetValue(7.0)
set_t(7.0)
show_or_save(plotter, "ray_t7", walkthrough=WALKTHROUGH)

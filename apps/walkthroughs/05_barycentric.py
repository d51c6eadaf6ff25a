"""
Barycentric coordinates as a centre of mass (Eq. 1.6-1.9)
=========================================================

Put three point masses :math:`m_1, m_2, m_3` on the corners :math:`\\vec r_1, \\vec r_2, \\vec r_3` of
a triangle. Their centre of mass is

.. math:: \\vec R = \\frac{m_1 \\vec r_1 + m_2 \\vec r_2 + m_3 \\vec r_3}{m_1 + m_2 + m_3}. \\qquad (1.6)

Divide each mass by the total and call the results :math:`\\alpha, \\beta, \\gamma`. Then
:math:`\\vec R = \\alpha \\vec v_0 + \\beta \\vec v_1 + \\gamma \\vec v_2` (Eq. 1.7) with
:math:`\\alpha + \\beta + \\gamma = 1` (Eq. 1.8): these are the point's *barycentric coordinates*.

* Whatever the masses, :math:`\\vec R` lies in the triangle's **plane** (Eq. 1.8 alone does that).
* It lies **inside the triangle** only when no mass is negative, :math:`\\alpha, \\beta, \\gamma \\ge 0`
  (Eq. 1.9). The thesis says the centre of mass "will always lie in the triangle": true for real,
  positive masses. Barycentric coordinates allow negative "masses", and then the point leaves.

That is exactly the test Moller-Trumbore uses (walkthrough 6): find the barycentric coordinates of
the point where the ray meets the plane, and check their signs.
"""

# %%
# Masses to coordinates
# ---------------------
import numpy as np

from xray_viz.walkthroughs import new_plotter, save_frame, show_or_save

WALKTHROUGH = 5

V = np.array([[0.0, 0.0, 0.0], [4.0, 0.5, 0.0], [1.2, 3.5, 0.0]])     # v0, v1, v2 (cm)


def centre_of_mass(masses):
    """Eq. 1.6."""
    m = np.asarray(masses, float)
    return (m[:, None] * V).sum(axis=0) / m.sum()


def barycentric(masses):
    """Normalised masses: (alpha, beta, gamma), summing to 1 (Eq. 1.8)."""
    m = np.asarray(masses, float)
    return m / m.sum()


cases = [(1.0, 1.0, 1.0), (1.0, 2.0, 0.5), (3.0, 0.2, 0.2), (1.0, 1.0, 0.0), (1.0, 1.5, -0.6)]
print("   m1    m2    m3  |  alpha   beta  gamma  sum |        R (Eq. 1.6)       | inside")
for m in cases:
    a, b, g = barycentric(m)
    R = centre_of_mass(m)
    assert np.allclose(R, a * V[0] + b * V[1] + g * V[2])        # Eq. 1.7 gives the same point
    inside = min(a, b, g) >= 0                                    # Eq. 1.9
    print(f"{m[0]:5.1f} {m[1]:5.1f} {m[2]:5.1f}  | {a:6.3f} {b:6.3f} {g:6.3f} {a + b + g:4.1f} | "
          f"{np.array2string(R, precision=3):>24s} | {inside}")

# %%
# Equal masses give the centroid, (1/3, 1/3, 1/3). A zero mass puts the point on the opposite
# edge (m3 = 0: on the edge v0-v1). A negative mass pushes the point out of the triangle, across
# the edge opposite the negative vertex, but it stays in the plane (z = 0): the sum of the
# coordinates is still 1.
#
# The picture
# -----------
# Sphere sizes show the masses (red when negative); the yellow point is :math:`\vec R`. The slider
# sets :math:`m_3`; off-screen, three of its positions are saved.
import pyvista as pv  # noqa: E402

plotter = new_plotter()
tri = pv.PolyData(V, faces=[3, 0, 1, 2])
plotter.add_mesh(pv.Plane(center=(1.7, 1.3, -0.01), i_size=9, j_size=8), color="whitesmoke",
                 lighting=False)
plotter.add_mesh(tri, color="lightsteelblue", show_edges=True, line_width=3, edge_color="navy")
plotter.add_point_labels(V + [[-0.45, -0.45, 0], [0.45, -0.4, 0], [0, 0.5, 0]],
                         ["v0 (m1)", "v1 (m2)", "v2 (m3)"], font_size=20, point_size=1,
                         shape_opacity=0.0, always_visible=True)
plotter.add_text("the plane P of the triangle", position="lower_left", font_size=12,
                 color="grey")
m1, m2 = 1.0, 1.5


def set_m3(m3):
    masses = (m1, m2, m3)
    if abs(sum(masses)) < 1e-6:      # no centre of mass when the total mass is zero
        return
    for k, m in enumerate(masses):
        plotter.add_mesh(pv.Sphere(radius=0.12 + 0.12 * abs(m), center=V[k]),
                         color="red" if m < 0 else "dimgray", name=f"mass{k}")
    R = centre_of_mass(masses)
    a, b, g = barycentric(masses)
    where = "OUTSIDE" if min(a, b, g) < 0 else "on the edge of" if min(a, b, g) == 0 else "inside"
    plotter.add_mesh(pv.Sphere(radius=0.13, center=R), color="gold", name="R")
    plotter.add_point_labels(R[None] + [0.3, 0.3, 0], ["R"], font_size=20, point_size=1,
                             shape_opacity=0.0, always_visible=True, name="Rlabel")
    plotter.add_text(f"m = ({m1:.1f}, {m2:.1f}, {m3:.2f})\n"
                     f"(alpha, beta, gamma) = ({a:.2f}, {b:.2f}, {g:.2f})\n"
                     f"R is {where} the triangle",
                     position="upper_left", font_size=13, color="black", name="caption")


slider = plotter.add_slider_widget(set_m3, [-1.2, 3.0], value=1.0, title="m3",
                                   pointa=(0.6, 0.88), pointb=(0.95, 0.88), color="black")
plotter.camera_position = [(1.9, 0.9, 14.0), (1.9, 1.4, 0.0), (0.0, 1.0, 0.0)]
for name, m3 in (("m3_positive", 1.0), ("m3_zero", 0.0), ("m3_negative", -0.6)):
    slider.GetRepresentation().SetValue(m3)
    set_m3(m3)
    if name != "m3_negative":
        save_frame(plotter, name, walkthrough=WALKTHROUGH)
show_or_save(plotter, "m3_negative", walkthrough=WALKTHROUGH)

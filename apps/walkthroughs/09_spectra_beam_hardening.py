"""
Polychromatic spectra and beam hardening
========================================

So far every ray carried photons of one energy, and Beer-Lambert was one exponential. An X-ray
tube emits a *spectrum*: bremsstrahlung from zero up to the tube voltage (80 kVp gives photons up
to 80 keV) plus the anode's characteristic lines. The attenuation coefficient depends strongly
on energy (low-energy photons are absorbed far more easily, mostly by the photoelectric effect),
so each energy bin :math:`k` is attenuated by its own exponential and the detector adds them up:

.. math:: \\frac{I}{I_0} = \\sum_k w_k \\exp\\Big(-\\sum_b \\mu_b(E_k) L_b\\Big),
          \\qquad \\sum_k w_k = 1,

with weights :math:`w_k \\propto \\phi_k E_k` for an energy-integrating detector (fluence times
energy). The geometry, and therefore the path lengths :math:`L_b`, do not depend on energy: the
rays are traced once and only this cheap sum runs per energy bin.

A sum of exponentials is not an exponential. The soft (low-energy) photons are removed first, so
the beam that survives a thick object has a higher mean energy and is attenuated *less* per
millimetre: **beam hardening**.
"""

# %%
# An 80 kVp tube spectrum
# -----------------------
# From SpekPy (tungsten anode, 12 degrees, 2.5 mm of aluminium filtration), with attenuation
# coefficients from xraylib.
import numpy as np
import trimesh

import xray_viz
from xray_viz.physics.imaging import detector_weights, transmission
from xray_viz.physics.materials import linear_attenuation
from xray_viz.physics.spectra import tube_spectrum
from xray_viz.scene import Body, Source
from xray_viz.walkthroughs import pyplot, show_or_save_figure

WALKTHROUGH = 9

spectrum = tube_spectrum(80.0, anode_angle=12.0, filters={"Al": 2.5})
E = spectrum.energies
w = detector_weights(spectrum, "energy")
mu_water = linear_attenuation("Water, Liquid", E)               # 1/cm, one per energy bin
print(f"spectrum: {len(E)} bins from {E[0]:.1f} to {E[-1]:.1f} keV, "
      f"mean energy {spectrum.mean_energy:.2f} keV")
print(f"water: mu = {linear_attenuation('Water, Liquid', [20.0])[0]:.3f} /cm at 20 keV, "
      f"{linear_attenuation('Water, Liquid', [60.0])[0]:.3f} /cm at 60 keV")

# %%
# Through more and more water
# ---------------------------
# For a water thickness :math:`x` the line integral is :math:`-\ln(I/I_0)` and the *effective*
# attenuation coefficient is that divided by :math:`x`. For a single energy it would be the same
# for every :math:`x`; here it falls with thickness while the surviving photons' mean energy rises.
print("  x (mm)   -ln(I/I0)   mu_eff (1/cm)   mean energy behind (keV)")
rows = []
for x in (1.0, 10.0, 50.0, 100.0, 200.0):
    survive = np.exp(-mu_water * x / 10)                          # per energy bin
    ratio = float(w @ survive)
    fluence_behind = spectrum.weights * survive
    mean_behind = float(fluence_behind @ E / fluence_behind.sum())
    rows.append((x, -np.log(ratio), -np.log(ratio) / (x / 10), mean_behind))
    print(f"{x:8.0f} {-np.log(ratio):11.4f} {-np.log(ratio) / (x / 10):15.4f} {mean_behind:18.2f}")

# %%
# The package does the same sum: :func:`xray_viz.physics.imaging.transmission` for a scene whose
# source has this spectrum, and a water body crossed over 100 mm, gives the same number.
box = trimesh.creation.box(extents=(100.0, 100.0, 100.0))
ball = xray_viz.load_scene("sphere")
water_scene = ball.replace(
    source=Source(position=[0.0, 0.0, 1000.0], energy=None,
                  spectrum={"kvp": 80.0, "anode_angle": 12.0, "filters": {"Al": 2.5}}),
    bodies=(Body(name="water", mesh=box, material="Water, Liquid"),))
package = float(transmission(np.array([[100.0]]), water_scene)[0])
by_hand = float(w @ np.exp(-mu_water * 100.0 / 10))
print(f"I/I0 through 100 mm of water: by hand {by_hand:.6f}, xray_viz {package:.6f}")

# %%
# A radiograph that shows it: the aluminium step wedge
# ----------------------------------------------------
# The bundled ``step_wedge`` phantom has ten aluminium steps, 2 to 20 mm thick along the beam.
# Render it once with a 60 keV monochromatic beam and once with the 80 kVp spectrum, and plot
# each pixel's line integral against its path length in aluminium (from the same trace).
# Monochromatic: a straight line through the origin, slope :math:`\mu`. Polychromatic: a curve
# that bends down, because each further millimetre attenuates the hardened beam less.
wedge = xray_viz.load_scene("step_wedge")
mono = xray_viz.render(wedge, engine="numpy")
poly_scene = wedge.replace(source=water_scene.source)
poly = xray_viz.render(poly_scene, engine="numpy")
h = wedge.detector.shape[1]
L_al = mono.path_length[h // 2, :, 0]
inside = L_al > 0.5
mono_li, poly_li = mono.line_integral[h // 2, inside], poly.line_integral[h // 2, inside]
slope_thin = np.polyfit(L_al[inside & (L_al < 5)], poly.line_integral[h // 2, inside & (L_al < 5)],
                        1)[0]
slope_thick = np.polyfit(L_al[inside & (L_al > 15)],
                         poly.line_integral[h // 2, inside & (L_al > 15)], 1)[0]
print(f"step wedge, 60 keV: line integral / mm of Al = {np.median(mono_li / L_al[inside]):.4f}"
      f" (mu(60 keV) = {linear_attenuation('Al', [60.0], density=2.699)[0] / 10:.4f} /mm)")
print(f"step wedge, 80 kVp: slope {slope_thin:.4f} /mm below 5 mm of Al, {slope_thick:.4f} /mm "
      f"above 15 mm (beam hardening)")
print(f"render times: mono {mono.timing['total']:.2f} s, 80 kVp ({len(E)} bins) "
      f"{poly.timing['total']:.2f} s")

# %%
# Figures
# -------
plt = pyplot()
fig, axes = plt.subplots(2, 2, figsize=(11, 8.5))
ax = axes[0, 0]
for x, style in ((0.0, "-"), (50.0, "--"), (200.0, ":")):
    f = spectrum.weights * np.exp(-mu_water * x / 10)
    ax.plot(E, f / f.sum(), style, label=f"behind {x:.0f} mm water")
ax.set_xlabel("photon energy (keV)")
ax.set_ylabel("fraction of photons per bin")
ax.set_title("80 kVp spectrum, hardened by water")
ax.legend()
ax = axes[0, 1]
xs = np.linspace(1, 300, 200)
mu_eff = [-np.log(w @ np.exp(-mu_water * x / 10)) / (x / 10) for x in xs]
ax.plot(xs, mu_eff, color="C3")
ax.set_xlabel("water thickness x (mm)")
ax.set_ylabel("effective mu (1/cm)")
ax.set_title("effective attenuation falls with thickness")
ax = axes[1, 0]
ax.imshow(poly.line_integral, cmap="gray_r")
ax.axhline(h // 2, color="C1", lw=1)
ax.set_title("step wedge, 80 kVp: line integral (row used in orange)")
ax.set_xticks([])
ax.set_yticks([])
ax = axes[1, 1]
ax.plot(L_al[inside], mono_li, ".", ms=3, label="60 keV monochromatic")
ax.plot(L_al[inside], poly_li, ".", ms=3, label="80 kVp spectrum")
ax.plot([0, 20], [0, 20 * slope_thin], "--", color="grey", lw=1,
        label="80 kVp, slope of the thin steps")
ax.set_xlabel("path length in aluminium (mm)")
ax.set_ylabel("line integral -ln(I/I0)")
ax.set_title("monochromatic: straight; polychromatic: bends")
ax.legend()
fig.tight_layout()
show_or_save_figure(fig, "beam_hardening", walkthrough=WALKTHROUGH)

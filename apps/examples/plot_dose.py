"""
Dose
====

The dose each body of a patient absorbs from one exposure: :func:`xray_viz.transport` follows
photons one by one (a Monte Carlo on the bodies' own meshes, with xraylib's cross sections)
and scores the energy each body's region absorbs; with the tube's ``[source] mas`` that energy
becomes a dose in gray, each figure with its standard error. The same run splits the detector
image into primary photons and three kinds of scattered ones. Here the bundled ``limb``
phantom (skin and fat, muscle, two bones with their marrow) under a 60 kVp beam.
"""

# %%
# The exposure
# ------------
# The phantom's bodies have materials (a body given by ``mu`` alone has no cross sections to
# sample); the source becomes a 60 kVp tungsten tube spectrum with 2.5 mm of aluminium and an
# exposure of 2 mAs: in a scene file, ``[source] spectrum = { kvp = 60, filters = { Al = 2.5 }
# }`` and ``mas = 2``. A detector of an eighth of the phantom's pixels in each direction (eight
# times the pitch, the same field) keeps the images' noise down for the histories run here.
import dataclasses

import matplotlib.pyplot as plt
import numpy as np

import xray_viz
from xray_viz.physics import air_kerma

limb = xray_viz.load_scene("limb")
w, h = limb.detector.shape
source = dataclasses.replace(limb.source, energy=None, mas=2.0,
                             spectrum={"kvp": 60.0, "filters": {"Al": 2.5}})
detector = dataclasses.replace(limb.detector, shape=(w // 8, h // 8),
                               pitch=tuple(8 * p for p in limb.detector.pitch))
scene = limb.replace(source=source, detector=detector)
kerma = air_kerma(scene)
print(f"incident air kerma: {kerma.entrance_uGy:.1f} uGy at the skin "
      f"({kerma.entrance_distance_mm:.0f} mm from the focal spot), "
      f"{kerma.detector_uGy:.1f} uGy at the detector")

# %%
# 400,000 histories
# -----------------
# One history is one photon emitted into the field the detector covers. The number of
# histories bounds the run (here a few seconds once the kernels are compiled); the standard
# errors fall as one over its square root. The same seed gives the same numbers bit for bit,
# on any number of threads or Dask workers (``client=``).
result = xray_viz.transport(scene, 400_000, seed=1)
b = result.balance
print(f"{result.histories} histories: of {b['emitted']:.0f} eV emitted per history, "
      f"{b['deposited']:.0f} +- {result.balance_error['deposited']:.0f} deposited in the "
      f"bodies, {b['detector']:.0f} reach the detector, {b['escaped']:.0f} escape")
rest = b["emitted"] - b["deposited"] - b["world"] - b["escaped"] - b["detector"]
print(f"energy balance: emitted - all the others = {rest:.1e} eV per history")

# %%
# The dose table
# --------------
# Per body: the energy its region absorbs (eV per history; where bodies nest, the inner one
# wins, so the muscle's region is the muscle less the bones) and the dose, that energy times
# the photons the tube emits into the field for 2 mAs over the region's mass. Each figure
# comes with its standard error (one standard deviation of the mean over the histories). The
# bones take the highest dose: cortical bone absorbs far more per gram than soft tissue at
# these energies (the photoelectric effect of its calcium).
print(f"{'body':>14s} {'eV/history':>11s} {'+-':>6s} {'dose (uGy)':>11s} {'+-':>6s} "
      f"{'rel. error':>10s}")
for row in result.table():
    dose, error = row["dose_Gy"] * 1e6, row["dose_error"] * 1e6
    print(f"{row['body']:>14s} {row['energy_eV_per_history']:11.1f} "
          f"{row['energy_error']:6.1f} {dose:11.2f} {error:6.2f} {error / dose:10.1%}")

# %%
# The same as a chart, with the standard errors as bars (two standard errors each way).
rows = result.table()
names = [r["body"] for r in rows]
doses = np.array([r["dose_Gy"] for r in rows]) * 1e6
errors = np.array([r["dose_error"] for r in rows]) * 1e6
fig, ax = plt.subplots(figsize=(8, 3.6))
ax.barh(names, doses, xerr=2 * errors, color="tab:orange", capsize=4)
ax.invert_yaxis()
ax.set_xlabel(f"dose (uGy) for {scene.source.mas:g} mAs at {scene.source.spectrum['kvp']:g} kVp")
ax.set_title(f"dose per body, {result.histories:,} histories (bars: 2 standard errors)")
fig.tight_layout()

# %%
# The four detector images
# ------------------------
# The energy reaching each pixel of the detector plane (eV per history, before any detector
# response): *primary* photons (no interaction: the Beer-Lambert radiograph), photons scattered
# once incoherently (Compton) or coherently (Rayleigh), and those scattered more than once.
# The scattered images are smooth (scatter blurs the bones away) and noisy (few photons reach
# any one pixel); the scatter-to-primary ratio of a thin limb in a narrow field is small.
images = result.images
total = {key: float(image.sum()) for key, image in images.items()}
scatter = total["incoherent"] + total["coherent"] + total["multiple"]
print(f"scatter-to-primary ratio on the detector: {scatter / total['primary']:.3f}")
width, height = scene.detector.size
extent = (-width / 2, width / 2, -height / 2, height / 2)
fig, axes = plt.subplots(1, 4, figsize=(13, 5.4))
for ax, key in zip(axes, ("primary", "incoherent", "coherent", "multiple")):
    shown = ax.imshow(images[key], cmap="inferno", extent=extent, interpolation="nearest")
    ax.set_title(f"{key}\n{total[key]:.0f} eV/history")
    ax.set_xlabel("u (mm)")
    fig.colorbar(shown, ax=ax, fraction=0.09, label="eV per history per pixel")
axes[0].set_ylabel("v (mm)")
fig.tight_layout()

# %%
# What to try next
# ----------------
# * ``xray-viz dose scene.toml --histories 1000000 --seed 1 -o dose.csv``: the same table from
#   the command line (``--workers 2`` on a Dask LocalCluster).
# * ``[world] material = "Air, Dry (near sea level)"``: the air around the patient scatters
#   and absorbs too (its energy is ``balance["world"]``).
# * Walkthrough 12, :doc:`../walkthroughs/12_where_the_photons_go`, follows the photons of a
#   water block with a bone ball step by step.

"""
Where the photons go: a photon Monte Carlo on the same meshes
=============================================================

Every image so far was *primary* radiation: Beer-Lambert counts a photon as lost the moment it
interacts. In a patient most of those photons are not lost at all: a photoelectric absorption
leaves its energy in the tissue, and a scattered photon (incoherent, Compton; or coherent,
Rayleigh) flies on in a new direction, may scatter again, and may still reach the detector.

:func:`xray_viz.transport` follows them one by one (a *history* is one photon emitted into the
field the detector covers), on the bodies' own triangle meshes with the primary engines'
watertight crossings and nesting rules, and with xraylib's cross sections:

* the energy each body absorbs (eV per history, and the dose in Gy when the source has ``mas``),
* the detector image split four ways: *primary* (no interaction: the Beer-Lambert image),
  *single incoherent*, *single coherent* and *multiple* scattering,
* an energy balance: deposited + absorbed in the world medium + escaped + reaching the detector
  = emitted,
* and, on request, the tracks of the first histories, drawn here in the 3D scene.

Here a narrow beam (the field of a 64 mm detector 70 cm from the source) enters a block of water
with a bone ball in it, in air; the detector lies 5 cm below the water, where scatter reaches it.
"""

# %%
# The scene: water, bone, air around them
# ---------------------------------------
# An 80 kVp tungsten spectrum with 2.5 mm of aluminium, 1 mAs (for the dose); a 200 x 200 x 100
# mm block of water with a bone ball (radius 12 mm) in its middle; the world medium is dry air.
import numpy as np
import trimesh

import xray_viz
from xray_viz.scene import Body, Detector, Scene, Source
from xray_viz.walkthroughs import new_plotter, pyplot, segments, show_or_save, show_or_save_figure

WALKTHROUGH = 12

water = trimesh.creation.box(extents=(200.0, 200.0, 100.0))
bone = trimesh.creation.icosphere(subdivisions=3, radius=12.0)
scene = Scene(source=Source(position=[0.0, 0.0, 600.0],
                            spectrum={"kvp": 80.0, "filters": {"Al": 2.5}}, mas=1.0),
              detector=Detector(center=[0.0, 0.0, -100.0], shape=(16, 16), pitch=(4.0, 4.0)),
              bodies=(Body(name="water", mesh=water, material="Water, Liquid"),
                      Body(name="bone", mesh=bone, material="Bone, Cortical (ICRP)")),
              world={"material": "Air, Dry (near sea level)"})

# %%
# The 3D scene: the source, the beam's field (the rectangle the detector's pixels cover) and the
# bodies. The bone ball wins over the water where it is (nesting), so the water's region is the
# block less the ball.
f = scene.acquisition.frame
width, height = scene.detector.size
corners = np.array([f.middle + a * width / 2 * f.ho + b * height / 2 * f.ve
                    for a, b in ((-1, -1), (1, -1), (1, 1), (-1, 1))])
plotter = new_plotter()
plotter.add_mesh(water, color="lightblue", opacity=0.25)
plotter.add_mesh(bone, color="ivory", opacity=0.9)
plotter.add_mesh(segments(np.repeat(f.source[None, :], 4, axis=0), corners), color="darkorange",
                 line_width=3)
plotter.add_mesh(segments(corners, np.roll(corners, -1, axis=0)), color="black", line_width=3)
plotter.add_mesh(segments(corners[:2], corners[2:][::-1]), color="grey", line_width=1)
plotter.add_points(f.source[None, :], color="red", point_size=14, render_points_as_spheres=True)
plotter.add_text("source (red), field (orange), detector (black)", position="lower_left",
                 font_size=10, color="black")
plotter.view_vector((1.0, -1.6, 0.45), viewup=(0.0, 0.0, 1.0))       # fits the whole scene
show_or_save(plotter, "scene_3d", walkthrough=WALKTHROUGH)

# %%
# 200,000 histories
# -----------------
# The same seed gives the same numbers bit for bit, on any number of threads or Dask workers.
# ``tracks=300`` also records the paths of the first 300 histories (every other number is the
# same, bit for bit, with or without them).
result = xray_viz.transport(scene, 200_000, seed=1, tracks=300)
b = result.balance
print(f"{result.histories} histories, mean energy emitted {b['emitted']:.0f} eV per history")
print(f"deposited in the bodies {b['deposited']:8.1f} eV/history "
      f"({b['deposited'] / b['emitted']:.1%})")
print(f"absorbed in the air     {b['world']:8.1f} eV/history ({b['world'] / b['emitted']:.1%})")
print(f"escaped                 {b['escaped']:8.1f} eV/history ({b['escaped'] / b['emitted']:.1%})")
print(f"reached the detector    {b['detector']:8.1f} eV/history "
      f"({b['detector'] / b['emitted']:.1%})")
rest = b["emitted"] - b["deposited"] - b["world"] - b["escaped"] - b["detector"]
print(f"balance: emitted - all the others = {rest:.2e} eV/history")

# %%
# The tracks: where the first 300 photons went
# ---------------------------------------------
# Each track runs from the source through every interaction (a scattering turns it, a
# photoelectric absorption ends it) to its end: the detector, unscattered (*primary*) or after
# scattering, the world's box (*escaped*), or an absorption. Most photons of this narrow beam
# cross the 10 cm of water unscattered or scatter out of it sideways; few scattered ones find
# the small detector.
ends = [end for _, end in result.tracks]
counts = {key: ends.count(key) for key in ("primary", "scattered", "escaped", "absorbed")}
print("tracks: " + ", ".join(f"{key} {n}" for key, n in counts.items()))
colours = {"primary": "limegreen", "scattered": "royalblue", "escaped": "darkgrey",
           "absorbed": "crimson"}
plotter = new_plotter()
plotter.add_mesh(water, color="lightblue", opacity=0.2)
plotter.add_mesh(bone, color="ivory", opacity=0.9)
plotter.add_mesh(segments(corners, np.roll(corners, -1, axis=0)), color="black", line_width=3)
for key, colour in colours.items():
    paths = [xyz for xyz, end in result.tracks if end == key]
    if not paths:
        continue
    starts = np.vstack([xyz[:-1] for xyz in paths])
    stops = np.vstack([xyz[1:] for xyz in paths])
    plotter.add_mesh(segments(starts, stops), color=colour, line_width=2,
                     label=f"{key} ({counts[key]})")
    if key == "absorbed":                   # where they ended
        plotter.add_points(np.array([xyz[-1] for xyz in paths]), color=colour, point_size=8,
                           render_points_as_spheres=True)
plotter.add_legend(bcolor="white", face="line", size=(0.22, 0.18))
# close to the water (the escaped tracks run on to the world's box, out of the picture)
plotter.camera_position = [(520.0, -700.0, 260.0), (0.0, 0.0, -20.0), (0.0, 0.0, 1.0)]
show_or_save(plotter, "tracks_3d", walkthrough=WALKTHROUGH)

# %%
# The energy and the dose per body
# --------------------------------
# Each body scores the energy deposited in its own region; with ``mas`` the dose is that energy
# over the region's mass. The bone absorbs strongly and lies in the beam; most of the water's
# 4 kg lies outside the narrow beam, so its dose (energy over the whole region's mass) is low.
print(f"{'body':>6s} {'eV/history':>12s} {'error':>9s} {'dose (uGy)':>12s}")
for name in result.energy:
    print(f"{name:>6s} {result.energy[name]:12.2f} {result.energy_error[name]:9.2f} "
          f"{result.dose[name] * 1e6:12.4f}")

# %%
# The four detector images
# ------------------------
# Energy per pixel reaching the detector plane (eV per history, before any detector response).
# The primary image is the Beer-Lambert radiograph (the bone's shadow); the scattered images
# are smoother and noisier (fewer photons). Their sum over the primary's is the
# scatter-to-primary ratio of this narrow beam behind 10 cm of water.
images = result.images
total = {k: v.sum() for k, v in images.items()}
scatter = total["incoherent"] + total["coherent"] + total["multiple"]
print("energy on the detector, eV per history:")
for key, value in total.items():
    print(f"  {key} {value:.2f}")
print(f"scatter-to-primary ratio on this detector: {scatter / total['primary']:.2f}")
plt = pyplot()
fig, axes = plt.subplots(2, 2, figsize=(10, 8.5))
extent = (-width / 2, width / 2, -height / 2, height / 2)
for ax, key in zip(axes.ravel(), ("primary", "incoherent", "coherent", "multiple")):
    shown = ax.imshow(images[key], cmap="inferno", extent=extent, interpolation="nearest")
    ax.set_title(f"{key}: {total[key]:.2f} eV/history")
    ax.set_xlabel("u (mm)")
    fig.colorbar(shown, ax=ax, fraction=0.046, label="eV per history per pixel")
for ax in axes[:, 0]:
    ax.set_ylabel("v (mm)")
fig.tight_layout()
show_or_save_figure(fig, "four_images", walkthrough=WALKTHROUGH)

"""
Your own mesh
=============

Render a mesh file of your own without writing a scene: :func:`xray_viz.load_scene` given a mesh
file frames a point source and a detector around it (the beam along -z) and reads the mesh in mm
as aluminium at 60 keV, as ``xray-viz render part.stl`` does. Here the "part" is a washer made
with :mod:`trimesh` and saved as STL: a thick washer, tilted so that the beam crosses its
wall at a slant.
"""

# %%
# Make a mesh and save it as STL
# ------------------------------
# Any file trimesh reads (STL, OBJ, PLY, glTF...) works the same. The mesh must be closed
# (watertight): ``xray-viz mesh part.stl -o fixed.stl`` repairs one that is not.
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import trimesh

import xray_viz
from xray_viz.scene import scene_from_dict

folder = Path(tempfile.mkdtemp())
part = trimesh.creation.annulus(r_min=12.0, r_max=25.0, height=15.0, sections=96)
part.apply_transform(trimesh.transformations.rotation_matrix(0.6, (1.0, 0.0, 0.0)))
assert part.is_watertight
part.export(folder / "washer.stl")

# %%
# Render it, framed, with a stated material
# -----------------------------------------
# The framing is a :class:`~xray_viz.scene.Scene` like any other: change its detector or its
# body's material before rendering. A 128 x 128 detector with four times the pitch keeps the
# field of view of the default 512 x 512 and renders in a fraction of the time.
scene = xray_viz.load_scene(folder / "washer.stl")
body = scene.bodies[0]
print(f"{body.name}: {body.material}, {body.density} g/cm3; source at {scene.source.position}")
doc = scene.to_dict(base=folder)
doc["detector"]["shape"] = [128, 128]
doc["detector"]["pitch"] = [4 * p for p in doc["detector"]["pitch"]]
for b in doc["body"]:                       # the same part in titanium
    b["material"], b["density"] = "Ti", 4.506
titanium = scene_from_dict(doc, base_dir=folder)

doc["body"][0]["material"], doc["body"][0]["density"] = "Al", 2.699
aluminium = scene_from_dict(doc, base_dir=folder)

images = {name: xray_viz.render(s).line_integral
          for name, s in [("aluminium", aluminium), ("titanium", titanium)]}
top = max(li.max() for li in images.values())           # one scale for both
fig, axes = plt.subplots(1, 2, figsize=(9, 4))
for ax, (name, li) in zip(axes, images.items()):
    shown = ax.imshow(li, cmap="gray_r", vmin=0.0, vmax=top)
    ax.set_title(f"{name}\nline integral, max {li.max():.2f}")
    ax.axis("off")
fig.colorbar(shown, ax=axes, shrink=0.8, label="-ln(I/I0)")

# %%
# On one scale, titanium is far darker. The rim is darkest where the tilted wall lies along the rays; the hole lets the beam through
# unattenuated where the rays pass it clean. Titanium attenuates more than
# aluminium at 60 keV, by the ratio of their mass attenuation times density.
#
# What to try next
# ----------------
# * ``xray-viz init --from washer.stl -o scene.toml`` writes this scene as a commented file.
# * Turn the part: the ``rotation`` key of a ``[[body]]`` (see :doc:`../scene_files`).
# * A polychromatic beam: ``[source] spectrum = {kvp = 80}`` (see :doc:`../physics`).

"""
An implant in a CT
==================

A CT in Hounsfield units as a ``[[ct]]`` table with ``trace = "voxels"`` (each ray's exact chord
in each voxel, density varying voxel by voxel with the HU), and a titanium pin as a mesh
``[[body]]`` inside it: where the mesh is, it replaces the tissue and bone of the voxels. The CT
here is synthetic (a limb: soft tissue around a bone), written as NIfTI with nibabel, so that
the example needs no download.
"""

# %%
# A small CT in HU, as NIfTI
# --------------------------
# 64 x 64 x 48 voxels of 2 mm, the volume's affine placing its centre at the origin (RAS+ mm).
import tempfile
import tomllib
from pathlib import Path

import matplotlib.pyplot as plt
import nibabel as nib
import numpy as np
import trimesh

import xray_viz
from xray_viz.scene import scene_from_dict

folder = Path(tempfile.mkdtemp())
n, voxel = (64, 64, 48), 2.0
x, y, z = (voxel * (np.arange(k) - (k - 1) / 2) for k in n)
X, Y, _ = np.meshgrid(x, y, z, indexing="ij")
r = np.hypot(X, Y)
hu = np.full(n, -1000.0)                     # air
hu[r < 45.0] = 40.0                          # soft tissue
hu[r < 14.0] = 1000.0                        # cortical bone ...
hu[r < 8.0] = 300.0                          # ... around cancellous bone
affine = np.diag([voxel, voxel, voxel, 1.0])
affine[:3, 3] = [-voxel * (k - 1) / 2 for k in n]
nib.save(nib.Nifti1Image(hu.astype(np.float32), affine), folder / "limb_ct.nii.gz")

# %%
# A pin through the bone, as STL
# ------------------------------
# A cylinder 3 mm in radius and 50 mm long, across the bone along x.
pin = trimesh.creation.cylinder(radius=3.0, height=50.0, sections=48)
pin.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (0.0, 1.0, 0.0)))
pin.export(folder / "pin.stl")

# %%
# The scene
# ---------
# The beam runs along -y (a front view); the limb's axis (z) is up on the detector.
scene_file = folder / "implant.toml"
scene_file.write_text('''
[source]
position = [0.0, 500.0, 0.0]
energy = 60.0

[detector]
center = [0.0, -300.0, 0.0]
up = [0.0, 0.0, 1.0]
shape = [128, 96]
pitch = 2.0

[[ct]]
file = "limb_ct.nii.gz"
trace = "voxels"

[[body]]
name = "pin"
mesh = "pin.stl"
material = "Ti"
density = 4.506
''')
with_pin = xray_viz.load_scene(scene_file)
doc = tomllib.loads(scene_file.read_text())
del doc["body"]
without_pin = scene_from_dict(doc, base_dir=folder)

# %%
# The radiographs
# ---------------
# The pin is far denser than bone: on one scale, it dominates the line integral where it
# crosses the limb, and the bone is visible around it.
images = {"CT alone": xray_viz.render(without_pin).line_integral,
          "CT with a titanium pin": xray_viz.render(with_pin).line_integral}
top = max(li.max() for li in images.values())
fig, axes = plt.subplots(1, 3, figsize=(12, 3.8))
axes[0].imshow(hu[:, :, n[2] // 2].T, cmap="gray", origin="lower", vmin=-1000, vmax=1200)
axes[0].set_title("the CT, axial slice (HU)")
for ax, (name, li) in zip(axes[1:], images.items()):
    shown = ax.imshow(li, cmap="gray_r", vmin=0.0, vmax=top)
    ax.set_title(f"{name}\nline integral, max {li.max():.2f}")
for ax in axes:
    ax.axis("off")
fig.colorbar(shown, ax=axes[1:], shrink=0.8, label="-ln(I/I0)")

# %%
# What to try next
# ----------------
# * Your own CT: ``file`` takes a NIfTI, an NRRD/MHA or a DICOM series folder; the HU classes
#   and their materials are the ``ranges`` key (see :doc:`../scene_files`).
# * A metal implant saturates a PNG's default window: save the line integral (``.tiff``) or
#   choose the window.
# * Register the implant's pose to a radiograph: ``xray_viz.register`` (see the README).

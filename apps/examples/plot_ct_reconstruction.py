"""
A CT scan and its reconstruction
================================

Scan a phantom on a circular orbit with :func:`xray_viz.scan` and reconstruct the stack with
:func:`xray_viz.reconstruct` (RTK's FDK on the CPU, the ``ct`` extra). The ``limb`` phantom,
32 projections on a small detector: a build-sized CT.
"""

# %%
# The scan
# --------
# :func:`~xray_viz.scan.default_orbit` is a full circle about the scene's axis through its
# centre; the detector here is a quarter of the phantom's in each direction, with four times
# the pitch (the same field of view).
import dataclasses

import matplotlib.pyplot as plt
import numpy as np

import xray_viz
from xray_viz.scan import default_orbit

scene = xray_viz.load_scene("limb")
w, h = scene.detector.shape
small = scene.replace(detector=dataclasses.replace(
    scene.detector, shape=(w // 4, h // 4), pitch=tuple(4 * p for p in scene.detector.pitch)))
orbit = default_orbit(small, projections=32)
result = xray_viz.scan(small, orbit)
print(f"{result.projections.shape[0]} projections of {result.projections.shape[1:]} pixels, "
      f"axis {result.geometry['axis']}")

# %%
# FDK
# ---
# The volume is ``mu[z, y, x]`` in 1/cm on a grid along the scene's axes (default: the detector
# pitch at the rotation axis, the detector's field of view). ``xray-viz reconstruct scan.zarr
# -o limb.nii.gz`` does the same from a stored scan, with a progress bar on a terminal.
volume = xray_viz.reconstruct(result.projections, result.geometry, method="fdk")
mu = volume.mu
print(f"volume {mu.shape} (z, y, x), voxel {volume.spacing} mm, "
      f"mu {mu.min():.3f} .. {mu.max():.3f} /cm")

# %%
# A projection and three slices through the middle of the volume: the two bones with their
# marrow in soft tissue.
nz, ny, nx = mu.shape
fig, axes = plt.subplots(1, 4, figsize=(13, 4))
axes[0].imshow(result.projections[0], cmap="gray_r")
axes[0].set_title("projection 0 (line integral)")
slices = {"z = 0": mu[nz // 2], "axial, y = 0": mu[:, ny // 2], "x = 0": mu[:, :, nx // 2]}
top = float(np.percentile(mu, 99.9))
for ax, (name, sl) in zip(axes[1:], slices.items()):
    shown = ax.imshow(sl, cmap="gray", vmin=0.0, vmax=top, origin="lower")
    ax.set_title(f"{name}, mu 1/cm")
for ax in axes:
    ax.axis("off")
fig.colorbar(shown, ax=axes[1:], shrink=0.8)

# %%
# What to try next
# ----------------
# * Fewer projections (``projections=12``) and ``method="sart"``: iterative methods fit
#   few-view scans better than FDK.
# * A Zarr store and a Dask cluster for a full-size scan: ``xray-viz scan limb -o scan.zarr``.
# * ``xray_viz.scan.cil_geometry`` / ``astra_vectors`` / ``tigre_geometry`` to reconstruct with
#   another toolbox.

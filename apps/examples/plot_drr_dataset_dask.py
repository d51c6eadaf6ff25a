"""
A DRR dataset with Dask
=======================

A training set of digitally reconstructed radiographs (DRRs): the ``limb`` phantom seen from
poses drawn at random (:class:`~xray_viz.orbit.RandomPoses`, a scene file's ``[scan] poses =
{ random = N, seed = 7, ... }``), rendered by :func:`xray_viz.scan` on a Dask cluster of
separate worker processes on this machine, each task writing its own projections into a Zarr
store, then read back with :func:`xray_viz.scan.read_zarr` and shown as a montage. The same
code runs on a cluster of many machines: only the :class:`distributed.Client` changes.
"""

# %%
# The poses
# ---------
# Each pose is a function of ``(seed, k)`` only: the gantry angle anywhere on the circle about
# the phantom's long axis (y), a cranio-caudal tilt of up to 20 degrees, an in-plane roll, the
# source 900-1100 mm from the centre and the detector 1150-1300 mm from the source, and the
# phantom shifted by up to 15 mm along each axis. Projection ``k`` is the same image whichever
# worker renders it, in whatever batch.
import dataclasses
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from distributed import Client, LocalCluster

import xray_viz
from xray_viz.orbit import Orbit, RandomPoses
from xray_viz.scan import projection, read_zarr

limb = xray_viz.load_scene("limb")
w, h = limb.detector.shape                     # 192 x 384 pixels of 1.08 mm
scene = limb.replace(detector=dataclasses.replace(
    limb.detector, shape=(w // 4, h // 4), pitch=tuple(4 * p for p in limb.detector.pitch)))
poses = RandomPoses(count=36, seed=7, tilt=(-20.0, 20.0), roll=(-10.0, 10.0),
                    sod=(900.0, 1100.0), sid=(1150.0, 1300.0), shift=(15.0, 15.0, 15.0))
orbit = Orbit("poses", projections=poses.count, axis=[0.0, 1.0, 0.0], random=poses)
if __name__ == "__main__":          # (see below: Dask's workers import this file too)
    print(f"{orbit.projections} poses of a {scene.detector.shape[0]} x "
          f"{scene.detector.shape[1]} detector, pitch {scene.detector.pitch[0]:.2f} mm")

# %%
# The cluster and the scan
# ------------------------
# A :class:`distributed.LocalCluster` of two worker processes, one thread each, listening on
# 127.0.0.1 only (its dashboard too, on a free port). Dask starts each worker as a new Python
# process that imports this script: run as a script, the work must sit under ``if __name__ ==
# "__main__":`` (in a notebook the test is simply true). Each worker loads the scene once (it
# is shipped as its scene file's text, keyed by a hash) and compiles or loads the fast engine's
# kernels when it starts; each task renders a batch of projections and writes them, chunk then ``done`` flag, into the
# store. Running the same scan again would render only the projections not flagged done.
# ``xray-viz scan scene.toml -o drr.zarr --workers 2`` does the same from the command line.
if __name__ == "__main__":
    folder = Path(tempfile.mkdtemp())
    store = folder / "drr.zarr"
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address="127.0.0.1:0") as cluster, Client(cluster) as client:
        print(f"scheduler at {cluster.scheduler_address}, {len(cluster.workers)} workers")
        xray_viz.scan(scene, orbit, store=store, client=client, batch=6)

# %%
# Read it back
# ------------
# The store holds the projections (float32 line integrals ``-ln(I/I0)``, ``(n, H, W)``), one
# ``done`` flag per projection, and the geometry: each projection's source, detector centre,
# ``u``, ``v`` and its 3 x 4 projection matrix, the labels a pose-regression network trains on.
# ``lazy=True`` keeps the Zarr array, read on indexing (a dataset larger than memory).
if __name__ == "__main__":
    data = read_zarr(store, lazy=True)
    stack = data.projections
    geometry = data.geometry
    print(f"{stack.shape[0]} projections of {stack.shape[2]} x {stack.shape[1]}, {stack.dtype}, "
          f"in {sum(f.stat().st_size for f in store.rglob('*') if f.is_file()) / 1e6:.1f} MB")
    pose = geometry["poses"][5]
    print("projection 5: source", np.round(pose["source"], 1), "mm, detector centre",
          np.round(pose["detector_center"], 1), "mm")
    with np.printoptions(precision=4, suppress=True):
        print("its 3 x 4 projection matrix (homogeneous mm to pixel column, row):")
        print(np.asarray(geometry["projection_matrices"][5]))

# %%
# The worker's image of a pose is the one this process renders for it, bit for bit.
if __name__ == "__main__":
    again = projection(scene, orbit, 5)
    print("projection 5 rendered here equals the worker's:", np.array_equal(again, stack[5]))

# %%
# The montage
# -----------
# All 36 DRRs on one grey scale (line integral): the two bones turn, tilt and slide with the
# pose; the magnification changes with the source and detector distances.
if __name__ == "__main__":
    images = stack[:]
    top = float(np.percentile(images, 99.5))
    fig, axes = plt.subplots(3, 12, figsize=(13, 6.2))
    for k, ax in enumerate(axes.ravel()):
        ax.imshow(images[k], cmap="gray_r", vmin=0.0, vmax=top)
        ax.set_title(str(k), fontsize=8)
        ax.axis("off")
    fig.suptitle("36 DRRs of the limb phantom from random poses (line integral)")
    fig.tight_layout()

# %%
# What to try next
# ----------------
# * A scene file with ``[scan] poses = { random = 100000, seed = 7, tilt = [-20, 20] }`` and
#   ``xray-viz scan scene.toml -o drr.zarr --workers 2``: the same dataset from the command
#   line, resumable; ``--scheduler tcp://HOST:8786`` for an existing cluster.
# * ``quantity="intensity"`` and ``[detector] noise = true`` for noisy images (each projection's
#   noise seed is a function of the detector's ``seed`` and ``k``).
# * A CT volume instead of meshes as the patient: ``[[ct]]`` in the scene file (see
#   :doc:`../scene_files`).

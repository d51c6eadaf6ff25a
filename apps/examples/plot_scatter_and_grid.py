"""
Scatter and the grid
====================

How much scatter reaches the detector behind a water slab, and how much an anti-scatter grid
takes away. :func:`xray_viz.render` with ``scatter="mc"`` adds the photon Monte Carlo's
scatter (:func:`xray_viz.transport` on the scene's own meshes) to the primary image; the
radiograph keeps the parts (``primary``, ``scatter``) and their ratio ``spr``. Here the
scatter-to-primary ratio (SPR) at the centre of the field against the water's thickness and
the field's size, at 80 kVp, without and with a grid of ratio 10 and 60 lines per cm
(``[detector] grid``). A coarse detector and a bounded number of photons keep it quick; the
error bars are the Monte Carlo's standard errors.
"""

# %%
# The scene
# ---------
# A 300 x 300 mm water slab 20 mm in front of the detector, the focal spot 1 m away. The
# field is the detector's size (16 x 16 pixels); the slab is always wider than the field.
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import trimesh

import xray_viz

folder = Path(tempfile.mkdtemp())
SCENE = """\
[source]
position = [0, 0, 1000]
spectrum = {{ kvp = 80, filters = {{ Al = 2.5 }} }}
[detector]
center = [0, 0, 0]
shape = [16, 16]
pitch = {pitch}
{grid}
[[body]]
name = "water"
mesh = "{mesh}"
material = "Water, Liquid"
"""
GRID = "grid = { ratio = 10, frequency = 60 }"
HISTORIES = 40_000


def central_spr(thickness_mm, field_mm, grid):
    """SPR of the central 4 x 4 pixels, and its standard error."""
    mesh = folder / f"slab{thickness_mm:g}.stl"
    slab = trimesh.creation.box(extents=[300, 300, thickness_mm])
    slab.apply_translation([0, 0, 20 + thickness_mm / 2])        # 20 mm air gap
    slab.export(mesh)
    path = folder / "scene.toml"
    path.write_text(SCENE.format(pitch=field_mm / 16, grid=GRID if grid else "",
                                 mesh=mesh.as_posix()))
    image = xray_viz.render(xray_viz.load_scene(path), scatter="mc", histories=HISTORIES)
    centre = (slice(6, 10), slice(6, 10))
    p = image.primary[centre].sum()
    s = image.scatter[centre].sum()
    err = np.sqrt((image.scatter_details["error"][centre] ** 2).sum())
    return s / p, err / p


# %%
# SPR against thickness and field size
# ------------------------------------
# Thicker water scatters more and lets less primary through; a larger field irradiates more
# water whose scatter reaches the centre. The grid passes most of the primary and stops most
# of the scatter, which arrives at oblique angles.
thicknesses = [20, 50, 100, 200]          # mm, in a 200 mm field
fields = [50, 100, 200, 300]              # mm, behind 100 mm of water
results = {}
for grid in (False, True):
    results[grid] = (
        np.array([central_spr(t, 200.0, grid) for t in thicknesses]),
        np.array([central_spr(100.0, f, grid) for f in fields]))
    label = "grid 10:1, 60 /cm" if grid else "no grid"
    print(f"{label}: SPR at 10 cm water, 20 cm field = {results[grid][0][2, 0]:.2f} "
          f"+- {results[grid][0][2, 1]:.2f}")

fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
for grid, style in ((False, "o-"), (True, "s--")):
    label = "grid 10:1, 60 lines/cm" if grid else "no grid"
    by_t, by_f = results[grid]
    axes[0].errorbar(np.array(thicknesses) / 10, by_t[:, 0], yerr=by_t[:, 1], fmt=style,
                     capsize=3, label=label)
    axes[1].errorbar(np.array(fields) / 10, by_f[:, 0], yerr=by_f[:, 1], fmt=style,
                     capsize=3, label=label)
axes[0].set_xlabel("water thickness (cm), 20 x 20 cm field")
axes[1].set_xlabel("field side (cm), 10 cm of water")
axes[0].set_ylabel("scatter-to-primary ratio at the centre")
for ax in axes:
    ax.grid(alpha=0.3)
    ax.legend()
fig.suptitle(f"80 kVp, 20 mm air gap, {HISTORIES:,} histories per point")
fig.tight_layout()

# %%
# What to try next
# ----------------
# * More histories (the error bars shrink as ``1 / sqrt(histories)``) or a finer detector.
# * ``scatter="kernel"``: the fast scatter model, calibrated on this Monte Carlo, for many
#   images (BENCHMARKS.md, "Scatter kernel model").
# * A wider air gap (move the slab away from the detector): scatter falls off with distance,
#   the primary does not.
# * ``xray-viz show scene.toml --scatter mc --histories 200000 --radiograph spr``: the SPR map
#   in the viewer (the key ``k`` cycles total, primary, scatter and SPR; the key ``a`` puts
#   the anti-scatter grid in front of the detector or takes it away).

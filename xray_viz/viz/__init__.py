"""Visualisation: the scene in 3D beside its radiograph, and the interactive viewer.

Viz only *reads* scenes, rays, hits and radiographs; nothing in tracing or physics imports it.

* :func:`plot_scene` / :class:`SceneView` - source, detector grid, HO/VE/FL/LHC, rays and hits.
* :class:`Viewer` - sliders, live re-render, pixel picking with a mu(t) chart.
* :mod:`~xray_viz.viz.rays` - the arrays drawn (chosen pixels, traced rays, mu profiles).
"""

from xray_viz.viz.rays import (AttenuationProfile, RaySelection, attenuation_profile,
                               effective_energy, inside_segments, pixel_ray_index,
                               select_pixels, trace_selection)

__all__ = ["plot_scene", "SceneView", "Viewer", "RaySelection", "AttenuationProfile",
           "select_pixels", "pixel_ray_index", "trace_selection", "inside_segments",
           "attenuation_profile", "effective_energy"]


def __getattr__(name):
    # PyVista (and VTK) only when a view is asked for: ``xray-viz render`` imports
    # :mod:`xray_viz.viz.command` for its parser, and pays nothing for them.
    if name == "Viewer":
        from xray_viz.viz.viewer import Viewer

        return Viewer
    if name in ("SceneView", "plot_scene"):
        from xray_viz.viz import scene_view

        return getattr(scene_view, name)
    raise AttributeError(name)

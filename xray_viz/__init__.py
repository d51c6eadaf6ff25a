"""xray_viz: simulate X-ray radiographs from triangle meshes, and see how the simulation works.

The pipeline follows the thesis "Computational modeling of X-ray attenuation and simulation of
medical imaging": scene (:mod:`~xray_viz.scene`) -> rays (:mod:`~xray_viz.geometry`) -> hits
(:mod:`~xray_viz.tracing`) -> path lengths (:mod:`~xray_viz.attenuation`) -> image
(:mod:`~xray_viz.physics`, :mod:`~xray_viz.output`). Meshes and phantoms feed the scene
(:mod:`~xray_viz.meshes`, :mod:`~xray_viz.phantoms`); :mod:`~xray_viz.viz` only reads.

Examples
--------
>>> import xray_viz
>>> scene = xray_viz.load_scene("sphere")
>>> image = xray_viz.render(scene)
>>> image.line_integral.shape
(256, 256)

Images are saved and read back, with the geometry they were taken in, skimage-style:

>>> import pathlib, tempfile
>>> out = xray_viz.save_image(pathlib.Path(tempfile.mkdtemp()) / "li.tiff", image.line_integral,
...                           scene=scene, quantity="line-integral")
>>> li, meta = xray_viz.load_image(out, with_metadata=True)
>>> li.shape, meta.quantity, meta.geometry["sid_mm"]
((256, 256), 'line-integral', 1500.0)
"""

from xray_viz.errors import (MaterialError, MeshError, OutputError, SceneError,
                             SceneFileNotFoundError, SpectrumError, XrayVizError)
from xray_viz.geometry import Rays, Viewport, detector_rays, viewport
from xray_viz.output import load_image, save_image
from xray_viz.reconstruct import reconstruct
from xray_viz.render import Radiograph, render
from xray_viz.scene import Body, Detector, Scene, Source, load_scene
from xray_viz.scan import scan
from xray_viz.tracing import Hits, trace_rays

__version__ = "0.1.0"


def __getattr__(name):
    if name == "show":    # the viewer (VTK, and trame in a notebook) only when asked for
        from xray_viz.viz.notebook import show

        return show
    raise AttributeError(f"module 'xray_viz' has no attribute {name!r}")


__all__ = [
    "Body", "Detector", "Hits", "MaterialError", "MeshError", "OutputError", "Radiograph",
    "Rays", "Scene", "SceneError", "SceneFileNotFoundError", "Source", "SpectrumError",
    "Viewport", "XrayVizError", "detector_rays", "load_image", "load_scene", "reconstruct",
    "render", "save_image", "scan", "show", "trace_rays", "viewport",
]

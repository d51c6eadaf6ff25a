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

import sys as _sys
import types as _types

from xray_viz.errors import (MaterialError, MeshError, OutputError, SceneError,
                             SceneFileNotFoundError, SpectrumError, XrayVizError)

__version__ = "0.1.0"

#: Where each public name of the API lives; imported on first use (``import xray_viz`` alone
#: costs the errors module, so that ``xray-viz render`` starts compiling the fast engine sooner).
_LAZY = {
    "Rays": "geometry", "Viewport": "geometry", "detector_rays": "geometry",
    "viewport": "geometry", "load_image": "output", "save_image": "output",
    "reconstruct": "reconstruct", "Radiograph": "render", "render": "render", "Body": "scene",
    "Detector": "scene", "Scene": "scene", "Source": "scene", "load_scene": "scene",
    "scan": "scan", "Hits": "tracing", "trace_rays": "tracing",
    "transport": "transport", "Transport": "transport",
    "pose_gradient": "gradients", "acquisition_gradient": "gradients",
    "register": "registration", "Registration": "registration",
}

def _is_submodule(name: str) -> bool:
    """Whether ``xray_viz.<name>`` is a module or subpackage on disk (found, not imported)."""
    import importlib.util

    return importlib.util.find_spec(f"{__name__}.{name}") is not None


def __getattr__(name):
    where = _LAZY.get(name)
    if where == "geometry":
        from xray_viz.geometry import Rays, Viewport, detector_rays, viewport  # noqa: F401
    elif where == "output":
        from xray_viz.output import load_image, save_image  # noqa: F401
    elif where == "reconstruct":
        from xray_viz.reconstruct import reconstruct  # noqa: F401
    elif where == "render":
        from xray_viz.render import Radiograph, render  # noqa: F401
    elif where == "scene":
        from xray_viz.scene import Body, Detector, Scene, Source  # noqa: F401
        from xray_viz.scene_file import load_scene  # noqa: F401
    elif where == "scan":
        from xray_viz.scan import scan  # noqa: F401
    elif where == "transport":
        from xray_viz.transport import Transport, transport  # noqa: F401
    elif where == "tracing":
        from xray_viz.tracing import Hits, trace_rays  # noqa: F401
    elif where == "gradients":      # issue 41: exact pose gradients
        from xray_viz.gradients import acquisition_gradient, pose_gradient  # noqa: F401
    elif where == "registration":   # issue 41: 2D/3D registration
        from xray_viz.registration import Registration, register  # noqa: F401
    elif name == "show":    # the viewer (VTK, and trame in a notebook) only when asked for
        from xray_viz.viz.notebook import show

        return show
    elif not name.startswith("_") and _is_submodule(name):
        # a public subpackage or module, imported on first use as an eager ``import xray_viz``
        # would have (``xray_viz.attenuation.path_lengths(...)``, ``xray_viz.physics.hvl``)
        import importlib

        return importlib.import_module(f"{__name__}.{name}")
    else:
        raise AttributeError(f"module 'xray_viz' has no attribute {name!r}")
    loaded = locals()
    for key, module in _LAZY.items():
        if module == where:
            globals()[key] = loaded[key]
    return loaded[name]


def __dir__():
    return sorted(set(globals()) | set(__all__))


class _Package(_types.ModuleType):
    """The package's module: ``xray_viz.render``, ``xray_viz.scan`` and ``xray_viz.reconstruct``
    stay the functions of those names when their modules are first imported (the import system
    sets a package's attribute to each submodule it loads; the functions were imported over
    them when this package imported everything eagerly)."""

    def __setattr__(self, name, value):
        if (isinstance(value, _types.ModuleType) and value.__name__ == f"{__name__}.{name}"
                and _LAZY.get(name) == name):
            value = getattr(value, name, value)
        super().__setattr__(name, value)


_sys.modules[__name__].__class__ = _Package


__all__ = [
    "Body", "Detector", "Hits", "MaterialError", "MeshError", "OutputError", "Radiograph",
    "Rays", "Scene", "SceneError", "SceneFileNotFoundError", "Source", "SpectrumError",
    "Viewport", "XrayVizError", "detector_rays", "load_image", "load_scene", "reconstruct",
    "render", "save_image", "scan", "show", "trace_rays", "transport", "Transport", "viewport",
    "pose_gradient", "acquisition_gradient", "register", "Registration",     # issue 41
]

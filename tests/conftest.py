"""Shared test settings. Viz: render off-screen (EGL when there is no X server) and keep
pytest-pyvista's cached images in tests/image_cache/."""

import os
import sys

# Read by PyVista at import and by VTK when it creates a render window.
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def pytest_configure(config):
    if hasattr(config.option, "image_cache_dir") and config.option.image_cache_dir is None:
        config.option.image_cache_dir = "tests/image_cache"

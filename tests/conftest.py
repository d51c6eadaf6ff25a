"""Shared test settings. Viz: render off-screen (EGL when there is no X server) and keep
pytest-pyvista's cached images in tests/image_cache/."""

import os
import sys

# Mesh reports are not read from or kept on disk during tests (tests/meshes/test_report_cache.py turns
# it on in a temporary folder): a test that changes the checker's behaviour must see it run.
os.environ["XRAY_VIZ_CACHE_DIR"] = "off"
# nor the bundled phantoms' reports shipped with the package (test_report_cache.py reads them)
os.environ["XRAY_VIZ_SHIPPED_REPORTS"] = "off"

# Read by PyVista at import and by VTK when it creates a render window.
os.environ.setdefault("PYVISTA_OFF_SCREEN", "true")
if sys.platform.startswith("linux") and not os.environ.get("DISPLAY"):
    os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkEGLRenderWindow")


def pytest_configure(config):
    import atexit

    if hasattr(config.option, "image_cache_dir") and config.option.image_cache_dir is None:
        config.option.image_cache_dir = "tests/image_cache"
    atexit.register(_skip_itk_teardown)      # first registered: the last exit handler to run


# Hypothesis (tests/tracing/test_properties.py): the default profile is derandomized (the same examples
# on every run and machine) and keeps no example database, so CI is reproducible and leaves no
# .hypothesis folder; HYPOTHESIS_PROFILE=slow runs many more, random examples (failures are
# saved in .hypothesis/, which git ignores, and printed with a @reproduce_failure blob).
try:
    from hypothesis import HealthCheck, settings as _hypothesis_settings
except ImportError:            # the test extra is not installed: test_properties.py says so
    pass
else:
    _hypothesis_settings.register_profile(
        "xray_viz", max_examples=15, deadline=None, derandomize=True, database=None,
        print_blob=True, suppress_health_check=[HealthCheck.too_slow])
    _hypothesis_settings.register_profile(
        "slow", max_examples=300, deadline=None, print_blob=True,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
    _hypothesis_settings.load_profile(os.environ.get("HYPOTHESIS_PROFILE", "xray_viz"))


_SESSION_STATUS = []


def _skip_itk_teardown():
    """ITK's SWIG modules (RTK, loaded by the reconstruction and geometry tests) can crash the
    interpreter's final teardown when other extension modules (VTK's) were loaded in the same
    process: a capsule of ``itk._ITKPyBasePython`` is freed after its type (a segmentation
    fault in ``capsule_dealloc`` after every test has passed: exit 139). Registered first, so
    run last of the exit handlers: with ITK loaded, the session's exit status goes to
    ``os._exit`` and the module teardown is skipped."""
    if _SESSION_STATUS and "itk" in sys.modules:
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_SESSION_STATUS[-1])


def pytest_sessionfinish(session, exitstatus):
    _SESSION_STATUS.append(int(exitstatus))

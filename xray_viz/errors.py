"""Errors raised by xray_viz.

Every error subclasses a built-in exception (``ValueError``, ``FileNotFoundError``) so that
``except ValueError`` works, and also :class:`XrayVizError`, so that the command line can tell
a user's bad input (printed as one line) from a bug (a traceback).
"""

from __future__ import annotations


class XrayVizError(Exception):
    """Base class of every error that describes bad input rather than a bug."""


class SceneError(XrayVizError, ValueError):
    """A scene file or scene description is malformed: unknown key, wrong type, bad value."""


class MeshError(XrayVizError, ValueError):
    """A mesh is missing, unreadable, empty, non-finite, or cannot be traced correctly."""


class MaterialError(XrayVizError, ValueError):
    """A material name, formula or density is unknown or invalid."""


class SpectrumError(XrayVizError, ValueError):
    """An X-ray spectrum specification is invalid."""


class OutputError(XrayVizError, ValueError):
    """An output file name or format is not supported."""


class SceneFileNotFoundError(XrayVizError, FileNotFoundError):
    """A file named by the user (scene, mesh, spectrum) does not exist."""

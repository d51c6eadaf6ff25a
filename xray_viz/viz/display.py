"""Whether a window can open here: kept apart from the command line (:mod:`xray_viz.viz.command`)
so that the notebook viewer, the walkthroughs and the command all ask the same question without
importing each other."""

from __future__ import annotations

import os
import sys

from xray_viz.errors import XrayVizError

__all__ = ["require_display"]


def require_display(remedy: str) -> None:
    """Raise unless there is a display to open a window on (always true off Linux).

    Without ``DISPLAY`` (or ``WAYLAND_DISPLAY``) VTK only logs "bad X server connection"
    and shows nothing; this says so in one line instead.

    Parameters
    ----------
    remedy : str
        What to use instead, e.g. ``"--off-screen to write the figures as PNGs"``.

    Raises
    ------
    XrayVizError
        ``no display to open a window on (DISPLAY is not set); use <remedy>``.
    """
    if sys.platform.startswith("linux") and not os.environ.get("DISPLAY") \
            and not os.environ.get("WAYLAND_DISPLAY"):
        raise XrayVizError(f"no display to open a window on (DISPLAY is not set); use "
                           f"{remedy}")

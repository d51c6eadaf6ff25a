"""The checks of 3-vectors given by a user, written once (issue 37).

Each caller names the value as its user wrote it (``[scan] axis``, ``pose 3: source``,
``geometry center``) and chooses the error class of its layer; the rule is the same
everywhere: three finite numbers (booleans are not numbers), and for a direction not all 0.
The scene's own positions and directions have stricter rules of their own (a coordinate limit,
a usable length: ``xray_viz.scene``).

Examples
--------
>>> vector3([0, 1, 0], "[scan] axis").tolist()
[0.0, 1.0, 0.0]
>>> vector3([0, 0, 0], "rotation axis", direction=True)
Traceback (most recent call last):
...
xray_viz.errors.SceneError: rotation axis must be 3 finite numbers, not all 0; got [0, 0, 0]
"""

from __future__ import annotations

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["vector3"]


def _has_bool(value) -> bool:
    if isinstance(value, (bool, np.bool_)):
        return True
    if isinstance(value, np.ndarray):
        return value.dtype.kind == "b"
    try:
        return any(isinstance(x, (bool, np.bool_)) for x in value)
    except TypeError:
        return False


def vector3(value, name: str, *, direction: bool = False, unit: bool = False,
            error: type[Exception] = SceneError, units: str = "") -> np.ndarray:
    """``value`` as a (3,) float64 array, or ``error`` naming ``name`` and the value.

    Parameters
    ----------
    value : sequence of 3 numbers or array
    name : str
        What the user calls it, first in the message.
    direction : bool
        Not all 0 (an axis, a detector direction).
    unit : bool
        Return it normalised (a direction).
    error : Exception class
        The caller's (``SceneError``, ``ReconstructionError``...).
    units : str
        Said in the message after "numbers", e.g. ``" (mm)"``.

    Raises
    ------
    error
        ``"{name} must be 3 finite numbers{units}[, not all 0]; got {value!r}"``.
    """
    try:
        out = np.array(value, dtype=np.float64).reshape(-1)
        ok = out.shape == (3,) and bool(np.all(np.isfinite(out))) and not _has_bool(value)
    except (TypeError, ValueError, OverflowError):
        ok = False
    norm = float(np.linalg.norm(out)) if ok else 0.0
    if not ok or (direction or unit) and not norm > 0:
        shown = value.tolist() if isinstance(value, np.ndarray) else value
        raise error(f"{name} must be 3 finite numbers{units}"
                    f"{', not all 0' if direction or unit else ''}; got {shown!r}")
    return out / norm if unit else out

